"""The data-set swap study (paper section IV-A-3, Fig. 3c): is the joint loss better only
because it collects better data?

1. Collect: run Algorithm 1 on the iiwa inverse-dynamics task with the task loss and with
   the joint loss (``--seeds`` seeds, ``--iterations`` iterations); each run writes its data
   set (``dataset.npz``).
2. Swap: retrain f and g from scratch on each recorded data set with each of the two losses
   (``cfm_jax.train(config, data=...)``: the recorded data is revealed iteration by
   iteration as it was collected, no new data enters; the controller is evaluated on the
   robot every iteration). Seed ``k`` of a retrain uses the data of seed ``k``.
3. Report: the 2 x 2 table of final tracking MSE (mean over seeds, each seed averaged over
   its targets, with a 95% bootstrap CI over seeds), the paired difference between the
   two data sets for each retraining loss, and a figure of the tracking MSE per iteration
   (mean and std over seeds x targets), one panel per data set.

Finished runs are skipped when the script is started again (each run's ``metrics.csv``
and ``dataset.npz`` mark it done), so an interrupted study resumes. Step 1's runs are
Algorithm 1 of the default config, as a sweep of the losses runs it: ``--collected DIR``
(repeatable) names sweep folders (``cfm_jax.sweep``'s ``out_dir``, for example the
robustness study's ``results/robustness/inverse_dynamics/home-default``) whose finished
cell of the very same config (``cells/<cell id>/run``, found by ``sweeps.cell_id``) is
used instead of running it again; the table says where each data set came from.

Issue 68 runs it on 20 seeds in two blocks of 10 (seeds 10-19 and 20-29), each block's
config that of the comparison's shared inverse-dynamics cell of the same block, so that the
block 20-29 takes its data sets from that cell's sweep (``--collected``), and ``--combine``
writes the blocks together.

Usage:
  python experiments/swap_study.py --out results/swap            # 5 seeds x 10 iterations
  python experiments/swap_study.py --seeds 10 --first-seed 10 --out results/swap/seeds-10-19
  python experiments/swap_study.py --seeds 10 --first-seed 20 --out results/swap/seeds-20-29 \
      --collected results/comparison/inverse_dynamics/shared/seeds-20-29
  python experiments/swap_study.py --combine results/swap/seeds-10-19 results/swap/seeds-20-29 \
      --out docs/results/swap
  python experiments/swap_study.py --out /tmp/swap --quick       # tiny, for a smoke test
  python experiments/swap_study.py --collected results/robustness/inverse_dynamics/home-default
"""

from __future__ import annotations

import argparse
import json
import os
import time

import matplotlib
import numpy as np
import pandas as pd

matplotlib.use("Agg")
import _study  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402

import cfm_jax  # noqa: E402
from cfm_jax import config as config_lib  # noqa: E402
from cfm_jax.analysis import report  # noqa: E402
from cfm_jax.runs import checkpoint, sweeps, training  # noqa: E402

LOSSES = ("task", "joint")


def base_config(seeds: int, iterations: int, quick: bool, first_seed: int = 0) -> config_lib.Config:
    """The iiwa14's inverse-dynamics defaults (``first_seed`` onwards): with ``first_seed``
    10 or 20 and 10 seeds, the config of the comparison's shared cell of that block
    (``experiments/comparison.py``), whose task and joint runs are then step 1's data sets."""
    # The torque scale of the comparison's cells.
    scale = _study.BEFORE_POSE["loop.torque_scale"]
    loop = config_lib.LoopConfig(iterations=iterations, seeds=seeds, torque_scale=scale)
    task = config_lib.TaskConfig(oracle=_study.BEFORE_PERIOD["task.oracle"])  # the records'
    if quick:  # the two-link arm with the studies' quick networks and fit steps
        return _study.quick_config(config_lib.Config(robot="two_link_arm", loop=loop,
                                                     task=task, seed=first_seed))  # fmt: skip
    return config_lib.Config(robot="iiwa14", loop=loop, task=task, seed=first_seed)


def done(run_dir: str, config: config_lib.Config) -> bool:
    """A finished run of this config: its dataset.npz exists and metrics.csv has the final
    evaluation of every seed."""
    try:
        with open(os.path.join(run_dir, "config.json")) as f:
            same = json.load(f) == json.loads(json.dumps(config_lib.to_dict(config)))
        metrics = pd.read_csv(os.path.join(run_dir, "metrics.csv"))
    except (FileNotFoundError, json.JSONDecodeError, pd.errors.EmptyDataError):
        return False
    final = metrics[metrics.iteration == config.loop.iterations]
    return (
        same
        and os.path.isfile(os.path.join(run_dir, "dataset.npz"))
        and final.seed.nunique() == config.loop.seeds
    )


def collect_dir(out: str, config: config_lib.Config, sweep_dirs=()) -> str:
    """Where the data set of ``config`` comes from: the first finished run of this very
    config among the sweep folders ``sweep_dirs`` (``cells/<cell id>/run``), else
    ``out/collect/<loss>`` (run there if it is not finished)."""
    for sweep_dir in sweep_dirs:
        run_dir = os.path.join(sweep_dir, "cells", sweeps.cell_id(config), "run")
        if done(run_dir, config):
            return run_dir
    return os.path.join(out, "collect", config.loss)


def _train(config, run_dir: str, progress: bool, experiment, **kwargs) -> None:
    """``cfm_jax.train`` into ``run_dir``, resumed from its checkpoints where an earlier
    piece was interrupted (bit for bit, ``cfm_jax.train``'s ``resume``)."""
    resume = run_dir if checkpoint.has_steps(run_dir) else None
    cfm_jax.train(config, progress=progress, out_dir=run_dir, experiment=experiment,
                  resume=resume, **kwargs)  # fmt: skip


def run(
    out: str, seeds: int, iterations: int, quick: bool, progress: bool, sweep_dirs=(),
    first_seed: int = 0,
) -> tuple[pd.DataFrame, dict, dict]:  # fmt: skip
    """Steps 1 and 2; returns the retrains' metrics (a ``data`` column says which data set),
    the wall times and where each data set came from."""
    base = base_config(seeds, iterations, quick, first_seed)
    experiment = training.Experiment(base)
    frames, walls, sources = [], {}, {}
    for collected in LOSSES:
        config = base.replace(loss=collected)
        run_dir = collect_dir(out, config, sweep_dirs)
        sources[collected] = run_dir
        start = time.perf_counter()
        if not done(run_dir, config):
            _train(config, run_dir, progress, experiment)
        walls[f"collect {collected}"] = time.perf_counter() - start
        data = os.path.join(run_dir, "dataset.npz")
        for loss in LOSSES:
            config = base.replace(loss=loss)
            replay_dir = os.path.join(out, "replay", f"{collected}_data", loss)
            start = time.perf_counter()
            if not done(replay_dir, config):
                _train(config, replay_dir, progress, experiment, data=data)
            walls[f"retrain {loss} on {collected}-loss data"] = time.perf_counter() - start
            metrics = pd.read_csv(os.path.join(replay_dir, "metrics.csv"))
            frames.append(metrics.assign(data=collected))
    metrics = pd.concat(frames, ignore_index=True)
    metrics.to_csv(os.path.join(out, "swap_metrics.csv"), index=False)
    with open(os.path.join(out, "wall_times.json"), "w") as f:
        json.dump({"seconds": walls, "data_sets": sources}, f, indent=2)
    return metrics, walls, sources


def table(metrics: pd.DataFrame) -> pd.DataFrame:
    """Rows: the data set (collected with loss ...); columns: the retraining loss; cells:
    the final tracking MSE, mean over seeds (each seed averaged over its targets) [95%
    bootstrap CI over seeds]; a last row: joint-loss data minus task-loss data, paired by
    seed (seed ``k`` of both retrains saw the data of seed ``k``), negative = the joint
    loss's data is better."""
    means = report.seed_means(metrics, by=("data", "loss"))
    per_seed = {
        (collected, loss): frame.set_index("seed").tracking_mse
        for (collected, loss), frame in means.groupby(["data", "loss"])
    }
    rows = {}
    for collected in LOSSES:
        rows[f"data collected with the {collected} loss"] = {
            f"retrained with {loss}": report.ci_text(report.mean_ci(per_seed[(collected, loss)]))
            for loss in LOSSES
        }
    rows["joint-loss data minus task-loss data (paired by seed)"] = {
        f"retrained with {loss}": report.ci_text(
            report.paired_difference(per_seed[("joint", loss)], per_seed[("task", loss)])
        )
        for loss in LOSSES
    }
    return pd.DataFrame.from_dict(rows, orient="index")


def figure(metrics: pd.DataFrame, path: str) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, collected in zip(axes, LOSSES, strict=True):
        for loss, color in zip(LOSSES, ("tab:blue", "tab:red"), strict=True):
            frame = metrics[(metrics.data == collected) & (metrics.loss == loss)]
            stats = frame.groupby("iteration").tracking_mse.agg(["mean", "std"])
            ax.plot(stats.index, stats["mean"], marker="o", ms=3, color=color, label=loss)
            lower = np.maximum(stats["mean"] - stats["std"], stats["mean"] * 1e-2)
            ax.fill_between(
                stats.index, lower, stats["mean"] + stats["std"], color=color, alpha=0.2
            )
        ax.set_title(f"data collected with the {collected} loss")
        ax.set_yscale("log")
        ax.set_xlabel("iteration (data revealed so far)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("joint tracking MSE (rad$^2$)")
    axes[0].legend(title="retrained with")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/swap")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="the first seed (a block of seeds: 10, 20 with --seeds 10)",
    )
    parser.add_argument(
        "--combine",
        nargs="+",
        metavar="OUT",
        help="write the table and figure of these finished blocks' "
        "swap_metrics.csv together into --out (nothing is trained)",
    )
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--quick", action="store_true", help="two-link arm, tiny networks")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--collected", action="append", default=[], metavar="SWEEP_DIR",
        help="a sweep folder whose finished cells of the same config give step 1's data "
        "sets (repeatable)",
    )  # fmt: skip
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    if args.combine:
        combine(args.combine, args.out)
        return
    start = time.perf_counter()
    metrics, walls, sources = run(
        args.out,
        args.seeds,
        args.iterations,
        args.quick,
        not args.quiet,
        args.collected,
        args.first_seed,
    )
    summary = table(metrics)
    markdown = _markdown(summary)
    protocol = report.protocol(
        base_config(args.seeds, args.iterations, args.quick, args.first_seed)
    )
    origin = "; ".join(f"{loss}-loss data from `{path}`" for loss, path in sources.items())
    with open(os.path.join(args.out, "swap_table.md"), "w") as f:
        f.write(protocol + "\n\n" + markdown + "\n\nData sets: " + origin + ".\n")
    figure(metrics, os.path.join(args.out, "swap_study.png"))
    print(markdown)
    for name, seconds in walls.items():
        print(f"{name}: {seconds:.0f} s")
    print(f"total {time.perf_counter() - start:.0f} s; results in {args.out}/")


def combine(blocks, out: str) -> pd.DataFrame:
    """The finished blocks of seeds (their ``--out`` folders) as one study in ``out``: their
    ``swap_metrics.csv`` together (disjoint seeds), ``swap_table.md`` with each block's
    protocol and data sets, the figure, and ``wall_times.json`` per block."""
    frames, texts, walls = [], [], {}
    for block in blocks:
        frames.append(pd.read_csv(os.path.join(block, "swap_metrics.csv")))
        with open(os.path.join(block, "swap_table.md")) as f:
            texts.append(f.read().split("\n\n")[0])
        with open(os.path.join(block, "wall_times.json")) as f:
            walls[os.path.basename(os.path.normpath(block))] = json.load(f)
    seeds = [set(f.seed) for f in frames]
    if sum(map(len, seeds)) != len(set().union(*seeds)):
        raise ValueError(f"--combine: the blocks {blocks} share seeds; each block its own")
    metrics = pd.concat(frames, ignore_index=True)
    metrics.to_csv(os.path.join(out, "swap_metrics.csv"), index=False)
    markdown = _markdown(table(metrics))
    with open(os.path.join(out, "swap_table.md"), "w") as f:
        f.write("\n\n".join(texts) + "\n\n" + markdown + "\n")
    with open(os.path.join(out, "wall_times.json"), "w") as f:
        json.dump(walls, f, indent=2)
    figure(metrics, os.path.join(out, "swap_study.png"))
    print(markdown)
    return metrics


def _markdown(frame: pd.DataFrame) -> str:
    lines = ["| data set | " + " | ".join(frame.columns) + " |"]
    lines.append("|---|" + "---:|" * len(frame.columns))
    for name, row in frame.iterrows():
        lines.append(f"| {name} | " + " | ".join(str(v) for v in row) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
