"""experiments/mjx_vs_native.py: its configs and its page, on hand-made cell records.

Oracle: the numbers written into the fake records (seed means, paired differences and falls
chosen by hand below) and the robustness study's default cell (the same config but for the
simulator and the seeds). No training runs here."""

from __future__ import annotations

import argparse
import dataclasses
import os

import mjx_vs_native as study
import pandas as pd
import pytest
import robustness_study

from cfm_jax import config as config_lib

# Final seed means (each seed's 2 targets average to it), per (task, simulator, loss):
# walk: native joint lower on both seeds, MJX task lower on both -> no common lower loss,
# and intervals [-0.4, -0.2] and [0.1, 0.3] that do not overlap. jump: both simulators put
# joint lower, with overlapping intervals.
SEED_MEANS = {
    ("walk", "native", "joint"): (0.1, 0.2),
    ("walk", "native", "task"): (0.5, 0.4),
    ("walk", "mjx", "joint"): (0.4, 0.6),
    ("walk", "mjx", "task"): (0.1, 0.5),
    ("jump", "native", "joint"): (0.2, 0.3),
    ("jump", "native", "task"): (0.5, 0.4),
    ("jump", "mjx", "joint"): (0.2, 0.2),
    ("jump", "mjx", "task"): (0.3, 0.6),
}


def _records(out, cells):
    for cell in cells:
        folder = study.record_dir(out, cell)
        os.makedirs(folder)
        rows = []
        for seed, mean in enumerate(SEED_MEANS[cell.task, cell.simulator, cell.loss]):
            for iteration in (0, 3):
                for target, offset in enumerate((-0.05, 0.05)):
                    final = iteration == 3
                    rows.append(
                        dict(loss=cell.loss, seed=seed, iteration=iteration, target=target,
                             tracking_mse=mean + offset if final else 9.0, force_mse=10.0,
                             fell=float(final and seed == 1 and target == 0))
                    )  # fmt: skip
        pd.DataFrame(rows).to_csv(os.path.join(folder, "metrics.csv"), index=False)
        pd.DataFrame(
            dict(baseline=["oracle", "pd_only"], target=[0, 0], tracking_mse=[1e-14, 1e-3])
        ).to_csv(os.path.join(folder, "baselines.csv"), index=False)
        with open(os.path.join(folder, "seconds.txt"), "w") as f:
            f.write("10.0\n5.5\n")


def test_config_is_the_robustness_cell_of_its_records_on_either_simulator():
    """The records ran the robustness study's cell home-default (the defaults before the
    selection run), on either simulator."""
    for task in study.TASKS:
        default = robustness_study.find(task, "home-default").config(3)
        for simulator in study.SIMULATORS:
            config = study.config_for(task, simulator, seeds=2, iterations=3, quick=False)
            assert config.simulator == simulator and config.loop.iterations == 3
            want = default.replace(loop=dataclasses.replace(default.loop, seeds=2))
            got = config.replace(simulator=default.simulator)
            assert config_lib.to_dict(got) == config_lib.to_dict(want)


def test_page_table_and_verdict_block(tmp_path):
    out = str(tmp_path)
    cells = study.cells(study.TASKS)
    assert len(cells) == 8 and not study.finished(out, cells[0])
    _records(out, cells)
    assert all(study.finished(out, c) for c in cells)
    args = argparse.Namespace(out=out, seeds=2, iterations=3)
    rows = study.write_outputs(args, cells)
    summary = pd.read_csv(os.path.join(out, "summary.csv")).set_index(["task", "simulator", "loss"])
    row = summary.loc[("walk", "mjx", "task")]
    assert row.final_mean == pytest.approx(0.3) and row.seed_min == pytest.approx(0.1)
    assert (row.falls, row.runs, row.seconds, row.iteration) == (1, 4, 15.5, 3)
    assert len(rows) == 8
    page = open(os.path.join(out, "index.md")).read()
    assert "with 2 seeds and 3 iterations" in page
    # joint - task: walk native -0.4, -0.2; mjx 0.3, 0.1. jump native -0.3, -0.1; mjx -0.1, -0.4
    walk = "| walk | -0.3 [-0.4, -0.2] | 0.2 [0.1, 0.3] | joint (clear), task (clear) | no | no |"
    jump = "| jump | -0.2 [-0.3, -0.1] | -0.25 [-0.4, -0.1] | joint (clear), joint (clear) | yes |"
    assert walk in page and jump in page
    # A written verdict survives the next rewrite.
    verdict = "<!-- verdict -->\nThe simulators agree.\n<!-- /verdict -->\n"
    with open(os.path.join(out, "index.md"), "w") as f:
        f.write(page.replace("<!-- verdict -->\n<!-- /verdict -->\n", verdict))
    study.write_outputs(args, cells)
    assert verdict in open(os.path.join(out, "index.md")).read()
