"""Checkpoints, resume after SIGKILL, divergence guards (cfm_jax/runs/checkpoint.py, training.py).

Oracles: an uninterrupted run of the same config (bit-for-bit metrics), the files on disk,
and faults injected on purpose: a real SIGKILL of a training subprocess, a truncated
checkpoint file, a NaN put into the simulator's state on the host and into the parameters.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from tiny import cli_command, tiny_config

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax.learning import algorithm
from cfm_jax.runs import checkpoint, training
from cfm_jax.sim import native

CFG = tiny_config(iterations=4, checkpoint_keep=2)
STEPS = 30  # control steps per rollout (0.3 s at 0.01 s)


@pytest.fixture(scope="module")
def experiment():
    """CFG's Experiment, shared by the runs whose point is not a fresh Experiment: the
    uninterrupted run, the refused and resumed runs of a damaged copy of it, the resume
    after the SIGKILL of a training subprocess, the NaN in the parameters. The determinism
    check builds its own."""
    return cfm_jax.Experiment(CFG)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory, experiment):
    out = tmp_path_factory.mktemp("full")
    return cfm_jax.train(CFG, progress=False, out_dir=str(out), experiment=experiment), out


def test_checkpoints_written_and_pruned(uninterrupted):
    _, out = uninterrupted
    ckpt = checkpoint.Checkpointer(str(out / "checkpoints"), keep=2)
    assert ckpt.steps() == [3, 4]  # every iteration, the last 2 kept
    assert all(ckpt.problem(s) is None for s in ckpt.steps())


def test_same_seed_twice_identical(uninterrupted):
    again = cfm_jax.train(CFG, progress=False, experiment=cfm_jax.Experiment(CFG))
    pd.testing.assert_frame_equal(again.metrics, uninterrupted[0].metrics, check_exact=True)


SCRIPT = """
import json, sys
import cfm_jax
from cfm_jax import config
cfg = config.from_dict(json.load(open(sys.argv[1])))
cfm_jax.train(cfg, progress=False, out_dir=sys.argv[2])
print("FINISHED")
"""


def test_sigkill_then_resume_gives_identical_metrics(uninterrupted, experiment, tmp_path):
    config_file = tmp_path / "config.json"
    config_file.write_text(json.dumps(config_lib.to_dict(CFG)))
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-c", SCRIPT, str(config_file), str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    manifest = out / "checkpoints" / "2" / checkpoint.MANIFEST
    deadline = time.time() + 300
    while not manifest.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)  # mid-run: after iteration 2 of 4
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    partial = pd.read_csv(out / "metrics.csv")
    assert partial.iteration.max() < CFG.loop.iterations  # it really was interrupted
    # The files the killed process left are all the resume has of it; this process's
    # compiled programs (the module's Experiment) only run it.
    resumed = cfm_jax.train(CFG, progress=False, resume=str(out), experiment=experiment)
    pd.testing.assert_frame_equal(resumed.metrics, uninterrupted[0].metrics, check_exact=True)
    on_disk = pd.read_csv(out / "metrics.csv")
    assert len(on_disk) == len(uninterrupted[0].metrics)


def test_resume_with_a_different_config_is_refused(uninterrupted):
    _, out = uninterrupted
    other = CFG.replace(seed=5, task=config_lib.TaskConfig(duration=0.3, kp=50.0))
    with pytest.raises(config_lib.ConfigError) as info:
        cfm_jax.train(other, progress=False, resume=str(out))
    message = str(info.value)
    assert "seed (0 in the run, 5 now)" in message
    assert "task.kp (100.0 in the run, 50.0 now)" in message
    assert "loop" not in message  # only the fields that differ


def test_a_finished_run_continued_for_more_iterations_equals_the_longer_run(
    uninterrupted, experiment, tmp_path
):
    """Issue 67: a run that finished at 2 iterations, resumed with loop.iterations 4, gives
    the metrics of the run that went to 4 at once, bit for bit: its data set is restored at
    its own capacity and grown, its iteration 2 (a final evaluation before) is run with the
    fits. A run cannot be continued for fewer iterations."""
    short = CFG.replace(loop=dataclasses.replace(CFG.loop, iterations=2))
    out = tmp_path / "short"
    first = cfm_jax.train(short, progress=False, out_dir=str(out))
    assert first.metrics.iteration.max() == 2 and first.metrics.forward_loss.isna().any()
    continued = cfm_jax.train(CFG, progress=False, resume=str(out), experiment=experiment)
    pd.testing.assert_frame_equal(continued.metrics, uninterrupted[0].metrics, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "metrics.csv"), pd.read_csv(uninterrupted[1] / "metrics.csv")
    )
    assert json.loads((out / "config.json").read_text())["loop"]["iterations"] == 4
    with pytest.raises(config_lib.ConfigError, match="goes to 4 iterations; a run continues"):
        cfm_jax.train(short, progress=False, resume=str(out))


def test_resume_from_a_directory_without_a_run(tmp_path):
    with pytest.raises(config_lib.ConfigError, match="no config.json there"):
        cfm_jax.train(CFG, progress=False, resume=str(tmp_path))


def _copy_run(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_truncated_checkpoint_detected_and_previous_offered(uninterrupted, experiment, tmp_path):
    out = _copy_run(uninterrupted[1], tmp_path / "run")
    step_dir = out / "checkpoints" / "4"
    manifest = json.loads((step_dir / checkpoint.MANIFEST).read_text())
    biggest = max(manifest, key=lambda name: manifest[name][0])
    path = step_dir / biggest
    path.write_bytes(path.read_bytes()[: manifest[biggest][0] // 2])
    with pytest.raises(checkpoint.CheckpointError) as info:
        cfm_jax.train(CFG, progress=False, resume=str(out), experiment=experiment)
    message = str(info.value)
    assert "checkpoint step 4 is not usable" in message and "truncated" in message
    assert str(path) in message
    assert "the previous valid checkpoint is step 3" in message


def test_incomplete_last_step_is_skipped_on_resume(uninterrupted, experiment, tmp_path):
    # A kill between Orbax's commit and the manifest leaves a step without manifest.
    out = _copy_run(uninterrupted[1], tmp_path / "run")
    os.remove(out / "checkpoints" / "4" / checkpoint.MANIFEST)
    with pytest.warns(UserWarning, match="skipping checkpoint step 4"):
        resumed = cfm_jax.train(CFG, progress=False, resume=str(out), experiment=experiment)
    pd.testing.assert_frame_equal(resumed.metrics, uninterrupted[0].metrics, check_exact=True)


def test_resume_with_no_complete_checkpoint_starts_from_the_beginning(
    uninterrupted, experiment, tmp_path
):
    # A kill while the first checkpoint was written (seen in a study) leaves one step without
    # manifest and nothing else: resume removes it, says so, and trains from the beginning,
    # as a fresh run of the same config and seed does (the uninterrupted run's tables).
    import shutil

    out = _copy_run(uninterrupted[1], tmp_path / "run")
    steps = sorted(int(p.name) for p in (out / "checkpoints").iterdir() if p.name.isdigit())
    for step in steps[1:]:
        shutil.rmtree(out / "checkpoints" / str(step))
    os.remove(out / "checkpoints" / str(steps[0]) / checkpoint.MANIFEST)
    os.remove(out / "metrics.csv")
    with pytest.warns(UserWarning) as caught:
        resumed = cfm_jax.train(CFG, progress=False, resume=str(out), experiment=experiment)
    said = " ".join(str(w.message) for w in caught)
    assert f"skipping checkpoint step {steps[0]}" in said
    assert "no complete checkpoint" in said and "starts from the beginning" in said
    pd.testing.assert_frame_equal(resumed.metrics, uninterrupted[0].metrics, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "metrics.csv"),
        pd.read_csv(uninterrupted[1] / "metrics.csv"),
        check_exact=True,
    )


def _poison_the_simulator(monkeypatch):
    """Put a NaN into the state MuJoCo returns for the first batch element (seed 0,
    target 0) at control step 9 of the rollout of iteration index 1 (the second one)."""
    original = native.Stepper.__call__
    calls = {"n": 0}
    babbling_calls = STEPS  # one batched call per control step

    def poisoned(self, qpos, qvel, ctrl):
        q, qd, sensors = original(self, qpos, qvel, ctrl)
        calls["n"] += 1
        if calls["n"] == babbling_calls + STEPS + 10:
            q = q.copy()
            q.reshape(-1, q.shape[-1])[0, 0] = np.nan
        return q, qd, sensors

    monkeypatch.setattr(native.Stepper, "__call__", poisoned)


@pytest.fixture(scope="module")
def nan_run(tmp_path_factory):
    """A run of CFG whose rollout (seed 0, target 0, iteration index 1) diverges, and its
    Experiment: a fresh one, whose babbling calls the simulator (the fault counts the calls).
    """
    out = tmp_path_factory.mktemp("nan_sim")
    experiment = cfm_jax.Experiment(CFG)
    with pytest.MonkeyPatch.context() as monkeypatch:
        _poison_the_simulator(monkeypatch)
        result = cfm_jax.train(CFG, progress=False, out_dir=str(out), experiment=experiment)
    return result, out, experiment  # no exception


def test_nan_in_simulator_state_is_a_diverged_rollout_not_an_error(uninterrupted, nan_run):
    result, out, _ = nan_run
    m, full = result.metrics, uninterrupted[0].metrics
    hit = (m.seed == 0) & (m.iteration == 1) & (m.target == 0)
    assert m.loc[hit, "diverged"].tolist() == [1.0]
    assert m.loc[hit, "diverged_step"].tolist() == [9.0]
    assert np.isnan(m.loc[hit, "tracking_mse"]).all()
    assert m.loc[hit, "transitions_added"].tolist() == [9.0]  # steps 0..8 are data
    assert (m.loc[~hit, "diverged"] == 0).all() and (m.loc[~hit, "diverged_step"] == -1).all()
    # Everything the divergence cannot reach is bit for bit the run without it: seed 1,
    # and seed 0 up to that rollout (its other targets of iteration 1 included).
    same = (m.seed == 1) | (m.iteration < 1) | ((m.iteration == 1) & (m.target > 0))
    columns = ["tracking_mse", "prediction_error", "finite_fraction", "transitions_added"]
    pd.testing.assert_frame_equal(
        m.loc[same, columns].reset_index(drop=True),
        full.loc[same, columns].reset_index(drop=True),
        check_exact=True,
    )
    # The data set holds only finite rows, 21 fewer for seed 0 than without the NaN.
    size = np.asarray(result.state.data.size)
    assert size[0] == np.asarray(uninterrupted[0].state.data.size)[0] - (STEPS - 9)
    assert np.all(np.isfinite(np.asarray(result.state.data.data.observed)[0, : size[0]]))
    assert result.stopped == []
    assert pd.read_csv(out / "metrics.csv").iteration.max() == CFG.loop.iterations


def test_resume_after_a_divergence_reproduces_its_flags_bit_for_bit(nan_run, tmp_path):
    # Resume from the checkpoint after iteration 3 (the divergence was in iteration index 1):
    # the diverged flags come back from the checkpoint, and iteration 4 learns from the
    # restored data set that lacks the diverged rows; the metrics equal the uninterrupted
    # run's bit for bit, the simulator no longer poisoned.
    result, out, experiment = nan_run
    copy = _copy_run(out, tmp_path / "run")
    import shutil

    shutil.rmtree(copy / "checkpoints" / "4")
    resumed = cfm_jax.train(CFG, progress=False, resume=str(copy), experiment=experiment)
    pd.testing.assert_frame_equal(resumed.metrics, result.metrics, check_exact=True)
    assert resumed.metrics.diverged.sum() == 1
    size = np.asarray(resumed.state.data.size)
    np.testing.assert_array_equal(size, np.asarray(result.state.data.size))


def test_a_sweep_keeps_the_cell_of_a_diverged_seed(nan_run, tmp_path, monkeypatch):
    # The same fault inside a sweep cell: the cell finishes with both seeds and its table
    # is train's under the same fault bit for bit (the diverged flag included).
    from cfm_jax.runs import sweeps

    _poison_the_simulator(monkeypatch)
    swept = sweeps.sweep(CFG, seeds=2, losses="joint", out_dir=str(tmp_path / "s"), progress=False)
    m = swept.metrics
    assert sorted(m.seed.unique()) == [0, 1] and (swept.cells.status == "ran").all()
    columns = list(nan_run[0].metrics.columns)
    pd.testing.assert_frame_equal(
        m[columns].reset_index(drop=True), nan_run[0].metrics, check_exact=True
    )
    assert m.diverged.sum() == 1


def _keys():
    return jax.vmap(jax.random.key)(jnp.arange(2, dtype=jnp.uint32))


def test_nan_in_parameters_stops_that_seed_only_and_names_it(uninterrupted, experiment,
                                                              tmp_path, monkeypatch):  # fmt: skip
    original = training.Experiment.iteration_losses
    calls = {"n": 0}

    def poisoned(self, losses, state, knobs=None, data=None):
        state, metrics = original(self, losses, state, knobs, data)
        calls["n"] += 1
        if calls["n"] == 3:  # iteration index 2, (the only) loss 0, seed 1
            params = jax.tree.map(lambda x: x.at[0, 1].set(jnp.nan), state.controller_params)
            state = state.replace(controller_params=params)
        return state, metrics

    monkeypatch.setattr(training.Experiment, "iteration_losses", poisoned)
    out = tmp_path / "nan_params"
    result = cfm_jax.train(CFG, progress=False, out_dir=str(out), experiment=experiment)
    expected = [{"loss": "joint", "seed": 1, "iteration": 2, "quantity": "controller parameters"}]
    assert result.stopped == expected
    assert json.loads((out / "stopped.json").read_text()) == expected
    m, full = result.metrics, uninterrupted[0].metrics
    # Seed 0 goes on exactly as without the fault; seed 1 has rows up to iteration 1 only.
    pd.testing.assert_frame_equal(
        m[m.seed == 0].reset_index(drop=True),
        full[full.seed == 0].reset_index(drop=True),
        check_exact=True,
    )
    assert sorted(m[m.seed == 1].iteration.unique()) == [0, 1]
    # Seed 1 kept its last good state: finite parameters, the data set of iteration 1.
    leaves = jax.tree.leaves(result.state.controller_params)
    assert all(np.all(np.isfinite(np.asarray(x[1]))) for x in leaves)
    ckpt = checkpoint.Checkpointer(str(out / "checkpoints"))
    assert ckpt.steps()[-1] == CFG.loop.iterations and ckpt.problem(ckpt.steps()[-1]) is None


def test_nan_in_one_loss_of_a_batch_stops_that_loss_seed_only(uninterrupted, experiment,
                                                               monkeypatch):  # fmt: skip
    # Two losses trained together (issue 46); the task loss's seed 1 gets NaN parameters
    # after iteration index 1. Oracle: the uninterrupted joint run (the fixture) for the
    # joint loss, unchanged bit for bit, and the task loss's seed 0 as in a batch without
    # the fault; only (task, seed 1) stops, keeping its last good state.
    original = training.Experiment.iteration_losses
    calls = {"n": 0}

    def poisoned(self, losses, state, knobs=None, data=None):
        state, metrics = original(self, losses, state, knobs, data)
        calls["n"] += losses == ("task",)  # the losses run one after the other
        if losses == ("task",) and calls["n"] == 2:  # iteration index 1, seed 1
            params = jax.tree.map(lambda x: x.at[0, 1].set(jnp.nan), state.controller_params)
            state = state.replace(controller_params=params)
        return state, metrics

    # Both runs on the module's Experiment: the fault is put in by the patched method, and
    # the clean run's compiled programs serve the faulty one.
    clean = cfm_jax.train(CFG, progress=False, losses=("joint", "task"), experiment=experiment)
    monkeypatch.setattr(training.Experiment, "iteration_losses", poisoned)
    result = cfm_jax.train(CFG, progress=False, losses=("joint", "task"), experiment=experiment)
    assert result.stopped == [
        {"loss": "task", "seed": 1, "iteration": 1, "quantity": "controller parameters"}
    ]
    joint = result.of("joint").metrics
    pd.testing.assert_frame_equal(joint, uninterrupted[0].metrics, check_exact=True)
    task, task_clean = result.of("task").metrics, clean.of("task").metrics
    pd.testing.assert_frame_equal(
        task[task.seed == 0].reset_index(drop=True),
        task_clean[task_clean.seed == 0].reset_index(drop=True),
        check_exact=True,
    )
    assert sorted(task[task.seed == 1].iteration.unique()) == [0]
    leaves = jax.tree.leaves(result.of("task").state.controller_params)
    assert all(np.all(np.isfinite(np.asarray(x[1]))) for x in leaves)


def test_cli_resume_continues_each_loss_and_restart_starts_again(tmp_path, monkeypatch,
                                                                 cli_in_process):  # fmt: skip
    # Run the CLI for two iterations of two losses, then leave the files as a kill during
    # the second loss's last iteration would: its last checkpoint gone, its metrics up to
    # iteration 1, the run's table with the first loss only. Resume: the second loss's last
    # iteration reruns (its checkpoint 2 is written again), the finished first loss is not
    # retrained (its checkpoint files untouched), and the final tables are the same.
    # The first run is a real subprocess of the entry point (its tables are the oracle of
    # every later command); the later commands run in this process through cli.main, the
    # same code without a fresh interpreter each, on the one Experiment the process keeps
    # for the run's config (Experiment.shared: the numbers are those of a fresh one,
    # test_train.py), each a separate cfm-jax command on the files the previous one left.
    out = tmp_path / "cli"
    command = cli_command(CFG, tmp_path, out, "joint,task", seeds=2, iterations=2)
    first = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-3000:]
    complete = pd.read_csv(out / "metrics.csv")
    task_complete = pd.read_csv(out / "task" / "metrics.csv")
    import shutil

    monkeypatch.setattr(algorithm, "_SHARED", collections.OrderedDict())  # kept: none yet

    def cli(*flags):
        return cli_in_process(*command[3:], *flags)

    def stamps(folder):
        return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*")}

    joint_before = stamps(out / "joint" / "checkpoints")
    task_one = out / "task" / "checkpoints" / "1"
    task_one_before = stamps(task_one)
    shutil.rmtree(out / "task" / "checkpoints" / "2")
    task_complete[task_complete.iteration <= 1].to_csv(out / "task" / "metrics.csv", index=False)
    complete[complete.loss == "joint"].to_csv(out / "metrics.csv", index=False)
    again = cli("--resume")
    assert again.returncode == 0, again.stderr[-3000:]
    rerun = out / "task" / "checkpoints" / "2"
    assert rerun.is_dir()  # the interrupted iteration ran again and was checkpointed
    assert min(stamps(rerun).values()) > max(task_one_before.values())
    assert stamps(task_one) == task_one_before  # restored from, not rewritten
    assert stamps(out / "joint" / "checkpoints") == joint_before  # finished: not retrained
    pd.testing.assert_frame_equal(pd.read_csv(out / "metrics.csv"), complete, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "task" / "metrics.csv"), task_complete, check_exact=True
    )
    # A kill before the task loss's first checkpoint leaves its checkpoint folder empty
    # (seen in a study): --resume starts that loss fresh, as it does a loss without the
    # folder, and gives the same tables (same seed, deterministic).
    shutil.rmtree(out / "task" / "checkpoints")
    (out / "task" / "checkpoints").mkdir()
    (out / "task" / "metrics.csv").unlink()
    complete[complete.loss == "joint"].to_csv(out / "metrics.csv", index=False)
    fresh = cli("--resume")
    assert fresh.returncode == 0, fresh.stderr[-3000:]
    assert stamps(out / "joint" / "checkpoints") == joint_before
    pd.testing.assert_frame_equal(pd.read_csv(out / "metrics.csv"), complete, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "task" / "metrics.csv"), task_complete, check_exact=True
    )
    refused = cli_in_process(*command[3:-1], "--seed", "3", "--quiet", "--resume")
    assert refused.returncode == 2
    assert "seed (0 in the run, 3 now)" in refused.stderr and "Traceback" not in refused.stderr
    # Every checkpoint damaged: --resume cannot continue (one error line naming --restart,
    # exit 2); --restart moves the old run aside, whole, and trains the run again from
    # nothing: the same tables as the first run (same config and seed).
    manifests = sorted(out.glob(f"*/checkpoints/*/{checkpoint.MANIFEST}"))
    assert {m.parent.parent.parent.name for m in manifests} == {"joint", "task"}
    for manifest in manifests:
        manifest.write_text("{")
    damaged = cli("--resume")
    lines = damaged.stderr.strip().splitlines()
    assert damaged.returncode == 2 and lines[-1].startswith("cfm-jax: error: checkpoint step")
    assert "no earlier valid checkpoint" in lines[-1] and "--restart" in lines[-1]
    both = cli("--resume", "--restart")
    assert both.returncode == 2 and "--restart=True is not allowed" in both.stderr
    again = cli("--restart")
    assert again.returncode == 0, again.stderr[-3000:]
    pd.testing.assert_frame_equal(pd.read_csv(out / "metrics.csv"), complete, check_exact=True)
    (aside,) = tmp_path.glob("cli.replaced-*")  # the old run, whole: nothing deleted
    assert f"now in {aside}" in again.stderr
    assert (aside / manifests[0].relative_to(out)).read_text() == "{"
    pd.testing.assert_frame_equal(pd.read_csv(aside / "metrics.csv"), complete, check_exact=True)
    assert len(algorithm._SHARED) == 1  # the in-process commands ran on one Experiment


def test_orbax_timing_note_is_not_printed_other_absl_warnings_are(tmp_path, caplog):
    """Orbax logs "Waiting for previous save to complete took N seconds" as an absl WARNING
    when a save waits (seen on busy cores in a --quiet run): a Checkpointer drops that
    note only, through absl's own logging call as Orbax makes it."""
    import logging

    from absl import logging as absl_logging

    from cfm_jax.runs.checkpoint import Checkpointer

    Checkpointer(str(tmp_path / "c"))
    with caplog.at_level(logging.WARNING, logger="absl"):
        absl_logging.warning("Waiting for previous save to complete took %f seconds.", 1.13)
        absl_logging.warning("A checkpoint problem of Orbax's own")
    assert [r.getMessage() for r in caplog.records] == ["A checkpoint problem of Orbax's own"]
