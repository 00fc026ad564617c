"""Summaries, tables and figures of training results (pandas, rich, matplotlib).

Examples:
  >>> import pandas as pd
  >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [1, 1],
  ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
  >>> summary(metrics).loc["joint", "tracking_mse_mean"]
  np.float64(2.0)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from cfm_jax import losses


def summary(
    metrics: pd.DataFrame, baselines: pd.DataFrame | None = None, rms_reach: float | None = None
) -> pd.DataFrame:
    """Final-iteration tracking MSE per loss: mean and std over seeds and targets.

    Args:
      metrics: a metrics table (``TrainResult.metrics``, or several concatenated), with
        columns ``loss``, ``iteration``, ``tracking_mse`` and optionally
        ``prediction_error``, ``predicted_task_error``.
      baselines: ``TrainResult.baselines``; adds rows ``oracle`` and ``pd_only`` (std over
        targets).
      rms_reach: the RMS reaching distance; adds the column ``rmse_over_reach`` (the square
        root of the mean MSE over this distance).

    Returns:
      One row per loss (in ``losses.CONTROLLER_LOSSES`` order) and baseline, columns
      ``iteration``, ``tracking_mse_mean``, ``tracking_mse_std``, ``runs`` and the others.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [1, 1],
      ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
      >>> summary(metrics).loc["joint", "tracking_mse_mean"]
      np.float64(2.0)
    """
    rows = {}
    order = [name for name in losses.CONTROLLER_LOSSES if name in set(metrics["loss"])]
    for loss in order:
        frame = metrics[metrics["loss"] == loss]
        final = frame[frame["iteration"] == frame["iteration"].max()]
        rows[loss] = {
            "iteration": int(final["iteration"].iloc[0]),
            "tracking_mse_mean": final["tracking_mse"].mean(),
            "tracking_mse_std": final["tracking_mse"].std(ddof=0),
            "runs": len(final),
        }
        for column in ("prediction_error", "predicted_task_error"):
            if column in final:
                rows[loss][f"{column}_mean"] = final[column].mean()
    if baselines is not None:
        for name, frame in baselines.groupby("baseline", sort=False):
            rows[name] = {
                "tracking_mse_mean": frame["tracking_mse"].mean(),
                "tracking_mse_std": frame["tracking_mse"].std(ddof=0),
                "runs": len(frame),
            }
    table = pd.DataFrame.from_dict(rows, orient="index")
    if rms_reach is not None:
        table["rmse_over_reach"] = np.sqrt(table["tracking_mse_mean"]) / rms_reach
    return table


SHORT_HEADERS = {
    "tracking_mse_mean": "MSE mean",
    "tracking_mse_std": "MSE std",
    "runs": "runs",
    "prediction_error_mean": "pred. err",
    "predicted_task_error_mean": "pred. task err",
    "rmse_over_reach": "RMSE/reach",
}


def print_summary(
    table: pd.DataFrame,
    title: str = "Final tracking error",
    tracking: str = "joint-position tracking MSE (rad^2)",
) -> None:
    """Print a :func:`summary` table with rich (short column headers, explained below it).

    Args:
      table: the output of :func:`summary`.
      title: the table's title.
      tracking: what the tracking error is and its unit (for the caption).

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["task"], "iteration": [0], "tracking_mse": [0.5]})
      >>> print_summary(summary(metrics))  # doctest: +SKIP
    """
    from rich.console import Console
    from rich.table import Table

    out = Table(
        title=title,
        caption=f"MSE: {tracking}, mean/std over seeds x targets; "
        "pred. err / pred. task err: forward-model prediction error and predicted task "
        "error (squared units of the predicted quantities); RMSE/reach: sqrt(MSE mean) / "
        "RMS reaching distance",
    )
    out.add_column("controller")
    columns = [c for c in table.columns if c != "iteration"]
    for column in columns:
        out.add_column(SHORT_HEADERS.get(column, column), justify="right")
    for name, row in table.iterrows():
        out.add_row(str(name), *(_format(row[c]) for c in columns))
    console = Console()
    if not console.is_terminal:  # files and pipes: do not squeeze the table into 80 columns
        console = Console(width=110)
    console.print(out)


def _format(value) -> str:
    if isinstance(value, float | np.floating):
        if np.isnan(value):
            return "-"
        return f"{value:.3g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.2e}"
    return str(value)


def markdown(table: pd.DataFrame) -> str:
    """The table as GitHub markdown (numbers to 3 significant digits).

    Args:
      table: the output of :func:`summary` (any frame with an index of row names).

    Returns:
      Markdown text, one line per row, the ``iteration`` column left out.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["task"], "iteration": [0], "tracking_mse": [0.5]})
      >>> print(markdown(summary(metrics)))
      | controller | tracking_mse_mean | tracking_mse_std | runs |
      |---|---:|---:|---:|
      | task | 0.5 | 0 | 1 |
    """
    columns = [c for c in table.columns if c != "iteration"]
    lines = ["| controller | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
    for name, row in table.iterrows():
        lines.append(f"| {name} | " + " | ".join(_format(row[c]) for c in columns) + " |")
    return "\n".join(lines)


def plot_learning_curves(
    metrics: pd.DataFrame,
    path: str,
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> str:
    """Tracking MSE, prediction error and predicted task error per iteration, per loss.

    Mean and standard deviation over seeds and targets (the paper's Fig. 3 and 4 style);
    oracle and PD-only tracking MSE as horizontal lines. Log scale. Saves a PNG.

    Args:
      metrics: a metrics table (``TrainResult.metrics``, or several concatenated) with
        columns ``loss``, ``iteration``, ``tracking_mse``, ``prediction_error`` and
        ``predicted_task_error``; one curve per loss.
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
    series = []
    for loss in [n for n in losses.CONTROLLER_LOSSES if n in set(metrics["loss"])]:
        grouped = metrics[metrics["loss"] == loss].groupby("iteration")
        stats = {}
        for column, _ in _panels(tracking_label, output_unit):
            frame = grouped[column]
            stats[column] = (frame.mean(), frame.std(ddof=0).fillna(0.0))
        series.append((loss, stats))
    return _plot_series(series, path, baselines, title, tracking_label, output_unit)


CURVE_ID_COLUMNS = ("seed", "iteration", "target")
"""Columns of a metrics table that identify a row rather than measure something."""


def seed_curves(
    metrics: pd.DataFrame, by: Sequence[str] = ("loss",), columns: Sequence[str] | None = None
) -> pd.DataFrame:
    """Mean and standard deviation over seeds, per iteration, for each group ``by`` (each
    loss, or each loss and override combination of a sweep): the paper's learning curves.

    Each seed's value at an iteration is first averaged over the targets; the mean and the
    population standard deviation (``ddof=0``, as in :func:`summary`) are then taken over
    the seeds.

    Args:
      metrics: a metrics table with ``seed``, ``iteration``, ``target``, the ``by`` columns
        and the metrics (``TrainResult.metrics``, a sweep's table).
      by: the columns that tell one curve from another.
      columns: the metrics to summarise (default: every numeric column that is not an id,
        a group column, ``finite_fraction``, ``transitions_added`` or a training loss).

    Returns:
      One row per group and iteration, groups in order of first appearance, iterations
      ascending: the ``by`` columns, ``iteration``, ``seeds`` and ``<column>_mean``,
      ``<column>_std`` for each column.

    Raises:
      ValueError: a column named in ``by`` or ``columns`` is not in ``metrics``.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 4, "seed": [0, 0, 1, 1],
      ...                         "iteration": [0] * 4, "target": [0, 1, 0, 1],
      ...                         "tracking_mse": [1.0, 3.0, 5.0, 7.0]})
      >>> curves = seed_curves(metrics)  # seed means 2 and 6
      >>> curves[["loss", "iteration", "seeds", "tracking_mse_mean", "tracking_mse_std"]]
          loss  iteration  seeds  tracking_mse_mean  tracking_mse_std
      0  joint          0      2                4.0               2.0
    """
    by = list(by)
    if columns is None:
        skip = set(CURVE_ID_COLUMNS) | set(by) | {
            "finite_fraction", "transitions_added", "forward_loss", "controller_loss"
        }  # fmt: skip
        numeric = pd.api.types.is_numeric_dtype
        columns = [c for c in metrics.columns if c not in skip and numeric(metrics[c])]
    columns = list(columns)
    missing = [c for c in by + columns + ["seed", "iteration"] if c not in metrics.columns]
    if missing:
        raise ValueError(f"columns {missing} are not in the metrics table")
    per_seed = (
        metrics.groupby(by + ["seed", "iteration"], sort=False, dropna=False)[columns]
        .mean()
        .reset_index()
    )
    grouped = per_seed.groupby(by + ["iteration"], sort=False, dropna=False)
    mean, std = grouped[columns].mean(), grouped[columns].std(ddof=0)
    out = pd.DataFrame({"seeds": grouped.size()})
    for column in columns:
        out[f"{column}_mean"] = mean[column]
        out[f"{column}_std"] = std[column]
    out = out.reset_index()
    rank = {key: i for i, key in enumerate(dict.fromkeys(_group_keys(out, by)))}
    out["_rank"] = [rank[key] for key in _group_keys(out, by)]
    out = out.sort_values(["_rank", "iteration"], kind="stable").drop(columns="_rank")
    return out.reset_index(drop=True)


def _group_keys(frame: pd.DataFrame, by: Sequence[str]) -> list[tuple]:
    return [tuple(row) for row in frame[list(by)].astype(str).itertuples(index=False)]


def curves_markdown(
    curves: pd.DataFrame,
    by: Sequence[str] = ("loss",),
    iteration: int | None = None,
    columns: Sequence[str] | None = None,
) -> str:
    """A :func:`seed_curves` table at one ``iteration`` as GitHub markdown: one row per
    group, each metric as ``mean ± std`` over seeds (3 significant digits).

    Args:
      curves: the output of :func:`seed_curves`.
      by: its group columns (as given to :func:`seed_curves`).
      iteration: the iteration to show; None: the last.
      columns: the metrics to show (default: all of ``curves``).

    Returns:
      Markdown text: a line naming the iteration, then the table.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [3, 3],
      ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
      >>> print(curves_markdown(seed_curves(metrics)))
      iteration 3; mean ± std over seeds (each seed averaged over targets)
      <BLANKLINE>
      | loss | seeds | tracking_mse |
      |---|---:|---:|
      | joint | 2 | 2 ± 1 |
    """
    by = list(by)
    if iteration is None:
        iteration = int(curves["iteration"].max())
    rows = curves[curves["iteration"] == iteration]
    if columns is None:
        columns = [c[: -len("_mean")] for c in curves.columns if c.endswith("_mean")]
    header = [*by, "seeds", *columns]
    lines = [
        f"iteration {iteration}; mean ± std over seeds (each seed averaged over targets)",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(by) + "---:|" * (1 + len(columns)),
    ]
    for _, row in rows.iterrows():
        cells = [str(row[c]) for c in by] + [str(int(row["seeds"]))]
        cells += [f"{_format(row[c + '_mean'])} ± {_format(row[c + '_std'])}" for c in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_curves(
    curves: pd.DataFrame,
    path: str,
    by: Sequence[str] = ("loss",),
    baselines: pd.DataFrame | None = None,
    title: str = "",
    tracking_label: str = "joint tracking MSE (rad$^2$)",
    output_unit: str = "(rad/s$^2$)$^2$",
) -> str:
    """The figure of :func:`plot_learning_curves` from a :func:`seed_curves` table: one
    line per group (mean over seeds, band of one std), log scale.

    Args:
      curves: the output of :func:`seed_curves` (with ``tracking_mse``, and
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
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 4, "seed": [0, 1, 0, 1],
      ...                         "iteration": [0, 0, 1, 1], "target": [0] * 4,
      ...                         "tracking_mse": [1.0, 3.0, 0.5, 0.7]})
      >>> path = os.path.join(tempfile.mkdtemp(), "curves.png")
      >>> plot_curves(seed_curves(metrics), path) == path and os.path.getsize(path) > 0
      True
    """
    by = list(by)
    series = []
    for key, frame in curves.groupby(by, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        pairs = zip(by[1:], key[1:], strict=True)
        label = str(key[0]) + "".join(f", {name}={value}" for name, value in pairs)
        frame = frame.set_index("iteration")
        stats = {}
        for column, _ in _panels(tracking_label, output_unit):
            if f"{column}_mean" in frame:
                stats[column] = (frame[f"{column}_mean"], frame[f"{column}_std"].fillna(0.0))
        series.append((label, stats))
    return _plot_series(series, path, baselines, title, tracking_label, output_unit)


def _panels(tracking_label: str, output_unit: str) -> list[tuple[str, str]]:
    return [
        ("tracking_mse", tracking_label),
        ("prediction_error", f"forward-model prediction error ({output_unit})"),
        ("predicted_task_error", f"predicted task error ({output_unit})"),
    ]


def _plot_series(series, path, baselines, title, tracking_label, output_unit) -> str:
    """Three log-scale panels; ``series``: ``[(label, {column: (mean, std)})]`` with
    iteration-indexed mean and std."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    panels = _panels(tracking_label, output_unit)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, (column, label) in zip(axes, panels, strict=True):
        for name, stats in series:
            if column not in stats:
                continue
            mean, std = stats[column]
            (line,) = ax.plot(mean.index, mean.values, marker="o", ms=3, label=name)
            lower = np.maximum(mean.values - std.values, mean.values * 1e-2)
            ax.fill_between(
                mean.index, lower, mean.values + std.values, alpha=0.2, color=line.get_color()
            )
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
        ax.set_yscale("log")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("iteration")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small", framealpha=0.8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
