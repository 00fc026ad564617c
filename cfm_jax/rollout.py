"""Closed-loop rollouts: ``scan`` over control steps, ``vmap`` over targets (and seeds).

No gradient flows through the simulator (the method does not need one): rollouts produce
transitions for the data set and tracking errors for the metrics. Two simulators step the
physics inside the same compiled rollout (see :data:`cfm_jax.config.SIMULATORS`):

* ``"native"`` (default): MuJoCo's C engine (``mujoco.rollout``), called once per control
  step for the whole batch through ``jax.pure_callback``. Exact MuJoCo physics in float64
  (the state is stored as float32 between control steps), joint limits and contacts at C
  speed, compiles in about a second. Runs on any JAX backend (on a GPU the state crosses to
  the host every control step).
* ``"mjx"``: ``mujoco.mjx.step`` in JAX (float32), everything on the device. On CPU it is
  slower, in particular with joint-limit constraints, and compiles for 15-30 s.

What is tracked, the learning state, the desired quantity and the observed quantity are
the *task*'s (:mod:`cfm_jax.tasks`); this module only steps the physics in a loop.
A *policy* is a pure function ``policy(step, key) -> tau`` of a :class:`Step` (the
simulator state, the task's state, desired quantity and reference at the current control
step) and a PRNG key. This module provides the learned controller's policy and
:func:`mixed_policy`, which combines a controller, the task's oracle, its PD feedback and
noise in one compiled rollout; the oracles and PD gains themselves are in
:mod:`cfm_jax.baselines`.

Examples:
  >>> import jax, numpy as np
  >>> from cfm_jax import references, robots, tasks
  >>> robot = robots.load("two_link_arm")
  >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.1, control_dt=0.01)
  >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
  >>> out = run(task, task.oracle_policy("native"), key=jax.random.key(0))
  >>> out.transitions.state.shape
  (1, 10, 4)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cfm_jax import dataset, native
from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, check_simulator


class Step(NamedTuple):
    """What a policy sees at control step ``t`` (arrays of one rollout).

    Attributes:
      t: the control step index (int32 scalar).
      qpos: the simulator's generalised positions ``(nq,)``.
      qvel: the simulator's generalised velocities ``(nv,)``.
      features: the task's extra measurements of this state (for example contact forces),
        ``(task.feature_dim,)``; empty for the joint-space task.
      state: the learning state ``s_t`` of the task, ``(task.state_dim,)``.
      desired: the task's desired quantity ``s*`` for this step, ``(task.desired_dim,)``.
      reference: the task's reference at ``t`` (a pytree, for example a
        :class:`cfm_jax.references.Reference` of one time step).

    Examples:
      >>> def gravity_free_pd(step, key):  # a policy: Step and PRNG key -> torques
      ...     return 10.0 * (step.reference.q - step.qpos) - 1.0 * step.qvel
    """

    t: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    features: jax.Array
    state: jax.Array
    desired: jax.Array
    reference: Any


class Rollout(NamedTuple):
    """Result of rollouts, leading axes ``(targets, steps)``.

    Attributes:
      transitions: :class:`cfm_jax.dataset.Transitions` with ``(targets, steps, ...)``.
      tracking_error: the task's tracking error after each step (for the joint-space task
        ``q_{t+1} - q_ref(t+1)``), ``(targets, steps, k)``.
      finite: whether the simulator state after the step is finite, ``(targets, steps)``.
      extras: the task's further per-step records (a dict of ``(targets, steps, ...)``
        arrays; see the task's ``record``).

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> out = run(task, task.oracle_policy("native"), key=jax.random.key(0))
      >>> out.tracking_error.shape, out.finite.shape, out.transitions.action.shape
      ((1, 20, 2), (1, 20), (1, 20, 2))
    """

    transitions: dataset.Transitions
    tracking_error: jax.Array
    finite: jax.Array
    extras: Any = None


def substeps(robot, control_dt: float) -> int:
    """Physics steps per control step; ``control_dt`` must be a multiple of the timestep.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      control_dt: the control period in seconds.

    Returns:
      ``control_dt / robot.timestep`` as an int.

    Raises:
      ConfigError: ``control_dt`` is not a positive multiple of the timestep.

    Examples:
      >>> from cfm_jax import robots
      >>> substeps(robots.load("two_link_arm"), 0.01)
      5
    """
    ratio = control_dt / robot.timestep
    count = int(round(ratio))
    if count < 1 or abs(ratio - count) > 1e-6 * max(ratio, 1.0):
        raise ConfigError(
            f"task.control_dt={control_dt!r} is not allowed: a positive multiple of robot "
            f"{robot.name!r}'s timestep {robot.timestep}"
        )
    return count


def run(task, policy, key, simulator="native") -> Rollout:
    """Roll a policy out on every target of a task (pure; jit and vmap it).

    Args:
      task: a task (:class:`cfm_jax.tasks.JointSpaceTask` or another task of
        :func:`cfm_jax.tasks.make`): its robot, references, state map and desired quantity.
      policy: ``policy(step, key) -> tau (action_dim,)`` of a :class:`Step`; torques are
        clipped to the robot's limits.
      key: PRNG key, split per target and step.
      simulator: one of :data:`cfm_jax.config.SIMULATORS`.

    Returns:
      A :class:`Rollout`; rollout ``k`` starts where the task says (``task.start``), for the
      joint-space task at rest at the reference's first position.

    Divergence: a rollout *diverges* at the first control step at one of whose physics
    steps its ``qpos``, ``qvel`` or ``qacc`` is bad (NaN, infinite, or beyond MuJoCo's
    ``mjMAXVAL`` = 1e10 in magnitude: MuJoCo's own test behind its "Nan, Inf or huge
    value" warnings), on both simulators. From that step on ``finite`` is False, the rollout
    is frozen at its last good state and not stepped again (its later transitions, tracking
    errors and observations are NaN or stale and never data, see
    :func:`cfm_jax.algorithm.data_mask`). Each rollout is simulated alone, so one that
    diverges changes no other rollout's numbers.

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> out = run(task, task.oracle_policy("native"), key=jax.random.key(0))
      >>> out.transitions.state.shape  # (targets, steps, state_dim)
      (1, 20, 4)
      >>> bool(tracking_mse(out)[0] < 1e-5)  # the oracle tracks the reference
      True
    """
    check_simulator(simulator)
    robot = task.robot
    n_sub = substeps(robot, task.control_dt)
    limit = jnp.asarray(robot.torque_limit, jnp.float32)
    physics = native_physics(robot, n_sub) if simulator == "native" else mjx_physics(robot, n_sub)

    def one_target(reference, target_key):
        qpos0, qvel0, features0 = task.start(reference)

        def control_step(carry, t):
            qpos, qvel, features, key, alive = carry
            key, key_policy = jax.random.split(key)
            ref_t = jax.tree.map(lambda x: x[t], reference)
            ref_next = jax.tree.map(lambda x: x[t + 1], reference)
            step = Step(
                t,
                qpos,
                qvel,
                features,
                task.state(qpos, qvel, features),
                task.desired(ref_t, qpos, qvel, features),
                ref_t,
            )
            tau = jnp.clip(policy(step, key_policy), -limit, limit)
            # A frozen (diverged) rollout is not stepped: a NaN control makes both
            # simulators return NaN without computing anything from it.
            ctrl = jnp.where(alive, robot.torque_to_ctrl(tau), jnp.nan)
            qpos_next, qvel_next, sensors = physics(qpos, qvel, ctrl)
            finite = alive & good(qpos_next) & good(qvel_next)
            features_next = task.features(qpos_next, qvel_next, sensors)
            out = (
                dataset.Transitions(
                    step.state,
                    step.desired,
                    tau,
                    task.observed(step, qpos_next, qvel_next, features_next),
                ),
                task.tracking_error(ref_next, qpos_next, qvel_next, features_next),
                finite,
                task.record(step, tau, qpos_next, qvel_next, features_next),
            )

            # Freeze a diverged rollout at its last good state: nothing non-finite
            # reaches the policy or the simulator again (its later steps are not data).
            def keep(new, old):
                return jnp.where(finite, new, old)

            carry = (
                keep(qpos_next, qpos),
                keep(qvel_next, qvel),
                jax.tree.map(keep, features_next, features),
                key,
                finite,
            )
            return carry, out

        _, (transitions, error, finite, extras) = jax.lax.scan(
            control_step,
            (qpos0, qvel0, features0, target_key, jnp.bool_(True)),
            jnp.arange(task.steps),
        )
        # Once the state is non-finite, everything after it is too.
        finite = jnp.cumprod(finite.astype(jnp.int32)).astype(bool)
        return Rollout(transitions, error, finite, extras)

    keys = jax.random.split(key, task.targets)
    return jax.vmap(one_target)(task.reference, keys)


MAXVAL = native.MAXVAL
"""MuJoCo's ``mjMAXVAL`` (1e10): the bound of a good simulator state (see :func:`run`)."""


def good(x):
    """All entries of ``x`` finite and at most :data:`MAXVAL` in magnitude (MuJoCo's
    ``mju_isBad`` negated; NaN compares false): the test of a diverged simulation, for a
    JAX array (traced or not) or a NumPy array alike.

    Args:
      x: an array of simulator values (positions, velocities, accelerations).

    Returns:
      A boolean scalar (of ``x``'s array kind).

    Examples:
      >>> bool(good(jnp.array([0.0, -1e9]))), bool(good(jnp.array([1.0, jnp.nan])))
      (True, False)
    """
    return (abs(x) <= MAXVAL).all()


def mjx_physics(robot, n_sub: int):
    """The MJX physics step of a rollout: ``n_sub`` ``mjx.step`` calls.

    Time and warm start start at zero at every call; as :func:`native_physics`.

    Args:
      robot: a :class:`cfm_jax.robots.Robot` (its ``mjx_model``).
      n_sub: physics steps per call (:func:`substeps`).

    Returns:
      ``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata (n_sub, nsensordata))``, pure
      and traceable.

    Examples:
      >>> import numpy as np
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> physics = mjx_physics(arm, n_sub=5)
      >>> qpos, qvel, _ = jax.jit(physics)(arm.home, np.zeros(2), np.zeros(2))
      >>> qpos.shape, bool(qvel[0] < 0)  # the arm starts to fall
      ((2,), True)
    """
    model = robot.mjx_model
    blank = mjx.make_data(model)

    def physics(qpos, qvel, ctrl):
        data = blank.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)

        def substep(data, _):
            data = mjx.step(model, data)
            fine = good(data.qpos) & good(data.qvel) & good(data.qacc)
            return data, (data.sensordata, fine)

        data, (sensors, fine) = jax.lax.scan(substep, data, None, length=n_sub)
        # As the native stepper: a state that was bad after any physics step is NaN.
        fine = jnp.all(fine)
        qpos, qvel = (jnp.where(fine, x, jnp.nan) for x in (data.qpos, data.qvel))
        return qpos, qvel, jnp.where(fine, sensors, jnp.nan)

    return physics


_STEPPERS: dict = {}


def native_physics(robot, n_sub: int):
    """``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata (n_sub, nsensordata))`` after
    ``n_sub`` steps of MuJoCo C (:class:`cfm_jax.native.Stepper`).

    A host callback (:func:`cfm_jax.native.host_step`, like ``jax.pure_callback`` with
    ``vmap_method="broadcast_all"`` but ~10x cheaper per call): under ``vmap`` the whole
    batch (targets x seeds) is stepped in one host call per control step. Time, warm start
    and actuator state start at the model defaults on every call.

    Args:
      robot: a :class:`cfm_jax.robots.Robot` (its ``mj_model``).
      n_sub: physics steps per call (:func:`substeps`).

    Returns:
      ``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata (n_sub, nsensordata))``, usable
      inside ``jit``, ``vmap`` and ``scan`` (no gradient).

    Examples:
      >>> import numpy as np
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> qpos, qvel, _ = jax.jit(native_physics(arm, 5))(arm.home, np.zeros(2), np.zeros(2))
      >>> bool(qvel[0] < 0)  # the arm starts to fall
      True
    """
    cache_key = (id(robot.mj_model), n_sub)
    if cache_key not in _STEPPERS:
        _STEPPERS[cache_key] = (robot.mj_model, native.Stepper(robot.mj_model, n_sub))
    stepper = _STEPPERS[cache_key][1]

    def physics(qpos, qvel, ctrl):
        return native.host_step(stepper, qpos, qvel, ctrl)

    return physics


def controller_policy(controller, params, normaliser):
    """The learned controller ``tau = g(s_t, s*_t)`` as a policy.

    Args:
      controller: the controller :class:`cfm_jax.networks.Model`.
      params: its parameters (one seed's).
      normaliser: the :class:`cfm_jax.networks.Normaliser` it was trained with.

    Returns:
      ``policy(step, key) -> tau (action_dim,)``.

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> from cfm_jax import networks
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> norm = networks.Normaliser.identity(4, 2, robot.torque_limit)
      >>> policy = controller_policy(g, g.init(jax.random.key(0), 4), norm)
      >>> run(task, policy, jax.random.key(1)).transitions.action.shape
      (1, 20, 2)
    """

    def policy(step, key):
        del key
        return controller.apply(params, normaliser, step.state, step.desired)

    return policy


class MixedPolicy(NamedTuple):
    """Parameters of :func:`mixed_policy`: one compiled rollout serves every policy.

    ``tau = controller_weight * g(s, s*) + oracle_weight * tau_oracle
    + feedback_weight * tau_feedback + noise_std * N(0, 1)``, where ``tau_oracle`` and
    ``tau_feedback`` are the task's oracle (for example MuJoCo's inverse dynamics) and its
    PD-only feedback on the reference (for example ``K_p (q_ref - q) + K_d (qd_ref - qd)``).

    Attributes:
      controller_params: the learned controller's parameters.
      normaliser: its :class:`cfm_jax.networks.Normaliser`.
      controller_weight: scalar (0 or 1).
      oracle_weight: scalar (0 or 1).
      feedback_weight: scalar (0 or 1).
      noise_std: ``(action_dim,)`` standard deviation of the added torque noise, or an
        ``(action_dim, action_dim)`` matrix ``N`` (the noise ``N n``, ``n ~ N(0, I)``).

    Examples:
      >>> import jax.numpy as jnp
      >>> from cfm_jax import networks
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> norm = networks.Normaliser.identity(4, 2, jnp.ones(2))
      >>> babbling = MixedPolicy.of(g.init(jax.random.key(0), 4), norm, 2, feedback=1.0,
      ...                           noise_std=0.1 * jnp.ones(2))
      >>> float(babbling.feedback_weight), float(babbling.controller_weight)
      (1.0, 0.0)
    """

    controller_params: Any
    normaliser: Any
    controller_weight: jax.Array
    oracle_weight: jax.Array
    feedback_weight: jax.Array
    noise_std: jax.Array

    @classmethod
    def of(
        cls,
        controller_params,
        normaliser,
        action_dim,
        controller=0.0,
        oracle=0.0,
        feedback=0.0,
        noise_std=None,
    ) -> MixedPolicy:
        noise = jnp.zeros(action_dim, jnp.float32) if noise_std is None else noise_std
        return cls(
            controller_params,
            normaliser,
            jnp.float32(controller),
            jnp.float32(oracle),
            jnp.float32(feedback),
            jnp.asarray(noise, jnp.float32),
        )


def mixed_policy(task, controller, parameters: MixedPolicy, simulator="native"):
    """The policy of :class:`MixedPolicy` parameters for a task.

    The oracle term is computed only when ``oracle_weight`` is non-zero (``lax.cond``), so
    babbling, the baselines and the learned controller share one compiled rollout.

    Args:
      task: the task (its ``feedback`` and ``oracle_policy``).
      controller: the controller :class:`cfm_jax.networks.Model`.
      parameters: the :class:`MixedPolicy` weights and parameters (may be traced).
      simulator: ``"native"`` or ``"mjx"`` (for the oracle).

    Returns:
      ``policy(step, key) -> tau (action_dim,)``.

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> from cfm_jax import networks
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> norm = networks.Normaliser.identity(4, 2, robot.torque_limit)
      >>> oracle = MixedPolicy.of(g.init(jax.random.key(0), 4), norm, 2, oracle=1.0)
      >>> out = run(task, mixed_policy(task, g, oracle), jax.random.key(1))
      >>> bool(tracking_mse(out)[0] < 1e-5)
      True
    """
    learned = controller_policy(controller, parameters.controller_params, parameters.normaliser)
    oracle = task.oracle_policy(simulator)

    def policy(step, key):
        tau = parameters.controller_weight * learned(step, key)
        tau = tau + parameters.feedback_weight * task.feedback(step)
        noise = jax.random.normal(key, tau.shape)
        if parameters.noise_std.ndim == 2:  # a coupled torque scale: the noise is T n
            tau = tau + parameters.noise_std @ noise
        else:
            tau = tau + parameters.noise_std * noise
        tau_oracle = jax.lax.cond(
            parameters.oracle_weight != 0,
            lambda: oracle(step, key),
            lambda: jnp.zeros_like(tau),
        )
        return tau + parameters.oracle_weight * tau_oracle

    return policy


def tracking_mse(result: Rollout) -> jax.Array:
    """Tracking MSE per target: mean over steps and components of the task's tracking error.

    Args:
      result: a :class:`Rollout`.

    Returns:
      ``(targets,)``.

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> tracking_mse(run(task, task.oracle_policy("native"), jax.random.key(0))).shape
      (1,)
    """
    return jnp.mean(jnp.square(result.tracking_error), axis=(-2, -1))
