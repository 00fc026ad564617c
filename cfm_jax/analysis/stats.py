"""Statistics for comparing learning methods on few runs: the interquartile mean (IQM) with
stratified bootstrap confidence intervals, the probability of improvement and performance
profiles, as defined by rliable (Agarwal et al., "Deep Reinforcement Learning at the Edge of
the Statistical Precipice", NeurIPS 2021), as effect sizes (issue 43); and the decision
(issue 68): the exact sign-flip test of paired differences, with Holm's correction for many
comparisons and the intervals that invert the test at the level Holm tests each comparison
at. A decision has no random number in it; a bootstrap interval (its p-value floor is
``1 / reps``, below what few seeds can support) never decides.

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
    """``statistic`` (reducing the last two axes) of ``reps`` stratified, paired bootstrap
    resamples of the ``(runs, tasks)`` arrays (rliable's; ``scipy.stats.bootstrap`` draws the
    run indices per task). Returns ``(reps,)``, or ``(k, reps)`` for ``k`` values."""
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


MAX_EXACT_RUNS = 44
"""The most paired runs :func:`sign_flip_p` enumerates (2^44 sign assignments, as two halves
of 2^22 sums each)."""


def _signed_sums(values: np.ndarray) -> np.ndarray:
    """The sums of ``values`` under all 2^k assignments of signs, sorted."""
    sums = np.zeros(1)
    for v in values:
        sums = np.concatenate([sums + v, sums - v])
    return np.sort(sums)


def _paired_runs(name: str, differences) -> np.ndarray:
    array = np.asarray(differences, dtype=float)
    if array.ndim == 2:  # (runs, tasks): one value per run, its mean over the tasks
        array = array.mean(axis=1)
    if array.ndim != 1 or len(array) < 1 or not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: a finite array of paired differences, one per run (or "
                         f"(runs, tasks)), got shape {np.shape(differences)}")  # fmt: skip
    if len(array) > MAX_EXACT_RUNS:
        raise ValueError(f"{name}: {len(array)} runs; the exact test enumerates at most "
                         f"{MAX_EXACT_RUNS} (MAX_EXACT_RUNS)")  # fmt: skip
    return array


def sign_flip_p(differences) -> float:
    """The two-sided exact sign-flip (paired permutation) test of "no difference": under it
    each run's difference is as likely positive as negative, and ``p`` is the fraction of all
    2^n assignments of signs to the n differences whose sum is at least as far from 0 as the
    observed sum. Every assignment is counted (two halves of the runs, each half's 2^(n/2)
    signed sums sorted, pairs counted by binary search): no random number, no resampling.
    The smallest p at n runs is ``2 / 2^n``.

    Args:
      differences: paired differences, one per run (``(runs, tasks)``: each run's mean over
        its tasks).

    Returns:
      The p-value in ``(0, 1]``.

    Examples:
      >>> sign_flip_p([1.0, 2.0, 3.0])  # all positive: 2 of the 8 assignments (all +, all -)
      0.25
      >>> sign_flip_p([1.0, -1.0])
      1.0
    """
    d = _paired_runs("differences", differences)
    observed = abs(float(d.sum()))
    # The observed sum is one of the enumerated ones, summed in another order: a tolerance of
    # a few ulps of the largest possible sum keeps it (and its mirror) counted.
    tolerance = 1e-9 * float(np.abs(d).sum())
    if observed <= tolerance:
        return 1.0
    half = len(d) // 2
    low, high = _signed_sums(d[:half]), _signed_sums(d[half:])
    threshold = observed - tolerance
    # Pairs (x, y) with x + y >= threshold, and by symmetry as many with x + y <= -threshold.
    at_least = len(high) - np.searchsorted(high, threshold - low, side="left")
    return float(2 * at_least.sum() / (len(low) * len(high)))


def sign_flip_interval(differences, level: float) -> tuple[float, float]:
    """The shifts ``delta`` that the exact sign-flip test of ``differences - delta`` does not
    reject at ``level``: the ``1 - level`` interval of the mean difference that excludes 0
    where :func:`sign_flip_p` rejects. Ends by bisection to 1e-9 of the differences' spread;
    ``(-inf, inf)`` where n runs cannot reach ``level`` (``2 / 2^n > level``).

    Args:
      differences: paired differences, one per run.
      level: the test's level, in (0, 1).

    Examples:
      >>> sign_flip_interval([1.0, 2.0, 3.0], 0.05)
      (-inf, inf)
    """
    d = _paired_runs("differences", differences)
    if not 0 < level < 1:
        raise ValueError(f"level={level}: between 0 and 1")
    if 2.0 / 2.0 ** len(d) > level:
        return -np.inf, np.inf
    center = float(d.mean())
    reach = float(np.ptp(d)) + float(np.abs(d).max()) + 1.0  # beyond it every sign agrees
    step = 1e-9 * reach

    def end(direction: float) -> float:
        inside, outside = center, center + direction * reach
        while abs(outside - inside) > step:
            middle = 0.5 * (inside + outside)
            if sign_flip_p(d - middle) > level:
                inside = middle
            else:
                outside = middle
        # The test's p jumps where a shifted difference is exactly 0 (a shift of 0 or of one
        # of the differences): such a point at the end, not rejected, closes the interval.
        for point in sorted({0.0, *d.tolist()}, key=lambda x: -direction * x):
            if min(inside, outside) <= point <= max(inside, outside):
                if sign_flip_p(d - point) > level:
                    return point
        return inside

    return end(-1.0), end(1.0)


def paired_comparisons(
    differences: Mapping[str, np.ndarray], alpha: float = 0.05, statistic: str = "iqm",
    reps: int = 4000, seed: int = 0, confidence: float = 0.95,
) -> pd.DataFrame:  # fmt: skip
    """Many paired comparisons at once, decided by an exact test and corrected for their
    number (Holm).

    Each comparison is one paired difference per run (seed) of two methods. Its decision:
    the exact sign-flip test (:func:`sign_flip_p`), and Holm's procedure over all the
    comparisons given (the family) at family-wise error ``alpha``: ``clear`` when Holm
    rejects "no difference". No random number enters the decision. Effect sizes beside it:
    the mean difference with the interval that inverts the same test at the level Holm
    tests that comparison at (:func:`sign_flip_interval`; it excludes 0 where the test
    rejects at that level), and the ``statistic`` (IQM by default) of the differences with
    its ``confidence`` bootstrap interval (``reps`` resamples, ``seed``: these move with the
    seed, the decision does not).

    Args:
      differences: per comparison the paired differences, one per run (or ``(runs,
        tasks)``: each run's mean over its tasks for the test).
      alpha: the family-wise error rate.
      statistic: the bootstrap effect size's aggregate, one of :data:`STATISTICS`.
      reps: bootstrap resamples per comparison.
      seed: the bootstrap's seed (effect sizes only).
      confidence: the bootstrap interval's coverage.

    Returns:
      A frame, one row per comparison: ``comparison, runs, mean, low, high, level, p,
      adjusted, clear, reachable`` (whether 2 / 2^runs is at most ``level``: the test can
      reject at all) and ``effect, effect_low, effect_high`` (the bootstrap effect size).

    Examples:
      >>> frame = paired_comparisons({"a - b": [-1.0, -2.0, -1.5, -1.2, -0.8, -1.1]})
      >>> float(frame.p[0]), bool(frame.clear[0])
      (0.03125, True)
    """
    aggregate = _aggregate(statistic)
    rows = []
    for name, values in differences.items():
        d = _paired_runs(name, values)
        rows.append({"comparison": name, "runs": len(d), "mean": float(d.mean()),
                     "p": sign_flip_p(d), "d": d})  # fmt: skip
    corrected = holm([row["p"] for row in rows], alpha)
    out = []
    for row, (_, holm_row) in zip(rows, corrected.iterrows(), strict=True):
        d = row.pop("d")
        low, high = sign_flip_interval(d, holm_row.level)
        if len(d) >= 2:
            draws = _bootstrap([d[:, None]], aggregate, reps, seed)
            effect_low, effect_high = _percentiles(draws, confidence)
            effect = float(aggregate(d[:, None]))
        else:
            effect = effect_low = effect_high = float(d[0])
        out.append({**row, "low": low, "high": high, "level": holm_row.level,
                    "adjusted": holm_row.adjusted, "clear": bool(holm_row.reject),
                    "reachable": 2.0 / 2.0 ** len(d) <= holm_row.level, "effect": effect,
                    "effect_low": effect_low, "effect_high": effect_high})  # fmt: skip
    columns = ["comparison", "runs", "mean", "low", "high", "level", "p", "adjusted", "clear",
               "reachable", "effect", "effect_low", "effect_high"]  # fmt: skip
    return pd.DataFrame(out, columns=columns)
