"""The oracle over the held control period on finished zoo runs (issue 64).

For each robot folder of ``experiments/robot_zoo.py`` (``OUT/seeds3/ROBOT``), the baselines of
its run's config with ``task.oracle="period"`` (the default since session 34; the runs
recorded the one-step oracle, their ``baselines.csv``), next to each seed's final tracking
of every loss: is the oracle at or below every learned controller, seed by seed? Only the
baselines are computed (a few seconds per robot): the learned runs do not depend on the
oracle (it has weight 0 in their rollouts and the babbling does not use it).

    python experiments/period_oracle.py --table docs/results/oracle_period.md \\
        RUN_FOLDER [RUN_FOLDER ...]

Each folder gets ``baselines_period.csv``; the page is written whole.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import time

import numpy as np
import pandas as pd
import robot_zoo

from cfm_jax import config as config_lib
from cfm_jax.analysis import report
from cfm_jax.learning import algorithm

LOSSES = ("joint", "task", "distal", "supervised")


def period_baselines(folder: str) -> pd.DataFrame:
    """The baselines of ``folder``'s run with the period oracle (written beside its own)."""
    path = os.path.join(folder, "baselines_period.csv")
    if os.path.exists(path):
        return pd.read_csv(path)
    with open(os.path.join(folder, "task", "config.json")) as f:
        config = config_lib.from_dict(json.load(f))
    config = config.replace(task=dataclasses.replace(config.task, oracle="period"))
    frame = algorithm.Experiment(config).baselines()
    frame.to_csv(path, index=False)
    return frame


def row(folder: str) -> dict:
    """One robot's numbers: PD-only, both oracles and the learned seeds' final tracking."""
    recorded = pd.read_csv(os.path.join(folder, "baselines.csv"))
    start = time.perf_counter()
    period = period_baselines(folder)
    seconds = time.perf_counter() - start
    means = report.seed_means(pd.read_csv(os.path.join(folder, "metrics.csv")))
    means = means[means.loss.isin(LOSSES) & np.isfinite(means.tracking_mse)]
    smallest = means.loc[means.tracking_mse.idxmin()]

    def mean(frame, name):
        return float(frame[frame.baseline == name].tracking_mse.mean())

    oracle = mean(period, "oracle")
    return {
        "robot": os.path.basename(os.path.normpath(folder)),
        "pd_only": mean(recorded, "pd_only"),
        "pd_only_again": mean(period, "pd_only"),
        "one_step": mean(recorded, "oracle"),
        "period": oracle,
        "smallest": float(smallest.tracking_mse),
        "smallest_of": f"{smallest.loss}, seed {int(smallest.seed)}",
        "below": int((means.tracking_mse > oracle).sum()),
        "seeds": len(means),
        "seconds": seconds,
    }


def page(rows: list[dict], command: str, note: str = "") -> str:
    """The Markdown page of ``rows`` (``note``: a paragraph after the table)."""
    lines = [
        "# The oracle over the held control period, on the published arms",
        "",
        f"Written by `{command}`, {datetime.date.today().isoformat()}, code "
        f"{robot_zoo.code_version()}. The baselines of each "
        "zoo run's config with `task.oracle=\"period\"` (MuJoCo's inverse dynamics made exact "
        "over the control period on the simulator: `baselines.over_the_period`), the default "
        "since session 34. `one step`: the oracle the runs recorded (the inverse of the "
        "period's first physics step, its torque then held for the period's five). "
        "`smallest learned`: the smallest final tracking MSE of any loss on any seed (each "
        "seed's mean over its 5 targets); `oracle below`: of the learned runs (4 losses x 3 "
        "seeds, diverged ones left out), how many track worse than the period oracle. "
        "Tracking MSE in rad^2, means over the 5 targets.",
        "",
        "| robot | PD-only | oracle, one step | oracle, period | smallest learned | oracle below |",
        "|---|---:|---:|---:|---|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['robot']} | {r['pd_only']:.3g} | {r['one_step']:.3g} | {r['period']:.3g} | "
            f"{r['smallest']:.3g} ({r['smallest_of']}) | {r['below']}/{r['seeds']} |"
        )
    return "\n".join(lines + ([f"\n{note}"] if note else [])) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", help="robot folders of robot_zoo runs")
    parser.add_argument("--table", required=True, help="the Markdown page to write")
    parser.add_argument("--note", default="", help="a paragraph after the table")
    args = parser.parse_args(argv)
    rows = []
    for folder in args.folders:
        rows.append(row(folder))
        r = rows[-1]
        print(
            f"{r['robot']}: one step {r['one_step']:.3g}, period {r['period']:.3g}, smallest "
            f"learned {r['smallest']:.3g}; oracle below {r['below']}/{r['seeds']}; PD-only "
            f"{r['pd_only']:.3g} (again {r['pd_only_again']:.3g}); {r['seconds']:.0f} s",
            flush=True,
        )
    command = "python experiments/period_oracle.py --table " + args.table + " ..."
    with open(args.table, "w") as f:
        f.write(page(rows, command, args.note))


if __name__ == "__main__":
    main()
