"""Robot loading and checks (cfm_jax/sim/robots.py).

Oracles: small MJCF strings written here with known joints/actuators, and MuJoCo's C engine
(``mj_fullM``) for the mass matrix. The physics numbers of the shipped XML files are tested
in tests/test_robot_models.py, not here.
"""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from cfm_jax import tasks
from cfm_jax.analysis import robot_check
from cfm_jax.config import ConfigError, TaskConfig
from cfm_jax.sim import robots
from cfm_jax.sim.robots import RobotError

ROBOT_DIR = Path(__file__).resolve().parents[1] / "robots"


def mjcf(body: str, actuators: str, option: str = "") -> str:
    return f"""<mujoco model="test">
  <compiler angle="radian" autolimits="true"/>
  {option}
  <worldbody>{body}</worldbody>
  <actuator>{actuators}</actuator>
</mujoco>"""


TWO_HINGES = """
<body name="a"><joint name="j1" type="hinge" axis="0 1 0" range="-1 1"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1"/>
  <body name="b" pos="0.3 0 0"><joint name="j2" type="slide" axis="1 0 0"/>
    <geom type="sphere" size="0.05" mass="0.5"/></body>
</body>"""


def write(tmp_path, text, name="robot.xml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# ---- loading ---------------------------------------------------------------------------------


def test_registered_robots():
    assert set(robots.registered()) >= {"iiwa14", "two_link_arm"}


@pytest.mark.parametrize("name, nv", [("iiwa14", 7), ("two_link_arm", 2)])
def test_load_by_name_and_by_path_agree(name, nv):
    by_name = robots.load(name)
    by_path = robots.load(str(ROBOT_DIR / f"{name}.xml"))
    for robot in (by_name, by_path):
        assert robot.name == name
        assert robot.nq == robot.nv == nv
        assert robot.state_dim == 2 * nv
        assert robot.timestep == 0.002
        assert Path(robot.path).is_absolute()
    np.testing.assert_array_equal(by_name.torque_limit, by_path.torque_limit)
    np.testing.assert_array_equal(by_name.joint_range, by_path.joint_range)
    np.testing.assert_array_equal(by_name.home, by_path.home)
    assert by_name.joint_names == by_path.joint_names


def test_two_link_arm_fields_from_its_xml():
    # Numbers typed from robots/two_link_arm.xml: ctrlrange 20 / 10, range +-2.5, key "home".
    robot = robots.load("two_link_arm")
    assert robot.joint_names == ("shoulder", "elbow")
    np.testing.assert_array_equal(robot.torque_limit, [20.0, 10.0])
    np.testing.assert_array_equal(robot.joint_range, [[-2.5, 2.5], [-2.5, 2.5]])
    np.testing.assert_allclose(robot.home, [-0.785398, 1.570796])
    np.testing.assert_array_equal(robot.gear, [1.0, 1.0])


def test_timestep_override():
    robot = robots.load("two_link_arm", timestep=0.001)
    assert robot.timestep == 0.001
    # the override must not leak into another load of the same file
    assert robots.load("two_link_arm").timestep == 0.002


def test_user_file_fields(tmp_path):
    # ctrlrange and forcerange both given: the torque limit is the smaller one;
    # unlimited slide joint: range (-inf, inf); no keyframe: home = qpos0 (0 for both).
    path = write(
        tmp_path,
        mjcf(
            TWO_HINGES,
            '<motor name="m2" joint="j2" gear="2" ctrlrange="-3 3" forcerange="-5 5"/>'
            '<motor name="m1" joint="j1" ctrlrange="-4 4"/>',
        ),
        "my_arm.xml",
    )
    robot = robots.load(path)
    assert robot.name == "my_arm"
    assert robot.joint_names == ("j1", "j2")
    np.testing.assert_array_equal(robot.actuator_of_joint, [1, 0])  # actuators listed reversed
    np.testing.assert_array_equal(robot.gear, [1.0, 2.0])
    # j1: ctrl 4 * gear 1 = 4; j2: min(ctrl 3, force 5) * gear 2 = 6 (MuJoCo clamps the
    # actuator's force, then applies the gear: test_torque_limit_is_what_mujoco_applies)
    np.testing.assert_array_equal(robot.torque_limit, [4.0, 6.0])
    np.testing.assert_array_equal(robot.joint_range, [[-1.0, 1.0], [-np.inf, np.inf]])
    np.testing.assert_array_equal(robot.home, [0.0, 0.0])


def test_torque_to_ctrl_with_gear(tmp_path):
    # ctrl = tau / gear, placed at the joint's actuator index.
    path = write(
        tmp_path,
        mjcf(
            TWO_HINGES,
            '<motor name="m2" joint="j2" gear="4" ctrlrange="-10 10"/>'
            '<motor name="m1" joint="j1" gear="0.5" ctrlrange="-10 10"/>',
        ),
    )
    robot = robots.load(path)
    tau = jnp.array([[1.0, 2.0], [-3.0, 8.0]])  # (batch, nv) in joint order j1, j2
    ctrl = jax.jit(robot.torque_to_ctrl)(tau)
    # actuator 0 drives j2 (gear 4), actuator 1 drives j1 (gear 0.5)
    np.testing.assert_array_equal(np.asarray(ctrl), [[0.5, 2.0], [2.0, -6.0]])
    # torque limit = ctrlrange * |gear|
    np.testing.assert_array_equal(robot.torque_limit, [5.0, 40.0])
    # And MuJoCo C turns that ctrl (inside ctrlrange) into exactly tau on each dof.
    data = mujoco.MjData(robot.mj_model)
    data.ctrl[:] = np.asarray(ctrl[0])
    mujoco.mj_forward(robot.mj_model, data)
    np.testing.assert_allclose(data.qfrc_actuator, [1.0, 2.0], rtol=1e-12)


LIMITED_HINGE = """
<body name="a"><joint name="j1" type="hinge" axis="0 1 0" {joint}/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1"/>
</body>"""


@pytest.mark.parametrize(
    "joint, motor, source",
    [
        ("", 'gear="2" forcerange="-5 5"', "forcerange"),
        ("", 'gear="-3" ctrlrange="-4 4" forcerange="-5 5"', "ctrlrange"),
        ("", 'gear="0.5" ctrlrange="-40 40" forcerange="-5 5"', "forcerange"),
        ('actuatorfrcrange="-3 3"', 'gear="2" forcerange="-5 5"', "actuatorfrcrange"),
        ('actuatorfrcrange="-30 30"', 'gear="2" forcerange="-5 5"', "forcerange"),
        ('actuatorfrcrange="-7 7"', "", "actuatorfrcrange"),
    ],
)
def test_torque_limit_is_what_mujoco_applies(tmp_path, joint, motor, source):
    # Oracle: MuJoCo C's joint torque for a control far beyond every bound, either sign
    # (the motor's force is clamped to ctrlrange and forcerange, then times the gear; the
    # joint's actuatorfrcrange clamps the sum). It used to forget the gear on forcerange and
    # the joint's bound.
    path = write(tmp_path, mjcf(LIMITED_HINGE.format(joint=joint), f'<motor joint="j1" {motor}/>'))
    robot = robots.load(path)
    data = mujoco.MjData(robot.mj_model)
    for sign in (1.0, -1.0):
        data.ctrl[:] = sign * 1e6
        mujoco.mj_forward(robot.mj_model, data)
        assert abs(data.qfrc_actuator[0]) == pytest.approx(robot.torque_limit[0], rel=1e-12)
    assert robot.limit_source[0] == source


@pytest.mark.parametrize(
    "joint, servo",
    [
        ("", 'gear="2" kp="1000" forcerange="-5 5"'),
        ('actuatorfrcrange="-3 3"', 'gear="2" kp="1000" forcerange="-5 5"'),
        ('actuatorfrcrange="-3 3"', 'kp="1000"'),
    ],
)
def test_servo_torque_limit_is_what_mujoco_applies(tmp_path, joint, servo):
    # A position servo far from its target pushes with the most torque MuJoCo lets it: the
    # converted motor's limit is that torque (both bounds where both are given).
    model = mujoco.MjModel.from_xml_string(
        mjcf(LIMITED_HINGE.format(joint=joint), f'<position joint="j1" {servo}/>')
    )
    data = mujoco.MjData(model)
    data.ctrl[:] = 100.0
    mujoco.mj_forward(model, data)
    limits = robots.servo_limits(model)
    assert limits[0][1] == pytest.approx(abs(data.qfrc_actuator[0]), rel=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "two_link_arm"])
def test_mass_matrix_diagonal_matches_mj_fullM(name):
    robot = robots.load(name)
    rng = np.random.default_rng(0)
    low = np.where(np.isfinite(robot.joint_range[:, 0]), robot.joint_range[:, 0], -1.0)
    high = np.where(np.isfinite(robot.joint_range[:, 1]), robot.joint_range[:, 1], 1.0)
    for _ in range(3):
        q = rng.uniform(low, high)
        # Oracle: a fresh MjData, mj_forward, then column i of M is mj_mulM(M, e_i) (a
        # different C code path from the library's mj_fullM) and the diagonal is e_i' M e_i.
        data = mujoco.MjData(robot.mj_model)
        data.qpos[:] = q
        mujoco.mj_forward(robot.mj_model, data)
        diag = np.zeros(robot.nv)
        for i in range(robot.nv):
            unit, column = np.zeros(robot.nv), np.zeros(robot.nv)
            unit[i] = 1.0
            mujoco.mj_mulM(robot.mj_model, data, column, unit)
            diag[i] = column[i]
        # float64 products with a unit vector are exact sums of the same terms: 1e-12 rel.
        np.testing.assert_allclose(robot.mass_matrix_diagonal(q), diag, rtol=1e-12)
        # and the dense matrix from mj_fullM agrees, as documented
        dense = np.zeros((robot.nv, robot.nv))
        mujoco.mj_fullM(robot.mj_model, data, dense)
        np.testing.assert_array_equal(robot.mass_matrix_diagonal(q), np.diag(dense))


def test_mass_matrix_diagonal_two_link_closed_form():
    # Planar two-link arm: M11 = I1 + I2 + m2 l1^2 + 2 m2 l1 c2 cos q2 + arm, M22 = I2 + arm,
    # so M11(q2) - M11(q2') = 2 m2 l1 c2 (cos q2 - cos q2'), m2 = 0.8, l1 = 0.5, c2 = 0.2.
    robot = robots.load("two_link_arm")
    m_a = robot.mass_matrix_diagonal(np.array([0.3, 0.0]))
    m_b = robot.mass_matrix_diagonal(np.array([-1.0, np.pi / 2]))
    np.testing.assert_allclose(m_a[0] - m_b[0], 2 * 0.8 * 0.5 * 0.2 * (1.0 - 0.0), rtol=1e-9)
    np.testing.assert_allclose(m_a[1], m_b[1], rtol=1e-12)  # M22 independent of q


# ---- errors ----------------------------------------------------------------------------------


def test_nonexistent_path(tmp_path):
    missing = str(tmp_path / "nope.xml")
    with pytest.raises(RobotError) as info:
        robots.load(missing)
    message = str(info.value)
    assert repr(missing) in message and "no such MJCF file" in message
    assert "iiwa14" in message  # lists the registered names as the alternative


def test_unknown_registered_name():
    with pytest.raises(RobotError) as info:
        robots.load("anymal")
    message = str(info.value)
    assert "'anymal' is not a registered robot" in message
    assert str(robots.registered()) in message
    assert "iiwa14" in message and "two_link_arm" in message


def test_mjcf_that_does_not_parse(tmp_path):
    path = write(tmp_path, "<mujoco><worldbody><body></worldbody></mujoco>")
    with pytest.raises(RobotError, match="does not parse"):
        robots.load(path)


@pytest.mark.parametrize(
    "change, found",
    [
        (('mass="1"', 'mass="nan"'), "in the file (MuJoCo: 'XML contains a NaN')"),
        (('range="-1 1"', 'range="-1 1" damping="inf"'), "in ['dof_damping']"),
        (('mass="0.5"', 'mass="0.5" pos="0 0 inf"'), "in ["),
    ],
)
def test_a_model_with_nan_or_inf_is_refused(tmp_path, capfd, change, found):
    # MuJoCo compiles all three (mass="nan" takes the density's mass and only warns), so
    # the model would train; the loader refuses them, naming what it found.
    text = mjcf(
        TWO_HINGES, '<motor joint="j1" ctrlrange="-1 1"/><motor joint="j2" ctrlrange="-1 1"/>'
    )
    assert change[0] in text
    path = write(tmp_path, text.replace(change[0], change[1], 1))
    mujoco.MjModel.from_xml_path(path)  # MuJoCo's compiler accepts it
    with pytest.raises(RobotError, match="NaN or infinite values " + re.escape(found)):
        robots.load(path)
    assert mujoco.get_mju_user_warning() is None  # MuJoCo's warning handler put back
    capfd.readouterr()
    robots.load(write(tmp_path, text, "sound.xml"))  # the same model with finite numbers


def test_mjcf_with_unknown_joint_reference(tmp_path):
    path = write(tmp_path, mjcf(TWO_HINGES, '<motor joint="nope" ctrlrange="-1 1"/>'))
    with pytest.raises(RobotError, match="does not parse"):
        robots.load(path)


def test_no_actuators(tmp_path):
    path = write(tmp_path, mjcf(TWO_HINGES, ""))
    with pytest.raises(RobotError, match="has no actuators"):
        robots.load(path)


def test_position_actuator_rejected(tmp_path):
    path = write(
        tmp_path,
        mjcf(
            TWO_HINGES,
            '<motor joint="j1" ctrlrange="-1 1"/>'
            '<position name="servo" joint="j2" kp="10" ctrlrange="-1 1"/>',
        ),
    )
    with pytest.raises(RobotError) as info:
        robots.load(path)
    message = str(info.value)
    assert "actuator 'servo' is not a torque motor" in message


def test_velocity_actuator_rejected(tmp_path):
    path = write(
        tmp_path,
        mjcf(
            TWO_HINGES,
            '<velocity name="vel" joint="j1" kv="3" ctrlrange="-1 1"/>'
            '<motor joint="j2" ctrlrange="-1 1"/>',
        ),
    )
    with pytest.raises(RobotError, match="actuator 'vel' is not a torque motor"):
        robots.load(path)


FLOATING = """
<body name="base"><freejoint name="root"/><geom type="box" size="0.1 0.1 0.1" mass="1"/>
  <body name="leg"><joint name="hip" axis="0 1 0"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.2"/>
    <body name="shin" pos="0 0 -0.3"><joint name="knee" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.2"/></body></body>
</body>"""


def test_floating_base_loads_with_its_joints_actuated_and_arm_tasks_refuse_it(tmp_path):
    motors = '<motor joint="knee" gear="2" ctrlrange="-1 1"/><motor joint="hip" ctrlrange="-3 3"/>'
    robot = robots.load(write(tmp_path, mjcf(FLOATING, motors)))
    assert robot.floating_base and (robot.nq, robot.nv, robot.action_dim) == (9, 8, 2)
    np.testing.assert_array_equal(robot.actuated_dofs, [6, 7])  # after the 6 base dofs
    np.testing.assert_array_equal(robot.torque_limit, [3.0, 2.0])  # hip, knee (2 x 1)
    np.testing.assert_array_equal(robot.actuator_of_joint, [1, 0])
    ctrl = np.asarray(robot.torque_to_ctrl(np.array([1.5, 1.0])))
    np.testing.assert_allclose(ctrl, [0.5, 1.5])  # knee: 1 N m / gear 2; hip: 1.5
    for name in ("inverse_dynamics", "opspace"):
        with pytest.raises(ConfigError, match=f"task.name='{name}' .* floating base"):
            tasks.make(robot, TaskConfig(name=name), 0.01)


def test_second_free_joint_or_actuated_base_rejected(tmp_path):
    # (MuJoCo itself refuses free joints below the top level; a second free body is ours
    # to refuse.)
    nested = """
<body name="a"><joint name="j1" axis="0 1 0"/><geom type="sphere" size="0.05" mass="1"/></body>
<body name="b" pos="0.5 0 0"><freejoint name="loose"/>
  <geom type="sphere" size="0.05" mass="1"/></body>"""
    path = write(tmp_path, mjcf(nested, '<motor joint="j1" ctrlrange="-1 1"/>'))
    with pytest.raises(RobotError, match="joint 'loose' is .*FREE.*floating base"):
        robots.load(path)
    motors = '<motor joint="root" ctrlrange="-1 1"/><motor joint="hip" ctrlrange="-1 1"/>'
    motors += '<motor joint="knee" ctrlrange="-1 1"/>'
    with pytest.raises(RobotError, match="floating base .* cannot be actuated"):
        robots.load(write(tmp_path, mjcf(FLOATING, motors)))


def test_ball_joint_rejected(tmp_path):
    body = """
<body name="a"><joint name="j1" axis="0 1 0"/><geom type="sphere" size="0.05" mass="1"/>
  <body name="b" pos="0.2 0 0"><joint name="wrist" type="ball"/>
    <geom type="sphere" size="0.05" mass="1"/></body>
</body>"""
    path = write(tmp_path, mjcf(body, '<motor joint="j1" ctrlrange="-1 1"/>'))
    with pytest.raises(RobotError, match="joint 'wrist' is .*BALL"):
        robots.load(path)


def test_joint_without_motor_is_passive_and_named(tmp_path):
    # A joint with no actuator and no coupling is left passive (not trained), and
    # `robot check` says so with a warning; tasks that need every joint refuse it.
    path = write(tmp_path, mjcf(TWO_HINGES, '<motor joint="j1" ctrlrange="-1 1"/>'))
    robot = robots.load(path)
    assert robot.passive_joints == ("j2",) and robot.action_dim == 1
    assert robot.actuated_dofs.tolist() == [0]
    text = robot_check.check(path).text
    assert "! passive joints: j2" in text


def test_joint_with_two_motors(tmp_path):
    path = write(
        tmp_path,
        mjcf(
            TWO_HINGES,
            '<motor joint="j1" ctrlrange="-1 1"/><motor joint="j1" ctrlrange="-1 1"/>'
            '<motor joint="j2" ctrlrange="-1 1"/>',
        ),
    )
    with pytest.raises(RobotError, match="driven by more than one actuator"):
        robots.load(path)


def test_motor_without_torque_limit(tmp_path):
    path = write(
        tmp_path,
        mjcf(TWO_HINGES, '<motor joint="j1" ctrlrange="-1 1"/><motor joint="j2"/>'),
    )
    with pytest.raises(RobotError, match=r"motors of joints \['j2'\] have no torque limit"):
        robots.load(path)


def test_shipped_robots_found_from_a_checkout_without_package_data(monkeypatch):
    # Python started inside a clone imports cfm_jax from the clone, where the package-data
    # module cfm_jax._robot_files (mapped from robots/ at install time) does not exist.
    # Simulated here whatever the install: no package data, module file inside the clone.
    from cfm_jax import _shipped

    monkeypatch.setattr(_shipped, "ROBOT_PACKAGE", "cfm_jax._no_such_module")
    monkeypatch.setattr(_shipped, "__file__", str(ROBOT_DIR.parent / "cfm_jax" / "_shipped.py"))
    assert {"iiwa14", "two_link_arm"} <= set(robots.registered())
    assert robots.resolve("iiwa14") == str(ROBOT_DIR / "iiwa14.xml")


def test_robot_check_warns_of_ranges_read_in_degrees(tmp_path):
    # A home-made file without <compiler angle="radian"/>: MuJoCo reads range="-1 1" as
    # +-1 degree (0.035 rad), and the reaches are drawn inside it. The check says so; the same
    # file with the compiler line, and every robot shipped or in the development set, does not.
    body = TWO_HINGES.replace('type="slide" axis="1 0 0"', 'type="hinge" axis="0 1 0" range="-1 1"')
    actuators = '<motor joint="j1" ctrlrange="-1 1"/><motor joint="j2" ctrlrange="-1 1"/>'
    radians = mjcf(body, actuators)
    degrees = radians.replace(
        '<compiler angle="radian" autolimits="true"/>', '<compiler autolimits="true"/>'
    )
    assert degrees != radians
    text = robot_check.check(write(tmp_path, degrees, "degrees.xml")).text
    warned = [line for line in text.splitlines() if "reads angles in degrees" in line]
    assert len(warned) == 1 and "0.0349 rad = 2 degrees" in warned[0]
    assert "reads angles in degrees" not in robot_check.check(write(tmp_path, radians)).text
    dev = Path(__file__).resolve().parent / "robots"
    for name in [*robots.registered(), *sorted(str(p) for p in dev.glob("*.xml"))]:
        model = robots.compile_file(robots.resolve(name))
        assert robot_check.degrees_trap(model, robots.resolve(name)) is None, name
