"""Initial-data strategies (cfm_jax/tasks/babbling.py and each task's ``babbling_reference``).

Oracles: the strategies' definitions. ``home`` and ``reaching`` must not depend on the test
references (the babbling data of a config is identical when only ``task.targets`` change, or
only a legged task's recorded motion); ``reference_pd`` and ``oracle`` do (the same check
fails for them, so it can fail). Every strategy's data (the rows that become data) is
finite on every task. The reaching goals lie inside the shrunk joint ranges (closed form),
and the held reference is the start pose at rest.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import tiny_config

from cfm_jax import config as config_lib
from cfm_jax.learning import algorithm
from cfm_jax.runs import training
from cfm_jax.tasks import babbling, references


def _keys(n=2):
    return jax.vmap(jax.random.key)(jnp.arange(n, dtype=jnp.uint32))


def _data(exp: training.Experiment, config=None):
    """The babbling rollouts of ``config`` (default: the experiment's) on its compilations:
    the transitions and the mask of rows that become data."""
    knobs = exp.knobs if config is None else exp.knobs_for(config)
    result = exp.babbling_rollouts(_keys(), knobs)
    return jax.device_get(result.transitions), np.asarray(algorithm.data_mask(result))


def _assert_same(a, b):
    for name in ("state", "desired", "action", "observed"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _differs(a, b) -> bool:
    return not np.array_equal(a.state, b.state) or not np.array_equal(a.desired, b.desired)


ARM_TASKS = {
    "inverse_dynamics": (
        config_lib.TaskConfig(duration=0.3, targets=((0.3, -0.4), (-0.2, 0.5))),
        ((-0.5, 0.2), (0.4, 0.3)),
    ),
    "opspace": (
        config_lib.TaskConfig(
            name="opspace", duration=0.3, site="tip", targets=((0.5, 0.0, 1.4), (0.6, 0.0, 1.2))
        ),
        ((0.7, 0.0, 1.1), (0.4, 0.0, 1.5)),
    ),
}


def _with(config, strategy):
    return config.replace(loop=dataclasses.replace(config.loop, babbling=strategy))


@pytest.mark.parametrize("name", sorted(ARM_TASKS))
def test_arm_babbling_ignores_the_targets_unless_it_uses_the_references(name):
    task, other_targets = ARM_TASKS[name]
    config = tiny_config().replace(task=task)
    moved = config.replace(task=dataclasses.replace(task, targets=other_targets))
    exp = training.Experiment(config)  # the strategy is a runtime value: one compilation
    for strategy in config_lib.BABBLING:
        first, valid = _data(exp, _with(config, strategy))
        second, _ = _data(exp, _with(moved, strategy))
        assert valid.all() and all(np.isfinite(x).all() for x in jax.tree.leaves(first)), strategy
        if babbling.uses_reference(strategy):
            assert _differs(first, second), strategy  # the check can fail
        else:
            _assert_same(first, second)
    assert exp.compilations()["babble"] == 1


@pytest.mark.parametrize("name", ["walk", "jump"])
def test_legged_babbling_ignores_the_recorded_motion_unless_it_uses_it(name):
    base = config_lib.for_task(name)
    config = tiny_config().replace(
        robot=base.robot, task=base.task, loop=dataclasses.replace(base.loop, babbling_rollouts=1)
    )
    exp = training.Experiment(config)
    data = {strategy: _data(exp, _with(config, strategy)) for strategy in config_lib.BABBLING}
    for strategy, (transitions, valid) in data.items():
        # Rows that become data are finite, and there are some.
        assert valid.any(), strategy
        for x in (transitions.state, transitions.desired, transitions.action):
            assert np.isfinite(x[valid]).all(), strategy
        assert np.isfinite(transitions.observed[valid]).all(), strategy
    if name == "jump":
        return  # the motion check below is the same code for both legged tasks
    # Another recorded motion of the same shape: the reference shifted by 2 cm forward with
    # forces scaled by 1.1 (the structure stays, every value of the motion moves).
    ref = exp.task.reference
    moved_task = exp.task.with_reference(
        ref._replace(qpos=ref.qpos.at[..., 0].add(0.02), force=1.1 * ref.force)
    )
    exp.setup = dataclasses.replace(exp.setup, task=moved_task)
    exp._compiled.clear()  # the legged references are constants of the compiled rollout
    for strategy in ("home", "oracle"):  # the default, and one that uses the references
        moved, _ = _data(exp, _with(config, strategy))
        if babbling.uses_reference(strategy):
            assert _differs(data[strategy][0], moved), strategy
        else:
            _assert_same(data[strategy][0], moved)


def test_reaching_goals_lie_inside_the_shrunk_ranges_and_hold_is_at_rest():
    from cfm_jax.sim import robots

    iiwa = robots.load("iiwa14")
    starts = jnp.broadcast_to(jnp.asarray(iiwa.home, jnp.float32), (2000, 7))
    goals = np.asarray(babbling.random_poses(jax.random.key(3), iiwa, starts))
    low, high = iiwa.joint_range[:, 0], iiwa.joint_range[:, 1]
    width = high - low
    assert np.all(goals >= low + 0.1 * width - 1e-6) and np.all(goals <= high - 0.1 * width + 1e-6)
    # Uniform: 2000 draws per joint, each decile of the shrunk range holds 200 +- 3 sd (38).
    u = (goals - (low + 0.1 * width)) / (0.8 * width)
    counts = np.stack([np.histogram(u[:, j], bins=10, range=(0, 1))[0] for j in range(7)])
    assert np.all(np.abs(counts - 200) < 60), counts
    # A floating base keeps its pose; only the actuated joints move.
    solo = robots.load("solo12")
    start = jnp.asarray(solo.home, jnp.float32)[None]
    goal = np.asarray(babbling.random_poses(jax.random.key(0), solo, start))[0]
    np.testing.assert_array_equal(goal[:7], solo.home[:7].astype(np.float32))
    assert np.all(goal[7:] != solo.home[7:].astype(np.float32))
    # The held reference: the start pose, zero velocity and acceleration, exactly.
    x, xd, xdd = references.minimum_jerk(starts[:3], starts[:3], duration=0.04, control_dt=0.01)
    np.testing.assert_array_equal(np.asarray(x), np.broadcast_to(starts[:3, None], (3, 5, 7)))
    assert not np.any(np.asarray(xd)) and not np.any(np.asarray(xdd))


def test_traced_minimum_jerk_matches_the_host_reference():
    host = references.quintic([0.1, -0.2], [0.7, 0.4], duration=0.5, control_dt=0.01)
    x, xd, xdd = jax.jit(lambda a, b: references.minimum_jerk(a, b, 0.5, 0.01))(
        jnp.array([0.1, -0.2]), jnp.array([0.7, 0.4])
    )
    assert x.dtype == jnp.float32 and x.shape == (51, 2)
    # float32 against float64: positions to 1e-6 rad, velocities (up to 2.25 rad/s) and
    # accelerations (up to 14 rad/s^2) to a few float32 ulps of their scale.
    np.testing.assert_allclose(np.asarray(x), host.q[0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(xd), host.qd[0], atol=1e-5)
    np.testing.assert_allclose(np.asarray(xdd), host.qdd[0], atol=1e-4)


def test_standing_forces_carry_the_weight():
    import mujoco

    from cfm_jax.sim import robots

    solo = robots.load("solo12")
    forces = babbling.standing_forces(solo, 4).reshape(4, 3)
    np.testing.assert_allclose(forces.sum(0)[2], mujoco.mj_getTotalmass(solo.mj_model) * 9.81)
    assert not np.any(forces[:, :2])


def test_unknown_strategy_is_refused_with_the_allowed_ones():
    with pytest.raises(config_lib.ConfigError, match="loop.babbling='pd'.*'home', 'reaching'"):
        config_lib.LoopConfig(babbling="pd")
    # The selection run's choices: reaching for the arms, home for the legged tasks.
    assert config_lib.for_task("walk").loop.babbling == "home"
    assert config_lib.Config().loop.babbling == "reaching"
