"""experiments/torque_scale_decision.py applies docs/results/torque_scale_rule.md as written.

Oracles: scores and the decision by hand on made-up zoo folders; the sign-flip p by a plain
loop over every sign assignment of the arms' mean differences.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import torque_scale_decision as rule


def _arm(folder, arm, pd_only, final, diverged=()):
    """A zoo arm folder: ``final[(loss, seed)]`` is the final MSE of each of 2 motions (an
    earlier iteration at 1.0 that must be ignored); ``diverged``: (loss, seed) whose motion 1
    diverged at the final iteration."""
    path = folder / arm
    path.mkdir(parents=True)
    rows = []
    for (loss, seed), mse in final.items():
        for target in (0, 1):
            rows.append(dict(loss=loss, seed=seed, iteration=0, target=target,
                             tracking_mse=1.0, diverged=0.0))  # fmt: skip
            bad = (loss, seed) in diverged and target == 1
            rows.append(dict(loss=loss, seed=seed, iteration=4, target=target,
                             tracking_mse=np.nan if bad else mse, diverged=float(bad)))  # fmt: skip
    pd.DataFrame(rows).to_csv(path / "metrics.csv", index=False)
    base = dict(baseline=["pd_only", "oracle"], target=[0, 0], tracking_mse=[pd_only, 1e-9])
    pd.DataFrame(base).to_csv(path / "baselines.csv", index=False)


def _runs(tmp_path, pose_values, pose_diverged=()):
    coupled, pose = tmp_path / "coupled", tmp_path / "pose"
    for i, arm in enumerate(("a", "b", "c")):
        _arm(coupled, arm, 1e-2, {("joint", 0): 1e-4, ("task", 0): 1e-5})
        _arm(pose, arm, 1e-2, {("joint", 0): pose_values[i], ("task", 0): 1e-5},
             diverged=pose_diverged if arm == "c" else ())  # fmt: skip
    return rule.scores(str(coupled)), rule.scores(str(pose))


def test_scores_are_log10_final_mse_and_a_diverged_run_the_floor(tmp_path):
    _arm(tmp_path, "x", 2e-2, {("joint", 0): 1e-4, ("task", 1): 1e-3}, diverged={("task", 1)})
    s = rule.scores(str(tmp_path)).set_index(["loss", "seed"])
    assert s.loc[("joint", 0), "score"] == np.log10(1e-4) and not s.loc[("joint", 0), "diverged"]
    assert s.loc[("task", 1), "score"] == np.log10(1000 * 2e-2) and s.loc[("task", 1), "diverged"]


def test_pose_becomes_the_default_when_lower_on_average_and_never_more_diverged(tmp_path):
    coupled, pose = _runs(tmp_path, [1e-5, 1e-5, 1e-3])  # d: -1, -1, +1 on joint, 0 on task
    result = rule.decide(coupled, pose)
    assert result["pairs"] == 6 and np.isclose(result["mean_d"], (-1 - 1 + 1) / 6)
    assert result["default"] == "pose"
    means = [-0.5, -0.5, 0.5]
    assert np.allclose(result["per_arm"].mean_d.to_numpy(), means)
    # the plain loop: |mean| of every sign assignment at least the observed one's
    flips = [abs(np.mean(np.array(s) * means)) >= abs(np.mean(means)) - 1e-12
             for s in itertools.product((1, -1), repeat=3)]  # fmt: skip
    assert result["p"] == sum(flips) / 8 and result["verdict"] == "not resolved"


def test_coupled_stays_when_pose_diverges_more_on_any_arm(tmp_path):
    coupled, pose = _runs(tmp_path, [1e-7, 1e-7, 1e-7], pose_diverged={("task", 0)})
    result = rule.decide(coupled, pose)
    assert result["mean_d"] < 0  # lower on average, yet
    assert result["more_diverged_under_pose"] == ["c"] and result["default"] == "coupled"


def test_no_decision_while_a_pair_is_missing(tmp_path):
    coupled, pose = _runs(tmp_path, [1e-5, 1e-5, 1e-5])
    result = rule.decide(coupled, pose[pose.arm != "b"])
    assert result["default"] is None and sorted(set(result["missing"].arm)) == ["b"]
    assert "No decision" in rule.page(result, "c", "p")
