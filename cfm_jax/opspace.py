"""Operational-space kinematics of an end-effector site: site lookup, MuJoCo C and MJX.

The operational-space task (paper section IV-A-2) controls a MuJoCo *site* (:func:`ee_site`)
of the arm. Everything here is linear, in the world frame, of the site's origin: position
``x (3,)``, velocity ``xd = J qd``, acceleration ``xdd = J qdd + Jdot qd`` with the
translational site Jacobian ``J (3, nv)``. The task's Cartesian references are in
:mod:`cfm_jax.references`, its oracle and PD baseline in :mod:`cfm_jax.baselines`.

Kinematics are computed by MuJoCo's C engine (``mj_kinematics``, ``mj_comPos``,
``mj_comVel``, ``mj_jacSite``, ``mj_jacDot``), on the host, through ``jax.pure_callback``
(``vmap_method="broadcast_all"``: one host call per batch, like the native simulator).
Measured against MJX in JAX on the iiwa (``docs/opspace.md``): compile 0.13 s instead of
33-37 s, and 180 / 390 us instead of 480 / 1230 us per control step for a batch of 5 / 15
states. The callback's inputs are wrapped in ``stop_gradient``: the kinematics are
constants of the state under ``jax.grad``; :func:`task_acceleration` is linear in ``qacc``
and differentiable in it (the path a task loss on predicted joint accelerations needs).
With ``simulator="mjx"`` the same quantities come from MJX (:func:`mjx_kinematics`), in
JAX on the device.

Host class (NumPy float64, any leading batch shape; the oracle of the tests):
:class:`HostKinematics`. JAX functions (float32, jit/vmap-able): :func:`kinematics`,
:func:`ee_position`, :func:`ee_velocity`, :func:`ee_jacobian`, :func:`ee_acceleration`.

Examples:
  >>> import numpy as np
  >>> from cfm_jax import robots
  >>> iiwa = robots.load("iiwa14")
  >>> x = ee_position(iiwa, iiwa.home)  # the flange at the home pose
  >>> np.round(np.asarray(x, np.float64), 3).tolist()
  [0.669, 0.0, 0.285]
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, check_simulator

DEFAULT_SITES = ("ee", "flange", "attachment_site")
"""Site names tried in order when no site is configured."""


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
    (``"ee"``, then ``"flange"``, then ``"attachment_site"``, MuJoCo Menagerie's name) that
    the model has.

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


def site_id(robot, site: int | str | None) -> int:
    """A site's id from its id, its name or None (:func:`ee_site`'s default), checked.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      site: a site id, a site name, or None.

    Returns:
      The site id.

    Raises:
      ConfigError: an id out of range, a name the robot lacks, a site fixed to the world.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> site_id(arm, "tip"), site_id(arm, 0)
      (0, 0)
    """
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
        self.site = site_id(robot, site)
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


def host_function(kind, robot, site: int, *args):
    """The host object ``kind(robot, site, *args)``, built once per (kind, model, site, args)
    and reused, wrapped to return float32 arrays: the callable that ``jax.pure_callback``
    calls for :func:`kinematics` and :func:`cfm_jax.baselines.opspace_oracle`.

    Args:
      kind: a class taking ``(robot, site, *args)`` whose instances are called on NumPy
        arrays (:class:`HostKinematics`, :class:`cfm_jax.baselines.HostOpspaceOracle`).
      robot: a :class:`cfm_jax.robots.Robot` (its model is kept alive with the object).
      site: the site id (:func:`site_id`).
      args: further hashable constructor arguments.

    Returns:
      A function of the same arguments as the object, returning its outputs as float32.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> host = host_function(HostKinematics, arm, site_id(arm, "tip"))
      >>> host(arm.home, np.zeros(2)).position.dtype
      dtype('float32')
    """
    key = (kind.__name__, id(robot.mj_model), site, args)
    if key not in _HOSTS:
        _HOSTS[key] = (robot.mj_model, kind(robot, site, *args))
    function = _HOSTS[key][1]

    def host(*arrays):
        return jax.tree.map(lambda a: np.asarray(a, np.float32), function(*arrays))

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
    check_simulator(simulator)
    host = host_function(HostKinematics, robot, site_id(robot, site))
    nv = robot.nv
    qpos = jax.lax.stop_gradient(jnp.asarray(qpos, jnp.float32))
    qvel = jax.lax.stop_gradient(jnp.broadcast_to(jnp.asarray(qvel, jnp.float32), qpos.shape))
    batch = qpos.shape[:-1]
    shapes = Kinematics(
        *(jax.ShapeDtypeStruct(batch + shape, jnp.float32) for shape in ((3,), (3,), (3, nv), (3,)))
    )
    return jax.pure_callback(host, shapes, qpos, qvel, vmap_method="broadcast_all")


def mjx_site(robot, site: int | str | None):
    """What the MJX site computations need: ``(mjx model, site id, body id, blank data)``.

    Args:
      robot: a :class:`cfm_jax.robots.Robot` with hinge and slide joints (``nq == nv``).
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Returns:
      ``(robot.mjx_model, site id, id of the site's body, mjx.make_data(model))``.

    Raises:
      ValueError: the robot has a ball or free joint (``nq != nv``).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> model, site, body, blank = mjx_site(arm, "tip")
      >>> site == site_id(arm, "tip"), blank.qpos.shape
      (True, (2,))
    """
    if robot.nq != robot.nv:
        raise ValueError(
            f"robot {robot.name!r} has nq={robot.nq} != nv={robot.nv} (a ball or free joint); "
            "the MJX site kinematics take hinge and slide joints only"
        )
    sid = site_id(robot, site)
    model = robot.mjx_model
    return model, sid, int(robot.mj_model.site_bodyid[sid]), mjx.make_data(model)


def over_batch(one, *arrays):
    """``one`` of unbatched arrays, mapped (``jax.vmap``) over the common leading axes of
    ``arrays`` (each broadcast to them; the last axis is each array's own).

    Args:
      one: a function of one unbatched array per argument, returning a pytree of arrays.
      arrays: ``(..., k_i)`` arrays whose leading axes broadcast together.

    Returns:
      ``one``'s pytree with the common leading axes ``...`` in front of every leaf.

    Examples:
      >>> out = over_batch(lambda a, b: a @ b, jnp.ones((4, 5, 3)), jnp.ones((5, 3)))
      >>> out.shape, float(out[0, 0])
      ((4, 5), 3.0)
    """
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
      >>> # not run: MJX run op by op, 15 s on 2 shared cores
      >>> kin = mjx_kinematics(arm, np.zeros(2), np.array([1.0, 0.0]), "tip")  # doctest: +SKIP
      >>> np.round(np.asarray(kin.velocity, np.float64), 3).tolist()  # doctest: +SKIP
      [0.0, 0.0, 0.9]
      >>> np.round(np.asarray(kin.bias_acceleration, np.float64), 3).tolist()  # doctest: +SKIP
      [-0.9, 0.0, 0.0]
    """
    model, sid, bid, blank = mjx_site(robot, site)

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
    return over_batch(one, qpos, qvel)


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
