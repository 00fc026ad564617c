"""The library's figures (matplotlib, without pyplot): each returns the ``Figure`` and, given
a ``path``, also writes the image there whole (the suffix picks the format, default PNG)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cfm_jax._files import atomic_path
from cfm_jax.analysis import report
from cfm_jax.sim import solo12

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

    from cfm_jax.tasks.locomotion import LocomotionReference


def _figure(figsize: tuple[float, float]) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=figsize)


def _save(figure: Figure, path: str | os.PathLike | None, dpi: int) -> None:
    if path is None:
        return
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        figure.savefig(f, format=fmt, dpi=dpi)


# ---- learning curves -------------------------------------------------------------------------


def plot_learning_curves(
    metrics: pd.DataFrame,
    path: str | os.PathLike | None = None,
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> Figure:
    """Tracking MSE, prediction and predicted task error per iteration and loss, mean over seeds
    with its bootstrap interval as a band, log scale (the paper's Fig. 3 and 4).

    Args:
      metrics: ``TrainResult.metrics``, or several concatenated (without ``seed``: one seed).
      path: the image file to write (its folder must exist), or None: no file.
      baselines: ``TrainResult.baselines``: each baseline's mean tracking MSE as a line.
      title: the figure's title ("": none).
      tracking_label: y label of the tracking panel (the task's error and unit).
      output_unit: squared unit of the forward model's output, for the other two panels.

    Examples:
      >>> import pandas as pd
      >>> m = pd.DataFrame(dict(loss="joint", seed=[0, 0, 1, 1], iteration=[0, 1, 0, 1],
      ...                       tracking_mse=[1.0, 0.1, 2.0, 0.2]))
      >>> plot_learning_curves(m).axes[0].get_ylabel()
      'joint tracking MSE (rad$^2$)'
    """
    frame = metrics if "seed" in metrics.columns else metrics.assign(seed=0)
    columns = [c for c, _ in _panels(tracking_label, output_unit) if c in frame.columns]
    curves = report.seed_curves(frame, by=["loss"], columns=columns)
    series = []
    for loss in report.loss_order(curves["loss"]):
        series.append((loss, _bands(curves[curves["loss"] == loss].set_index("iteration"))))
    return _plot_series(
        series, path, baselines, title, tracking_label, output_unit, _band_label(curves)
    )


def plot_curves(
    curves: pd.DataFrame,
    path: str | os.PathLike | None = None,
    by: Sequence[str] = ("loss",),
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> Figure:
    """:func:`plot_learning_curves` from a :func:`cfm_jax.analysis.report.seed_curves` table: a line
    per group, its band the confidence interval (a table without one: mean ± one std).

    Args:
      curves: the output of :func:`cfm_jax.analysis.report.seed_curves`.
      path: the image file to write, or None: no file.
      by: the group columns of ``curves``; lines are labelled ``loss, column=value``.
      baselines: as for :func:`plot_learning_curves`.
      title: as for :func:`plot_learning_curves`.
      tracking_label: as for :func:`plot_learning_curves`.
      output_unit: as for :func:`plot_learning_curves`.

    Examples:
      >>> import tempfile
      >>> import pandas as pd
      >>> m = pd.DataFrame(dict(loss="joint", seed=[0, 1, 0, 1], iteration=[0, 0, 1, 1],
      ...                       tracking_mse=[1.0, 3.0, 0.5, 0.7]))
      >>> from cfm_jax.analysis import report
      >>> figure = plot_curves(report.seed_curves(m), tempfile.mkdtemp() + "/curves.png")
      >>> figure.axes[0].get_lines()[0].get_ydata().tolist()  # mean over seeds
      [2.0, 0.6]
    """
    by = list(by)
    series = []
    for key, frame in curves.groupby(by, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        pairs = zip(by[1:], key[1:], strict=True)
        label = str(key[0]) + "".join(f", {name}={value}" for name, value in pairs)
        series.append((label, _bands(frame.set_index("iteration"))))
    return _plot_series(
        series, path, baselines, title, tracking_label, output_unit, _band_label(curves)
    )


def _panels(tracking_label: str, output_unit: str) -> list[tuple[str, str]]:
    return [
        ("tracking_mse", tracking_label),
        ("prediction_error", f"forward-model prediction error ({output_unit})"),
        ("predicted_task_error", f"predicted task error ({output_unit})"),
    ]


def _bands(frame: pd.DataFrame) -> dict:
    bands = {}
    for column, _ in _panels("", ""):
        if f"{column}_mean" not in frame:
            continue
        mean = frame[f"{column}_mean"]
        if f"{column}_ci_low" in frame:
            low, high = frame[f"{column}_ci_low"], frame[f"{column}_ci_high"]
        else:
            std = frame[f"{column}_std"].fillna(0.0)
            low, high = mean - std, mean + std
        bands[column] = (mean, low.fillna(mean), high.fillna(mean))
    return bands


def _band_label(curves: pd.DataFrame) -> str:
    if any(c.endswith("_ci_low") for c in curves.columns):
        confidence = curves.attrs.get("confidence") or report.CONFIDENCE
        return f"band: {100 * confidence:g}% bootstrap CI of the mean over seeds"
    return "band: ± 1 std over seeds"


def _plot_series(
    series, path, baselines, title, tracking_label, output_unit, band_label=None
) -> Figure:
    """The three panels of ``series``, ``[(label, {column: (mean, low, high)})]``."""
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    panels = _panels(tracking_label, output_unit)
    fig = _figure((15, 5.2))
    axes = fig.subplots(1, 3)
    banded = False  # whether any band has a width (one seed: none)
    for ax, (column, label) in zip(axes, panels, strict=True):
        positive = False  # a log scale needs a positive value (every run may have diverged)
        recorded = any(column in stats for _, stats in series)
        for name, stats in series:
            if column not in stats:
                continue
            mean, low, high = stats[column]
            positive |= bool(np.any(np.asarray(mean.values, float) > 0))
            (line,) = ax.plot(mean.index, mean.values, marker="o", ms=3, label=name)
            lower = np.maximum(low.values, mean.values * 1e-2)  # log scale: keep it positive
            ax.fill_between(mean.index, lower, high.values, alpha=0.2, color=line.get_color())
            banded |= bool(np.any(np.asarray(high.values) > np.asarray(low.values)))
        if column == "tracking_mse" and baselines is not None:
            styles = {"oracle": ":", "pd_only": "--"}
            for name, frame in baselines.groupby("baseline", sort=False):
                ax.axhline(
                    frame["tracking_mse"].mean(),
                    color="k",
                    ls=styles.get(name, "-."),
                    lw=1,
                    label=name,
                )
                positive |= bool(frame["tracking_mse"].mean() > 0)
        if positive:
            ax.set_yscale("log")
        else:
            empty = "no values: every run diverged" if recorded else "not in these metrics"
            ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        first, last = ax.get_xlim()
        if last - first < 2:  # one or two iterations (0 only: no fractional ticks)
            low, high = np.floor(first + 0.5), np.ceil(last - 0.5)
            ax.set_xlim(low - 0.5, high + 0.5)
            ax.set_xticks(np.arange(low, high + 1))
        ax.set_xlabel("iteration")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    if band_label and banded:
        handles.append(Patch(facecolor="0.5", alpha=0.3, label=band_label))
        labels.append(band_label)
    # Below the panels, never over a curve.
    fig.legend(
        handles,
        labels,
        loc="lower center",
        ncol=min(len(labels), 4),
        fontsize="small",
        title="line: mean over seeds, each seed averaged over its targets",
        title_fontsize="small",
    )
    if title:
        fig.suptitle(title)
    rows = -(-len(labels) // 4)
    fig.tight_layout(rect=(0, 0.06 + 0.045 * rows, 1, 1))
    _save(fig, path, dpi=120)
    return fig


# ---- legged references -----------------------------------------------------------------------


def plot_foot_force(
    ref: LocomotionReference,
    path: str | os.PathLike | None = None,
    *,
    observed: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    foot: str = "FR",
    title: str | None = None,
) -> Figure:
    """Desired (``ref.foot_force``), observed and predicted force of one foot per world axis.

    Args:
      ref: the :class:`cfm_jax.tasks.locomotion.LocomotionReference`.
      path: the image file to write (its folder is created), or None: no file.
      observed: ``(T+1, 4, 3)`` or ``(T, 4, 3)`` observed forces, or None.
      predicted: forces predicted by a model, or None.
      foot: ``"FL"``, ``"FR"``, ``"HL"`` or ``"HR"``.
      title: the figure's title (None: the kind and foot).

    Examples:
      >>> from cfm_jax.tasks import locomotion
      >>> ref = locomotion.walk_reference(0.2, use_cache=False)
      >>> figure = plot_foot_force(ref, observed=locomotion.replay(ref).foot_force)
      >>> [line.get_label() for line in figure.axes[0].get_lines()]  # the paper's Fig. 6
      ['desired', 'observed']
    """
    leg = solo12.LEGS.index(foot)
    t = np.arange(len(ref.foot_force)) * ref.control_dt
    fig = _figure((7, 6))
    axes = fig.subplots(3, 1, sharex=True)
    curves = [("desired", ref.foot_force, dict(color="k", lw=2.0, alpha=0.6))]
    if observed is not None:
        curves.append(("observed", np.asarray(observed), dict(color="C0", lw=1.2)))
    if predicted is not None:
        curves.append(("predicted", np.asarray(predicted), dict(color="C3", lw=1.0, ls="--")))
    for axis, ax in enumerate(axes):
        for label, force, style in curves:
            ax.plot(t[-len(force) :], force[:, leg, axis], label=label, **style)
        ax.set_ylabel(f"f{'xyz'[axis]} [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or f"{ref.kind}: contact force of the {foot} foot (world frame)")
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    _save(fig, path, dpi=110)
    return fig
