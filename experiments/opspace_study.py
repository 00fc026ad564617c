"""The operational-space study (paper section IV-A-2, Fig. 3b): learn g(q, qdot, xdd*_ee)
for the redundant iiwa with each controller loss.

Runs ``cfm-jax train --robot iiwa14 --task opspace --loss all`` (``--seeds`` seeds x
``--iterations`` iterations; the four losses one after another, sharing babbling data and
the initial forward fit) and writes, into ``--out``: ``metrics.csv``, ``baselines.csv``
(the analytic operational-space oracle and task-space PD-only), ``summary.md`` (final
end-effector tracking MSE per loss, mean and std over seeds x targets) and
``learning_curves.png`` (tracking MSE, forward-model prediction error and predicted task
error per iteration, mean and std: the paper's Fig. 3b and 4 style). Interrupted runs
resume with ``--resume``.

Usage:
  python experiments/opspace_study.py --out results/opspace      # 5 seeds x 10 iterations
  python experiments/opspace_study.py --quick --out /tmp/opspace  # pipeline smoke test
"""

from __future__ import annotations

import argparse
import json
import os

import _study

from cfm_jax import cli
from cfm_jax import config as config_lib


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/opspace")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--robot", default="iiwa14")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"tiny networks, 0.3 s references, 2 seeds, 1 iteration, losses "
        f"{_study.QUICK_LOSSES}: a smoke test of the pipeline, not a result",
    )
    args = parser.parse_args()
    config, loss, seeds, iterations = None, "all", args.seeds, args.iterations
    if args.quick:
        os.makedirs(args.out, exist_ok=True)
        config = os.path.join(args.out, "quick_config.json")
        quick = _study.quick_config(config_lib.for_task("opspace", robot=args.robot))
        with open(config, "w") as f:
            json.dump(config_lib.to_dict(quick), f, indent=2)
        loss, seeds, iterations = _study.QUICK_LOSSES, 2, 1
    cli.train(
        robot=args.robot,
        task="opspace",
        loss=loss,
        seeds=seeds,
        iterations=iterations,
        out=args.out,
        config=config,
        resume=args.resume,
        quiet=args.quiet,
    )


if __name__ == "__main__":
    main()
