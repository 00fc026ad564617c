"""experiments/robustness_study.py: the grid and its tables, on hand-made sweep outputs.

Oracle: the numbers written into the fake runs (seed means, paired differences and falls
computed by hand below) and :func:`cfm_jax.analysis.report.bootstrap_ci` (tested on its own in
test_report.py). No training runs here; the study's cells are the library's sweeps.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil

import _study
import numpy as np
import pandas as pd
import pytest
import robustness_study as study

from cfm_jax import config as config_lib
from cfm_jax.analysis import report


def _as_run_today(recorded: dict) -> dict:
    """A record's config.json with the fields added since it was written
    (``_study.BEFORE_TORQUE_SCALING``: a record that predates them ran on those values;
    ``task.motion_family``: the test family; ``loop.restart_on_terminal``: off) and its
    forward section upgraded (:func:`cfm_jax.config.upgrade_forward`)."""
    loop = dict(recorded["loop"])
    for path, value in _study.BEFORE_TORQUE_SCALING.items():
        loop.setdefault(path.split(".")[1], value)
    # loop.restart_on_terminal (issue 65) came later: every record's data ended at a fall
    loop.setdefault("restart_on_terminal", False)
    # task.motion_family (issue 43) came later: every record followed the test motions' family
    task = {**recorded["task"], "motion_family": recorded["task"].get("motion_family", "test")}
    # task.oracle (session 34) came later: every record ran the one-step oracle
    task.setdefault("oracle", "step")
    # and the forward section's rigid_body fields as they are read today (forward.options)
    forward = config_lib.upgrade_forward(recorded["forward"])
    return {**recorded, "loop": loop, "task": task, "forward": forward}


LOSSES = ("joint", "task", "distal", "supervised")


def _fake_run(runs, cell, scale, legged):
    """metrics.csv of a finished cell: 3 seeds x 2 targets at iterations 0 and 10; seed s,
    target k of loss i has final tracking MSE scale[i] * (1 + s) + k (seed mean
    scale[i] (1 + s) + 0.5); a legged cell's joint loss fell on seed 2 target 1."""
    rows = []
    for i, loss in enumerate(LOSSES):
        for seed in range(3):
            for iteration in (0, 10):
                for target in range(2):
                    row = dict(
                        loss=loss,
                        seed=seed,
                        iteration=iteration,
                        target=target,
                        tracking_mse=scale[i] * (1 + seed) + target + (iteration == 0),
                    )
                    if legged:
                        row["force_mse"] = 10.0 * row["tracking_mse"]
                        row["fell"] = float(loss == "joint" and seed == 2 and target == 1)
                    rows.append(row)  # fmt: skip
    path = study.run_dir(runs, cell)
    os.makedirs(path, exist_ok=True)
    pd.DataFrame(rows).to_csv(os.path.join(path, "metrics.csv"), index=False)
    with open(os.path.join(path, "seconds.txt"), "w") as f:
        f.write("100.0\n20.5\n")


def test_summary_and_who_wins_from_finished_cells(tmp_path):
    runs, out = str(tmp_path / "runs"), str(tmp_path / "out")
    walk = next(c for c in study.CELLS if c.task == "walk" and c.default)
    arm = study.find("inverse_dynamics", "reference_pd-default")
    _fake_run(runs, walk, scale=(1.0, 2.0, 4.0, 0.5), legged=True)
    _fake_run(runs, arm, scale=(3.0, 1.0, 2.0, 5.0), legged=False)
    summary = study.write_outputs(runs, out, study.CELLS)
    assert set(os.listdir(out)) >= {"summary.csv", "who_wins.md", "walk.png"}
    written = pd.read_csv(os.path.join(out, "summary.csv"))
    assert len(written) == 8 and list(written.columns[:10]) == [
        "robot", "task", "cell", "label", "loss", "seeds", "final_mean", "final_std",
        "ci_low", "ci_high",
    ]  # fmt: skip
    row = summary[(summary.task == "walk") & (summary.loss == "task")].iloc[0]
    # task on walk: seed means 2 (1 + s) + 0.5 = 2.5, 4.5, 6.5: mean 4.5, sample std 2.
    assert (row.robot, row.cell, row.label, row.seeds) == ("solo12", "defaults", "defaults", 3)
    np.testing.assert_allclose([row.final_mean, row.final_std], [4.5, 2.0])
    np.testing.assert_allclose([row.ci_low, row.ci_high], report.bootstrap_ci([2.5, 4.5, 6.5]))
    # joint minus task per seed: (1 (1 + s) + 0.5) - (2 (1 + s) + 0.5) = -1, -2, -3.
    np.testing.assert_allclose(row.joint_minus, -2.0)
    np.testing.assert_allclose(
        [row.joint_minus_low, row.joint_minus_high], report.bootstrap_ci([-1.0, -2.0, -3.0])
    )
    np.testing.assert_allclose(row.force_mean, 45.0)
    joint = summary[(summary.task == "walk") & (summary.loss == "joint")].iloc[0]
    assert (joint.falls, joint.runs) == (1, 6)
    assert row.seconds == pytest.approx(120.5)  # the pieces of an interrupted cell add up
    text = open(os.path.join(out, "who_wins.md")).read()
    # walk: supervised lowest (0.5 (1 + s) + 0.5), below every other loss in every seed.
    walk_line = next(line for line in text.splitlines() if line.startswith("| **defaults**")
                     and "falls" in line)  # fmt: skip
    assert "**supervised** (clear)" in walk_line and "falls 1/6" in walk_line
    # the arm's reference_pd cell: task lowest; the default arm cell was not run.
    arm_line = next(line for line in text.splitlines() if "reference_pd" in line)
    assert arm_line.startswith(f"| {arm.label} | 3 |") and "**task** (clear)" in arm_line
    assert "| **defaults** | 5 | not run yet" in text
    assert not study.finished(runs, out, study.CELLS[0]) and study.finished(runs, out, walk)
    # From a fresh clone (no runs, only the records next to the tables): the same tables.
    shutil.rmtree(runs)
    again = study.write_outputs(runs, out, study.CELLS)
    pd.testing.assert_frame_equal(again, summary)
    assert open(os.path.join(out, "who_wins.md")).read() == text


RECORDS = os.path.join(os.path.dirname(__file__), "..", "docs", "results", "robustness")


def test_cells_configs_follow_the_protocol():
    # The headline cells are the task's defaults (as the records were made: the arms' torque
    # scale before issue 64, _study.for_task), 5 seeds.
    for task in study.TASK_ORDER:
        default = study.find(task, study.DEFAULTS)
        want = _study.for_task(task, robot=default.robot)
        want = want.replace(loop=dataclasses.replace(want.loop, iterations=10))
        assert default.config(10) == want
        assert default.seeds == 5 and default.default and not default.changes
    assert all(c.seeds >= 3 for c in study.CELLS)
    # The legged defaults at the authors' 30 iterations, whatever the study's count.
    for task in ("walk", "jump"):
        cell = study.find(task, "iterations=30")
        want = _study.for_task(task, robot=cell.robot)
        want = want.replace(loop=dataclasses.replace(want.loop, iterations=30))
        assert cell.config(10) == want and cell.seeds == 5 and not cell.default
    before = study.find("jump", "oracle-pilot_tuned").config(10)
    assert (before.loop.babbling, before.loop.babbling_rollouts, before.loop.babbling_noise) == (
        "oracle", 4, 0.3)  # fmt: skip
    assert (before.task.kp, before.task.kd, before.task.joint_kp, before.task.joint_kd) == (
        100.0, 20.0, 2000.0, 50.0)  # fmt: skip


def test_cells_that_ran_before_the_selection_keep_the_configs_of_their_records():
    """Oracle: the config.json of each such record, written by the study's code of the time
    (its cells were then grids of babbling x gains on the defaults of the time)."""
    old = [c for c in study.CELLS if c.before_selection]
    assert len(old) == 11
    for cell in old:
        with open(os.path.join(study.record_dir(RECORDS, cell), "config.json")) as f:
            recorded = json.load(f)
        config = cell.config(recorded["loop"]["iterations"])
        config = config.replace(loop=dataclasses.replace(config.loop, seeds=cell.seeds))
        assert json.loads(json.dumps(config_lib.to_dict(config))) == _as_run_today(recorded), (
            cell.path
        )


def test_cells_of_the_first_selection_round_keep_the_configs_of_their_records():
    """Oracle: the config.json of each record, written when the cell ran as the legged
    ``defaults`` (and ``iterations=30``) of the selection's first round; pinned since
    (``_study.ROUND_ONE_LEGGED``), they stay those configs whatever the defaults become."""
    cells = [c for c in study.CELLS if c.name.startswith("round1-")]
    assert {c.path for c in cells} == {
        "walk/round1-defaults",
        "jump/round1-defaults",
        "walk/round1-iterations=30",
    }
    for cell in cells:
        with open(os.path.join(study.record_dir(RECORDS, cell), "config.json")) as f:
            recorded = json.load(f)
        config = cell.config(10)
        assert config.loop.iterations == recorded["loop"]["iterations"]
        config = config.replace(loop=dataclasses.replace(config.loop, seeds=cell.seeds))
        assert json.loads(json.dumps(config_lib.to_dict(config))) == _as_run_today(recorded), (
            cell.path
        )


def test_one_cell_per_changed_default_with_its_old_value(monkeypatch):
    """Had the options before the selection differed from today's defaults only in the
    babbling and the fit start, the study would add two 3-seed cells per task, each with
    one old value and the other defaults; the two networks' starts are one factor."""
    defaults = _study.for_task("walk")  # the study's cells' base (the records' s*)
    old_babbling = next(b for b in config_lib.BABBLING if b != defaults.loop.babbling)
    old_start = next(s for s in config_lib.FIT_STARTS if s != defaults.forward.start)
    before = {p: getattr(getattr(defaults, p.split(".")[0]), p.split(".")[1]) for p in study.BEFORE}
    before.update({"loop.babbling": old_babbling, "forward.start": old_start,
                   "controller.start": old_start})  # fmt: skip
    monkeypatch.setattr(study, "BEFORE", before)
    assert study.changed_factors("walk") == {
        "loop.babbling": old_babbling,
        "forward.start": old_start,
        "controller.start": old_start,
    }
    cells = study.old_value_cells("walk", "solo12")
    assert [c.name for c in cells] == [f"babbling={old_babbling}", f"start={old_start}"]
    assert all(c.seeds == 3 and c.robot == "solo12" and not c.default for c in cells)
    walk = defaults.replace(loop=dataclasses.replace(defaults.loop, iterations=10))
    walk = config_lib.to_dict(walk)
    babbling, start = (config_lib.to_dict(c.config(10)) for c in cells)
    assert babbling["loop"].pop("babbling") == old_babbling
    assert (start["forward"].pop("start"), start["controller"].pop("start")) == (old_start,) * 2
    for changed, section, field in ((babbling, "loop", "babbling"), (start, "forward", "start"),
                                    (start, "controller", "start")):  # fmt: skip
        changed[section][field] = walk[section][field]
    assert babbling == walk and start == walk


def test_the_default_cells_run_the_configs_of_reproduce_all(tmp_path):
    """The headline results are the robustness study's default cells; reproduce_all.py's
    parts (through their scripts) run the very same configs, so either reproduces the
    other's numbers (a sweep cell is cfm_jax.train of its config, test_sweep.py)."""
    import _study
    import solo_study
    import swap_study

    from cfm_jax import cli

    def plain(config):
        tree = config_lib.to_dict(config.replace(loss="joint"))
        tree["loop"]["seeds"] = 5
        return tree

    cells = {c.task: c for c in study.CELLS if c.default}
    assert set(cells) == {"inverse_dynamics", "opspace", "walk", "jump"}
    args = _study.parser("", "").parse_args([])
    assert (args.seeds, args.iterations, args.losses) == (5, 10, "all")
    iiwa = _study.for_task("inverse_dynamics", robot="iiwa14")  # the records' torque scale
    iiwa = iiwa.replace(loop=dataclasses.replace(iiwa.loop, iterations=args.iterations))
    assert plain(iiwa) == plain(cells["inverse_dynamics"].config(10))
    assert plain(swap_study.base_config(5, 10, quick=False)) == plain(iiwa)
    # opspace_study.py calls cli.train with these flags (its defaults), solo_study.py with
    # its study_config written to a file (the records' s*: the walk's without joint feedback).
    for task, robot in (("opspace", "iiwa14"), ("walk", None), ("jump", None)):
        base = None
        if task != "opspace":
            base = str(tmp_path / f"{task}.json")
            with open(base, "w") as f:
                json.dump(config_lib.to_dict(solo_study.study_config(task)), f)
        flags = cli._base_config(robot, task, "joint", 0, 5, 10, base, None, None, None)
        assert plain(flags) == plain(cells[task].config(10)), task
        assert cells[task].seeds == 5


def test_run_cells_skips_finished_cells_and_stops_at_the_budget(monkeypatch, capsys):
    """The study scripts' loop (``_study.run_cells``): finished cells are skipped, a started
    cell always finishes, no cell starts once the budget is spent, ``after`` follows each
    cell, and a second call resumes with the first cell left undone."""
    cell = dataclasses.make_dataclass("C", ["task", "name"])
    todo = [cell("walk", n) for n in ("a", "b", "c", "d")]
    done, ran, after = {"a"}, [], []
    clock = iter([0.0, 0.0, 5.0, 20.0, 20.0])  # start, before b, before c, before d, ...
    monkeypatch.setattr(_study.time, "perf_counter", lambda: next(clock))

    def run_cell(c, args):
        ran.append(c.name)
        done.add(c.name)
        return 1.0

    args = argparse.Namespace(runs="r", out="o", budget=10.0)
    finished = lambda runs, out, c: (runs, out) == ("r", "o") and c.name in done  # noqa: E731
    stopped = _study.run_cells("s", todo, args, run_cell, finished, label=lambda c: "(x)",
                               after=lambda: after.append(len(ran)))  # fmt: skip
    assert stopped and ran == ["b", "c"] and after == [1, 2]
    out = capsys.readouterr().out
    assert "s: walk/b (x)\ns: walk/b done in 1 s\n" in out
    assert out.endswith("s: budget of 10 s used; stopping\n")
    clock = iter([0.0, 0.0])
    assert not _study.run_cells("s", todo, args, run_cell, finished) and ran == ["b", "c", "d"]
