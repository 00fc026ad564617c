"""Locomotion references, their cache and replay (cfm_jax/tasks/locomotion.py) on robots/solo12.xml.

Oracles: MuJoCo C (``mj_inverse`` and re-simulation with the library's native stepper for
dynamic consistency) and the requested task quantities (distance, jump height). The robot's
own kinematics, contact forces and fall rule are tested in tests/test_solo12.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cfm_jax.sim import solo12
from cfm_jax.sim.native import Stepper
from cfm_jax.tasks import locomotion as L


@pytest.fixture(scope="session")
def model():
    return solo12.load_model()


@pytest.fixture(scope="session")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("references")


@pytest.fixture(scope="session")
def walks(cache):
    return L.default_walks(cache=cache)


@pytest.fixture(scope="session")
def jumps(cache):
    return L.default_jumps(cache=cache)


def _tilt(qpos):
    return np.arccos(np.clip(solo12.quat_to_mat(qpos[..., 3:7])[..., 2, 2], -1, 1))


# ---- references -------------------------------------------------------------------------------
def test_reference_shapes_and_definitions(walks, jumps):
    for ref in walks + jumps:
        t = ref.horizon
        assert ref.control_dt == 0.004 and (ref.kp, ref.kd) == (5.0, 0.1)
        assert ref.qpos.shape == (t + 1, 19) and ref.qvel.shape == (t + 1, 18)
        assert ref.qacc.shape == (t, 18) and ref.tau.shape == (t, 12)
        assert ref.foot_force.shape == (t + 1, 4, 3) and ref.contact.shape == (t + 1, 4)
        assert ref.foot_force_mean.shape == (t, 4, 3)
        assert ref.desired_next.shape == (t, 30)
        np.testing.assert_allclose(ref.qacc, np.diff(ref.qvel, axis=0) / ref.control_dt)
        assert np.abs(ref.tau).max() <= 2.7
        assert not solo12.fell(ref.qpos, ref.foot_force).any()
    assert [r.duration for r in walks] == pytest.approx(list(L.WALK_DURATIONS))


def test_references_are_dynamically_consistent_with_the_native_stepper(model, walks, jumps):
    """Each reference step re-simulated with the library's own stepper (MuJoCo C, torque held
    for control_dt) from the reference state lands on the next reference state, and its
    sensordata gives the reference contact forces. Stepper output is float32 and it
    restarts the constraint solver each call; measured errors < 1.3e-7 (qpos), 1e-6
    (qvel), 1e-6 N, so tolerances 1e-6 / 1e-5 / 1e-4 N."""
    stepper = Stepper(model, n_sub=2)
    for ref in walks + jumps:
        qpos, qvel, sensors = stepper(ref.qpos[:-1], ref.qvel[:-1], ref.tau)
        np.testing.assert_allclose(qpos, ref.qpos[1:], atol=1e-6, rtol=0)
        np.testing.assert_allclose(qvel, ref.qvel[1:], atol=1e-5, rtol=0)
        force = solo12.foot_forces(sensors.astype(np.float64))
        np.testing.assert_allclose(force.mean(axis=1), ref.foot_force_mean, atol=1e-4, rtol=0)
        np.testing.assert_allclose(force[:, 0], ref.foot_force[:-1], atol=1e-4, rtol=0)
        np.testing.assert_array_equal(
            solo12.foot_contact(sensors[:, 0].astype(np.float64)), ref.contact[:-1]
        )


@pytest.mark.parametrize("kind", ["walk", "jump"])
def test_physics_recording_satisfies_inverse_dynamics(model, kind):
    """mj_inverse on every recorded physics step returns the applied torques (and zero on
    the unactuated base): measured residual ~1e-13 N (m); tolerance 1e-8 (solver tolerance)."""
    if kind == "walk":
        _, rec = L.simulate_walk(L.WalkParams(duration=1.5), model)
    else:
        _, rec = L.simulate_jump(L.JumpParams(height=0.14, push_force=23.0), model)
    residual = L.inverse_dynamics_residual(rec, model)
    assert np.abs(residual).max() < 1e-8
    np.testing.assert_allclose(np.diff(rec.qvel, axis=0), rec.qacc * model.opt.timestep)
    contact = solo12.foot_contact(rec.sensordata)
    if kind == "walk":
        assert contact.any(axis=1).all()  # a trot always has a foot on the ground
    else:
        # A jump starts and lands on all four feet and has a flight phase. Its longest
        # airborne stretch: measured 151 steps (0.30 s; free fall to and from a 0.14 m apex
        # takes 0.34 s); required: over 0.2 s (a 5 cm free-fall apex).
        assert contact[0].all() and contact[-1].all()
        airborne = np.concatenate([[0], (~contact.any(axis=1)).astype(int), [0]])
        edges = np.flatnonzero(np.diff(airborne))
        longest = (edges[1::2] - edges[::2]).max(initial=0) * model.opt.timestep
        assert longest > 0.2


def test_replay_reproduces_each_reference(model, walks, jumps):
    """Feed-forward torques plus the stated PD from the reference's own start reproduce the
    reference exactly (the feedback term is then zero at every step)."""
    for ref in walks[:1] + walks[-1:] + jumps:
        run = L.replay(ref, model)
        assert not run.fell
        np.testing.assert_allclose(run.qpos, ref.qpos, atol=1e-9, rtol=0)
        np.testing.assert_allclose(run.foot_force, ref.foot_force, atol=1e-6, rtol=0)


def test_replay_from_perturbed_start_stays_close(model, walks, jumps):
    """Start 5 mm higher with +-0.03 rad on alternate joints; the stated feedback (kp 5,
    kd 0.1) around the reference keeps every run upright and close. Measured: base position
    error <= 3.3 cm (highest jump; walks <= 1.4 cm), joint RMS <= 0.026 rad. Tolerances: base
    5 cm (a fifth of the standing height), joint RMS 0.05 rad, no fall."""
    for ref in walks + jumps:
        q0 = ref.qpos[0].copy()
        q0[2] += 0.005
        q0[7:] += 0.03 * np.where(np.arange(12) % 2, 1.0, -1.0)
        run = L.replay(ref, model, qpos0=q0)
        assert not run.fell
        assert np.abs(run.qpos[:, :3] - ref.qpos[:, :3]).max() < 0.05
        assert np.sqrt(np.mean((run.qpos[:, 7:] - ref.qpos[:, 7:]) ** 2)) < 0.05


def test_walks_make_forward_progress(walks):
    """Forward distance at least half the commanded one (measured 55 % for the 1 s walk that
    is mostly speed ramp, 82 % for 3 s), cruise speed >= 80 % of 0.3 m/s over the last
    second, straight (|y| < 3 cm, yaw < 5 deg) and level (tilt < 5 deg)."""
    distances = []
    for ref in walks:
        params = L.WalkParams(**json.loads(ref.params))
        x = ref.qpos[-1, 0] - ref.qpos[0, 0]
        assert x >= 0.5 * L.commanded_distance(params)
        distances.append(x)
        assert np.abs(ref.qpos[:, 1]).max() < 0.03
        rot = solo12.quat_to_mat(ref.qpos[-1, 3:7])
        assert abs(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))) < 5
        assert np.degrees(_tilt(ref.qpos)).max() < 5
        assert ref.contact.sum(axis=1).min() >= 2  # a trot: always at least a diagonal pair
        if ref.duration >= 2.0:
            last = int(round(1.0 / ref.control_dt))
            speed = (ref.qpos[-1, 0] - ref.qpos[-1 - last, 0]) / 1.0
            assert speed >= 0.8 * 0.3
    assert np.all(np.diff(distances) > 0.1)  # longer horizons walk further


def test_jumps_reach_the_requested_height_and_land(model, jumps):
    """Foot clearance (lowest foot bottom above the floor at the apex) within 20 % of the
    requested height (the push force is bisected to 2 %), all four feet airborne at the apex,
    upright landing back at standing height."""
    home_z = model.key("home").qpos[2]
    for ref, height in zip(jumps, L.JUMP_HEIGHTS, strict=True):
        clearance = L.jump_clearance(ref)
        assert clearance >= 0.8 * height and abs(clearance - height) <= 0.2 * height
        assert abs(clearance - height) <= 0.02 * height
        assert (~ref.contact).all(axis=1).any()  # a flight phase
        assert ref.qpos[:, 2].max() - home_z >= 0.8 * height  # the base rose too
        assert ref.contact[-1].all()
        assert abs(ref.qpos[-1, 2] - home_z) < 0.01
        assert np.degrees(_tilt(ref.qpos)).max() < 15
        assert np.abs(ref.qpos[-1, :2]).max() < 0.03  # vertical: little drift


def test_determinism_and_cache(tmp_path, model):
    a, _ = L.simulate_walk(L.WalkParams(duration=0.5), model)
    b, _ = L.simulate_walk(L.WalkParams(duration=0.5), model)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    first = L.walk_reference(0.5, cache=tmp_path)
    files = list(tmp_path.glob("walk-*.npz"))
    assert len(files) == 1
    stamp = files[0].stat().st_mtime_ns
    again = L.walk_reference(0.5, cache=tmp_path)
    assert files[0].stat().st_mtime_ns == stamp  # loaded, not recomputed
    for x, y, z in zip(first, again, a, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)
    L.walk_reference(0.5, speed=0.2, cache=tmp_path)
    assert len(list(tmp_path.glob("walk-*.npz"))) == 2
    # a different model file gives a different key
    other = tmp_path / "solo12_copy.xml"
    other.write_text(open(solo12.model_path()).read().replace('friction="1 1', 'friction="0.9 0.9'))
    L.walk_reference(0.5, cache=tmp_path, model_file=str(other))
    assert len(list(tmp_path.glob("walk-*.npz"))) == 3


def test_references_of_a_loaded_robots_model_are_its_files_bit_for_bit(tmp_path, model):
    """The legged tasks simulate their references on the robot's loaded model (``model=``);
    for the Solo12 that is the file's model, so the references are the same bit for bit and
    share one cache entry (the key holds the model's bytes, mj_saveModel). The same file
    with only a comment added compiles to the same model: the same entry; the model at
    another timestep is another model: another entry, another motion."""
    import copy

    from cfm_jax.sim import robots

    solo = robots.load("solo12")
    assert L.model_bytes(solo.mj_model) == L.model_bytes(model)
    from_model = L.walk_reference(0.5, model=solo.mj_model, cache=tmp_path)
    from_file = L.walk_reference(0.5, cache=tmp_path)
    fresh = L.walk_reference(0.5, use_cache=False)
    assert len(list(tmp_path.glob("walk-*.npz"))) == 1
    for x, y, z in zip(from_model, from_file, fresh, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)
    commented = tmp_path / "solo12_commented.xml"
    commented.write_text(Path(solo12.model_path()).read_text() + "<!-- a comment -->\n")
    L.walk_reference(0.5, cache=tmp_path, model_file=str(commented))
    assert len(list(tmp_path.glob("walk-*.npz"))) == 1
    finer = copy.deepcopy(solo.mj_model)
    finer.opt.timestep = 0.001
    other = L.walk_reference(0.5, model=finer, cache=tmp_path)
    assert len(list(tmp_path.glob("walk-*.npz"))) == 2
    assert not np.array_equal(other.qpos, from_model.qpos)
    with pytest.raises(ValueError, match="model or model_file, not both"):
        L.walk_reference(0.5, model=model, model_file=solo12.model_path(), use_cache=False)


def test_an_edited_generator_is_not_answered_from_the_cache(tmp_path, monkeypatch):
    """The generator's source is part of the key: after an edit of one of its files (here a
    copy of the module with one added comment standing for the edit) the same call
    simulates anew instead of loading what the code before the edit recorded."""
    L.walk_reference(0.2, cache=tmp_path)
    assert len(list(tmp_path.glob("walk-*.npz"))) == 1
    L.walk_reference(0.2, cache=tmp_path)  # unchanged source: the same entry
    assert len(list(tmp_path.glob("walk-*.npz"))) == 1
    edited = tmp_path / "locomotion_edited.py"
    edited.write_bytes(Path(L.__file__).read_bytes() + b"# an edit\n")
    monkeypatch.setattr(L, "GENERATOR_FILES", (edited, *L.GENERATOR_FILES[1:]))
    L.walk_reference(0.2, cache=tmp_path)
    assert len(list(tmp_path.glob("walk-*.npz"))) == 2


def test_cache_dir_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(L.CACHE_ENV, str(tmp_path / "x"))
    assert L.cache_dir() == tmp_path / "x"
    assert L.cache_dir(tmp_path) == tmp_path
    monkeypatch.delenv(L.CACHE_ENV)
    assert L.cache_dir() == Path.home() / ".cache" / "cfm_jax" / "references"


# ---- selection motions (issue 43) ----------------------------------------------------------

# The selection's walk durations and jump clearances (experiments/select_defaults.py).
SELECTION_WALKS = (1.25, 1.75, 2.25, 2.75)
SELECTION_JUMPS = (0.065, 0.095, 0.125, 0.155)
WINDOW = int(round(0.25 / L.CONTROL_DT))  # 0.25 s


def test_closest_window_equals_a_plain_loop_over_every_pair_of_windows():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(23, 3)), rng.normal(size=(17, 3))
    b[4:12] = a[9:17] + 0.01  # a near-copy of 8 steps at another time

    def plain(a, b, w):
        return min(
            np.sqrt(np.mean((a[t : t + w] - b[s : s + w]) ** 2))
            for t in range(len(a) - w + 1)
            for s in range(len(b) - w + 1)
        )

    for window in (1, 5, 8, 17):
        assert L.closest_window(a, b, window) == pytest.approx(plain(a, b, window), rel=1e-9)
    assert L.closest_window(a, b, 8) == pytest.approx(0.01, rel=1e-9)
    with pytest.raises(ValueError, match="window=18: between 1 and 17"):
        L.closest_window(a, b, 18)


@pytest.mark.parametrize("kind", ["walk", "jump"])
def test_selection_motions_hold_no_window_of_a_test_motion(cache, walks, jumps, kind):
    """Disjoint in content, not in parameters: no 0.25 s window of a test reference's joint
    positions is within DISJOINT_RMS of any window of a selection reference, at any shift in
    time. The selection run's motions (the same durations and heights in the test gait) fail
    this check: its walks are prefixes of the test walks, and its jumps begin with the test
    jumps' settle and crouch (both distance 0)."""
    make = L.walk_reference if kind == "walk" else L.jump_reference
    values = SELECTION_WALKS if kind == "walk" else SELECTION_JUMPS
    tests = walks if kind == "walk" else jumps

    def closest(selection):
        return min(L.closest_window(t.qpos[:, 7:], s.qpos[:, 7:], WINDOW)
                   for t in tests for s in selection)  # fmt: skip

    before = closest([make(v, cache=cache) for v in values])
    assert before < L.DISJOINT_RMS / 10  # the check catches today's selection motions
    now = [make(v, cache=cache, **L.SELECTION_MOTIONS[kind]) for v in values]
    assert closest(now) > L.DISJOINT_RMS
    if kind == "walk":  # and they walk as the test walks do: half the commanded distance
        for ref in now:
            params = L.WalkParams(**json.loads(ref.params))
            assert L.summary(ref)["distance_m"] >= 0.5 * L.commanded_distance(params)
            assert np.degrees(_tilt(ref.qpos)).max() < 5
    else:  # and jump to the requested clearance (to 3 %) and land upright
        got = [L.jump_clearance(r) for r in now]
        np.testing.assert_allclose(got, values, rtol=0.03)
        assert all(np.degrees(_tilt(r.qpos[-1])) < 10 for r in now)
