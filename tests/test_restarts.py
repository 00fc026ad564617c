"""Data after a fall (``loop.restart_on_terminal``, issue 65): the data rollout starts again
from the reference after each fall, so that a controller that falls early still collects data
of the whole motion, and the metrics stay those of the rollout without restarts.

Oracles: the rollout without restarts (the same key; bit for bit up to the first fall), the
reference's own arrays for the state after each restart, and counts by hand of the steps that
become data."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.learning import algorithm
from cfm_jax.sim import robots, rollout

WALK = config_lib.TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0, motions=(0.8, 0.4))


@pytest.fixture(scope="module")
def walk():
    robot = robots.load("solo12")
    return tasks.make(robot, WALK, control_dt=WALK.control_period(robot.timestep))


def limp(step, key):
    """No torque at all: the Solo12 folds and falls within a fraction of a second."""
    del key
    return jnp.zeros(12, jnp.float32)


@pytest.fixture(scope="module")
def rollouts(walk):
    run = jax.jit(lambda restart: rollout.run(walk, limp, jax.random.key(0), restart=restart),
                  static_argnums=0)  # fmt: skip
    return jax.device_get(run(False)), jax.device_get(run(True))


def test_restarts_follow_the_rollout_to_the_first_fall_then_start_from_the_reference(
    walk, rollouts
):
    plain, again = rollouts
    terminal = np.asarray(again.extras["terminal"])
    restarted = np.asarray(again.extras["restarted"])
    for k in range(walk.targets):
        first = int(np.argmax(np.asarray(plain.extras["terminal"])[k]))
        assert plain.extras["terminal"][k, first], "the limp robot must fall"
        # The same rollout up to and including the first fall, bit for bit.
        for a, b in zip(plain.transitions[:4], again.transitions[:4], strict=True):
            np.testing.assert_array_equal(a[k, : first + 1], b[k, : first + 1])
        np.testing.assert_array_equal(restarted[k], terminal[k])
        # After each fall at step t, step t + 1 starts from the reference at t + 1.
        reference = jax.tree.map(lambda x, k=k: np.asarray(x)[k], walk.reference)
        steps = np.flatnonzero(restarted[k][:-1])
        assert len(steps) >= 2, "a limp 0.8-s walk falls again after its restart"
        for t in steps:
            want = walk.state(reference.qpos[t + 1], reference.qvel[t + 1],
                              reference.force[t + 1])  # fmt: skip
            np.testing.assert_array_equal(again.transitions.state[k, t + 1], want)
    # Without restarts the robot stays down: every step after its first fall is terminal.
    down = np.asarray(plain.extras["terminal"])
    first = np.argmax(down, axis=-1)
    for k in range(walk.targets):
        assert down[k, first[k] :].all()


def test_the_data_of_a_restarted_rollout_are_every_step_but_the_falls(walk, rollouts):
    plain, again = rollouts
    active = np.asarray(again.extras["active"])
    terminal = np.asarray(again.extras["terminal"])
    np.testing.assert_array_equal(algorithm.data_mask(again), active & ~terminal)
    before = np.cumsum(np.asarray(plain.extras["terminal"]), axis=-1) == 0
    np.testing.assert_array_equal(
        algorithm.data_mask(plain), np.asarray(plain.extras["active"]) & before
    )
    # The short walk (0.4 s inside a 0.8-s horizon) counts only its active steps.
    assert algorithm.data_mask(again)[1].sum() == (active[1] & ~terminal[1]).sum() < 0.4 / 0.004 + 1


def test_tasks_without_falls_have_no_restarts():
    robot = robots.load("two_link_arm")
    task_config = config_lib.TaskConfig(duration=0.1)
    task = tasks.make(robot, task_config, control_dt=task_config.control_period(robot.timestep))
    plain, again = (rollout.run(task, task.oracle_policy("native"), jax.random.key(0), restart=r)
                    for r in (False, True))  # fmt: skip
    for a, b in zip(plain.transitions[:4], again.transitions[:4], strict=True):
        np.testing.assert_array_equal(a, b)
    assert "restarted" not in (again.extras or {})


def test_collect_measures_the_plain_rollout_and_adds_the_restarted_ones_data():
    """One iteration's rollout with and without the option from the same state: the metrics
    are the same numbers but ``transitions_added``, which counts the restarted data."""
    base = config_lib.Config(
        robot="solo12",
        task=dataclasses.replace(WALK, motions=(0.6,)),
        forward=config_lib.ForwardModelConfig(hidden=(8,), ensemble_size=2, initial_steps=2,
                                              batch_size=16, kind="mlp"),
        controller=config_lib.ControllerConfig(hidden=(8,), initial_steps=2, batch_size=16),
        loop=config_lib.LoopConfig(babbling="home", babbling_rollouts=1, iterations=1),
    )  # fmt: skip
    setups = {r: algorithm.Setup.of(base.replace(loop=dataclasses.replace(base.loop,
                                                                          restart_on_terminal=r)))
              for r in (False, True)}  # fmt: skip
    knobs = algorithm.Knobs.of(base, setups[False].robot, setups[False].task)
    state = jax.jit(lambda key, knobs: algorithm.init(setups[False], "task", key, knobs))(
        jax.random.key(0), knobs
    )
    plain, again = (jax.device_get(jax.jit(lambda s, k, r=r: algorithm.collect(setups[r], s, k))(
        state, knobs)) for r in (False, True))  # fmt: skip
    (measured, (_, valid)), (measured_again, (_, valid_again)) = plain, again
    assert measured["fell"][0] == 1.0, "an untrained controller falls in 0.6 s"
    for name, value in measured.items():
        if name != "transitions_added":
            np.testing.assert_array_equal(measured_again[name], value, err_msg=name)
    assert measured["transitions_added"][0] == valid.sum()
    assert measured_again["transitions_added"][0] == valid_again.sum() > valid.sum()


def test_the_option_is_checked():
    with pytest.raises(config_lib.ConfigError, match=r"loop.restart_on_terminal='yes'"):
        config_lib.LoopConfig(restart_on_terminal="yes")
