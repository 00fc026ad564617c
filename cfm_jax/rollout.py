"""Closed-loop rollouts: ``scan`` over control steps, ``vmap`` over targets (and seeds).

No gradient flows through the simulator (the method does not need one): rollouts produce
transitions for the data set and tracking errors for the metrics. Two simulators step the
physics inside the same compiled rollout (see :data:`SIMULATORS`):

* ``"native"`` (default): MuJoCo's C engine (``mujoco.rollout``), called once per control
  step for the whole batch through ``jax.pure_callback``. Exact MuJoCo physics in float64
  (the state is stored as float32 between control steps), joint limits and contacts at C
  speed, compiles in about a second. Runs on any JAX backend (on a GPU the state crosses to
  the host every control step).
* ``"mjx"``: ``mujoco.mjx.step`` in JAX (float32), everything on the device. On CPU it is
  slower, in particular with joint-limit constraints, and compiles for 15-30 s.

A *policy* is a pure function ``policy(mjx_model, data, step, key) -> tau`` of the MJX data
at the current control step, a :class:`Step` of the state and reference, and a PRNG key.
This module provides the learned controller's, the oracle's (MuJoCo's inverse dynamics)
and PD-only policies.

Example:
  >>> import jax, numpy as np
  >>> from cfm_jax import robots, tasks
  >>> robot = robots.load("two_link_arm")
  >>> ref = tasks.quintic(robot.home, robot.home + 0.1, duration=0.1, control_dt=0.01)
  >>> out = run(robot, oracle_policy(robot), tasks.as_jax(ref), kp=100.0, kd=20.0,
  ...           control_dt=0.01, key=jax.random.key(0))
  >>> out.transitions.state.shape
  (1, 10, 4)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from cfm_jax import dataset, native, tasks

SIMULATORS = ("native", "mjx")
"""Physics back ends for :func:`run`."""


class Step(NamedTuple):
    """What a policy sees at control step ``t`` (arrays of one rollout)."""

    state: jax.Array  # s_t = [q, qdot], (state_dim,)
    desired: jax.Array  # qdd*_t, (nv,)
    ref_q: jax.Array  # q_ref(t), (nq,)
    ref_qd: jax.Array  # qd_ref(t), (nv,)
    ref_qdd: jax.Array  # qdd_ref(t), (nv,)


class Rollout(NamedTuple):
    """Result of rollouts, leading axes ``(targets, steps)``.

    Attributes:
      transitions: :class:`cfm_jax.dataset.Transitions` with ``(targets, steps, ...)``.
      position_error: ``q_{t+1} - q_ref(t+1)``, ``(targets, steps, nq)``.
      finite: whether the simulator state after the step is finite, ``(targets, steps)``.
    """

    transitions: dataset.Transitions
    position_error: jax.Array
    finite: jax.Array


def substeps(robot, control_dt: float) -> int:
    """Physics steps per control step; ``control_dt`` must be a multiple of the timestep."""
    ratio = control_dt / robot.timestep
    count = int(round(ratio))
    if count < 1 or abs(ratio - count) > 1e-6 * max(ratio, 1.0):
        from cfm_jax.config import ConfigError

        raise ConfigError(
            f"task.control_dt={control_dt!r} is not allowed: a positive multiple of robot "
            f"{robot.name!r}'s timestep {robot.timestep}"
        )
    return count


def run(
    robot, policy, reference: tasks.Reference, kp, kd, control_dt, key, simulator="native"
) -> Rollout:
    """Roll a policy out on every target of ``reference`` (pure; jit and vmap it).

    Args:
      robot: a :class:`cfm_jax.robots.Robot` (its models are closed over).
      policy: ``policy(mjx_model, data, step, key) -> tau (nv,)``; torques are clipped to the
        limits. ``data`` is an ``mjx.Data`` holding the current ``qpos, qvel`` and ``time``
        (with either simulator; other fields are not computed).
      reference: a :class:`cfm_jax.tasks.Reference` of JAX arrays ``(targets, steps+1, nq)``.
      kp, kd: gains of the PD correction in the desired acceleration.
      control_dt: control period (a multiple of the physics timestep).
      key: PRNG key, split per target and step.
      simulator: one of :data:`SIMULATORS`.

    Returns:
      A :class:`Rollout`; every rollout starts at rest at ``reference.q[:, 0]``.
    """
    if simulator not in SIMULATORS:
        from cfm_jax.config import ConfigError

        raise ConfigError(f"simulator={simulator!r} is not allowed: one of {SIMULATORS}")
    model = robot.mjx_model
    n_sub = substeps(robot, control_dt)
    limit = jnp.asarray(robot.torque_limit, jnp.float32)
    nq = robot.nq
    physics = native_physics(robot, n_sub) if simulator == "native" else mjx_physics(robot, n_sub)
    blank = mjx.make_data(model)

    def one_target(ref_q, ref_qd, ref_qdd, target_key):
        q0 = ref_q[0].astype(jnp.float32)
        qd0 = jnp.zeros(robot.nv, jnp.float32)

        def control_step(carry, t):
            q, qd, key = carry
            key, key_policy = jax.random.split(key)
            data = blank.replace(qpos=q, qvel=qd, time=t * jnp.float32(control_dt))
            desired = tasks.desired_acceleration(ref_q[t], ref_qd[t], ref_qdd[t], q, qd, kp, kd)
            step = Step(jnp.concatenate([q, qd]), desired, ref_q[t], ref_qd[t], ref_qdd[t])
            tau = jnp.clip(policy(model, data, step, key_policy), -limit, limit)
            q_next, qd_next, _ = physics(q, qd, robot.torque_to_ctrl(tau))
            observed = (qd_next - qd) / control_dt
            finite = jnp.all(jnp.isfinite(q_next)) & jnp.all(jnp.isfinite(qd_next))
            out = (
                dataset.Transitions(step.state, desired, tau, observed),
                q_next[:nq] - ref_q[t + 1],
                finite,
            )
            return (q_next, qd_next, key), out

        steps = ref_q.shape[0] - 1
        _, (transitions, error, finite) = jax.lax.scan(
            control_step, (q0, qd0, target_key), jnp.arange(steps)
        )
        # Once the state is non-finite, everything after it is too.
        finite = jnp.cumprod(finite.astype(jnp.int32)).astype(bool)
        return Rollout(transitions, error, finite)

    keys = jax.random.split(key, reference.q.shape[0])
    return jax.vmap(one_target)(reference.q, reference.qd, reference.qdd, keys)


def mjx_physics(robot, n_sub: int):
    """``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata (n_sub, nsensordata))`` after
    ``n_sub`` ``mjx.step`` calls from the state ``(qpos, qvel)`` (time and warm start start
    at zero); as :func:`native_physics`."""
    model = robot.mjx_model
    blank = mjx.make_data(model)

    def physics(qpos, qvel, ctrl):
        data = blank.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)

        def substep(data, _):
            data = mjx.step(model, data)
            return data, data.sensordata

        data, sensors = jax.lax.scan(substep, data, None, length=n_sub)
        return data.qpos, data.qvel, sensors

    return physics


_STEPPERS: dict = {}


def native_physics(robot, n_sub: int):
    """``physics(qpos, qvel, ctrl) -> (qpos, qvel, sensordata (n_sub, nsensordata))`` after
    ``n_sub`` steps of MuJoCo C (:class:`cfm_jax.native.Stepper`).

    A host callback (:func:`cfm_jax.native.host_step`, like ``jax.pure_callback`` with
    ``vmap_method="broadcast_all"`` but ~10x cheaper per call): under ``vmap`` the whole
    batch (targets x seeds) is stepped in one host call per control step. Time, warm start
    and actuator state start at the model defaults on every call.
    """
    cache_key = (id(robot.mj_model), n_sub)
    if cache_key not in _STEPPERS:
        _STEPPERS[cache_key] = (robot.mj_model, native.Stepper(robot.mj_model, n_sub))
    stepper = _STEPPERS[cache_key][1]

    def physics(qpos, qvel, ctrl):
        return native.host_step(stepper, qpos, qvel, ctrl)

    return physics


def controller_policy(controller, params, normaliser):
    """The learned controller ``tau = g(s_t, qdd*_t)``."""

    def policy(model, data, step, key):
        del model, data, key
        return controller.apply(params, normaliser, step.state, step.desired)

    return policy


def oracle_policy(robot, simulator="native"):
    """MuJoCo's inverse dynamics at the current state: ``tau = M qdd* + c - passive``.

    ``c`` is MuJoCo's bias force (Coriolis, centrifugal, gravity), ``passive`` the joint
    damping and spring forces. With the Euler integrator and implicit damping, the
    integrator's extra ``h D qdd`` term (``h`` the timestep, ``D`` the joint damping) is
    added so that one physics step realises ``qdd*`` exactly (up to torque limits); with
    several physics steps per control step the torque is held and tracking is approximate.

    ``simulator="native"`` computes it with MuJoCo C (``mj_fwdPosition``,
    ``mj_fwdVelocity``, ``mj_mulM``) through ``jax.pure_callback``; ``"mjx"`` with the
    corresponding MJX functions.
    """
    import mujoco

    mj = robot.mj_model
    eulerdamp = int(mj.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_EULER) and not int(
        mj.opt.disableflags
    ) & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    damping = mj.dof_damping * mj.opt.timestep if eulerdamp else np.zeros(mj.nv)
    implicit_damping = jnp.asarray(damping, jnp.float32)

    if simulator == "native":
        inverse = _native_inverse(mj, damping)

        def policy(model, data, step, key):
            del model, key
            shape = jax.ShapeDtypeStruct(jnp.shape(step.desired), jnp.float32)
            return jax.pure_callback(
                inverse, shape, data.qpos, data.qvel, step.desired, vmap_method="broadcast_all"
            )

        return policy

    def policy(model, data, step, key):
        del key
        data = mjx.fwd_position(model, data)
        data = mjx.fwd_velocity(model, data)
        inertial = mjx.mul_m(model, data, step.desired) + implicit_damping * step.desired
        return inertial + data.qfrc_bias - data.qfrc_passive

    return policy


def _native_inverse(mj_model, implicit_damping):
    """Host function ``(qpos, qvel, qacc) -> M qacc + h D qacc + bias - passive`` (float32),
    any leading batch shape."""
    import mujoco

    data = mujoco.MjData(mj_model)
    nq, nv = mj_model.nq, mj_model.nv

    def inverse(qpos, qvel, qacc):
        shape = np.shape(qacc)
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, nv)
        qacc = np.asarray(qacc, np.float64).reshape(-1, nv)
        out = np.empty_like(qacc)
        inertial = np.empty(nv)
        for i in range(qacc.shape[0]):
            data.qpos[:], data.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_fwdPosition(mj_model, data)
            mujoco.mj_fwdVelocity(mj_model, data)
            mujoco.mj_mulM(mj_model, data, inertial, qacc[i])
            out[i] = inertial + implicit_damping * qacc[i] + data.qfrc_bias - data.qfrc_passive
        return out.astype(np.float32).reshape(shape)

    return inverse


def pd_gains(robot, kp: float, kd: float, home) -> tuple[np.ndarray, np.ndarray]:
    """Torque PD gains equivalent to the acceleration gains ``kp, kd`` at the home pose.

    ``K_p = kp * diag(M(q_home))`` and ``K_d = kd * diag(M(q_home))``: the gains that give each
    joint, taken alone at the home pose, the same closed-loop stiffness and damping as the
    PD correction of the desired acceleration. No gravity compensation, no feed-forward.
    """
    inertia = robot.mass_matrix_diagonal(home)
    return kp * inertia, kd * inertia


def pd_policy(gain_p, gain_d, noise_std=None):
    """PD-only feedback ``tau = K_p (q_ref - q) + K_d (qd_ref - qd)`` (+ Gaussian noise).

    With ``noise_std`` (per joint, N·m) this is the motor-babbling policy.
    """
    gain_p = jnp.asarray(gain_p, jnp.float32)
    gain_d = jnp.asarray(gain_d, jnp.float32)

    def policy(model, data, step, key):
        del model
        tau = gain_p * (step.ref_q - data.qpos) + gain_d * (step.ref_qd - data.qvel)
        if noise_std is not None:
            tau = tau + jnp.asarray(noise_std, jnp.float32) * jax.random.normal(key, tau.shape)
        return tau

    return policy


class MixedPolicy(NamedTuple):
    """Parameters of :func:`mixed_policy`: one compiled rollout serves every policy.

    ``tau = controller_weight * g(s, qdd*) + oracle_weight * tau_oracle
    + K_p (q_ref - q) + K_d (qd_ref - qd) + noise_std * N(0, 1)``.

    Attributes:
      controller_params, normaliser: the learned controller and its statistics.
      controller_weight, oracle_weight: scalars (0 or 1).
      gain_p, gain_d, noise_std: ``(nv,)``.
    """

    controller_params: Any
    normaliser: Any
    controller_weight: jax.Array
    oracle_weight: jax.Array
    gain_p: jax.Array
    gain_d: jax.Array
    noise_std: jax.Array

    @classmethod
    def of(
        cls,
        controller_params,
        normaliser,
        nv,
        controller=0.0,
        oracle=0.0,
        gain_p=None,
        gain_d=None,
        noise_std=None,
    ) -> MixedPolicy:
        zeros = jnp.zeros(nv, jnp.float32)
        as_vector = lambda x: zeros if x is None else jnp.asarray(x, jnp.float32)  # noqa: E731
        return cls(
            controller_params,
            normaliser,
            jnp.float32(controller),
            jnp.float32(oracle),
            as_vector(gain_p),
            as_vector(gain_d),
            as_vector(noise_std),
        )


def mixed_policy(robot, controller, parameters: MixedPolicy, simulator="native"):
    """The policy of :class:`MixedPolicy` parameters (the oracle term is computed only when
    ``oracle_weight`` is non-zero, by ``lax.cond``)."""
    learned = controller_policy(controller, parameters.controller_params, parameters.normaliser)
    oracle = oracle_policy(robot, simulator)
    pd = pd_policy(parameters.gain_p, parameters.gain_d, noise_std=parameters.noise_std)

    def policy(model, data, step, key):
        tau = parameters.controller_weight * learned(model, data, step, key)
        tau = tau + pd(model, data, step, key)
        tau_oracle = jax.lax.cond(
            parameters.oracle_weight != 0,
            lambda: oracle(model, data, step, key),
            lambda: jnp.zeros_like(tau),
        )
        return tau + parameters.oracle_weight * tau_oracle

    return policy


def tracking_mse(result: Rollout) -> jax.Array:
    """Joint-position tracking MSE per target: mean over steps and joints, ``(targets,)``."""
    return jnp.mean(jnp.square(result.position_error), axis=(-2, -1))
