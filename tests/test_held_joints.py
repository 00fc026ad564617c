"""Arms as they come, with joints the controller does not drive (issue 41, item 5).

``tests/gripper_arm.xml``: a two-joint arm with torque motors, a two-finger gripper whose
fingers an equality couples and one position servo moves, and a passive pendulum joint.
The controller drives the two arm joints; the fingers are held by their own servo at the
keyframe's set point, the pendulum swings as published. Checked against MuJoCo C in a
plain loop written here (not the library's stepper): the PD-only baseline's rollout, step
by step, with the gripper's servo given its set point by hand.
"""

from __future__ import annotations

from pathlib import Path

import jax
import mujoco
import numpy as np
import pytest

from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.config import ConfigError
from cfm_jax.sim import robots, rollout
from cfm_jax.tasks import references

ARM = str(Path(__file__).parent / "gripper_arm.xml")
CONTROL_DT = 0.01


@pytest.fixture(scope="module")
def arm():
    return robots.load(ARM)


@pytest.mark.parametrize("actuators", ["strict", "torque"])
def test_the_arm_joints_are_driven_the_fingers_held_the_pendulum_passive(actuators):
    arm = robots.load(ARM, actuators=actuators)
    assert arm.action_dim == 2
    assert arm.actuated_dofs.tolist() == [1, 2] and arm.actuated_qpos.tolist() == [1, 2]
    assert arm.held_joints == ("left_finger", "right_finger")
    assert arm.passive_joints == ("swing",)
    assert not arm.drives_every_dof
    # The gripper's servo is kept as published (a position servo, never converted) and
    # holds the keyframe's set point; the arm's motors start from zero.
    assert arm.converted == ()
    assert int(arm.mj_model.actuator_biastype[2]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
    assert arm.hold_ctrl.tolist() == [0.0, 0.0, 0.02]
    ctrl = np.asarray(arm.torque_to_ctrl(np.array([4.0, -2.0], np.float32)))
    assert ctrl.tolist() == [4.0, -2.0, np.float32(0.02)]


def test_a_held_servo_without_a_torque_limit_is_recorded_as_load_keeps_it(tmp_path):
    # The published I2RT YAM's gripper servo has no forcerange: load() keeps it as published
    # (held), so the run's record of the conversion (robots.conversion, written before any
    # training) must not ask for its limit either; it lists the converted servos only.
    path = tmp_path / "unlimited_gripper.xml"
    path.write_text(Path(ARM).read_text().replace('forcerange="-5 5"', ""))
    assert robots.load(str(path), actuators="torque").held_joints == ARM_HELD
    assert robots.conversion(str(path)) == []  # the arm's motors are motors, the gripper held
    spec = mujoco.MjSpec.from_file(str(path))
    spec.actuators[0].gaintype = mujoco.mjtGain.mjGAIN_FIXED  # a shoulder servo, no limit
    spec.actuators[0].biastype = mujoco.mjtBias.mjBIAS_AFFINE
    spec.actuators[0].biasprm[:3] = [0.0, -30.0, 0.0]
    spec.actuators[0].ctrllimited = 0
    servo = tmp_path / "servo_shoulder.xml"
    servo.write_text(spec.to_xml())
    with pytest.raises(robots.RobotError, match=r"servos of joints \['shoulder'\]"):
        robots.conversion(str(servo))  # a driven servo still needs one


ARM_HELD = ("left_finger", "right_finger")


def _task(arm):
    return tasks.make(arm, config_lib.TaskConfig(duration=0.4), CONTROL_DT)


def test_the_task_sees_the_driven_joints_and_targets_move_only_them(arm):
    task = _task(arm)
    assert (task.state_dim, task.desired_dim, task.output_dim, task.action_dim) == (4, 2, 2, 2)
    entries = task.entries()
    assert entries["state"] == (
        ("position", 1),
        ("position", 2),
        ("velocity", 1),
        ("velocity", 2),
    )
    assert entries["output"] == (("acceleration", 1), ("acceleration", 2))
    goals = task.reference_np.q[:, -1]
    np.testing.assert_array_equal(goals[:, [0, 3, 4]], np.broadcast_to(arm.home[[0, 3, 4]], (5, 3)))
    assert np.all(np.abs(goals[:, [1, 2]] - arm.home[[1, 2]]) > 0.1)
    # The reach is the driven joints' alone (the held ones would dilute it).
    delta = goals[:, [1, 2]] - arm.home[[1, 2]]
    assert task.tracking_scale == pytest.approx(float(np.sqrt(np.mean(delta**2))))


def _plain_pd_loop(task):
    """The PD-only baseline in MuJoCo C, written out: the arm's torques from the task's
    gains at the arm's qpos/qvel entries (1, 2), the gripper servo's ctrl 0.02 as the file's
    keyframe says, the state kept in float32 between control steps (the native stepper's
    convention), each control step from fresh defaults."""
    model = task.robot.mj_model
    n_sub = round(CONTROL_DT / model.opt.timestep)
    gain_p, gain_d = (np.asarray(g, np.float64) for g in (task.gain_p, task.gain_d))
    ref = task.reference_np
    errors, fingers, swing = [], [], []
    for k in range(ref.q.shape[0]):
        qpos = ref.q[k, 0].astype(np.float32)
        qvel = np.zeros(model.nv, np.float32)
        err, fin, sw = [], [], []
        for t in range(ref.steps):
            tau = gain_p * (ref.q[k, t, [1, 2]] - qpos[[1, 2]]) + gain_d * (
                ref.qd[k, t, [1, 2]] - qvel[[1, 2]]
            )
            tau = np.clip(tau, [-40, -20], [40, 20])
            data = mujoco.MjData(model)
            data.qpos[:], data.qvel[:] = qpos, qvel
            data.ctrl[:] = [tau[0], tau[1], 0.02]
            for _ in range(n_sub):
                mujoco.mj_step(model, data)
            qpos, qvel = data.qpos.astype(np.float32), data.qvel.astype(np.float32)
            err.append(qpos[[1, 2]] - ref.q[k, t + 1, [1, 2]])
            fin.append(qpos[[3, 4]])
            sw.append(qpos[0])
        errors.append(err), fingers.append(fin), swing.append(sw)
    return np.array(errors), np.array(fingers), np.array(swing)


def test_pd_only_rollout_equals_a_plain_mujoco_loop(arm):
    task = _task(arm)
    out = rollout.run(task, lambda step, key: task.feedback(step), jax.random.key(0))
    errors, fingers, swing = _plain_pd_loop(task)
    np.testing.assert_allclose(np.asarray(out.tracking_error), errors, rtol=1e-4, atol=1e-6)
    # The servo closes the fingers onto its set point and the equality keeps them together;
    # the pendulum is pushed by the arm's reaction (it moves, as a passive joint does).
    np.testing.assert_allclose(fingers[:, -1], 0.02, atol=2e-3)
    assert np.abs(swing).max() > 0


def test_the_oracle_drives_the_arm_and_beats_pd(arm):
    # Native only: MJX on held joints is checked against native on the published grippers
    # (tests/test_dev_robots.py).
    task = _task(arm)
    oracle = rollout.run(task, task.oracle_policy("native"), jax.random.key(0))
    pd = rollout.run(task, lambda step, key: task.feedback(step), jax.random.key(0))
    oracle_mse = float(np.mean(rollout.tracking_mse(oracle)))
    pd_mse = float(np.mean(rollout.tracking_mse(pd)))
    assert np.isfinite(oracle_mse) and oracle_mse < 1e-3 * pd_mse, (oracle_mse, pd_mse)


def test_tasks_that_need_every_joint_name_the_held_ones(arm):
    with pytest.raises(ConfigError, match=r"left_finger.*right_finger.*swing"):
        tasks.make(arm, config_lib.TaskConfig(name="opspace", duration=0.4), CONTROL_DT)


def test_an_arm_with_no_driven_joint_is_refused(tmp_path):
    path = tmp_path / "only_fingers.xml"
    text = Path(ARM).read_text()
    text = text.replace(
        '<motor name="shoulder" joint="shoulder" ctrlrange="-40 40" ctrllimited="true"/>', ""
    )
    text = text.replace(
        '<motor name="elbow" joint="elbow" ctrlrange="-20 20" ctrllimited="true"/>', ""
    )
    text = text.replace('ctrl="0 0 0.02"', 'ctrl="0.02"')
    path.write_text(text)
    with pytest.raises(robots.RobotError, match="no joint is driven by a torque motor"):
        robots.load(str(path))


def test_default_targets_keep_held_joints_at_a_user_home(arm):
    home = arm.home.copy()
    home[3:] = 0.01
    ref = references.reaching(arm, config_lib.TaskConfig(duration=0.4, home=tuple(home)), 0.01)
    np.testing.assert_array_equal(ref.q[:, -1, 3:], 0.01)
