"""experiments/walk_falls.py: where the learned walks fall, from the records (issue 65)."""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import walk_falls

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_the_fall_table_counts_falls_and_their_steps_by_hand():
    # Two losses, iterations 0-2, two runs each; transitions_added ends at the first fall.
    metrics = pd.DataFrame({
        "loss": ["a"] * 6 + ["b"] * 6,
        "iteration": [0, 0, 1, 1, 2, 2] * 2,
        "fell": [1, 1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1.0],
        "transitions_added": [100, 140, 300, 750, 750, 750, 90, 750, 750, 750, 400, 600.0],
    })  # fmt: skip
    table = walk_falls.fall_table(metrics, every=2)
    assert table.iteration.tolist() == [0, 2, 0, 2]  # every 2nd iteration, the last included
    a0, a2, b0, b2 = table.to_dict("records")
    assert (a0["fell"], a0["median"], a0["earliest"], a0["latest"]) == (2, 120.0, 100.0, 140.0)
    assert a2["fell"] == 0 and np.isnan(a2["median"])
    assert (b0["fell"], b0["median"]) == (1, 90.0)
    assert (b2["runs"], b2["fell"], b2["median"]) == (2, 2, 500.0)
    page = walk_falls.markdown(table, "x")
    assert "| a | 0 | 2 of 2 | 0.48 [0.40, 0.56] |" in page  # 120 steps of 0.004 s
    assert "| a | 2 | 0 of 2 | - |" in page


def test_the_committed_page_is_the_scripts_output_on_the_committed_records():
    cell = os.path.join(ROOT, "docs", "results", "comparison", "cells", "walk", "shared")
    metrics = pd.read_csv(os.path.join(cell, "metrics.csv"))
    page = walk_falls.markdown(
        walk_falls.fall_table(metrics), "docs/results/comparison/cells/walk/shared"
    )
    with open(os.path.join(ROOT, "docs", "results", "walk_falls.md")) as f:
        assert f.read() == page
