"""The legged tasks ``walk`` and ``jump`` on the Solo12 (cfm_jax/tasks.py ``LeggedTask``).

Oracle: the references recorded by cfm_jax.tasks.locomotion from MuJoCo C on the same model.
Replaying a reference's own controller (feed-forward torque plus joint PD) in the
library's compiled rollout must reproduce the recording, and then the desired quantity
(reference accelerations and foot forces, no feedback error) must equal the observed one;
horizons of different length must be masked out of the data and the metrics.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.learning import algorithm
from cfm_jax.runs import training
from cfm_jax.sim import quadruped, robots, rollout, solo12
from cfm_jax.tasks import legged, locomotion

QUADRUPEDS = Path(__file__).parent / "robots" / "quadrupeds"


@pytest.fixture(scope="module")
def walk(solo):
    # s* with PD gains (the walk's default is the desired next velocity): the reference
    # controller then reproduces the recording with desired == observed.
    pd = config_lib.TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0)
    return tasks.make(solo, pd, 0.004)


def test_sizes_and_padding(walk, solo):
    # s = [qpos 19, foot forces 12, qvel 18]; y = s* = [qacc dt 18, foot forces 12].
    assert (walk.state_dim, walk.desired_dim, walk.output_dim, walk.action_dim) == (49, 30, 30, 12)
    horizons = [round(d / 0.004) for d in locomotion.WALK_DURATIONS]
    assert walk.steps == max(horizons) and walk.targets == 5
    active = np.asarray(walk.reference.active)
    np.testing.assert_array_equal(active.sum(axis=1), horizons)


def test_reference_controller_reproduces_the_recording(walk):
    out = jax.jit(lambda: rollout.run(walk, walk.oracle_policy("native"), jax.random.key(0)))()
    active = np.asarray(out.extras["active"])
    for k, ref in enumerate(walk.references):
        n = ref.horizon
        np.testing.assert_array_equal(active[k], np.arange(walk.steps) < n)
        qpos = np.asarray(out.transitions.state[k, :n, :19])
        # float32 state between control steps against the float64 recording: 1e-5.
        np.testing.assert_allclose(qpos, ref.qpos[:n], atol=1e-5)
        # Following the reference with no feedback error, desired == observed: the
        # accelerations times dt and the mean foot forces of each period.
        desired = np.asarray(out.transitions.desired[k, :n])
        observed = np.asarray(out.transitions.observed[k, :n])
        np.testing.assert_allclose(desired[:, :18], ref.qacc * 0.004, atol=1e-5)
        np.testing.assert_allclose(observed[:, :18], ref.qacc * 0.004, atol=1e-4)
        forces = ref.foot_force_mean.reshape(n, 12)
        np.testing.assert_allclose(observed[:, 18:], forces, atol=1e-2)  # N, of ~12 N
    fell = np.asarray(out.extras["fell"])
    assert not np.any(fell & active)
    # The walk moves forward by the recorded distance.
    assert walk.references[-1].qpos[-1, 0] - walk.references[-1].qpos[0, 0] > 0.5


def test_configuration_of_a_state_is_its_whole_floating_base_configuration(walk, solo):
    """The ``rigid_body`` forward model reads ``(qpos, qvel)`` back from a learning state
    ``[qpos, foot forces, qvel]``: every entry, base included (a floating base is not an
    arm's held joint, which the arms' ``configuration`` fills in at ``home``; 46cd728 had
    the walk and jump crash there on their default forward model)."""
    rng = np.random.default_rng(0)
    qpos = rng.normal(size=(3, solo.nq)).astype(np.float32)
    qvel = rng.normal(size=(3, solo.nv)).astype(np.float32)
    forces = rng.normal(size=(3, 12)).astype(np.float32)
    state = jax.vmap(walk.state)(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(forces))
    got_qpos, got_qvel = walk.configuration(state)
    np.testing.assert_array_equal(got_qpos, qpos)
    np.testing.assert_array_equal(got_qvel, qvel)


def test_desired_acceleration_has_base_gains_on_the_base_and_joint_gains_on_the_joints(solo):
    # Oracle: the PD correction written out by hand, with MuJoCo's mju_subQuat for the base
    # orientation error (a rotation vector in the base frame, the frame of the free joint's
    # angular velocity).
    import mujoco

    cfg = config_lib.TaskConfig(
        name="walk", desired="pd", kp=100.0, kd=20.0, joint_kp=2000.0, joint_kd=50.0
    )
    task = tasks.make(solo, cfg, 0.004)
    k, t = 2, 40
    ref = jax.tree.map(lambda x: np.asarray(x[k, t], np.float64), task.reference)
    rng = np.random.default_rng(0)
    qpos = ref.qpos.copy()
    qpos[:3] += [0.01, -0.02, 0.005]
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.array([0.3, -0.2, 1.0]) / np.sqrt(1.13), 0.05)
    mujoco.mju_mulQuat(qpos[3:7], ref.qpos[3:7], turn)
    qpos[7:] += rng.normal(0.0, 0.03, 12)
    qvel = ref.qvel + rng.normal(0.0, 0.2, 18)
    rotation = np.zeros(3)
    mujoco.mju_subQuat(rotation, ref.qpos[3:7], qpos[3:7])
    error = np.concatenate([ref.qpos[:3] - qpos[:3], rotation, ref.qpos[7:] - qpos[7:]])
    gains_p = np.array([100.0] * 6 + [2000.0] * 12)
    gains_d = np.array([20.0] * 6 + [50.0] * 12)
    expected = (ref.qacc + gains_p * error + gains_d * (ref.qvel - qvel)) * 0.004
    ref_t = jax.tree.map(lambda x: x[k, t], task.reference)
    qpos32, qvel32 = qpos.astype(np.float32), qvel.astype(np.float32)
    desired = np.asarray(task.desired(ref_t, qpos32, qvel32, None))
    np.testing.assert_allclose(desired[:18], expected, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(desired[18:], ref.force, atol=1e-6)
    # joint_kp / joint_kd None: the base gains on the joints too.
    pd = config_lib.TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0)
    same = tasks.make(solo, pd, 0.004)
    np.testing.assert_allclose(np.asarray(same.desired_kp), 100.0)
    np.testing.assert_allclose(np.asarray(same.desired_kd), 20.0)
    # The values of the task built for cfg given to that task (as the compiled functions
    # get them, cfm_jax.runs.training.Knobs) give its s* bit for bit and leave it as it was.
    assert same.value_names == ("desired_kp", "desired_kd")
    moved = same.with_values(task.values())
    np.testing.assert_array_equal(np.asarray(moved.desired(ref_t, qpos32, qvel32, None)), desired)
    np.testing.assert_allclose(np.asarray(same.desired_kp), 100.0)


def test_falls_are_flagged_when_the_robot_goes_down(walk):
    # Zero torque: the robot collapses; the fall flag and the base error see it.
    out = jax.jit(
        lambda: rollout.run(walk, lambda step, key: 0.0 * step.reference.tau, jax.random.key(0))
    )()
    assert np.all(np.any(np.asarray(out.extras["fell"]), axis=1))
    assert float(np.max(np.abs(np.asarray(out.tracking_error[..., 2])))) > 0.1
    # A fallen robot gives no more data (its body has no floor contact and sinks): the
    # steps that become data end before the first fallen step of each target (plain loop).
    valid = np.asarray(algorithm.data_mask(out))
    fell, active = np.asarray(out.extras["fell"]), np.asarray(out.extras["active"])
    for k in range(walk.targets):
        first_fall = next(i for i in range(walk.steps) if fell[k, i])
        expected = np.zeros(walk.steps, bool)
        expected[:first_fall] = True
        np.testing.assert_array_equal(valid[k], expected & active[k])
    assert 0 < valid.sum() < active.sum()


def test_training_fall_flag_counts_the_knees_as_the_reference_checks_do(walk, solo):
    """The metric ``fell`` and the terminal step use the library's one fall rule: a robot
    whose knees are at the floor (base sunk to 0.11 m: knee axes just below the floor; to
    0.115 m: 0-5 mm above it, inside the leg's 8 mm capsule; the base box 8 cm up and the
    base above its 0.10 m limit) has fallen, in training as in the reference checks;
    standing has not."""
    import types

    import mujoco

    m, d = solo.mj_model, mujoco.MjData(solo.mj_model)
    home = m.key("home").qpos.copy()
    cases = [(home, False)]
    for height, knee_low, knee_high in ((0.11, -0.005, 0.0), (0.115, 0.0, 0.005)):
        state = home.copy()
        state[2] = height
        d.qpos[:] = state
        mujoco.mj_kinematics(m, d)
        knee_z = min(d.xpos[m.body(f"{leg}_lower_leg").id][2] for leg in ("FL", "FR", "HL", "HR"))
        assert knee_low < knee_z < knee_high and height - solo12.BASE_HALF[2] > 0.08
        cases.append((state, True))
    reference = types.SimpleNamespace(active=jnp.float32(1.0), force=jnp.zeros(12))
    step = types.SimpleNamespace(reference=reference)
    for qpos, expected in cases:
        out = walk.record(step, None, jnp.asarray(qpos, jnp.float32), None, jnp.zeros(12))
        assert bool(out["fell"]) is expected and bool(out["terminal"]) is expected
        assert bool(solo12.fell(qpos)) is expected  # the reference checks' answer


def test_legged_tasks_refuse_arms_and_slow_control(solo):
    arm = robots.load("iiwa14")
    with pytest.raises(config_lib.ConfigError, match="task.name='walk' .* floating base"):
        tasks.make(arm, config_lib.TaskConfig(name="walk"), 0.01)
    with pytest.raises(config_lib.ConfigError, match=r"task.control_dt=0.01 .* 0.004"):
        tasks.make(solo, config_lib.TaskConfig(name="jump"), 0.01)
    # Targets and start pose come from the recorded references: given ones are refused,
    # not silently ignored.
    targets = config_lib.TaskConfig(name="walk", control_dt=0.004, targets=((0.1,) * 19,))
    with pytest.raises(config_lib.ConfigError, match=r"task.targets=.* not allowed .* 'walk'"):
        tasks.make(solo, targets, 0.004)
    home = config_lib.TaskConfig(name="jump", control_dt=0.004, home=(0.0,) * 19)
    with pytest.raises(config_lib.ConfigError, match=r"task.home=.* not allowed .* 'jump'"):
        tasks.make(solo, home, 0.004)


def test_references_the_robots_own_fall_rule_calls_fallen_are_refused_naming_where(solo):
    """A reference that the robot's fall rule calls fallen at some step cannot judge a
    controller (tracking it perfectly counts as a fall): legged.check_references refuses it,
    naming the reference, the step and the clause. Oracle: the Solo12's 1-s walk, upright as
    recorded, edited by hand to fall at a known step in a known way."""
    legs = legged.legs_of(solo)
    walk = locomotion.walk_reference(1.0)
    legged.check_references([walk], solo, legs)  # as recorded: never fallen
    tipped = walk._replace(qpos=walk.qpos.copy())
    tipped.qpos[120:, 3:7] = (np.cos(0.45), np.sin(0.45), 0.0, 0.0)  # rolled 0.9 rad > 0.8
    with pytest.raises(config_lib.ConfigError) as refused:
        legged.check_references([walk, tipped], solo, legs, "refused: ")
    assert str(refused.value).startswith(
        "refused: its 1-s walk reference falls by the robot's own fall rule at control step "
        "120 of 250 (the base tilted more than 46 deg)"
    )
    pulling = walk._replace(qpos=walk.qpos.copy(), foot_force=walk.foot_force.copy())
    pulling.foot_force[7, 2, 2] = -1.0  # the HL foot pulls the floor down at step 7
    pulling.qpos[200:, 2] = 0.05  # and the base is low from step 200 (not reached)
    with pytest.raises(config_lib.ConfigError, match=r"at control step 7 of 250 \(a foot pull"):
        legged.check_references([pulling], solo, legs)


def test_motions_choose_the_references_other_than_the_test_ones(solo):
    """``task.motions`` names the walk durations / jump clearances to follow (the selection
    of defaults runs on motions other than the test ones); oracle: the references
    :mod:`cfm_jax.tasks.locomotion` records for those parameters, and the test set for None."""
    config = config_lib.TaskConfig(name="jump", control_dt=0.004, motions=(0.065, 0.125))
    jump = tasks.make(solo, config, 0.004)
    expected = [locomotion.jump_reference(h) for h in (0.065, 0.125)]
    assert jump.targets == 2 and jump.steps == max(r.horizon for r in expected)
    for got, ref in zip(jump.references, expected, strict=True):
        np.testing.assert_array_equal(got.qpos, ref.qpos)
    clearances = [locomotion.jump_clearance(r) for r in jump.references]
    np.testing.assert_allclose(clearances, [0.065, 0.125], atol=0.002)
    assert not set(np.round(clearances, 3)) & set(locomotion.JUMP_HEIGHTS)
    # None: the 5 test references.
    default = config_lib.TaskConfig(name="jump", control_dt=0.004)
    assert [r.params for r in tasks.make(solo, default, 0.004).references] == [
        r.params for r in locomotion.default_jumps()
    ]


def test_motion_family_selection_follows_the_selection_gait(solo):
    """``task.motion_family="selection"``: the references of locomotion.SELECTION_MOTIONS
    for the same durations (oracle: locomotion.walk_reference with those parameters); the
    arm tasks refuse it, naming the field."""
    config = config_lib.TaskConfig(name="walk", motions=(1.25,), motion_family="selection")
    walk = tasks.make(solo, config, 0.004)
    expected = locomotion.walk_reference(1.25, **locomotion.SELECTION_MOTIONS["walk"])
    np.testing.assert_array_equal(walk.references[0].qpos, expected.qpos)
    assert json.loads(walk.references[0].params)["speed"] == 0.2
    with pytest.raises(config_lib.ConfigError, match=r"task.motion_family='selection' .* 'test'"):
        config_lib.TaskConfig(name="inverse_dynamics", motion_family="selection")
    with pytest.raises(config_lib.ConfigError, match=r"task.motion_family='train' .* one of"):
        config_lib.TaskConfig(name="walk", motion_family="train")


def test_a_quadruped_whose_legs_are_not_the_solo12s_is_read_from_its_file(tmp_path):
    """The Solo12's closed-form legs serve a robot whose kinematics are the Solo12's (a
    Solo12 with other physics: friction); any other quadruped (a front-left shin 1 cm
    longer, a joint renamed) is read from its file (locomotion.Legs.of) and its references
    made with its own kinematics. The oracle of what differs is MuJoCo's own kinematics of
    the edited file: the longer shin's foot stands 1 cm lower than the closed form's."""
    text = Path(solo12.model_path()).read_text()
    knee = '<body name="FL_lower_leg" pos="0 0.03745 -0.16">'
    assert text.count(knee) == 1 and text.count('friction="1.0 ') == 2
    edits = {
        "longer_shin.xml": text.replace(knee, knee.replace("-0.16", "-0.17")),
        "renamed.xml": text.replace('"HR_KFE"', '"HR_knee"'),  # and its motor's
        "slippery.xml": text.replace('friction="1.0 ', 'friction="0.5 '),
    }
    for name, edited in edits.items():
        (tmp_path / name).write_text(edited)
    with pytest.raises(config_lib.ConfigError, match=r"its joints are .*'HR_knee'"):
        solo12.check_model(robots.load(str(tmp_path / "renamed.xml")).mj_model, "renamed")
    solo12.check_model(robots.load(str(tmp_path / "slippery.xml")).mj_model)  # accepted
    assert legged.legs_of(robots.load(str(tmp_path / "slippery.xml"))).sites is not None
    longer = robots.load(str(tmp_path / "longer_shin.xml"))
    legs = legged.legs_of(longer)
    assert legs.sites is None  # read from the file, not the Solo12's closed forms
    moved = legs.nominal - solo12.hip_positions()

    def fl_foot(model):  # MuJoCo's kinematics at the keyframe, base at the origin, level
        data = mujoco.MjData(model)
        data.qpos[:] = model.key("home").qpos
        data.qpos[:3], data.qpos[3:7] = 0.0, (1.0, 0.0, 0.0, 0.0)
        mujoco.mj_kinematics(model, data)
        return data.geom_xpos[model.geom("FL_foot").id].copy()

    expected = fl_foot(longer.mj_model) - fl_foot(solo12.load_model())
    assert np.linalg.norm(expected) == pytest.approx(0.01)  # the shin's extra centimetre
    np.testing.assert_allclose(moved[0], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(moved[1:], 0.0, atol=1e-9)
    assert legged.fits(longer) == ""  # MJX builds it: the defaults run


def test_a_published_quadruped_runs_the_walk_with_its_oracle_on_the_reference():
    """The Unitree Go2 as MuJoCo Menagerie publishes it (no ground, no foot sensors; loading
    adds them): the walk task reads its legs, feet and fall rule from the file, and its
    baselines roll out on the native simulator: the oracle (the reference's own feed-forward
    and PD) retraces the recorded reference to round-off and does not fall; PD-only, the
    feedback alone, tracks worse. MJX cannot build the Go2 (cylinder-box collisions), which
    robot check and ``fits`` say: the defaults' rigid-body forward model needs it."""
    from tiny import tiny_config

    go2 = robots.load(str(QUADRUPEDS / "go2.xml"))
    assert go2.added == (
        "a ground plane 'floor' at z = 0",
        "a contact sensor per foot (FL: FL, FR: FR, HL: RL, HR: RR on 'floor')",
    )
    np.testing.assert_array_equal(go2.home, go2.mj_model.key("home").qpos)
    assert "forward.kind='rigid_body' needs MJX" in legged.fits(go2)
    config = tiny_config(iterations=1, seeds=1).replace(
        robot=str(QUADRUPEDS / "go2.xml"),
        task=config_lib.TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0, motions=(0.3,)),
    )
    experiment = training.Experiment(config)
    task = experiment.task
    # the feet's sensors in the legs' order FL, FR, HL, HR, as loading added them
    adr = [go2.mj_model.sensor(f"{leg}_contact").adr[0] for leg in ("FL", "FR", "HL", "HR")]
    np.testing.assert_array_equal(task.sensor_rows.reshape(4, 10)[:, 0], adr)
    assert task.gain_p.shape == (12,)  # the Go2's per-joint reference gains
    base = experiment.baselines().set_index("baseline")
    assert base.loc["oracle", "tracking_mse"] < 1e-10 and base.loc["oracle", "fell"] == 0
    assert base.loc["pd_only", "tracking_mse"] > 1e3 * base.loc["oracle", "tracking_mse"]


def test_a_servo_driven_quadruped_converted_at_load_time_runs_the_walk_with_its_oracle():
    """ANYmal C as MuJoCo Menagerie publishes it: position servos, no keyframe, no ground.
    Loaded with robot_actuators='torque', one MjSpec takes both edits (servos to torque
    motors of the servos' 80 N m force range, ground and foot sensors added), home is its
    computed standing pose, and the walk's references are simulated on that loaded model
    (the oracle: the references of locomotion.walk_reference on robot.mj_model, bit for
    bit). Its baselines on the native simulator: the oracle (the reference's feed-forward and
    PD) retraces the reference to round-off and does not fall; PD-only tracks worse."""
    from tiny import tiny_config

    path = str(QUADRUPEDS / "anymal_c.xml")
    anymal = robots.load(path, actuators="torque")
    assert len(anymal.converted) == 12 and anymal.added[0] == "a ground plane 'floor' at z = 0"
    assert "FL: FL_foot" in anymal.added[1]
    np.testing.assert_array_equal(anymal.torque_limit, np.full(12, 80.0))
    found = quadruped.describe(anymal.mj_model)
    assert found.standing_from.startswith("computed")
    np.testing.assert_array_equal(anymal.home, found.standing)
    assert "forward.kind='rigid_body' needs MJX" in legged.fits(anymal)
    config = tiny_config(iterations=1, seeds=1).replace(
        robot=path,
        robot_actuators="torque",
        task=config_lib.TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0, motions=(0.3,)),
    )
    experiment = training.Experiment(config)
    (reference,) = experiment.task.references
    expected = locomotion.walk_reference(0.3, model=anymal.mj_model)
    for got, want in zip(reference, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(reference.qpos[0], anymal.home)
    assert np.abs(reference.tau).max() <= 80.0
    base = experiment.baselines().set_index("baseline")
    assert base.loc["oracle", "tracking_mse"] < 1e-10 and base.loc["oracle", "fell"] == 0
    assert base.loc["pd_only", "tracking_mse"] > 1e3 * base.loc["oracle", "tracking_mse"]


@pytest.mark.parametrize("name", ["jump", "walk"])
def test_legged_task_trains_end_to_end_with_masked_metrics(name):
    from golden import assert_bit_identical
    from tiny import tiny_config

    config = tiny_config(iterations=1, seeds=1).replace(
        robot="solo12",
        task=config_lib.TaskConfig(name=name, desired="pd", kp=100.0, kd=20.0),
    )
    # The legged tasks' torque scaling (for_task's), on which the golden record was made.
    config = config.replace(loop=dataclasses.replace(config.loop, torque_scale="limit"))
    experiment = training.Experiment(config)
    result = cfm_jax.train(config, progress=False, experiment=experiment)
    frame = result.metrics
    horizons = [r.horizon for r in experiment.task.references]
    first = frame[frame.iteration == 0]
    added, fell = first.transitions_added.to_numpy(), first.fell.to_numpy()
    # Every step of a horizon is data, up to a fall (a tiny controller may fall).
    np.testing.assert_array_equal(added[fell == 0], np.asarray(horizons)[fell == 0])
    assert np.all(added[fell == 1] < np.asarray(horizons)[fell == 1])
    for column in ("force_mse", "fell", "base_position_mse", "tracking_mse"):
        assert np.all(np.isfinite(frame[column]))
    base = result.baselines.set_index(["baseline", "target"])
    assert base.loc["oracle"].fell.max() == 0.0
    assert base.loc["oracle"].tracking_mse.max() < 1e-8
    assert_bit_identical(name, result)
