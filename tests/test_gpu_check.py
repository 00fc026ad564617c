"""experiments/gpu_check.py: the parts that run without a GPU (the script itself runs on one).

The wheels it prepares are pinned by constraints.txt (read back here by hand), and the final
errors it reports are recomputed from a hand-written metrics table.
"""

from __future__ import annotations

import os

import gpu_check
import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")


def test_every_missing_package_has_the_pin_of_constraints_txt():
    pinned = {}
    for line in open(os.path.join(ROOT, "constraints.txt")):
        if "==" in line and not line.lstrip().startswith("#"):
            name, version = line.strip().split("==")
            pinned[name.lower().replace("_", "-")] = version
    got = gpu_check.pins()
    for name in gpu_check.MISSING:
        key = name.lower().replace("_", "-")
        assert got[key] == pinned[key], name
    assert got["jax"] == pinned["jax"]


def test_final_errors_skip_diverged_runs_and_read_the_last_iteration(tmp_path):
    (tmp_path / "metrics.csv").write_text(
        "loss,seed,iteration,target,tracking_mse,diverged\n"
        "joint,0,0,0,9.0,0\njoint,0,1,0,1.0,0\njoint,0,1,1,3.0,0\njoint,0,1,2,100.0,1\n"
        "task,0,0,0,5.0,0\ntask,0,1,0,2.0,0\n"
    )
    (tmp_path / "baselines.csv").write_text(
        "baseline,target,tracking_mse\noracle,0,1e-6\noracle,1,3e-6\npd_only,0,0.5\n"
    )
    e = gpu_check._final_errors(str(tmp_path))
    assert e["joint"] == dict(mse=2.0, diverged=1, runs=3, iteration=1)  # (1 + 3) / 2
    assert e["task"] == dict(mse=2.0, diverged=0, runs=1, iteration=1)
    assert e["oracle"]["mse"] == pytest.approx(2e-6) and e["pd_only"]["mse"] == 0.5


def test_json_line_is_the_last_json_object_with_the_key():
    text = 'noise\n{"a": 1, "iteration_s": 2}\nwarning {not json iteration_s\n{"b": 3}\n'
    assert gpu_check._json_line(text, "iteration_s") == {"a": 1, "iteration_s": 2}
    assert gpu_check._json_line("nothing here", "iteration_s") is None


def test_pytest_summary_finds_the_result_line_among_warnings_and_counts_a_cut_run():
    # As on the H100 (2026-11-27): the result line on stdout, pytest-benchmark's warnings after
    # it on stderr; the first table showed a warning as the result.
    done = (
        "............FF.ssss......   [100%]\n=== FAILURES ===\n"
        "FAILED tests/test_native.py::test_x\n2 failed, 46 passed, 4 skipped in 49.71s\n"
        "logger.py:44: PytestBenchmarkWarning: Benchmarks are automatically disabled\n"
        "  warner(PytestBenchmarkWarning(text))\n"
    )
    assert gpu_check.pytest_summary(done) == "2 failed, 46 passed, 4 skipped in 49.71s"
    cut = "bringing up nodes...\n\n..F.   [ 80%]\n..   [100%]  warner(x)\n"
    assert gpu_check.pytest_summary(cut) == "progress: 5 passed, 1 failed"
    assert gpu_check.pytest_summary("no pytest here\n") == ""
