"""Summary tables and figures (cfm_jax/report.py) against hand-computed numbers."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cfm_jax import report


def _metrics():
    rows = []
    for loss, scale in (("task", 2.0), ("joint", 1.0)):
        for seed in (0, 1):
            for iteration in (0, 1):
                for target in (0, 1):
                    mse = scale * (1 + seed + 2 * target) * (10.0 if iteration == 0 else 1.0)
                    rows.append(
                        dict(loss=loss, seed=seed, iteration=iteration, target=target,
                             tracking_mse=mse, prediction_error=0.5 * mse,
                             predicted_task_error=0.25 * mse)
                    )  # fmt: skip
    return pd.DataFrame(rows)


def test_summary_uses_the_final_iteration_over_seeds_and_targets():
    baselines = pd.DataFrame(
        {"baseline": ["oracle", "oracle", "pd_only", "pd_only"], "target": [0, 1, 0, 1],
         "tracking_mse": [1e-8, 3e-8, 0.1, 0.3]}
    )  # fmt: skip
    table = report.summary(_metrics(), baselines, rms_reach=2.0)
    # joint, final iteration: seeds x targets give 1, 3, 2, 4 -> mean 2.5, pop. std sqrt(1.25)
    assert table.loc["joint", "tracking_mse_mean"] == 2.5
    np.testing.assert_allclose(table.loc["joint", "tracking_mse_std"], np.sqrt(1.25))
    assert table.loc["task", "tracking_mse_mean"] == 5.0
    assert table.loc["joint", "runs"] == 4
    assert table.loc["joint", "prediction_error_mean"] == 1.25
    # losses in the library's order, then the baselines
    assert list(table.index) == ["joint", "task", "oracle", "pd_only"]
    assert table.loc["pd_only", "tracking_mse_mean"] == 0.2
    np.testing.assert_allclose(table.loc["joint", "rmse_over_reach"], np.sqrt(2.5) / 2.0)
    text = report.markdown(table)
    assert text.splitlines()[0].startswith("| controller |")
    assert "| joint | 2.5 |" in text


def test_learning_curves_figure_is_written(tmp_path):
    path = report.plot_learning_curves(_metrics(), str(tmp_path / "curves.png"), title="t")
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    assert path.endswith("curves.png")
