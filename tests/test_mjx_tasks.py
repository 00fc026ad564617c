"""MJX as an on-device simulator: with ``simulator="mjx"`` a task's rollout is a JAX
program with no host callback, and the MJX site kinematics and operational-space oracle
equal MuJoCo C's.

Oracles: the traced program itself (its primitives; the native simulator's rollout is the
positive control, it must show its host callback), and MuJoCo C in float64
(:class:`cfm_jax.opspace.HostKinematics`, :class:`cfm_jax.baselines.HostOpspaceOracle`) at
random states."""

from __future__ import annotations

import re

import jax
import numpy as np
import pytest

from cfm_jax import baselines, opspace, robots, tasks, training
from cfm_jax import config as config_lib

CALLBACK = re.compile(r"callback|cfm_native_step")


def small(name: str, simulator: str) -> config_lib.Config:
    """The task's defaults at a small size (the traced program has the same structure)."""
    base = tasks.load(name).default_config()
    changes = {"simulator": simulator}
    if name in ("inverse_dynamics", "opspace"):
        site = "tip" if name == "opspace" else None
        task = config_lib.TaskConfig(name=name, duration=0.1, site=site)
        changes.update(robot="two_link_arm", task=task)
    return base.replace(
        **changes,
        forward=config_lib.ForwardModelConfig(hidden=(8,), ensemble_size=1),
        controller=config_lib.ControllerConfig(hidden=(8,)),
        loop=config_lib.LoopConfig(iterations=1, seeds=1, babbling_rollouts=1),
    )


def rollout_program(name: str, simulator: str) -> str:
    experiment = training.Experiment(small(name, simulator))
    # The babbling policy mixes every branch (controller, feedback, oracle, noise) with
    # runtime weights, so all of them are in the program.
    policy = experiment.babbling_policy()
    return str(jax.make_jaxpr(experiment.rollout_one)(policy, jax.random.key(0)))


@pytest.mark.parametrize("name", sorted(tasks.REGISTRY))
def test_mjx_rollout_has_no_host_callback(name):
    assert not CALLBACK.findall(rollout_program(name, "mjx"))


def test_the_callback_check_sees_the_native_simulator():
    """Positive control: the native rollout steps MuJoCo C through a host callback."""
    assert CALLBACK.findall(rollout_program("inverse_dynamics", "native"))


@pytest.fixture(scope="module")
def arms():
    return {"iiwa14": robots.load("iiwa14"), "two_link_arm": robots.load("two_link_arm")}


def random_states(robot, n: int, seed: int):
    rng = np.random.default_rng(seed)
    low, high = robot.joint_range[:, 0], robot.joint_range[:, 1]
    qpos = rng.uniform(low + 0.1 * (high - low), high - 0.1 * (high - low), (n, robot.nq))
    qvel = rng.normal(0.0, 1.0, (n, robot.nv))
    return qpos.astype(np.float32), qvel.astype(np.float32)


@pytest.mark.parametrize(
    "name,site",
    # The iiwa compiles for ~40 s per test: a slow study (pytest -m slow), run before release.
    [pytest.param("iiwa14", None, marks=pytest.mark.slow), ("two_link_arm", "tip")],
)
def test_mjx_site_kinematics_equal_mujoco_c(arms, name, site):
    robot = arms[name]
    qpos, qvel = random_states(robot, 6, seed=1)
    got = jax.jit(lambda q, qd: opspace.mjx_kinematics(robot, q, qd, site))(qpos, qvel)
    want = opspace.HostKinematics(robot, site)(qpos, qvel)
    for field, a, b in zip(want._fields, got, want, strict=True):
        # float32 against float64: positions to ~1e-6 m, derivatives to a few 1e-5.
        np.testing.assert_allclose(np.asarray(a), b, rtol=1e-4, atol=1e-4, err_msg=field)
    # The same through the task's entry point, and batched over two axes.
    both = opspace.kinematics(robot, qpos.reshape(2, 3, -1), qvel.reshape(2, 3, -1), site, "mjx")
    np.testing.assert_allclose(
        np.asarray(both.jacobian).reshape(6, 3, -1), want.jacobian, rtol=1e-4, atol=1e-4
    )


@pytest.mark.parametrize(
    "name,site",
    # The iiwa compiles for ~40 s per test: a slow study (pytest -m slow), run before release.
    [pytest.param("iiwa14", None, marks=pytest.mark.slow), ("two_link_arm", "tip")],
)
def test_mjx_oracle_equals_the_host_oracle(arms, name, site):
    robot = arms[name]
    qpos, qvel = random_states(robot, 6, seed=2)
    desired = np.random.default_rng(3).normal(0.0, 2.0, (6, 3)).astype(np.float32)
    got = jax.jit(baselines.opspace_oracle(robot, site, simulator="mjx"))(qpos, qvel, desired)
    want = baselines.HostOpspaceOracle(robot, site)(qpos, qvel, desired)
    scale = np.abs(want).max()
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-3, atol=1e-4 * scale)
