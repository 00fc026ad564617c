"""cfm_jax.stats (issue 43): the few-run statistics against hand computations, closed forms
and plain loops written here."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from cfm_jax import stats


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


def test_paired_comparisons_decide_by_holm_and_show_its_intervals():
    rng = np.random.default_rng(3)
    clear = -1.0 + 0.1 * rng.normal(size=10)  # every seed below 0
    unclear = np.array([1.0, -1.0] * 5) + 0.01 * rng.normal(size=10)  # centred on 0
    frame = stats.paired_comparisons({"a - b": clear, "a - c": unclear}, reps=4000)
    first, second = frame.iloc[0], frame.iloc[1]
    assert first.clear and not second.clear
    assert first.p == pytest.approx(2 / 4001)  # no resample at or above 0: (1 + 0) / (1 + reps)
    # Two comparisons: the smaller p is tested at alpha / 2, the other at alpha.
    assert first.confidence == pytest.approx(0.975) and second.confidence == pytest.approx(0.95)
    assert first.high < 0 and second.low < 0 < second.high
    assert first.point == pytest.approx(clear.mean())


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
    ],
)  # fmt: skip
def test_bad_input_names_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()
