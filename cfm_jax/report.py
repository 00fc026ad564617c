"""Summaries, tables and statistics of training results (pandas, rich); their figures are
in :mod:`cfm_jax.plots`.

Statistics: the unit of every uncertainty here is the *seed*, each seed averaged over its
targets (:func:`seed_means`): the targets of one seed share its networks and data, so they
are not independent runs. :func:`summary` gives each loss's mean with a percentile
bootstrap confidence interval over seeds (:func:`bootstrap_ci`), :func:`paired_table` the
paired difference between a reference loss and each other loss over the seeds both have
(:func:`paired_difference`), and the learning-curve figures (:mod:`cfm_jax.plots`) draw
the same interval as a band. The bootstrap uses a fixed seed, so the same metrics give the
same report.

Examples:
  >>> import pandas as pd
  >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [1, 1],
  ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
  >>> summary(metrics).loc["joint", "tracking_mse_mean"]
  np.float64(2.0)
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from cfm_jax import losses

CONFIDENCE = 0.95
"""Confidence level of the intervals of the tables and figures."""

RESAMPLES = 10_000
"""Bootstrap resamples of :func:`bootstrap_ci` and of every table and figure here."""

BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's random numbers (fixed: the same data give the same report)."""


def config_record(config) -> dict:
    """The config as a run records it in ``config.json`` (and in its checkpoints): the
    JSON form of :func:`cfm_jax.config.to_dict`, and for ``robot_actuators='torque'`` the
    conversion (``robot_conversion``: each servo's joint, kind, torque limit and the
    limit's source, :func:`cfm_jax.robots.conversion`). That part is derived from the robot
    file, for the reader; :func:`cfm_jax.config.from_dict` ignores it, and a resume whose
    file now converts differently is refused as a different config.

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Returns:
      A dict of JSON types.

    Examples:
      >>> from cfm_jax import config as config_lib
      >>> record = config_record(config_lib.Config(robot="two_link_arm"))
      >>> "robot_conversion" in record, config_lib.from_dict(record).robot
      (False, 'two_link_arm')
    """
    import json

    from cfm_jax import config as config_lib

    record = json.loads(json.dumps(config_lib.to_dict(config)))
    if getattr(config, "robot_actuators", "strict") != "strict":
        from cfm_jax import robots

        record["robot_conversion"] = robots.conversion(config.robot, config.robot_torque_limit)
    return record


def protocol(config) -> str:
    """One line that says how a run's initial data and ``s*`` were made and how the
    networks' inputs are scaled, for every summary table: ``loop.babbling``
    (:mod:`cfm_jax.babbling`), its rollouts and noise, the ``s*`` gains (or
    ``task.desired='next_velocity'``), ``loop.normaliser`` and ``forward.kind`` (with
    ``forward.nominal`` and ``forward.nominal_mass_scale`` where they are not the default),
    (the noise a fraction of the limits or of the torque scales, ``loop.torque_scale``, and
    for inverse dynamics the babbling's gains), and with ``robot_actuators='torque'`` the
    servos converted and each torque limit's
    source (:func:`cfm_jax.robots.conversion_note`).

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Returns:
      A line of text (markdown).

    Examples:
      >>> from cfm_jax import config
      >>> print(protocol(config.Config()))
      initial data: `loop.babbling='reaching'` (2 rollouts per target, torque noise 0.1 of the coupled torque scale, T n, `loop.babbling_gains='lightest'`); s* gains kp 100, kd 20; `loop.normaliser='babbling'`; `forward.kind='mlp'`
      >>> walk = config.for_task("walk")
      >>> print(protocol(walk).split("; ", 1)[1])
      s* the desired next velocity (`task.desired='next_velocity'`: kp 0, kd 1/control_dt = 250/s on base and joints); `loop.normaliser='data'`; `forward.kind='rigid_body'`
      >>> biased = walk.replace(forward=config.ForwardModelConfig(
      ...     kind="rigid_body", nominal_mass_scale=1.2))
      >>> print(protocol(biased).rsplit("; ", 1)[1])
      `forward.kind='rigid_body'` (`forward.nominal_mass_scale=1.2`)
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
    forward = config.forward
    model = f"`forward.kind={forward.kind!r}`"
    nominal = []
    if forward.nominal is not None:
        nominal.append(f"`forward.nominal={forward.nominal!r}`")
    if forward.nominal_mass_scale != 1.0:
        nominal.append(f"`forward.nominal_mass_scale={forward.nominal_mass_scale:g}`")
    if nominal:
        model += f" ({', '.join(nominal)})"
    if getattr(config, "robot_actuators", "strict") != "strict":
        from cfm_jax import robots

        model += "; " + robots.conversion_note(config.robot, config.robot_torque_limit)
    scale = getattr(loop, "torque_scale", "limit")
    noise_of = {"limit": "the limit", "coupled": "the coupled torque scale, T n"}.get(
        scale, "each joint's torque scale"
    )
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
    """Percentile bootstrap confidence interval of the mean of a 1-D sample.

    For ``x`` of length ``n``, ``B = resamples`` and ``c = confidence``: the index matrix
    ``I = rng.integers(0, n, size=(B, n))`` with ``rng = np.random.default_rng(seed)``
    gives the resample means ``m_b = (1/n) sum_j x[I[b, j]]`` (``b = 0 .. B-1``); the
    interval is their ``100 (1 - c)/2``-th and ``100 (1 + c)/2``-th percentiles
    (``np.percentile``, linear: with ``m`` sorted and ``h = (B - 1) p / 100``, the
    ``p``-th percentile is ``m[floor(h)] + (h - floor(h)) (m[floor(h) + 1] - m[floor(h)])``).

    The interval describes how much the mean moves when the sample is redrawn from
    itself; with few values it is too narrow for a ``c`` interval of the true mean (for
    normal data, a simulation gives a coverage of about 50% with 2 values, 75% with 3,
    85% with 5 and 90% with 10), so read a 3-seed interval as a lower bound on the
    uncertainty. The order of ``values`` matters only through the fixed random indices:
    callers here pass seed means ordered by seed.

    Args:
      values: the sample, shape ``(n,)`` (a list, array or Series). NaN values are not
        dropped: they make the interval NaN (callers here drop them first).
      confidence: the level ``c``, in (0, 1).
      resamples: the number ``B`` of resamples (memory: ``B x n`` integer indices; meant
        for small samples such as seeds).
      seed: seed of ``np.random.default_rng``.

    Returns:
      ``(low, high)`` as floats. ``n == 1``: ``(x[0], x[0])``: every resample is that
      value, so no spread can be estimated (the interval says nothing about the
      uncertainty). ``n == 0``: ``(nan, nan)``.

    Raises:
      ValueError: ``values`` is not 1-D, ``confidence`` is not in (0, 1) or
        ``resamples`` is not a positive integer.

    Examples:
      >>> bootstrap_ci([1.0, 2.0, 3.0, 4.0])
      (1.5, 3.5)
      >>> bootstrap_ci([2.0]), bootstrap_ci([])
      ((2.0, 2.0), (nan, nan))
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
    """Which rows of a metrics table are runs whose simulation diverged (``diverged == 1``;
    none when the table has no ``diverged`` column). See :func:`without_diverged`.

    Args:
      metrics: a metrics table.

    Returns:
      A bool Series on the table's index.

    Examples:
      >>> import pandas as pd
      >>> diverged_runs(pd.DataFrame({"diverged": [0.0, 1.0]})).tolist()
      [False, True]
    """
    if "diverged" not in metrics.columns:
        return pd.Series(False, index=metrics.index)
    return metrics["diverged"].fillna(0) == 1


def failed_runs(metrics: pd.DataFrame) -> pd.Series:
    """Which rows are failed runs for every ranking or selection rule: the simulation
    diverged (:func:`diverged_runs`) or, for the legged tasks, the robot fell (``fell``).

    Args:
      metrics: a metrics table.

    Returns:
      A bool Series on the table's index.

    Examples:
      >>> import pandas as pd
      >>> failed_runs(pd.DataFrame({"diverged": [0.0, 1.0, 0.0], "fell": [1.0, 0.0, 0.0]})).tolist()
      [True, True, False]
    """
    failed = diverged_runs(metrics)
    if "fell" in metrics.columns:
        failed = failed | (metrics["fell"].fillna(0) == 1)
    return failed


def without_diverged(metrics: pd.DataFrame, column: str) -> pd.Series:
    """The one rule for a metric of runs that may have diverged: ``column`` with the
    diverged runs (:func:`diverged_runs`) set to NaN, so every mean of this module is over
    the runs that did not diverge and the count and fraction of those that did are
    reported beside it (``diverged``, ``diverged_fraction`` of :func:`summary`). A
    diverged run is a failed run, as a fall is: its error over the steps before it
    diverged is not a small error (see docs/how-to/metrics.md).

    Args:
      metrics: a metrics table.
      column: the metric (``diverged`` and ``diverged_step`` themselves, and non-numeric
        columns, are returned as they are).

    Returns:
      The column as a Series, NaN at the diverged runs.

    Examples:
      >>> import pandas as pd
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
    """Each seed's ``column`` averaged over its targets at one iteration: the unit of the
    statistics of this module.

    ``m[g, s] = (1/K) sum_k x[g, s, k]`` for each group ``g`` (a loss), seed ``s`` and the
    ``K`` targets (rows) of that seed at the iteration; NaN values and the runs that
    diverged (:func:`without_diverged`) are skipped.

    Args:
      metrics: a metrics table (``TrainResult.metrics``, several concatenated, a sweep's
        table) with the ``by`` columns, ``iteration``, ``column`` and ``seed`` (a table
        without ``seed`` is one seed, seed 0).
      column: the metric to average.
      iteration: the iteration; None: each group's last iteration.
      by: the columns that tell one group from another.

    Returns:
      One row per group and seed, groups in order of first appearance, seeds ascending:
      the ``by`` columns, ``seed``, ``iteration``, ``column`` (the seed mean) and
      ``targets`` (the number of values averaged). Groups without ``iteration`` are left
      out.

    Raises:
      ValueError: a column named in ``by`` or ``column`` is not in ``metrics``.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 4, "seed": [1, 1, 0, 0],
      ...                         "iteration": [2] * 4, "target": [0, 1, 0, 1],
      ...                         "tracking_mse": [5.0, 7.0, 1.0, 3.0]})
      >>> seed_means(metrics)
          loss  seed  iteration  tracking_mse  targets
      0  joint     0          2           2.0        2
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
    """The mean of a sample and its bootstrap confidence interval (:func:`bootstrap_ci`).

    Args:
      values: the sample, shape ``(n,)``: e.g. one loss's seed means (a list, array or
        Series ordered by seed).
      confidence: the confidence level, in (0, 1).

    Returns:
      ``{"mean": ..., "low": ..., "high": ...}`` (floats; ``n == 0``: NaN), the keys
      of :func:`paired_difference` less ``n``, so :func:`ci_text` formats either.

    Examples:
      >>> mean_ci([1.0, 2.0, 3.0, 4.0])
      {'mean': 2.5, 'low': 1.5, 'high': 3.5}
    """
    x = np.asarray(values, dtype=float)
    low, high = bootstrap_ci(x, confidence)
    return {"mean": float(x.mean()) if x.size else float("nan"), "low": low, "high": high}


def ci_text(stats: dict) -> str:
    """``"mean [low, high]"`` of a :func:`mean_ci` or :func:`paired_difference` result,
    each number to 3 significant digits (the tables' format).

    Args:
      stats: a mapping with the keys ``"mean"``, ``"low"`` and ``"high"``.

    Returns:
      The text, for example ``"0.154 [0.0420, 0.270]"``.

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
    """Paired comparison over seeds: the mean of ``d_s = a_s - b_s`` and its bootstrap
    confidence interval (:func:`bootstrap_ci`).

    Only the seeds that both ``a`` and ``b`` have (with finite values) enter; ``d`` is
    ordered by seed before the bootstrap, so the result does not depend on the order of
    the inputs. Pairing removes what two losses share within a seed (its babbling data,
    the initial forward model), so the interval of the difference is usually narrower
    than the two losses' own intervals suggest.

    Args:
      a: values per seed: a ``pd.Series`` indexed by seed or a ``{seed: value}`` dict
        (e.g. a column of :func:`seed_means` indexed by ``seed``).
      b: the same for the other loss.
      confidence: the confidence level, in (0, 1).
      resamples: bootstrap resamples.
      seed: seed of the bootstrap's random numbers.

    Returns:
      ``{"mean": mean of d, "low": ..., "high": ..., "n": number of paired seeds}``
      (floats, ``n`` an int; ``n == 1``: ``low == high == mean``, no spread can be
      estimated; ``n == 0``: NaN).

    Raises:
      ValueError: a seed appears twice in ``a`` or in ``b``.

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
    """Final-iteration error per loss: mean and std over seeds and targets, and the mean's
    bootstrap confidence interval over seeds.

    For loss ``l`` with seeds ``s = 1..S`` and seed means ``m_s`` (:func:`seed_means`:
    each seed averaged over its targets): ``seeds = S``, ``seed_std = sqrt(sum_s (m_s -
    mean(m))^2 / (S - 1))`` (the sample std, ``ddof=1``; NaN for one seed) and
    ``[ci_low, ci_high]`` = :func:`bootstrap_ci` of ``m`` (ordered by seed): the
    percentile bootstrap interval of the mean over seeds. ``mean(m)`` equals
    ``<column>_mean`` when every seed has the same number of targets (always, for the
    library's runs).

    Args:
      metrics: a metrics table (``TrainResult.metrics``, or several concatenated), with
        columns ``loss``, ``iteration``, ``column``, ``seed`` (without it: one seed) and
        optionally ``prediction_error``, ``predicted_task_error``.
      baselines: ``TrainResult.baselines``; adds rows ``oracle`` and ``pd_only`` (mean and
        std over targets; no seed columns) when it has ``column``.
      rms_reach: the RMS reaching distance; adds the column ``rmse_over_reach`` (the square
        root of ``<column>_mean`` over this distance; meant for ``tracking_mse``).
      column: the metric, e.g. ``tracking_mse`` or the legged tasks' ``force_mse``.
      iteration: the iteration to summarise; None: each loss's last.
      confidence: the level of the interval.

    Returns:
      One row per loss (``losses.CONTROLLER_LOSSES`` order, then other names in order of
      appearance) and baseline. Columns: ``iteration``; ``<column>_mean`` and
      ``<column>_std`` (mean and population std, ``ddof=0``, over seeds x targets);
      ``runs`` (seeds x targets); ``seeds``, ``seed_std``, ``ci_low``, ``ci_high`` (over
      the seed means, as above; NaN for the baselines); ``diverged`` and
      ``diverged_fraction`` (the runs whose simulation diverged, when ``metrics`` has a
      ``diverged`` column: every mean is over the others, :func:`without_diverged`);
      ``fell`` (the runs in which the robot fell, when ``metrics`` has a ``fell``
      column: the legged tasks); ``prediction_error_mean``,
      ``predicted_task_error_mean`` (when in ``metrics``); ``rmse_over_reach``. The
      frame's ``attrs`` hold ``column``, ``confidence`` and ``resamples``.

    Raises:
      ValueError: ``loss``, ``iteration`` or ``column`` is not in ``metrics``.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [1, 1],
      ...                         "target": [0, 0], "tracking_mse": [1.0, 3.0]})
      >>> summary(metrics).loc["joint", "tracking_mse_mean"]
      np.float64(2.0)
      >>> summary(metrics).loc["joint", ["seeds", "seed_std", "ci_low", "ci_high"]].round(3)
      seeds       2.000
      seed_std    1.414
      ci_low      1.000
      ci_high     3.000
      Name: joint, dtype: float64
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
    """Paired comparison of a reference loss with every other loss, over seeds.

    For each other loss ``l``: ``d_s = m_s(reference) - m_s(l)`` over the seeds both
    have, ``m`` the seed means of ``column`` (:func:`seed_means`, each seed averaged over
    its targets), then :func:`paired_difference`. For an error metric (``tracking_mse``,
    ``force_mse``) a negative difference means the reference is better (lower); a ``c``
    interval that excludes 0 means the sign holds in at least ``(1 + c)/2`` of the
    bootstrap resamples of the seeds.

    Args:
      metrics: a metrics table with ``loss``, ``seed``, ``iteration`` and ``column``.
      reference: the loss every other one is compared with; None: ``joint`` when present,
        else the first loss in ``losses.CONTROLLER_LOSSES`` order.
      column: the metric.
      iteration: the iteration; None: each loss's last.
      confidence: the level of the interval.

    Returns:
      One row per other loss (index ``loss``, library order), columns
      ``mean_difference`` (reference minus loss), ``ci_low``, ``ci_high`` and ``seeds``
      (the number of paired seeds); ``attrs`` hold ``reference``, ``column``,
      ``confidence`` and ``resamples``. No other loss: no rows.

    Raises:
      ValueError: ``reference`` is not in ``metrics`` or a needed column is missing.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2 + ["task"] * 2, "seed": [0, 1] * 2,
      ...                         "iteration": [1] * 4, "tracking_mse": [1.0, 2.0, 3.0, 3.0]})
      >>> paired_table(metrics).reset_index()  # joint - task: -2 (seed 0), -1 (seed 1)
         loss  mean_difference  ci_low  ci_high  seeds
      0  task             -1.5    -2.0     -1.0      2
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
    """The order in which tables and figures show losses: the library's losses in
    ``CONTROLLER_LOSSES`` order, then other names (baselines, ...) as they come.

    Args:
      names: loss names, repeats allowed (a metrics table's ``loss`` column).

    Returns:
      The distinct names in that order.

    Examples:
      >>> loss_order(["mine", "task", "joint", "task"])
      ['joint', 'task', 'mine']
    """
    present = list(dict.fromkeys(names))
    known = [name for name in losses.CONTROLLER_LOSSES if name in present]
    return known + [name for name in present if name not in losses.CONTROLLER_LOSSES]


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
    """``[low, high]``; ``-`` with fewer than two seeds (no spread) or no seeds at all."""
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
    """The columns to show: ``iteration`` left out, ``ci_low``/``ci_high`` as one column
    (named ``"ci"``) in the place of ``ci_low``."""
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
    """Print a :func:`summary` table with rich (short column headers, explained below it):
    ``ci_low`` and ``ci_high`` as one column ``95% CI`` (``[low, high]``), the caption says
    what the interval is (percentile bootstrap of the mean over seeds, each seed averaged
    over its targets). No number or name is ever cut: a table wider than the console is
    printed in parts, each with the controller column, the most read columns (MSE mean,
    95% CI, seeds, diverged) first.

    Args:
      table: the output of :func:`summary`.
      title: the table's title.
      tracking: what the table's metric (``summary(column=...)``) is and its unit, for
        the caption.
      console: a ``rich.console.Console`` (None: the terminal's, or 200 columns for a file
        or a pipe).

    Examples:
      >>> import io
      >>> import pandas as pd
      >>> from rich.console import Console
      >>> metrics = pd.DataFrame({"loss": ["supervised"], "iteration": [0],
      ...                         "tracking_mse": [3.8e-7]})
      >>> narrow = Console(width=40, file=io.StringIO())
      >>> print_summary(summary(metrics), console=narrow)
      >>> text = narrow.file.getvalue()
      >>> "supervised" in text and "3.80e-07" in text
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
      title: the table's title (None: says the reference and the metric).

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint", "task"], "seed": [0, 0],
      ...                         "iteration": [0, 0], "tracking_mse": [0.5, 1.0]})
      >>> # not run: rich lays the table out to the terminal's width
      >>> print_paired(paired_table(metrics))  # doctest: +SKIP
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
    """The table as GitHub markdown (numbers to 3 significant digits).

    A :func:`summary` table's ``ci_low`` and ``ci_high`` become one column ``95% CI``
    (``[low, high]``; ``-`` with fewer than two seeds and for the baselines), and a line
    below the table says what the interval is.

    Args:
      table: the output of :func:`summary` (any frame with an index of row names).

    Returns:
      Markdown text, one line per row, the ``iteration`` column left out.

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["task"] * 2, "seed": [0, 1], "iteration": [0, 0],
      ...                         "tracking_mse": [0.5, 1.5]})
      >>> print(markdown(summary(metrics)))  # doctest: +ELLIPSIS
      | controller | tracking_mse_mean | tracking_mse_std | runs | seeds | seed_std | 95% CI |
      |---|---:|---:|---:|---:|---:|---:|
      | task | 1 | 0.5 | 2 | 2 | 0.707 | [0.5, 1.5] |
      <BLANKLINE>
      95% CI: percentile bootstrap (10000 resamples) of the mean over seeds of tracking_mse, ...
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
    """A :func:`paired_table` as GitHub markdown, with a line that says what it is.

    Args:
      table: the output of :func:`paired_table`.

    Returns:
      Markdown text: the explanation, a blank line, then one table row per loss
      (``loss``, ``<reference> - loss``, ``95% CI``, ``seeds``).

    Examples:
      >>> import pandas as pd
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2 + ["task"] * 2, "seed": [0, 1] * 2,
      ...                         "iteration": [1] * 4, "tracking_mse": [1.0, 2.0, 3.0, 3.0]})
      >>> print(paired_markdown(paired_table(metrics)))  # doctest: +ELLIPSIS
      joint - loss: mean over the seeds both have of the difference of their tracking_mse ...
      <BLANKLINE>
      | loss | joint - loss | 95% CI | seeds |
      |---|---:|---:|---:|
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
    """Mean, standard deviation and bootstrap confidence interval over seeds, per
    iteration, for each group ``by`` (each loss, or each loss and override combination of
    a sweep): the paper's learning curves.

    Each seed's value at an iteration is first averaged over the targets (``m_s``, as in
    :func:`seed_means`); the mean and the population standard deviation (``ddof=0``) are
    then taken over the seeds, and the interval is :func:`bootstrap_ci` of the ``m_s``
    (ordered by seed; NaN seed means left out).

    Args:
      metrics: a metrics table with ``seed``, ``iteration``, ``target``, the ``by`` columns
        and the metrics (``TrainResult.metrics``, a sweep's table).
      by: the columns that tell one curve from another.
      columns: the metrics to summarise (default: every numeric column that is not an id,
        a group column, ``finite_fraction``, ``transitions_added`` or a training loss).
      confidence: the level of the interval; None: no interval columns.

    Returns:
      One row per group and iteration, groups in order of first appearance, iterations
      ascending: the ``by`` columns, ``iteration``, ``seeds`` and ``<column>_mean``,
      ``<column>_std``, ``<column>_ci_low``, ``<column>_ci_high`` for each column;
      ``attrs["confidence"]`` the level.

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
      >>> curves[["tracking_mse_ci_low", "tracking_mse_ci_high"]]
         tracking_mse_ci_low  tracking_mse_ci_high
      0                  2.0                   6.0
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
