"""The physics-structured forward model (``forward.kind = "rigid_body"``, docs/concepts/method.md).

As in the authors' Solo12 code: the free-space ``qacc = M(q)^-1 (S tau - h(q, qd))`` of a
nominal MuJoCo model (by MJX) in the task's output coordinates
(:class:`cfm_jax.tasks.inverse_dynamics.AccelerationOutput`), plus the ``mlp`` ensemble as
a residual that learns contacts, joint limits and the control period's average.
:class:`Terms` are computed once per transition, so a fit costs what ``mlp``'s does.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, ForwardModelConfig, fail
from cfm_jax.learning import networks
from cfm_jax.sim import robots
from cfm_jax.tasks.inverse_dynamics import AccelerationOutput


@dataclasses.dataclass(frozen=True)
class RigidBodyOptions:
    """The ``rigid_body`` kind's own settings, ``forward.options``.

    Attributes:
      nominal: the MJCF (path or robot name) whose ``M`` and ``h`` the model takes; None
        (default): the robot's own.
      mass_scale: factor (> 0) on the nominal model's masses and inertias, to study model
        bias.

    Examples:
      >>> RigidBodyOptions(mass_scale=0.8)
      RigidBodyOptions(nominal=None, mass_scale=0.8)
    """

    nominal: str | None = None
    mass_scale: float = 1.0

    def __post_init__(self):
        if self.nominal is not None and (not isinstance(self.nominal, str) or not self.nominal):
            fail("forward.options.nominal", self.nominal, "None or an MJCF path / robot name")
        scale = self.mass_scale
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not scale > 0:
            fail("forward.options.mass_scale", scale, "a finite number > 0")
        if not np.isfinite(scale):
            fail("forward.options.mass_scale", scale, "a finite number > 0")
        object.__setattr__(self, "mass_scale", float(scale))


def describe(options: RigidBodyOptions) -> str:
    """The options that differ from the defaults, for the protocol line of every summary.

    Args:
      options: the kind's :class:`RigidBodyOptions`.

    Examples:
      >>> describe(RigidBodyOptions(mass_scale=1.2)), describe(RigidBodyOptions())
      ('`forward.options.mass_scale=1.2`', '')
    """
    parts = []
    if options.nominal is not None:
        parts.append(f"`forward.options.nominal={options.nominal!r}`")
    if options.mass_scale != 1.0:
        parts.append(f"`forward.options.mass_scale={options.mass_scale:g}`")
    return ", ".join(parts)


class Terms(NamedTuple):
    """The rigid-body terms of states, stored with each transition: the free-space output for
    torques ``tau`` is ``gain @ tau + drift``.

    Attributes:
      gain: ``M^-1 S``, ``(..., nv, action_dim)``; with a task's map ``A``, ``A M^-1 S``.
      drift: ``-M^-1 h = M^-1 (qfrc_passive - qfrc_bias)``, ``(..., nv)``; with ``(A, b)``,
        ``A (-M^-1 h) + b``.

    Examples:
      >>> t = Terms(jnp.eye(2), jnp.array([0.0, -9.5]))
      >>> (t.gain @ jnp.array([1.0, 2.0]) + t.drift).tolist()
      [1.0, -7.5]
    """

    gain: jax.Array
    drift: jax.Array


def nominal_model(robot, nominal: str | None = None, mass_scale: float = 1.0) -> mujoco.MjModel:
    """A fresh nominal ``mujoco.MjModel`` (the robot's or ``nominal``), body masses and inertias
    times ``mass_scale`` (the joints' armature, damping and springs unscaled).

    Args:
      robot: the simulated :class:`cfm_jax.sim.robots.Robot`.
      nominal: an MJCF path or robot name (``forward.options.nominal``), or None: the robot's.
      mass_scale: factor on ``body_mass`` and ``body_inertia``.

    Raises:
      ConfigError: ``nominal`` does not load as a robot, or its joints differ from the robot's.

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> float(nominal_model(arm, mass_scale=2.0).body_mass[1] / arm.mj_model.body_mass[1])
      2.0
    """
    if nominal is None:
        model = robots.fresh_model(robot)
    else:
        try:
            limits = tuple(robot.torque_limit.tolist())
            other = robots.load(nominal, actuators=robot.actuators, torque_limit=limits)
        except robots.RobotError as error:
            raise ConfigError(
                f"forward.options.nominal={nominal!r} is not allowed: an MJCF file or robot name "
                f"that loads as a robot ({error})"
            ) from error
        same = (
            other.nq == robot.nq
            and other.nv == robot.nv
            and np.array_equal(other.actuated_dofs, robot.actuated_dofs)
        )
        if not same:
            raise ConfigError(
                f"forward.options.nominal={nominal!r} is not allowed: a model with the joints of "
                f"robot {robot.name!r} (nq={robot.nq}, nv={robot.nv}, actuated dofs "
                f"{robot.actuated_dofs.tolist()}); it has nq={other.nq}, nv={other.nv}, "
                f"actuated dofs {other.actuated_dofs.tolist()}"
            )
        model = robots.fresh_model(other)
    model.body_mass[:] = model.body_mass * mass_scale
    model.body_inertia[:] = model.body_inertia * mass_scale
    return model


def physics_terms(model, actuated_dofs, qpos, qvel) -> Terms:
    """:class:`Terms` of one state by MJX (``M`` by ``crb``, ``h`` by ``rne`` and ``passive``).

    Args:
      model: an MJX model (of :func:`nominal_model`).
      actuated_dofs: ``(action_dim,)`` dof index of each torque.
      qpos: ``(nq,)``.
      qvel: ``(nv,)``.

    Examples:
      >>> arm, zero = robots.load("two_link_arm"), jnp.zeros(2)  # not run: MJX op by op, 12 s
      >>> physics_terms(arm.mjx_model, arm.actuated_dofs, zero, zero).gain.shape  # doctest: +SKIP
      (2, 2)
    """
    data = _inertia(model, mjx.make_data(model).replace(qpos=qpos, qvel=qvel))
    data = mjx.fwd_velocity(model, data)  # com_vel, passive, rne, tendon_bias
    mass = mjx.full_m(model, data)
    select = jnp.zeros((model.nv, len(actuated_dofs)), mass.dtype)
    select = select.at[jnp.asarray(actuated_dofs), jnp.arange(len(actuated_dofs))].set(1.0)
    rhs = jnp.concatenate([select, (data.qfrc_passive - data.qfrc_bias)[:, None]], axis=1)
    solution = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(mass), rhs)
    return Terms(solution[:, :-1], solution[:, -1])


def _inertia(model, data):
    """``data`` with the joint-space inertia of its ``qpos`` (``qM``, armature included)."""
    for stage in (
        mjx.kinematics,
        mjx.com_pos,
        mjx.tendon,
        mjx.crb,
        mjx.tendon_armature,
    ):
        data = stage(model, data)
    return data


def mass_function(model: mujoco.MjModel, actuated_dofs, configuration):
    """``mass(states) -> (..., k, k)``: the block of the actuated dofs of ``M(qpos)`` (by
    MJX, armature included), ``qpos`` of ``configuration(states)``; float32.

    Args:
      model: a ``mujoco.MjModel`` (put on the device here).
      actuated_dofs: ``(k,)`` dof index of each torque.
      configuration: the task's ``configuration(state) -> (qpos, qvel)``.

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> mass = mass_function(arm.mj_model, arm.actuated_dofs, lambda s: (s[..., :2], s[..., 2:]))
      >>> m = jax.jit(mass)(jnp.zeros((3, 4)))  # 2 s: MJX's inertia compiles
      >>> m.shape, bool(np.allclose(m[0], arm.mass_matrix(np.zeros(2)), rtol=1e-5))
      ((3, 2, 2), True)
    """
    device_model = mjx.put_model(model)
    dofs = jnp.asarray(np.asarray(actuated_dofs))

    def one(qpos, qvel):
        data = _inertia(device_model, mjx.make_data(device_model).replace(qpos=qpos))
        return mjx.full_m(device_model, data)[dofs[:, None], dofs[None, :]]

    return _per_state(jax.jit(one), configuration)


def _per_state(one, configuration):
    """``states -> one(*configuration(state))`` over any leading axes, float32."""

    def over(states):
        lead = states.shape[:-1]
        qpos, qvel = configuration(states.reshape((-1, states.shape[-1])))
        out = jax.vmap(one)(qpos, qvel)
        return jax.tree.map(lambda x: x.reshape(lead + x.shape[1:]).astype(jnp.float32), out)

    return over


def terms_function(model: mujoco.MjModel, actuated_dofs, configuration, affine=None):
    """``terms(state) -> Terms``: :func:`physics_terms` of each ``configuration(state)``, in
    the output coordinates of ``affine``: ``Terms(A M^-1 S, A (-M^-1 h) + b)``.

    Args:
      model: the nominal ``mujoco.MjModel`` (put on the device here).
      actuated_dofs: ``(action_dim,)`` dof index of each torque.
      configuration: the task's ``configuration(state) -> (qpos, qvel)``.
      affine: None (``A = I``, ``b = 0``), or ``affine(qpos, qvel) -> (A (k, nv), b (k,))``.

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> split = lambda s: (s[..., :2], s[..., 2:])  # (qpos, qvel) of [q, qd]
      >>> double = lambda q, v: (2.0 * jnp.eye(2), jnp.ones(2))  # y = 2 qacc + 1
      >>> terms = terms_function(arm.mj_model, arm.actuated_dofs, split, double)
      >>> jax.jit(terms)(jnp.zeros((3, 4))).gain.shape  # 4 s: MJX's dynamics compile
      (3, 2, 2)
    """
    device_model = mjx.put_model(model)
    dofs = np.asarray(actuated_dofs)
    exact = jax.lax.Precision.HIGHEST  # no reduced-precision matmul on accelerators

    def one(qpos, qvel):
        terms = physics_terms(device_model, dofs, qpos, qvel)
        if affine is None:
            return terms
        a, b = affine(qpos, qvel)
        gain = jnp.matmul(a, terms.gain, precision=exact)
        return Terms(gain, jnp.matmul(a, terms.drift, precision=exact) + b)

    return _per_state(one, configuration)


def structured(residual: networks.Model, terms, output_dim: int, entries, scale: float):
    """A forward :class:`cfm_jax.learning.networks.Model`: the residual's ``(mean, log_variance)``
    with ``normaliser.output(y)`` added to the mean at ``entries``, ``y = scale * (gain @ tau +
    drift)`` of the ``terms=`` its ``apply`` takes.

    Args:
      residual: the ensemble (:func:`cfm_jax.learning.networks.forward_model`).
      terms: ``terms(state) -> Terms`` (:func:`terms_function`).
      output_dim: the task's output size.
      entries: the output entries of the physics.
      scale: the factor on the physics (1, or ``control_dt`` for the legged tasks).

    Examples:
      >>> residual = networks.forward_model(hidden=(4,), ensemble_size=2, nv=3, action_dim=1)
      >>> fm = structured(residual, None, output_dim=3, entries=(0,), scale=0.5)
      >>> norm = networks.Normaliser.identity(state_dim=2, output_dim=3, torque_limit=[1.0])
      >>> zero = jax.tree.map(jnp.zeros_like, fm.init(jax.random.key(0), state_dim=2))
      >>> t = Terms(gain=jnp.array([[[2.0]]]), drift=jnp.array([[1.0]]))  # qacc = 2 tau + 1
      >>> mean, _ = fm.apply(zero, norm, jnp.zeros((1, 2)), jnp.array([[3.0]]), terms=t)
      >>> mean[:, 0].tolist()  # per member: 0.5 * 7 in entry 0, the residual's 0 elsewhere
      [[3.5, 0.0, 0.0], [3.5, 0.0, 0.0]]
    """
    index = np.asarray(entries, np.int32)
    mask = np.zeros(output_dim, bool)
    mask[index] = True

    def apply(params, normaliser, state, tau, per_member: bool = False, terms=None):
        if terms is None:
            raise ValueError(
                "the rigid_body forward model needs terms=Terms of the states "
                "(forward.terms(state), stored with each transition)"
            )
        mean, log_variance = residual.apply(params, normaliser, state, tau, per_member)
        qacc = jnp.einsum("...ij,...j->...i", terms.gain, tau) + terms.drift
        physics = jnp.zeros(qacc.shape[:-1] + (output_dim,), qacc.dtype)
        physics = physics.at[..., index].set(scale * qacc)
        return mean + jnp.where(mask, normaliser.output(physics), 0.0), log_variance

    return networks.pets(residual.init, apply, terms)


def make(forward: ForwardModelConfig, robot, task) -> networks.Model:
    """The ``rigid_body`` forward model of a config for a robot and task.

    Args:
      forward: the :class:`cfm_jax.config.ForwardModelConfig`.
      robot: the :class:`cfm_jax.sim.robots.Robot`.
      task: the task object (:func:`cfm_jax.tasks.make`).

    Raises:
      ConfigError: the task's output is not an affine image of ``qacc``
        (``acceleration_output()`` is None), or the nominal model does not fit the robot.

    Examples:
      >>> from cfm_jax import config, tasks
      >>> arm = robots.load("two_link_arm")
      >>> ops = tasks.make(arm, config.TaskConfig(name="opspace", duration=0.1, site="tip"), 0.01)
      >>> fm = make(config.ForwardModelConfig(kind="rigid_body", hidden=(8,)), arm, ops)
      >>> jax.jit(fm.terms)(jnp.zeros((5, 4))).gain.shape  # y = [qacc (2), xdd (3)]
      (5, 5, 2)
    """
    where = task.acceleration_output()
    if where is None:
        raise ConfigError(
            f"forward.kind='rigid_body' is not allowed for task {task.name!r}: its "
            "acceleration_output() is None (the output is not an affine image of the joint "
            "accelerations); use forward.kind='mlp'"
        )
    where = AccelerationOutput(*where)  # a task may return a plain (entries, scale)
    options = forward.options
    model = nominal_model(robot, options.nominal, options.mass_scale)
    residual = networks.ensemble(forward, task.output_dim, task.action_dim)
    terms = terms_function(model, robot.actuated_dofs, task.configuration, where.affine)
    return structured(residual, terms, task.output_dim, where.entries, float(where.scale))
