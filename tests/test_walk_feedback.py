"""experiments/walk_feedback.py: the comparison's walk cell with joint position feedback in
``s*`` against its committed record without it (issue 65, goal 2)."""

from __future__ import annotations

import os

import comparison
import numpy as np
import pandas as pd
import pytest
import walk_feedback

from cfm_jax import config as config_lib
from cfm_jax.tasks import legged

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _flat(config) -> dict:
    out = {}
    for name, value in config_lib.to_dict(config).items():
        if isinstance(value, dict):
            out.update({f"{name}.{k}": v for k, v in value.items()})
        else:
            out[name] = value
    return out


def test_the_cell_is_the_comparisons_walk_cell_with_only_the_joint_gain_changed():
    before = _flat(comparison.Cell("walk", "shared", ("joint",)).config())
    after = _flat(walk_feedback.cell(comparison.FIRST_SEED).config())
    changed = {k for k in before if before[k] != after[k]}
    assert changed == {"task.joint_kp"}
    assert (before["task.joint_kp"], after["task.joint_kp"]) == (None, legged.WALK_JOINT_KP)
    assert after["task.desired"] == "next_velocity" and after["loop.iterations"] == 30
    # the record folders are the comparison's layout, under another root
    assert comparison.record_dir("X", walk_feedback.cell(20)).endswith(
        os.path.join("X", "cells", "walk", "shared", "seeds-20-29")
    )


def _write_cell(root: str, first: int, tracking: dict, fell: dict, pd_only: float) -> None:
    folder = comparison.record_dir(root, walk_feedback.cell(first))
    os.makedirs(folder)
    rows = []
    for (loss, seed), values in tracking.items():
        for target, value in enumerate(values):
            for iteration in (0, 1):  # iteration 0 rows must not count
                rows.append({"loss": loss, "seed": seed, "iteration": iteration,
                             "target": target, "tracking_mse": value if iteration else 9.0,
                             "fell": float(fell.get((loss, seed, target), 0) if iteration
                                           else 1)})  # fmt: skip
    pd.DataFrame(rows).to_csv(os.path.join(folder, "metrics.csv"), index=False)
    baselines = pd.DataFrame({"baseline": ["oracle", "oracle", "pd_only", "pd_only"],
                              "target": [0, 1, 0, 1],
                              "tracking_mse": [0.0, 0.0, pd_only - 1, pd_only + 1]})  # fmt: skip
    baselines.to_csv(os.path.join(folder, "baselines.csv"), index=False)


def test_the_table_counts_falls_and_seed_means_by_hand(tmp_path, monkeypatch):
    monkeypatch.setattr(walk_feedback.losses_lib, "PAPER_LOSSES", ("joint", "task"))
    before, after = str(tmp_path / "before"), str(tmp_path / "after")
    # two walks per seed; seeds 10, 11 in block 10 and 20 in block 20
    _write_cell(before, 10, {("joint", 10): [1, 3], ("joint", 11): [5, 7],
                             ("task", 10): [2, 2], ("task", 11): [2, 4]},
                {("joint", 10, 0): 1, ("joint", 11, 1): 1}, pd_only=3.0)  # fmt: skip
    _write_cell(before, 20, {("joint", 20): [0, 0], ("task", 20): [6, 6]},
                {("task", 20, 0): 1, ("task", 20, 1): 1}, pd_only=3.0)  # fmt: skip
    ones = {(loss, seed): [1, 1] for loss in ("joint", "task") for seed in (10, 11)}
    _write_cell(after, 10, ones, {}, pd_only=3.0)
    table = walk_feedback.table([10, 20], out=after, before=before)
    # 'after' lacks block 20: only 'before' is tabled
    assert table["s*"].tolist() == ["before", "before"]
    joint, task = table.to_dict("records")
    assert joint["seeds"] == 3 and joint["fell"] == "2 of 6"
    assert joint["tracking_mse"] == pytest.approx((2 + 6 + 0) / 3)  # seed means 2, 6, 0
    assert joint["seeds_below_pd"] == "2 of 3" and joint["pd_only"] == 3.0
    assert task["fell"] == "2 of 6" and task["tracking_mse"] == pytest.approx((2 + 3 + 6) / 3)
    assert task["seeds_below_pd"] == "1 of 3"  # 3 is not below 3
    assert joint["ci_low"] <= joint["tracking_mse"] <= joint["ci_high"]
    both = walk_feedback.table([10], out=after, before=before)
    assert both["s*"].tolist() == ["before", "before", "after", "after"]
    assert both.iloc[2]["fell"] == "0 of 4" and both.iloc[2]["seeds_below_pd"] == "2 of 2"
    page = walk_feedback.page(both, [10])
    assert "| after | joint | 2 | 0 of 4 | 1 | [1, 1] | 3 | 2 of 2 |" in page
    # Paired by seed, after - before, block 10 only (block 20 has no 'after').
    assert walk_feedback.paired([10, 20], out=after, before=before).empty
    tests = walk_feedback.paired([10], out=after, before=before).set_index(["loss", "measure"])
    joint_log = tests.loc[("joint", "log10 error")]
    # before: seed 10 mean(log10 1, log10 3), seed 11 mean(log10 5, log10 7); after: 0, 0
    by_hand = -(np.log10(3) / 2 + (np.log10(5) + np.log10(7)) / 2) / 2
    assert joint_log.mean_difference == pytest.approx(by_hand)
    assert (joint_log.after_lower, joint_log.after_higher, joint_log.p) == (2, 0, 0.5)  # 2 of 4
    falls = tests.loc[("joint", "falls")]
    assert (falls.mean_difference, falls.p) == (-1.0, 0.5)  # one fall per seed before, none after
    assert tests.loc[("task", "falls")].p == 1.0  # no falls either side: no difference
    # Holm over the 4 tests: 4 x 0.5 and 1 cap at 1; nothing is clear at two seeds.
    assert tests.holm_p.tolist() == [1.0] * 4 and set(tests.verdict) == {"not resolved"}
    assert "| joint | falls | 2 | -1 | 2 / 0 | 0.5 | 1 | not resolved |" in walk_feedback.page(
        both, [10], tests.reset_index()
    )
    # Each loss against PD-only (after): PD-only tracks 2 and 4 on the two walks, every
    # after-seed 1 and 1: per seed mean(log10 1/2, log10 1/4), both seeds below.
    versus = walk_feedback.against_pd([10], out=after).set_index("loss")
    joint = versus.loc["joint"]
    assert joint.mean_log10_ratio == pytest.approx((np.log10(0.5) + np.log10(0.25)) / 2)
    assert (joint.seeds, joint.below, joint.above, joint.p) == (2, 2, 0, 0.5)  # 2 of 4 signs
    assert versus.holm_p.tolist() == [1.0, 1.0] and set(versus.verdict) == {"not resolved"}
    # Ten seeds all below would be clear (p = 2 / 2^10, Holm x 2): the verdict names the side.
    ten = {(loss, seed): [1, 1] for loss in ("joint", "task") for seed in range(10, 20)}
    _write_cell(str(tmp_path / "ten"), 10, ten, {}, pd_only=3.0)
    clear = walk_feedback.against_pd([10], out=str(tmp_path / "ten"))
    assert clear.p.tolist() == [2 / 2**10] * 2
    assert set(clear.verdict) == {"clear below PD-only"}
    assert "| joint | 10 | -0.452 | 10 / 0 | 0.002 | 0.0039 | clear below PD-only |" in (
        walk_feedback.page(both, [10], None, clear)
    )


def test_the_confirmation_checks_the_second_block_alone_by_hand(tmp_path, monkeypatch):
    monkeypatch.setattr(walk_feedback.losses_lib, "PAPER_LOSSES", ("joint", "supervised"))
    out = str(tmp_path / "after")
    # Block 10 (not the confirmation's): every seed far below PD-only, none fell.
    _write_cell(out, 10, {(loss, seed): [1e-3, 1e-3] for loss in ("joint", "supervised")
                          for seed in range(10, 20)}, {}, pd_only=3.0)  # fmt: skip
    assert walk_feedback.confirmation(out).empty  # block 20 not recorded yet
    # Block 20: joint at half of PD-only on both walks of every seed, one walk fell;
    # supervised (no forward model: no falls limit) above PD-only, 5 walks fell.
    tracking = {("joint", seed): [1.0, 2.0] for seed in range(20, 30)}
    tracking |= {("supervised", seed): [4.0, 8.0] for seed in range(20, 30)}
    fell = {("joint", 21, 0): 1} | {("supervised", seed, 1): 1 for seed in range(20, 25)}
    _write_cell(out, 20, tracking, fell, pd_only=3.0)  # PD-only 2 and 4 on the two walks
    checks = walk_feedback.confirmation(out)
    assert checks.check.tolist() == [
        "the best loss (joint) falls in no test walk",
        "the best loss (joint) is clear below PD-only",
        "joint falls in at most 2 test walks",
    ]
    # 10 seeds all below, p = 2 / 2^10, Holm over 2 losses: 0.0039; joint fell once of 20.
    assert checks.measured.tolist() == ["1 of 20", "clear below PD-only, Holm p 0.0039", "1 of 20"]
    assert checks.holds.tolist() == [False, True, True]
    page = walk_feedback.page(walk_feedback.table([10, 20], out=out), [10, 20], None, None,
                              checks)  # fmt: skip
    assert "| the best loss (joint) falls in no test walk | 1 of 20 | no |" in page
    assert page.rstrip().endswith("Goal 2 on seeds 20-29: **not confirmed**.")


def test_the_committed_page_is_the_scripts_output_on_the_committed_records():
    path = os.path.join(ROOT, "docs", "results", "walk_feedback.md")
    blocks = walk_feedback.recorded()
    assert blocks, "the page exists, so some block is recorded"
    page = walk_feedback.page(
        walk_feedback.table(blocks),
        blocks,
        walk_feedback.paired(blocks),
        walk_feedback.against_pd(blocks),
        walk_feedback.confirmation(),
    )
    with open(path) as f:
        assert f.read() == page


def test_a_bad_block_is_refused_with_the_allowed_ones(capsys):
    with pytest.raises(SystemExit):
        walk_feedback.main(["--blocks", "15", "--table"])
    assert "--blocks='15' is not allowed: first seeds from (10, 20)" in capsys.readouterr().err
