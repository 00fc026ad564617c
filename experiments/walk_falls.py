"""Where in a walk the learned controllers fall, iteration by iteration (issue 65, item 4).

Reads a comparison cell's committed records (``metrics.csv``: one row per loss, seed,
iteration and test walk; ``fell`` and ``transitions_added``, the control steps of a
rollout that became data, which end at its first fall) and writes a table: per loss and
iteration, the falls among the test walks and the median, earliest and latest control step
of those falls. The five test walks are prefixes of one 3-s trot
(``locomotion.WALK_DURATIONS``, the same reference up to each horizon), so a fall at 2.2 s
is a fall of the 2.5-s and the 3-s walk alike.

Usage::

  python experiments/walk_falls.py                       # the walk's shared cell, seeds 10-19
  python experiments/walk_falls.py --cell docs/results/comparison/cells/walk/own-joint \
      --out docs/results/walk_falls.md
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import pandas as pd

from cfm_jax.tasks import locomotion

CONTROL_DT = locomotion.CONTROL_DT


def fall_table(metrics: pd.DataFrame, every: int = 5) -> pd.DataFrame:
    """Per loss and iteration (0, ``every``, 2 ``every``, ..., the last): ``runs`` (seeds x
    walks), ``fell`` (runs with a fall), and the ``median``, ``earliest`` and ``latest``
    control step of the first fall among them (NaN without falls).

    Args:
      metrics: a metrics table with ``loss``, ``iteration``, ``fell`` and ``transitions_added``.
      every: the step between the iterations shown.

    Examples:
      >>> m = pd.DataFrame({"loss": "joint", "iteration": [0, 0, 1, 1], "fell": [1.0, 1, 0, 1],
      ...                   "transitions_added": [100.0, 120, 250, 300]})
      >>> fall_table(m, every=1)[["iteration", "fell", "median"]].values.tolist()
      [[0, 2, 110.0], [1, 1, 300.0]]
    """
    rows = []
    for loss, frame in metrics.groupby("loss", sort=False):
        last = int(frame.iteration.max())
        for it in sorted(set(range(0, last + 1, every)) | {last}):
            at = frame[frame.iteration == it]
            steps = at[at.fell > 0].transitions_added.to_numpy()
            rows.append({
                "loss": loss, "iteration": it, "runs": len(at), "fell": len(steps),
                "median": float(np.median(steps)) if len(steps) else np.nan,
                "earliest": float(steps.min()) if len(steps) else np.nan,
                "latest": float(steps.max()) if len(steps) else np.nan,
            })  # fmt: skip
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame, source: str) -> str:
    """The table as a page: falls of the runs and where they happen (s)."""
    lines = [
        f"# Where the learned walks fall, iteration by iteration\n\nFrom `{source}` "
        "(`python experiments/walk_falls.py`). *fell*: runs (seeds x test walks) with a "
        "fall; where: the control step of the first fall, median [earliest, latest], in "
        f"seconds ({CONTROL_DT} s a step). The test walks are prefixes of one 3-s trot.\n",
        "| loss | iteration | fell | where (s) |",
        "|---|---:|---:|---|",
    ]
    for r in table.itertuples():
        where = ("-" if np.isnan(r.median) else
                 f"{r.median * CONTROL_DT:.2f} [{r.earliest * CONTROL_DT:.2f}, "
                 f"{r.latest * CONTROL_DT:.2f}]")  # fmt: skip
        lines.append(f"| {r.loss} | {r.iteration} | {r.fell} of {r.runs} | {where} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cell", default="docs/results/comparison/cells/walk/shared")
    parser.add_argument("--every", type=int, default=5)
    parser.add_argument("--out", default=None, help="write the page here (default: print)")
    args = parser.parse_args()
    metrics = pd.read_csv(os.path.join(args.cell, "metrics.csv"))
    page = markdown(fall_table(metrics, args.every), args.cell)
    if args.out:
        with open(args.out, "w") as f:
            f.write(page)
    print(page)


if __name__ == "__main__":
    main()
