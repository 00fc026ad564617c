"""Operational-space (end-effector) building blocks: site, kinematics, references, oracle.

The operational-space task (paper section IV-A-2): the end effector (a MuJoCo *site*,
:func:`ee_site`) reaches from its home position to each target along a quintic straight
line of ``duration`` seconds. At each control step the desired end-effector acceleration is

    xdd*_t = xdd_ref(t) + kp (x_ref(t) - x_t) + kd (xd_ref(t) - xd_t)

and the controller input is ``(q, qdot, xdd*)``. Everything is linear, in the world frame,
of the site's origin: position ``x (3,)``, velocity ``xd = J qd``, acceleration
``xdd = J qdd + Jdot qd`` with the translational site Jacobian ``J (3, nv)``.

Kinematics are computed by MuJoCo's C engine (``mj_kinematics``, ``mj_comPos``,
``mj_comVel``, ``mj_jacSite``, ``mj_jacDot``), on the host, through ``jax.pure_callback``
(``vmap_method="broadcast_all"``: one host call per batch, like the native simulator).
Measured against MJX in JAX on the iiwa (``docs/opspace.md``): compile 0.13 s instead of
33-37 s, and 180 / 390 us instead of 480 / 1230 us per control step for a batch of 5 / 15
states. The callback's inputs are wrapped in ``stop_gradient``: the kinematics are
constants of the state under ``jax.grad``; :func:`task_acceleration` is linear in ``qacc``
and differentiable in it (the path a task loss on predicted joint accelerations needs).

Host classes (NumPy float64, any leading batch shape; the oracles of the tests):
:class:`HostKinematics`, :class:`HostOracle`. JAX functions (float32, jit/vmap-able):
:func:`kinematics`, :func:`ee_position`, :func:`ee_velocity`, :func:`ee_jacobian`,
:func:`ee_acceleration`, :func:`oracle_policy`, :func:`pd_policy`.

Examples:
  >>> import numpy as np
  >>> from cfm_jax import robots
  >>> iiwa = robots.load("iiwa14")
  >>> ref = cartesian_reaching(iiwa, None, None, duration=2.0, control_dt=0.01)
  >>> ref.x.shape
  (5, 201, 3)
  >>> np.round(ref.x[0, 0], 3).tolist()  # the flange at the home pose
  [0.669, 0.0, 0.285]
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from cfm_jax import native, references, rollout
from cfm_jax.config import ConfigError, check_duration

DEFAULT_SITES = ("ee", "flange")
"""Site names tried in order when no site is configured."""

# Gains of the null-space posture term of the oracle (1/s^2 and 1/s): a critically damped
# joint-space PD towards the home pose, 5 rad/s, acting only in the task's null space.
NULL_KP = 25.0
NULL_KD = 10.0
# Relative singular-value cut-off of the pseudo-inverse of J M^-1 J^T (the two-link arm
# moves in a plane, so its 3 x 3 J M^-1 J^T has rank 2; the iiwa's has rank 3 away from
# singularities).
RCOND = 1e-9


# ---- site -------------------------------------------------------------------------------


def site_names(robot) -> tuple[str, ...]:
    """Names of the model's sites in id order (unnamed sites as ``'#id'``).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.

    Returns:
      A tuple of ``nsite`` names.

    Examples:
      >>> from cfm_jax import robots
      >>> site_names(robots.load("two_link_arm")), site_names(robots.load("iiwa14"))
      (('tip',), ('flange',))
    """
    model = robot.mj_model
    return tuple(
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, i) or f"#{i}" for i in range(model.nsite)
    )


def ee_site(robot, name: str | None = None) -> int:
    """Id of the end-effector site: ``name`` if given, else the first of :data:`DEFAULT_SITES`
    (``"ee"``, then ``"flange"``) that the model has.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      name: a site name of the robot's MJCF, or None for the default.

    Returns:
      The site id (int).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> ee_site(iiwa) == ee_site(iiwa, "flange")
      True
      >>> ee_site(robots.load("two_link_arm"))  # its only site is called "tip"
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.site=None is not allowed for robot 'two_link_arm': ...

    Raises:
      ConfigError: no such site, no default site, or a site fixed to the world body; the
        message names the site and lists the model's sites.
    """
    model = robot.mj_model
    names = site_names(robot)
    if name is None:
        for candidate in DEFAULT_SITES:
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, candidate)
            if site >= 0:
                break
        else:
            raise ConfigError(
                f"task.site=None is not allowed for robot {robot.name!r}: it has no site named "
                f"{' or '.join(map(repr, DEFAULT_SITES))}; name one of its sites {names} in "
                'task.site, or add <site name="ee"/> to the end-effector body of its MJCF'
            )
    else:
        if not isinstance(name, str):
            raise ConfigError(f"task.site={name!r} is not allowed: a site name (str) or None")
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
        if site < 0:
            raise ConfigError(
                f"task.site={name!r} is not allowed: robot {robot.name!r} has no such site; "
                f"its sites are {names}"
            )
    if int(model.body_weldid[model.site_bodyid[site]]) == 0:
        raise ConfigError(
            f"task.site={names[site]!r} is not allowed: it is fixed to the world (no joint "
            f"between it and the world body) and cannot move; choose a site on the arm among "
            f"{names}"
        )
    return int(site)


def _site_id(robot, site) -> int:
    """A site id from an id, a name or None (default site)."""
    if isinstance(site, int | np.integer) and not isinstance(site, bool):
        if not 0 <= int(site) < robot.mj_model.nsite:
            raise ConfigError(
                f"task.site={site!r} is not allowed: a site id in [0, {robot.mj_model.nsite}) "
                f"or a name among {site_names(robot)}"
            )
        return int(site)
    return ee_site(robot, site)


# ---- kinematics -------------------------------------------------------------------------


class Kinematics(NamedTuple):
    """End-effector (site origin) kinematics in the world frame, leading batch axes ``...``.

    Attributes:
      position: ``x``, ``(..., 3)`` (m).
      velocity: ``xd = J qd``, ``(..., 3)`` (m/s).
      jacobian: ``J = dx/dq``, ``(..., 3, nv)``.
      bias_acceleration: ``Jdot qd``, ``(..., 3)`` (m/s^2): the site's acceleration when
        ``qdd = 0``, so that ``xdd = J qdd + Jdot qd``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")  # stretched out along x at q = 0, 0.9 m long
      >>> kin = HostKinematics(arm, "tip")(np.zeros(2), np.array([1.0, 0.0]))
      >>> np.round(kin.position, 3).tolist(), np.round(kin.velocity, 3).tolist()
      ([0.9, 0.0, 1.0], [0.0, 0.0, 0.9])
      >>> np.round(kin.bias_acceleration, 3).tolist()  # centripetal, towards the shoulder
      [-0.9, 0.0, 0.0]
    """

    position: np.ndarray
    velocity: np.ndarray
    jacobian: np.ndarray
    bias_acceleration: np.ndarray


def task_acceleration(kin: Kinematics, qacc):
    """``xdd = J qacc + Jdot qd`` from :class:`Kinematics` and joint accelerations.

    Linear and differentiable in ``qacc``; NumPy in (float64 :class:`HostKinematics`), NumPy
    out, otherwise ``jnp``.

    Args:
      kin: :class:`Kinematics` of the states, leading axes ``...``.
      qacc: joint accelerations, ``(..., nv)``.

    Returns:
      The site accelerations ``xdd``, ``(..., 3)``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> kin = HostKinematics(arm, "tip")(np.zeros(2), np.array([1.0, 0.0]))
      >>> np.round(task_acceleration(kin, np.array([1.0, 0.0])), 3).tolist()
      [-0.9, 0.0, 0.9]
    """
    arrays = (kin.jacobian, kin.bias_acceleration, qacc)
    xp = np if all(isinstance(a, np.ndarray) for a in arrays) else jnp
    return xp.einsum("...ij,...j->...i", kin.jacobian, qacc) + kin.bias_acceleration


class HostKinematics:
    """Site kinematics with MuJoCo C on the host, float64, any leading batch shape.

    ``HostKinematics(robot, site)(qpos (..., nq), qvel (..., nv)) -> Kinematics`` of NumPy
    float64 arrays. Per state: ``mj_kinematics``, ``mj_comPos``, ``mj_comVel``, then
    ``J = mj_jacSite`` (translational part) and ``Jdot = mj_jacDot`` at the site position.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> kin = HostKinematics(iiwa)(iiwa.home, np.zeros(7))
      >>> kin.jacobian.shape, np.round(kin.position, 3).tolist()
      ((3, 7), [0.669, 0.0, 0.285])
    """

    def __init__(self, robot, site: int | str | None = None):
        self.model = robot.mj_model
        self.site = _site_id(robot, site)
        self.body = int(self.model.site_bodyid[self.site])
        self.data = mujoco.MjData(self.model)

    def _load(self, qpos, qvel) -> None:
        data = self.data
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        mujoco.mj_comVel(self.model, data)

    def _jacobians(self):
        """``(x, J, Jdot)`` of the loaded state."""
        nv = self.model.nv
        x = self.data.site_xpos[self.site].copy()
        jac, jac_dot = np.empty((3, nv)), np.empty((3, nv))
        mujoco.mj_jacSite(self.model, self.data, jac, None, self.site)
        mujoco.mj_jacDot(self.model, self.data, jac_dot, None, x, self.body)
        return x, jac, jac_dot

    def __call__(self, qpos, qvel) -> Kinematics:
        nq, nv = self.model.nq, self.model.nv
        batch_shape = np.shape(qpos)[:-1]
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.broadcast_to(np.asarray(qvel, np.float64), batch_shape + (nv,)).reshape(-1, nv)
        n = qpos.shape[0]
        x, jac, bias = np.empty((n, 3)), np.empty((n, 3, nv)), np.empty((n, 3))
        for i in range(n):
            self._load(qpos[i], qvel[i])
            x[i], jac[i], jac_dot = self._jacobians()
            bias[i] = jac_dot @ qvel[i]
        velocity = np.einsum("nij,nj->ni", jac, qvel)
        return Kinematics(
            x.reshape(batch_shape + (3,)),
            velocity.reshape(batch_shape + (3,)),
            jac.reshape(batch_shape + (3, nv)),
            bias.reshape(batch_shape + (3,)),
        )


_HOSTS: dict = {}


def _cached(kind, robot, site, *args):
    """One host object per (kind, model, site, args); the model is kept alive with it."""
    key = (kind.__name__, id(robot.mj_model), site, args)
    if key not in _HOSTS:
        _HOSTS[key] = (robot.mj_model, kind(robot, site, *args))
    return _HOSTS[key][1]


def _float32(function):
    def host(*args):
        return jax.tree.map(lambda a: np.asarray(a, np.float32), function(*args))

    return host


def kinematics(
    robot, qpos, qvel, site: int | str | None = None, simulator: str = "native"
) -> Kinematics:
    """:class:`Kinematics` of the site as float32 JAX arrays, any leading batch shape.

    ``simulator="native"``: one ``jax.pure_callback`` into :class:`HostKinematics` (under
    ``vmap``, one host call for the whole batch), MuJoCo C in float64. ``"mjx"``:
    :func:`mjx_kinematics`, in JAX on the device, no host callback. Either way treated as
    a constant of ``(qpos, qvel)`` by ``jax.grad``.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)`` (broadcast to ``qpos``'s batch shape).
      site: the site's id or name, or None for :func:`ee_site`'s default.
      simulator: ``"native"`` or ``"mjx"``.

    Returns:
      :class:`Kinematics` of float32 ``jax.Array`` with leading axes ``...``.

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> kin = jax.jit(lambda q, qd: kinematics(iiwa, q, qd))(iiwa.home, np.zeros(7))
      >>> kin.jacobian.shape, kin.position.dtype
      ((3, 7), dtype('float32'))
    """
    if simulator == "mjx":
        qpos = jax.lax.stop_gradient(jnp.asarray(qpos, jnp.float32))
        qvel = jax.lax.stop_gradient(jnp.asarray(qvel, jnp.float32))
        return mjx_kinematics(robot, qpos, qvel, site)
    _check_simulator(simulator)
    host = _cached(HostKinematics, robot, _site_id(robot, site))
    nv = robot.nv
    qpos = jax.lax.stop_gradient(jnp.asarray(qpos, jnp.float32))
    qvel = jax.lax.stop_gradient(jnp.broadcast_to(jnp.asarray(qvel, jnp.float32), qpos.shape))
    batch = qpos.shape[:-1]
    shapes = Kinematics(
        *(jax.ShapeDtypeStruct(batch + shape, jnp.float32) for shape in ((3,), (3,), (3, nv), (3,)))
    )
    return jax.pure_callback(_float32(host), shapes, qpos, qvel, vmap_method="broadcast_all")


def _check_simulator(simulator: str) -> None:
    if simulator not in rollout.SIMULATORS:
        raise ConfigError(f"simulator={simulator!r} is not allowed: one of {rollout.SIMULATORS}")


def _mjx_site(robot, site):
    """``(mjx model, site id, body id, blank data)``; MJX kinematics here need nq == nv."""
    if robot.nq != robot.nv:
        raise ValueError(
            f"robot {robot.name!r} has nq={robot.nq} != nv={robot.nv} (a ball or free joint); "
            "the MJX site kinematics take hinge and slide joints only"
        )
    sid = _site_id(robot, site)
    model = robot.mjx_model
    return model, sid, int(robot.mj_model.site_bodyid[sid]), mjx.make_data(model)


def _over_batch(one, *arrays):
    """``one`` of unbatched arrays, mapped over the common leading axes of ``arrays``."""
    batch = jnp.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    flat = [jnp.broadcast_to(a, batch + a.shape[-1:]).reshape(-1, a.shape[-1]) for a in arrays]
    out = jax.vmap(one)(*flat)
    return jax.tree.map(lambda x: x.reshape(batch + x.shape[1:]), out)


def mjx_kinematics(robot, qpos, qvel, site: int | str | None = None) -> Kinematics:
    """:class:`Kinematics` of the site computed by MJX, in JAX: no host callback.

    ``x`` is MJX's ``site_xpos`` after ``mjx.kinematics`` and ``mjx.com_pos``, ``J`` the
    translational part of ``mjx.jac`` at the site (MuJoCo's ``mj_jacSite``), ``xd = J qd``,
    and ``Jdot qd`` the derivative of ``J(q) qd`` along ``qd`` (forward-mode
    differentiation through MJX; MuJoCo C's ``mj_jacDot`` is the host counterpart).
    float32, any leading batch shape, jit/vmap-able and differentiable.

    Args:
      robot: a :class:`cfm_jax.robots.Robot` with hinge and slide joints (``nq == nv``).
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      :class:`Kinematics` of float32 ``jax.Array``.

    Raises:
      ValueError: the robot has a ball or free joint.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")  # stretched out along x at q = 0, 0.9 m long
      >>> kin = mjx_kinematics(arm, np.zeros(2), np.array([1.0, 0.0]), "tip")  # doctest: +SKIP
      >>> np.round(np.asarray(kin.velocity, np.float64), 3).tolist()  # doctest: +SKIP
      [0.0, 0.0, 0.9]
      >>> np.round(np.asarray(kin.bias_acceleration, np.float64), 3).tolist()  # doctest: +SKIP
      [-0.9, 0.0, 0.0]
    """
    model, sid, bid, blank = _mjx_site(robot, site)

    def position_and_jacobian(q):
        data = mjx.com_pos(model, mjx.kinematics(model, blank.replace(qpos=q)))
        x = data.site_xpos[sid]
        jacp, _ = mjx.jac(model, data, x, bid)  # (nv, 3)
        return x, jacp.T

    def one(q, qd):
        x, jac = position_and_jacobian(q)
        velocity, bias = jax.jvp(lambda p: position_and_jacobian(p)[1] @ qd, (q,), (qd,))
        return Kinematics(x, velocity, jac, bias)

    qpos, qvel = (jnp.asarray(a, jnp.float32) for a in (qpos, qvel))
    return _over_batch(one, qpos, qvel)


def ee_position(robot, qpos, site: int | str | None = None):
    """Site position ``x(q)`` in the world frame, ``(..., 3)`` float32 (m).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``x``, ``(..., 3)`` float32 ``jax.Array``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")  # shoulder at (0, 0, 1), links 0.5 + 0.4 m
      >>> x = ee_position(arm, np.zeros((4, 2)), "tip")  # a batch of 4 poses
      >>> x.shape, np.round(np.asarray(x[0], float), 3).tolist()
      ((4, 3), [0.9, 0.0, 1.0])
    """
    return kinematics(robot, qpos, jnp.zeros(jnp.shape(qpos)), site).position


def ee_velocity(robot, qpos, qvel, site: int | str | None = None):
    """Linear site velocity ``xd = J(q) qd`` in the world frame, ``(..., 3)`` float32.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``xd`` (m/s), ``(..., 3)`` float32 ``jax.Array``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> xd = ee_velocity(arm, np.zeros(2), np.array([1.0, 0.0]), "tip")
      >>> np.round(np.asarray(xd, float), 3).tolist()
      [0.0, 0.0, 0.9]
    """
    return kinematics(robot, qpos, qvel, site).velocity


def ee_jacobian(robot, qpos, site: int | str | None = None):
    """Translational site Jacobian ``J(q) = dx/dq`` (world frame), ``(..., 3, nv)``.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``J``, ``(..., 3, nv)`` float32 ``jax.Array``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> jac = ee_jacobian(arm, np.zeros(2), "tip")
      >>> jac.shape, np.round(np.asarray(jac[2], float), 3).tolist()  # dz/dq: lever arms
      ((3, 2), [0.9, 0.4])
    """
    return kinematics(robot, qpos, jnp.zeros(jnp.shape(qpos)), site).jacobian


def ee_acceleration(robot, qpos, qvel, qacc, site: int | str | None = None):
    """Linear site acceleration ``xdd = J(q) qacc + Jdot(q, qd) qd`` in the world frame,
    ``(..., 3)`` float32 (m/s^2); differentiable in ``qacc``.

    This is the classical acceleration of the site point (the second time derivative of
    ``x``), without gravity. MuJoCo's ``mj_objectAcceleration`` (after
    ``mj_rnePostConstraint``) returns, in its linear part with ``flg_local=0``, this same
    quantity minus ``opt.gravity`` (its recursion starts from the world body accelerating at
    ``-gravity``); it already adds the ``omega x v`` term that converts MuJoCo's spatial
    ``cacc`` to the classical acceleration. So ``xdd = res[3:] + opt.gravity``.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      qacc: joint accelerations, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``xdd``, ``(..., 3)`` float32 ``jax.Array``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> xdd = ee_acceleration(arm, np.zeros(2), np.array([1.0, 0.0]), np.zeros(2), "tip")
      >>> np.round(np.asarray(xdd, float), 3).tolist()  # centripetal, |qd|^2 * 0.9 m
      [-0.9, 0.0, 0.0]
    """
    return task_acceleration(kinematics(robot, qpos, qvel, site), qacc)


# ---- references ------------------------------------------------------------------------


class CartesianReference(NamedTuple):
    """End-effector reference trajectories, one per target.

    Arrays are NumPy float64 (:func:`as_jax` makes float32 JAX copies).

    Attributes:
      x: ``(targets, steps + 1, 3)`` site positions at the control times
        ``0, dt, ..., duration`` (world frame, m).
      xd: ``(targets, steps + 1, 3)`` site velocities at the same times (m/s).
      xdd: ``(targets, steps + 1, 3)`` site accelerations at the same times (m/s^2).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> ref.x.shape, ref.steps, ref.x[0, -1].tolist()
      ((1, 51, 3), 50, [0.5, 0.0, 1.4])
    """

    x: np.ndarray
    xd: np.ndarray
    xdd: np.ndarray

    @property
    def steps(self) -> int:
        """Number of control steps per rollout."""
        return self.x.shape[1] - 1


def reach(robot, site: int | str | None = None) -> tuple[float, np.ndarray, str]:
    """Upper bound of the distance between the arm's base and the site, from the model.

    The base is the anchor of the last joint of the site's kinematic chain whose anchor
    cannot move (it lies on the axes of all hinges before it, with no slide joint before
    it): for the iiwa joint 2 at (0, 0, 0.36), for the two-link arm the shoulder. The reach
    is the sum of the distances between consecutive joint anchors from there to the site
    (taken at ``qpos0``), plus the travel ``hi - lo`` of every slide joint (infinite if a
    slide joint is unlimited). A target farther than this is certainly unreachable;
    joint limits may make nearer targets unreachable too.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``(reach in m, base position (3,), base joint name)``.

    Examples:
      >>> from cfm_jax import robots
      >>> length, base, joint = reach(robots.load("two_link_arm"), "tip")
      >>> round(length, 6), base.tolist(), joint
      (0.9, [0.0, 0.0, 1.0], 'shoulder')
    """
    model = robot.mj_model
    site = _site_id(robot, site)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    chain = []
    body = int(model.site_bodyid[site])
    while body > 0:
        start, count = model.body_jntadr[body], model.body_jntnum[body]
        chain = list(range(start, start + count)) + chain
        body = int(model.body_parentid[body])
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    base = 0
    for k in range(1, len(chain)):
        anchor = data.xanchor[chain[k]]
        fixed = True
        for j in chain[:k]:
            if int(model.jnt_type[j]) == slide:
                fixed = False
                break
            offset = anchor - data.xanchor[j]
            if np.linalg.norm(np.cross(offset, data.xaxis[j])) > 1e-9:
                fixed = False
                break
        if not fixed:
            break
        base = k
    points = [data.xanchor[j] for j in chain[base:]] + [data.site_xpos[site]]
    length = float(np.sum(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1)))
    for j in chain:
        if int(model.jnt_type[j]) == slide:
            limited = bool(model.jnt_limited[j])
            length += float(np.ptp(model.jnt_range[j])) if limited else np.inf
        elif int(model.jnt_type[j]) != hinge:
            length = np.inf
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, chain[base]) or f"#{chain[base]}"
    return length, data.xanchor[chain[base]].copy(), name


def default_cartesian_targets(robot, site: int | str | None = None, home=None) -> np.ndarray:
    """Five reachable end-effector targets: the site positions at the five default
    joint-space targets :func:`cfm_jax.references.default_targets` (inside the joint limits, so
    reachable by construction, and deterministic; the same reaching motions as the
    joint-space task, seen at the end effector).

    For the iiwa with the flange from the home pose they lie 0.21 to 0.57 m from the home
    flange position.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` pose the joint-space targets are placed around, or None for
        ``robot.home``.

    Returns:
      ``(5, 3)`` positions in the world frame (m).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> targets = default_cartesian_targets(arm, "tip")
      >>> targets.shape, bool(np.all(targets[:, 1] == 0.0))  # the arm moves in the x-z plane
      ((5, 3), True)
    """
    home = robot.home if home is None else np.asarray(home, np.float64)
    joint_targets = references.default_targets(robot.joint_range, home)
    return HostKinematics(robot, site)(joint_targets, np.zeros_like(joint_targets)).position


def check_targets(robot, targets, site: int | str | None = None) -> np.ndarray:
    """Validate end-effector targets; returns them as a ``(k, 3)`` float64 array.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      targets: end-effector positions (m, world frame), anything ``np.asarray`` makes a
        ``(k, 3)`` array of.
      site: the site's id or name, or None for :func:`ee_site`'s default (for the reach).

    Returns:
      ``(k, 3)`` float64 array of the targets.

    Raises:
      ConfigError: not a non-empty ``(k, 3)`` array of finite numbers, or a target farther
        from the arm's base than its :func:`reach` (the message names the target and its
        distance).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> check_targets(arm, [[0.5, 0.0, 1.4]], "tip").shape
      (1, 3)
      >>> check_targets(arm, [[2.0, 0.0, 0.0]], "tip")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.targets[0]=(2.0, 0.0, 0.0) is not allowed: it is ...
    """
    try:
        array = np.asarray(targets, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.ndim != 2 or array.shape[0] == 0 or array.shape[1] != 3:
        shape = None if array is None else array.shape
        raise ConfigError(
            f"task.targets={targets!r} is not allowed (shape {shape}): a non-empty sequence "
            "of end-effector positions (x, y, z) in metres, shape (k, 3)"
        )
    if not np.all(np.isfinite(array)):
        k = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise ConfigError(
            f"task.targets[{k}]={tuple(array[k].tolist())} is not allowed: finite positions"
        )
    length, base, joint = reach(robot, site)
    distance = np.linalg.norm(array - base, axis=1)
    far = np.flatnonzero(distance > length)
    if far.size:
        k = int(far[0])
        raise ConfigError(
            f"task.targets[{k}]={tuple(np.round(array[k], 4).tolist())} is not allowed: it is "
            f"{distance[k]:.3f} m from the base of robot {robot.name!r} (joint {joint!r} at "
            f"{tuple(np.round(base, 4).tolist())}), beyond the arm's reach of {length:.3f} m "
            f"to site {site_names(robot)[_site_id(robot, site)]!r}"
        )
    return array


def cartesian_reaching(
    robot, site: int | str | None, targets, duration: float, control_dt: float, home=None
) -> CartesianReference:
    """Quintic straight-line paths of the site from its home position to each target.

    ``x(t) = x_home + (x_goal - x_home) s(t / duration)``, ``s(u) = 10 u^3 - 15 u^4 + 6 u^5``
    (minimum jerk; zero velocity and acceleration at both ends), sampled every
    ``control_dt`` (:func:`cfm_jax.references.quintic` per target).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      site: site name, id, or None for :func:`ee_site`'s default.
      targets: ``(k, 3)`` end-effector positions (m, world frame), or None for
        :func:`default_cartesian_targets`.
      duration: seconds per reach, a whole number (>= 1) of control periods.
      control_dt: control period (s).
      home: ``(nq,)`` start pose, or None for ``robot.home``.

    Returns:
      A :class:`CartesianReference` ``(k, steps + 1, 3)``.

    Raises:
      ConfigError: bad site, home, targets (see :func:`check_targets`) or duration.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> np.round(ref.x[0, 0], 3).tolist()  # the tip at the home pose
      [0.636, 0.0, 0.929]
    """
    check_duration(duration, control_dt)
    home = robot.home if home is None else np.asarray(home, np.float64)
    references.check_positions("task.home", home[None], robot)
    if targets is None:
        targets = default_cartesian_targets(robot, site, home)
    targets = check_targets(robot, targets, site)
    start = HostKinematics(robot, site)(home, np.zeros(robot.nv)).position
    parts = [references.quintic(start, goal, duration, control_dt) for goal in targets]
    return CartesianReference(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


def desired_acceleration(ref_x, ref_xd, ref_xdd, x, xd, kp: float, kd: float):
    """``xdd* = xdd_ref + kp (x_ref - x) + kd (xd_ref - xd)``; all arrays ``(..., 3)``
    (the same formula as :func:`cfm_jax.references.desired_acceleration`).

    Args:
      ref_x: reference site positions ``x_ref``, ``(..., 3)``.
      ref_xd: reference site velocities ``xd_ref``, ``(..., 3)``.
      ref_xdd: reference site accelerations ``xdd_ref``, ``(..., 3)``.
      x: current site positions, ``(..., 3)``.
      xd: current site velocities, ``(..., 3)``.
      kp: proportional gain (1/s^2).
      kd: derivative gain (1/s).

    Returns:
      ``xdd*``, ``(..., 3)`` (NumPy or JAX, as the inputs).

    Examples:
      >>> desired_acceleration(np.array([1.0, 0.0, 0.0]), np.zeros(3), np.zeros(3),
      ...                      np.array([0.9, 0.0, 0.0]), np.array([0.1, 0.0, 0.0]),
      ...                      kp=100.0, kd=20.0)
      array([8., 0., 0.])
    """
    return references.desired_acceleration(ref_x, ref_xd, ref_xdd, x, xd, kp, kd)


def as_jax(reference: CartesianReference) -> CartesianReference:
    """The same reference as float32 JAX arrays.

    Args:
      reference: a :class:`CartesianReference` of NumPy arrays.

    Returns:
      A :class:`CartesianReference` of float32 ``jax.Array``, same shapes.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> as_jax(ref).xdd.dtype
      dtype('float32')
    """
    return CartesianReference(*(jnp.asarray(x, jnp.float32) for x in reference))


# ---- oracle: operational-space control --------------------------------------------------


class HostOracle:
    """Analytic operational-space controller (Khatib 1987) with MuJoCo C, float64.

    ``HostOracle(robot, site, home, null_kp, null_kd)(qpos (..., nq), qvel (..., nv),
    xdd_desired (..., 3)) -> tau (..., nv)``:

        tau = J^T Lambda (xdd* - Jdot qd) + N^T tau_null + bias - passive
        Lambda = (J Mt^-1 J^T)^+,   Jbar = Mt^-1 J^T Lambda,   N^T = I - J^T Jbar^T
        tau_null = Mt (null_kp (q_home - q) - null_kd qd),     Mt = M + h D

    ``bias`` is MuJoCo's ``qfrc_bias`` (Coriolis, centrifugal, gravity), ``passive``
    ``qfrc_passive`` (joint damping and springs), ``M`` the joint-space inertia (with
    armature), ``h D`` :func:`cfm_jax.rollout.implicit_damping`. ``^+`` is the
    pseudo-inverse (relative cut-off :data:`RCOND`), which is the inverse when ``J`` has
    full row rank.

    Derivation: one Euler step realises ``qdd = Mt^-1 (tau + passive - bias)``
    (:func:`cfm_jax.rollout.implicit_damping`), so ``J qdd = J Mt^-1 J^T Lambda (xdd* - Jdot qd) +
    J Mt^-1 N^T tau_null``. The first term is ``xdd* - Jdot qd`` (``J Mt^-1 J^T Lambda = I``
    on the range of ``J``); the second is zero because ``J Mt^-1 N^T = J Mt^-1 -
    (J Mt^-1 J^T) Lambda J Mt^-1 = 0`` (dynamically consistent projector). Hence the site's
    acceleration ``J qdd + Jdot qd = xdd*`` exactly over one physics step from any state
    (up to torque and joint limits), whatever ``tau_null``. With the torque held over
    several physics steps, tracking is approximate. Using ``M`` instead of ``Mt`` leaves an
    error of order ``h D / M`` (~1e-3 on the iiwa).

    The null-space term pulls the redundant joints towards ``home`` (default
    ``robot.home``) with the joint-space acceleration gains ``null_kp`` (1/s^2, default
    25) and ``null_kd`` (1/s, default 10, critical damping at 5 rad/s), scaled by ``Mt``.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> tau = HostOracle(iiwa)(iiwa.home, np.zeros(7), np.zeros(3))  # holds the pose
      >>> tau.shape
      (7,)
    """

    def __init__(
        self,
        robot,
        site: int | str | None = None,
        home=None,
        null_kp: float = NULL_KP,
        null_kd: float = NULL_KD,
    ):
        self.kinematics = HostKinematics(robot, site)
        self.model = robot.mj_model
        self.data = self.kinematics.data
        self.home = np.asarray(robot.home if home is None else home, np.float64)
        self.null_kp, self.null_kd = float(null_kp), float(null_kd)
        self.implicit_damping = rollout.implicit_damping(self.model)

    def task_inertia(self, qpos) -> np.ndarray:
        """``Lambda(q) = (J Mt^-1 J^T)^+``, ``(3, 3)``, at one pose (kg)."""
        self.data.qpos[:], self.data.qvel[:] = qpos, 0.0
        mujoco.mj_fwdPosition(self.model, self.data)
        _, jac, _ = self.kinematics._jacobians()
        return self._task_inertia(jac, self._inertia())[0]

    def _inertia(self) -> np.ndarray:
        nv = self.model.nv
        full = np.zeros((nv, nv))
        mujoco.mj_fullM(self.model, self.data, full)
        return full + np.diag(self.implicit_damping)

    @staticmethod
    def _task_inertia(jac, inertia):
        inverse_jt = np.linalg.solve(inertia, jac.T)  # Mt^-1 J^T, (nv, 3)
        return np.linalg.pinv(jac @ inverse_jt, rcond=RCOND, hermitian=True), inverse_jt

    def __call__(self, qpos, qvel, xdd_desired):
        nq, nv = self.model.nq, self.model.nv
        batch_shape = np.shape(xdd_desired)[:-1]
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, nv)
        desired = np.asarray(xdd_desired, np.float64).reshape(-1, 3)
        tau = np.empty((desired.shape[0], nv))
        for i in range(desired.shape[0]):
            self.data.qpos[:], self.data.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_fwdPosition(self.model, self.data)  # kinematics, com, M
            mujoco.mj_fwdVelocity(self.model, self.data)  # cvel, Jdot terms, bias, passive
            _, jac, jac_dot = self.kinematics._jacobians()
            inertia = self._inertia()
            task_inertia, inverse_jt = self._task_inertia(jac, inertia)
            force = task_inertia @ (desired[i] - jac_dot @ qvel[i])
            null_accel = self.null_kp * (self.home - qpos[i]) - self.null_kd * qvel[i]
            tau_null = inertia @ null_accel
            # N^T tau_null = tau_null - J^T Jbar^T tau_null, Jbar^T = Lambda J Mt^-1.
            projected = tau_null - jac.T @ (task_inertia @ (inverse_jt.T @ tau_null))
            tau[i] = jac.T @ force + projected + self.data.qfrc_bias - self.data.qfrc_passive
        return tau.reshape(batch_shape + (nv,))


def oracle_policy(
    robot,
    site: int | str | None = None,
    home=None,
    null_kp: float = NULL_KP,
    null_kd: float = NULL_KD,
    simulator: str = "native",
):
    """The operational-space oracle as a JAX function
    ``torque(qpos (..., nq), qvel (..., nv), xdd_desired (..., 3)) -> tau (..., nv)``
    (float32). ``simulator="native"``: one ``jax.pure_callback`` into :class:`HostOracle`
    (one host call per batch under ``vmap``); ``"mjx"``: the same controller computed by
    MJX in JAX (:func:`mjx_oracle_policy`). Torques are not clipped.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).
      simulator: ``"native"`` or ``"mjx"``.

    Returns:
      The function ``torque``; one :class:`HostOracle` per (model, site, home, gains) is
      built and reused.

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = oracle_policy(iiwa)
      >>> jax.jit(torque)(iiwa.home, np.zeros(7), np.zeros(3)).shape
      (7,)
    """
    if simulator == "mjx":
        return mjx_oracle_policy(robot, site, home, null_kp, null_kd)
    _check_simulator(simulator)
    home = tuple(np.asarray(robot.home if home is None else home, np.float64).tolist())
    host = _cached(HostOracle, robot, _site_id(robot, site), home, float(null_kp), float(null_kd))

    def torque(qpos, qvel, xdd_desired):
        args = [jax.lax.stop_gradient(jnp.asarray(a, jnp.float32)) for a in (qpos, qvel)]
        desired = jax.lax.stop_gradient(jnp.asarray(xdd_desired, jnp.float32))
        shape = jax.ShapeDtypeStruct(desired.shape[:-1] + (robot.nv,), jnp.float32)
        return jax.pure_callback(_float32(host), shape, *args, desired, vmap_method="broadcast_all")

    return torque


def mjx_oracle_policy(
    robot,
    site: int | str | None = None,
    home=None,
    null_kp: float = NULL_KP,
    null_kd: float = NULL_KD,
):
    """:class:`HostOracle`'s controller computed by MJX, in JAX (no host callback), as
    ``torque(qpos (..., nq), qvel (..., nv), xdd_desired (..., 3)) -> tau (..., nv)``.

    The same formula: ``J``, ``Jdot qd`` from :func:`mjx_kinematics`, ``M`` from
    ``mjx.full_m``, ``qfrc_bias`` and ``qfrc_passive`` from ``mjx.fwd_position`` and
    ``mjx.fwd_velocity``, ``Lambda`` with ``jnp.linalg.pinv`` at the same relative cut-off
    :data:`RCOND`; float32 instead of float64.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot` with hinge and slide joints.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Returns:
      The function ``torque`` (float32, jit/vmap-able).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = mjx_oracle_policy(iiwa)  # compiles for ~40 s on a CPU:
      >>> tau = jax.jit(torque)(iiwa.home, np.zeros(7), np.zeros(3))  # doctest: +SKIP
      >>> tau.shape  # doctest: +SKIP
      (7,)
    """
    model, sid, bid, blank = _mjx_site(robot, site)
    del sid, bid
    home = jnp.asarray(robot.home if home is None else home, jnp.float32)
    damping = jnp.asarray(rollout.implicit_damping(robot.mj_model), jnp.float32)
    null_kp, null_kd = float(null_kp), float(null_kd)

    def one(q, qd, desired):
        kin = mjx_kinematics(robot, q, qd, site)
        data = mjx.fwd_velocity(model, mjx.fwd_position(model, blank.replace(qpos=q, qvel=qd)))
        inertia = mjx.full_m(model, data) + jnp.diag(damping)
        jac = kin.jacobian
        inverse_jt = jnp.linalg.solve(inertia, jac.T)  # Mt^-1 J^T, (nv, 3)
        task_inertia = jnp.linalg.pinv(jac @ inverse_jt, rtol=RCOND, hermitian=True)
        force = task_inertia @ (desired - kin.bias_acceleration)
        tau_null = inertia @ (null_kp * (home - q) - null_kd * qd)
        projected = tau_null - jac.T @ (task_inertia @ (inverse_jt.T @ tau_null))
        return jac.T @ force + projected + data.qfrc_bias - data.qfrc_passive

    def torque(qpos, qvel, xdd_desired):
        args = [jax.lax.stop_gradient(jnp.asarray(a, jnp.float32)) for a in (qpos, qvel)]
        desired = jax.lax.stop_gradient(jnp.asarray(xdd_desired, jnp.float32))
        return _over_batch(one, *args, desired)

    return torque


# ---- PD-only baseline -------------------------------------------------------------------


def pd_gains(
    robot, kp: float, kd: float, site: int | str | None = None, home=None
) -> tuple[np.ndarray, np.ndarray]:
    """Task-space torque PD gains equivalent to the acceleration gains ``kp, kd`` at home.

    ``K_p = kp * Lambda(q_home)``, ``K_d = kd * Lambda(q_home)``, ``(3, 3)`` each, with the
    task-space inertia ``Lambda = (J Mt^-1 J^T)^+`` of :class:`HostOracle`: a force
    ``F = K_p e + K_d ed`` on the end effector alone at the home pose gives it the
    acceleration ``kp e + kd ed`` (the PD correction of the desired acceleration). The
    analogue of :func:`cfm_jax.rollout.pd_gains` (which uses ``diag M(q_home)``).

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      kp: proportional acceleration gain (1/s^2).
      kd: derivative acceleration gain (1/s).
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` pose where ``Lambda`` is taken, or None for ``robot.home``.

    Returns:
      ``(K_p, K_d)``, ``(3, 3)`` NumPy arrays each (N/m and N s/m).

    Examples:
      >>> from cfm_jax import robots
      >>> gain_p, gain_d = pd_gains(robots.load("two_link_arm"), 100.0, 20.0, "tip")
      >>> gain_p.shape, bool(np.allclose(gain_p / 100.0, gain_d / 20.0))
      ((3, 3), True)
    """
    home = robot.home if home is None else np.asarray(home, np.float64)
    task_inertia = HostOracle(robot, site).task_inertia(home)
    return kp * task_inertia, kd * task_inertia


def pd_policy(robot, gain_p, gain_d, site: int | str | None = None, simulator: str = "native"):
    """PD-only feedback in task space as a JAX function
    ``torque(qpos, qvel, ref_x (..., 3), ref_xd (..., 3)) -> tau (..., nv)``:

        tau = J(q)^T (K_p (x_ref - x) + K_d (xd_ref - xd))

    with ``x, xd, J`` from :func:`kinematics` (of ``simulator``). No gravity compensation,
    no feed-forward, no null-space term (the joint damping of the model is the only
    null-space damping).

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      gain_p: ``K_p``, ``(3, 3)`` (for example from :func:`pd_gains`).
      gain_d: ``K_d``, ``(3, 3)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      simulator: ``"native"`` (site kinematics from MuJoCo C on the host) or ``"mjx"``.

    Returns:
      The function ``torque`` (float32, jit/vmap-able).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = pd_policy(iiwa, *pd_gains(iiwa, 100.0, 20.0))
      >>> x = ee_position(iiwa, iiwa.home)
      >>> bool(np.abs(np.asarray(torque(iiwa.home, np.zeros(7), x, np.zeros(3)))).max() < 1e-3)
      True
    """
    gain_p = jnp.asarray(gain_p, jnp.float32)
    gain_d = jnp.asarray(gain_d, jnp.float32)

    def torque(qpos, qvel, ref_x, ref_xd):
        kin = kinematics(robot, qpos, qvel, site, simulator)
        force = jnp.einsum("ij,...j->...i", gain_p, ref_x - kin.position) + jnp.einsum(
            "ij,...j->...i", gain_d, ref_xd - kin.velocity
        )
        return jnp.einsum("...ij,...i->...j", kin.jacobian, force)

    return torque


# ---- metrics and a reference closed loop ------------------------------------------------


def tracking_mse(positions, reference_x):
    """End-effector position tracking MSE per target, ``(targets,)`` (m^2).

    Args:
      positions: ``(targets, steps, 3)`` site positions after each control step,
        ``x_{t+1}``.
      reference_x: ``(targets, steps + 1, 3)`` (``CartesianReference.x``) or already
        aligned ``(targets, steps, 3)``.

    Returns:
      ``mean over t and axes of (x_{t+1} - x_ref(t+1))^2``, ``(targets,)``.

    Examples:
      >>> positions = np.zeros((2, 3, 3))  # 2 targets, 3 steps
      >>> reference_x = np.ones((2, 4, 3))  # the first reference point is dropped
      >>> tracking_mse(positions, reference_x).tolist()
      [1.0, 1.0]
    """
    positions = jnp.asarray(positions)
    reference_x = jnp.asarray(reference_x)
    if reference_x.shape[-2] == positions.shape[-2] + 1:
        reference_x = reference_x[..., 1:, :]
    return jnp.mean(jnp.square(positions - reference_x), axis=(-2, -1))


class HostRollout(NamedTuple):
    """Result of :func:`host_rollout`, leading axes ``(targets, steps)``.

    Attributes:
      qpos: joint positions after each control step, ``(targets, steps, nq)``.
      qvel: joint velocities after each control step, ``(targets, steps, nv)``.
      position: site position after each control step, ``(targets, steps, 3)``.
      desired: ``xdd*_t`` at each control step, ``(targets, steps, 3)``.
      tau: applied (clipped) torque, ``(targets, steps, nv)``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.1, control_dt=0.01)
      >>> oracle = HostOracle(arm, "tip")
      >>> out = host_rollout(arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd),
      ...                    kp=100.0, kd=20.0, control_dt=0.01, site="tip")
      >>> out.qpos.shape, out.position.shape, out.tau.shape
      ((1, 10, 2), (1, 10, 3), (1, 10, 2))
    """

    qpos: np.ndarray
    qvel: np.ndarray
    position: np.ndarray
    desired: np.ndarray
    tau: np.ndarray


def host_rollout(
    robot,
    reference: CartesianReference,
    policy,
    kp: float,
    kd: float,
    control_dt: float,
    site: int | str | None = None,
    home=None,
) -> HostRollout:
    """Closed loop of a host policy on every target, MuJoCo C on the host (NumPy).

    The reference implementation of the operational-space rollout, with the conventions of
    :func:`cfm_jax.rollout.run` and its ``native`` simulator (:class:`cfm_jax.native.Stepper`,
    state stored as float32 between control steps): start at rest at ``home``; at step ``t``
    ``xdd*_t`` from :func:`desired_acceleration`, ``tau = clip(policy(qpos, qvel, xdd*_t,
    x_ref(t), xd_ref(t)), limits)`` held for ``control_dt / timestep`` physics steps.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      reference: a :class:`CartesianReference` (NumPy), ``(targets, steps + 1, 3)``.
      policy: ``policy(qpos (B, nq), qvel (B, nv), desired (B, 3), ref_x (B, 3),
        ref_xd (B, 3)) -> tau (B, nv)``, NumPy; e.g. ``lambda q, qd, xdd, *_:
        HostOracle(robot)(q, qd, xdd)``.
      kp: proportional gain (1/s^2) of the desired acceleration.
      kd: derivative gain (1/s) of the desired acceleration.
      control_dt: control period (s), a multiple of the robot's timestep.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      home: ``(nq,)`` start pose (at rest), or None for ``robot.home``.

    Returns:
      A :class:`HostRollout`, ``(targets, steps, ...)``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> oracle = HostOracle(arm, "tip")
      >>> out = host_rollout(arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd),
      ...                    kp=100.0, kd=20.0, control_dt=0.01, site="tip")
      >>> bool(tracking_mse(out.position, ref.x)[0] < 1e-5)  # the oracle tracks the line
      True
    """
    n_sub = rollout.substeps(robot, control_dt)
    stepper = native.Stepper(robot.mj_model, n_sub)
    kin = HostKinematics(robot, site)
    home = robot.home if home is None else np.asarray(home, np.float64)
    k, steps = reference.x.shape[0], reference.steps
    qpos = np.tile(np.asarray(home, np.float32), (k, 1))
    qvel = np.zeros((k, robot.nv), np.float32)
    out = {name: [] for name in HostRollout._fields}
    ctrl = np.zeros((k, robot.mj_model.nu))
    for t in range(steps):
        state = kin(qpos, qvel)
        desired = desired_acceleration(
            reference.x[:, t],
            reference.xd[:, t],
            reference.xdd[:, t],
            state.position,
            state.velocity,
            kp,
            kd,
        )
        desired = np.asarray(desired)
        tau = policy(qpos, qvel, desired, reference.x[:, t], reference.xd[:, t])
        tau = np.clip(tau, -robot.torque_limit, robot.torque_limit)
        ctrl[:, robot.actuator_of_joint] = tau / robot.gear
        qpos, qvel, _ = stepper(qpos, qvel, ctrl)
        for name, value in zip(
            HostRollout._fields,
            (qpos, qvel, kin(qpos, qvel).position, desired, tau),
            strict=True,
        ):
            out[name].append(np.asarray(value))
    return HostRollout(*(np.stack(out[name], axis=1) for name in HostRollout._fields))
