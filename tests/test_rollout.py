"""MJX rollouts (cfm_jax/sim/rollout.py) against MuJoCo's C engine and plain Python loops.

Oracles: ``mujoco.mj_step`` (C, float64) on the same torque sequence; a Python loop of
``mjx.step`` with the same policy.

Compiles are the cost here (10-25 s each on 2 cores): one iiwa rollout, and on the two-link
arm one rollout shared by the scan-vs-loop and NaN tests (the torque sequence is an argument),
and one jitted ``mjx.step``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from cfm_jax import tasks
from cfm_jax.config import SIMULATORS, ConfigError
from cfm_jax.sim import native, rollout
from cfm_jax.tasks import baselines, references

CONTROL_DT = 0.01  # 5 physics steps of 0.002 s per control step


def open_loop_policy(torques, control_dt, gain_p=0.0, gain_d=0.0):
    """tau_t = torques[t] (+ optional PD feedback on the reference)."""
    del control_dt

    def policy(step, key):
        del key
        ref = step.reference
        feedback = gain_p * (ref.q - step.qpos) + gain_d * (ref.qd - step.qvel)
        return torques[step.t] + feedback

    return policy


def c_rollout(robot, q0, torques, control_dt):
    """Same open-loop torques in MuJoCo C (float64); qpos, qvel after every control step."""
    model = robot.mj_model
    data = mujoco.MjData(model)
    data.qpos[:] = q0
    data.qvel[:] = 0.0
    n_sub = int(round(control_dt / model.opt.timestep))
    qpos, qvel, max_constraints = [], [], 0
    for tau in torques:
        data.ctrl[:] = np.asarray(robot.torque_to_ctrl(jnp.asarray(tau)), np.float64)
        for _ in range(n_sub):
            mujoco.mj_step(model, data)
            max_constraints = max(max_constraints, data.nefc)
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
    return np.array(qpos), np.array(qvel), max_constraints


# ---- (a) MJX vs MuJoCo C on the iiwa ----------------------------------------------------------


@pytest.mark.parametrize("simulator", SIMULATORS)
def test_iiwa_rollout_matches_mujoco_c(iiwa, simulator):
    steps = 50
    ref = references.quintic(
        iiwa.home, iiwa.home, duration=steps * CONTROL_DT, control_dt=CONTROL_DT
    )
    # Gravity compensation at home plus sinusoids of 5 % of each torque limit: the arm moves
    # by a few tenths of a radian without touching a joint limit (checked below), so there
    # are no constraints and both engines integrate the same smooth ODE.
    data = mujoco.MjData(iiwa.mj_model)
    data.qpos[:] = iiwa.home
    mujoco.mj_forward(iiwa.mj_model, data)
    t = np.arange(steps)[:, None] * CONTROL_DT
    phase = np.arange(iiwa.nv)[None, :]
    torques = data.qfrc_bias[None, :] + 0.05 * iiwa.torque_limit * np.sin(
        2 * np.pi * 2.0 * t + phase
    )
    out = jax.jit(
        lambda tq: rollout.run(
            tasks.JointSpaceTask(iiwa, ref, kp=0.0, kd=0.0, control_dt=CONTROL_DT),
            open_loop_policy(tq, CONTROL_DT),
            key=jax.random.key(0),
            simulator=simulator,
        )
    )(jnp.asarray(torques, jnp.float32))
    q_c, qd_c, constraints = c_rollout(iiwa, iiwa.home, torques.astype(np.float32), CONTROL_DT)
    assert constraints == 0  # no joint limit became active: a clean comparison
    q_mjx = np.asarray(out.tracking_error[0]) + ref.q[0, 1:]
    # The executed torques are the requested ones (inside the limits).
    np.testing.assert_allclose(np.asarray(out.transitions.action[0]), torques, rtol=1e-6)
    # The arm really moves (otherwise the comparison is vacuous).
    assert np.max(np.abs(q_c[-1] - iiwa.home)) > 0.05
    # Tolerance: float32 MJX (eps 1.2e-7) vs float64 C over 250 steps of h = 0.002 s, no
    # constraints (the native simulator is C in float64 with the state rounded to float32
    # between control steps: smaller errors). Each qpos += h qd update rounds at
    # eps * |q| ~ 2e-7 rad (|q| <= 1.7); over
    # 250 steps these add as a random walk, sqrt(250) * 2e-7 ~ 3e-6 rad (observed 3e-7). The
    # acceleration's relative rounding (~1e-6 on |qdd| ~ 10 rad/s^2) integrated over 0.5 s
    # adds ~1e-6 rad and ~1e-5 rad/s at worst. 1e-5 rad and 2e-5 rad/s bound these; a
    # modelling difference (a wrong gear, damping, armature or substep count) gives errors
    # of 1e-3 and more.
    np.testing.assert_allclose(q_mjx, q_c, atol=1e-5, rtol=0)
    qd_mjx = np.asarray(out.transitions.state[0, 1:, iiwa.nq :])
    np.testing.assert_allclose(qd_mjx, qd_c[:-1], atol=2e-5, rtol=0)
    # Observed acceleration is (qd_{t+1} - qd_t) / control_dt of the C run: two velocity
    # errors over 0.01 s, 2 * 2e-5 / 0.01 = 4e-3 rad/s^2.
    qd_prev = np.concatenate([np.zeros((1, iiwa.nv)), qd_c[:-1]])
    np.testing.assert_allclose(
        np.asarray(out.transitions.observed[0]), (qd_c - qd_prev) / CONTROL_DT, atol=4e-3, rtol=0
    )
    assert bool(np.all(np.asarray(out.finite)))


# ---- two-link arm: one compiled rollout shared by (b) and (d) --------------------------------

ARM_STEPS = 10  # duration 0.1 s at control_dt 0.01


@pytest.fixture(scope="module", params=SIMULATORS)
def arm_case(arm, request):
    ref = references.quintic(
        arm.home, arm.home + np.array([0.1, -0.1]), duration=0.1, control_dt=CONTROL_DT
    )
    gain_p, gain_d = baselines.joint_pd_gains(arm, 100.0, 20.0, arm.home)

    @jax.jit
    def run(torques, key):
        policy = open_loop_policy(
            torques, CONTROL_DT, jnp.asarray(gain_p, jnp.float32), jnp.asarray(gain_d, jnp.float32)
        )
        return rollout.run(
            tasks.JointSpaceTask(arm, ref, kp=100.0, kd=20.0, control_dt=CONTROL_DT),
            policy,
            key=key,
            simulator=request.param,
        )

    data = mujoco.MjData(arm.mj_model)
    data.qpos[:] = arm.home
    mujoco.mj_forward(arm.mj_model, data)
    # gravity compensation at home plus a ramp; the second joint's torque exceeds its
    # 10 N m limit in the last steps so clipping is exercised
    torques = data.qfrc_bias[None, :] + np.linspace(0, 1, ARM_STEPS)[:, None] * [3.0, 30.0]
    return dict(
        ref=ref,
        run=run,
        torques=torques.astype(np.float32),
        gains=(np.float32(gain_p), np.float32(gain_d)),
        simulator=request.param,
    )


def python_loop_physics(arm, simulator):
    """``physics(q, qd, tau) -> (q, qd)`` after 5 physics steps, one call at a time:
    jitted ``mjx.step`` for MJX, ``mujoco.mj_step`` on an ``MjData`` (float64, state
    rounded to float32 between control steps, as the library stores it) for native."""
    if simulator == "mjx":
        model = arm.mjx_model
        step_fn = jax.jit(mjx.step)

        def physics(q, qd, tau):
            data = mjx.make_data(model).replace(
                qpos=jnp.asarray(q), qvel=jnp.asarray(qd), ctrl=jnp.asarray(tau)
            )
            for _ in range(5):
                data = step_fn(model, data)
            return np.asarray(data.qpos), np.asarray(data.qvel)

        return physics

    def physics(q, qd, tau):
        data = mujoco.MjData(arm.mj_model)
        data.qpos[:], data.qvel[:], data.ctrl[:] = q, qd, tau
        for _ in range(5):
            mujoco.mj_step(arm.mj_model, data)
        return data.qpos.astype(np.float32), data.qvel.astype(np.float32)

    return physics


def test_scan_rollout_matches_python_loop(arm, arm_case):
    ref, torques = arm_case["ref"], arm_case["torques"]
    out = arm_case["run"](jnp.asarray(torques), jax.random.key(0))
    assert out.transitions.state.shape == (1, ARM_STEPS, 4)
    assert out.tracking_error.shape == (1, ARM_STEPS, 2)

    # Plain Python loop: same policy, same clipping, same n_sub = 5 physics steps.
    physics = python_loop_physics(arm, arm_case["simulator"])
    gain_p, gain_d = arm_case["gains"]
    limit = np.float32(arm.torque_limit)
    ref32 = [np.asarray(x[0], np.float32) for x in ref]
    q, qd = ref32[0][0], np.zeros(arm.nv, np.float32)
    states, actions, observed, errors, desired = [], [], [], [], []
    for t in range(ARM_STEPS):
        desired.append(ref32[2][t] + 100.0 * (ref32[0][t] - q) + 20.0 * (ref32[1][t] - qd))
        tau = np.clip(
            torques[t] + gain_p * (ref32[0][t] - q) + gain_d * (ref32[1][t] - qd), -limit, limit
        )
        q_next, qd_next = physics(q, qd, tau)
        states.append(np.concatenate([q, qd]))
        actions.append(tau)
        observed.append((qd_next - qd) / CONTROL_DT)
        errors.append(q_next - ref32[0][t + 1])
        q, qd = q_next, qd_next
    # The clip was active at the end (elbow torque request > 10 N m).
    assert np.max(np.abs(np.array(actions)[:, 1])) == limit[1]
    # Same float32 operations in a different compiled program (scan + fori_loop vs separate
    # jitted steps): XLA may fuse and reorder, so results agree to float32 rounding, not
    # bitwise (observed: state 5e-7, observed accel 5e-5, torque 2e-6). Bounds: state 2e-6
    # (a few ulps of values up to ~2 after 50 steps); torque = K_p dq + K_d dqd with
    # K_p ~ 30 N m/rad: 30 * 2e-6 ~ 6e-5, allow 1e-4; desired = 100 dq + 20 dqd: 2.4e-4,
    # allow 3e-4; observed accel = two velocity errors / 0.01 s: 4e-4.
    np.testing.assert_allclose(np.asarray(out.transitions.state[0]), states, atol=2e-6)
    np.testing.assert_allclose(np.asarray(out.transitions.action[0]), actions, atol=1e-4)
    np.testing.assert_allclose(np.asarray(out.transitions.desired[0]), desired, atol=3e-4)
    np.testing.assert_allclose(np.asarray(out.transitions.observed[0]), observed, atol=4e-4)
    np.testing.assert_allclose(np.asarray(out.tracking_error[0]), errors, atol=2e-6)
    assert bool(np.all(np.asarray(out.finite)))
    # tracking_mse is the mean square of the position errors
    np.testing.assert_allclose(
        np.asarray(rollout.tracking_mse(out)), [np.mean(np.square(errors))], rtol=1e-4
    )


def test_nan_torque_makes_finite_false_from_that_step_on(arm_case):
    bad_step = 4
    torques = arm_case["torques"].copy()
    torques[bad_step] = [np.nan, 0.0]  # clip(NaN) is NaN: the NaN reaches the simulator
    out = arm_case["run"](jnp.asarray(torques), jax.random.key(0))
    finite = np.asarray(out.finite[0])
    expected = np.arange(ARM_STEPS) < bad_step
    np.testing.assert_array_equal(finite, expected)
    # The steps before are real transitions; from it on the rollout is frozen at its last
    # good state (nothing non-finite reaches the policy again), and what it observed is NaN.
    state = np.asarray(out.transitions.state[0])
    assert np.all(np.isfinite(state))
    assert np.all(state[bad_step + 1 :] == state[bad_step])
    assert np.all(np.isnan(np.asarray(out.transitions.observed[0, bad_step:])))


# ---- (e) control_dt must be a multiple of the timestep ---------------------------------------


def test_substeps(arm):
    assert rollout.substeps(arm, 0.002) == 1
    assert rollout.substeps(arm, 0.01) == 5
    assert rollout.substeps(arm, 0.1) == 50


@pytest.mark.parametrize("control_dt", [0.003, 0.001, 0.0101])
def test_substeps_rejects_non_multiples(arm, control_dt):
    with pytest.raises(ConfigError) as info:
        rollout.substeps(arm, control_dt)
    message = str(info.value)
    assert message.startswith(f"task.control_dt={control_dt!r}"), message
    assert "multiple" in message and "0.002" in message and "'two_link_arm'" in message


# ---- (f) the native simulator's host side ----------------------------------------------------


@pytest.mark.parametrize("batch", [1, 3, 40])  # 40 >= THREADED_BATCH: the thread pool
def test_native_stepper_matches_mj_step_per_element(iiwa, batch):
    # Any batch shape, single-threaded or pooled, equals stepping each state alone in C.
    rng = np.random.default_rng(batch)
    n_sub = 5
    low, high = iiwa.joint_range[:, 0], iiwa.joint_range[:, 1]
    qpos = rng.uniform(0.8 * low, 0.8 * high, (batch, iiwa.nq)).astype(np.float32)
    qvel = rng.normal(0.0, 0.5, (batch, iiwa.nv)).astype(np.float32)
    ctrl = rng.uniform(-0.3, 0.3, (batch, iiwa.mj_model.nu)).astype(np.float32)
    stepper = native.Stepper(iiwa.mj_model, n_sub)
    q_out, qd_out, _ = stepper(qpos.reshape(batch, 1, -1), qvel, ctrl)  # extra axis: reshaped
    assert q_out.shape == (batch, 1, iiwa.nq) and q_out.dtype == np.float32
    data = mujoco.MjData(iiwa.mj_model)
    for i in range(batch):
        mujoco.mj_resetData(iiwa.mj_model, data)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos[i], qvel[i], ctrl[i]
        for _ in range(n_sub):
            mujoco.mj_step(iiwa.mj_model, data)
        # Same C code on the same float64 inputs: equal up to the float32 output rounding.
        np.testing.assert_array_equal(q_out[i, 0], data.qpos.astype(np.float32))
        np.testing.assert_array_equal(qd_out[i, 0], data.qvel.astype(np.float32))
    # The robot's own model keeps automatic reset (only the stepper's copy disables it).
    assert not iiwa.mj_model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
