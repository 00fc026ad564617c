"""The networks' normalisers of ``loop.normaliser`` (cfm_jax/learning/algorithm.py,
cfm_jax/tasks/scales.py) and the legged tasks' ``task.desired``.

Oracles: for ``data``, NumPy statistics of the data set's filled rows at every refit,
recorded as the fits see them; for ``robot``, scales computed by hand from a robot file
held out of ``robots/`` (tests/three_joint_arm.xml: hinges about y, so the diagonal of the
inertia at home is ``sum m d^2 + I_yy + armature`` over the links beyond each joint).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import tiny_config

from cfm_jax import config, tasks
from cfm_jax.learning import algorithm, networks
from cfm_jax.learning.algorithm import Experiment
from cfm_jax.sim import dataset, robots
from cfm_jax.tasks import scales

ARM3 = str(Path(__file__).parent / "three_joint_arm.xml")
HOME = (0.3, 0.0, 0.5)  # its keyframe "home"
G = 9.81


def hand_scales():
    """Centres and scales of [q, qd] and of qdd for tests/three_joint_arm.xml, by hand."""
    c, s = math.cos(HOME[2]), math.sin(HOME[2])
    # Link 3's centre of mass from joints 2 and 1 (link 2 straight, q2 = 0; q1 moves nothing).
    d3_2 = (0.8 + 0.3 * c) ** 2 + (0.3 * s) ** 2
    d3_1 = (1.8 + 0.3 * c) ** 2 + (0.3 * s) ** 2
    m33 = 0.5 * 0.3**2 + 0.004 + 0.1
    m22 = 1.0 * 0.4**2 + 0.01 + 0.5 * d3_2 + 0.004 + 0.05
    m11 = 2.0 * 0.5**2 + 0.02 + 1.0 * 1.4**2 + 0.01 + 0.5 * d3_1 + 0.004
    limits = np.array([30.0, 12.0, 2.0 * 2.0])  # ctrlrange x gear
    return {
        # ranges [-1, 2], [-0.5, 0.3]: middle and half range; j3 unlimited: home, 1 rad.
        "state_mean": np.array([0.5, -0.1, HOME[2], 0.0, 0.0, 0.0]),
        "state_std": np.array([1.5, 0.4, 1.0, 8.0, 8.0, 8.0]),
        "output_mean": np.zeros(3),
        "output_std": limits / np.array([m11, m22, m33]),
        "torque_limit": limits,
        # loop.torque_scale "inertia": each M_jj times the least of limit / M_jj.
        "torque_scale": np.array([m11, m22, m33]) * np.min(limits / np.array([m11, m22, m33])),
    }


def test_robot_scales_of_a_held_out_arm_equal_the_hand_computation():
    arm = robots.load(ARM3)
    task = tasks.make(
        arm, config.TaskConfig(duration=0.1, targets=((0.5, 0.1, 0.2),)), control_dt=0.01
    )
    expected = hand_scales()
    got = scales.robot_scales(task)
    for name in ("state_mean", "state_std", "output_mean", "output_std"):
        np.testing.assert_allclose(got[name], expected[name], rtol=1e-9, atol=1e-12)
    # The other kinds on the same robot: foot-like forces by m g, a velocity change over
    # dt by the acceleration times dt, a site's acceleration by the RMS over x, y, z of
    # J diag(A) (hinges about y: |column j|^2 is the squared distance of the site from
    # joint j, in the xz plane).
    import mujoco

    tip = mujoco.mj_name2id(arm.mj_model, mujoco.mjtObj.mjOBJ_SITE, "tip")
    entries = [("force", 0), ("velocity_change", 1), ("site_acceleration", tip)]
    centre, scale = scales.scales_of(arm, entries, control_dt=0.01)
    a = expected["output_std"]
    c, s = math.cos(HOME[2]), math.sin(HOME[2])
    r2 = [(1.8 + 0.5 * c) ** 2 + (0.5 * s) ** 2, (0.8 + 0.5 * c) ** 2 + (0.5 * s) ** 2, 0.25]
    site = math.sqrt(sum(a[j] ** 2 * r2[j] for j in range(3)) / 3.0)
    np.testing.assert_allclose(scale, [3.5 * G, a[1] * 0.01, site], rtol=1e-9)
    np.testing.assert_array_equal(centre, 0.0)
    with pytest.raises(ValueError, match="'torque' is not allowed"):
        scales.scales_of(arm, [("torque", 0)], 0.01)


def test_torque_scale_of_the_held_out_arm_equals_the_hand_computation():
    arm = robots.load(ARM3)
    expected = hand_scales()
    np.testing.assert_allclose(arm.torque_scale(), expected["torque_scale"], rtol=1e-9)
    # The weakest joint (the least limit / M_jj) is scaled by its own limit, exactly.
    weakest = np.argmin(expected["output_std"])
    assert arm.torque_scale()[weakest] == expected["torque_limit"][weakest]
    # The babbling noise is loop.babbling_noise of the scale, or of the limits.
    for torque_scale, of in (
        ("inertia", expected["torque_scale"]),
        ("limit", expected["torque_limit"]),
    ):
        cfg = config.Config(robot=ARM3, loop=config.LoopConfig(torque_scale=torque_scale))
        setup = algorithm.Setup.of(cfg)
        knobs = algorithm.Knobs.of(cfg, setup.robot, setup.task)
        np.testing.assert_allclose(knobs.babbling_noise_std, 0.1 * of, rtol=1e-6)


def test_torque_maps_of_the_normaliser():
    limit, scale = jnp.array([10.0, 2.0]), jnp.array([0.5, 2.0])
    norm = networks.Normaliser.identity(2, 2, limit, torque_scale=scale)
    plain = networks.Normaliser.identity(2, 2, limit)
    u = jnp.array([0.3, -1.7])
    # Without a scale: tau_max tanh(u) and tau / tau_max, as before the option existed.
    np.testing.assert_array_equal(plain.torque_output(u), limit * jnp.tanh(u))
    np.testing.assert_array_equal(plain.torque(u), u / limit)
    np.testing.assert_allclose(norm.torque(u), u / scale, rtol=1e-7)
    # Slope at 0 is the scale; the output never passes the limit.
    _, slope = jax.jvp(norm.torque_output, (jnp.zeros(2),), (jnp.ones(2),))
    np.testing.assert_allclose(slope, scale, rtol=1e-6)
    huge = norm.torque_output(jnp.array([1e6, -1e6]))
    np.testing.assert_allclose(huge, [10.0, -2.0], rtol=1e-6)
    np.testing.assert_allclose(norm.torque_output(u), limit * np.tanh(scale * u / limit), rtol=1e-6)


def test_robot_normaliser_is_what_the_loop_uses_on_the_held_out_arm():
    # The hand values are the per-joint scale's (the coupled one: tests/test_coupled_scale.py).
    cfg = tiny_config(normaliser="robot", torque_scale="inertia").replace(
        robot=ARM3, task=config.TaskConfig(duration=0.1, targets=((0.5, 0.1, 0.2),))
    )
    cfg = cfg.replace(forward=dataclasses.replace(cfg.forward, initial_steps=0))
    setup = algorithm.Setup.of(cfg)
    knobs = algorithm.Knobs.of(cfg, setup.robot, setup.task)
    # Start from some data (not babbling): the robot's scales must not depend on it.
    rows = 10
    chunk = dataset.Transitions(
        *(jax.random.normal(jax.random.key(k), (rows, 3)) * 5.0 for k in range(4))
    )
    chunk = chunk._replace(state=jnp.concatenate([chunk.state, chunk.state], -1))
    state, _ = jax.jit(lambda key, knobs, chunk: algorithm.prepare(setup, key, knobs, chunk))(
        jax.random.key(0), knobs, (chunk, jnp.ones(rows, bool))
    )
    expected = hand_scales()
    for name, value in expected.items():
        # float32 of the float64 hand values
        np.testing.assert_allclose(np.asarray(getattr(state.normaliser, name)), value, rtol=1e-6)


def test_legged_entries_have_the_solo12_layout(solo):
    walk = tasks.make(solo, config.for_task("walk").task, 0.004)
    entries = walk.entries()
    kinds = [kind for kind, _ in entries["state"]]
    assert kinds == ["position"] * 19 + ["force"] * 12 + ["velocity"] * 18
    assert [k for k, _ in entries["output"]] == ["velocity_change"] * 18 + ["force"] * 12
    got = scales.robot_scales(walk)
    # Oracle: the masses of the MJCF's <inertial> elements, summed from the XML text.
    import xml.etree.ElementTree as ET

    mass = sum(float(e.get("mass")) for e in ET.parse(solo.path).iter("inertial"))
    np.testing.assert_allclose(got["state_std"][19:31], mass * G, rtol=1e-6)
    np.testing.assert_allclose(got["output_std"][18:], mass * G, rtol=1e-6)
    # free joint: centred at home, scale 1; base accelerations by g, times dt
    np.testing.assert_array_equal(got["state_std"][:7], 1.0)
    np.testing.assert_allclose(got["state_mean"][:7], solo.home[:7])
    np.testing.assert_allclose(got["output_std"][:6], G * 0.004)


def test_data_normaliser_equals_numpy_statistics_of_the_data_at_every_refit(monkeypatch):
    cfg = tiny_config(normaliser="data")
    cfg = cfg.replace(task=dataclasses.replace(cfg.task, duration=0.1))
    setup = algorithm.Setup.of(cfg)
    knobs = algorithm.Knobs.of(cfg, setup.robot, setup.task)
    seen = []

    def recording(original):
        def fit(*args, **kwargs):
            state = next(a for a in args if isinstance(a, algorithm.TrainState))
            norm, data = state.normaliser, state.data
            jax.debug.callback(
                lambda *x: seen.append([np.asarray(v) for v in x]),
                norm.state_mean,
                norm.state_std,
                norm.output_mean,
                norm.output_std,
                data.data.state,
                data.data.observed,
                data.size,
            )
            return original(*args, **kwargs)

        return fit

    monkeypatch.setattr(algorithm, "_fit_forward", recording(algorithm._fit_forward))
    monkeypatch.setattr(algorithm, "_fit_controller", recording(algorithm._fit_controller))
    state = jax.jit(lambda key, knobs: algorithm.init(setup, "joint", key, knobs))(
        jax.random.key(0), knobs
    )
    step = jax.jit(lambda state, knobs: algorithm.iteration(setup, "joint", state, knobs))
    for _ in range(2):
        state, _ = step(state, knobs)
    jax.effects_barrier()
    assert len(seen) == 6  # initial fits of f and g, then both refits of two iterations
    sizes = [int(record[6]) for record in seen]
    assert sizes[0] == sizes[1] < sizes[2] == sizes[3] < sizes[4] == sizes[5]
    for mean_s, std_s, mean_y, std_y, states, observed, size in seen:
        rows_s = states[: int(size)].astype(np.float64)
        rows_y = observed[: int(size)].astype(np.float64)
        # float32 sums of a few hundred values: rtol 1e-5 against float64 NumPy.
        np.testing.assert_allclose(mean_s, rows_s.mean(0), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(std_s, np.maximum(rows_s.std(0), 1e-3), rtol=1e-5)
        np.testing.assert_allclose(mean_y, rows_y.mean(0), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(std_y, np.maximum(rows_y.std(0), 1e-3), rtol=1e-5)
    # It follows the data: each iteration's statistics differ from the babbling ones, and
    # the state carries the last refit's (the one its controller was fitted with).
    assert not np.allclose(seen[0][1], seen[4][1])
    np.testing.assert_array_equal(np.asarray(state.normaliser.state_std), seen[-1][1])


def test_next_velocity_desired_is_the_reference_next_velocity_minus_the_velocity(solo):
    walk_config = config.for_task("walk").task
    bare = dataclasses.replace(walk_config, desired="next_velocity", joint_kp=None)
    task = tasks.make(solo, bare, 0.004)
    np.testing.assert_array_equal(np.asarray(task.desired_kp), 0.0)
    np.testing.assert_array_equal(np.asarray(task.desired_kd), np.float32(250.0))
    ref = task.references[0]  # a recorded walk (NumPy, float64)
    n = ref.horizon
    rng = np.random.default_rng(0)
    qpos = ref.qpos[:n] + rng.normal(0, 0.01, (n, 19))
    qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)
    qvel = ref.qvel[:n] + rng.normal(0, 0.3, (n, 18))  # off the reference
    ref_t = jax.tree.map(lambda x: x[0, :n], task.reference)
    desired = jax.jit(jax.vmap(task.desired))(
        ref_t, jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32), jnp.zeros((n, 12))
    )
    desired = np.asarray(desired, np.float64)
    # s* = v_ref(t+1) - v(t) in velocity coordinates, from the float64 recording; float32
    # arithmetic on velocities up to ~20 rad/s times 250/s, times dt: atol 2e-5.
    np.testing.assert_allclose(desired[:, :18], ref.qvel[1 : n + 1] - qvel, atol=2e-5)
    np.testing.assert_allclose(desired[:, 18:], ref.foot_force_mean.reshape(n, 12), atol=1e-4)
    # With joint position feedback: + control_dt joint_kp (q_ref(t) - q(t)) on the joints
    # (qpos 7.. are the joints, qvel 6..), the base's entries unchanged.
    fed_config = dataclasses.replace(walk_config, desired="next_velocity", joint_kp=1000.0)
    fed = tasks.make(solo, fed_config, 0.004)
    fed_desired = jax.jit(jax.vmap(fed.desired))(
        ref_t, jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32), jnp.zeros((n, 12))
    )
    fed_desired = np.asarray(fed_desired, np.float64)
    expected = ref.qvel[1 : n + 1] - qvel
    expected[:, 6:] += 0.004 * 1000.0 * (ref.qpos[:n, 7:] - qpos[:, 7:])
    np.testing.assert_allclose(fed_desired[:, :18], expected, atol=2e-5)
    np.testing.assert_array_equal(fed_desired[:, :6], desired[:, :6])


def test_config_of_normaliser_and_desired():
    for bad in ("frozen", None):
        with pytest.raises(config.ConfigError, match="loop.normaliser"):
            config.LoopConfig(normaliser=bad)
    with pytest.raises(config.ConfigError, match="task.desired='next_velocity'.*'pd' for task"):
        config.TaskConfig(desired="next_velocity")
    with pytest.raises(config.ConfigError, match=r"task.kp=100.0 is not allowed: 0.0 with"):
        config.TaskConfig(name="walk", desired="next_velocity", kp=100.0)
    with pytest.raises(config.ConfigError, match=r"task.joint_kd=5.0 is not allowed: None"):
        config.TaskConfig(name="jump", desired="next_velocity", kp=0, kd=0, joint_kd=5.0)
    with pytest.raises(config.ConfigError, match=r"task.joint_kp=-1.0"):
        config.TaskConfig(name="walk", desired="next_velocity", kp=0, kd=0, joint_kp=-1.0)
    assert config.TaskConfig(name="walk", desired="next_velocity", joint_kp=10.0).joint_kp == 10
    with pytest.raises(config.ConfigError, match="task.desired"):
        config.TaskConfig(desired="velocity")
    walk = config.for_task("walk")  # next_velocity and data: the selection run's choices
    changed = walk.replace(
        task=dataclasses.replace(walk.task, desired="pd"),
        loop=dataclasses.replace(walk.loop, normaliser="babbling"),
    )
    assert config.from_dict(config.to_dict(changed)) == changed
    assert config.from_dict(config.to_dict(walk)) == walk
    # Old config.json files without the fields read as what ran then (pd, babbling).
    old = config.to_dict(changed)
    del old["loop"]["normaliser"], old["task"]["desired"]
    assert config.from_dict(old) == changed
    # task.desired only changes the gains (compiled once); loop.normaliser is structure.
    assert config.structure(changed.replace(loop=walk.loop)) == config.structure(walk)
    assert config.structure(changed) != config.structure(walk)


def test_the_torque_scale_is_a_value_of_the_config_that_follows_the_gains():
    # The torque scale weighs damping at the feedback's frequency sqrt(kp), and task.kp is a
    # runtime field (a sweep over it compiles once): the scale travels in the knobs, and the
    # normaliser the loop builds carries the cell's own. Oracle: Robot.torque_scale at
    # sqrt(kp), from the two-link arm's damping 0.1 and M(home); for the coupled scale (the
    # default) Robot.coupled_torque_scale at sqrt(kp), whose diagonal is that scale. Per
    # scale one Experiment (built at the first kp) and one compiled prepare, called with the
    # knobs of each kp (Experiment.knobs_for, as a sweep over task.kp runs it): each call
    # carries its own kp's scale.
    arm = robots.load("two_link_arm")
    for scale, of in (("inertia", arm.torque_scale), ("coupled", arm.coupled_torque_scale)):
        base = tiny_config(normaliser="robot", torque_scale=scale)
        built = Experiment(base.replace(task=config.TaskConfig(duration=0.1, kp=25.0)))
        prepare = jax.jit(functools.partial(algorithm.prepare, built.setup))
        for kp in (25.0, 100.0):
            cfg = base.replace(task=config.TaskConfig(duration=0.1, kp=kp))
            knobs = built.knobs_for(cfg)
            want = of(np.sqrt(kp))
            np.testing.assert_array_equal(knobs.torque_scale, want.astype(np.float32))
            np.testing.assert_allclose(knobs.babbling_noise_std, 0.1 * want, rtol=1e-6)
            state, _ = prepare(jax.random.key(0), knobs)
            np.testing.assert_array_equal(state.normaliser.torque_scale, knobs.torque_scale)
        assert prepare._cache_size() == 1  # the second kp compiled nothing
    assert config.LoopConfig().torque_scale == "auto"  # the arm tasks' default (pose here)
    # The damping (0.1 N m s) makes the scales of the two gains differ.
    assert not np.array_equal(arm.torque_scale(5.0), arm.torque_scale(10.0))
    limit = tiny_config(torque_scale="limit")
    assert algorithm.Knobs.of(limit, arm, algorithm.Setup.of(limit).task).torque_scale is None
