"""The physics-structured forward model (``forward.kind = "rigid_body"``).

The authors' public Solo12 code (``model_module.py`` of ``bechtle/learning_control_solo``)
does not learn the dynamics from scratch: it predicts
``qdd = M(q)^-1 (S tau - h(q, qd)) - MLP(q, qd, forces, tau)`` with the simulator's mass
matrix ``M`` and bias forces ``h`` stored with every transition, and the next foot forces
with a second MLP. This module is that model for any robot and task of the library:

* ``M(q)`` is the joint-space inertia of a *nominal* MuJoCo model (its bodies' inertias and
  the joints' ``armature``), and ``h(q, qd) = qfrc_bias - qfrc_passive`` in MuJoCo's terms:
  ``qfrc_bias`` is the Coriolis, centrifugal and gravity force (``mj_rne`` with zero
  acceleration), ``qfrc_passive`` the joints' spring and damping forces (and gravity
  compensation, fluid forces where the model has them). Contact and joint-limit forces
  are not in it: for a legged robot ``M^-1 (S tau - h)`` is the free-space part, and the
  contact effects are learned by the residual, as in the authors' code. ``S`` maps the
  action to generalised forces: the unit columns of the actuated dofs (the library's
  robots have one torque motor per joint, :func:`cfm_jax.robots.load`).
* The residual is the ``mlp`` kind's PETS ensemble (:func:`cfm_jax.networks.forward_model`,
  mean and log-variance, the same inputs ``(s, tau)``); its mean is added to the physics
  in the model's output space. Output entries that are not accelerations (the legged
  tasks' foot forces) are the ensemble's alone. With the exact model and a zero residual
  the prediction is MuJoCo's free-space acceleration ``qacc_smooth``; with the exact model
  the free-space part is therefore trivially right, and the residual has only contacts,
  joint limits and the difference between the instantaneous ``qacc`` and its average over
  a control period to learn.
* ``M`` and ``h`` depend on the state only, and every loss evaluates the model at states of
  the data set: :class:`Terms` (``M^-1 S`` and ``-M^-1 h``) are computed once per
  transition when it enters the data set (:attr:`cfm_jax.dataset.Transitions.terms`, by
  ``Model.terms``), so a fit costs about what the ``mlp`` kind's does; the gradient of the
  controller losses flows through the linear term ``M^-1 S tau``.
* The nominal model is the robot's own MJCF (default), another MJCF file
  (``forward.nominal``) of the same joints, or either with every body mass and inertia
  multiplied by ``forward.nominal_mass_scale`` (joint armature, damping and springs are not
  scaled: they belong to the joints, not the links), to study model bias. Scaling every
  link by ``c`` scales the links' part of ``M`` and the whole ``qfrc_bias`` by ``c``.
* ``M`` and ``h`` come from MJX (JAX, float32) with both simulators: no host callback, so
  ``simulator="mjx"`` stays on the device.

The model's output is the task's, declared by
:meth:`cfm_jax.tasks.JointSpaceTask.acceleration_output` as an affine image of ``qacc``
that may depend on the state, ``y[entries] = scale * (A(s) qacc + b(s))``
(:class:`cfm_jax.tasks.inverse_dynamics.AccelerationOutput`): ``qacc`` for
``inverse_dynamics`` (``A = I``), ``[qacc dt, foot forces]`` for ``walk`` and ``jump``
(``A = I`` on the first ``nv`` entries, scale ``control_dt``), ``[qacc, xdd]`` for
``opspace`` with ``A = [I; J(q)]`` and ``b = [0; Jdot(q, qd) qd]`` of the task's site, so
that the site part is ``xdd = J qdd + Jdot qd``. A task with a state-dependent map gets
its :class:`Terms` in output coordinates, ``A M^-1 S`` and ``A (-M^-1 h) + b``, computed
once per transition like ``M`` and ``h`` (``J`` and ``Jdot qd`` by MJX, of the simulated
robot's kinematics: the nominal model enters through ``M`` and ``h`` only), so a fit costs
the same and the gradient flows through ``gain @ tau`` as for the joint tasks; a task
whose map is the identity (today's joint tasks) keeps the terms ``M^-1 S`` and ``-M^-1 h``.

``opspace`` observes its site acceleration as the finite difference of the site velocity
``xd = J qd`` over the control period, ``(xd' - xd) / control_dt``, which is the *average*
of the site acceleration over the period (as its joint part is the average of ``qacc``).
The physics part is the *instantaneous* ``J qdd + Jdot qd`` at the start of the period,
with the torque held; the residual learns the difference (the change of ``J``, ``Jdot``
and ``qdd`` along the period), as it does for ``qacc``.

Examples:
  >>> import jax, jax.numpy as jnp
  >>> from cfm_jax import config, robots, tasks
  >>> arm = robots.load("two_link_arm")
  >>> task = tasks.make(arm, config.TaskConfig(duration=0.1), control_dt=0.01)
  >>> fm = make(config.ForwardModelConfig(kind="rigid_body", hidden=(8,), ensemble_size=2),
  ...           arm, task)
  >>> terms = jax.jit(fm.terms)(jnp.zeros((5, 4)))
  >>> terms.gain.shape, terms.drift.shape
  ((5, 2, 2), (5, 2))
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax import networks, robots
from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, ForwardModelConfig
from cfm_jax.tasks.inverse_dynamics import AccelerationOutput


class Terms(NamedTuple):
    """The rigid-body terms of states, stored with each transition.

    Attributes:
      gain: ``M(q)^-1 S``, ``(..., nv, action_dim)``: the acceleration per unit torque; for
        a task with a state-dependent output map ``A`` (``opspace``), ``A M^-1 S``,
        ``(..., k, action_dim)``, in output coordinates.
      drift: ``-M(q)^-1 h(q, qd) = M^-1 (qfrc_passive - qfrc_bias)``, ``(..., nv)``: the
        acceleration at zero torque; with a map ``(A, b)``, ``A (-M^-1 h) + b``, ``(..., k)``.

    The free-space acceleration (or its image ``A qacc + b``) for torques ``tau`` is
    ``gain @ tau + drift``.

    Examples:
      >>> t = Terms(jnp.eye(2), jnp.array([0.0, -9.5]))
      >>> (t.gain @ jnp.array([1.0, 2.0]) + t.drift).tolist()
      [1.0, -7.5]
    """

    gain: jax.Array
    drift: jax.Array


def nominal_model(robot, nominal: str | None = None, mass_scale: float = 1.0) -> mujoco.MjModel:
    """The nominal MuJoCo model of a robot: its own MJCF or ``nominal``, every body mass and
    inertia times ``mass_scale``.

    Args:
      robot: the :class:`cfm_jax.robots.Robot` that is simulated.
      nominal: an MJCF path or registered robot name (``forward.nominal``), or None (the
        robot's own file).
      mass_scale: factor on ``body_mass`` and ``body_inertia`` (``forward.nominal_mass_scale``).

    Returns:
      A fresh ``mujoco.MjModel`` (the robot's is not changed).

    Raises:
      ConfigError: ``forward.nominal`` does not load as a robot, or its joints (``nq``,
        ``nv``, actuated dofs) differ from the robot's.

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> heavy = nominal_model(arm, mass_scale=2.0)
      >>> float(heavy.body_mass[1] / arm.mj_model.body_mass[1])
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
                f"forward.nominal={nominal!r} is not allowed: an MJCF file or robot name "
                f"that loads as a robot ({error})"
            ) from error
        same = (
            other.nq == robot.nq
            and other.nv == robot.nv
            and np.array_equal(other.actuated_dofs, robot.actuated_dofs)
        )
        if not same:
            raise ConfigError(
                f"forward.nominal={nominal!r} is not allowed: a model with the joints of "
                f"robot {robot.name!r} (nq={robot.nq}, nv={robot.nv}, actuated dofs "
                f"{robot.actuated_dofs.tolist()}); it has nq={other.nq}, nv={other.nv}, "
                f"actuated dofs {other.actuated_dofs.tolist()}"
            )
        model = robots.fresh_model(other)
    model.body_mass[:] = model.body_mass * mass_scale
    model.body_inertia[:] = model.body_inertia * mass_scale
    return model


def physics_terms(model, actuated_dofs, qpos, qvel) -> Terms:
    """:class:`Terms` of one state by MJX (``M`` by ``crb``, ``h`` by ``rne`` and
    ``passive``; no collision, no constraint).

    Args:
      model: an MJX model (``mjx.put_model`` of :func:`nominal_model`).
      actuated_dofs: ``(action_dim,)`` dof index of each torque (``Robot.actuated_dofs``).
      qpos: ``(nq,)``.
      qvel: ``(nv,)``.

    Returns:
      :class:`Terms` of this state, ``gain (nv, action_dim)``, ``drift (nv,)``.

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> zero = jnp.zeros(2)
      >>> # not run: MJX run op by op, 12 s on 2 shared cores
      >>> t = physics_terms(arm.mjx_model, arm.actuated_dofs, zero, zero)  # doctest: +SKIP
      >>> t.gain.shape  # doctest: +SKIP
      (2, 2)
    """
    data = mjx.make_data(model).replace(qpos=qpos, qvel=qvel)
    for stage in (
        mjx.kinematics,
        mjx.com_pos,
        mjx.tendon,
        mjx.crb,
        mjx.tendon_armature,
    ):
        data = stage(model, data)
    data = mjx.fwd_velocity(model, data)  # com_vel, passive, rne, tendon_bias
    mass = mjx.full_m(model, data)
    select = jnp.zeros((model.nv, len(actuated_dofs)), mass.dtype)
    select = select.at[jnp.asarray(actuated_dofs), jnp.arange(len(actuated_dofs))].set(1.0)
    rhs = jnp.concatenate([select, (data.qfrc_passive - data.qfrc_bias)[:, None]], axis=1)
    solution = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(mass), rhs)
    return Terms(solution[:, :-1], solution[:, -1])


def terms_function(model: mujoco.MjModel, actuated_dofs, configuration, affine=None):
    """``terms(state (..., state_dim)) -> Terms (..., ·)``: :func:`physics_terms` of every
    state, with ``configuration(state) -> (qpos, qvel)`` (the task's), in the output
    coordinates of ``affine``.

    With ``affine(qpos, qvel) -> (A (k, nv), b (k,))`` (a task's
    :class:`cfm_jax.tasks.inverse_dynamics.AccelerationOutput`) the terms are
    ``Terms(A M^-1 S, A (-M^-1 h) + b)``, so that ``gain @ tau + drift = A qacc + b``;
    without (None), ``M^-1 S`` and ``-M^-1 h``.

    Args:
      model: the nominal ``mujoco.MjModel`` (put on the device here, outside any trace).
      actuated_dofs: ``(action_dim,)`` dof index of each torque.
      configuration: the task's ``configuration``.
      affine: None, or the map of one state to ``(A, b)`` (traceable, float32).

    Returns:
      The function (pure, jittable).

    Examples:
      >>> arm = robots.load("two_link_arm")
      >>> split = lambda s: (s[..., :2], s[..., 2:])  # (qpos, qvel) of [q, qd]
      >>> terms = terms_function(arm.mj_model, arm.actuated_dofs, split)
      >>> # not run: each compile of MJX's dynamics takes about 4 s on 2 shared cores
      >>> jax.jit(terms)(jnp.zeros((3, 7, 4))).gain.shape  # doctest: +SKIP
      (3, 7, 2, 2)
      >>> double = lambda q, v: (2.0 * jnp.eye(2), jnp.ones(2))  # y = 2 qacc + 1
      >>> jax.jit(terms_function(arm.mj_model, arm.actuated_dofs, split, double))(
      ...     jnp.zeros((3, 4))).drift.shape
      (3, 2)
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

    def terms(state):
        lead = state.shape[:-1]
        qpos, qvel = configuration(state.reshape((-1, state.shape[-1])))
        out = jax.vmap(one)(qpos, qvel)
        return jax.tree.map(lambda x: x.reshape(lead + x.shape[1:]).astype(jnp.float32), out)

    return terms


def structured(residual: networks.Model, terms, output_dim: int, entries, scale: float):
    """A forward :class:`cfm_jax.networks.Model` whose mean is the physics plus the
    residual's mean.

    ``apply(params, normaliser, state, tau, per_member=False, terms=Terms)`` returns
    ``(mean, log_variance)`` in normalised output units, like the ensemble's: the residual
    ensemble's outputs, with ``normaliser.output(y_phys)`` added at ``entries``, where
    ``y_phys[entries] = scale * (gain @ tau + drift)`` (the terms in the coordinates of
    ``entries``: ``qacc``, or ``A qacc + b`` of the task's map). ``init`` is the residual's.

    Args:
      residual: the ensemble (:func:`cfm_jax.networks.forward_model`).
      terms: ``terms(state) -> Terms`` (:func:`terms_function`).
      output_dim: the task's output size.
      entries: the output entries of the physics (``task.acceleration_output().entries``).
      scale: the factor on ``gain @ tau + drift`` there (1, or ``control_dt`` for the
        legged tasks).

    Returns:
      The :class:`cfm_jax.networks.Model` (with ``terms``; the ensemble's contract,
      :func:`cfm_jax.networks.pets`).

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
      forward: the :class:`cfm_jax.config.ForwardModelConfig` (the residual ensemble's
        sizes and bounds, ``nominal``, ``nominal_mass_scale``).
      robot: the :class:`cfm_jax.robots.Robot`.
      task: the task object (:func:`cfm_jax.tasks.make`).

    Returns:
      A :class:`cfm_jax.networks.Model` with ``terms``.

    Raises:
      ConfigError: the task's ``acceleration_output()`` is None (its output is not an
        affine image of ``qacc``), or the nominal model does not fit the robot.

    Examples:
      >>> from cfm_jax import config, tasks
      >>> arm = robots.load("two_link_arm")
      >>> ops = tasks.make(arm, config.TaskConfig(name="opspace", duration=0.1, site="tip"),
      ...                  control_dt=0.01)
      >>> fm = make(config.ForwardModelConfig(kind="rigid_body", hidden=(8,)), arm, ops)
      >>> terms = jax.jit(fm.terms)(jnp.zeros((5, 4)))  # y = [qacc (2), xdd (3)]
      >>> terms.gain.shape, terms.drift.shape
      ((5, 5, 2), (5, 5))
    """
    where = task.acceleration_output()
    if where is None:
        raise ConfigError(
            f"forward.kind='rigid_body' is not allowed for task {task.name!r}: its "
            "acceleration_output() is None (the output is not an affine image of the joint "
            "accelerations); use forward.kind='mlp'"
        )
    where = AccelerationOutput(*where)  # a task may return a plain (entries, scale)
    model = nominal_model(robot, forward.nominal, forward.nominal_mass_scale)
    residual = networks.ensemble(forward, task.output_dim, task.action_dim)
    terms = terms_function(model, robot.actuated_dofs, task.configuration, where.affine)
    return structured(residual, terms, task.output_dim, where.entries, float(where.scale))
