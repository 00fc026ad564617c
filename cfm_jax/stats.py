"""Statistics for comparing learning methods on few runs (issue 43): the interquartile mean
(IQM) with stratified bootstrap confidence intervals, the probability of improvement and
performance profiles, as defined by rliable (Agarwal et al., "Deep Reinforcement Learning at
the Edge of the Statistical Precipice", NeurIPS 2021), and Holm's correction for many
comparisons, with intervals at the level Holm tests each comparison at.

Scores are arrays of shape ``(runs, tasks)`` (a run: one seed; a task: one robot and task,
or one cell of a study), higher is better: :func:`score` turns a tracking MSE into orders of
magnitude below the PD-only baseline.

Libraries: SciPy (the trimmed mean, ``scipy.stats.bootstrap`` for the
resampling) and statsmodels (Holm; the ``stats`` extra, ``pip install "cfm_jax[stats]"``).
Not the ``rliable`` package itself: it pins ``arch < 8``, whose 7.x releases fail on import
with pandas 3 (``TypeError: deprecate_kwarg()``); its definitions are followed here and the
tests check them against plain loops.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from scipy import stats as scipy_stats

STATISTICS = ("iqm", "mean", "median")
"""The aggregate statistics :func:`interval_estimates` and :func:`paired_comparisons` know."""


def score(mse, pd_only) -> np.ndarray:
    """Orders of magnitude below PD-only, ``log10(pd_only / mse)``: 0 at PD-only, 1 ten times
    below it, negative above it (higher is better, as rliable's scores).

    Args:
      mse: tracking MSEs (any shape), positive.
      pd_only: the PD-only baseline's MSE (a number, or broadcastable to ``mse``).

    Examples:
      >>> float(score(1e-5, 1e-3))
      2.0
    """
    mse, pd_only = np.asarray(mse, dtype=float), np.asarray(pd_only, dtype=float)
    if np.any(~(mse > 0)) or np.any(~(pd_only > 0)):
        raise ValueError(
            "score: every mse and pd_only must be positive (a failed run is not a score)"
        )
    return np.log10(pd_only / mse)


def _matrix(name: str, scores) -> np.ndarray:
    array = np.asarray(scores, dtype=float)
    if array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or array.shape[0] < 2 or not np.all(np.isfinite(array)):
        raise ValueError(
            f"scores[{name!r}]: a finite array of shape (runs, tasks) with at least 2 runs, "
            f"got shape {np.shape(scores)}"
        )
    return array


def _flat(array: np.ndarray) -> np.ndarray:
    """``(..., runs, tasks)`` -> ``(..., runs x tasks)``: all of a sample's scores together."""
    return array.reshape(*array.shape[:-2], -1)


# The aggregates reduce the last two axes (runs, tasks) of an array that may carry leading
# batch axes: one bootstrap resample each, all computed at once.
_AGGREGATES = {"iqm": lambda a: scipy_stats.trim_mean(_flat(a), 0.25, axis=-1),
               "mean": lambda a: np.mean(_flat(a), axis=-1),
               "median": lambda a: np.median(_flat(a), axis=-1)}  # fmt: skip


def _aggregate(statistic: str):
    if statistic not in _AGGREGATES:
        raise ValueError(f"statistic={statistic!r} is not allowed: one of {STATISTICS}")
    return _AGGREGATES[statistic]


def iqm(scores) -> float:
    """The interquartile mean: the mean of the middle 50% of all runs' scores (over runs and
    tasks together; scipy's 25% trimmed mean).

    Args:
      scores: an array ``(runs, tasks)`` or ``(runs,)``.

    Examples:
      >>> iqm([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 100.0])
      4.5
    """
    return float(_aggregate("iqm")(_matrix("scores", scores)))


def _bootstrap(arrays, statistic, reps: int, seed: int) -> np.ndarray:
    """``statistic`` of ``reps`` stratified bootstrap resamples of the same-shaped ``(runs,
    tasks)`` arrays: each task's runs resampled on their own (rliable's stratified
    bootstrap), the arrays' runs together (paired). ``scipy.stats.bootstrap`` draws the run
    indices, one sample per task. ``statistic`` reduces the last two axes of arrays with
    leading batch axes (all resamples at once). Returns ``(reps,)``, or ``(k, reps)`` for a
    statistic of ``k`` values."""
    runs, tasks = arrays[0].shape

    def resampled(*indices, axis=-1):
        # indices: per task (..., runs) run indices; each array -> (..., runs, tasks).
        return statistic(*[np.stack([a[i, t] for t, i in enumerate(indices)], axis=-1)
                           for a in arrays])  # fmt: skip

    result = scipy_stats.bootstrap(
        (np.arange(runs),) * tasks, resampled, n_resamples=reps, vectorized=True,
        method="percentile", rng=np.random.default_rng(seed),
    )  # fmt: skip
    return np.asarray(result.bootstrap_distribution)


def interval_estimates(
    scores: Mapping[str, np.ndarray], statistic: str = "iqm", confidence: float = 0.95,
    reps: int = 2000, seed: int = 0,
) -> pd.DataFrame:  # fmt: skip
    """Each method's aggregate score with its stratified bootstrap percentile interval.

    Args:
      scores: per method an array ``(runs, tasks)`` (or ``(runs,)``: one task).
      statistic: ``"iqm"`` (the default, robust to a few outlying runs), ``"mean"`` or
        ``"median"``.
      confidence: the interval's coverage.
      reps: bootstrap resamples.
      seed: the resampling's seed (the same seed, the same intervals).

    Returns:
      A frame with one row per method: ``method, statistic, point, low, high, runs``.

    Examples:
      >>> frame = interval_estimates({"a": [[1.0], [2.0], [3.0]]}, statistic="mean")
      >>> float(frame.point[0])
      2.0
    """
    aggregate = _aggregate(statistic)
    rows = []
    for method, values in scores.items():
        array = _matrix(method, values)
        draws = _bootstrap([array], aggregate, reps, seed)
        low, high = _percentiles(draws, confidence)
        rows.append({"method": method, "statistic": statistic, "point": float(aggregate(array)),
                     "low": low, "high": high, "runs": array.shape[0]})  # fmt: skip
    return pd.DataFrame(rows)


def _percentiles(draws: np.ndarray, confidence: float, axis=None):
    """The percentile interval of ``confidence`` over ``draws`` (``axis``: the resamples'
    axis of a statistic of several values; None: one value, as floats)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence={confidence}: between 0 and 1")
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(draws, [tail, 100 - tail], axis=axis)
    return (float(low), float(high)) if axis is None else (low, high)


def probability_of_improvement(x, y, confidence: float = 0.95, reps: int = 2000,
                               seed: int = 0) -> tuple[float, float, float]:  # fmt: skip
    """P(X > Y): the probability that a run of method X scores above a run of method Y on
    the same task (ties count half; the Mann-Whitney U over runs / (runs_x runs_y), averaged
    over tasks), with its stratified bootstrap percentile interval.

    Args:
      x: an array ``(runs, tasks)`` of method X.
      y: method Y's, on the same runs (seeds) and tasks (the bootstrap resamples the runs of
        both together).
      confidence: the interval's coverage.
      reps: bootstrap resamples.
      seed: the resampling's seed.

    Returns:
      ``(point, low, high)``.

    Examples:
      >>> probability_of_improvement([[2.0], [3.0]], [[0.0], [1.0]])[0]
      1.0
    """
    x, y = _matrix("x", x), _matrix("y", y)
    if x.shape != y.shape:
        raise ValueError(f"x and y: the same runs and tasks, got shapes {x.shape} and {y.shape}")
    point = float(_improvement(x, y))
    draws = _bootstrap([x, y], _improvement, reps, seed)
    return (point, *_percentiles(draws, confidence))


def _improvement(x, y) -> float:
    """P(X > Y) per task (Mann-Whitney U / (runs_x runs_y), ties half), mean over tasks: the
    U statistic counted over all pairs of runs at once (scipy's ``mannwhitneyu`` per task
    and resample was 9 ms, most of a claims page's time)."""
    greater = x[..., :, None, :] > y[..., None, :, :]  # (..., runs x, runs y, tasks)
    ties = x[..., :, None, :] == y[..., None, :, :]
    per_task = greater.mean(axis=(-3, -2)) + 0.5 * ties.mean(axis=(-3, -2))
    return per_task.mean(axis=-1)


def performance_profile(scores: Mapping[str, np.ndarray], thresholds, confidence: float = 0.95,
                        reps: int = 2000, seed: int = 0) -> pd.DataFrame:  # fmt: skip
    """The score distribution of each method: the fraction of runs (over all tasks) whose
    score exceeds each threshold, with its stratified bootstrap interval (rliable).

    Args:
      scores: per method an array ``(runs, tasks)``.
      thresholds: the scores ``tau`` at which to evaluate the profile.
      confidence: the intervals' coverage.
      reps: bootstrap resamples.
      seed: the resampling's seed.

    Returns:
      A frame ``method, threshold, fraction, low, high``.

    Examples:
      >>> frame = performance_profile({"a": [[0.0], [2.0]]}, thresholds=[1.0])
      >>> float(frame.fraction[0])
      0.5
    """
    thresholds = np.asarray(thresholds, dtype=float)

    def profile(array):  # (..., runs, tasks) -> (thresholds, ...)
        return np.stack([np.mean(_flat(array) > tau, axis=-1) for tau in thresholds])

    rows = []
    for method, values in scores.items():
        array = _matrix(method, values)
        draws = _bootstrap([array], profile, reps, seed).reshape(len(thresholds), reps)
        low, high = _percentiles(draws, confidence, axis=1)
        for k, (tau, fraction) in enumerate(zip(thresholds, profile(array), strict=True)):
            rows.append({"method": method, "threshold": float(tau), "fraction": float(fraction),
                         "low": float(low[k]), "high": float(high[k])})  # fmt: skip
    return pd.DataFrame(rows)


def holm(p_values, alpha: float = 0.05) -> pd.DataFrame:
    """Holm's step-down correction of many tests (statsmodels): with the p-values sorted,
    test ``i`` (1-based) is rejected when it and every smaller one are below
    ``alpha / (m - i + 1)``; the family-wise error rate is at most ``alpha``.

    Args:
      p_values: one p-value per comparison.
      alpha: the family-wise error rate.

    Returns:
      A frame in the input order: ``p, adjusted`` (Holm's adjusted p-value), ``reject`` and
      ``level``, the significance level the comparison is tested at (``alpha / (m - rank +
      1)``).

    Examples:
      >>> holm([0.01, 0.04, 0.03, 0.005]).reject.tolist()
      [True, False, False, True]
    """
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(p_values, dtype=float)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)):
        raise ValueError(f"p_values: a list of numbers in [0, 1], got {p_values!r}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha}: between 0 and 1")
    reject, adjusted, _, _ = multipletests(p, alpha=alpha, method="holm")
    rank = np.empty(len(p), dtype=int)
    rank[np.argsort(p, kind="stable")] = np.arange(1, len(p) + 1)
    level = alpha / (len(p) - rank + 1)
    return pd.DataFrame({"p": p, "adjusted": adjusted, "reject": reject, "level": level})


def paired_comparisons(
    differences: Mapping[str, np.ndarray], statistic: str = "mean", alpha: float = 0.05,
    reps: int = 10000, seed: int = 0,
) -> pd.DataFrame:  # fmt: skip
    """Many paired comparisons at once, corrected for their number (Holm).

    Each comparison is the per-run difference of two methods' scores on the same runs
    (seeds) and tasks. Its bootstrap distribution (stratified, ``reps`` resamples) gives a
    two-sided p-value for "no difference" (twice the smaller tail beyond 0) and percentile
    intervals; Holm's procedure over all comparisons decides which differences are clear,
    and each comparison's interval is at Holm's level for it (``1 - level``): a clear
    difference's interval excludes 0.

    Args:
      differences: per comparison an array ``(runs, tasks)`` of paired differences.
      statistic: the aggregate of the differences, one of :data:`STATISTICS`.
      alpha: the family-wise error rate.
      reps: bootstrap resamples per comparison.
      seed: the resampling's seed.

    Returns:
      A frame, one row per comparison: ``comparison, point, low, high, confidence, p,
      adjusted, clear``.

    Examples:
      >>> frame = paired_comparisons({"a - b": [-1.0, -2.0, -1.5, -1.2]})
      >>> bool(frame.clear[0])
      True
    """
    aggregate = _aggregate(statistic)
    rows = []
    for name, values in differences.items():
        array = _matrix(name, values)
        draws = _bootstrap([array], aggregate, reps, seed)
        # Two-sided, (1 + count) / (1 + reps): never 0 from a finite number of resamples.
        tail = min(np.sum(draws <= 0), np.sum(draws >= 0))
        p = min(1.0, 2 * (1 + tail) / (1 + reps))
        rows.append({"comparison": name, "point": float(aggregate(array)), "p": p, "draws": draws})
    corrected = holm([row["p"] for row in rows], alpha)
    out = []
    for row, (_, holm_row) in zip(rows, corrected.iterrows(), strict=True):
        low, high = _percentiles(row.pop("draws"), 1 - holm_row.level)
        out.append({**row, "low": low, "high": high, "confidence": 1 - holm_row.level,
                    "adjusted": holm_row.adjusted, "clear": bool(holm_row.reject)})  # fmt: skip
    columns = ["comparison", "point", "low", "high", "confidence", "p", "adjusted", "clear"]
    return pd.DataFrame(out, columns=columns)
