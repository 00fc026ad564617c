"""Servo robots (issue 28): ``robot_actuators="torque"`` replaces each joint servo by a
torque motor. Oracle: the same arm edited by hand into ``<motor>`` elements, simulated by
MuJoCo C (and the closed-loop baselines on the native simulator)."""

import json
import sys

import jax
import mujoco
import numpy as np
import pytest

from cfm_jax import cli, config, tasks
from cfm_jax.analysis import report
from cfm_jax.learning import rigid_body
from cfm_jax.sim import robots, rollout
from cfm_jax.sim.robots import RobotError
from cfm_jax.tasks import references

# A vertical two-link arm under gravity with damping, armature, friction loss, joint ranges
# and the implicitfast integrator (as Menagerie's arms); ACTUATORS and KEY are filled in.
ARM = """
<mujoco model="servo_arm">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast"/>
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="-2 2" damping="2"
             armature="0.1" frictionloss="0.3" {frc1}/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.04" mass="1.5"/>
      <body name="fore" pos="0.5 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" range="-2.5 2.5" damping="0.5"
               armature="0.05" {frc2}/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="0.8"/>
        <site name="attachment_site" pos="0.4 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>{actuators}</actuator>
  <keyframe><key name="home" qpos="0.3 -0.6" {key}/></keyframe>
</mujoco>
"""


def arm(tmp_path, actuators, key="", frc1="", frc2="", name="arm.xml"):
    path = tmp_path / name
    path.write_text(ARM.format(actuators=actuators, key=key, frc1=frc1, frc2=frc2))
    return str(path)


POSITION = (
    '<position name="a1" joint="shoulder" kp="300" kv="20" forcerange="-40 40" '
    'ctrlrange="-2 2"/>'
    '<position name="a2" joint="elbow" kp="100" gear="2" forcerange="-10 10"/>'
)
# The same arm edited by hand: each servo a motor on its joint and gear with the servo's
# force range as its control range (MuJoCo clamps the actuator force, before the gear, to
# forcerange: the elbow's joint torque limit is 2 x 10 = 20 N m).
POSITION_BY_HAND = (
    '<motor joint="shoulder" ctrlrange="-40 40" forcerange="-40 40"/>'
    '<motor joint="elbow" gear="2" ctrlrange="-10 10"/>'
)
VELOCITY = '<velocity joint="shoulder" kv="30"/><velocity joint="elbow" kv="10"/>'
VELOCITY_BY_HAND = (
    '<motor joint="shoulder" ctrlrange="-25 25"/><motor joint="elbow" ctrlrange="-8 8"/>'
)
# Menagerie's iiwa servo: an affine-bias general actuator with no limit anywhere.
GENERAL = (
    '<general joint="shoulder" gainprm="2000" biastype="affine" biasprm="0 -2000 -200"/>'
    '<general joint="elbow" gainprm="500" biastype="affine" biasprm="0 -500 -50"/>'
)
GENERAL_BY_HAND = (
    '<motor joint="shoulder" ctrlrange="-30 30"/><motor joint="elbow" ctrlrange="-12 12"/>'
)


def ctrl_of(robot, tau):
    ctrl = np.zeros(robot.mj_model.nu)
    ctrl[robot.actuator_of_joint] = tau / robot.gear
    return ctrl


def qacc(model, qpos, qvel, ctrl):
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    mujoco.mj_forward(model, data)
    return data.qacc.copy()


CASES = {
    "position": (dict(actuators=POSITION), POSITION_BY_HAND, None, [40.0, 20.0],
                 ("forcerange", "forcerange"), ("position", "position")),
    "velocity": (dict(actuators=VELOCITY, frc1='actuatorfrcrange="-25 25"',
                      frc2='actuatorfrcrange="-8 8"'),
                 VELOCITY_BY_HAND, None, [25.0, 8.0],
                 ("actuatorfrcrange", "actuatorfrcrange"), ("velocity", "velocity")),
    "general": (dict(actuators=GENERAL), GENERAL_BY_HAND, (30.0, 12.0), [30.0, 12.0],
                ("robot_torque_limit", "robot_torque_limit"), ("position", "position")),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CASES))
def test_converted_servos_match_motors_edited_by_hand(tmp_path, case):
    kwargs, by_hand, user, limits, sources, kinds = CASES[case]
    servo = robots.load(arm(tmp_path, **kwargs), actuators="torque", torque_limit=user)
    frc = {k: v for k, v in kwargs.items() if k.startswith("frc")}
    hand = robots.load(arm(tmp_path, by_hand, name="hand.xml", **frc))
    assert servo.torque_limit.tolist() == limits == hand.torque_limit.tolist()
    assert servo.limit_source == sources and [k for _, k in servo.converted] == list(kinds)
    assert servo.gear.tolist() == hand.gear.tolist()
    # The joints, options and integrator are untouched.
    a, b = servo.mj_model, hand.mj_model
    for field in ("dof_damping", "dof_armature", "dof_frictionloss", "jnt_range"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.opt.integrator == int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST) == b.opt.integrator
    assert a.na == 0 and servo.home.tolist() == [0.3, -0.6]
    rng = np.random.default_rng(0)
    for _ in range(20):
        qpos = rng.uniform(-1.5, 1.5, 2)
        qvel = rng.normal(0, 2, 2)
        tau = rng.uniform(-1, 1, 2) * servo.torque_limit
        np.testing.assert_array_equal(
            qacc(a, qpos, qvel, ctrl_of(servo, tau)), qacc(b, qpos, qvel, ctrl_of(hand, tau))
        )


def baselines_match(tmp_path, simulator):
    """PD-only and oracle rollouts of the converted arm and of the arm by hand agree."""
    servo = robots.load(arm(tmp_path, POSITION), actuators="torque")
    hand = robots.load(arm(tmp_path, POSITION_BY_HAND, name="hand.xml"))
    ref = references.quintic(servo.home, servo.home + 0.2, duration=0.1, control_dt=0.01)
    outs = []
    for robot in (servo, hand):
        task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
        oracle = rollout.run(task, task.oracle_policy(simulator), jax.random.key(0), simulator)
        pd = rollout.run(task, lambda step, key, t=task: t.feedback(step), jax.random.key(0),
                         simulator)  # fmt: skip
        outs.append((oracle.tracking_error, pd.tracking_error))
    for x, y in zip(outs[0], outs[1], strict=True):
        assert np.all(np.isfinite(np.asarray(x)))
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    return servo


# MJX: 25 s on 2 busy cores (four rollout programs compiled), in the default run: the
# conversion must hold on both simulators (issue 28).
def test_baselines_on_a_converted_arm_match_the_arm_by_hand_mjx(tmp_path):
    baselines_match(tmp_path, "mjx")


def test_baselines_on_a_converted_arm_match_the_arm_by_hand(tmp_path):
    servo = baselines_match(tmp_path, "native")
    # The rigid-body model (and any other copy built from the file) sees the converted model.
    nominal = rigid_body.nominal_model(servo)
    assert nominal.actuator_biastype.tolist() == [0, 0]
    assert nominal.actuator_ctrlrange.tolist() == servo.mj_model.actuator_ctrlrange.tolist()


def test_strict_default_names_the_option(tmp_path):
    with pytest.raises(RobotError, match="robot_actuators='torque'"):
        robots.load(arm(tmp_path, POSITION))


def test_servo_without_a_limit_names_joints_and_the_three_ways(tmp_path):
    path = arm(tmp_path, GENERAL)
    with pytest.raises(RobotError) as info:
        robots.load(path, actuators="torque")
    message = str(info.value)
    for needed in ("'shoulder'", "'elbow'", "forcerange", "actuatorfrcrange", "robot_torque_limit"):
        assert needed in message
    # One number for all joints; a wrong count is an error naming the joints.
    assert robots.load(path, actuators="torque", torque_limit=(7.0,)).torque_limit.tolist() == [
        7.0,
        7.0,
    ]
    with pytest.raises(RobotError, match="one per joint"):
        robots.load(path, actuators="torque", torque_limit=(1.0, 2.0, 3.0))


def test_limit_order_forcerange_then_joint_then_user(tmp_path):
    actuators = (
        '<position joint="shoulder" kp="50" forcerange="-5 5"/><position joint="elbow" kp="50"/>'
    )
    robot = robots.load(
        arm(tmp_path, actuators, frc1='actuatorfrcrange="-9 9"', frc2='actuatorfrcrange="-3 3"'),
        actuators="torque",
        torque_limit=(100.0,),
    )
    assert robot.torque_limit.tolist() == [5.0, 3.0]
    assert robot.limit_source == ("forcerange", "actuatorfrcrange")


def test_intvelocity_and_keyframe_ctrl(tmp_path):
    actuators = (
        '<intvelocity joint="shoulder" kp="100" actrange="-2 2" forcerange="-20 20"/>'
        '<motor joint="elbow" ctrlrange="-5 5"/>'
    )
    path = arm(tmp_path, actuators, key='ctrl="0.3 1.0" act="0.3"')
    robot = robots.load(path, actuators="torque")
    model = robot.mj_model
    assert model.na == 0 and robot.converted == (("#0", "intvelocity"),)
    assert model.key_ctrl[0].tolist() == [0.0, 1.0]  # the servo's set point dropped
    assert robot.limit_source == ("forcerange", "ctrlrange")
    # A keyframe written for servos since removed (ctrl of 3 for 2 motors) still loads.
    stale = arm(tmp_path, POSITION_BY_HAND, key='ctrl="0 0 0"', name="stale.xml")
    assert robots.load(stale).home.tolist() == [0.3, -0.6]


def test_non_joint_transmission_says_why(tmp_path):
    actuators = '<general site="attachment_site" gear="1 0 0 0 0 0"/><motor joint="elbow"/>'
    with pytest.raises(RobotError, match="site transmission; every actuator must drive one"):
        robots.load(arm(tmp_path, actuators), actuators="torque")


def test_config_protocol_and_setup(tmp_path):
    path = arm(tmp_path, GENERAL)
    cfg = config.Config(
        robot=path,
        robot_actuators="torque",
        robot_torque_limit=(30.0, 12.0),
        task=config.TaskConfig(duration=0.1),
    )
    assert config.from_dict(config.to_dict(cfg)) == cfg
    assert config.Config(robot_torque_limit=5).robot_torque_limit == (5.0,)
    for bad in (dict(robot_actuators="servo"), dict(robot_torque_limit=(1.0, -2.0))):
        with pytest.raises(config.ConfigError, match=next(iter(bad))):
            config.Config(**bad)
    line = report.protocol(cfg)
    assert "shoulder 30 (position, robot_torque_limit)" in line
    assert "elbow 12 (position, robot_torque_limit)" in line
    assert "robot_actuators" not in report.protocol(config.Config())
    # config.json (report.config_record, what train, the CLI and sweeps write) records the
    # conversion and each limit's source; reading it back gives the same config.
    record = report.config_record(cfg)
    assert record["robot_conversion"] == [
        {"joint": "shoulder", "servo": "position", "torque_limit": 30.0,
         "source": "robot_torque_limit"},
        {"joint": "elbow", "servo": "position", "torque_limit": 12.0,
         "source": "robot_torque_limit"},
    ]  # fmt: skip
    assert config.from_dict(json.loads(json.dumps(record))) == cfg
    forcerange = config.Config(robot=arm(tmp_path, POSITION, name="p.xml"),
                               robot_actuators="torque")  # fmt: skip
    assert [(c["joint"], c["torque_limit"], c["source"])
            for c in report.config_record(forcerange)["robot_conversion"]] == [
        ("shoulder", 40.0, "forcerange"), ("elbow", 20.0, "forcerange")]  # fmt: skip
    assert "robot_conversion" not in report.config_record(config.Config())


def robot_check(argv, monkeypatch, capsys):
    """``cfm-jax robot check ARGV`` in-process: (exit status, printed text)."""
    monkeypatch.setattr(sys, "argv", ["cfm-jax", "robot", "check", *argv])
    try:
        cli.main()
        status = 0
    except SystemExit as stop:
        status = stop.code
    return status, capsys.readouterr().out


def test_robot_check_on_a_servo_arm(tmp_path, monkeypatch, capsys):
    path = arm(tmp_path, POSITION, frc2='actuatorfrcrange="-8 8"')
    status, text = robot_check([path], monkeypatch, capsys)
    assert status == 1
    assert "a1: position servo on shoulder; as a torque motor: torque limit 40 (forcerange)" in text
    # The joint's actuatorfrcrange (8 N m) binds before the actuator's forcerange (2 x 10 =
    # 20 N m): MuJoCo clamps both (test_robots.test_servo_torque_limit_is_what_mujoco_applies).
    assert (
        "a2: position servo on elbow; as a torque motor: torque limit 8 (actuatorfrcrange)" in text
    )
    assert "loads with robot_actuators='strict': no" in text
    assert "with robot_actuators='torque' it loads" in text
    status, text = robot_check([path, "--robot-actuators", "torque"], monkeypatch, capsys)
    assert status == 0
    lines = text.splitlines()
    assert "  shoulder: hinge, range [-2, 2]" in lines
    assert "floating base: no" in lines and "sites: attachment_site" in lines
    assert "  inverse_dynamics: yes" in lines
    assert "  opspace: yes (site 'attachment_site')" in lines
    assert lines[-1].startswith("  jump: no: the legged tasks need a floating base")
    status, text = robot_check([arm(tmp_path, GENERAL), "--robot-actuators", "torque"],
                               monkeypatch, capsys)  # fmt: skip
    assert status == 1 and "no torque limit found" in text
    status, text = robot_check(
        [arm(tmp_path, GENERAL), "--robot-actuators", "torque", "--robot-torque-limit", "9"],
        monkeypatch,
        capsys,
    )
    assert status == 0 and "torque limit 9 (robot_torque_limit)" in text


@pytest.mark.parametrize(
    ("name", "status", "expected"),
    [
        ("two_link_arm", 0, ["  opspace: no: task.site=None", "  inverse_dynamics: yes"]),
        ("iiwa14", 0, ["  opspace: yes (site 'flange')", "  joint7: motor on joint7, torque "
                       "limit 40 (ctrlrange)"]),
        ("solo12", 1, ["floating base: yes", "  walk: yes", "  jump: yes",
                       "  inverse_dynamics: no: task.name='inverse_dynamics' is not allowed"]),
    ],
)  # fmt: skip
def test_robot_check_on_the_shipped_robots(name, status, expected, monkeypatch, capsys):
    got, text = robot_check([name], monkeypatch, capsys)
    assert got == status
    for line in expected:
        assert any(out.startswith(line) for out in text.splitlines()), line


def test_cli_flags_reach_the_config(monkeypatch, capsys):
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "cfm-jax",
            "config",
            "--robot",
            "two_link_arm",
            "--robot-actuators",
            "torque",
            "--robot-torque-limit",
            "3",
            "4",
        ],  # fmt: skip
    )
    cli.main()
    printed = json.loads(capsys.readouterr().out)
    assert printed["robot_actuators"] == "torque" and printed["robot_torque_limit"] == [3.0, 4.0]
