"""Closed-loop rollouts (:func:`run`): ``scan`` over control steps, ``vmap`` over targets, on
MuJoCo C (:mod:`cfm_jax.sim.native`) or MJX; what is tracked is the task's (:mod:`cfm_jax.tasks`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cfm_jax._mjx import mjx
from cfm_jax.config import ConfigError, check_simulator
from cfm_jax.sim import dataset, native


class Step(NamedTuple):
    """What a policy ``policy(step, key) -> tau`` sees at control step ``t`` (one rollout).

    Attributes:
      t: the control step index (int32 scalar).
      qpos: generalised positions ``(nq,)``.
      qvel: generalised velocities ``(nv,)``.
      features: the task's extra measurements (e.g. contact forces), ``(task.feature_dim,)``.
      state: the task's learning state ``s_t``, ``(task.state_dim,)``.
      desired: the task's desired quantity ``s*``, ``(task.desired_dim,)``.
      reference: the task's reference at ``t`` (a pytree).

    Examples:
      >>> pd = lambda step, key: 10.0 * (step.reference.q - step.qpos) - 1.0 * step.qvel
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
      transitions: :class:`cfm_jax.sim.dataset.Transitions`, ``(targets, steps, ...)``.
      tracking_error: the task's tracking error after each step, ``(targets, steps, k)``.
      finite: whether the state after the step is good (:func:`good`), ``(targets, steps)``.
      extras: the task's further per-step records (a dict, see the task's ``record``).

    Examples:
      >>> Rollout(None, jnp.zeros((1, 20, 2)), jnp.ones((1, 20), bool)).extras is None
      True
    """

    transitions: dataset.Transitions
    tracking_error: jax.Array
    finite: jax.Array
    extras: Any = None


def substeps(robot, control_dt: float) -> int:
    """Physics steps per control step: ``control_dt / robot.timestep`` as an int.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      control_dt: the control period (s).

    Raises:
      ConfigError: ``control_dt`` is not a positive multiple of the timestep.

    Examples:
      >>> from cfm_jax.sim import robots
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


def run(task, policy, key, simulator="native", restart: bool = False) -> Rollout:
    """Roll a policy out on every target of a task into a :class:`Rollout` (pure; jit it).

    A rollout that *diverged* (``qpos``, ``qvel`` or ``qacc`` not :func:`good`) is frozen at
    its last good state, ``finite`` False (no data, :func:`cfm_jax.learning.algorithm.data_mask`).

    Args:
      task: a task of :func:`cfm_jax.tasks.make` (``task.start`` starts each rollout).
      policy: ``policy(step, key) -> tau`` of a :class:`Step`, clipped to the torque limits.
      key: PRNG key, split per target and step.
      simulator: one of :data:`cfm_jax.config.SIMULATORS`.
      restart: after a terminal step (a legged robot's fall: the task's ``record`` marks it
        ``terminal``), start again from the reference's state of the next step
        (``task.start`` of the reference from there), so that the rollout covers the whole
        motion; ``extras["restarted"]`` marks the steps after which it did. Up to the first
        terminal step the rollout is the one without restarts.

    Examples:
      >>> from cfm_jax.tasks import references
      >>> from cfm_jax.sim import robots
      >>> from cfm_jax import tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> out = run(task, task.oracle_policy("native"), key=jax.random.key(0))
      >>> out.transitions.state.shape, bool(tracking_mse(out)[0] < 1e-5)
      ((1, 20, 4), True)
    """
    check_simulator(simulator)
    robot = task.robot
    n_sub = substeps(robot, task.control_dt)
    limit = jnp.asarray(robot.torque_limit, jnp.float32)
    physics = native_physics(robot, n_sub) if simulator == "native" else mjx_physics(robot, n_sub)

    def one_target(reference, target_key, start, alive):
        qpos0, qvel0, features0 = start

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
            extras = out[3] if isinstance(out[3], dict) else {}
            if restart and "terminal" in extras:  # tasks without terminal steps: no restarts
                again = finite & extras["terminal"]
                after = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, t + 1, 1), reference)
                fresh = task.start(after)  # the reference's state at step t + 1

                def restarted(new, old):
                    return jnp.where(again, new, old)

                carry = (*jax.tree.map(restarted, fresh, carry[:3]), key, finite)
                out = (*out[:3], {**extras, "restarted": again})
            return carry, out

        _, (transitions, error, finite, extras) = jax.lax.scan(
            control_step,
            (qpos0, qvel0, features0, target_key, alive),
            jnp.arange(task.steps),
        )
        # Once the state is non-finite, everything after it is too.
        finite = jnp.cumprod(finite.astype(jnp.int32)).astype(bool)
        return Rollout(transitions, error, finite, extras)

    keys = jax.random.split(key, task.targets)
    # The start states as inputs with a target axis, not constants: every carry of the scan
    # is batched from its first step, so vmap batches the scan's body once, not twice until
    # the carries' batching settles (tracing MJX's step is most of an MJX program's build).
    starts = jax.vmap(task.start)(task.reference)
    alive = jnp.ones(task.targets, bool)
    return jax.vmap(one_target)(task.reference, keys, starts, alive)


MAXVAL = native.MAXVAL
"""MuJoCo's ``mjMAXVAL`` (1e10): the bound of a good simulator state."""


def good(x):
    """Whether ``x`` is all finite and within :data:`MAXVAL` (``mju_isBad`` negated).

    Args:
      x: simulator values (JAX or NumPy).

    Examples:
      >>> bool(good(jnp.array([0.0, -1e9]))), bool(good(jnp.array([1.0, jnp.nan])))
      (True, False)
    """
    return (abs(x) <= MAXVAL).all()


def mjx_physics(robot, n_sub: int):
    """``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata)`` of ``n_sub`` MJX steps (bad: NaN).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      n_sub: physics steps per call (:func:`substeps`).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> physics = jax.jit(mjx_physics(robots.load("two_link_arm"), 5))
      >>> bool(physics(jnp.zeros(2), jnp.zeros(2), jnp.zeros(2))[1][0] < 0)  # it falls
      True
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
    """As :func:`mjx_physics`, by MuJoCo C (:func:`cfm_jax.sim.native.host_step`); no gradient.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      n_sub: physics steps per call (:func:`substeps`).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> physics = jax.jit(native_physics(robots.load("two_link_arm"), 5))
      >>> bool(physics(jnp.zeros(2), jnp.zeros(2), jnp.zeros(2))[1][0] < 0)  # it falls
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
    """The learned controller ``tau = g(s_t, s*_t)`` as a policy ``(step, key) -> tau``.

    Args:
      controller: the controller :class:`cfm_jax.learning.networks.Model`.
      params: its parameters (one seed's).
      normaliser: the :class:`cfm_jax.learning.networks.Normaliser` it was trained with.

    Examples:
      >>> from cfm_jax.learning import networks
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> norm = networks.Normaliser.identity(4, 2, jnp.ones(2))
      >>> policy = controller_policy(g, g.init(jax.random.key(0), 4), norm)
      >>> policy(Step(0, None, None, None, jnp.zeros(4), jnp.zeros(2), None), None).shape
      (2,)
    """

    def policy(step, key):
        del key
        return controller.apply(params, normaliser, step.state, step.desired)

    return policy


class MixedPolicy(NamedTuple):
    """Parameters of :func:`mixed_policy`: ``tau = controller_weight g(s, s*) + oracle_weight
    tau_oracle + feedback_weight tau_feedback + noise`` (the task's oracle and PD feedback).

    Attributes:
      controller_params: the learned controller's parameters.
      normaliser: its :class:`cfm_jax.learning.networks.Normaliser`.
      controller_weight: scalar (0 or 1).
      oracle_weight: scalar (0 or 1).
      feedback_weight: scalar (0 or 1).
      noise_std: ``(action_dim,)`` std of the torque noise, or a matrix ``N`` (noise ``N n``).

    Examples:
      >>> MixedPolicy.of(None, None, action_dim=2, feedback=1.0).noise_std.tolist()
      [0.0, 0.0]
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
    """The policy of :class:`MixedPolicy` parameters (one compiled rollout for every policy).

    Args:
      task: the task (its ``feedback`` and ``oracle_policy``).
      controller: the controller :class:`cfm_jax.learning.networks.Model`.
      parameters: the :class:`MixedPolicy` (may be traced; the oracle runs only if weighted).
      simulator: ``"native"`` or ``"mjx"`` (for the oracle).

    Examples:
      >>> from cfm_jax.learning import networks
      >>> from cfm_jax.tasks import references
      >>> from cfm_jax.sim import robots
      >>> from cfm_jax import tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> norm = networks.Normaliser.identity(4, 2, robot.torque_limit)
      >>> oracle = MixedPolicy.of(g.init(jax.random.key(0), 4), norm, 2, oracle=1.0)
      >>> bool(tracking_mse(run(task, mixed_policy(task, g, oracle), jax.random.key(1))) < 1e-5)
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
        # Rows that weight the oracle 0 (a batch of policies makes the cond a select) ask it
        # nothing: s* NaN, which its solvers skip (baselines.over_the_period).
        active = parameters.oracle_weight != 0
        asked = step._replace(desired=jnp.where(active, step.desired, jnp.nan))
        tau_oracle = jax.lax.cond(
            active,
            lambda: oracle(asked, key),
            lambda: jnp.zeros_like(tau),
        )
        return tau + jnp.where(active, parameters.oracle_weight * tau_oracle, 0.0)

    return policy


def tracking_mse(result: Rollout) -> jax.Array:
    """Tracking MSE per target, ``(targets,)``: the mean square of the tracking error.

    Args:
      result: a :class:`Rollout`.

    Examples:
      >>> tracking_mse(Rollout(None, jnp.ones((2, 5, 3)), None)).tolist()
      [1.0, 1.0]
    """
    return jnp.mean(jnp.square(result.tracking_error), axis=(-2, -1))
