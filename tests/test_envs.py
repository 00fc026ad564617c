"""cfm_jax.envs: the arm tracking task as a Gymnasium environment gives, for the same actions,
the very rollout and tracking error of the library's own compiled rollout (rollout.run),
follows training reaches that are not the test references, and ends a diverged episode."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from cfm_jax import config as config_lib
from cfm_jax import envs
from cfm_jax.learning.algorithm import Experiment
from cfm_jax.sim import native, rollout
from cfm_jax.tasks import scales

CONFIG = config_lib.Config(robot="two_link_arm", task=config_lib.TaskConfig(duration=0.2))


@pytest.fixture(scope="module")
def experiment():
    return Experiment(CONFIG)


def test_same_actions_give_the_library_rollout_bit_for_bit(experiment):
    env = envs.TrackingEnv(CONFIG, references="test", experiment=experiment)
    check_env(env, skip_render_check=True)
    task, steps = experiment.task, experiment.task.steps
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (steps, task.action_dim))
    actions = actions.astype(np.float32)
    limit = jnp.asarray(experiment.robot.torque_limit, jnp.float32)

    def replay(step, key):  # the same actions through the library's own rollout
        del key
        return jnp.asarray(actions)[step.t] * limit

    out = jax.jit(lambda: rollout.run(task, replay, jax.random.key(0)))()
    library_mse = np.asarray(rollout.tracking_mse(out))
    norm = scales.robot_scales(task)
    for k in range(task.targets):
        obs, info = env.reset(options={"target": k})
        assert info["target"] == k
        rewards = []
        for t in range(steps):
            # The observation is g's input: s_t and s*_t by the robot's scales (NumPy here).
            state = np.asarray(out.transitions.state[k, t], np.float64)
            desired = np.asarray(out.transitions.desired[k, t], np.float64)
            want = np.concatenate(
                [
                    (state - norm["state_mean"]) / norm["state_std"],
                    (desired - norm["output_mean"]) / norm["output_std"],
                ]
            )
            np.testing.assert_allclose(obs, want, rtol=1e-5, atol=1e-6)
            obs, reward, terminated, truncated, info = env.step(actions[t])
            # The physics and the task's error: bit for bit.
            np.testing.assert_array_equal(info["tracking_error"], out.tracking_error[k, t])
            assert not terminated and truncated == (t == steps - 1)
            rewards.append(reward)
        # Mean of -reward over the episode: the library's tracking MSE (float32 sums in
        # another order there).
        np.testing.assert_allclose(-np.mean(rewards), library_mse[k], rtol=1e-5)


def test_training_reaches_come_from_the_seed_and_are_not_the_test_references(experiment):
    env = envs.TrackingEnv(CONFIG, experiment=experiment)
    task = experiment.task
    home = np.asarray(task.reference.q[0, 0])

    def goal(seed):
        env.reset(seed=seed)
        assert env.reset(seed=seed)[1]["target"] is None
        return np.asarray(env._reference.q[-1])

    assert np.array_equal(goal(3), goal(3)) and not np.array_equal(goal(3), goal(4))
    low, high = env.robot.mj_model.jnt_range.T
    for seed in range(5):
        g = goal(seed)
        np.testing.assert_array_equal(np.asarray(env._reference.q[0]), home)  # from home
        assert np.all((g >= low) & (g <= high))  # inside the joint ranges
        assert not any(np.allclose(g, np.asarray(task.reference.q[k, -1])) for k in range(5))
    # An episode lasts the task's steps; the rewards are minus squared errors.
    env.reset(seed=1)
    for _ in range(task.steps):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert reward <= 0 and not terminated
    assert truncated


def test_a_diverging_simulation_terminates_the_episode(tmp_path):
    # A 1e-6 kg m^2 pendulum with a 1e9 N m motor: one full torque gives 1e15 rad/s^2.
    path = tmp_path / "wild.xml"
    path.write_text(
        """<mujoco><compiler angle="radian"/><option gravity="0 0 0"/><worldbody><body>
        <joint name="j" type="hinge" axis="0 1 0" range="-3 3"/>
        <inertial pos="0.1 0 0" mass="1e-4" diaginertia="1e-9 1e-9 1e-9"/></body></worldbody>
        <keyframe><key name="home" qpos="0"/></keyframe>
        <actuator><motor joint="j" ctrlrange="-1e9 1e9"/></actuator></mujoco>"""
    )
    env = envs.TrackingEnv(config_lib.Config(robot=str(path), task=config_lib.TaskConfig(
        duration=0.1, targets=((1.0,),))), references="test")  # fmt: skip
    env.reset()
    _, reward, terminated, truncated, info = env.step(np.ones(1, np.float32))
    assert terminated and info["diverged"] and not truncated and np.isfinite(reward)
    # MuJoCo's own warning was captured (and is taken here, not left to later tests).
    assert native.take_warnings() == {"Nan, Inf or huge value in QACC": 1}


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(task=config_lib.TaskConfig(name="walk")), "task.name='walk'"),
        (dict(simulator="mjx"), "simulator='mjx'"),
    ],
)
def test_refused_configs_name_the_field(change, field):
    with pytest.raises(config_lib.ConfigError, match=field):
        envs.TrackingEnv(CONFIG.replace(**change))
    with pytest.raises(config_lib.ConfigError, match="references='eval'"):
        envs.TrackingEnv(CONFIG, references="eval")
    with pytest.raises(config_lib.ConfigError, match="action='torque'.*'residual'"):
        envs.TrackingEnv(CONFIG, action="torque")
    with pytest.raises(config_lib.ConfigError, match="reward_scale=0.0.*> 0"):
        envs.TrackingEnv(CONFIG, reward_scale=0.0)
    with pytest.raises(config_lib.ConfigError, match="residual_scale=-1.*> 0"):
        envs.TrackingEnv(CONFIG, action="residual", residual_scale=-1.0)
    with pytest.raises(config_lib.ConfigError, match="residual_scale=0.1.*action='residual'"):
        envs.TrackingEnv(CONFIG, action="scale", residual_scale=0.1)


def test_environments_of_one_experiment_share_compilation_not_state(experiment):
    # A vector of environments (SAC/PPO run several) compiles the task's functions once;
    # stepping two of them in turn gives each the trajectory it has alone.
    alone = envs.TrackingEnv(CONFIG, references="test", experiment=experiment)
    first = envs.TrackingEnv(CONFIG, references="test", experiment=experiment)
    second = envs.TrackingEnv(CONFIG, experiment=experiment)
    assert first._fns is second._fns is alone._fns
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, (20, experiment.task.action_dim))
    expected = [alone.reset(options={"target": 2})[0]]
    expected += [alone.step(a)[0] for a in actions]
    got = [first.reset(options={"target": 2})[0]]
    second.reset(seed=0)
    for a in actions:
        second.step(-a)
        got.append(first.step(a)[0])
    np.testing.assert_array_equal(np.stack(got), np.stack(expected))


def _mass_diagonal_by_hand(robot, qpos):
    """diag M(q) from MuJoCo C's full mass matrix."""
    import mujoco

    data = mujoco.MjData(robot.mj_model)
    data.qpos[:] = qpos
    mujoco.mj_forward(robot.mj_model, data)
    full = np.zeros((robot.mj_model.nv, robot.mj_model.nv))
    mujoco.mj_fullM(robot.mj_model, data, full)
    return np.diag(full)


def test_residual_action_at_zero_is_the_task_pd_and_scores_pd_only(experiment):
    # The residual on PD at zero action: the PD-only baseline's torque, K_p (q_ref - q) +
    # K_d (qd_ref - qd), K = (kp, kd) diag M(start pose) from the config's gains (100, 20 by
    # default) and MuJoCo's mass matrix; its episodes score the library's PD-only rollout.
    env = envs.TrackingEnv(CONFIG, references="test", experiment=experiment, action="residual")
    task, robot = experiment.task, experiment.robot
    inertia = _mass_diagonal_by_hand(robot, np.asarray(task.reference.q[0, 0]))
    kp, kd = 100.0, 20.0
    assert (float(task.kp), float(task.kd)) == (kp, kd)
    zero = np.zeros(task.action_dim, np.float32)
    mses = []
    for k in range(task.targets):
        env.reset(options={"target": k})
        errors = []
        for t in range(task.steps):
            q, qd = np.asarray(env._qpos, np.float64), np.asarray(env._qvel, np.float64)
            ref_q, ref_qd = np.asarray(task.reference.q[k, t]), np.asarray(task.reference.qd[k, t])
            pd = kp * inertia * (ref_q - q) + kd * inertia * (ref_qd - qd)
            pd = np.clip(pd, -robot.torque_limit, robot.torque_limit)
            ref_t = jax.tree.map(lambda x, k=k, t=t: np.asarray(x)[k, t], task.reference)
            got = np.asarray(env._torque.torque(zero, ref_t, env._qpos, env._qvel, env._feat))
            np.testing.assert_allclose(got, pd, rtol=1e-4, atol=1e-4)
            _, reward, _, _, info = env.step(zero)
            errors.append(np.mean(np.square(info["tracking_error"], dtype=np.float64)))
        mses.append(np.mean(errors))
    # The library's own rollout of the PD-only policy (the baseline's).
    out = jax.jit(lambda: rollout.run(task, lambda step, key: task.feedback(step),
                                      jax.random.key(0)))()  # fmt: skip
    np.testing.assert_allclose(mses, np.asarray(rollout.tracking_mse(out)), rtol=1e-5)


def test_scale_action_is_the_controller_squashing_through_the_coupled_scale(experiment):
    # tau = limit tanh(T (reach a) / limit), T the robot's coupled torque scale at the task's
    # feedback frequency (sqrt(kp) = 10 rad/s), computed here from the robot's method; the
    # step applies that torque (the "limit" environment given tau / limit moves alike).
    scaled = envs.TrackingEnv(CONFIG, references="test", experiment=experiment, action="scale",
                              reward_scale=3.0)  # fmt: skip
    plain = envs.TrackingEnv(CONFIG, references="test", experiment=experiment)
    robot, task = experiment.robot, experiment.task
    limit = np.asarray(robot.torque_limit, np.float64)
    coupled = robot.coupled_torque_scale(10.0)
    reach = 1.0 * np.max(limit / np.diag(coupled))
    assert scaled.reach == pytest.approx(reach)
    scaled.reset(options={"target": 1})
    plain.reset(options={"target": 1})
    for a in np.random.default_rng(2).uniform(-1, 1, (5, task.action_dim)).astype(np.float32):
        tau = limit * np.tanh(coupled @ (reach * a) / limit)
        ref_t = jax.tree.map(lambda x: np.asarray(x)[1, scaled._t], task.reference)
        got = scaled._torque.torque(a, ref_t, scaled._qpos, scaled._qvel, scaled._feat)
        np.testing.assert_allclose(np.asarray(got), tau, rtol=1e-5, atol=1e-5)
        obs, reward, *_ = scaled.step(a)
        obs_plain, reward_plain, *_ = plain.step((tau / limit).astype(np.float32))
        np.testing.assert_allclose(obs, obs_plain, rtol=1e-4, atol=1e-5)
        assert reward == pytest.approx(3.0 * reward_plain, rel=1e-4)  # the reward scale
    # a = +-1 on one joint alone drives it to at least tanh(1) of its limit.
    for j in range(task.action_dim):
        unit = np.eye(task.action_dim, dtype=np.float32)[j]
        got = np.asarray(scaled._torque.torque(unit, ref_t, scaled._qpos, scaled._qvel,
                                               scaled._feat))  # fmt: skip
        assert got[j] >= np.tanh(1.0) * limit[j] * (1 - 1e-6)


def test_a_residual_scale_multiplies_the_policy_torque_not_the_feedback(experiment):
    # tau = clip(PD + s * scale-torque(a)): the PD part from the residual environment at zero
    # action, the policy's part from the scale environment (unclipped there for these small
    # actions); s = 1 is the environment without the factor, bit for bit.
    s = 0.05
    small = envs.TrackingEnv(CONFIG, references="test", experiment=experiment,
                             action="residual", residual_scale=s)  # fmt: skip
    full = envs.TrackingEnv(CONFIG, references="test", experiment=experiment, action="residual")
    one = envs.TrackingEnv(CONFIG, references="test", experiment=experiment, action="residual",
                           residual_scale=1.0)  # fmt: skip
    scale = envs.TrackingEnv(CONFIG, references="test", experiment=experiment, action="scale")
    task, robot = experiment.task, experiment.robot
    limit = np.asarray(robot.torque_limit, np.float64)
    small.reset(options={"target": 0})
    zero = np.zeros(task.action_dim, np.float32)
    for a in np.random.default_rng(3).uniform(-1, 1, (6, task.action_dim)).astype(np.float32):
        ref_t = jax.tree.map(lambda x: np.asarray(x)[0, small._t], task.reference)
        state = (ref_t, small._qpos, small._qvel, small._feat)
        pd = np.asarray(full._torque.torque(zero, *state), np.float64)
        policy = np.asarray(scale._torque.torque(a, *state), np.float64)
        got = np.asarray(small._torque.torque(a, *state), np.float64)
        np.testing.assert_allclose(got, np.clip(pd + s * policy, -limit, limit), rtol=1e-5,
                                   atol=1e-6)  # fmt: skip
        np.testing.assert_array_equal(np.asarray(one._torque.torque(a, *state)),
                                      np.asarray(full._torque.torque(a, *state)))  # fmt: skip
        assert not np.allclose(got, np.asarray(full._torque.torque(a, *state)))
        small.step(a)


def test_registered_ids_build_the_environment_gymnasium_checks_and_renders():
    """``gymnasium.make`` of a registered id (the module imported by the id's prefix) is the
    environment built directly: the same observations and rewards for the same seed and
    actions. Gymnasium's own checker passes it, render check included, and a frame is the
    one :func:`cfm_jax.sim.render.render_frames` draws of the same state (its own renderer)."""
    import gymnasium

    from cfm_jax.sim import render

    made = gymnasium.make("cfm_jax.envs:cfm_jax/Tracking-v0", config=CONFIG)
    direct = envs.TrackingEnv(CONFIG)
    assert set(envs.IDS) <= set(gymnasium.envs.registry)
    actions = np.random.default_rng(0).uniform(-0.2, 0.2, (5, 2)).astype(np.float32)
    for env in (made, direct):
        env.reset(seed=3)
    for action in actions:
        a, b = made.step(action), direct.step(action)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]
    with pytest.raises(config_lib.ConfigError, match="render_mode='human' is not allowed"):
        envs.TrackingEnv(CONFIG, render_mode="human")
    assert direct.render() is None  # no render mode: nothing drawn
    available, why = render.render_available()
    if not available:
        pytest.skip(f"no offscreen OpenGL: {why}")
    drawn = envs.TrackingEnv(CONFIG, render_mode="rgb_array")
    check_env(drawn, skip_render_check=False)
    drawn.reset(seed=0)
    drawn.step(actions[0])
    frame = drawn.render()
    qpos = np.asarray(drawn._qpos, float)
    reference = render.render_frames(drawn.robot.mj_model, qpos)[0]
    assert frame.shape == (envs.RENDER_HEIGHT, envs.RENDER_WIDTH, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, reference)
    drawn.close()
