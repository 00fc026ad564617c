"""Cartesian references of the operational-space task (cfm_jax/tasks/references.py): quintic
straight lines of the end-effector site, default targets, the reach check, and the desired
acceleration for a site.

Oracles: closed forms of the quintic; the two-link arm's closed-form planar kinematics and
MuJoCo's site positions at the default joint-space targets; the iiwa's home flange and
reach worked by hand from the facts sheet. The joint-space references are tested in
test_tasks.py.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from sites import IIWA_HOME_FLANGE, IIWA_REACH, L1, L2, SHOULDER_Z, site_kinematics_closed_form

from cfm_jax.config import ConfigError
from cfm_jax.sim import opspace
from cfm_jax.tasks import references


def test_cartesian_reaching_quintic_straight_lines(iiwa):
    targets = np.array([[0.6, 0.2, 0.4], [0.5, -0.3, 0.3]])
    ref = references.cartesian_reaching(iiwa, None, targets, duration=2.0, control_dt=0.5)
    assert ref.x.shape == ref.xd.shape == ref.xdd.shape == (2, 5, 3) and ref.steps == 4
    np.testing.assert_allclose(ref.x[:, 0], np.tile(IIWA_HOME_FLANGE, (2, 1)), atol=2e-6)
    np.testing.assert_allclose(ref.x[:, -1], targets, atol=1e-15)
    start = ref.x[:, :1]
    delta = targets[:, None] - start
    # straight line: x(t) - x_home parallel to x_goal - x_home
    np.testing.assert_allclose(np.cross(ref.x - start, delta), 0.0, atol=1e-15)
    # t = T/2: s = 1/2, s' = 15/8 / T, s'' = 0; t = T/4: s = 106/1024, s'' = 5.625 / T^2
    np.testing.assert_allclose(ref.x[:, 2], start[:, 0] + delta[:, 0] / 2, atol=1e-15)
    np.testing.assert_allclose(ref.xd[:, 2], 15 / 8 * delta[:, 0] / 2.0, atol=1e-15)
    np.testing.assert_allclose(ref.xdd[:, 2], 0.0, atol=1e-15)
    np.testing.assert_allclose(ref.x[:, 1], start[:, 0] + delta[:, 0] * 106 / 1024, atol=1e-15)
    np.testing.assert_allclose(ref.xdd[:, 1], 5.625 * delta[:, 0] / 4.0, atol=1e-14)
    for end in (0, -1):
        np.testing.assert_allclose(ref.xd[:, end], 0.0, atol=1e-12)
        np.testing.assert_allclose(ref.xdd[:, end], 0.0, atol=1e-12)


def test_default_targets_are_the_tip_at_the_default_joint_targets(arm):
    joint_targets = references.default_targets(arm.joint_range, arm.home)
    expected = np.array([site_kinematics_closed_form(q, np.zeros(2))[0] for q in joint_targets])
    targets = references.default_cartesian_targets(arm, "tip")
    np.testing.assert_allclose(targets, expected, atol=1e-13)
    ref = references.cartesian_reaching(arm, "tip", None, duration=0.5, control_dt=0.01)
    assert ref.x.shape == (5, 51, 3)
    np.testing.assert_allclose(ref.x[:, -1], expected, atol=1e-13)
    home_tip = site_kinematics_closed_form(arm.home, np.zeros(2))[0]
    np.testing.assert_allclose(ref.x[:, 0], np.tile(home_tip, (5, 1)), atol=1e-13)


def test_default_targets_iiwa_deterministic_distinct_within_reach(iiwa):
    targets = references.default_cartesian_targets(iiwa)
    assert targets.shape == (5, 3)
    model, data = iiwa.mj_model, mujoco.MjData(iiwa.mj_model)
    for target, q in zip(
        targets, references.default_targets(iiwa.joint_range, iiwa.home), strict=True
    ):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(target, data.site_xpos[opspace.ee_site(iiwa)], atol=1e-15)
    distance = np.linalg.norm(targets - IIWA_HOME_FLANGE, axis=1)
    assert np.all(distance > 0.2) and np.all(distance < 0.6)  # documented 0.21 .. 0.57 m
    assert np.all(np.linalg.norm(targets - [0, 0, 0.36], axis=1) < IIWA_REACH)
    np.random.seed(7)
    np.testing.assert_array_equal(references.default_cartesian_targets(iiwa), targets)


def test_reach_from_the_model(iiwa, arm):
    length, base, joint = references.reach(iiwa)
    assert joint == "joint2"
    np.testing.assert_allclose(base, [0.0, 0.0, 0.36], atol=1e-15)
    np.testing.assert_allclose(length, IIWA_REACH, rtol=1e-12)
    length, base, joint = references.reach(arm, "tip")
    assert joint == "shoulder"
    np.testing.assert_allclose((length, *base), (L1 + L2, 0.0, 0.0, SHOULDER_Z), atol=1e-15)


def test_targets_beyond_reach_name_target_and_distance(iiwa):
    inside = [0.0, 0.0, 0.36 + 0.94]  # 0.94 m above joint 2: within reach 0.946
    far = [2.0, 0.0, 0.36]
    with pytest.raises(ConfigError) as info:
        references.cartesian_reaching(iiwa, None, [inside, far], 2.0, 0.01)
    message = str(info.value)
    assert message.startswith("task.targets[1]=(2.0, 0.0, 0.36) is not allowed: it is 2.000 m"), (
        message
    )
    assert "joint 'joint2' at (0.0, 0.0, 0.36)" in message and "reach of 0.946 m" in message
    assert references.check_targets(iiwa, [inside]).shape == (1, 3)


@pytest.mark.parametrize(
    ("targets", "start"),
    [
        ([[0.5, 0.1]], "task.targets=[[0.5, 0.1]] is not allowed (shape (1, 2))"),
        ([], "task.targets=[] is not allowed (shape (0,))"),
        ([[0.5, 0.0, 0.4], [0.5, np.nan, 0.4]], "task.targets[1]=(0.5, nan, 0.4) is not allowed"),
        ("far", "task.targets='far' is not allowed (shape None)"),
    ],
)
def test_bad_targets(iiwa, targets, start):
    with pytest.raises(ConfigError) as info:
        references.cartesian_reaching(iiwa, None, targets, 2.0, 0.01)
    assert str(info.value).startswith(start), str(info.value)


def test_bad_duration_and_home(arm):
    with pytest.raises(ConfigError, match=r"^task\.duration=0\.015 is not allowed"):
        references.cartesian_reaching(arm, "tip", None, 0.015, 0.01)
    with pytest.raises(ConfigError, match=r"^task\.home\[0\]\[1\]=3 \(joint 'elbow'\)"):
        references.cartesian_reaching(arm, "tip", None, 0.5, 0.01, home=np.array([0.0, 3.0]))


def test_desired_acceleration_formula_for_a_site():
    out = references.desired_acceleration(
        np.array([1.0, 0.0, 0.5]),
        np.array([0.0, 0.1, 0.0]),
        np.array([0.2, 0.0, -1.0]),
        np.array([0.99, 0.0, 0.5]),
        np.array([0.0, 0.0, 0.05]),
        100.0,
        20.0,
    )
    # x: 0.2 + 100 * 0.01 = 1.2; y: 20 * 0.1 = 2; z: -1 - 20 * 0.05 = -2
    np.testing.assert_allclose(np.asarray(out), [1.2, 2.0, -2.0], atol=1e-12)
