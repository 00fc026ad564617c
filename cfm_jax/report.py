"""Summaries, tables and figures of training results (pandas, rich, matplotlib).

Examples:
  >>> import pandas as pd
  >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [1, 1],
  ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
  >>> summary(metrics).loc["joint", "tracking_mse_mean"]
  np.float64(2.0)
"""

from __future__ import annotations

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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    panels = [
        ("tracking_mse", tracking_label),
        ("prediction_error", f"forward-model prediction error ({output_unit})"),
        ("predicted_task_error", f"predicted task error ({output_unit})"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, (column, label) in zip(axes, panels, strict=True):
        for loss in [n for n in losses.CONTROLLER_LOSSES if n in set(metrics["loss"])]:
            frame = metrics[metrics["loss"] == loss].groupby("iteration")[column]
            mean, std = frame.mean(), frame.std(ddof=0).fillna(0.0)
            (line,) = ax.plot(mean.index, mean.values, marker="o", ms=3, label=loss)
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
