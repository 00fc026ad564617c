"""cfm_jax.analysis.stats (issues 43 and 68): the few-run statistics against hand computations,
closed forms and plain loops written here (the exact test against every assignment of signs
enumerated with itertools)."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from scipy.stats import mannwhitneyu

from cfm_jax.analysis import stats


def test_score_is_orders_of_magnitude_below_pd_only():
    np.testing.assert_allclose(stats.score([1e-3, 1e-5, 1e-2], 1e-3), [0.0, 2.0, -1.0])
    with pytest.raises(ValueError, match="positive"):
        stats.score([1e-3, np.nan], 1e-3)


def test_iqm_is_the_mean_of_the_middle_half_over_runs_and_tasks():
    # 8 values: the lowest 2 and highest 2 cut, mean of 3, 4, 5, 6 (by hand).
    assert stats.iqm([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 100.0]) == 4.5
    # (runs, tasks): pooled over both.
    assert stats.iqm(np.array([[1.0, 5.0], [2.0, 6.0], [3.0, 7.0], [4.0, 100.0]])) == 4.5


def test_interval_of_the_mean_matches_the_normal_closed_form_on_many_runs():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 2.0, size=400)
    frame = stats.interval_estimates({"a": x}, statistic="mean", reps=4000, seed=1)
    row = frame.iloc[0]
    assert row.point == pytest.approx(x.mean(), rel=1e-12)
    half = 1.96 * x.std(ddof=1) / np.sqrt(len(x))  # CLT: mean +- 1.96 sigma / sqrt(n)
    assert row.low == pytest.approx(x.mean() - half, abs=0.1 * half)
    assert row.high == pytest.approx(x.mean() + half, abs=0.1 * half)
    again = stats.interval_estimates({"a": x}, statistic="mean", reps=4000, seed=1)
    assert again.equals(frame)  # the same seed, the same interval
    constant = stats.interval_estimates({"c": np.full((5, 2), 1.5)})
    assert constant.point[0] == constant.low[0] == constant.high[0] == 1.5


def test_the_bootstrap_resamples_each_tasks_runs_on_their_own():
    # Two tasks whose runs cancel row by row: resampling whole rows would keep every mean at
    # 0; resampling each task's runs on its own (stratified) spreads it as the average of two
    # independent means does: sd = sd(v) / sqrt(2 n).
    v = np.linspace(-1.0, 1.0, 200)
    frame = stats.interval_estimates({"a": np.stack([v, -v], axis=1)}, "mean", reps=4000)
    half = 1.96 * v.std() / np.sqrt(2 * len(v))
    assert frame.low[0] == pytest.approx(-half, rel=0.1)
    assert frame.high[0] == pytest.approx(half, rel=0.1)


def test_probability_of_improvement_counts_pairs_with_ties_half():
    x = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 5.0]])
    y = np.array([[2.0, 0.0], [0.0, 1.0], [1.0, 1.0]])

    def plain(x, y):  # every pair of runs, task by task, then the mean over tasks
        per_task = []
        for t in range(x.shape[1]):
            wins = sum((a > b) + 0.5 * (a == b) for a in x[:, t] for b in y[:, t])
            per_task.append(wins / (len(x) * len(y)))
        return np.mean(per_task)

    point, low, high = stats.probability_of_improvement(x, y, reps=500)
    assert point == pytest.approx(plain(x, y), abs=1e-12)
    u = [mannwhitneyu(x[:, t], y[:, t]).statistic / 9 for t in range(2)]  # SciPy's U
    assert point == pytest.approx(np.mean(u), abs=1e-12)
    assert 0.0 <= low <= point <= high <= 1.0
    assert stats.probability_of_improvement([[2.0], [3.0]], [[0.0], [1.0]])[0] == 1.0


def test_performance_profile_is_the_fraction_of_runs_above_each_threshold():
    a = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    frame = stats.performance_profile({"a": a}, thresholds=[-1.0, 0.5, 2.5, 9.0], reps=300)
    np.testing.assert_allclose(frame.fraction, [6 / 6, 5 / 6, 3 / 6, 0 / 6])
    assert (frame.low <= frame.fraction).all() and (frame.fraction <= frame.high).all()


def test_holm_on_a_hand_worked_example():
    # Sorted: 0.005 <= 0.05/4 rejected, 0.01 <= 0.05/3 rejected, 0.03 > 0.05/2: stop.
    # Adjusted (running max of (m - i + 1) p): 0.02, 0.03, 0.06, max(0.06, 0.04) = 0.06.
    frame = stats.holm([0.01, 0.04, 0.03, 0.005], alpha=0.05)
    assert frame.reject.tolist() == [True, False, False, True]
    np.testing.assert_allclose(frame.adjusted, [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(frame.level, [0.05 / 3, 0.05, 0.05 / 2, 0.05 / 4])


def _plain_sign_flip(d) -> float:
    """Every assignment of signs, one by one (itertools): the fraction whose |sum| reaches
    the observed |sum| (a relative tolerance of 1e-9 for the sums' rounding)."""
    observed = abs(sum(d))
    tolerance = 1e-9 * sum(abs(v) for v in d)
    hits = sum(abs(sum(s * v for s, v in zip(signs, d, strict=True))) >= observed - tolerance
               for signs in itertools.product((1, -1), repeat=len(d)))  # fmt: skip
    return hits / 2 ** len(d)


def test_sign_flip_p_counts_every_assignment_of_signs_as_a_plain_loop_does():
    rng = np.random.default_rng(5)
    for n in (1, 2, 5, 8, 11):
        for _ in range(3):
            d = rng.normal(rng.normal(), 1.0, size=n)
            d[rng.random(n) < 0.2] = 0.0  # exact zeros: they flip to themselves
            assert stats.sign_flip_p(d) == pytest.approx(_plain_sign_flip(d), abs=1e-15)
    # All of one sign: only the two assignments that keep every sign together reach it.
    for n in (4, 10, 20):
        assert stats.sign_flip_p(np.linspace(0.1, 1.0, n)) == 2 / 2**n
    assert stats.sign_flip_p(np.zeros(6)) == 1.0
    assert stats.sign_flip_p([[1.0, 3.0], [2.0, 2.0]]) == stats.sign_flip_p([2.0, 2.0])


def test_sign_flip_interval_inverts_the_test_and_is_unbounded_where_it_cannot_reject():
    rng = np.random.default_rng(6)
    for level in (0.05, 0.01, 0.002):
        d = rng.normal(0.4, 1.0, size=12)
        low, high = stats.sign_flip_interval(d, level)
        assert low < d.mean() < high
        step = 1e-6 * (high - low)
        # Just inside each end the shifted differences are not rejected, just outside they are.
        assert stats.sign_flip_p(d - (low + step)) > level >= stats.sign_flip_p(d - (low - step))
        assert stats.sign_flip_p(d - (high - step)) > level >= stats.sign_flip_p(d - (high + step))
        # 0 outside the interval exactly when the test rejects at that level.
        assert (stats.sign_flip_p(d) <= level) == (not low <= 0 <= high)
    # 10 seeds: 2 / 2^10 = 2.0e-3 > 1e-3, no shift can be rejected at 1e-3.
    assert stats.sign_flip_interval(np.ones(10), 1e-3) == (-np.inf, np.inf)
    # One seed of ten moved off 0: p = 1 at a shift of 0 (the interval's closed end), every
    # positive shift makes all ten negative (p = 2 / 2^10 <= 0.01): the interval ends at 0.
    low, high = stats.sign_flip_interval([0.0] * 9 + [-0.2], 0.01)
    assert high == 0.0 and low < -0.02


def test_paired_comparisons_decide_by_the_exact_test_and_holm_with_no_random_number():
    rng = np.random.default_rng(3)
    clear = -1.0 + 0.1 * rng.normal(size=10)  # every seed below 0
    unclear = np.array([1.0, -1.0] * 5) + 0.01 * rng.normal(size=10)  # centred on 0
    moderate = np.array([-0.5, -0.4, -0.3, -0.2, 0.1, 0.05, -0.6, -0.35, -0.25, 0.1])
    frame = stats.paired_comparisons({"a - b": clear, "a - c": unclear, "a - d": moderate})
    p = [_plain_sign_flip(d) for d in (clear, unclear, moderate)]
    np.testing.assert_allclose(frame.p, p, rtol=1e-12)
    assert frame.p[0] == 2 / 2**10  # the smallest p 10 seeds can give
    # Holm by hand: sorted p's against 0.05/3, 0.05/2, 0.05/1, stopping at the first miss.
    order = np.argsort(p)
    reject, going = [False] * 3, True
    for rank, k in enumerate(order):
        going = going and p[k] <= 0.05 / (3 - rank)
        reject[k] = going
    assert frame.clear.tolist() == reject == [True, False, True]
    assert frame["mean"][0] == pytest.approx(clear.mean())
    assert frame.high[0] < 0 and frame.low[1] < 0 < frame.high[1]
    assert frame.reachable.all()
    # The bootstrap's seed moves the effect size's interval, never the decision.
    other = stats.paired_comparisons({"a - b": clear, "a - c": unclear, "a - d": moderate},
                                     seed=7)  # fmt: skip
    decision = ["p", "level", "clear", "low", "high", "mean"]
    pd.testing.assert_frame_equal(other[decision], frame[decision])
    assert not np.allclose(other.effect_low, frame.effect_low)
    # 54 comparisons of 10 seeds: Holm's first level 0.05 / 54 is below 2 / 2^10: unreachable.
    many = stats.paired_comparisons({f"c{k}": clear for k in range(54)})
    assert not many.clear.any() and not many.reachable[many.level.idxmin()]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: stats.iqm([1.0, np.nan]), r"scores\['scores'\]: a finite array"),
        (lambda: stats.interval_estimates({"a": [1.0, 2.0]}, statistic="max"),
         r"statistic='max' is not allowed: one of \('iqm', 'mean', 'median'\)"),
        (lambda: stats.interval_estimates({"a": [1.0, 2.0]}, confidence=95),
         r"confidence=95: between 0 and 1"),
        (lambda: stats.holm([0.5, 1.5]), r"p_values: a list of numbers in \[0, 1\]"),
        (lambda: stats.probability_of_improvement([[1.0], [2.0]], [[1.0], [2.0], [3.0]]),
         r"x and y: the same runs and tasks"),
        (lambda: stats.sign_flip_p([1.0, np.inf]), r"differences: a finite array"),
        (lambda: stats.sign_flip_p(np.ones(45)), r"45 runs; the exact test enumerates at most 44"),
        (lambda: stats.sign_flip_interval([1.0, 2.0], 5.0), r"level=5.0: between 0 and 1"),
    ],
)  # fmt: skip
def test_bad_input_names_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()
