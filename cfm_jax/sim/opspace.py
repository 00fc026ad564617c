"""Kinematics of an end-effector site (a MuJoCo site's origin, world frame) for the
operational-space task: :func:`kinematics` takes them from MuJoCo C on the host
(:class:`HostKinematics`, one host call per batch through :func:`cfm_jax.sim.host.host_call`: it
compiles in 0.13 s, MJX in over 30 s) or from MJX (:func:`mjx_kinematics`), as constants of
the state under ``jax.grad``. See docs/opspace.md.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, check_simulator
from cfm_jax.sim import native
from cfm_jax.sim.host import host_call

DEFAULT_SITES = ("ee", "flange", "attachment_site")
"""Site names tried in order when no site is configured."""


# ---- site -------------------------------------------------------------------------------


def site_names(robot) -> tuple[str, ...]:
    """Names of the model's sites in id order (unnamed sites as ``'#id'``).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> site_names(cfm_jax.sim.robots.load("iiwa14"))
      ('flange',)
    """
    model = robot.mj_model
    return tuple(
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, i) or f"#{i}" for i in range(model.nsite)
    )


def ee_site(robot, name: str | None = None) -> int:
    """Id of the end-effector site: ``name``, or the first of :data:`DEFAULT_SITES` the model has.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      name: a site name of the robot's MJCF, or None.

    Raises:
      ConfigError: no such site, no default site, or a site fixed to the world body.

    Examples:
      >>> ee_site(cfm_jax.sim.robots.load("two_link_arm"))  # its only site is called "tip"
      Traceback (most recent call last):
      cfm_jax.config.ConfigError: task.site=None is not allowed for robot 'two_link_arm': ...
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
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: a site id, a site name, or None.

    Raises:
      ConfigError: an id out of range, or as :func:`ee_site`.

    Examples:
      >>> site_id(cfm_jax.sim.robots.load("two_link_arm"), "tip")
      0
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
      bias_acceleration: ``Jdot qd``, ``(..., 3)`` (m/s^2): ``xdd`` at ``qdd = 0``.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")  # along x at q = 0, 0.9 m long
      >>> kin = HostKinematics(arm, "tip")(np.zeros(2), np.array([1.0, 0.0]))
      >>> kin.velocity.round(3).tolist(), kin.bias_acceleration.round(3).tolist()
      ([0.0, 0.0, 0.9], [-0.9, 0.0, 0.0])
    """

    position: np.ndarray
    velocity: np.ndarray
    jacobian: np.ndarray
    bias_acceleration: np.ndarray


def task_acceleration(kin: Kinematics, qacc):
    """``xdd = J qacc + Jdot qd``, ``(..., 3)``: linear and differentiable in ``qacc``.

    Args:
      kin: :class:`Kinematics` of the states (NumPy ones give NumPy, else ``jnp``).
      qacc: joint accelerations, ``(..., nv)``.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> kin = HostKinematics(arm, "tip")(np.zeros(2), np.ones(2))
      >>> task_acceleration(kin, np.zeros(2)).round(3).tolist()  # centripetal
      [-2.1, 0.0, 0.0]
    """
    arrays = (kin.jacobian, kin.bias_acceleration, qacc)
    xp = np if all(isinstance(a, np.ndarray) for a in arrays) else jnp
    return xp.einsum("...ij,...j->...i", kin.jacobian, qacc) + kin.bias_acceleration


class HostKinematics:
    """Site kinematics by MuJoCo C on the host, NumPy float64: the tests' oracle.

    ``HostKinematics(robot, site)(qpos (..., nq), qvel (..., nv))`` gives :class:`Kinematics`.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> iiwa = cfm_jax.sim.robots.load("iiwa14")
      >>> HostKinematics(iiwa)(iiwa.home, np.zeros(7)).jacobian.shape
      (3, 7)
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
    """``kind(robot, site, *args)``, built once, returning float32, for
    :func:`cfm_jax.sim.host.host_call` (its ``key``: the kind, the model's bytes, site and args).

    Args:
      kind: a class such as :class:`HostKinematics` or
        :class:`cfm_jax.tasks.baselines.HostOpspaceOracle`.
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: the site id (:func:`site_id`).
      args: further hashable constructor arguments.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> host_function(HostKinematics, arm, 0)(arm.home, np.zeros(2)).position.dtype
      dtype('float32')
    """
    key = (kind.__name__, id(robot.mj_model), site, args)
    if key not in _HOSTS:
        digest = native.model_digest(robot.mj_model)
        _HOSTS[key] = (robot.mj_model, kind(robot, site, *args),
                       f"{kind.__name__}-{digest}-{site}-{args!r}")  # fmt: skip
    _, function, name = _HOSTS[key]

    def host(*arrays):
        return jax.tree.map(lambda a: np.asarray(a, np.float32), function(*arrays))

    host.key = name
    return host


def kinematics(
    robot, qpos, qvel, site: int | str | None = None, simulator: str = "native"
) -> Kinematics:
    """:class:`Kinematics` of the site as float32 JAX arrays, any leading batch shape.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.
      simulator: ``"native"`` (MuJoCo C, one host callback per batch) or ``"mjx"``.

    Examples:
      >>> iiwa = cfm_jax.sim.robots.load("iiwa14")
      >>> jax.jit(lambda q, v: kinematics(iiwa, q, v))(iiwa.home, np.zeros(7)).jacobian.shape
      (3, 7)
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
    return host_call(host.key, host, shapes, qpos, qvel)


def mjx_site(robot, site: int | str | None):
    """``(robot.mjx_model, site id, the site's body id, blank mjx data)``.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot` with hinge and slide joints only.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Raises:
      ValueError: a ball or free joint (``nq != nv``).

    Examples:
      >>> mjx_site(cfm_jax.sim.robots.load("two_link_arm"), "tip")[1:3]
      (0, 2)
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
    """``jax.vmap`` of ``one`` over the leading axes of ``arrays``, broadcast together.

    Args:
      one: a function of one unbatched array per argument, returning a pytree.
      arrays: ``(..., k_i)`` arrays.

    Examples:
      >>> over_batch(lambda a, b: a @ b, jnp.ones((4, 5, 3)), jnp.ones((5, 3))).shape
      (4, 5)
    """
    batch = jnp.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    flat = [jnp.broadcast_to(a, batch + a.shape[-1:]).reshape(-1, a.shape[-1]) for a in arrays]
    out = jax.vmap(one)(*flat)
    return jax.tree.map(lambda x: x.reshape(batch + x.shape[1:]), out)


def mjx_kinematics(robot, qpos, qvel, site: int | str | None = None) -> Kinematics:
    """:class:`Kinematics` by MJX, in JAX; ``Jdot qd`` is ``J(q) qd``'s derivative along ``qd``.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot` with hinge and slide joints only.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Raises:
      ValueError: a ball or free joint.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")  # not run: MJX op by op takes 15 s
      >>> mjx_kinematics(arm, np.zeros(2), np.ones(2), "tip").position.shape  # doctest: +SKIP
      (3,)
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
    """Site position ``x(q)`` (m), world frame, ``(..., 3)`` float32.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> iiwa = cfm_jax.sim.robots.load("iiwa14")
      >>> np.round(np.asarray(ee_position(iiwa, iiwa.home), float), 3).tolist()  # the flange
      [0.669, 0.0, 0.285]
    """
    return kinematics(robot, qpos, jnp.zeros(jnp.shape(qpos)), site).position


def ee_velocity(robot, qpos, qvel, site: int | str | None = None):
    """Site velocity ``xd = J(q) qd`` (m/s), world frame, ``(..., 3)`` float32.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")  # along x at q = 0, 0.9 m long
      >>> np.asarray(ee_velocity(arm, np.zeros(2), np.array([1.0, 0.0]), "tip")).round(3)
      array([0. , 0. , 0.9], dtype=float32)
    """
    return kinematics(robot, qpos, qvel, site).velocity


def ee_jacobian(robot, qpos, site: int | str | None = None):
    """Translational site Jacobian ``J(q) = dx/dq``, world frame, ``(..., 3, nv)`` float32.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> jac = ee_jacobian(cfm_jax.sim.robots.load("two_link_arm"), np.zeros(2), "tip")
      >>> np.asarray(jac[2]).round(3)  # dz/dq: the lever arms
      array([0.9, 0.4], dtype=float32)
    """
    return kinematics(robot, qpos, jnp.zeros(jnp.shape(qpos)), site).jacobian


def ee_acceleration(robot, qpos, qvel, qacc, site: int | str | None = None):
    """Site acceleration ``xdd = J qacc + Jdot qd`` (m/s^2), world frame, ``(..., 3)`` float32.

    Without gravity: ``mj_objectAcceleration``'s linear part plus ``opt.gravity`` (docs/opspace.md).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      qpos: joint positions, ``(..., nq)``.
      qvel: joint velocities, ``(..., nv)``.
      qacc: joint accelerations, ``(..., nv)``.
      site: the site's id or name, or None for :func:`ee_site`'s default.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> xdd = ee_acceleration(arm, np.zeros(2), np.array([1.0, 0.0]), np.zeros(2), "tip")
      >>> np.asarray(xdd).round(3)  # centripetal, |qd|^2 * 0.9 m
      array([-0.9, 0. , 0. ], dtype=float32)
    """
    return task_acceleration(kinematics(robot, qpos, qvel, site), qacc)
