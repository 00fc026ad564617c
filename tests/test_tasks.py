"""Reaching references and desired accelerations (cfm_jax/tasks.py).

Oracles: the closed form of the minimum-jerk polynomial (boundary and midpoint values worked
by hand), finite differences of the sampled path, the joint limits of the robots, and the
PD formula qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd) evaluated by hand.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax import tasks
from cfm_jax.config import ConfigError, TaskConfig
from cfm_jax.sim import robots
from cfm_jax.tasks import references

START = np.array([0.2, -1.0, 0.5])
GOAL = np.array([0.8, 0.5, 0.5])  # the third joint does not move


def test_quintic_boundary_conditions():
    ref = references.quintic(START, GOAL, duration=2.0, control_dt=0.01)
    assert ref.q.shape == ref.qd.shape == ref.qdd.shape == (1, 201, 3)
    assert ref.steps == 200
    # Polynomial 10u^3 - 15u^4 + 6u^5 is 0 at u=0 and 1 at u=1: positions exact up to one
    # float64 rounding of start + delta * 1.0 (atol 1e-15).
    np.testing.assert_allclose(ref.q[0, 0], START, atol=1e-15)
    np.testing.assert_allclose(ref.q[0, -1], GOAL, atol=1e-15)
    # Velocity 30u^2 - 60u^3 + 30u^4 and acceleration 60u - 180u^2 + 120u^3 vanish at both
    # ends; at u = 1 the terms cancel in float64 to within a few ulps of 120 (atol 1e-12).
    for end in (0, -1):
        np.testing.assert_allclose(ref.qd[0, end], 0.0, atol=1e-12)
        np.testing.assert_allclose(ref.qdd[0, end], 0.0, atol=1e-12)
    # The fixed joint stays put everywhere.
    np.testing.assert_array_equal(ref.q[0, :, 2], 0.5)
    np.testing.assert_array_equal(ref.qd[0, :, 2], 0.0)


def test_quintic_midpoint_closed_form():
    # u = 1/2: s = 10/8 - 15/16 + 6/32 = 1/2; s' = 30/4 - 60/8 + 30/16 = 15/8; s'' = 0.
    duration = 2.0
    ref = references.quintic(START, GOAL, duration=duration, control_dt=0.5)
    mid = 2  # t = 1.0 s
    np.testing.assert_allclose(ref.q[0, mid], (START + GOAL) / 2, rtol=1e-14)
    np.testing.assert_allclose(ref.qd[0, mid], 15 / 8 * (GOAL - START) / duration, rtol=1e-14)
    np.testing.assert_allclose(ref.qdd[0, mid], 0.0, atol=1e-14)
    # u = 1/4: s = 10/64 - 15/256 + 6/1024 = 106/1024; s'' = 15 - 11.25 + 1.875 = 5.625
    np.testing.assert_allclose(ref.q[0, 1], START + (GOAL - START) * 106 / 1024, rtol=1e-14)
    np.testing.assert_allclose(ref.qdd[0, 1], 5.625 * (GOAL - START) / duration**2, rtol=1e-13)


def test_quintic_derivatives_by_finite_differences():
    h, duration = 1e-4, 1.0
    ref = references.quintic(START, GOAL, duration=duration, control_dt=h)
    q, qd, qdd = ref.q[0], ref.qd[0], ref.qdd[0]
    # Central differences: truncation error h^2/6 * max|q'''| = 1e-8/6 * 60 * 1.5 = 1.5e-7
    # for velocity, h^2/6 * max|q''''| = 1e-8/6 * 360 * 1.5 = 9e-7 for acceleration;
    # rounding error eps * |q| / h ~ 1e-12. Tolerance 2e-6 covers both with margin.
    np.testing.assert_allclose((q[2:] - q[:-2]) / (2 * h), qd[1:-1], atol=2e-6)
    np.testing.assert_allclose((qd[2:] - qd[:-2]) / (2 * h), qdd[1:-1], atol=2e-6)


def test_quintic_as_jax_is_float32():
    ref = references.as_jax(references.quintic(START, GOAL, duration=1.0, control_dt=0.1))
    assert all(isinstance(x, jax.Array) and x.dtype == jnp.float32 for x in ref)
    assert ref.q.shape == (1, 11, 3)


@pytest.mark.parametrize("seed", [0, references.SELECTION_SEED])
@pytest.mark.parametrize("name", ["iiwa14", "two_link_arm"])
def test_default_targets_inside_limits_five_deterministic(name, seed):
    robot = robots.load(name)
    targets = references.default_targets(robot.joint_range, robot.home, seed)
    assert targets.shape == (5, robot.nq)
    low, high = robot.joint_range[:, 0], robot.joint_range[:, 1]
    width = high - low
    # Inside the range shrunk by 10 % at each end (the documented margin).
    assert np.all(targets >= low + 0.1 * width - 1e-12)
    assert np.all(targets <= high - 0.1 * width + 1e-12)
    # At most reach = min(0.6, width / 4) away from home on every joint.
    reach = np.minimum(0.6, width / 4)
    assert np.all(np.abs(targets - robot.home) <= reach + 1e-12)
    # Distinct targets, every one moves the arm.
    assert len({tuple(t) for t in targets}) == 5
    assert np.all(np.max(np.abs(targets - robot.home), axis=1) > 0.1)
    # Deterministic: same inputs, same targets (no global RNG state involved).
    np.random.seed(123)
    np.testing.assert_array_equal(
        references.default_targets(robot.joint_range, robot.home, seed), targets
    )
    if seed != 0:  # the selection's targets: none of them a test target
        test = references.default_targets(robot.joint_range, robot.home)
        assert np.min(np.abs(test[:, None] - targets[None]).max(axis=-1)) > 0.1


def test_default_targets_unlimited_joint():
    # An unlimited joint gets reach 0.6 and no clipping; each direction has |d| >= 1/3.
    joint_range = np.array([[-np.inf, np.inf]])
    targets = references.default_targets(joint_range, np.array([10.0]))
    assert np.all(np.abs(targets - 10.0) <= 0.6 + 1e-12)
    assert np.all(np.abs(targets - 10.0) >= 0.2 - 1e-12)


def test_reaching_default_targets(arm):
    ref = references.reaching(arm, TaskConfig(duration=0.5), control_dt=0.01)
    assert ref.q.shape == (5, 51, 2)
    np.testing.assert_allclose(ref.q[:, 0], np.broadcast_to(arm.home, (5, 2)), atol=1e-15)
    np.testing.assert_allclose(
        ref.q[:, -1], references.default_targets(arm.joint_range, arm.home), atol=1e-15
    )


def test_reaching_explicit_targets_and_home(arm):
    task = TaskConfig(duration=0.2, targets=((0.1, 0.2), (-0.3, 0.4)), home=(0.0, 1.0))
    ref = references.reaching(arm, task, control_dt=0.05)
    assert ref.q.shape == (2, 5, 2)
    np.testing.assert_allclose(ref.q[:, 0], [[0.0, 1.0], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(ref.q[:, -1], [[0.1, 0.2], [-0.3, 0.4]], atol=1e-15)
    # RMS reach: sqrt(mean(0.1^2, 0.8^2, 0.3^2, 0.6^2)) = sqrt(1.1 / 4)
    np.testing.assert_allclose(references.rms_reach(ref), np.sqrt(1.1 / 4), rtol=1e-12)


def test_reaching_target_out_of_range(iiwa):
    targets = (tuple(iiwa.home), tuple(iiwa.home[:3]) + (-2.5,) + tuple(iiwa.home[4:]))
    with pytest.raises(ConfigError) as info:
        references.reaching(iiwa, TaskConfig(targets=targets), control_dt=0.01)
    message = str(info.value)
    # second target, fourth joint (range +-2.0944 rad)
    assert message.startswith("task.targets[1][3]=-2.5 (joint 'joint4')"), message
    assert "[-2.094, 2.094]" in message


def test_reaching_target_wrong_length(arm):
    with pytest.raises(ConfigError) as info:
        references.reaching(arm, TaskConfig(targets=((0.1, 0.2, 0.3),)), control_dt=0.01)
    message = str(info.value)
    assert message.startswith("task.targets has 3 joint positions per entry"), message
    assert "nq=2" in message and "'shoulder'" in message and "'elbow'" in message


def test_reaching_home_out_of_range(arm):
    with pytest.raises(ConfigError, match=r"^task\.home\[0\]\[1\]=3 \(joint 'elbow'\)"):
        references.reaching(arm, TaskConfig(home=(0.0, 3.0)), control_dt=0.01)


def test_desired_acceleration_formula():
    ref_q, ref_qd, ref_qdd = jnp.array([1.0, -2.0]), jnp.array([0.5, 0.0]), jnp.array([3.0, 1.0])
    q, qd = jnp.array([0.75, -2.5]), jnp.array([0.25, 1.0])
    out = jax.jit(references.desired_acceleration)(ref_q, ref_qd, ref_qdd, q, qd, 100.0, 20.0)
    # joint 0: 3 + 100 * 0.25 + 20 * 0.25 = 33 ; joint 1: 1 + 100 * 0.5 + 20 * (-1) = 31
    np.testing.assert_allclose(np.asarray(out), [33.0, 31.0], rtol=1e-6)  # float32 rounding
    # kp = kd = 0: pure feed-forward, exactly the reference acceleration
    ff = references.desired_acceleration(ref_q, ref_qd, ref_qdd, q, qd, 0.0, 0.0)
    np.testing.assert_array_equal(np.asarray(ff), np.asarray(ref_qdd))


@pytest.mark.parametrize("name", ["inverse_dynamics", "opspace"])
def test_values_of_another_config_equal_a_task_built_for_it(arm, name):
    # Oracle: the task built from the config with other gains and other targets (the same
    # number). A PD-only rollout uses the reference and the gains twice, in s* (kp, kd) and
    # in the feedback torque (gain_p, gain_d); with that task's values swapped in (what
    # cfm_jax.learning.algorithm.Knobs carries into the compiled functions) it must be the same
    # rollout bit for bit, and differ from the original one.
    from cfm_jax.sim import rollout

    if name == "opspace":
        config = TaskConfig(name=name, duration=0.2, site="tip")
        # The default goals pulled 10 % towards the shoulder (at (0, 0, 1)): in reach.
        goals = tasks.make(arm, config, 0.01).reference_np.x[:, -1]
        targets = tuple(map(tuple, 0.9 * goals + 0.1 * np.array([0.0, 0.0, 1.0])))
        other = dataclasses.replace(config, kp=30.0, kd=4.0, targets=targets)
    else:
        config = TaskConfig(name=name, duration=0.2)
        other = TaskConfig(name=name, duration=0.2, kp=30.0, kd=4.0, home=(0.2, 0.6))
    task, built = tasks.make(arm, config, 0.01), tasks.make(arm, other, 0.01)
    moved = task.with_values(built.values())

    def run(t):
        policy = lambda step, key: t.feedback(step)  # noqa: E731
        return jax.jit(lambda: rollout.run(t, policy, jax.random.key(0)))()

    original, expected, got = run(task), run(built), run(moved)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not np.allclose(original.tracking_error, got.tracking_error)
    assert float(task.kp) == 100.0  # the task itself keeps its values
    with pytest.raises(ValueError, match="gain_p"):
        task.with_values({"kp": 1.0, "kd": 1.0})
    two = other.targets[:2] if name == "opspace" else ((0.1, 0.2), (0.3, 0.4))
    fewer = tasks.make(arm, dataclasses.replace(config, targets=two), 0.01)
    with pytest.raises(ValueError, match=r"values\['reference'\] has shapes \[\(2, 21"):
        task.with_values(fewer.values())
