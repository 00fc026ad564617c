"""Summary tables and statistics (cfm_jax/analysis/report.py) against hand-computed numbers; the
figures drawn from them are tested in tests/test_plots.py."""

from __future__ import annotations

import math
import statistics
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import scipy.stats

from cfm_jax.analysis import report


def _metrics():
    rows = []
    for loss, scale in (("task", 2.0), ("joint", 1.0)):
        for seed in (0, 1):
            for iteration in (0, 1):
                for target in (0, 1):
                    mse = scale * (1 + seed + 2 * target) * (10.0 if iteration == 0 else 1.0)
                    rows.append(
                        dict(loss=loss, seed=seed, iteration=iteration, target=target,
                             tracking_mse=mse, prediction_error=0.5 * mse,
                             predicted_task_error=0.25 * mse)
                    )  # fmt: skip
    return pd.DataFrame(rows)


def test_summary_uses_the_final_iteration_over_seeds_and_targets():
    baselines = pd.DataFrame(
        {"baseline": ["oracle", "oracle", "pd_only", "pd_only"], "target": [0, 1, 0, 1],
         "tracking_mse": [1e-8, 3e-8, 0.1, 0.3]}
    )  # fmt: skip
    table = report.summary(_metrics(), baselines, rms_reach=2.0)
    # joint, final iteration: seeds x targets give 1, 3, 2, 4 -> mean 2.5, pop. std sqrt(1.25)
    assert table.loc["joint", "tracking_mse_mean"] == 2.5
    np.testing.assert_allclose(table.loc["joint", "tracking_mse_std"], np.sqrt(1.25))
    assert table.loc["task", "tracking_mse_mean"] == 5.0
    assert table.loc["joint", "runs"] == 4
    assert table.loc["joint", "prediction_error_mean"] == 1.25
    # losses in the library's order, then the baselines
    assert list(table.index) == ["joint", "task", "oracle", "pd_only"]
    assert table.loc["pd_only", "tracking_mse_mean"] == 0.2
    np.testing.assert_allclose(table.loc["joint", "rmse_over_reach"], np.sqrt(2.5) / 2.0)
    text = report.markdown(table)
    assert text.splitlines()[0].startswith("| controller |")
    assert "| joint | 2.5 |" in text


# ----- statistics over seeds ----------------------------------------------------------


def _percentile_by_hand(sorted_values, p):
    """The linear percentile of numpy (its default method), written out: with the values
    sorted, ``h = (B - 1) p / 100``, ``k = floor(h)``: ``v[k] + (h - k) (v[k+1] - v[k])``."""
    h = (len(sorted_values) - 1) * p / 100.0
    k = math.floor(h)
    if k + 1 >= len(sorted_values):
        return sorted_values[-1]
    return sorted_values[k] + (h - k) * (sorted_values[k + 1] - sorted_values[k])


def _bootstrap_by_hand(values, confidence, resamples, seed):
    """Plain-loop reference of report.bootstrap_ci: the same index matrix (rebuilt from the
    same seed), each resample mean summed element by element, sorted, percentiles by hand."""
    n = len(values)
    index = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    means = []
    for b in range(resamples):
        total = 0.0
        for j in range(n):
            total += values[int(index[b, j])]
        means.append(total / n)
    means.sort()
    low_p, high_p = 100 * (1 - confidence) / 2, 100 * (1 + confidence) / 2
    return _percentile_by_hand(means, low_p), _percentile_by_hand(means, high_p)


@pytest.mark.parametrize(
    "values, confidence, resamples, seed",
    [
        ([0.3, 1.7, 0.9, 2.4, 1.1], 0.95, 10_000, 0),  # the defaults
        ([0.3, 1.7, 0.9, 2.4, 1.1], 0.9, 2_001, 7),
        ([5.0, -2.0, 0.5, 3.3, 1.25, -0.7], 0.8, 999, 3),
    ],
)
def test_bootstrap_ci_equals_a_plain_loop(values, confidence, resamples, seed):
    expected = _bootstrap_by_hand(values, confidence, resamples, seed)
    if (confidence, resamples, seed) == (0.95, 10_000, 0):
        got = report.bootstrap_ci(values)
    else:
        got = report.bootstrap_ci(values, confidence=confidence, resamples=resamples, seed=seed)
    # the same numbers summed in another order (numpy's mean): equal to rounding
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)
    assert isinstance(got[0], float) and isinstance(got[1], float)
    # another seed gives other resamples: the check depends on the index matrix
    other = _bootstrap_by_hand(values, confidence, resamples, seed + 1)
    assert not np.allclose(got, other, rtol=1e-9, atol=0.0)


def test_mean_ci_is_the_plain_mean_and_the_plain_loop_interval():
    values = [0.3, 1.7, 0.9, 2.4, 1.1]
    seed_means = pd.Series(values, index=[4, 0, 2, 1, 3])  # order of seeds kept as given
    expected_low, expected_high = _bootstrap_by_hand(values, 0.95, 10_000, 0)
    for sample in (values, np.array(values), seed_means):
        got = report.mean_ci(sample)
        assert set(got) == {"mean", "low", "high"}
        assert got["mean"] == pytest.approx(sum(values) / 5, rel=1e-15)
        np.testing.assert_allclose(
            (got["low"], got["high"]), (expected_low, expected_high), rtol=1e-12
        )
    narrow = report.mean_ci(values, confidence=0.5)
    assert expected_low < narrow["low"] < narrow["high"] < expected_high
    empty = report.mean_ci([])
    assert all(math.isnan(v) for v in empty.values())


def test_ci_text_formats_means_and_paired_differences_alike():
    assert report.ci_text({"mean": 0.1543, "low": 0.04213, "high": 0.2718}) == (
        "0.154 [0.0421, 0.272]"
    )
    # small numbers in exponent form, NaN as "-", the extra "n" of paired_difference ignored
    assert report.ci_text({"mean": 2.0e-5, "low": float("nan"), "high": 1.0, "n": 3}) == (
        "2.00e-05 [-, 1]"
    )


def test_bootstrap_ci_agrees_with_scipy_within_monte_carlo_error():
    x = np.random.default_rng(42).lognormal(0.0, 0.5, size=20)
    low, high = report.bootstrap_ci(x, confidence=0.95, resamples=10_000)
    ref = scipy.stats.bootstrap(
        (x,), np.mean, confidence_level=0.95, n_resamples=10_000, method="percentile",
        rng=np.random.default_rng(123),
    ).confidence_interval  # fmt: skip
    # Tolerance: the two use different random resamples, so they differ by Monte-Carlo
    # error only. The bootstrap distribution of the mean is nearly normal with sd
    # s_b = std(x) / sqrt(n); the standard error of its 2.5% quantile estimated from
    # B = 10,000 resamples is sqrt(p (1 - p) / B) / phi(1.96) * s_b = 0.027 s_b, so the
    # difference of two independent estimates has sd 0.038 s_b. 0.2 s_b is over five such
    # sds, yet small enough to catch a wrong level: a 90% interval's ends lie
    # (1.96 - 1.645) s_b = 0.31 s_b inside.
    s_b = x.std() / np.sqrt(len(x))
    assert abs(low - ref.low) < 0.2 * s_b
    assert abs(high - ref.high) < 0.2 * s_b
    narrower = report.bootstrap_ci(x, confidence=0.9)
    assert abs(narrower[0] - ref.low) > 0.2 * s_b  # positive control of the tolerance


def test_bootstrap_ci_of_one_value_and_of_none():
    assert report.bootstrap_ci([2.5]) == (2.5, 2.5)
    assert report.bootstrap_ci(np.array([-1.0]), confidence=0.5) == (-1.0, -1.0)
    low, high = report.bootstrap_ci([])
    assert math.isnan(low) and math.isnan(high)
    for bad in ({"confidence": 1.0}, {"confidence": 0.0}, {"resamples": 0}):
        with pytest.raises(ValueError):
            report.bootstrap_ci([1.0, 2.0], **bad)
    with pytest.raises(ValueError, match="1-D"):
        report.bootstrap_ci([[1.0, 2.0]])


def test_seed_means_average_each_seed_over_its_targets():
    metrics = pd.DataFrame(
        {"loss": ["task"] * 6 + ["joint"] * 2, "seed": [1, 1, 0, 0, 1, 0, 0, 0],
         "iteration": [1, 1, 1, 1, 0, 0, 1, 1], "target": [0, 1, 0, 1, 0, 0, 0, 1],
         "tracking_mse": [4.0, 6.0, 1.0, 2.0, 9.0, 8.0, 0.5, 1.5]}
    )  # fmt: skip
    means = report.seed_means(metrics)
    # last iteration (1): task seed 0 (1 + 2) / 2 = 1.5, seed 1 (4 + 6) / 2 = 5; joint 1
    assert means[["loss", "seed", "iteration"]].values.tolist() == [
        ["task", 0, 1], ["task", 1, 1], ["joint", 0, 1]
    ]  # fmt: skip
    assert means["tracking_mse"].tolist() == [1.5, 5.0, 1.0]
    assert means["targets"].tolist() == [2, 2, 2]
    first = report.seed_means(metrics, iteration=0)
    assert first[["loss", "seed", "tracking_mse", "targets"]].values.tolist() == [
        ["task", 0, 8.0, 1], ["task", 1, 9.0, 1]
    ]  # fmt: skip
    no_seed = report.seed_means(metrics.drop(columns="seed"), column="tracking_mse")
    assert no_seed["tracking_mse"].tolist() == [(4 + 6 + 1 + 2) / 4, 1.0]
    with pytest.raises(ValueError, match="force_mse"):
        report.seed_means(metrics, column="force_mse")


def test_paired_difference_matches_seeds_and_equals_a_hand_computation():
    a = {3: 2.0, 1: 5.0, 2: 4.0, 0: 1.5}  # out of order
    b = pd.Series({2: 1.0, 0: 2.5, 3: 0.5})  # seed 1 missing
    # seeds 0, 2, 3: d = 1.5 - 2.5 = -1, 4 - 1 = 3, 2 - 0.5 = 1.5; mean 3.5 / 3
    result = report.paired_difference(a, b)
    assert result["n"] == 3
    np.testing.assert_allclose(result["mean"], 3.5 / 3, rtol=1e-15)
    assert (result["low"], result["high"]) == report.bootstrap_ci([-1.0, 3.0, 1.5])
    assert result["low"] < result["mean"] < result["high"]
    # the order of the inputs does not matter (d is ordered by seed)
    shuffled = report.paired_difference(pd.Series(a).sort_index(ascending=False), dict(b))
    assert shuffled == result
    # the bootstrap arguments are passed on
    level = report.paired_difference(a, b, confidence=0.5, resamples=500, seed=9)
    expected = report.bootstrap_ci([-1.0, 3.0, 1.5], confidence=0.5, resamples=500, seed=9)
    assert (level["low"], level["high"]) == expected
    one = report.paired_difference({4: 1.0}, {4: 3.0, 5: 0.0})
    assert one == {"mean": -2.0, "low": -2.0, "high": -2.0, "n": 1}
    none = report.paired_difference({1: 1.0}, {2: 1.0})
    assert none["n"] == 0 and math.isnan(none["mean"]) and math.isnan(none["low"])
    with pytest.raises(ValueError, match="more than once"):
        report.paired_difference(pd.Series([1.0, 2.0], index=[0, 0]), b)


def _hand_frame():
    """Three seeds (rows out of order) x two targets at the final iteration 2 for joint
    and task, supervised without seed 2; an earlier iteration that must be ignored."""
    rows = []
    values = {  # (loss, seed): the two targets' values
        ("joint", 2): (1.0, 3.0), ("joint", 0): (0.5, 1.5), ("joint", 1): (2.0, 2.0),
        ("task", 1): (3.0, 5.0), ("task", 0): (1.0, 2.0), ("task", 2): (4.0, 4.0),
        ("supervised", 0): (0.25, 0.75), ("supervised", 1): (1.0, 1.0),
    }  # fmt: skip
    for (loss, seed), pair in values.items():
        for target, value in enumerate(pair):
            rows.append(dict(loss=loss, seed=seed, iteration=2, target=target,
                             tracking_mse=value, force_mse=10 * value))  # fmt: skip
            rows.append(dict(loss=loss, seed=seed, iteration=1, target=target,
                             tracking_mse=100.0, force_mse=100.0))  # fmt: skip
    return pd.DataFrame(rows)


# seed means at iteration 2, by hand (seeds 0, 1, 2):
#   joint: (0.5 + 1.5) / 2 = 1, (2 + 2) / 2 = 2, (1 + 3) / 2 = 2
#   task: (1 + 2) / 2 = 1.5, (3 + 5) / 2 = 4, (4 + 4) / 2 = 4
#   supervised: (0.25 + 0.75) / 2 = 0.5, (1 + 1) / 2 = 1 (no seed 2)
JOINT, TASK, SUPERVISED = [1.0, 2.0, 2.0], [1.5, 4.0, 4.0], [0.5, 1.0]


def test_summary_ci_columns_on_a_hand_made_frame():
    baselines = pd.DataFrame({"baseline": ["oracle", "pd_only"], "target": [0, 0],
                              "tracking_mse": [0.01, 9.0], "force_mse": [0.1, 90.0]})  # fmt: skip
    table = report.summary(_hand_frame(), baselines)
    assert list(table.index) == ["joint", "task", "supervised", "oracle", "pd_only"]
    for loss, means in (("joint", JOINT), ("task", TASK), ("supervised", SUPERVISED)):
        row = table.loc[loss]
        assert row["iteration"] == 2 and row["seeds"] == len(means)
        np.testing.assert_allclose(row["seed_std"], statistics.stdev(means), rtol=1e-12)
        assert (row["ci_low"], row["ci_high"]) == report.bootstrap_ci(means)
        assert row["ci_low"] <= statistics.mean(means) <= row["ci_high"]
    # joint: 3 seeds (1, 2, 2): resample means lie in [1, 2], 1 and 2 each with chance
    # 1/27 > 2.5%, so the 95% interval is exactly [1, 2]
    assert (table.loc["joint", "ci_low"], table.loc["joint", "ci_high"]) == (1.0, 2.0)
    # the pooled columns are unchanged: mean and population std over seeds x targets
    pooled = [0.5, 1.5, 2.0, 2.0, 1.0, 3.0]
    assert table.loc["joint", "tracking_mse_mean"] == statistics.mean(pooled)
    np.testing.assert_allclose(table.loc["joint", "tracking_mse_std"], statistics.pstdev(pooled))
    assert table.loc["joint", "runs"] == 6
    assert table.loc["oracle", "tracking_mse_mean"] == 0.01
    assert math.isnan(table.loc["oracle", "seeds"]) and math.isnan(table.loc["oracle", "ci_low"])
    assert table.attrs == {"column": "tracking_mse", "confidence": 0.95, "resamples": 10_000}
    text = report.markdown(table)
    low, high = report.bootstrap_ci(TASK)
    assert f"| task | {report._format(statistics.mean(TASK))} |" in text
    assert f"| {report._format(statistics.stdev(TASK))} | [{report._format(low)}, " in text
    assert "| 95% CI |" in text.splitlines()[0] and "ci_low" not in text
    assert text.splitlines()[-1].startswith("95% CI: percentile bootstrap (10000 resamples)")
    assert "| oracle | 0.01 | 0 | 1 | - | - | - |" in text
    # any metric column; another level
    force = report.summary(_hand_frame(), baselines, column="force_mse", confidence=0.8)
    np.testing.assert_allclose(force.loc["task", "force_mse_mean"], 10 * statistics.mean(TASK))
    assert (force.loc["task", "ci_low"], force.loc["task", "ci_high"]) == report.bootstrap_ci(
        [10 * m for m in TASK], confidence=0.8
    )
    assert force.loc["pd_only", "force_mse_mean"] == 90.0
    assert "| 80% CI |" in report.markdown(force).splitlines()[0]
    # one seed: no spread, the interval is the value itself and shown as "-"
    one = report.summary(_hand_frame().query("seed == 0"))
    assert (one.loc["task", "ci_low"], one.loc["task", "ci_high"]) == (1.5, 1.5)
    assert math.isnan(one.loc["task", "seed_std"])
    assert "| task | 1.5 | 0.5 | 2 | 1 | - | - |" in report.markdown(one)


def test_paired_table_against_hand_differences():
    table = report.paired_table(_hand_frame())
    assert list(table.index) == ["task", "supervised"]
    # joint - task over seeds 0, 1, 2: 1 - 1.5, 2 - 4, 2 - 4 = -0.5, -2, -2
    d_task = [-0.5, -2.0, -2.0]
    np.testing.assert_allclose(table.loc["task", "mean_difference"], -4.5 / 3, rtol=1e-15)
    assert (table.loc["task", "ci_low"], table.loc["task", "ci_high"]) == report.bootstrap_ci(
        d_task
    )
    # joint - supervised over seeds 0, 1 only: 1 - 0.5, 2 - 1 = 0.5, 1
    assert table.loc["supervised", "mean_difference"] == 0.75
    assert table.loc["supervised", "seeds"] == 2
    assert (table.loc["supervised", "ci_low"], table.loc["supervised", "ci_high"]) == (
        report.bootstrap_ci([0.5, 1.0])
    )
    assert table.attrs["reference"] == "joint" and table.attrs["column"] == "tracking_mse"
    text = report.paired_markdown(table)
    low, high = report.bootstrap_ci(d_task)
    assert f"| task | -1.5 | [{report._format(low)}, {report._format(high)}] | 3 |" in text
    assert "| loss | joint - loss | 95% CI | seeds |" in text
    assert "negative: joint lower, better" in text.splitlines()[0]
    # another reference and metric; None picks joint, else the first loss present
    other = report.paired_table(_hand_frame(), reference="task", column="force_mse")
    assert list(other.index) == ["joint", "supervised"]
    np.testing.assert_allclose(other.loc["joint", "mean_difference"], 10 * 4.5 / 3)
    assert report.paired_table(_hand_frame(), reference=None).attrs["reference"] == "joint"
    no_joint = _hand_frame().query("loss != 'joint'")
    assert report.paired_table(no_joint, reference=None).attrs["reference"] == "task"
    with pytest.raises(ValueError, match="distal"):
        report.paired_table(_hand_frame(), reference="distal")
    alone = report.paired_table(_hand_frame().query("loss == 'joint'"))
    assert len(alone) == 0 and "| loss | joint - loss |" in report.paired_markdown(alone)


def test_seed_curves_band_is_the_bootstrap_ci_over_seed_means():
    curves = report.seed_curves(_hand_frame(), columns=["tracking_mse"])
    final = curves[curves.iteration == 2].set_index("loss")
    for loss, means in (("joint", JOINT), ("task", TASK), ("supervised", SUPERVISED)):
        expected = report.bootstrap_ci(means)
        got = (final.loc[loss, "tracking_mse_ci_low"], final.loc[loss, "tracking_mse_ci_high"])
        assert got == expected


def test_rich_tables_show_the_interval_and_say_what_it_is(capsys):
    report.print_summary(report.summary(_hand_frame()), title="t")
    out = capsys.readouterr().out
    low, high = report.bootstrap_ci(TASK)
    assert f"[{report._format(low)}, {report._format(high)}]" in out
    assert "95% CI" in out and "percentile" in " ".join(out.split())
    assert "each seed averaged over its targets" in " ".join(out.split())
    report.print_paired(report.paired_table(_hand_frame()))
    out = " ".join(capsys.readouterr().out.split())
    assert "joint minus each loss" in out and "joint - loss" in out and "-1.5" in out


def test_cli_summary_file_has_the_interval_and_the_paired_table(tmp_path):
    from cfm_jax import cli
    from cfm_jax import config as config_lib

    metrics = _hand_frame()
    result = SimpleNamespace(
        baselines=pd.DataFrame({"baseline": ["oracle"], "target": [0], "tracking_mse": [0.01]}),
        rms_reach=1.0,
    )
    task = SimpleNamespace(tracking_name="joint", tracking_unit="rad", output_unit="rad")
    cli._write_outputs(str(tmp_path), [metrics], result, config_lib.Config(), task)
    text = (tmp_path / "summary.md").read_text()
    # The protocol line (initial data and s* gains), then the table.
    protocol = "initial data: `loop.babbling='reaching'` (2 rollouts per target, torque noise 0.1"
    assert text.startswith(protocol)
    table = report.markdown(report.summary(metrics, result.baselines, 1.0))
    assert text.startswith(report.protocol(config_lib.Config()) + "\n\n" + table)
    assert report.paired_markdown(report.paired_table(metrics)) in text
    cli._write_outputs(str(tmp_path), [metrics.query("loss == 'task'")], result,
                       config_lib.Config(), task)  # fmt: skip
    assert "- loss |" not in (tmp_path / "summary.md").read_text()  # one loss: no pairs


def test_sweep_summary_has_the_interval_and_the_paired_table_per_override():
    from cfm_jax.runs import sweeps

    metrics = pd.concat(
        [
            _hand_frame().assign(kp=50.0),
            _hand_frame().assign(kp=100.0, tracking_mse=lambda f: 2 * f.tracking_mse),
        ],
        ignore_index=True,
    )
    baselines = pd.DataFrame({"kp": [50.0, 100.0], "baseline": ["oracle"] * 2, "target": [0, 0],
                              "tracking_mse": [0.125, 0.375]})  # fmt: skip
    result = sweeps.SweepResult(metrics, baselines, pd.DataFrame(), ("kp",), None, 0.0)
    text = result.markdown()
    assert text.startswith(report.curves_markdown(result.curves(), ["loss", "kp"]))
    for kp, scale, oracle in ((50.0, 1.0, 0.125), (100.0, 2.0, 0.375)):
        frame = metrics[metrics.kp == kp]
        base = baselines[baselines.kp == kp]
        assert f"at the last iteration, kp={kp}:" in text
        assert report.markdown(report.summary(frame, base)) in text
        assert f"| oracle | {oracle} |" in text
        assert report.paired_markdown(report.paired_table(frame)) in text
        low, high = report.bootstrap_ci([scale * m for m in TASK])
        assert f"| task | {report._format(scale * statistics.mean(TASK))} |" in text
    assert text.count("| loss | joint - loss | 95% CI | seeds |") == 2


def test_intervals_take_the_seed_means_in_seed_order():
    """The fixed bootstrap indices make the interval depend on the order of the values:
    every function orders by seed, whatever the order of the rows."""
    values = [
        0.6181,
        0.4518,
        0.8616,
        1.2869,
        1.9771,
        1.068,
        0.7178,
        0.6245,
        1.5671,
        2.6668,
        1.1778,
        0.4771,
    ]  # seeds 0..11: with 12 seeds the resample means rarely tie
    means = {seed: values[seed] for seed in (7, 2, 11, 0, 5, 9, 1, 10, 3, 8, 6, 4)}
    ordered = [means[s] for s in sorted(means)]
    expected = report.bootstrap_ci(ordered)
    assert expected != report.bootstrap_ci(ordered[::-1])  # positive control: order matters
    rows = [
        dict(loss=loss, seed=seed, iteration=0, target=target,
             tracking_mse=value * shift + (0.1 if target else -0.1))
        for seed, value in means.items()
        for loss, shift in (("joint", 1.0), ("task", 2.0))
        for target in (0, 1)
    ]  # fmt: skip
    metrics = pd.DataFrame(rows)
    table = report.summary(metrics)
    np.testing.assert_allclose(table.loc["joint", ["ci_low", "ci_high"]], expected, rtol=1e-12)
    curves = report.seed_curves(metrics).set_index("loss")
    got = curves.loc["joint", ["tracking_mse_ci_low", "tracking_mse_ci_high"]]
    np.testing.assert_allclose(got.astype(float), expected, rtol=1e-12)
    # joint - task = -mean per seed
    paired = report.paired_table(metrics)
    negated = report.bootstrap_ci([-m for m in ordered])
    np.testing.assert_allclose(paired.loc["task", ["ci_low", "ci_high"]], negated, rtol=1e-12)
    scrambled = report.paired_difference(means, {s: 0.0 for s in reversed(sorted(means))})
    np.testing.assert_allclose([scrambled["low"], scrambled["high"]], expected, rtol=1e-12)


@pytest.mark.parametrize("width", [100, 60])
def test_a_narrow_console_cuts_no_number_and_no_name(width):
    # On a 100-column terminal the MSE mean showed as "3.70e…" and RMSE/reach vanished;
    # through a pipe, loss names were clipped ("supervis…"). Every cell must be whole.
    import io

    from rich.console import Console

    frame = _hand_frame()
    frame = pd.concat([frame, frame.assign(loss="supervised_long_name")])
    table = report.summary(frame, rms_reach=0.35)
    console = Console(width=width, file=io.StringIO())
    report.print_summary(table, title="t", console=console)
    out = console.file.getvalue()
    assert "…" not in out
    for name, row in table.iterrows():
        assert str(name) in out
        for column in report._table_columns(table):
            assert report._cell(row, column) in out, (name, column)


def test_falls_are_counted_in_the_summary_and_its_printouts(capsys):
    # The walk's printed table and summary.md did not show falls (only metrics.csv had them).
    metrics = pd.DataFrame(
        {
            "loss": ["joint"] * 4 + ["task"] * 4,
            "seed": [0, 0, 1, 1] * 2,
            "iteration": [2] * 8,
            "target": [0, 1] * 4,
            "tracking_mse": [1.0, 2.0, 3.0, 4.0, 1.0, 1.0, 1.0, 1.0],
            "fell": [0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, np.nan],
        }
    )
    table = report.summary(metrics)
    assert table.loc["joint", "fell"] == 2 and table.loc["task", "fell"] == 0
    text = report.markdown(table)
    assert "fell" in [h.strip() for h in text.splitlines()[0].split("|")]
    report.print_summary(table, title="walk")
    out = " ".join(capsys.readouterr().out.split())
    assert " fell " in out and "fell: runs in which the robot fell" in out
