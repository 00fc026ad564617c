"""Summaries, tables and bootstrap statistics of training results (pandas, rich), each
uncertainty over seeds averaged over their targets; see docs/how-to/metrics.md."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from cfm_jax import config as config_lib
from cfm_jax.learning import forward_models, losses

CONFIDENCE = 0.95
"""Confidence level of the intervals of the tables and figures."""

RESAMPLES = 10_000
"""Bootstrap resamples of :func:`bootstrap_ci` and of every table and figure here."""

BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's random numbers (fixed: the same data give the same report)."""


def config_record(config) -> dict:
    """The ``config.json`` record: JSON of ``config.to_dict``, plus a torque ``robot_conversion``.

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Examples:
      >>> config_record(cfm_jax.Config(robot="two_link_arm"))["robot"]
      'two_link_arm'
    """
    import json

    record = json.loads(json.dumps(config_lib.to_dict(config)))
    if getattr(config, "robot_actuators", "strict") != "strict":
        from cfm_jax.sim import robots

        record["robot_conversion"] = robots.conversion(config.robot, config.robot_torque_limit)
    return record


def protocol(config) -> str:
    """The line every summary starts with: how the data and ``s*`` were made, normaliser, model.

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Examples:
      >>> print(protocol(cfm_jax.Config()))
      initial data: `loop.babbling='reaching'` (2 rollouts per target, torque noise 0.1 of the coupled torque scale, T n, `loop.babbling_gains='lightest'`); s* gains kp 100, kd 20; `loop.normaliser='babbling'`; `forward.kind='mlp'`
    """  # noqa: E501
    loop, task = config.loop, config.task
    gains = f"s* gains kp {task.kp:g}, kd {task.kd:g}"
    if task.joint_kp is not None or task.joint_kd is not None:
        joint_kp = task.kp if task.joint_kp is None else task.joint_kp
        joint_kd = task.kd if task.joint_kd is None else task.joint_kd
        gains += f" (base), joint_kp {joint_kp:g}, joint_kd {joint_kd:g}"
    if task.desired == "next_velocity":
        rate = "" if task.control_dt is None else f" = {1.0 / task.control_dt:g}/s"
        gains = (
            f"s* the desired next velocity (`task.desired={task.desired!r}`: kp 0, kd "
            f"1/control_dt{rate} on base and joints)"
        )
        if task.joint_kp:
            gains = gains[:-1] + f", joint_kp {task.joint_kp:g})"
    model = forward_models.describe(config.forward)
    if getattr(config, "robot_actuators", "strict") != "strict":
        from cfm_jax.sim import robots

        model += "; " + robots.conversion_note(config.robot, config.robot_torque_limit)
    scale = getattr(loop, "torque_scale", "limit")
    coupled = "the coupled torque scale, T n"
    noise_of = {"limit": "the limit", **dict.fromkeys(config_lib.COUPLED_NOISE_SCALES, coupled)}
    noise_of = noise_of.get(scale, "each joint's torque scale")
    babbling_gains = getattr(loop, "babbling_gains", "baseline")
    if task.name == "inverse_dynamics" and babbling_gains != "baseline":
        noise_of += f", `loop.babbling_gains={babbling_gains!r}`"
    return (
        f"initial data: `loop.babbling={loop.babbling!r}` ({loop.babbling_rollouts} rollout"
        f"{'s' if loop.babbling_rollouts != 1 else ''} "
        f"per target, torque noise {loop.babbling_noise:g} of {noise_of}); {gains}; "
        f"`loop.normaliser={loop.normaliser!r}`; {model}"
    )


# ----- statistics over seeds ----------------------------------------------------------


def bootstrap_ci(
    values, confidence: float = CONFIDENCE, resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> tuple[float, float]:
    """Percentile bootstrap interval ``(low, high)`` of the mean of a 1-D sample (ValueError: bad
    arguments); too narrow with few values: read a 3-seed interval as a lower bound.

    Args:
      values: the sample ``(n,)``; NaN makes the interval NaN.
      confidence: the level ``c`` in (0, 1): the ``(1 ± c)/2`` percentiles of the means.
      resamples: the number of resamples (``resamples x n`` indices: for small samples).
      seed: seed of ``np.random.default_rng``, which draws the indices.

    Examples:
      >>> bootstrap_ci([1.0, 2.0, 3.0, 4.0]), bootstrap_ci([2.0]), bootstrap_ci([])
      ((1.5, 3.5), (2.0, 2.0), (nan, nan))
    """
    x = np.asarray(values, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"values must be 1-D, got shape {x.shape}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is not allowed: a number in (0, 1)")
    if isinstance(resamples, bool) or int(resamples) != resamples or resamples < 1:
        raise ValueError(f"resamples={resamples!r} is not allowed: a positive integer")
    n = len(x)
    if n == 0:
        return float("nan"), float("nan")
    if n == 1:
        return float(x[0]), float(x[0])
    rng = np.random.default_rng(seed)
    index = rng.integers(0, n, size=(int(resamples), n))
    means = x[index].mean(axis=1)
    low, high = np.percentile(means, [100 * (1 - confidence) / 2, 100 * (1 + confidence) / 2])
    return float(low), float(high)


def diverged_runs(metrics: pd.DataFrame) -> pd.Series:
    """Bool Series: which rows of a metrics table diverged (``diverged == 1``).

    Args:
      metrics: a metrics table (no ``diverged`` column: none).

    Examples:
      >>> diverged_runs(pd.DataFrame({"diverged": [0.0, 1.0]})).tolist()
      [False, True]
    """
    if "diverged" not in metrics.columns:
        return pd.Series(False, index=metrics.index)
    return metrics["diverged"].fillna(0) == 1


def failed_runs(metrics: pd.DataFrame) -> pd.Series:
    """Bool Series: the failed runs of every ranking, diverged (:func:`diverged_runs`) or fell.

    Args:
      metrics: a metrics table.

    Examples:
      >>> failed_runs(pd.DataFrame({"diverged": [0.0, 1.0, 0.0], "fell": [1.0, 0.0, 0.0]})).tolist()
      [True, True, False]
    """
    failed = diverged_runs(metrics)
    if "fell" in metrics.columns:
        failed = failed | (metrics["fell"].fillna(0) == 1)
    return failed


def without_diverged(metrics: pd.DataFrame, column: str) -> pd.Series:
    """``column``, NaN at the diverged runs: the rule of every table (counted, not averaged).

    Args:
      metrics: a metrics table.
      column: the metric (``diverged``, ``diverged_step`` and non-numeric ones: unchanged).

    Examples:
      >>> frame = pd.DataFrame({"tracking_mse": [1.0, 0.5], "diverged": [0.0, 1.0]})
      >>> without_diverged(frame, "tracking_mse").tolist()
      [1.0, nan]
    """
    values = metrics[column]
    if column in ("diverged", "diverged_step") or not pd.api.types.is_numeric_dtype(values):
        return values
    return values.where(~np.asarray(diverged_runs(metrics)))


def seed_means(
    metrics: pd.DataFrame,
    column: str = "tracking_mse",
    iteration: int | None = None,
    by: Sequence[str] = ("loss",),
) -> pd.DataFrame:
    """Per group and seed, ``column`` averaged over the seed's ``targets`` (NaN, diverged skipped)
    at one iteration: the unit of the statistics (ValueError: a missing column).

    Args:
      metrics: a metrics table with ``by``, ``iteration``, ``column``, ``seed`` (else 0).
      column: the metric to average.
      iteration: the iteration; None: each group's last.
      by: the columns that tell one group from another.

    Examples:
      >>> m = pd.DataFrame(dict(loss="joint", seed=[1, 1, 0], iteration=2, tracking_mse=[5, 7, 2]))
      >>> seed_means(m)
          loss  seed  iteration  tracking_mse  targets
      0  joint     0          2           2.0        1
      1  joint     1          2           6.0        2
    """
    by = list(by)
    _require(metrics, [*by, "iteration", column])
    frame = metrics if "seed" in metrics.columns else metrics.assign(seed=0)
    if iteration is None:
        last = frame.groupby(by, sort=False, dropna=False)["iteration"].transform("max")
        frame = frame[frame["iteration"] == last]
    else:
        frame = frame[frame["iteration"] == iteration]
    frame = frame.assign(**{column: without_diverged(frame, column)})
    grouped = frame.groupby([*by, "seed", "iteration"], sort=False, dropna=False)[column]
    out = pd.DataFrame({column: grouped.mean(), "targets": grouped.count()}).reset_index()
    rank = {key: i for i, key in enumerate(dict.fromkeys(_group_keys(out, by)))}
    out["_rank"] = [rank[key] for key in _group_keys(out, by)]
    out = out.sort_values(["_rank", "seed"], kind="stable").drop(columns="_rank")
    return out.reset_index(drop=True)


def mean_ci(values, confidence: float = CONFIDENCE) -> dict:
    """``{"mean", "low", "high"}`` of a sample: its mean and :func:`bootstrap_ci`.

    Args:
      values: the sample ``(n,)``, e.g. one loss's seed means ordered by seed.
      confidence: the confidence level, in (0, 1).

    Examples:
      >>> mean_ci([1.0, 2.0, 3.0, 4.0])
      {'mean': 2.5, 'low': 1.5, 'high': 3.5}
    """
    x = np.asarray(values, dtype=float)
    low, high = bootstrap_ci(x, confidence)
    return {"mean": float(x.mean()) if x.size else float("nan"), "low": low, "high": high}


def ci_text(stats: dict) -> str:
    """``"mean [low, high]"`` of :func:`mean_ci` or :func:`paired_difference`, 3 digits each.

    Args:
      stats: a mapping with the keys ``"mean"``, ``"low"`` and ``"high"``.

    Examples:
      >>> ci_text({"mean": 2.0e-5, "low": 1.2e-5, "high": 0.2718})
      '2.00e-05 [1.20e-05, 0.272]'
    """
    f = _format
    return f"{f(stats['mean'])} [{f(stats['low'])}, {f(stats['high'])}]"


def paired_difference(
    a,
    b,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> dict:
    """Mean of ``d_s = a_s - b_s`` over the ``n`` seeds both have, :func:`bootstrap_ci` of ``d``.

    Args:
      a: values per seed, a ``pd.Series`` indexed by seed or a dict (ValueError: a seed twice).
      b: the same for the other loss.
      confidence: the confidence level, in (0, 1).
      resamples: bootstrap resamples.
      seed: seed of the bootstrap's random numbers.

    Examples:
      >>> paired_difference({0: 1.0, 1: 2.0, 2: 4.0}, {2: 3.0, 0: 2.0})  # d = -1, 1
      {'mean': 0.0, 'low': -1.0, 'high': 1.0, 'n': 2}
    """
    a, b = _per_seed(a, "a"), _per_seed(b, "b")
    seeds = sorted(set(a.index) & set(b.index))
    d = (a.loc[seeds] - b.loc[seeds]).to_numpy(dtype=float) if seeds else np.zeros(0)
    low, high = bootstrap_ci(d, confidence, resamples, seed)
    mean = float(d.mean()) if len(d) else float("nan")
    return {"mean": mean, "low": low, "high": high, "n": len(d)}


def _per_seed(values, name: str) -> pd.Series:
    series = pd.Series(values, dtype=float)  # a dict's keys or a Series' index: the seeds
    if series.index.has_duplicates:
        seeds = sorted(set(series.index[series.index.duplicated()]))
        raise ValueError(f"{name} has seeds {seeds} more than once: one value per seed")
    return series[np.isfinite(series.to_numpy())]


def summary(
    metrics: pd.DataFrame,
    baselines: pd.DataFrame | None = None,
    rms_reach: float | None = None,
    column: str = "tracking_mse",
    iteration: int | None = None,
    confidence: float = CONFIDENCE,
) -> pd.DataFrame:
    """Final error per loss and baseline, over seeds x targets and over seed means (bootstrap
    interval), with the failed runs; columns: docs/how-to/metrics.md.

    Args:
      metrics: a metrics table with ``loss``, ``iteration``, ``column`` (else ValueError).
      baselines: ``TrainResult.baselines``: adds rows ``oracle`` and ``pd_only``.
      rms_reach: the RMS reaching distance: adds ``rmse_over_reach``, ``sqrt(mean) / reach``.
      column: the metric, e.g. ``tracking_mse`` or ``force_mse``.
      iteration: the iteration; None: each loss's last.
      confidence: the level of the interval.

    Examples:
      >>> m = pd.DataFrame(dict(loss="joint", seed=[0, 1], iteration=1, tracking_mse=[1.0, 3.0]))
      >>> summary(m).loc["joint", ["tracking_mse_mean", "seed_std", "ci_low", "ci_high"]].tolist()
      [2.0, 1.4142135623730951, 1.0, 3.0]
    """
    _require(metrics, ["loss", "iteration", column])
    means = seed_means(metrics, column, iteration)
    rows = {}
    for loss in loss_order(means["loss"]):
        per_seed = means[means["loss"] == loss]
        at = int(per_seed["iteration"].iloc[0])
        final = metrics[(metrics["loss"] == loss) & (metrics["iteration"] == at)]
        values = per_seed[column].to_numpy(dtype=float)
        values = values[np.isfinite(values)]
        low, high = bootstrap_ci(values, confidence)
        kept = without_diverged(final, column)
        rows[loss] = {
            "iteration": at,
            f"{column}_mean": kept.mean(),
            f"{column}_std": kept.std(ddof=0),
            "runs": len(final),
            "seeds": len(values),
            "seed_std": float(np.std(values, ddof=1)) if len(values) > 1 else float("nan"),
            "ci_low": low,
            "ci_high": high,
        }
        if "diverged" in final:
            count = int(np.sum(diverged_runs(final)))
            rows[loss]["diverged"] = count
            rows[loss]["diverged_fraction"] = count / len(final) if len(final) else np.nan
        if "fell" in final:  # the legged tasks: runs in which the robot fell
            rows[loss]["fell"] = int(np.sum(final["fell"].fillna(0) == 1))
        for extra in ("prediction_error", "predicted_task_error"):
            if extra in final and extra != column:
                rows[loss][f"{extra}_mean"] = without_diverged(final, extra).mean()
    if baselines is not None and column in baselines:
        for name, frame in baselines.groupby("baseline", sort=False):
            rows[name] = {
                f"{column}_mean": frame[column].mean(),
                f"{column}_std": frame[column].std(ddof=0),
                "runs": len(frame),
            }
    table = pd.DataFrame.from_dict(rows, orient="index")
    if rms_reach is not None and len(table):
        table["rmse_over_reach"] = np.sqrt(table[f"{column}_mean"]) / rms_reach
    table.attrs.update(column=column, confidence=confidence, resamples=RESAMPLES)
    return table


def paired_table(
    metrics: pd.DataFrame,
    reference: str | None = "joint",
    column: str = "tracking_mse",
    iteration: int | None = None,
    confidence: float = CONFIDENCE,
) -> pd.DataFrame:
    """Per other loss, :func:`paired_difference` of the seed means, reference minus loss.

    Args:
      metrics: a metrics table with ``loss``, ``seed``, ``iteration`` and ``column``.
      reference: the loss compared with (ValueError if absent); None: ``joint``, else the first.
      column: the metric (an error: negative, the reference is better).
      iteration: the iteration; None: each loss's last.
      confidence: the level of the interval.

    Examples:
      >>> m = pd.DataFrame(dict(loss=["joint"] * 2 + ["task"] * 2, seed=[0, 1] * 2,
      ...                       iteration=1, tracking_mse=[1.0, 2.0, 3.0, 3.0]))  # d: -2, -1
      >>> paired_table(m).loc["task"].tolist()  # mean_difference, ci_low, ci_high, seeds
      [-1.5, -2.0, -1.0, 2.0]
    """
    means = seed_means(metrics, column, iteration)
    present = loss_order(means["loss"])
    if reference is None:
        reference = "joint" if "joint" in present else (present[0] if present else "joint")
    if reference not in present:
        raise ValueError(f"reference loss {reference!r} is not in the metrics (losses: {present})")

    def per_seed(loss):
        return means[means["loss"] == loss].set_index("seed")[column]

    rows, index = [], []
    for loss in present:
        if loss == reference:
            continue
        result = paired_difference(per_seed(reference), per_seed(loss), confidence)
        index.append(loss)
        rows.append([result["mean"], result["low"], result["high"], result["n"]])
    table = pd.DataFrame(
        rows, index=pd.Index(index, name="loss", dtype=object),
        columns=["mean_difference", "ci_low", "ci_high", "seeds"],
    )  # fmt: skip
    table["seeds"] = table["seeds"].astype(int)
    table.attrs.update(
        reference=reference, column=column, confidence=confidence, resamples=RESAMPLES
    )
    return table


def _require(frame: pd.DataFrame, columns: Iterable[str]) -> None:
    missing = [c for c in dict.fromkeys(columns) if c not in frame.columns]
    if missing:
        raise ValueError(f"columns {missing} are not in the metrics table")


def loss_order(names) -> list[str]:
    """Distinct loss names in table order: the registered losses'
    (:data:`cfm_jax.learning.losses.REGISTRY`) first, then others.

    Args:
      names: loss names, repeats allowed (a metrics table's ``loss`` column).

    Examples:
      >>> loss_order(["mine", "task", "joint", "task"])
      ['joint', 'task', 'mine']
    """
    present = list(dict.fromkeys(names))
    known = [name for name in losses.REGISTRY if name in present]
    return known + [name for name in present if name not in losses.REGISTRY]


# ----- tables -------------------------------------------------------------------------


SHORT_HEADERS = {
    "tracking_mse_mean": "MSE mean",
    "tracking_mse_std": "MSE std",
    "runs": "runs",
    "seeds": "seeds",
    "seed_std": "seed std",
    "prediction_error_mean": "pred. err",
    "predicted_task_error_mean": "pred. task err",
    "rmse_over_reach": "RMSE/reach",
    "diverged": "diverged",
    "diverged_fraction": "div. frac.",
    "fell": "fell",
}


def _ci_header(table: pd.DataFrame) -> str:
    return f"{100 * table.attrs.get('confidence', CONFIDENCE):g}% CI"


def _ci_cell(row) -> str:
    seeds = row.get("seeds", np.nan)
    if not (isinstance(seeds, int | float | np.integer | np.floating) and seeds >= 2):
        return "-"
    return f"[{_format(row['ci_low'])}, {_format(row['ci_high'])}]"


def _ci_note(table: pd.DataFrame) -> str:
    column = table.attrs.get("column", "the metric")
    resamples = table.attrs.get("resamples", RESAMPLES)
    return (
        f"{_ci_header(table)}: percentile bootstrap ({resamples} resamples) of the mean over "
        f"seeds of {column}, each seed averaged over its targets; seed_std: sample std "
        "(ddof=1) of those seed means; -: fewer than two seeds (no spread can be estimated) "
        "or a baseline."
    )


def _table_columns(table: pd.DataFrame) -> list[str]:
    """The columns shown: no ``iteration``, ``ci_low``/``ci_high`` as one ``"ci"``."""
    columns = [c for c in table.columns if c not in ("iteration", "ci_high")]
    if "ci_high" not in table.columns:
        columns = [c for c in columns if c != "ci_low"]
    return ["ci" if c == "ci_low" else c for c in columns]


def _cell(row, column: str) -> str:
    return _ci_cell(row) if column == "ci" else _format(row[column])


def print_summary(
    table: pd.DataFrame,
    title: str = "Final tracking error",
    tracking: str = "joint-position tracking MSE (rad^2)",
    console=None,
) -> None:
    """Print a :func:`summary` table with rich, headers explained below; in parts if too wide.

    Args:
      table: the output of :func:`summary`.
      title: the table's title.
      tracking: what the metric is and its unit, for the caption.
      console: a ``rich.console.Console`` (None: the terminal's; 200 columns for a file).

    Examples:
      >>> import io, rich.console
      >>> narrow = rich.console.Console(width=40, file=io.StringIO())
      >>> m = pd.DataFrame(dict(loss=["supervised"], iteration=0, tracking_mse=3.8e-7))
      >>> print_summary(summary(m), console=narrow)
      >>> "3.80e-07" in narrow.file.getvalue()
      True
    """
    from rich.table import Table

    console = console or _console()
    column = table.attrs.get("column", "tracking_mse")
    short = "MSE" if column.endswith("mse") else column
    headers = {
        **SHORT_HEADERS,
        f"{column}_mean": f"{short} mean",
        f"{column}_std": f"{short} std",
        "ci": _ci_header(table),
    }
    caption = (
        f"{short}: {tracking}, mean/std over seeds x targets; seed std: sample std over "
        f"seeds of each seed's mean over its targets; {_ci_header(table)}: percentile "
        f"bootstrap ({table.attrs.get('resamples', RESAMPLES)} resamples) of the mean over "
        "seeds, each seed averaged over its targets (-: fewer than two seeds, or a "
        "baseline); pred. err / pred. task err: forward-model prediction error and "
        "predicted task error (squared units of the predicted quantities); RMSE/reach: "
        "sqrt(MSE mean) / RMS reaching distance; diverged / div. frac.: count and fraction "
        "of the runs whose simulation diverged (failed runs; every mean is over the others)"
        + ("; fell: runs in which the robot fell" if "fell" in table.columns else "")
    )
    names = [str(name) for name in table.index]
    columns = _table_columns(table)
    first = [f"{column}_mean", "ci", "seeds", "diverged"]
    columns = [c for c in first if c in columns] + [c for c in columns if c not in first]
    cells = {c: [_cell(row, c) for _, row in table.iterrows()] for c in columns}

    def width(values, header):  # a column's width: its longest cell, or its header
        return max([len(v) for v in values] + [len(header)]) + 3  # padding and border

    parts, part, used = [], [], width(names, "controller") + 1
    for c in columns:
        need = width(cells[c], headers.get(c, c))
        if part and used + need > console.width:
            parts.append(part)
            part, used = [], width(names, "controller") + 1
        part.append(c)
        used += need
    parts.append(part)
    for k, part in enumerate(parts):
        suffix = f" ({k + 1}/{len(parts)})" if len(parts) > 1 else ""
        out = Table(title=title + suffix)
        out.add_column("controller", no_wrap=True, min_width=max(map(len, names)))
        for c in part:
            out.add_column(
                headers.get(c, c),
                justify="right",
                no_wrap=True,
                min_width=max([len(v) for v in cells[c]] + [len(headers.get(c, c))]),
            )
        for i, name in enumerate(names):
            out.add_row(name, *(cells[c][i] for c in part))
        console.print(out)
    console.print(caption)  # below, at the console's width (a caption wraps narrow)


def print_paired(table: pd.DataFrame, title: str | None = None) -> None:
    """Print a :func:`paired_table` with rich, and below it what the numbers are.

    Args:
      table: the output of :func:`paired_table`.
      title: the table's title (None: the reference and the metric).

    Examples:
      >>> print_paired(paired_table(metrics))  # laid out to the terminal  # doctest: +SKIP
    """
    from rich.table import Table

    reference = table.attrs.get("reference", "reference")
    out = Table(title=title or f"Paired over seeds: {reference} minus each loss")
    out.add_column("loss")
    out.add_column(f"{reference} - loss", justify="right")
    out.add_column(_ci_header(table), justify="right", no_wrap=True)
    out.add_column("seeds", justify="right")
    for name, row in table.iterrows():
        cells = [_format(row["mean_difference"]), _ci_cell(row), str(int(row["seeds"]))]
        out.add_row(str(name), *cells)
    console = _console()
    console.print(out)
    console.print(_paired_note(table))  # below, at the console's width (a caption wraps narrow)


def _console():
    from rich.console import Console

    console = Console()
    if not console.is_terminal:  # files and pipes: do not squeeze the table into 80 columns
        console = Console(width=200)
    return console


def _format(value) -> str:
    if isinstance(value, float | np.floating):
        if np.isnan(value):
            return "-"
        return f"{value:.3g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.2e}"
    return str(value)


def markdown(table: pd.DataFrame) -> str:
    """The table as GitHub markdown (3 digits; a :func:`summary`'s interval as one column).

    Args:
      table: the output of :func:`summary` (any frame with an index of row names).

    Examples:
      >>> m = pd.DataFrame(dict(loss="task", seed=[0, 1], iteration=0, tracking_mse=[0.5, 1.5]))
      >>> print(markdown(summary(m)))  # doctest: +ELLIPSIS
      | controller | tracking_mse_mean | tracking_mse_std | runs | seeds | seed_std | 95% CI |
      ...| task | 1 | 0.5 | 2 | 2 | 0.707 | [0.5, 1.5] |
      ...
    """
    columns = _table_columns(table)
    headers = [_ci_header(table) if c == "ci" else c for c in columns]
    lines = ["| controller | " + " | ".join(headers) + " |", "|---|" + "---:|" * len(columns)]
    for name, row in table.iterrows():
        lines.append(f"| {name} | " + " | ".join(_cell(row, c) for c in columns) + " |")
    if "ci" in columns:
        lines += ["", _ci_note(table)]
    return "\n".join(lines)


def _paired_note(table: pd.DataFrame) -> str:
    reference = table.attrs.get("reference", "the reference")
    column = table.attrs.get("column", "the metric")
    return (
        f"{reference} - loss: mean over the seeds both have of the difference of their "
        f"{column} (each seed averaged over its targets; for an error, negative: {reference} "
        f"lower, better); {_ci_header(table)}: percentile bootstrap "
        f"({table.attrs.get('resamples', RESAMPLES)} resamples) of that mean; -: fewer than "
        "two paired seeds."
    )


def paired_markdown(table: pd.DataFrame) -> str:
    """A :func:`paired_table` as GitHub markdown, below a line that says what it is.

    Args:
      table: the output of :func:`paired_table`.

    Examples:
      >>> m = pd.DataFrame(dict(loss=["joint"] * 2 + ["task"] * 2, seed=[0, 1] * 2,
      ...                       iteration=1, tracking_mse=[1.0, 2.0, 3.0, 3.0]))
      >>> print(paired_markdown(paired_table(m)))  # doctest: +ELLIPSIS
      joint - loss: mean over the seeds both have of the difference of their tracking_mse ...
      | task | -1.5 | [-2, -1] | 2 |
    """
    reference = table.attrs.get("reference", "reference")
    lines = [
        _paired_note(table),
        "",
        f"| loss | {reference} - loss | {_ci_header(table)} | seeds |",
        "|---|---:|---:|---:|",
    ]
    for name, row in table.iterrows():
        cells = [str(name), _format(row["mean_difference"]), _ci_cell(row)]
        cells.append(str(int(row["seeds"])))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


CURVE_ID_COLUMNS = ("seed", "iteration", "target")
"""Columns of a metrics table that identify a row rather than measure something."""


def seed_curves(
    metrics: pd.DataFrame,
    by: Sequence[str] = ("loss",),
    columns: Sequence[str] | None = None,
    confidence: float | None = CONFIDENCE,
) -> pd.DataFrame:
    """Learning curves: per group and iteration, ``seeds`` and each column's ``_mean``, ``_std``
    (``ddof=0``), ``_ci_low``, ``_ci_high`` over the seed means (as :func:`seed_means`).

    Args:
      metrics: a metrics table with ``seed``, ``iteration``, ``by`` and the metrics.
      by: the columns that tell one curve from another (ValueError: not in ``metrics``).
      columns: the metrics (default: numeric ones but ids, ``by`` and training quantities).
      confidence: the level of the interval; None: no interval columns.

    Examples:
      >>> m = pd.DataFrame(dict(loss="joint", seed=[0, 0, 1, 1], iteration=0,
      ...                       tracking_mse=[1.0, 3.0, 5.0, 7.0]))  # seed means 2 and 6
      >>> seed_curves(m).iloc[0, 3:].tolist()  # mean, std, ci_low, ci_high
      [4.0, 2.0, 2.0, 6.0]
    """
    by = list(by)
    if columns is None:
        skip = set(CURVE_ID_COLUMNS) | set(by) | {
            "finite_fraction", "transitions_added", "forward_loss", "controller_loss"
        }  # fmt: skip
        numeric = pd.api.types.is_numeric_dtype
        columns = [c for c in metrics.columns if c not in skip and numeric(metrics[c])]
    columns = list(columns)
    _require(metrics, by + columns + ["seed", "iteration"])
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
        if confidence is not None:
            bounds = grouped[["seed", column]].apply(
                lambda g, c=column: bootstrap_ci(
                    g.sort_values("seed", kind="stable")[c].dropna(), confidence
                )
            )
            out[f"{column}_ci_low"] = [low for low, _ in bounds]
            out[f"{column}_ci_high"] = [high for _, high in bounds]
    out = out.reset_index()
    rank = {key: i for i, key in enumerate(dict.fromkeys(_group_keys(out, by)))}
    out["_rank"] = [rank[key] for key in _group_keys(out, by)]
    out = out.sort_values(["_rank", "iteration"], kind="stable").drop(columns="_rank")
    out = out.reset_index(drop=True)
    out.attrs["confidence"] = confidence
    return out


def _group_keys(frame: pd.DataFrame, by: Sequence[str]) -> list[tuple]:
    return [tuple(row) for row in frame[list(by)].astype(str).itertuples(index=False)]


def curves_markdown(
    curves: pd.DataFrame,
    by: Sequence[str] = ("loss",),
    iteration: int | None = None,
    columns: Sequence[str] | None = None,
) -> str:
    """A :func:`seed_curves` table at one iteration as GitHub markdown, ``mean ± std``.

    Args:
      curves: the output of :func:`seed_curves`.
      by: its group columns.
      iteration: the iteration to show; None: the last.
      columns: the metrics to show (default: all of ``curves``).

    Examples:
      >>> m = pd.DataFrame(dict(loss="joint", seed=[0, 1], iteration=3, tracking_mse=[1.0, 3.0]))
      >>> print(curves_markdown(seed_curves(m)))  # doctest: +ELLIPSIS
      iteration 3; mean ± std over seeds (each seed averaged over targets)
      ...| joint | 2 | 2 ± 1 |
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
