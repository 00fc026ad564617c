"""The arms' default torque scale, decided by the rule written before the runs (issue 64,
``docs/results/torque_scale_rule.md``): the pose scale against the coupled one on the
development set's arms, from the two zoo runs' folders.

    python experiments/torque_scale_decision.py \\
        --coupled results/robot_zoo/seeds3 --pose results/robot_zoo/seeds3_pose \\
        --page docs/results/torque_scale_decision.md

A run (one arm, seed and loss) scores log10 of its final tracking MSE (the mean over the
test motions), or log10(1000 x the arm's PD-only MSE) where a final motion diverged; ``d`` is
the pose run's score minus the coupled one's. The default becomes ``"pose"`` if the mean of
``d`` over all pairs is below 0 and on no arm does the pose scale have more diverged runs;
else ``"coupled"`` stays. The question whether one scale is better is the exact sign-flip
test of the arms' mean ``d`` (``cfm_jax.analysis.stats.sign_flip_p``), "not resolved" where
p >= 0.05. Nothing is decided while a pair is missing.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import pandas as pd

FLOOR = 1000.0  # a diverged run scores log10(FLOOR x PD-only), the floor of the searches


def scores(folder: str) -> pd.DataFrame:
    """One row per arm, seed and loss of a zoo run's folder (one sub-folder per arm with its
    ``metrics.csv`` and ``baselines.csv``; arms without them are left out): ``score`` and
    whether a final motion ``diverged``."""
    rows = []
    for arm in sorted(os.listdir(folder)):
        metrics_path = os.path.join(folder, arm, "metrics.csv")
        baselines_path = os.path.join(folder, arm, "baselines.csv")
        if not (os.path.exists(metrics_path) and os.path.exists(baselines_path)):
            continue
        metrics = pd.read_csv(metrics_path)
        base = pd.read_csv(baselines_path)
        pd_only = float(base[base.baseline == "pd_only"].tracking_mse.mean())
        for (loss, seed), run in metrics.groupby(["loss", "seed"]):
            final = run[run.iteration == run.iteration.max()]
            mse = float(final.tracking_mse.mean())
            diverged = bool((final.diverged != 0).any()) or not np.isfinite(mse)
            score = np.log10(FLOOR * pd_only) if diverged else np.log10(mse)
            rows.append(dict(arm=arm, seed=int(seed), loss=loss, score=score, diverged=diverged))
    return pd.DataFrame(rows, columns=["arm", "seed", "loss", "score", "diverged"])


def decide(coupled: pd.DataFrame, pose: pd.DataFrame) -> dict:
    """The rule's decision from the two runs' :func:`scores`: ``per_arm`` (mean ``d``, diverged
    runs under each scale), ``mean_d``, ``default``, the sign-flip ``p`` and its ``verdict``;
    ``missing`` pairs (then no decision: ``default`` None)."""
    from cfm_jax.analysis import stats

    keys = ["arm", "seed", "loss"]
    pairs = coupled.merge(pose, on=keys, how="outer", suffixes=("_coupled", "_pose"))
    missing = pairs[pairs.score_coupled.isna() | pairs.score_pose.isna()][keys]
    pairs = pairs.dropna(subset=["score_coupled", "score_pose"])
    pairs["d"] = pairs.score_pose - pairs.score_coupled
    per_arm = pairs.groupby("arm").agg(
        mean_d=("d", "mean"),
        pairs=("d", "size"),
        diverged_coupled=("diverged_coupled", "sum"),
        diverged_pose=("diverged_pose", "sum"),
    )
    result = dict(per_arm=per_arm, pairs=len(pairs), missing=missing, default=None)
    if pairs.empty:
        return result
    mean_d = float(pairs.d.mean())
    worse = per_arm[per_arm.diverged_pose > per_arm.diverged_coupled].index.tolist()
    p = stats.sign_flip_p(per_arm.mean_d.to_numpy())
    lower = "pose" if per_arm.mean_d.mean() < 0 else "coupled"
    result.update(
        mean_d=mean_d,
        more_diverged_under_pose=worse,
        p=p,
        verdict="not resolved" if p >= 0.05 else f"{lower} scores lower (p = {p:.2g})",
    )
    if missing.empty:
        result["default"] = "pose" if mean_d < 0 and not worse else "coupled"
    return result


def page(result: dict, coupled: str, pose: str) -> str:
    """The decision as Markdown: the per-arm table, then the rule's two conditions."""
    lines = [
        "# The arms' default torque scale: the rule applied",
        "",
        f"From `{coupled}` (coupled) and `{pose}` (pose) by `experiments/torque_scale_decision.py`"
        ", under the rule of [torque_scale_rule.md](torque_scale_rule.md). `d`: the pose run's "
        "score minus the coupled run's (log10 final tracking MSE; a diverged run log10(1000 x "
        "PD-only)); diverged: runs (seed and loss) with a diverged final motion.",
        "",
        "| arm | pairs | mean d | diverged runs, coupled | diverged runs, pose |",
        "|---|---:|---:|---:|---:|",
    ]
    for arm, row in result["per_arm"].iterrows():
        lines.append(
            f"| {arm} | {int(row.pairs)} | {row.mean_d:+.2f} | {int(row.diverged_coupled)} | "
            f"{int(row.diverged_pose)} |"
        )
    lines.append("")
    if result["pairs"] == 0:
        return "\n".join(lines + ["No pairs yet."]) + "\n"
    worse = result["more_diverged_under_pose"]
    lines += [
        f"Mean d over the {result['pairs']} pairs: {result['mean_d']:+.3f}; arms with more "
        f"diverged runs under pose: {', '.join(worse) if worse else 'none'}. Exact sign-flip "
        f"test of the {len(result['per_arm'])} arms' mean d: p = {result['p']:.3g}, "
        f"{result['verdict']}.",
        "",
    ]
    if result["default"] is None:
        lines.append(
            f"**No decision**: {len(result['missing'])} pairs are missing "
            f"({', '.join(sorted(set(result['missing'].arm)))})."
        )
    else:
        lines.append(f'**The arms\' default by the rule: `"{result["default"]}"`.**')
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--coupled", required=True, help="the zoo's folder of the defaults' run")
    parser.add_argument("--pose", required=True, help="the zoo's folder of the pose run")
    parser.add_argument("--page", default="", help="write the decision here (Markdown)")
    args = parser.parse_args(argv)
    for flag in ("coupled", "pose"):
        if not os.path.isdir(getattr(args, flag)):
            parser.error(f"--{flag}={getattr(args, flag)!r} is not a folder")
    result = decide(scores(args.coupled), scores(args.pose))
    text = page(result, args.coupled, args.pose)
    print(text)
    if args.page:
        with open(args.page, "w") as f:
            f.write(text)


if __name__ == "__main__":
    main()
