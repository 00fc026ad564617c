"""Baselines (cfm_jax/tasks/baselines.py): the operational-space oracle, task-space PD, the
implicit-damping term both oracles use, the site tracking metric, the NumPy closed loop and
the joint-space (inverse dynamics) oracle.

Oracles: one ``mj_step`` of the C engine for the oracle controller and the PD gains
(realised site accelerations from MuJoCo's own recursion); the host controller for its JAX
form; MuJoCo's Jacobian for the PD formula; sums worked by hand for the metric; the host
closed loop for the compiled one; for the joint-space oracle, the closed-form reference
(quintic) and the semi-implicit Euler recurrence of the rollout it drives.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from sites import mujoco_site_acceleration, random_states

from cfm_jax import _shipped, tasks
from cfm_jax.analysis import robot_check
from cfm_jax.config import SIMULATORS
from cfm_jax.sim import opspace, robots, rollout
from cfm_jax.tasks import babbling, baselines, references

# ---- oracle -----------------------------------------------------------------------------


def step_once(robot, qpos, qvel, tau):
    """One mj_step of the C engine with torque tau; returns the new qvel and #constraints."""
    model = robot.mj_model
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    data.ctrl[robot.actuator_of_joint] = tau / robot.gear
    mujoco.mj_step(model, data)
    return data.qvel.copy(), data.nefc


@pytest.mark.parametrize(("name", "site"), [("iiwa14", None), ("two_link_arm", "tip")])
def test_oracle_realises_desired_site_acceleration_in_one_step(name, site):
    robot = robots.load(name)
    model, site_id = robot.mj_model, opspace.ee_site(robot, site)
    oracle = baselines.HostOpspaceOracle(robot, site)
    rng = np.random.default_rng(4)
    checked = 0
    while checked < 8:
        q, qd = random_states(robot, rng, 1)
        desired = rng.uniform(-2.0, 2.0, 3)
        if name == "two_link_arm":
            desired[1] = 0.0  # the arm moves in the x-z plane
        tau = oracle(q[0], qd[0], desired)
        if np.any(np.abs(tau) >= robot.torque_limit):
            continue  # the test is about the dynamics, not about saturation
        qvel, constraints = step_once(robot, q[0], qd[0], tau)
        assert constraints == 0
        realised_qacc = (qvel - qd[0]) / model.opt.timestep
        realised = mujoco_site_acceleration(model, site_id, q[0], qd[0], realised_qacc)
        # float64: (qd1 - qd0) / h amplifies rounding by 1/h = 500; measured ~4e-14.
        np.testing.assert_allclose(realised, desired, atol=1e-11)
        checked += 1


def test_oracle_null_space_term_is_invisible_at_the_site(iiwa):
    # The posture term changes the torque but, through J Mt^-1 N^T = 0, not the site
    # acceleration: one C step with either torque realises the same xdd.
    rng = np.random.default_rng(5)
    q, qd = random_states(iiwa, rng, 1, spread=0.3)
    desired = np.array([0.5, -0.5, 1.0])
    with_posture = baselines.HostOpspaceOracle(iiwa)(q[0], qd[0], desired)
    without = baselines.HostOpspaceOracle(iiwa, null_kp=0.0, null_kd=0.0)(q[0], qd[0], desired)
    assert np.linalg.norm(with_posture - without) > 1.0
    site, h = opspace.ee_site(iiwa), iiwa.mj_model.opt.timestep
    for tau in (with_posture, without):
        assert np.all(np.abs(tau) < iiwa.torque_limit)
        qvel, _ = step_once(iiwa, q[0], qd[0], tau)
        xdd = mujoco_site_acceleration(iiwa.mj_model, site, q[0], qd[0], (qvel - qd[0]) / h)
        np.testing.assert_allclose(xdd, desired, atol=1e-11)


def test_implicit_damping_only_for_euler(iiwa):
    np.testing.assert_allclose(baselines.implicit_damping(iiwa.mj_model), 0.5 * 0.002)
    model = copy.deepcopy(iiwa.mj_model)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    np.testing.assert_array_equal(baselines.implicit_damping(model), 0.0)
    model = copy.deepcopy(iiwa.mj_model)
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    np.testing.assert_array_equal(baselines.implicit_damping(model), 0.0)


def test_opspace_oracle_jax_matches_host(iiwa):
    rng = np.random.default_rng(6)
    q, qd = (np.asarray(a, np.float32) for a in random_states(iiwa, rng, 5))
    desired = rng.uniform(-1.0, 1.0, (5, 3)).astype(np.float32)
    torque = jax.jit(jax.vmap(baselines.opspace_oracle(iiwa)))(q, qd, desired)
    expected = baselines.HostOpspaceOracle(iiwa)(q, qd, desired)
    assert torque.dtype == jnp.float32 and torque.shape == (5, 7)
    # float32 rounding of torques up to a few hundred N m
    np.testing.assert_allclose(torque, expected, atol=1e-4 * np.max(np.abs(expected)))


# ---- PD baseline ------------------------------------------------------------------------


def test_pd_gains_give_kp_acceleration_at_home(iiwa):
    # A task-space force F = K_p e applied from rest at home (with the bias compensated so
    # that only F acts) accelerates the site at kp e over one C step: K_p = kp Lambda(home).
    kp, kd = 100.0, 20.0
    gain_p, gain_d = baselines.opspace_pd_gains(iiwa, kp, kd)
    np.testing.assert_allclose(gain_d, gain_p * kd / kp, rtol=1e-15)
    np.testing.assert_allclose(gain_p, gain_p.T, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(gain_p) > 0)
    model, site = iiwa.mj_model, opspace.ee_site(iiwa)
    data = mujoco.MjData(model)
    data.qpos[:] = iiwa.home
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, 7))
    mujoco.mj_jacSite(model, data, jac, None, site)
    error = np.array([0.01, -0.02, 0.005])
    tau = jac.T @ gain_p @ error + data.qfrc_bias
    qvel, _ = step_once(iiwa, iiwa.home, np.zeros(7), tau)
    xdd = mujoco_site_acceleration(model, site, iiwa.home, np.zeros(7), qvel / model.opt.timestep)
    np.testing.assert_allclose(xdd, kp * error, atol=1e-11)


def test_pd_policy_formula(iiwa):
    gain_p = np.diag([300.0, 200.0, 100.0])
    gain_d = np.diag([30.0, 20.0, 10.0])
    rng = np.random.default_rng(8)
    q, qd = random_states(iiwa, rng, 3)
    ref_x = rng.uniform(0.3, 0.7, (3, 3))
    ref_xd = rng.uniform(-0.5, 0.5, (3, 3))
    args = [np.asarray(a, np.float32) for a in (q, qd, ref_x, ref_xd)]
    torque = jax.jit(baselines.opspace_pd_policy(iiwa, gain_p, gain_d))(*args)
    model, site = iiwa.mj_model, opspace.ee_site(iiwa)
    data = mujoco.MjData(model)
    for i in range(3):
        data.qpos[:], data.qvel[:] = args[0][i], args[1][i]
        mujoco.mj_forward(model, data)
        jac = np.zeros((3, 7))
        mujoco.mj_jacSite(model, data, jac, None, site)
        force = gain_p @ (args[2][i] - data.site_xpos[site]) + gain_d @ (
            args[3][i] - jac @ args[1][i]
        )
        np.testing.assert_allclose(torque[i], jac.T @ force, atol=1e-5 * np.abs(force).max())


# ---- metrics and closed loop ------------------------------------------------------------


def test_site_tracking_mse_by_hand():
    reference = np.zeros((2, 3, 3))
    reference[1, 1:] = 1.0
    positions = np.zeros((2, 2, 3))
    positions[0, 0] = [0.1, 0.2, 0.2]  # error^2 sum 0.09 over 6 numbers
    positions[1] = 1.0  # exactly on the reference after step 0
    mse = baselines.site_tracking_mse(positions, reference)
    np.testing.assert_allclose(np.asarray(mse), [0.09 / 6, 0.0], rtol=1e-6)
    np.testing.assert_allclose(baselines.site_tracking_mse(positions, reference[:, 1:]), mse)


def test_closed_loop_oracle_tracks_pd_does_not(iiwa):
    # 5 default references, 2 s, control_dt 0.01 (torque held for 5 physics steps).
    ref = references.cartesian_reaching(iiwa, None, None, 2.0, 0.01)
    oracle = baselines.HostOpspaceOracle(iiwa)
    out = baselines.host_rollout(
        iiwa, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd), 100.0, 20.0, 0.01
    )
    assert out.position.shape == (5, 200, 3)
    assert np.all(np.abs(out.tau) < iiwa.torque_limit)
    rmse = np.sqrt(np.asarray(baselines.site_tracking_mse(out.position, ref.x)))
    # exact per physics step, the held torque leaves ~0.05 mm (measured 0.03-0.08 mm)
    assert np.all(rmse < 2e-4), rmse
    gains = baselines.opspace_pd_gains(iiwa, 100.0, 20.0)
    kin = opspace.HostKinematics(iiwa)

    def pd(q, qd, desired, ref_x, ref_xd):
        state = kin(q, qd)
        force = (ref_x - state.position) @ gains[0].T + (ref_xd - state.velocity) @ gains[1].T
        return np.einsum("bij,bi->bj", state.jacobian, force)

    pd_out = baselines.host_rollout(iiwa, ref, pd, 100.0, 20.0, 0.01)
    pd_rmse = np.sqrt(np.asarray(baselines.site_tracking_mse(pd_out.position, ref.x)))
    assert np.all(pd_rmse > 0.02), pd_rmse  # no gravity compensation: sags by centimetres


def test_jax_closed_loop_matches_host_rollout(arm):
    # The JAX policies inside a scanned, vmapped loop with the native simulator reproduce
    # the host reference loop (what a wired-in opspace rollout must do).
    control_dt, kp, kd = 0.01, 100.0, 20.0
    ref = references.cartesian_reaching(arm, "tip", None, 0.5, control_dt)
    oracle = baselines.HostOpspaceOracle(arm, "tip")
    host = baselines.host_rollout(
        arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd), kp, kd, control_dt, "tip"
    )
    physics = rollout.native_physics(arm, rollout.substeps(arm, control_dt))
    torque = baselines.opspace_oracle(arm, "tip")
    limit = jnp.asarray(arm.torque_limit, jnp.float32)

    def one_target(ref_x, ref_xd, ref_xdd):
        def step(carry, t):
            q, qd = carry
            kin = opspace.kinematics(arm, q, qd, "tip")
            desired = references.desired_acceleration(
                ref_x[t], ref_xd[t], ref_xdd[t], kin.position, kin.velocity, kp, kd
            )
            tau = jnp.clip(torque(q, qd, desired), -limit, limit)
            q, qd, _ = physics(q, qd, arm.torque_to_ctrl(tau))
            return (q, qd), opspace.ee_position(arm, q, "tip")

        q0 = jnp.asarray(arm.home, jnp.float32)
        return jax.lax.scan(step, (q0, jnp.zeros_like(q0)), jnp.arange(ref_x.shape[0] - 1))[1]

    positions = jax.jit(jax.vmap(one_target))(*references.as_jax_cartesian(ref))
    # float32 desired accelerations vs float64 in the host loop: differences ~1e-6 m/s^2
    # that the stable closed loop does not amplify.
    np.testing.assert_allclose(positions, host.position, atol=1e-6)


# ---- the joint-space (inverse dynamics) oracle ---------------------------------------------
@pytest.mark.parametrize("simulator", SIMULATORS)
def test_oracle_policy_realises_desired_acceleration(arm, simulator):
    # kp = kd = 0 and control_dt = timestep (1 physics step per control step): the oracle's
    # torque M qdd* + h D qdd* + bias - passive makes MuJoCo's Euler step (implicit joint
    # damping) produce exactly qdd* = qdd_ref(t).
    dt = arm.timestep
    ref = references.quintic(
        arm.home, arm.home + np.array([0.05, -0.05]), duration=0.1, control_dt=dt
    )
    out = jax.jit(
        lambda: rollout.run(
            tasks.JointSpaceTask(arm, ref, kp=0.0, kd=0.0, control_dt=dt),
            baselines.inverse_dynamics_oracle(arm, simulator),
            key=jax.random.key(0),
            simulator=simulator,
        )
    )()
    qdd_ref = ref.qdd[0, :-1]
    np.testing.assert_allclose(np.asarray(out.transitions.desired[0]), qdd_ref, atol=1e-5)
    # Torques stay inside the limits (so no clipping spoils the inverse dynamics).
    assert np.all(np.abs(np.asarray(out.transitions.action[0])) < 0.9 * arm.torque_limit)
    # Observed (qd_{t+1} - qd_t) / h equals qdd_ref(t). float32: |qd| <= 0.94 rad/s has
    # rounding <= 6e-8, divided by h = 0.002 that is 3e-5 rad/s^2 per velocity, 6e-5 for the
    # difference (observed 1.8e-5); allow 1e-4 against |qdd| up to 29 rad/s^2.
    np.testing.assert_allclose(np.asarray(out.transitions.observed[0]), qdd_ref, atol=1e-4)
    # Positions follow the semi-implicit Euler recurrence of qdd_ref exactly (float64 here):
    # qd_{t+1} = qd_t + h qdd_ref(t), q_{t+1} = q_t + h qd_{t+1}.
    q, qd = ref.q[0, 0].copy(), np.zeros(2)
    expected = []
    for t in range(ref.steps):
        qd = qd + dt * ref.qdd[0, t]
        q = q + dt * qd
        expected.append(q)
    q_mjx = np.asarray(out.tracking_error[0], np.float64) + ref.q[0, 1:]
    # float32 positions ~1 rad: 50 rounded increments, 50 * 1.2e-7 = 6e-6; allow 1e-5.
    np.testing.assert_allclose(q_mjx, expected, atol=1e-5)
    # And against the closed form of the reference the only error is the Euler
    # discretisation, O(h * reach) = 0.002 * 0.05 * 15/8 / 0.1 ~ 2e-4 rad: tiny.
    assert np.max(np.abs(np.asarray(out.tracking_error[0]))) < 3e-4


@pytest.fixture(scope="module")
def friction_arm(tmp_path_factory):
    """The two-link arm with dry friction on both joints (``frictionloss`` 0.5 N m, a fifth
    of the elbow's torque at rest-to-reach accelerations), as published arms have it."""
    text = (_shipped.robot_dir() / "two_link_arm.xml").read_text()
    text = text.replace('damping="0.1"', 'damping="0.1" frictionloss="0.5"', 1)
    path = tmp_path_factory.mktemp("friction") / "friction_arm.xml"
    path.write_text(text)
    return robots.load(str(path))


@pytest.mark.parametrize("simulator", SIMULATORS)
def test_the_oracle_counts_dry_friction(friction_arm, simulator):
    # Oracle: MuJoCo's own step (the rollout's physics) with the oracle's torque; kp = kd = 0
    # and one physics step per control step, as above. With frictionloss the closed form
    # M qdd* + h D qdd* + bias - passive misses the friction force and the arm lags its
    # reference; MuJoCo's discrete-time inverse (constraint forces included) realises qdd*.
    arm = friction_arm
    assert baselines.constraints_act(arm.mj_model)
    dt = arm.timestep
    ref = references.quintic(
        arm.home, arm.home + np.array([0.05, -0.05]), duration=0.1, control_dt=dt
    )
    task = tasks.JointSpaceTask(arm, ref, kp=0.0, kd=0.0, control_dt=dt)

    def run(oracle):
        return jax.jit(lambda: rollout.run(task, oracle, key=jax.random.key(0),
                                           simulator=simulator))()  # fmt: skip

    out = run(baselines.inverse_dynamics_oracle(arm, simulator))
    qdd_ref = ref.qdd[0, :-1]
    observed = np.asarray(out.transitions.observed[0])
    # The constraint solver's tolerance and float32 velocities: allow 1e-2 of up to 29 rad/s^2
    # (the closed form's error is 100x that, below).
    np.testing.assert_allclose(observed, qdd_ref, atol=1e-2)
    # The closed form (what the oracle computed before) on the same states.
    inverse = baselines._native_inverse(arm.mj_model, baselines.implicit_damping(arm.mj_model))
    tau = inverse(
        np.asarray(out.transitions.state[0, :, :2]),
        np.asarray(out.transitions.state[0, :, 2:]),
        qdd_ref,
    )
    data = mujoco.MjData(arm.mj_model)
    realised = []
    for t in range(len(qdd_ref)):
        data.qpos[:] = out.transitions.state[0, t, :2]
        data.qvel[:] = out.transitions.state[0, t, 2:]
        data.ctrl[:] = tau[t]
        before = data.qvel.copy()
        mujoco.mj_step(arm.mj_model, data)
        realised.append((data.qvel - before) / dt)
    assert np.max(np.abs(np.asarray(realised) - qdd_ref)) > 1.0  # the closed form misses
    # The oracle's torques carry the friction: they differ from the closed form's by up to
    # the frictionloss, no more.
    gap = np.abs(np.asarray(out.transitions.action[0]) - tau)
    assert 0.3 < gap.max() <= 0.5 + 1e-3


def _wrist(tmp_path, frictionloss: float):
    """A one-hinge wrist about the vertical (no gravity torque): inertia 1e-4 kg m^2, no
    armature, damping 2 N m s/rad (the published xArm7's last joint), a 20 N m motor."""
    path = tmp_path / f"wrist_{frictionloss}.xml"
    path.write_text(f"""<mujoco model="wrist"><option timestep="0.002" integrator="Euler"/>
  <worldbody><body name="link"><joint name="roll" axis="0 0 1" range="-3 3" damping="2"
    frictionloss="{frictionloss}"/><inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>
  </body></worldbody>
  <actuator><motor joint="roll" ctrlrange="-20 20"/></actuator></mujoco>""")
    return robots.load(str(path))


def _hold(robot, gain_p, gain_d, q_ref: float, periods: int, n_sub: int = 5) -> np.ndarray:
    """MuJoCo C: the joint PD on a held reference, its torque held for ``n_sub`` steps."""
    data = mujoco.MjData(robot.mj_model)
    errors = [q_ref - data.qpos[0]]
    for _ in range(periods):
        data.ctrl[:] = gain_p * (q_ref - data.qpos) - gain_d * data.qvel
        mujoco.mj_step(robot.mj_model, data, n_sub)
        errors.append(q_ref - data.qpos[0])
    return np.asarray(errors)


def test_babbling_stiffness_moves_a_damped_joint_at_the_feedback_frequency(tmp_path, iiwa):
    kp, kd, dt, e0 = 100.0, 20.0, 0.01, 0.5
    wrist = _wrist(tmp_path, 0.0)
    gain_p, gain_d = baselines.babbling_joint_gains(wrist, kp, kd, wrist.home[None])
    inertia = float(wrist.lightest_inertia(wrist.home[None])[0])
    # Damping outweighs inertia at w = sqrt(kp) = 10 rad/s (2 / 10 > 1e-4): stiffness w D.
    np.testing.assert_allclose([gain_p[0], gain_d[0]], [10.0 * 2.0, kd * inertia], rtol=1e-12)
    # Hand derivation: with I << h D the velocity is tau / D within a physics step, so the
    # held error shrinks by (1 - dt K_p / D) = (1 - dt w) = 0.9 a period; the neglected
    # inertia (I / (I + h D) = 2.4% of a step) and K_d (2e-3 against D = 2) move it < 3%.
    errors = _hold(wrist, gain_p, gain_d, e0, periods=10)
    np.testing.assert_allclose(errors[1:] / e0, 0.9 ** np.arange(1, 11), rtol=0.03)
    # kp I (the babbling's stiffness before): the joint stays where it started.
    assert _hold(wrist, kp * inertia, gain_d, e0, periods=10)[-1] > 0.99 * e0
    # With the published wrist's dry friction (1 N m) the old stiffness (7e-3 N m at 0.5 rad)
    # leaves it stuck (MuJoCo's soft friction lets it creep, < 1% in a second); the new one
    # moves it through its friction to a dead band of a few F / K_p = 0.05 rad (on so light
    # a joint MuJoCo's soft constraint holds up to about 1.8 N m: 0.09 rad).
    dry = _wrist(tmp_path, 1.0)
    assert _hold(dry, kp * inertia, gain_d, e0, periods=100)[-1] > 0.99 * e0
    assert _hold(dry, gain_p, gain_d, e0, periods=100)[-1] < 0.2 * e0
    # Where inertia outweighs damping (the shipped iiwa14) the gains stay kp I, kd I exactly.
    poses = babbling.pose_sample(iiwa, iiwa.home)
    lightest = iiwa.lightest_inertia(poses)
    gains = baselines.babbling_joint_gains(iiwa, kp, kd, poses)
    for got, want in zip(gains, (kp, kd), strict=True):
        np.testing.assert_array_equal(got, want * lightest)
    # `robot check` names the joints whose stiffness their damping sets.
    for robot, damped in ((wrist, ("roll",)), (iiwa, ())):
        assert robot_check.dynamics(robot, 0.1, kd, dt, kp=kp).babbling_damped == damped


def _damped_arm(tmp_path, frictionloss: float):
    """The two-link arm with joint damping 5 N m s/rad (50x the shipped arm's: within the
    10 ms control period its velocities relax towards ``tau / D``, as on published arms
    whose damping outweighs their inertia), dry friction ``frictionloss``."""
    text = (_shipped.robot_dir() / "two_link_arm.xml").read_text()
    text = text.replace('damping="0.1"', f'damping="5" frictionloss="{frictionloss}"', 1)
    path = tmp_path / f"damped_{frictionloss}.xml"
    path.write_text(text)
    return robots.load(str(path))


def _held_in_mujoco(arm, qpos, qvel, tau, n_sub):
    """``(qvel' - qvel) / period`` of MuJoCo C (float64) with ``tau`` held ``n_sub`` steps."""
    model, data = arm.mj_model, mujoco.MjData(arm.mj_model)
    out = []
    for q, v, t in zip(qpos, qvel, np.asarray(tau, np.float64), strict=True):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = q, v
        data.ctrl[arm.actuator_of_joint] = t / arm.gear
        mujoco.mj_step(model, data, n_sub)
        out.append((data.qvel - v) / (n_sub * model.opt.timestep))
    return np.asarray(out)


@pytest.mark.parametrize(
    "simulator, frictionloss", [("native", 0.0), ("mjx", 0.0), ("native", 0.5)]
)
def test_the_period_oracle_realises_s_star_over_the_held_period(tmp_path, simulator,
                                                                 frictionloss):  # fmt: skip
    # Oracle: MuJoCo C with the oracle's torque held for the control period's 5 physics
    # steps, as the rollout holds it. The one-step inverse (task.oracle='step') realises s*
    # in the first step only and misses it over the period; 'period' solves the period.
    arm = _damped_arm(tmp_path, frictionloss)
    n_sub, control_dt = 5, 5 * arm.timestep
    ref = references.quintic(arm.home, arm.home + 0.1, duration=0.1, control_dt=control_dt)
    rng = np.random.default_rng(0)
    rows = 16
    qpos = (arm.home + 0.3 * rng.standard_normal((rows, 2))).astype(np.float32)
    qvel = (0.2 * rng.standard_normal((rows, 2))).astype(np.float32)
    desired = (2.0 * rng.standard_normal((rows, 2))).astype(np.float32)
    step = rollout.Step(0, qpos, qvel, None, None, desired, None)

    def realised(oracle):
        task = tasks.JointSpaceTask(arm, ref, 100.0, 20.0, control_dt, oracle=oracle)
        axes = rollout.Step(None, 0, 0, None, None, 0, None)
        policy = jax.vmap(task.oracle_policy(simulator), in_axes=(axes, None))
        tau = np.asarray(jax.jit(policy)(step, jax.random.key(0)))
        assert np.all(np.abs(tau) < 0.9 * arm.torque_limit), tau  # no clipping in the way
        return _held_in_mujoco(arm, qpos, qvel, tau, n_sub)

    miss = np.abs(realised("step") - desired).max()
    error = np.abs(realised("period") - desired).max()
    assert miss > 1.0, miss  # the one-step inverse: off by more than 1 rad/s^2
    # float32 velocities (|qvel| < 1 rad/s: rounding 6e-8) over a 10 ms period: 6e-6 rad/s^2
    # per row and velocity; measured 1.3e-6 (native), 3.9e-6 (mjx), 2.5e-6 (friction).
    assert error < 5e-5, error


def test_rows_without_s_star_ask_the_simulator_nothing():
    # The period oracle's Newton loop on a batch whose s* is NaN (a rollout that weights the
    # oracle 0) runs no step: the simulator (here a counting affine response) is never called.
    calls = []

    def count(tau):
        calls.append(tau.shape)
        return np.asarray(tau, np.float32)

    def response(step, tau):
        out = jax.ShapeDtypeStruct(tau.shape, jnp.float32)
        return 2.0 * jax.pure_callback(count, out, tau, vmap_method="expand_dims") + 1.0

    exact = baselines.over_the_period(lambda step, key: jnp.zeros(2), response, jnp.full(2, 9.0))
    axes = rollout.Step(None, None, None, None, None, 0, None)
    policy = jax.jit(jax.vmap(exact, in_axes=(axes, None)))

    def ask(desired):
        calls.clear()
        step = rollout.Step(0, None, None, None, None, jnp.asarray(desired, jnp.float32), None)
        return np.asarray(policy(step, None)), len(calls)

    tau, n = ask([[3.0, 5.0], [np.nan, 1.0]])
    np.testing.assert_allclose(tau[0], [1.0, 2.0], rtol=1e-6)  # (s* - 1) / 2
    np.testing.assert_array_equal(tau[1], [0.0, 0.0])  # unrefined: the start
    assert n == baselines.PERIOD_NEWTON_STEPS + 1
    tau, n = ask([[np.nan, 1.0], [np.nan, np.nan]])
    np.testing.assert_array_equal(tau, 0.0)
    assert n == 0
