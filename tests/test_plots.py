"""The figures (cfm_jax/plots.py): each is written, and the learning curves draw the
statistics of cfm_jax/report.py (the hand-computed frames of tests/test_report.py) as their
lines and bands."""

from __future__ import annotations

import os
import statistics

import numpy as np
from test_report import TASK, _hand_frame, _metrics

from cfm_jax import locomotion, plots, report


def test_learning_curves_figure_is_written(tmp_path):
    path = plots.plot_learning_curves(_metrics(), str(tmp_path / "curves.png"), title="t")
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    assert path.endswith("curves.png")


def test_learning_curves_band_is_the_bootstrap_ci_over_seed_means(monkeypatch, tmp_path):
    """The learning-curve figure draws report's interval as its band, and says so; a table
    without the interval's columns: mean ± std."""
    curves = report.seed_curves(_hand_frame(), columns=["tracking_mse"])
    final = curves[curves.iteration == 2].set_index("loss")
    drawn = {}

    def capture(series, path, baselines, title, tracking_label, output_unit, band_label=None):
        drawn.update(series=dict(series), band_label=band_label)
        return path

    monkeypatch.setattr(plots, "_plot_series", capture)
    plots.plot_learning_curves(_hand_frame(), str(tmp_path / "c.png"))
    mean, low, high = drawn["series"]["task"]["tracking_mse"]
    assert mean[2] == statistics.mean(TASK) and (low[2], high[2]) == report.bootstrap_ci(TASK)
    assert low[1] == high[1] == 100.0  # every seed the same: no spread
    assert drawn["band_label"] == "band: 95% bootstrap CI of the mean over seeds"
    assert list(drawn["series"]) == ["joint", "task", "supervised"]  # report.loss_order
    old = curves.drop(columns=["tracking_mse_ci_low", "tracking_mse_ci_high"])
    plots.plot_curves(old, str(tmp_path / "old.png"))
    mean, low, high = drawn["series"]["task"]["tracking_mse"]
    std = final.loc["task", "tracking_mse_std"]
    np.testing.assert_allclose([low[2], high[2]], [mean[2] - std, mean[2] + std])
    assert drawn["band_label"] == "band: ± 1 std over seeds"


def test_figures_with_bands_are_written(tmp_path):
    path = plots.plot_curves(report.seed_curves(_hand_frame()), str(tmp_path / "c.png"))
    assert os.path.getsize(path) > 10_000


def test_foot_force_plot(tmp_path):
    ref = locomotion.jump_reference(0.05, cache=tmp_path / "references")
    q0 = ref.qpos[0].copy()
    q0[2] += 0.005
    run = locomotion.replay(ref, qpos0=q0)
    path = tmp_path / "force.png"
    plots.plot_foot_force(ref, path, observed=run.foot_force, predicted=run.foot_force, foot="FR")
    assert path.stat().st_size > 10_000
