"""Inverse dynamics on the KUKA iiwa 14 (paper section IV-A-1, Fig. 3a, and the forward-model
prediction error and predicted task error during learning of Fig. 4), through cfm_jax.sweep.

Every controller loss (``--losses``), ``--seeds`` seeds (one vmapped program per loss) and
``--iterations`` iterations of Algorithm 1. Writes into ``--out`` what the sweep writes
(``metrics.csv`` and ``metrics.parquet``: one row per loss, seed, iteration, target;
``summary.md``: mean and std over seeds at the last iteration; ``curves.png``: tracking
MSE, prediction error and predicted task error per iteration, mean and std over seeds;
``cells/``: one folder per loss, so an interrupted study resumes where it stopped) and
``table.md``: final joint tracking MSE per loss, mean and std over seeds x targets, next to
the oracle and PD-only, with the RMSE as a fraction of the RMS reaching distance (the
table of the README).

Usage:
  python experiments/iiwa_inverse_dynamics.py --out results/iiwa_inverse_dynamics
  python experiments/iiwa_inverse_dynamics.py --quick --out /tmp/iiwa   # pipeline smoke test
"""

from __future__ import annotations

import os

import _study

import cfm_jax
from cfm_jax.analysis import report


def main() -> None:
    args = _study.parser(__doc__.split("\n")[0], "results/iiwa_inverse_dynamics").parse_args()
    config = _study.for_task("inverse_dynamics", robot="iiwa14")
    result, seconds, config = _study.run(config, args)
    rms_reach = cfm_jax.Experiment.shared(config).task.tracking_scale
    table = report.summary(result.metrics, result.baselines, rms_reach)
    seeds = result.metrics.seed.nunique()
    text = (
        f"Final joint-position tracking MSE (rad^2) at iteration "
        f"{int(result.metrics.iteration.max())}, mean and std over {seeds} seed(s) x targets; "
        f"RMSE/reach: sqrt(mean) over the RMS reaching distance {rms_reach:.4f} rad. "
        f"Wall time {seconds:.0f} s.\n\n{report.protocol(config)}.\n\n"
        + report.markdown(table)
        + "\n"
    )
    with open(os.path.join(args.out, "table.md"), "w") as f:
        f.write(text)
    print(text)
    print(result.markdown())


if __name__ == "__main__":
    main()
