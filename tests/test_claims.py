"""experiments/claims.py (issue 43): the claims page's statistics, verdicts and sources.

Oracles: per-seed values and runs built by hand so that each answer is plain (log10 errors,
scores in orders of magnitude below PD-only, counts); the committed records, from which the
page and the README's results are regenerated bit for bit.
"""

from __future__ import annotations

import os
import re
import sys

import numpy as np
import pandas as pd
import pytest

from cfm_jax import report

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "experiments"))
import claims  # noqa: E402
import comparison  # noqa: E402

LOSSES = ("joint", "task", "distal", "supervised")
ROOT = os.path.join(os.path.dirname(__file__), "..")
SEEDS = pd.Index(range(10), name="seed")
MODERATE = [-0.5, -0.4, -0.3, -0.2, 0.1, 0.05, -0.6, -0.35, -0.25, 0.1]
"""A difference whose bootstrap p-value is about 0.011: clear alone, not among 30."""


def _family(**differences):
    family = claims.Family()
    zero = pd.Series(0.0, index=SEEDS)
    for name, values in differences.items():
        family.add(name, pd.Series(values, index=SEEDS), zero)
    family.solve()
    return family


def test_verdicts_follow_the_rule_and_holm_corrects_for_the_pages_comparisons():
    rng = np.random.default_rng(0)
    family = _family(
        task=-1.0 + 0.1 * rng.normal(size=10),  # joint ten times lower on every seed
        distal=np.array([1.0, -1.0] * 5),  # no difference on average
        supervised=1.0 + 0.1 * rng.normal(size=10),  # supervised ten times lower
    )
    signs = {n: family.sign(n) for n in ("task", "distal", "supervised")}
    assert signs == {"task": -1, "distal": 0, "supervised": 1}
    assert claims.beats_verdict([signs["task"]]) == "reproduces"
    assert claims.beats_verdict([signs["distal"]]) == "not resolved"
    assert claims.beats_verdict([signs["task"], signs["distal"]]) == "not resolved"
    assert claims.beats_verdict(list(signs.values())) == "does not reproduce"
    row = family.table.loc["task"]
    assert family.text("task", "joint - task") == (
        f"joint - task {row.point:+.2f} [{row.low:+.2f}, {row.high:+.2f}] "
        f"({100 * row.confidence:.2f}% clear)"
    )
    assert row.confidence == pytest.approx(1 - 0.05 / 3)  # Holm: the smallest p of 3 (a tie)
    # The same moderate difference: clear alone, not clear among 30 comparisons.
    assert _family(m=MODERATE).sign("m") == -1
    nulls = {f"null{k}": np.array([1.0, -1.0] * 5) + 0.01 * k for k in range(29)}
    crowded = _family(m=MODERATE, **nulls)
    assert crowded.sign("m") == 0
    row = crowded.table.loc["m"]
    assert row.low < 0 < row.high and row.confidence > 0.95


def _arm(mse: dict, failed=(), pd_only=1e-2, iterations=(0, 3)):
    """Two seeds x two motions per loss; ``mse[loss]`` the error of every run at the last
    iteration (10x higher before), ``failed`` the (loss, seed, target) runs that fell."""
    rows = [dict(loss=loss, seed=s, iteration=it, target=k,
                 tracking_mse=value * (1 if it == iterations[-1] else 10),
                 fell=float(it == iterations[-1] and (loss, s, k) in failed), diverged=0.0,
                 force_mse=100.0 * (s + 1))
            for loss, value in mse.items() for s in (0, 1) for it in iterations
            for k in (0, 1)]  # fmt: skip
    baselines = pd.DataFrame({"baseline": ["pd_only"] * 2 + ["oracle"] * 2, "target": [0, 1] * 2,
                              "tracking_mse": [pd_only] * 2 + [1e-9] * 2})  # fmt: skip
    return claims.Arm(pd.DataFrame(rows), baselines, "hand-made")


def test_per_seed_values_are_log10_errors_with_the_failure_floor_by_hand():
    # PD-only 1e-2: a failed run's log10 error is at least log10(1000 x 1e-2) = 1.
    arm = _arm({"joint": 1e-4, "task": 1e-6}, failed=[("task", 1, 0)])
    last = claims.per_seed(arm, "tracking_mse")
    assert last["joint"].tolist() == pytest.approx([-4.0, -4.0])
    assert last["task"].tolist() == pytest.approx([-6.0, (1.0 - 6.0) / 2])
    during = claims.per_seed(arm, "tracking_mse", over="all")  # iterations 0 and 3
    assert during["joint"].tolist() == pytest.approx([(-3.0 - 4.0) / 2] * 2)
    forces = claims.per_seed(arm, "force_mse")  # plain log10, no floor
    assert forces["task"].tolist() == pytest.approx([2.0, np.log10(200.0)])


def test_headline_table_scores_runs_below_pd_only_with_failures_floored():
    arm = _arm({"joint": 1e-4, "task": 1e-3, "distal": 1e-6, "supervised": 1e-2},
               failed=[("distal", s, k) for s in (0, 1) for k in (0, 1)])  # fmt: skip
    scores = claims.run_scores(arm)
    np.testing.assert_allclose(scores["joint"], [[2.0, 2.0], [2.0, 2.0]])
    np.testing.assert_allclose(scores["distal"], -3.0)  # failed: at most 3 above PD-only
    lines = claims.headline_table("walk", {"shared": arm, "own": None})
    assert "| joint | 2.00 [2.00, 2.00] | 0/4 |  | not run yet |  |  |" in lines
    assert (
        "| distal | -3.00 [-3.00, -3.00] | 4/4 | 1.00 [1.00, 1.00] | not run yet |  |  |" in lines
    )
    assert (
        "| supervised | 0.00 [0.00, 0.00] | 0/4 | 1.00 [1.00, 1.00] | not run yet |  |  |" in lines
    )


def test_success_counts_the_falls_of_the_last_iteration():
    """Fig. 5's "only the joint loss succeeds": the joint loss never falls at the last
    iteration, every other loss does once (its fall before that does not count)."""
    others = [(n, 0, 0) for n in LOSSES[1:]]
    arm = _arm(dict.fromkeys(LOSSES, 1e-3), failed=others)
    verdict, text = claims.success_verdict(arm)
    assert verdict == "reproduces" and text == "joint 0/4, task 1/4, distal 1/4, supervised 1/4"
    arm = _arm(dict.fromkeys(LOSSES, 1e-3), failed=[*others, ("joint", 1, 1)])
    assert claims.success_verdict(arm)[0] == "does not reproduce"


def test_arms_take_the_comparisons_cells_and_the_robustness_default_until_then(tmp_path):
    robustness = claims.records(os.path.join(ROOT, "docs", "results", "robustness"))
    default = next(c for c in robustness if c.task == "jump" and c.default)
    got = claims.arms(str(tmp_path), robustness)["jump"]
    assert got["shared"].source.startswith("the robustness study's default cell")
    assert got["shared"].metrics.equals(robustness[default][0]) and got["own"] is None
    arm = _arm(dict.fromkeys(LOSSES, 1e-3))
    for name, losses in (("shared", LOSSES), *((f"own-{n}", (n,)) for n in LOSSES[:3])):
        folder = comparison.record_dir(str(tmp_path), comparison.Cell("jump", name, losses))
        os.makedirs(folder)
        arm.metrics[arm.metrics.loss.isin(losses)].to_csv(f"{folder}/metrics.csv", index=False)
        arm.baselines.to_csv(f"{folder}/baselines.csv", index=False)
    got = claims.arms(str(tmp_path), robustness)["jump"]
    assert got["shared"].source == "the comparison's shared cell" and got["own"] is None
    folder = comparison.record_dir(str(tmp_path), comparison.Cell("jump", "own-supervised", ()))
    os.makedirs(folder)
    arm.metrics[arm.metrics.loss == "supervised"].to_csv(f"{folder}/metrics.csv", index=False)
    arm.baselines.to_csv(f"{folder}/baselines.csv", index=False)
    own = claims.arms(str(tmp_path), robustness)["jump"]["own"]
    assert sorted(set(own.metrics.loss)) == sorted(LOSSES) and len(own.metrics) == len(arm.metrics)
    assert own.source == "the comparison's own cells"
    # An own cell that is the shared cell's run (the same sweep cell, so the same config) is
    # named: here the joint loss's.
    for name, losses in (("shared", LOSSES), ("own-joint", ("joint",)), ("own-task", ("task",))):
        record = comparison.record_dir(str(tmp_path), comparison.Cell("jump", name, losses))
        mine = arm.metrics[arm.metrics.loss.isin(losses)]
        same = name in ("shared", "own-joint")
        mine.assign(cell=mine.loss + ("-0" if same else "-1")).to_csv(f"{record}/metrics.csv",
                                                                        index=False)  # fmt: skip
    own = claims.arms(str(tmp_path), robustness)["jump"]["own"]
    assert own.source == ("the comparison's own cells (joint: their search chose the shared "
                          "defaults, so these are the shared cell's runs)")  # fmt: skip
    # An own cell on other motions (another PD-only) cannot be compared: refused.
    arm.baselines.assign(tracking_mse=2e-2).to_csv(f"{folder}/baselines.csv", index=False)
    with pytest.raises(ValueError, match="jump: the own-supervised cell's PD-only differs"):
        claims.arms(str(tmp_path), robustness)


def test_theory_verdict_can_return_every_verdict():
    """The 1-D claim (issue 43): each verdict of THEORY_RULE from counts made for it."""
    assert claims.theory_verdict(cases=254, closer=254) == "reproduces"
    assert claims.theory_verdict(cases=254, closer=0) == "does not reproduce"
    assert claims.theory_verdict(cases=254, closer=3) == "mixed"
    assert claims.theory_verdict(cases=0, closer=0) == "not resolved"
    with pytest.raises(ValueError, match="closer=5: between 0 and cases=4"):
        claims.theory_verdict(cases=4, closer=5)


def test_committed_claims_page_is_its_records(tmp_path):
    """docs/results/claims.md regenerated from the committed records (the comparison's
    cells, the robustness study's, the swap) and the 1-D theory recomputed: every number
    and verdict on the page comes from them (issue 43, item 4)."""
    results = os.path.join(ROOT, "docs", "results")
    got = claims.write(os.path.join(results, "comparison"), os.path.join(results, "robustness"),
                       os.path.join(results, "swap", "swap_metrics.csv"),
                       str(tmp_path / "claims.md"))  # fmt: skip
    with open(os.path.join(results, "claims.md")) as f:
        assert got == f.read()
    assert (tmp_path / "claims_profiles.png").stat().st_size > 10_000


def test_every_comparison_the_readme_quotes_is_on_the_claims_page():
    """The README's prose quotes comparisons of the claims page ("joint - task +0.61 [+0.29,
    +0.89]": the IQM of per-seed log10 differences and its Holm-level interval); each must
    be the page's, as the page is today (its intervals move with the number of comparisons
    Holm corrects together)."""
    readme = open(os.path.join(ROOT, "README.md")).read()
    page = open(os.path.join(ROOT, "docs", "results", "claims.md")).read()
    quoted = re.findall(r"[+-]\d+\.\d\d \[[+-]\d+\.\d\d, [+-]\d+\.\d\d\]", readme)
    assert len(quoted) >= 10  # the README's results text quotes them
    assert [q for q in quoted if q not in page] == []


def test_readme_results_table_is_the_committed_records():
    """The README's results table (final tracking MSE per loss, mean over seeds [95% CI],
    falls, oracle and PD-only) recomputed from the claims page's headline cells (the
    comparison's, or the robustness default cells standing in), two significant digits; a
    task whose own cells have run has a second row, "each at its best" (issue 43, item 4:
    the README tied to the records)."""

    def fmt(value):
        if value < 0.01:
            mantissa, exponent = f"{value:.1e}".split("e")
            return f"{mantissa}e{int(exponent)}"
        return f"{value:.2g}"

    labels = {"inverse_dynamics": "iiwa inverse dynamics, rad^2", "opspace": "iiwa op-space, m^2",
              "walk": "Solo12 walk, base pose", "jump": "Solo12 jump, base pose"}  # fmt: skip
    readme = open(os.path.join(ROOT, "README.md")).read().splitlines()
    results = os.path.join(ROOT, "docs", "results")
    robustness = claims.records(os.path.join(results, "robustness"))
    tasks = claims.arms(os.path.join(results, "comparison"), robustness)
    assert set(tasks) == set(labels) and all(t["shared"] is not None for t in tasks.values())
    for task, pair in tasks.items():
        for key, arm in pair.items():
            if arm is None:
                continue
            metrics, baselines = arm.metrics, arm.baselines
            means = report.seed_means(metrics, column="tracking_mse")
            final = metrics[metrics.iteration == metrics.iteration.max()]
            row = [labels[task] + ("" if key == "shared" else ", each at its best")]
            for loss in LOSSES:
                ci = report.mean_ci(means[means.loss == loss].set_index("seed").tracking_mse)
                text = f"{fmt(ci['mean'])} [{fmt(ci['low'])}, {fmt(ci['high'])}]"
                if task in ("walk", "jump"):
                    text += f"; {int(report.failed_runs(final[final.loss == loss]).sum())} fell"
                row.append(text)
            for baseline in ("oracle", "pd_only"):
                row.append(fmt(baselines[baselines.baseline == baseline].tracking_mse.mean()))
            assert "| " + " | ".join(row) + " |" in readme, (task, key)
