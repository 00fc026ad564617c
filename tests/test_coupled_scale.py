"""The coupled torque scale (``loop.torque_scale="coupled"``, issue 41): against closed forms
on the held-out three-joint arm (no damping or friction, coupled links: ``T = a M(home)``, so
a scaled torque moves every joint alike, ``M^-1 T = a I``) and the damped two-link arm (the
diagonal is the per-joint scale); the normaliser's maps, the babbling noise ``T n`` and the
robot check's noise accelerations by hand; a run trains with it."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tiny import tiny_config

from cfm_jax import config
from cfm_jax.analysis import robot_check
from cfm_jax.learning import algorithm, networks
from cfm_jax.sim import robots, rollout

ARM3 = str(Path(__file__).parent / "three_joint_arm.xml")


def _home_inertia(arm):
    dofs = np.asarray(arm.actuated_dofs)
    return arm.mass_matrix(arm.home)[np.ix_(dofs, dofs)]


def test_without_damping_a_scaled_torque_moves_every_joint_alike():
    arm = robots.load(ARM3)
    inertia = _home_inertia(arm)
    assert np.abs(inertia - np.diag(np.diag(inertia))).max() > 0.1  # coupled links
    a = np.min(np.asarray(arm.torque_limit) / np.diag(inertia))  # the weakest joint's
    scale = arm.coupled_torque_scale()
    np.testing.assert_allclose(np.linalg.solve(inertia, scale), a * np.eye(3), atol=1e-9 * a)
    # The per-joint scale gives the light joints more: a M^-1 diag(M) is not a I.
    assert not np.allclose(a * np.linalg.solve(inertia, np.diag(np.diag(inertia))), a * np.eye(3))


def test_with_damping_the_diagonal_is_the_per_joint_scale():
    arm = robots.load("two_link_arm")  # joint damping 0.05
    w = 10.0
    inertia = _home_inertia(arm)
    per_joint = arm.torque_scale(w)
    damping = arm.mj_model.dof_damping[np.asarray(arm.actuated_dofs)]
    impedance = np.hypot(np.diag(inertia), damping / w)
    a = np.min(np.asarray(arm.torque_limit) / impedance)
    scale = arm.coupled_torque_scale(w)
    np.testing.assert_array_equal(np.diag(scale), per_joint)
    np.testing.assert_allclose(scale[0, 1], a * inertia[0, 1], rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(scale) > 0) and np.array_equal(scale, scale.T)


def test_normaliser_maps_of_a_matrix_scale():
    arm = robots.load(ARM3)
    scale = arm.coupled_torque_scale()
    norm = networks.Normaliser.identity(6, 3, arm.torque_limit, torque_scale=scale)
    u = np.random.default_rng(0).normal(size=(4, 3)).astype(np.float32)
    # The forward model's input: T^-1 tau.
    np.testing.assert_allclose(norm.torque(jnp.asarray(u @ scale.T)), u, rtol=1e-4, atol=1e-5)
    # The controller's output: bounded by the limits, slope T at 0.
    slope = jax.jacfwd(norm.torque_output)(jnp.zeros(3))
    np.testing.assert_allclose(slope, scale, rtol=1e-5)
    big = norm.torque_output(jnp.asarray(1e3 * u))
    assert np.all(np.abs(big) <= np.asarray(arm.torque_limit) + 1e-4)


def test_babbling_noise_is_the_matrix_times_gaussian_noise():
    cfg = config.Config(robot=ARM3, loop=config.LoopConfig(torque_scale="coupled"))
    setup = algorithm.Setup.of(cfg)
    knobs = algorithm.Knobs.of(cfg, setup.robot, setup.task)
    scale = setup.robot.coupled_torque_scale(cfg.task.feedback_frequency(0.005))
    np.testing.assert_allclose(knobs.babbling_noise_std, 0.1 * scale, rtol=1e-6)
    np.testing.assert_allclose(knobs.torque_scale, scale, rtol=1e-6)
    # The policy's noise term (no controller, oracle or feedback): N n, n the key's draw.
    task = setup.task.with_values(knobs.task)
    quiet = algorithm.mixed_policy(setup, noise_std=knobs.babbling_noise_std)
    policy = rollout.mixed_policy(task, setup.controller, quiet)
    reference = jax.tree.map(lambda x: x[0, 0], task.reference)
    q, qd = jnp.asarray(setup.robot.home, jnp.float32), jnp.zeros(3, jnp.float32)
    features = jnp.zeros(0, jnp.float32)
    step = rollout.Step(jnp.int32(0), q, qd, features, task.state(q, qd, features),
                        task.desired(reference, q, qd, features), reference)  # fmt: skip
    key = jax.random.key(3)
    expected = np.asarray(knobs.babbling_noise_std) @ np.asarray(jax.random.normal(key, (3,)))
    np.testing.assert_allclose(np.asarray(policy(step, key)), expected, rtol=1e-5, atol=1e-6)


def test_robot_check_noise_acceleration_is_the_same_on_every_joint():
    arm = robots.load(ARM3)
    a = np.min(np.asarray(arm.torque_limit) / np.diag(_home_inertia(arm)))
    d = robot_check.dynamics(arm, babbling_noise=0.1, kd=20.0, control_dt=0.005,
                        torque_scale="coupled")  # fmt: skip
    np.testing.assert_allclose(d.noise_acceleration, 0.1 * a * np.ones(3), rtol=1e-9)
    per_joint = robot_check.dynamics(arm, 0.1, 20.0, 0.005, torque_scale="inertia")
    assert per_joint.noise_acceleration.max() > 1.2 * d.noise_acceleration.max()


def test_a_run_trains_with_the_coupled_scale(tmp_path):
    import cfm_jax

    # The tiny config (16-unit networks, a few dozen fit steps): the default networks took
    # 94 s of CI here for the same check.
    cfg = tiny_config(torque_scale="coupled")  # the default scale, said here
    result = cfm_jax.train(cfg, progress=False)
    assert np.all(np.isfinite(result.metrics.tracking_mse))
    np.testing.assert_allclose(
        np.asarray(result.state.normaliser.torque_scale)[0],
        robots.load("two_link_arm").coupled_torque_scale(10.0),
        rtol=1e-6,
    )
