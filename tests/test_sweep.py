"""Sweeps (cfm_jax/runs/sweeps.py): the grid, the tidy table, resuming, and the Ray backend.

Oracles: separate single-seed ``cfm_jax.train`` runs for the vmapped seeds of a cell; an
uninterrupted sweep for an interrupted and resumed one; the ``local`` backend for the
``ray`` backend on a real local Ray cluster (its own processes, started here on the
loopback address with two CPUs); a plain loop for the mean and std over seeds; the
files read back for what was written. Cells are tiny (two-link arm, 16-unit networks,
one iteration): these tests check the wiring, not learning quality.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import secrets
import shutil
import statistics
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from tiny import tiny_config

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax.analysis import report
from cfm_jax.learning import algorithm
from cfm_jax.runs import sweeps, training

TINY = tiny_config(iterations=1)  # two seeds, one iteration
LOSSES = ["joint", "task"]
# One override with one value: the override column is there, and no second compile.
OVERRIDES = {"task.kp": [100.0]}
TARGETS = 5
HAVE_RAY = importlib.util.find_spec("ray") is not None
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _sweep(out_dir, **kwargs):
    return cfm_jax.sweep(
        TINY, seeds=2, losses=LOSSES, overrides=OVERRIDES, out_dir=str(out_dir), progress=False,
        **kwargs,
    )  # fmt: skip


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """The reference sweep: the local backend, uninterrupted."""
    out = tmp_path_factory.mktemp("local")
    return _sweep(out), out


# ----- the grid (no training) ---------------------------------------------------------


def test_grid_is_the_product_of_overrides_and_losses():
    overrides = {"task.kp": [50, 100.0], "controller.learning_rate": [1e-3, 3e-4]}
    cells = sweeps.grid(TINY, seeds=range(3, 6), losses=["task", "joint"], overrides=overrides)
    assert len(cells) == 2 * 2 * 2
    expected = [
        (kp, lr, loss) for kp in (50.0, 100.0) for lr in (1e-3, 3e-4) for loss in ("task", "joint")
    ]
    for cell, (kp, lr, loss) in zip(cells, expected, strict=True):
        config = cell.config
        assert (config.task.kp, config.controller.learning_rate, config.loss) == (kp, lr, loss)
        assert isinstance(config.task.kp, float)  # 50 and 50.0 are one cell
        assert (config.seed, config.loop.seeds) == (3, 3)
        # everything else is the base config's
        assert (
            config.replace(
                loss=TINY.loss,
                seed=TINY.seed,
                task=TINY.task,
                controller=TINY.controller,
                loop=TINY.loop,
            )
            == TINY
        )
        assert cell.overrides == {"task.kp": kp, "controller.learning_rate": lr}
        assert cell.id.startswith(loss + "-")
    assert len({cell.id for cell in cells}) == len(cells)
    # ids name configs, not grid positions: the grid in another order has the same ids
    reordered = sweeps.grid(
        TINY, seeds=[3, 4, 5], losses=["joint", "task"],
        overrides={"controller.learning_rate": [3e-4, 1e-3], "task.kp": [100, 50]},
    )  # fmt: skip
    assert [c.id for c in reordered] != [c.id for c in cells]
    assert {c.id for c in reordered} == {c.id for c in cells}
    # tuples (e.g. targets) are values of their own; lists become tuples
    targets = sweeps.grid(
        TINY, overrides={"task.targets": [[[0.1, 0.2]], [[0.3, 0.4], [0.5, 0.6]]]}
    )
    assert [c.config.task.targets for c in targets] == [((0.1, 0.2),), ((0.3, 0.4), (0.5, 0.6))]
    # a kind's options are fields like the others; a sweep over the kind drops the base
    # kind's options where they are its defaults (the mlp takes none)
    rigid = TINY.replace(forward=dataclasses.replace(TINY.forward, kind="rigid_body"))
    scaled = sweeps.grid(rigid, overrides={"forward.options.mass_scale": [0.8, 1.2]})
    assert [c.config.forward.options.mass_scale for c in scaled] == [0.8, 1.2]
    kinds = sweeps.grid(rigid, overrides={"forward.kind": ["mlp", "rigid_body"]})
    assert [c.config.forward.options for c in kinds] == [None, rigid.forward.options]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (
            dict(overrides={"task.kpp": [1.0]}),
            r"overrides\['task.kpp'\].*fields of task are .*'kp'",
        ),
        (dict(overrides={"robots": ["iiwa14"]}), r"overrides\['robots'\].*'robot'"),
        (dict(overrides={"task": [1]}), r"not a section"),
        (  # the tiny config's mlp has no options: said so, with the kind
            dict(overrides={"forward.options.mass_scale": [0.8]}),
            r"fields of forward.options are none: the base's forward.kind='mlp' takes none",
        ),
        (
            dict(overrides={"forward.options.mass_scale": [0.0]}, base="rigid_body"),
            r"forward.options.mass_scale=0.0 is not allowed",
        ),
        (dict(overrides={"loss": ["task"]}), r"axis of the sweep: use sweep's losses="),
        (dict(overrides={"loop.seeds": [2]}), r"use sweep's seeds="),
        # An override keeps the base's sections: opspace would run the arm's torque scale.
        (dict(overrides={"task.name": ["inverse_dynamics", "opspace"]}), r"one sweep per task"),
        (dict(overrides={"task.kp": 50.0}), r"overrides\['task.kp'\]=50.0 .*non-empty list"),
        (dict(overrides={"task.kp": []}), r"non-empty list"),
        (dict(overrides={"task.kp": [50, 50.0]}), r"distinct values"),
        (dict(overrides={"task.kp": [-1.0]}), r"task.kp=-1.0 is not allowed: a finite number >= 0"),
        (dict(losses=["joint", "jont"]), r"losses=\['joint', 'jont'\] is not allowed"),
        (dict(seeds=0), r"seeds=0 is not allowed"),
        (dict(seeds=[0, 2]), r"seeds=\[0, 2\] is not allowed: consecutive integers"),
        (dict(backend="dask"), r"backend='dask' is not allowed: one of \('local', 'ray'\)"),
        (dict(address="127.0.0.1:6379"), r"address='127.0.0.1:6379' is not allowed: None with"),
        (dict(max_retries=-1), r"max_retries=-1 is not allowed"),
    ],
)
def test_bad_arguments_are_named(kwargs, match):
    base = TINY
    if kwargs.pop("base", None) == "rigid_body":
        base = TINY.replace(forward=dataclasses.replace(TINY.forward, kind="rigid_body"))
    with pytest.raises(config_lib.ConfigError, match=match):
        cfm_jax.sweep(base, progress=False, **kwargs)


# ----- local backend ------------------------------------------------------------------


def test_tidy_table_and_files(local):
    result, out = local
    cells = sweeps.grid(TINY, seeds=2, losses=LOSSES, overrides=OVERRIDES)
    frame = result.metrics
    assert list(frame.columns[:7]) == ["cell", "task.kp", "loss", "seed", "iteration", "target",
                                       "tracking_mse"]  # fmt: skip
    assert len(frame) == len(cells) * 2 * (TINY.loop.iterations + 1) * TARGETS
    assert list(frame.cell.unique()) == [c.id for c in cells]  # grid order
    assert frame.groupby("cell", sort=False).loss.first().to_dict() == {c.id: c.loss for c in cells}
    assert (frame["task.kp"] == 100.0).all()
    assert list(result.cells.status) == ["ran", "ran"]
    # What was written is what was returned, bit for bit, as CSV and as Parquet.
    pd.testing.assert_frame_equal(pd.read_csv(out / "metrics.csv"), frame, check_exact=True)
    pd.testing.assert_frame_equal(pd.read_parquet(out / "metrics.parquet"), frame, check_exact=True)
    for cell in cells:
        saved = pd.read_csv(out / "cells" / cell.id / "metrics.csv")
        mine = frame[frame.cell == cell.id].drop(columns=["cell", "task.kp"])
        pd.testing.assert_frame_equal(saved, mine.reset_index(drop=True), check_exact=True)
        config = json.loads((out / "cells" / cell.id / "config.json").read_text())
        assert config_lib.from_dict(config) == cell.config
        assert (out / "cells" / cell.id / "run" / "dataset.npz").is_file()
    baselines = pd.read_csv(out / "baselines.csv")
    assert set(baselines.baseline) == {"oracle", "pd_only"} and len(baselines) == 2 * TARGETS
    assert (out / "curves.png").stat().st_size > 10_000
    assert "| joint | 100.0 | 2 |" in (out / "summary.md").read_text()


def test_without_pyarrow_a_sweep_writes_the_csv_alone(local, tmp_path, monkeypatch):
    # pyarrow is the optional `parquet` extra: without it (parquet_available() False) a
    # re-run of the finished sweep (every cell read back, none trained) writes the same
    # metrics.csv and no metrics.parquet, and fails nowhere.
    shutil.copytree(local[1], tmp_path / "out")
    (tmp_path / "out" / "metrics.parquet").unlink()
    monkeypatch.setattr(sweeps, "parquet_available", lambda: False)
    again = _sweep(tmp_path / "out")
    assert not (tmp_path / "out" / "metrics.parquet").exists()
    pd.testing.assert_frame_equal(again.metrics, local[0].metrics, check_exact=True)
    assert (tmp_path / "out" / "metrics.csv").read_bytes() == (
        local[1] / "metrics.csv"
    ).read_bytes()


def test_a_cell_equals_train_of_its_config_with_the_seeds_vmapped(local):
    # Oracle: cfm_jax.train of the cell's config, all seeds in one vmapped call: the sweep's
    # rows must equal it bit for bit (a cell is that call). That a vmapped seed equals the
    # seed run alone (to float32 rounding) is test_train.py's
    # test_vmapped_seeds_equal_a_loop_over_seeds. The call runs on the Experiment the sweep
    # kept for the cell's structure (a fresh one compiles the same native programs again;
    # reuse is checked against a fresh Experiment bit for bit in test_train.py, and the
    # value overrides' cells below against fresh ones).
    frame = local[0].metrics
    frame = frame[frame.loss == "joint"].drop(columns=["cell", *OVERRIDES]).reset_index(drop=True)
    experiment = cfm_jax.Experiment.shared(TINY)
    alone = cfm_jax.train(TINY, progress=False, experiment=experiment).metrics
    assert sorted(frame.seed.unique()) == [0, 1]
    pd.testing.assert_frame_equal(frame[list(alone.columns)], alone, check_exact=True)


def test_value_overrides_compile_once_and_equal_separate_runs(tmp_path):
    # Overrides of runtime fields (config.RUNTIME_FIELDS): a learning rate, a gain and the
    # target set (5 targets each), 2 x 2 x 2 cells per loss, one Experiment, each function
    # compiled once. Oracle: a cell's config trained alone on an Experiment built for it
    # (its values baked in, as before they became arguments); the sweep's rows of that cell
    # must equal it bit for bit. The cells checked differ from the first cell in one field
    # each, so each field is seen to reach the compiled program.
    algorithm.clear_shared()
    near, far = (0.3, 0.6), (-0.4, 1.2)
    targets = [tuple([near] * 5), tuple([near, far, near, far, near])]
    overrides = {
        "controller.learning_rate": [1e-3, 3e-3],
        "task.kp": [50.0, 100.0],
        "task.targets": targets,
    }
    result = cfm_jax.sweep(
        TINY, seeds=2, losses=LOSSES, overrides=overrides, out_dir=str(tmp_path), progress=False
    )
    assert len(algorithm._SHARED) == 1
    counts = next(iter(algorithm._SHARED.values())).compilations()
    # The two losses of a cell's values train together: one rollout program for both.
    names = ("babbling_data", "prepare_from_data", "collect[1]", "init[joint]", "init[task]")
    for name in (*names, "refit[joint]", "refit[task]"):
        assert counts[name] == 1, counts
    assert counts["evaluate"] == 1, counts
    frame = result.metrics
    assert frame.cell.nunique() == 16
    finals = frame[frame.iteration == TINY.loop.iterations].groupby("cell").tracking_mse.sum()
    assert finals.nunique() == 16  # every value changes the run
    base = config_lib.to_dict(TINY)
    for lr, kp, target_set in ((1e-3, 100.0, 0), (3e-3, 50.0, 0), (1e-3, 50.0, 1)):
        config = TINY.replace(
            task=config_lib.TaskConfig(
                **{**base["task"], "kp": kp, "targets": targets[target_set]}
            ),
            controller=config_lib.ControllerConfig(**{**base["controller"], "learning_rate": lr}),
        )
        alone = cfm_jax.train(config, progress=False, experiment=cfm_jax.Experiment(config))
        mine = frame[
            (frame.loss == "joint")
            & (frame["controller.learning_rate"] == lr)
            & (frame["task.kp"] == kp)
            & (frame["task.targets"] == json.dumps(targets[target_set]))
        ]
        columns = list(alone.metrics.columns)
        pd.testing.assert_frame_equal(
            mine[columns].reset_index(drop=True), alone.metrics, check_exact=True
        )


def test_interrupted_sweep_resumes_and_gives_the_same_table(local, tmp_path, monkeypatch):
    calls = []

    def task_cell_fails(config, run_dir):
        calls.append(config.loss)
        if config.loss == "task":
            # The cell trains and checkpoints, then dies before its result is written, with
            # only the checkpoint after the initial fit left: interrupted mid-way.
            sweeps.run_cell(config, run_dir)
            shutil.rmtree(os.path.join(run_dir, "checkpoints", str(TINY.loop.iterations)))
            raise RuntimeError("simulated crash of the task cell")
        return sweeps.run_cell(config, run_dir)

    with pytest.raises(cfm_jax.SweepError, match=r"1 of 2 cells failed") as caught:
        _sweep(tmp_path, runner=task_cell_fails)
    task_id = sweeps.grid(TINY, seeds=2, losses=["task"], overrides=OVERRIDES)[0].id
    assert list(caught.value.failures) == [task_id]
    assert "simulated crash" in caught.value.failures[task_id]
    # The finished cell is kept, on disk and in the partial result; no tables yet.
    kept = caught.value.result.metrics
    assert set(kept.loss) == {"joint"}
    reference = local[0].metrics
    pd.testing.assert_frame_equal(
        kept, reference[reference.loss == "joint"].reset_index(drop=True), check_exact=True
    )
    assert not (tmp_path / "cells" / task_id / "metrics.csv").exists()
    assert not (tmp_path / "metrics.csv").exists()
    assert calls == ["joint", "task"]

    resumed_from = []
    train = training.train

    def spy(config, **kwargs):
        resumed_from.append(kwargs.get("resume"))
        return train(config, **kwargs)

    monkeypatch.setattr(training, "train", spy)
    calls.clear()

    def counting(config, run_dir):
        calls.append(config.loss)
        return sweeps.run_cell(config, run_dir)

    resumed = _sweep(tmp_path, runner=counting)
    assert calls == ["task"]  # the finished joint cell was skipped
    # the task cell continued from its checkpoint in its run directory
    assert resumed_from == [str(tmp_path / "cells" / task_id / "run")]
    assert list(resumed.cells.status) == ["done before", "ran"]
    pd.testing.assert_frame_equal(resumed.metrics, reference, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(tmp_path / "metrics.csv"), reference, check_exact=True
    )


def test_cli_sweep_skips_the_finished_cells_of_another_process(local, tmp_path, cli_in_process):
    # A real subprocess of the CLI on a copy of the finished sweep: the same flags name the
    # same cells, so nothing runs again and the table is the same.
    out = tmp_path / "copy"
    shutil.copytree(local[1], out)
    config_file = tmp_path / "config.json"
    config_file.write_text(json.dumps(config_lib.to_dict(TINY)))
    os.remove(out / "metrics.csv")
    command = [
        sys.executable, "-m", "cfm_jax.cli", "sweep", "--robot", TINY.robot, "--losses",
        ",".join(LOSSES), "--seeds", "2", "--iterations", "1", "--override", "task.kp=100",
        "--config", str(config_file), "--out", str(out), "--quiet",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "2 cells (0 ran, 2 finished before)" in done.stdout
    assert "| joint | 100.0 | 2 |" in done.stdout
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "metrics.csv"), local[0].metrics, check_exact=True
    )
    # A refusal: in this process (cli.main), no second interpreter needed.
    bad = cli_in_process("sweep", "--override", "task.kp", "--out", str(out))
    assert bad.returncode == 2
    assert "--override='task.kp' is not allowed: PATH=V1,V2" in bad.stderr


# ----- summaries ----------------------------------------------------------------------


def test_curves_are_the_mean_and_std_over_seeds_of_the_target_means(local, tmp_path):
    result = local[0]
    curves = result.curves()
    metrics = result.metrics
    # Oracle: a plain loop over (loss, iteration): average each seed over its targets, then
    # the mean and the population std over seeds.
    rows = 0
    for loss in LOSSES:
        for iteration in range(TINY.loop.iterations + 1):
            row = curves[(curves.loss == loss) & (curves.iteration == iteration)]
            assert len(row) == 1
            for column in ("tracking_mse", "prediction_error", "predicted_task_error"):
                per_seed = []
                for seed in (0, 1):
                    values = [
                        r[column]
                        for _, r in metrics.iterrows()
                        if r.loss == loss and r.iteration == iteration and r.seed == seed
                    ]
                    assert len(values) == TARGETS
                    per_seed.append(sum(values) / len(values))
                np.testing.assert_allclose(row[f"{column}_mean"].item(), statistics.mean(per_seed),
                                           rtol=1e-12)  # fmt: skip
                np.testing.assert_allclose(row[f"{column}_std"].item(), statistics.pstdev(per_seed),
                                           rtol=1e-9)  # fmt: skip
            assert row["seeds"].item() == 2 and row["task.kp"].item() == 100.0
            rows += 1
    assert len(curves) == rows
    text = result.markdown()
    final = curves[(curves.loss == "task") & (curves.iteration == 1)]
    expected = report._format(final.tracking_mse_mean.item()) + " ± "
    assert f"| task | 100.0 | 2 | {expected}" in text
    figure = result.plot(str(tmp_path / "curves.png"), title="tiny")
    assert os.path.getsize(tmp_path / "curves.png") > 10_000
    assert figure._suptitle.get_text() == "tiny"


def test_seed_curves_group_by_override_values():
    # Two override values and two seeds, one target: hand-made numbers.
    metrics = pd.DataFrame(
        {"loss": ["joint"] * 4, "lr": [0.1, 0.1, 0.2, 0.2], "seed": [0, 1, 0, 1],
         "iteration": [0] * 4, "target": [0] * 4, "tracking_mse": [1.0, 3.0, 10.0, 30.0]}
    )  # fmt: skip
    curves = report.seed_curves(metrics, by=["loss", "lr"])
    assert list(curves.lr) == [0.1, 0.2]
    assert list(curves.tracking_mse_mean) == [2.0, 20.0]
    assert list(curves.tracking_mse_std) == [1.0, 10.0]


# ----- the Ray backend ----------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_cluster():
    """A real local Ray cluster in its own process: a head node on 127.0.0.1 with two CPUs
    (two worker processes), token authentication with a token made here. Yields its
    address; this process connects to it as a second driver, as a user would."""
    if not HAVE_RAY:
        pytest.skip("Ray is not installed: pip install 'cfm_jax[ray]' to test the ray backend")
    env = {
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        # Ray resolves 127.0.0.1 to the machine's network address unless told it is on a
        # single machine; this keeps every Ray service on the loopback address.
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    }
    with pytest.MonkeyPatch.context() as patch:
        for name, value in env.items():
            patch.setenv(name, value)
        script = (
            "import ray, sys\n"
            "ctx = ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)\n"
            "print(ctx.address_info['gcs_address'], ray.cluster_resources()['CPU'], flush=True)\n"
            "sys.stdin.read()\n"
            "ray.shutdown()\n"
        )
        head = subprocess.Popen(
            [sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )  # fmt: skip
        try:
            address, cpus = head.stdout.readline().split()
            assert address.startswith("127.0.0.1:") and float(cpus) == 2.0
            yield address
        finally:
            head.stdin.close()  # the head node shuts its cluster down and exits
            try:
                head.wait(timeout=60)
            except subprocess.TimeoutExpired:
                head.kill()
                head.wait()


def _dies_on_attempts(markers, crashes: int):
    """A runner whose worker process dies (``os._exit``: no cleanup, like a kill) while
    running the task cell, on its first ``crashes`` attempts; every attempt at the task cell
    leaves a marker file ``<attempt>-<pid>``."""

    def runner(config, run_dir):
        if config.loss == "task":
            attempt = len(os.listdir(markers)) + 1
            (markers / f"{attempt}-{os.getpid()}").write_text("")
            if attempt <= crashes:
                os._exit(1)
        return sweeps.run_cell(config, run_dir)

    return runner


def test_ray_backend_gives_the_same_table_as_local_when_a_worker_dies(local, ray_cluster, tmp_path):
    # The worker running the task cell dies mid-task; Ray retries the cell in another
    # worker process. Oracle: the local backend's table.
    markers = tmp_path / "attempts"
    markers.mkdir()
    result = _sweep(tmp_path / "out", backend="ray", address=ray_cluster, max_retries=1,
                    runner=_dies_on_attempts(markers, 1))  # fmt: skip
    pd.testing.assert_frame_equal(result.metrics, local[0].metrics, check_exact=True)
    pd.testing.assert_frame_equal(result.baselines, local[0].baselines, check_exact=True)
    pd.testing.assert_frame_equal(
        pd.read_csv(tmp_path / "out" / "metrics.csv"), local[0].metrics, check_exact=True
    )
    attempts = sorted(os.listdir(markers))
    assert len(attempts) == 2  # the attempt that died and the retry
    dead = int(attempts[0].split("-")[1])
    joint_pid, task_pid = (int(p) for p in result.cells.pid)
    assert task_pid == int(attempts[1].split("-")[1]) != dead
    # The cells ran in the cluster's worker processes (two at once), not in this one.
    workers = {dead, joint_pid, task_pid}
    assert os.getpid() not in workers and len(workers) >= 2


def test_a_lost_ray_cell_is_reported_and_the_others_are_kept(ray_cluster, tmp_path):
    # No retries: the task cell's worker dies and the cell is lost; the joint cell is
    # written all the same (re-running skips it: the local test above covers that part).
    markers = tmp_path / "attempts"
    markers.mkdir()
    task_id = sweeps.grid(TINY, seeds=2, losses=["task"], overrides=OVERRIDES)[0].id
    with pytest.raises(cfm_jax.SweepError, match=task_id) as caught:
        _sweep(tmp_path / "out", backend="ray", address=ray_cluster, max_retries=0,
               runner=_dies_on_attempts(markers, 1))  # fmt: skip
    assert list(caught.value.failures) == [task_id]
    assert "died" in caught.value.failures[task_id].lower()
    assert len(os.listdir(markers)) == 1  # not retried
    joint_id = caught.value.result.cells.cell[0]
    assert joint_id.startswith("joint-")
    assert (tmp_path / "out" / "cells" / joint_id / "metrics.csv").exists()
    assert not (tmp_path / "out" / "cells" / task_id / "metrics.csv").exists()


def test_ray_backend_without_address_starts_a_local_cluster_and_stops_it(local, tmp_path):
    # A fresh Python process (no Ray running in it) calls sweep(backend="ray") with no
    # address, as a user in a notebook would: Ray starts a local cluster on demand, the
    # cells run in its worker processes, and the cluster is shut down afterwards.
    # Oracle: the local backend's table.
    if not HAVE_RAY:
        pytest.skip("Ray is not installed: pip install 'cfm_jax[ray]' to test the ray backend")
    out = tmp_path / "out"
    script = (
        "import json, os, sys, ray, cfm_jax\n"
        "from tiny import tiny_config\n"
        f"result = cfm_jax.sweep(tiny_config(iterations=1), seeds=2, losses={LOSSES!r},\n"
        f"    overrides={OVERRIDES!r}, out_dir={str(out)!r}, progress=False, backend='ray')\n"
        "print(json.dumps({'pid': os.getpid(), 'cells': [int(p) for p in result.cells.pid],\n"
        "    'connected_after': ray.is_initialized()}))\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), *sys.path])}
    env.pop("RAY_ADDRESS", None)  # an address in the environment would join that cluster
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    report_line = json.loads(done.stdout.strip().splitlines()[-1])
    assert report_line["connected_after"] is False  # the on-demand cluster was shut down
    assert report_line["pid"] not in report_line["cells"]  # the cells ran in Ray workers
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "metrics.csv"), local[0].metrics, check_exact=True
    )


# ----- the swap study reuses a sweep's runs ------------------------------------------


def test_swap_study_takes_its_data_sets_from_a_sweep_cell_of_the_same_config(local, tmp_path):
    """``swap_study.py --collected SWEEP_DIR`` uses the run that the sweep wrote for the very
    same config (the folder the sweep itself lists in cells.csv), and runs afresh in its own
    folder for any other config."""
    import swap_study  # experiments/ is on pytest's path (pyproject.toml)

    _, out = local
    cells = pd.read_csv(out / "cells.csv").set_index("loss")
    for loss in LOSSES:
        config = TINY.replace(loss=loss, loop=dataclasses.replace(TINY.loop, seeds=2))
        found = swap_study.collect_dir(str(tmp_path), config, [str(tmp_path / "none"), str(out)])
        assert found == os.path.join(str(out), "cells", cells.loc[loss, "cell"], "run")
        assert os.path.isfile(os.path.join(found, "dataset.npz"))
    other = TINY.replace(loss="joint", seed=7)
    assert swap_study.collect_dir(str(tmp_path), other, [str(out)]) == os.path.join(
        str(tmp_path), "collect", "joint"
    )


# ----- reproduce_all --quick ----------------------------------------------------------


def test_reproduce_all_quick_iiwa(tmp_path):
    out = tmp_path / "results"
    command = [sys.executable, os.path.join(ROOT, "experiments", "reproduce_all.py"), "--quick",
               "--only", "iiwa_inverse_dynamics", "--out", str(out)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    folder = out / "iiwa_inverse_dynamics"
    metrics = pd.read_csv(folder / "metrics.csv")
    assert set(metrics.loss) == {"joint", "task"} and set(metrics.seed) == {0, 1}
    assert np.isfinite(metrics.tracking_mse).all()
    summary = (folder / "summary.md").read_text()
    curves = report.seed_curves(metrics, by=["loss"])
    final = curves[curves.iteration == curves.iteration.max()]
    for _, row in final.iterrows():
        assert f"| {row.loss} | 2 | {report._format(row.tracking_mse_mean)} ± " in summary
    assert (folder / "curves.png").stat().st_size > 10_000
    index = (out / "README.md").read_text()
    assert "iiwa_inverse_dynamics" in index and "wall time" in index
