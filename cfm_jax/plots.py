"""Every figure of the library (matplotlib, imported when a figure is drawn): learning curves
of training results and the foot forces of a legged reference. The numbers they draw come
from :mod:`cfm_jax.report` (tables, statistics) and :mod:`cfm_jax.locomotion`.

Examples:
  >>> import os, tempfile
  >>> import pandas as pd
  >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [0, 1],
  ...                         "tracking_mse": [1.0, 0.1]})
  >>> path = os.path.join(tempfile.mkdtemp(), "curves.png")
  >>> plot_learning_curves(metrics, path) == path
  True
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cfm_jax import report, solo12

if TYPE_CHECKING:
    import pandas as pd

    from cfm_jax.locomotion import LocomotionReference


def _pyplot():
    """matplotlib's pyplot on the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ---- learning curves -------------------------------------------------------------------------


def plot_learning_curves(
    metrics: pd.DataFrame,
    path: str,
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> str:
    """Tracking MSE, prediction error and predicted task error per iteration, per loss.

    Each seed is averaged over its targets; the line is the mean over seeds and the shaded
    band its 95% percentile bootstrap confidence interval over seeds
    (:func:`cfm_jax.report.seed_curves`, :func:`cfm_jax.report.bootstrap_ci`; one seed: no
    band), as the legend says (the paper's Fig. 3 and 4 style). Oracle and PD-only tracking
    MSE as horizontal lines. Log scale. Saves a PNG.

    Args:
      metrics: a metrics table (``TrainResult.metrics``, or several concatenated) with
        columns ``loss``, ``iteration``, ``tracking_mse``, ``seed`` (without it: one
        seed) and optionally ``prediction_error`` and ``predicted_task_error``; one curve
        per loss.
      path: the image file to write (its folder must exist).
      baselines: ``TrainResult.baselines`` (columns ``baseline``, ``tracking_mse``); their
        mean tracking MSE is drawn as horizontal lines (None: no lines).
      title: the figure's title ("": none).
      tracking_label: y label of the tracking panel (the task's tracking error and unit).
      output_unit: squared unit of the forward model's predicted quantity, for the labels
        of the two prediction panels.

    Returns:
      ``path``.

    Examples:
      >>> import os, tempfile
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 4, "seed": [0, 0, 1, 1],
      ...                         "iteration": [0, 1, 0, 1], "target": [0] * 4,
      ...                         "tracking_mse": [1.0, 0.1, 2.0, 0.2],
      ...                         "prediction_error": [1.0, 0.5, 1.0, 0.5],
      ...                         "predicted_task_error": [0.5, 0.1, 0.5, 0.1]})
      >>> with tempfile.TemporaryDirectory() as folder:
      ...     path = plot_learning_curves(metrics, os.path.join(folder, "curves.png"))
      ...     os.path.getsize(path) > 0
      True
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
    path: str,
    by: Sequence[str] = ("loss",),
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> str:
    """The figure of :func:`plot_learning_curves` from a :func:`cfm_jax.report.seed_curves`
    table: one line per group (mean over seeds, each seed averaged over its targets) with its
    confidence interval over seeds as a shaded band (a table without ``_ci_low`` /
    ``_ci_high`` columns: mean ± one std), log scale; the legend says which.

    Args:
      curves: the output of :func:`cfm_jax.report.seed_curves` (with ``tracking_mse``, and
        ``prediction_error`` and ``predicted_task_error`` when they are to be drawn).
      path: the image file to write (its suffix picks the format).
      by: the group columns of ``curves``; lines are labelled ``loss, path=value``.
      baselines: oracle and PD-only tracking per target (drawn as horizontal lines), or
        None.
      title: the figure's title.
      tracking_label: the label of the tracking error's axis.
      output_unit: the unit of the forward model's output, for the other two axes.

    Returns:
      ``path``.

    Examples:
      >>> import os, tempfile
      >>> import pandas as pd
      >>> from cfm_jax import report
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 4, "seed": [0, 1, 0, 1],
      ...                         "iteration": [0, 0, 1, 1], "target": [0] * 4,
      ...                         "tracking_mse": [1.0, 3.0, 0.5, 0.7]})
      >>> path = os.path.join(tempfile.mkdtemp(), "curves.png")
      >>> curves = report.seed_curves(metrics)
      >>> plot_curves(curves, path) == path and os.path.getsize(path) > 0
      True
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
    """``{column: (mean, low, high)}`` of an iteration-indexed
    :func:`cfm_jax.report.seed_curves` group: its confidence interval, or mean ± std for a
    table without one."""
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
) -> str:
    """Three log-scale panels; ``series``: ``[(label, {column: (mean, low, high)})]`` with
    iteration-indexed mean and band (:func:`_bands`); ``band_label`` names the band in the
    legend."""
    plt = _pyplot()
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    panels = _panels(tracking_label, output_unit)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, (column, label) in zip(axes, panels, strict=True):
        positive = False  # a log scale needs a positive value (every run may have diverged)
        for name, stats in series:
            if column not in stats:
                continue
            mean, low, high = stats[column]
            positive |= bool(np.any(np.asarray(mean.values, float) > 0))
            (line,) = ax.plot(mean.index, mean.values, marker="o", ms=3, label=name)
            lower = np.maximum(low.values, mean.values * 1e-2)  # log scale: keep it positive
            ax.fill_between(mean.index, lower, high.values, alpha=0.2, color=line.get_color())
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
            ax.text(0.5, 0.5, "no values: every run diverged", ha="center",
                    transform=ax.transAxes)  # fmt: skip
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("iteration")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    if band_label:
        handles.append(Patch(facecolor="0.5", alpha=0.3, label=band_label))
        labels.append(band_label)
    axes[0].legend(
        handles,
        labels,
        fontsize="small",
        framealpha=0.8,
        title="line: mean over seeds,\neach seed averaged over its targets",
        title_fontsize="small",
    )
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ---- legged references -----------------------------------------------------------------------


def plot_foot_force(
    ref: LocomotionReference,
    path: str | os.PathLike,
    *,
    observed: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    foot: str = "FR",
    title: str | None = None,
):
    """Plot desired (``ref.foot_force``) vs observed (and optionally predicted) force of one
    foot over time, one panel per world axis, like the paper's Fig. 6; saves a PNG. The
    force arrays are ``(T+1, 4, 3)`` (or ``(T, 4, 3)`` for the states after each step).

    Args:
      ref: the :class:`cfm_jax.locomotion.LocomotionReference` (its ``foot_force`` is the
        desired force).
      path: the image file to write (its folder is created).
      observed: ``(T+1, 4, 3)`` or ``(T, 4, 3)`` observed forces, or None.
      predicted: forces of the same shape predicted by a model, or None.
      foot: ``"FL"``, ``"FR"``, ``"HL"`` or ``"HR"``.
      title: the figure's title (None: the kind and foot).

    Examples:
      >>> import os, tempfile
      >>> from cfm_jax import locomotion
      >>> ref = locomotion.walk_reference(0.2, use_cache=False)
      >>> with tempfile.TemporaryDirectory() as folder:
      ...     path = os.path.join(folder, "force.png")
      ...     plot_foot_force(ref, path, observed=locomotion.replay(ref).foot_force)
      ...     os.path.getsize(path) > 0
      True
    """
    plt = _pyplot()
    leg = solo12.LEGS.index(foot)
    t = np.arange(len(ref.foot_force)) * ref.control_dt
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
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
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
