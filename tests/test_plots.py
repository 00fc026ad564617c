"""The figures (cfm_jax/analysis/plots.py): each is returned as a matplotlib Figure and written only
when given a path, and the learning curves draw the statistics of cfm_jax/analysis/report.py (the
hand-computed frames of tests/test_report.py) as their lines and bands, read back from the
returned figure."""

from __future__ import annotations

import os
import statistics

import numpy as np
import pandas as pd
import pytest
from test_report import JOINT, SUPERVISED, TASK, _hand_frame, _metrics

from cfm_jax.analysis import plots, report
from cfm_jax.tasks import locomotion


def _lines(ax):
    """``{label: (x, y)}`` of an axes' plotted lines (horizontal lines: y of length 2)."""
    return {
        line.get_label(): (np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata()))
        for line in ax.get_lines()
    }


def test_learning_curves_figure_is_written(tmp_path):
    """The three panels' lines are the metrics' means by hand: _metrics() has
    ``mse = scale (1 + seed + 2 target) (10 at iteration 0, else 1)``, so a seed's mean
    over its targets 0, 1 is ``scale (2 + seed) f`` and the mean over seeds 0, 1 is
    ``2.5 scale f``; prediction_error is 0.5 mse, predicted_task_error 0.25 mse. The
    baselines are horizontal lines at their mean over targets."""
    baselines = pd.DataFrame(
        {"baseline": ["oracle", "oracle", "pd_only", "pd_only"], "target": [0, 1, 0, 1],
         "tracking_mse": [1e-3, 3e-3, 10.0, 30.0]}
    )  # fmt: skip
    figure = plots.plot_learning_curves(
        _metrics(), str(tmp_path / "curves.png"), baselines=baselines, title="t"
    )
    assert (tmp_path / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "curves.png").stat().st_size > 10_000
    assert os.listdir(tmp_path) == ["curves.png"]  # no temporary file left
    axes = figure.axes
    assert len(axes) == 3
    for ax, factor in zip(axes, (1.0, 0.5, 0.25), strict=True):
        lines = _lines(ax)
        for loss, scale in (("joint", 1.0), ("task", 2.0)):
            x, y = lines[loss]
            np.testing.assert_array_equal(x, [0, 1])
            np.testing.assert_allclose(y, factor * 2.5 * scale * np.array([10.0, 1.0]))
        assert ax.get_yscale() == "log"
    tracking = _lines(axes[0])
    assert set(tracking) == {"joint", "task", "oracle", "pd_only"}
    np.testing.assert_allclose(tracking["oracle"][1], [2e-3, 2e-3])
    np.testing.assert_allclose(tracking["pd_only"][1], [20.0, 20.0])
    assert set(_lines(axes[1])) == {"joint", "task"}  # baselines on the tracking panel only
    assert figure._suptitle.get_text() == "t"


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
    """plot_curves draws each loss's mean over seeds (the hand-computed seed means JOINT,
    TASK, SUPERVISED at iteration 2; every seed 100 at iteration 1) and fills its band
    between report's interval bounds (the band's upper edge is the interval's high end,
    its lower edge the low end, kept above 1 % of the mean for the log scale)."""
    curves = report.seed_curves(_hand_frame())
    figure = plots.plot_curves(curves, str(tmp_path / "c.pdf"))
    assert (tmp_path / "c.pdf").read_bytes()[:5] == b"%PDF-"  # the suffix picks the format
    tracking = figure.axes[0]
    lines = _lines(tracking)
    assert set(lines) == {"joint", "task", "supervised"}
    for loss, seed_means in (("joint", JOINT), ("task", TASK), ("supervised", SUPERVISED)):
        x, y = lines[loss]
        np.testing.assert_array_equal(x, [1, 2])
        np.testing.assert_allclose(y, [100.0, statistics.mean(seed_means)])
    bands = tracking.collections
    assert len(bands) == 3
    for band, seed_means in zip(bands, (JOINT, TASK, SUPERVISED), strict=True):
        vertices = band.get_paths()[0].vertices
        at_final = vertices[vertices[:, 0] == 2, 1]
        low, high = report.bootstrap_ci(seed_means)
        np.testing.assert_allclose([at_final.min(), at_final.max()], [low, high])
        at_first = vertices[vertices[:, 0] == 1, 1]
        np.testing.assert_allclose(at_first, 100.0)  # every seed the same: no spread


def test_foot_force_plot(tmp_path):
    ref = locomotion.jump_reference(0.05, cache=tmp_path / "references")
    q0 = ref.qpos[0].copy()
    q0[2] += 0.005
    run = locomotion.replay(ref, qpos0=q0)
    path = tmp_path / "force.png"
    observed = np.asarray(run.foot_force)
    # a prediction unlike the observation on every leg and axis, so each curve is told apart
    predicted = 0.5 * observed[1:] + np.arange(12.0).reshape(4, 3)
    figure = plots.plot_foot_force(ref, path, observed=observed, predicted=predicted, foot="FR")
    assert path.stat().st_size > 10_000
    fr = 1  # Solo12's legs in the order FL, FR, HL, HR
    time = np.arange(len(ref.foot_force)) * ref.control_dt
    for axis, ax in enumerate(figure.axes):
        lines = _lines(ax)
        assert list(lines) == ["desired", "observed", "predicted"]
        for label, force in (
            ("desired", ref.foot_force), ("observed", observed), ("predicted", predicted)
        ):  # fmt: skip
            x, y = lines[label]
            np.testing.assert_allclose(x, time[len(time) - len(force) :])  # the last steps
            np.testing.assert_array_equal(y, force[:, fr, axis])
        assert ax.get_ylabel() == f"f{'xyz'[axis]} [N]"


def test_without_a_path_nothing_is_written_and_no_pyplot_figure_stays_open(tmp_path, monkeypatch):
    """The returned figure is the one a path would have saved; without a path no file is
    written; pyplot's list of open figures is not touched (no leak in a long notebook)."""
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    before = plt.get_fignums()
    figure = plots.plot_learning_curves(_metrics())
    assert os.listdir(tmp_path) == []
    assert plt.get_fignums() == before
    x, y = _lines(figure.axes[0])["joint"]
    np.testing.assert_allclose(y, 2.5 * np.array([10.0, 1.0]))  # as in the test above


def test_a_failed_save_leaves_the_previous_image(tmp_path, monkeypatch):
    """The image is written whole and renamed into place: a failure in the middle of
    writing keeps the previous file and leaves no temporary file."""
    from matplotlib.figure import Figure

    path = tmp_path / "curves.png"
    plots.plot_learning_curves(_metrics(), path)
    previous = path.read_bytes()

    def half_save(self, f, **kwargs):
        f.write(b"\x89PNG half")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", half_save)
    with pytest.raises(OSError, match="disk full"):
        plots.plot_learning_curves(_metrics(), path, title="new")
    assert path.read_bytes() == previous
    assert os.listdir(tmp_path) == ["curves.png"]


def _one_seed(iterations: int) -> pd.DataFrame:
    rows = [
        dict(loss=loss, seed=0, iteration=i, target=0, tracking_mse=v * (i + 1))
        for loss, v in (("joint", 1.0), ("task", 2.0), ("distal", 3.0), ("supervised", 4.0))
        for i in range(iterations + 1)
    ]
    return pd.DataFrame(rows)


@pytest.mark.parametrize("iterations", [0, 1, 4])
def test_legend_below_the_curves_no_band_without_one_and_whole_iterations(iterations):
    # The legend sat on the tracking panel's curves; with one seed it named a "95%
    # bootstrap CI" band that is not drawn; a 0-iteration run had ticks at 0.02, 0.04...
    baselines = pd.DataFrame({"baseline": ["oracle", "pd_only"], "tracking_mse": [1e-3, 0.5]})
    figure = plots.plot_learning_curves(_one_seed(iterations), baselines=baselines)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    renderer = canvas.get_renderer()
    (legend,) = figure.legends
    assert all(ax.get_legend() is None for ax in figure.axes)
    box = legend.get_window_extent(renderer)
    for ax in figure.axes:
        assert not box.overlaps(ax.get_window_extent(renderer))
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts == ["joint", "task", "distal", "supervised", "oracle", "pd_only"]
    ticks = [t for t in figure.axes[0].get_xticks() if figure.axes[0].get_xlim()[0] <= t]
    ticks = [t for t in ticks if t <= figure.axes[0].get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)
    assert set(range(iterations + 1)) <= {int(t) for t in ticks} or iterations > 2
    # These metrics have no prediction columns: said so, not "every run diverged".
    words = [t.get_text() for t in figure.axes[1].texts]
    assert words == ["not in these metrics"]


def test_legend_names_the_band_when_there_is_one(tmp_path):
    frame = pd.concat(
        [_one_seed(2), _one_seed(2).assign(seed=1, tracking_mse=lambda f: 2 * f.tracking_mse)]
    )
    figure = plots.plot_learning_curves(frame)
    texts = [t.get_text() for t in figure.legends[0].get_texts()]
    assert any("bootstrap CI" in t for t in texts)
