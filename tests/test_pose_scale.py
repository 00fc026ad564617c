"""The torque scale at each state's own pose (``loop.torque_scale="pose"``, issue 64):
``T(q) = T + a (M(q) - M(home))``. Against MuJoCo C's mass matrix (``mj_fullM``, not MJX,
which the library uses): on the held-out three-joint arm (no damping or friction, so ``T = a
M(home)`` and ``T(q) = a M(q)``: a scaled torque moves every joint alike at every pose); the
normaliser's maps at a pose; a run trains with it, and a continued run from its checkpoint."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import tiny_config

import cfm_jax
from cfm_jax import config
from cfm_jax.learning import algorithm, networks
from cfm_jax.sim import dataset, robots

ARM3 = str(Path(__file__).parent / "three_joint_arm.xml")


@pytest.fixture(scope="module")
def arm3():
    cfg = config.Config(robot=ARM3, loop=config.LoopConfig(torque_scale="pose"))
    return cfg, algorithm.Setup.of(cfg)


def _poses(robot, n, seed=0):
    low, high = robot.mj_model.jnt_range.T
    return np.random.default_rng(seed).uniform(low, high, size=(n, robot.nq))


def test_the_scale_at_a_pose_is_a_times_mujocos_mass_matrix(arm3):
    cfg, setup = arm3
    robot = setup.robot
    home = robot.mass_matrix(robot.home)
    a = np.min(np.asarray(robot.torque_limit) / np.diag(home))  # the weakest joint's
    poses = _poses(robot, 6)
    states = jnp.asarray(np.concatenate([poses, np.ones_like(poses)], 1), jnp.float32)
    knobs = algorithm.Knobs.of(cfg, robot, setup.task)
    scale = np.asarray(knobs.torque_scale)[None] + np.asarray(jax.jit(setup.pose_scale)(states))
    for pose, at_pose in zip(poses, scale, strict=True):
        inertia = robot.mass_matrix(pose)  # MuJoCo C
        assert not np.allclose(inertia, home, rtol=0.05)  # the poses move the inertia
        np.testing.assert_allclose(np.linalg.solve(inertia, at_pose), a * np.eye(3),
                                   atol=2e-5 * a)  # fmt: skip
    # At home the pose term vanishes: T(home) = T, the coupled scale.
    at_home = jnp.asarray(np.concatenate([robot.home, np.zeros(3)]), jnp.float32)
    np.testing.assert_allclose(jax.jit(setup.pose_scale)(at_home), 0.0, atol=1e-5 * a)


def test_normaliser_maps_at_a_pose(arm3):
    cfg, setup = arm3
    robot = setup.robot
    knobs = algorithm.Knobs.of(cfg, robot, setup.task)
    norm = networks.Normaliser.identity(6, 3, robot.torque_limit, torque_scale=knobs.torque_scale,
                                        pose_scale=setup.pose_scale)  # fmt: skip
    poses = _poses(robot, 4, seed=1)
    states = jnp.asarray(np.concatenate([poses, np.zeros_like(poses)], 1), jnp.float32)
    # T(q) from MuJoCo C: T + a (M(q) - M(home)), a = T's off-diagonal over M(home)'s.
    home_inertia = robot.mass_matrix(robot.home)
    a = np.asarray(knobs.torque_scale)[0, 1] / home_inertia[0, 1]
    scale = np.stack([np.asarray(knobs.torque_scale) + a * (robot.mass_matrix(p) - home_inertia)
                      for p in poses])  # fmt: skip
    u = np.random.default_rng(2).normal(size=(4, 3)).astype(np.float32)
    tau = np.einsum("nij,nj->ni", scale, u)
    # The forward model's input: T(q)^-1 tau; without a state, T (home) alone.
    scaled = jax.jit(norm.torque)(jnp.asarray(tau), states)
    np.testing.assert_allclose(scaled, u, rtol=1e-4, atol=1e-4)
    home = np.linalg.solve(np.asarray(knobs.torque_scale), tau.T).T
    np.testing.assert_allclose(norm.torque(jnp.asarray(tau)), home, rtol=1e-4, atol=1e-4)
    # The controller's output: slope T(q) at u = 0, bounded by the limits.
    slopes = jax.jit(jax.vmap(jax.jacfwd(norm.torque_output)))(jnp.zeros((4, 3)), states)
    np.testing.assert_allclose(slopes, scale, rtol=1e-4, atol=1e-4 * np.abs(scale).max())
    big = jax.jit(norm.torque_output)(jnp.asarray(1e3 * u), states)
    assert np.all(np.abs(big) <= np.asarray(robot.torque_limit) + 1e-4)


def test_the_networks_take_the_scale_at_their_states_pose():
    """The wiring, with a hand-made pose term (no MJX to compile): f's torque input and g's
    output go through ``T(s) = T + s_0 B`` at each row's state."""
    scale, added = jnp.array([[2.0, 0.5], [0.5, 1.0]]), jnp.array([[1.0, -0.2], [-0.2, 0.5]])
    norm = networks.Normaliser.identity(4, 2, jnp.array([50.0, 50.0]), torque_scale=scale,
                                        pose_scale=lambda s: s[..., :1, None] * added)  # fmt: skip
    states = jnp.array([[0.0, 1.0, 2.0, 3.0], [1.5, -1.0, 0.0, 2.0]])
    at_pose = np.stack([np.asarray(scale) + float(s[0]) * np.asarray(added) for s in states])
    g = networks.controller(hidden=(8,), nv=2)
    params = g.init(jax.random.key(0), 4)
    desired = jnp.array([[0.3, -0.1], [0.2, 0.4]])
    plain = networks.Normaliser.identity(4, 2, jnp.array([50.0, 50.0]))  # tanh(u): u by hand
    u = np.arctanh(np.asarray(g.apply(params, plain, states, desired)) / 50.0)
    expected = 50.0 * np.tanh(np.einsum("nij,nj->ni", at_pose, u) / 50.0)
    np.testing.assert_allclose(g.apply(params, norm, states, desired), expected, rtol=1e-4)
    fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
    theta = fm.init(jax.random.key(1), 4)
    tau = jnp.array([[1.0, 2.0], [-3.0, 0.5]])
    unscaled = np.linalg.solve(at_pose, np.asarray(tau)[..., None])[..., 0]
    mean, _ = fm.apply(theta, norm, states, tau)
    same, _ = fm.apply(theta, plain.replace(torque_scale=jnp.ones(2)), states, unscaled)
    np.testing.assert_allclose(mean, same, rtol=1e-4, atol=1e-5)


def test_data_rows_carry_the_pose_term_that_the_fits_use(arm3):
    """The pose term is computed once per data-set row (``with_terms``: MuJoCo C's ``T(q) -
    T`` at the row's pose), and the losses on rows use the stored term, not ``pose_scale``."""
    cfg, setup = arm3
    robot = setup.robot
    poses = _poses(robot, 5, seed=4)
    states = jnp.asarray(np.concatenate([poses, np.zeros_like(poses)], 1), jnp.float32)
    rows = dataset.Transitions(states, jnp.ones((5, 3)), jnp.ones((5, 3)), jnp.ones((5, 3)))
    stored = np.asarray(jax.jit(algorithm.with_terms, static_argnums=0)(setup, rows).pose)
    home = robot.mass_matrix(robot.home)
    a = np.min(np.asarray(robot.torque_limit) / np.diag(home))
    oracle = np.stack([a * (robot.mass_matrix(p) - home) for p in poses])
    np.testing.assert_allclose(stored, oracle, atol=2e-5 * np.abs(oracle).max())
    # The objectives read the rows' term: a row term that is not pose_scale's changes them
    # exactly as a pose_scale giving that term does.
    scale, added = jnp.array([[2.0, 0.5], [0.5, 1.0]]), jnp.array([[1.0, -0.2], [-0.2, 0.5]])
    plain = networks.Normaliser.identity(4, 2, jnp.array([50.0, 50.0]), torque_scale=scale)
    by_state = plain.replace(pose_scale=lambda s: s[..., :1, None] * added)
    other = jnp.array([[0.3, 0.1], [0.1, 0.2]])
    by_rows = by_state.replace(pose_scale=lambda s: jnp.zeros(s.shape[:-1] + (2, 2)))
    fixed = plain.replace(pose_scale=lambda s: jnp.broadcast_to(other, s.shape[:-1] + (2, 2)))
    batch = dataset.Transitions(*(jnp.asarray(np.random.default_rng(5).normal(size=(6, d)),
                                              jnp.float32) for d in (4, 2, 2, 2)))  # fmt: skip
    g = networks.controller(hidden=(8,), nv=2)
    fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
    beta, theta = g.init(jax.random.key(0), 4), fm.init(jax.random.key(1), 4)
    posed = batch._replace(pose=jnp.broadcast_to(other, (6, 2, 2)))
    for loss in ("joint", "supervised"):

        def objective(norm, rows, loss=loss):
            return algorithm.controller_objective(beta, theta, loss, fm, g, norm, rows)

        assert float(objective(by_rows, posed)) == float(objective(fixed, batch))
        assert float(objective(by_state, posed)) != float(objective(by_state, batch))

    def members(rows):  # f's objective scores member e on minibatch e
        return jax.tree.map(lambda x: jnp.stack([x, x]), rows)

    assert float(fm.objective(theta, by_rows, members(posed))) == float(
        fm.objective(theta, fixed, members(batch))
    )


@pytest.mark.slow  # MJX's inertia compiles into every fit and rollout: ~100 s of CPU
def test_a_run_trains_with_the_pose_scale_and_continues(tmp_path):
    cfg = tiny_config(torque_scale="pose")
    result = cfm_jax.train(cfg, out_dir=str(tmp_path / "run"), progress=False)
    assert np.all(np.isfinite(result.metrics.tracking_mse))
    assert result.state.normaliser.pose_scale is not None
    arm = robots.load("two_link_arm")
    np.testing.assert_allclose(np.asarray(result.state.normaliser.torque_scale)[0],
                               arm.coupled_torque_scale(10.0), rtol=1e-6)  # fmt: skip
    # A third iteration from the checkpoint (the pose term is code, not a saved array).
    more = cfg.replace(loop=dataclasses.replace(cfg.loop, iterations=3))
    again = cfm_jax.train(more, resume=str(tmp_path / "run"), progress=False)
    assert int(again.state.iteration[0]) == 3
    assert np.all(np.isfinite(again.metrics.tracking_mse))


def test_the_default_is_the_pose_scale_where_mjx_builds_the_robot():
    # 'auto' (the default since issue 64's decision) builds what 'pose' builds: the same
    # knobs and the same pose term at random states (its fallback to 'coupled' where MJX
    # cannot build the robot: tests/test_dev_robots.py).
    assert config.LoopConfig().torque_scale == "auto"
    auto = algorithm.Setup.of(config.Config(robot=ARM3))
    named = config.LoopConfig(torque_scale="pose")
    pose = algorithm.Setup.of(config.Config(robot=ARM3, loop=named))
    assert algorithm.scale_kind(auto.config, auto.robot) == "pose"
    knobs = [algorithm.Knobs.of(s.config, s.robot, s.task) for s in (auto, pose)]
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.all(a == b)), *knobs))
    states = jnp.asarray(np.random.default_rng(1).normal(size=(5, auto.task.state_dim)))
    np.testing.assert_array_equal(auto.pose_scale(states), pose.pose_scale(states))


def test_the_pose_scale_is_a_config_value_checked_by_name():
    with pytest.raises(config.ConfigError, match="loop.torque_scale.*'pose'"):
        config.LoopConfig(torque_scale="poses")


def test_the_positive_definite_solve_is_numpys():
    """The pose path's solve (a Cholesky in array operations, no LAPACK batch: see its
    docstring) against NumPy's float64 ``solve``, on a batch of ill-conditioned matrices."""
    rng = np.random.default_rng(3)
    for k in (1, 3, 7):
        half = rng.normal(size=(6, k, k))
        a = half @ half.transpose(0, 2, 1) + np.diag(np.logspace(-3, 0, k))
        b = rng.normal(size=(6, k))
        expected = np.linalg.solve(a, b[..., None])[..., 0]
        got = jax.jit(networks._positive_definite_solve)(jnp.asarray(a, jnp.float32),
                                                         jnp.asarray(b, jnp.float32))  # fmt: skip
        # float32 against float64: relative to the solution's size and a's conditioning.
        tolerance = 1e-6 * np.linalg.cond(a).max() * np.abs(expected).max()
        np.testing.assert_allclose(got, expected, atol=tolerance)
