"""Walking and jumping with the Solo12 quadruped (paper section IV-B), through cfm_jax.sweep.

``--task walk`` (a trot over 5 horizons of 1-3 s) or ``--task jump`` (a vertical jump to 5
heights); every controller loss, ``--seeds`` seeds, ``--iterations`` iterations. Writes into
``--out`` what the sweep writes (``metrics.csv``/``.parquet``, ``summary.md``,
``curves.png``, ``cells/``; an interrupted study resumes) and ``table.md``: per loss at the
last iteration, the base pose tracking MSE, the foot-force MSE, the share of targets on
which the robot fell and the base position and orientation errors, mean and std over seeds
(each seed averaged over the 5 targets), with the reference controller (oracle) and its
joint PD alone (PD-only) below: the quantities to set beside the paper's Table I.

Usage:
  python experiments/solo_locomotion.py --task walk --out results/solo_walk
  python experiments/solo_locomotion.py --task jump --out results/solo_jump
  python experiments/solo_locomotion.py --task walk --quick --out /tmp/walk   # smoke test
"""

from __future__ import annotations

import os

import _study

from cfm_jax import config as config_lib
from cfm_jax import report

COLUMNS = ("tracking_mse", "force_mse", "fell", "base_position_mse", "base_orientation_mse")


def main() -> None:
    parser = _study.parser(__doc__.split("\n")[0], "results/solo_walk")
    parser.add_argument("--task", default="walk", choices=("walk", "jump"))
    args = parser.parse_args()
    result, seconds, _ = _study.run(config_lib.for_task(args.task), args)
    curves = report.seed_curves(result.metrics, by=["loss"], columns=COLUMNS)
    lines = [
        f"Solo12 {args.task}: wall time {seconds:.0f} s.",
        "",
        report.curves_markdown(curves, ["loss"], columns=COLUMNS),
        "",
        "Baselines, mean over the targets:",
        "",
        "| baseline | " + " | ".join(COLUMNS) + " |",
        "|---|" + "---:|" * len(COLUMNS),
    ]
    for name, frame in result.baselines.groupby("baseline", sort=False):
        values = " | ".join(report._format(frame[c].mean()) for c in COLUMNS)
        lines.append(f"| {name} | {values} |")
    text = "\n".join(lines) + "\n"
    with open(os.path.join(args.out, "table.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()
