"""The development set of published arms (tests/robots/, MuJoCo Menagerie as published, meshes
stripped; tests/robots/README.md) and what the library tells about a robot before training.

* Every arm of the set loads with ``robot_actuators="torque"``, and its oracle and PD-only
  baselines roll out on the native simulator and on MJX: finite, the two simulators within
  float32 of each other, the oracle below PD-only. The
  two arms with a gripper (fingers coupled by an equality, moved by one servo) train their
  six arm joints and hold the fingers with the gripper's servo as published
  (tests/test_held_joints.py checks that mechanism against MuJoCo C).
* :func:`cfm_jax.analysis.robot_check.dynamics` against MuJoCo's own forward dynamics (the
  acceleration a torque gives, ``mj_forward``), not against the matrix inverse it uses, and in
  closed form on a one-joint pendulum.
* A model MJX cannot build (a cylinder-box collision pair) runs on the native simulator;
  asked for on MJX it raises a ``RobotError`` naming the pair.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import mujoco
import numpy as np
import pytest

from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.analysis import robot_check
from cfm_jax.learning import algorithm
from cfm_jax.learning.algorithm import Experiment
from cfm_jax.sim import robots
from cfm_jax.tasks import babbling, legged
from cfm_jax.tasks.baselines import pd_loop_radius

HERE = Path(__file__).parent
DEV = HERE / "robots"
# The arms with one actuator per joint, and those with a gripper.
ARMS = (
    "flexiv_rizon4",
    "m1013",
    "lite6",
    "lite6_continuous",
    "kuka_iiwa_14",
    "kinova_gen3",
    "franka_fr3",
)
GRIPPERS = ("piper", "arx_l5")


def test_the_set_is_what_its_readme_lists():
    listed = {p.stem for p in DEV.glob("*.xml")}
    assert listed == set(ARMS) | set(GRIPPERS)
    readme = (DEV / "README.md").read_text()
    for name in listed:
        assert f"{name}.xml" in readme or f"`{name}`" in readme or name in readme
    for path in DEV.glob("*.xml"):
        head = path.read_text()[:2000]
        assert "mujoco_menagerie" in head and "Licen" in head, path.name


QUADRUPEDS = DEV / "quadrupeds"


def test_the_quadrupeds_load_as_published_and_the_legged_tasks_run_on_them():
    """The published quadrupeds (tests/robots/quadrupeds/, issue 65) load with their 12 leg
    actuators as torque motors (the Go2's as published, ANYmal C's and Barkour vB's servos
    converted), a floating base, and the ground and foot sensors loading adds. ``robot
    check`` says the legged tasks run on them (with a note where MJX cannot build the
    model, so the defaults' rigid-body forward model cannot run), and the arm tasks refuse
    the floating base."""
    files = sorted(QUADRUPEDS.glob("*.xml"))
    assert {p.stem for p in files} == {"go2", "anymal_c", "barkour_vb_mjx"}
    readme = (QUADRUPEDS / "README.md").read_text()
    for path in files:
        head = path.read_text()[:2000]
        assert "mujoco_menagerie" in head and "Licen" in head, path.name
        assert f"`{path.name}`" in readme
        found = robot_check.check(str(path), "torque")
        robot = found.robot
        assert robot.floating_base and len(robot.actuated_dofs) == 12
        model = mujoco.MjModel.from_xml_path(str(path))
        assert robot.mj_model.nv == model.nv == 18 and robot.mj_model.nq == model.nq == 19
        assert len(robot.converted) == (0 if path.stem == "go2" else 12)
        assert robot.added and "a contact sensor per foot" in robot.added[-1]
        for task in ("walk", "jump"):
            assert found.tasks[task] is None, (path.name, task, found.tasks[task])
        # MJX builds Barkour vB, not the Go2's or ANYmal's cylinder-box pairs
        assert (legged.fits(robot) == "") == (path.stem == "barkour_vb_mjx"), path.name
        assert "floating base" in found.tasks["inverse_dynamics"]


def torque_limit(arm: str):
    """The ``--robot-torque-limit`` of ``arm`` in tests/robots/robots.json (a file without
    limits of its own: the published iiwa 14, data-sheet limits), or None."""
    flags = json.loads((DEV / "robots.json").read_text()).get(f"{arm}.xml", [])
    if "--robot-torque-limit" not in flags:
        return None
    return tuple(float(x) for x in flags[flags.index("--robot-torque-limit") + 1 :])


def baselines(arm: str, simulator: str, oracle: str = "period"):
    config = config_lib.Config(
        robot=str(DEV / f"{arm}.xml"),
        robot_actuators="torque",
        robot_torque_limit=torque_limit(arm),
        simulator=simulator,
        task=config_lib.TaskConfig(duration=0.3, oracle=oracle),
        # The baselines do not depend on the torque scale; the default pose scale would put
        # MJX's mass matrix into their rollouts' programs (weight 0) and its compile time here.
        loop=config_lib.LoopConfig(torque_scale="coupled"),
    )
    # MJX's programs without LLVM optimisation: they compile in about 35 s instead of 50 s
    # (the PiPER, beside two studies) for a rollout of 0.3 s; the numbers move in float32's
    # last digits, far inside the 1e-3 the test allows against MuJoCo C.
    options = {"xla_backend_optimization_level": 0} if simulator == "mjx" else None
    table = Experiment(config, compiler_options=options).baselines()
    return table.pivot(index="target", columns="baseline", values="tracking_mse")


@pytest.fixture(scope="module")
def native():
    return {arm: baselines(arm, "native", "step") for arm in ARMS + GRIPPERS}


@pytest.mark.parametrize("arm", ARMS + GRIPPERS)
def test_baselines_roll_out_on_both_simulators(native, arm):
    nat = native[arm]
    assert np.isfinite(nat.to_numpy()).all()
    assert nat["oracle"].mean() < nat["pd_only"].mean()
    # The default oracle, exact over the held control period. These 0.3 s reaches ask for
    # more torque than the limits give (the oracles clip), so it need not track below the
    # one-step oracle (the Franka: 7.39e-4 against 7.29e-4); on the M1013, whose damping
    # outweighs its inertia on every joint, the one-step oracle misses the period: 0.0248
    # against the period oracle's 0.0083.
    period = baselines(arm, "native")
    assert np.isfinite(period.to_numpy()).all()
    assert period["oracle"].mean() < nat["pd_only"].mean()
    if arm == "m1013":
        assert period["oracle"].mean() < nat["oracle"].mean() / 2
    np.testing.assert_array_equal(period["pd_only"], nat["pd_only"])
    # The one-step oracle on MJX (the period oracle's MJX path is tests/test_baselines.py's:
    # its Newton steps on MJX's CPU backend tripled this test's time).
    mjx = baselines(arm, "mjx", "step")
    assert np.isfinite(mjx.to_numpy()).all()
    # MJX in float32 against MuJoCo C in float64: measured within 1e-6 relative (lite6,
    # m1013); 1e-3 leaves room for float32 and still catches a different model.
    np.testing.assert_allclose(mjx.to_numpy(), nat.to_numpy(), rtol=1e-3, atol=1e-9)


@pytest.mark.parametrize("arm", GRIPPERS)
def test_gripper_arms_drive_the_arm_and_hold_the_fingers(arm):
    robot = robots.load(str(DEV / f"{arm}.xml"), actuators="torque")
    assert robot.action_dim == 6
    assert robot.held_joints == ("joint7", "joint8") and robot.passive_joints == ()
    # The gripper's servo is not converted; the six arm servos are.
    assert [name for name, _ in robot.converted] == [f"joint{i}" for i in range(1, 7)]


# ---- dynamics at the start pose, against MuJoCo's forward dynamics ----------------------


def _response(robot, torque, qpos=None):
    """``qacc(torque) - qacc(0)`` of the actuated dofs at rest at ``qpos`` (default: home;
    MuJoCo C): M^-1 torque."""
    model = robot.mj_model
    data = mujoco.MjData(model)

    def qacc(tau):
        data.qpos[:] = robot.home if qpos is None else qpos
        data.qvel[:] = 0.0
        data.ctrl[:] = 0.0
        data.ctrl[robot.actuator_of_joint] = tau / robot.gear
        mujoco.mj_forward(model, data)
        return data.qacc[robot.actuated_dofs].copy()

    return qacc(torque) - qacc(np.zeros_like(torque))


@pytest.mark.parametrize(
    "name", ["iiwa14", str(HERE / "three_joint_arm.xml"), str(DEV / "m1013.xml")]
)
def test_dynamics_against_mujoco_forward_dynamics(name):
    robot = robots.load(name, actuators="torque")
    d = robot_check.dynamics(robot, babbling_noise=0.1, kd=20.0, control_dt=0.01, frequency=10.0)
    by_limit = robot_check.dynamics(
        robot, babbling_noise=0.1, kd=20.0, control_dt=0.01, torque_scale="limit"
    )
    n = robot.action_dim
    limit = np.asarray(robot.torque_limit, np.float64)
    scale = robot.torque_scale(10.0)  # the defaults' feedback: sqrt(kp = 100)
    # Column j of M^-1 times a torque on joint j alone, from mj_forward.
    cols = np.stack([_response(robot, np.eye(n)[j] * limit[j]) for j in range(n)], axis=1)
    # Gaussian noise of std 0.1 * limit on each joint: acceleration std of joint i is the
    # root sum of squares of row i of those columns, scaled by 0.1; of std 0.1 * scale, the
    # same with each column scaled by scale / limit.
    np.testing.assert_allclose(
        by_limit.noise_acceleration, 0.1 * np.sqrt((cols**2).sum(1)), rtol=1e-6
    )
    np.testing.assert_allclose(
        d.noise_acceleration, 0.1 * np.sqrt(((cols * scale / limit) ** 2).sum(1)), rtol=1e-6
    )
    np.testing.assert_allclose(d.limit_acceleration, np.abs(cols).sum(1), rtol=1e-6)
    # Effective inertia: a unit torque on joint i alone accelerates it by (M^-1)_ii.
    unit = np.array([_response(robot, np.eye(n)[i])[i] for i in range(n)])
    np.testing.assert_allclose(d.effective_inertia, 1.0 / unit, rtol=1e-6)


def test_dynamics_of_a_pendulum_in_closed_form(tmp_path):
    # One hinge, point mass m at distance r, armature a: M = m r^2 + a; lambda(diag M M^-1)=1.
    m, r, a, limit = 2.0, 0.5, 0.1, 8.0
    path = tmp_path / "pendulum.xml"
    path.write_text(
        f"""<mujoco><option gravity="0 0 0"/><worldbody><body>
        <joint name="j" type="hinge" axis="0 1 0" armature="{a}"/>
        <inertial pos="{r} 0 0" mass="{m}" diaginertia="1e-9 1e-9 1e-9"/></body></worldbody>
        <actuator><motor joint="j" ctrlrange="-{limit} {limit}"/></actuator></mujoco>"""
    )
    d = robot_check.dynamics(robots.load(str(path)), babbling_noise=0.1, kd=20.0, control_dt=0.01)
    inertia = m * r**2 + a
    assert d.effective_inertia[0] == pytest.approx(inertia, rel=1e-6)
    assert d.limit_acceleration[0] == pytest.approx(limit / inertia, rel=1e-6)
    assert d.noise_acceleration[0] == pytest.approx(0.1 * limit / inertia, rel=1e-6)
    assert d.pd_number == pytest.approx(20.0 * 0.01, rel=1e-9)
    # One joint: its inertia does not change with the pose, so the babbling's gains are
    # the baseline's and so is the number.
    assert d.babbling_pd_number == pytest.approx(20.0 * 0.01, rel=1e-9)


def test_torque_scale_with_damping_and_friction_in_closed_form(tmp_path):
    # Three separate pendulums (gravity off, no coupling): M_jj = m r^2 + armature. Joint
    # "damped" has damping 20 and inertia 0.006, as the M1013's wrist; "dry" has dry
    # friction 0.3 N m, as the PiPER's joints; "free" neither.
    joints = (  # name, mass, r, armature, damping, frictionloss, limit
        ("free", 2.0, 0.5, 0.1, 0.0, 0.0, 30.0),
        ("damped", 0.1, 0.2, 0.002, 20.0, 0.0, 50.0),
        ("dry", 0.5, 0.3, 0.01, 0.0, 0.3, 4.0),
    )
    bodies = "".join(
        f"""<body><joint name="{n}" type="hinge" axis="0 1 0" armature="{a}" damping="{d}"
        frictionloss="{f}"/><inertial pos="{r} 0 0" mass="{m}" diaginertia="1e-9 1e-9 1e-9"/>
        </body>"""
        for n, m, r, a, d, f, _ in joints
    )
    motors = "".join(f'<motor joint="{j[0]}" ctrlrange="-{j[6]} {j[6]}"/>' for j in joints)
    path = tmp_path / "three.xml"
    path.write_text(f"""<mujoco><option gravity="0 0 0"/><worldbody>{bodies}</worldbody>
        <actuator>{motors}</actuator></mujoco>""")
    arm = robots.load(str(path))
    w = 10.0  # rad/s, sqrt(kp = 100)
    # m r^2 + armature + the body's own 1e-9 about the axis.
    mass = np.array([m * r**2 + a + 1e-9 for _, m, r, a, *_ in joints])
    damping = np.array([j[4] for j in joints])
    friction = np.array([j[5] for j in joints])
    limit = np.array([j[6] for j in joints])
    # Impedance per unit acceleration of tau = M qdd + D qd for q = e^(iwt): |M - i D / w|.
    # By hand: free 0.6 kg m^2, limit 30 -> 50 rad/s^2; damped |0.006 - 2i| = 2.000009
    # -> 25 rad/s^2; dry 0.055, (4 - 0.3) / 0.055 = 67. The damped joint is the weakest.
    impedance = np.abs(mass - 1j * damping / w)
    assert impedance[1] == pytest.approx(np.sqrt(0.006**2 + 2.0**2), rel=1e-6)
    rate = (limit[1] - friction[1]) / impedance[1]
    want = friction + impedance * rate
    got = arm.torque_scale(w)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got[1] == 50.0  # the weakest joint: its limit
    # By inertia alone (w = inf) the damped joint looked the strongest (8333 rad/s^2) and
    # got a scale of 0.006 * 50 = 0.3 N m: the free joint is the weakest there.
    alone = arm.torque_scale()
    assert alone[0] == 30.0 and alone[1] == pytest.approx(0.006 * 50.0, rel=1e-6)
    # The dry joint's scale includes its friction: 0.3 + 0.055 * rate.
    assert got[2] == pytest.approx(0.3 + 0.055 * 50.0 / np.sqrt(0.006**2 + 4.0), rel=1e-6)
    with pytest.raises(ValueError, match="frequency=0.0"):
        arm.torque_scale(0.0)


@pytest.mark.parametrize("arm", ARMS + GRIPPERS)
def test_torque_scale_without_damping_and_friction_is_the_acceleration_scale(arm):
    # Where no driven joint has damping or friction the feedback frequency changes nothing,
    # bit for bit: those arms' zoo runs made before the damping term stand. Elsewhere the
    # scale is by hand from M(home) (MuJoCo C), the damping and the friction.
    robot = robots.load(str(DEV / f"{arm}.xml"), actuators="torque",
                        torque_limit=torque_limit(arm))  # fmt: skip
    dofs = np.asarray(robot.actuated_dofs)
    damping = robot.mj_model.dof_damping[dofs]
    friction = robot.mj_model.dof_frictionloss[dofs]
    got = robot.torque_scale(10.0)
    if not damping.any() and not friction.any():
        np.testing.assert_array_equal(got, robot.torque_scale())
        return
    limit = np.asarray(robot.torque_limit, np.float64)
    impedance = np.sqrt(robot.mass_matrix_diagonal(robot.home)[dofs] ** 2 + (damping / 10) ** 2)
    want = friction + impedance * np.min((limit - friction) / impedance)
    np.testing.assert_allclose(got, np.minimum(want, limit), rtol=1e-9)


def test_noise_velocity_of_a_damped_pendulum_against_one_mujoco_step(tmp_path):
    # One hinge, M = m r^2 + 1e-9 = 0.006, damping 20, Euler with the control period as
    # its timestep: MuJoCo's implicit damping gives qvel = tau h / (M + h D) after one step.
    path = tmp_path / "damped.xml"
    path.write_text(
        """<mujoco><option gravity="0 0 0" timestep="0.01" integrator="Euler"/>
        <worldbody><body><joint name="j" type="hinge" axis="0 1 0" damping="20"/>
        <inertial pos="0.2 0 0" mass="0.15" diaginertia="1e-9 1e-9 1e-9"/></body></worldbody>
        <actuator><motor joint="j" ctrlrange="-50 50"/></actuator></mujoco>"""
    )
    robot = robots.load(str(path))
    d = robot_check.dynamics(robot, babbling_noise=0.1, kd=20.0, control_dt=0.01, frequency=10.0)
    noise = 0.1 * robot.torque_scale(10.0)[0]  # one joint: its limit, 5 N m
    assert noise == pytest.approx(5.0)
    inertia = 0.15 * 0.2**2 + 1e-9
    assert d.noise_velocity[0] == pytest.approx(0.01 * noise / (inertia + 0.01 * 20.0), rel=1e-9)
    data = mujoco.MjData(robot.mj_model)
    data.ctrl[0] = noise
    mujoco.mj_step(robot.mj_model, data)
    assert d.noise_velocity[0] == pytest.approx(data.qvel[0], rel=1e-9)
    # At rest the damping does not act: the acceleration is the undamped one, 833 rad/s^2,
    # whose velocity over a period (8.3 rad/s) the check no longer reports as the kick.
    assert d.noise_acceleration[0] == pytest.approx(noise / inertia, rel=1e-6)
    text = robot_check.check(str(path)).text
    assert "babbling noise changes" not in text and "0.243 rad/s per control period" in text


def test_robot_check_warns_where_the_numbers_say_so(tmp_path):
    coupled = robot_check.check(str(DEV / "kinova_gen3.xml"), actuators="torque").text
    assert "PD-only baseline's feedback is unstable" in coupled
    assert "babbling's feedback is unstable" not in coupled
    # The M1013's number kd dt lambda_max is 2.2, but its joints' damping makes the loop
    # stable (test_pd_loop_radius_against_mujoco): no warning.
    damped = robot_check.check(str(DEV / "m1013.xml"), actuators="torque").text
    assert "= 2.21)" in damped and "is unstable" not in damped
    # A pendulum whose only limit gives it 1e5 rad/s^2: noise 0.1 of it, 100 rad/s a period.
    path = tmp_path / "strong.xml"
    path.write_text(
        """<mujoco><option gravity="0 0 0"/><worldbody><body>
        <joint name="j" type="hinge" axis="0 1 0"/>
        <inertial pos="0.5 0 0" mass="0.4" diaginertia="1e-9 1e-9 1e-9"/></body></worldbody>
        <actuator><motor joint="j" ctrlrange="-1e4 1e4"/></actuator></mujoco>"""
    )
    strong = robot_check.check(str(path)).text
    assert "babbling noise changes j's velocity by about 100 rad/s" in strong
    shipped = robot_check.check("iiwa14").text
    assert "dynamics at the start pose" in shipped and "!" not in shipped.split("dynamics")[1]


def test_pd_loop_radius_of_a_two_joint_arm_in_closed_form(tmp_path):
    # Two hinges in a plane, gravity off, no damping, Euler with the control period as its
    # timestep (one step a period). With gains G (kp, kd), G diagonal, the error obeys
    # v' = v - h M^-1 G (kp q + kd v), q' = q + h v'; in the modes of M^-1 G (eigenvalues
    # lam) each is [[1 - h^2 lam kp, h - h^2 lam kd], [-h lam kp, 1 - h lam kd]]: trace
    # 2 - h lam kd - h^2 lam kp, determinant 1 - h lam kd (by hand).
    h = 0.01
    path = tmp_path / "two.xml"
    path.write_text(f"""<mujoco><option gravity="0 0 0" timestep="{h}" integrator="Euler"/>
        <worldbody><body><joint name="a" type="hinge" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.03" mass="2"/>
        <body pos="0.5 0 0"><joint name="b" type="hinge" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.02" mass="0.3"/></body></body>
        </worldbody><actuator><motor joint="a" ctrlrange="-50 50"/>
        <motor joint="b" ctrlrange="-50 50"/></actuator></mujoco>""")
    arm = robots.load(str(path))
    pose = np.array([0.3, 0.4])
    inertia = arm.mass_matrix(pose)
    for gains, kp, kd in ((np.diag(inertia), 100.0, 20.0), (np.diag(inertia), 100.0, 190.0),
                          (np.array([1.0, 0.05]), 400.0, 60.0)):  # fmt: skip
        lam = np.linalg.eigvals(np.linalg.solve(inertia, np.diag(gains))).real
        roots = [np.roots([1.0, -(2 - h * x * kd - h * h * x * kp), 1 - h * x * kd]) for x in lam]
        want = np.abs(roots).max()
        got = pd_loop_radius(arm, kp * gains, kd * gains, pose, h)
        assert got == pytest.approx(want, rel=1e-9)
    # The second case is unstable (the coupled mode has lam kd h > 2), the first is not.
    assert pd_loop_radius(arm, 100 * np.diag(inertia), 190 * np.diag(inertia), pose, h) > 1
    assert pd_loop_radius(arm, 100 * np.diag(inertia), 20 * np.diag(inertia), pose, h) < 1


@pytest.mark.parametrize("arm", ["kinova_gen3", "m1013"])
def test_pd_loop_radius_against_mujoco(arm):
    """The PD-only loop at home, simulated by MuJoCo C (gravity off, a 1e-7 rad start error,
    the torque held over each period's five steps): its error grows or decays per period by the
    radius. The Gen3 (implicitfast, no damping) diverges at 4.3 a period; the M1013 (Euler,
    damping 20-180), whose kd dt lambda_max is 2.2, decays."""
    robot = robots.load(str(DEV / f"{arm}.xml"), actuators="torque")
    model, dt = robot.mj_model, 0.01
    model.opt.gravity[:] = 0.0
    dofs = np.asarray(robot.actuated_dofs)
    gains = np.diag(robot.mass_matrix(robot.home))[dofs]
    radius = pd_loop_radius(robot, 100 * gains, 20 * gains, robot.home, dt)
    data = mujoco.MjData(model)
    data.qpos[:] = robot.home
    data.qpos[dofs] += 1e-7 * np.random.default_rng(0).standard_normal(len(dofs))
    periods, tail = (12, 6) if radius > 1 else (3000, 1000)
    size = []
    for _ in range(periods):
        error, velocity = data.qpos[dofs] - robot.home[dofs], data.qvel[dofs]
        data.ctrl[robot.actuator_of_joint] = -(100 * gains * error + 20 * gains * velocity)
        for _ in range(round(dt / robot.timestep)):
            mujoco.mj_step(model, data)
        size.append(np.linalg.norm(np.r_[data.qpos[dofs] - robot.home[dofs], dt * data.qvel[dofs]]))
    rate = (size[-1] / size[-1 - tail]) ** (1 / tail)
    assert rate == pytest.approx(radius, rel=1e-3)
    assert (radius > 1) == (arm == "kinova_gen3") and (size[-1] > size[0]) == (radius > 1)


# ---- the babbling's gains and noise on an arm with light links ---------------------------


def _kuka():
    return robots.load(
        str(DEV / "kuka_iiwa_14.xml"), actuators="torque", torque_limit=torque_limit("kuka_iiwa_14")
    )


def test_lightest_inertia_against_mujoco_forward_dynamics():
    robot = _kuka()
    poses = babbling.pose_sample(robot, robot.home, count=6)
    n = robot.action_dim
    # A unit torque on joint j alone, at rest, accelerates it by (M^-1)_jj (mj_forward).
    effective = [[1.0 / _response(robot, np.eye(n)[j], q)[j] for j in range(n)] for q in poses]
    np.testing.assert_allclose(robot.lightest_inertia(poses), np.min(effective, 0), rtol=1e-6)


def test_babbling_gains_are_stable_wherever_the_babbling_goes():
    """The published iiwa 14 (no armature): the baseline's gains ``kd diag M(home)`` make a
    held-torque PD loop unstable (``kd dt lambda_max(M^-1 K_d) >= 2``) at many poses the
    babbling visits; the babbling's own gains keep it below 1 at poses drawn apart from the
    sample they were sized on."""
    robot, kd, dt = _kuka(), 20.0, 0.01
    task = tasks.make(robot, config_lib.TaskConfig(), dt)
    start = np.asarray(task.reference_np.q[0, 0])
    poses = np.asarray(babbling.random_poses(jax.random.key(7), robot, np.tile(start, (200, 1))))

    def number(gain_d):
        return max(
            dt
            * np.abs(
                np.linalg.eigvals(np.linalg.solve(robot.mass_matrix(q), np.diag(gain_d)))
            ).max()
            for q in poses
        )

    assert number(np.asarray(task.gain_d, np.float64)) > 2.0
    assert number(np.asarray(task.babbling_gain_d, np.float64)) < 1.0
    # The baseline keeps its gains; the babbling's copy of the task uses its own.
    babbling_task = task.for_babbling(task.reference)
    np.testing.assert_array_equal(babbling_task.gain_d, task.babbling_gain_d)
    np.testing.assert_array_equal(task.gain_d, np.float32(kd * robot.mass_matrix_diagonal(start)))
    # loop.babbling_gains="baseline" (the babbling before issue 41) gives it the baseline's.
    config = config_lib.Config(
        robot=str(DEV / "kuka_iiwa_14.xml"),
        robot_actuators="torque",
        robot_torque_limit=torque_limit("kuka_iiwa_14"),
    )
    for gains, expected in (("lightest", task.babbling_gain_d), ("baseline", task.gain_d)):
        config = config.replace(loop=config_lib.LoopConfig(babbling_gains=gains))
        knobs = algorithm.Knobs.of(config, robot, task)
        np.testing.assert_array_equal(knobs.task["babbling_gain_d"], expected)


def test_babbling_data_of_a_light_arm_moves_as_its_reaches_do():
    """With the defaults (torque noise of the inertia's scale, the babbling's own gains) the
    published iiwa 14's babbling velocities stay within a few times those of the reaches it
    follows; with noise of the torque limits the wrist is shaken at tens of times them."""

    def spread(torque_scale):
        config = config_lib.Config(
            robot=str(DEV / "kuka_iiwa_14.xml"),
            robot_actuators="torque",
            robot_torque_limit=torque_limit("kuka_iiwa_14"),
            loop=config_lib.LoopConfig(babbling_rollouts=1, torque_scale=torque_scale),
        )
        setup = algorithm.Setup.of(config)
        knobs = algorithm.Knobs.of(config, setup.robot, setup.task)
        key = jax.random.key(0)
        data, _ = algorithm.collected(algorithm.babble_all(setup, key, knobs))
        goals_key = jax.random.fold_in(jax.random.split(key, 1)[0], babbling.GOAL_STREAM)
        reach = setup.task.babbling_reference("reaching", goals_key)
        nq = setup.robot.nq
        moved = np.asarray(data.state)[..., nq:].reshape(-1, nq).std(0)
        return moved / np.asarray(reach.qd).reshape(-1, nq).std(0)

    # Measured: 1.3-5.8 times the reaches' spread with the defaults (the most on joints 1
    # and 3, coaxial at the upright start pose), 81 times on the wrist with the limits' noise.
    assert spread("inertia").max() < 8.0
    assert spread("limit").max() > 40.0


# ---- a model MJX cannot build ------------------------------------------------------------


def test_a_model_mjx_cannot_build_runs_native_and_names_the_pair_on_mjx():
    path = str(HERE / "cylinder_box_arm.xml")
    robot = robots.load(path)  # loads: the native simulator runs it
    assert "CYLINDER" in robot.mjx_error and "BOX" in robot.mjx_error
    found = robot_check.check(path)
    assert "MJX builds it: no (the native simulator runs it)" in found.text
    short = config_lib.TaskConfig(duration=0.1)
    # The default torque scale 'auto' is the coupled one here (pose needs MJX), and says so.
    assert "loop.torque_scale 'auto' gives 'coupled' here (MJX cannot build it" in found.text
    default = Experiment(config_lib.Config(robot=path, task=short))
    assert default.setup.pose_scale is None
    frequency = short.feedback_frequency(short.control_period(robot.timestep))
    np.testing.assert_allclose(np.asarray(default.knobs.torque_scale),
                               robot.coupled_torque_scale(frequency), rtol=1e-6)  # fmt: skip
    table = default.baselines()
    assert np.isfinite(table.tracking_mse).all()
    rigid = config_lib.ForwardModelConfig(kind="rigid_body")
    pose = config_lib.LoopConfig(torque_scale="pose")  # asked for by name: refused
    for changes in ({"simulator": "mjx"}, {"forward": rigid}, {"loop": pose}):
        with pytest.raises(robots.RobotError, match="MJX cannot build.*CYLINDER"):
            Experiment(config_lib.Config(robot=path, task=short, **changes))


def test_an_integrator_mjx_lacks_is_named_with_its_remedy(tmp_path):
    # MuJoCo's 'implicit' integrator (the published Panda's and Sawyer's): MJX implements
    # Euler, RK4 and implicitfast. The error names it and the remedy, and the remedy builds.
    text = (Path(__file__).parent.parent / "robots" / "two_link_arm.xml").read_text()
    for integrator, builds in (("implicit", False), ("implicitfast", True)):
        path = tmp_path / f"{integrator}.xml"
        path.write_text(text.replace('integrator="Euler"', f'integrator="{integrator}"', 1))
        robot = robots.load(str(path))
        assert robot.mj_model.opt.integrator == getattr(
            mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}"
        )
        if builds:
            assert robot.mjx_error is None
        else:
            assert "mjINT_IMPLICIT)" in robot.mjx_error
            assert '<option integrator="implicitfast"/>' in robot.mjx_error


def test_a_model_mjx_builds_but_cannot_step_is_refused_as_one_it_cannot_build(tmp_path):
    # An elliptic friction cone with a frictionless (condim 1) geom, as Menagerie's Unitree
    # Go1 has: mjx.put_model accepts it, and MJX (3.x here) fails only when a step is traced
    # (the oracle: jax.jit(mjx.step) of it raises). Pyramidal, the same model steps.
    from cfm_jax._mjx import mjx

    text = (Path(__file__).parent.parent / "robots" / "two_link_arm.xml").read_text()
    for cone, steps in (("elliptic", False), ("pyramidal", True)):
        path = tmp_path / f"{cone}.xml"
        path.write_text(text.replace("<worldbody>", f'<option cone="{cone}"/>\n<worldbody>', 1)
                        .replace("<geom ", '<geom condim="1" ', 1))  # fmt: skip
        robot = robots.load(str(path))
        assert robot.mj_model.opt.cone == getattr(mujoco.mjtCone, f"mjCONE_{cone.upper()}")
        model = mjx.put_model(robot.mj_model)  # builds either way
        try:
            jax.jit(mjx.step)(model, mjx.make_data(model))
            stepped = True
        except Exception:  # noqa: BLE001  whatever MJX raises
            stepped = False
        assert stepped == steps
        if steps:
            assert robot.mjx_error is None
        else:
            assert "MJX cannot build this model (mjx.step: " in robot.mjx_error
            short = config_lib.TaskConfig(duration=0.1)
            rigid = config_lib.ForwardModelConfig(kind="rigid_body")
            with pytest.raises(robots.RobotError, match=r"\(mjx\.step: "):
                Experiment(config_lib.Config(robot=str(path), task=short, forward=rigid))
