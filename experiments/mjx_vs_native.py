"""MJX against the native simulator on the Solo12 walk and jump: does a short learning run
reach the same conclusions on both?

For each task (``walk``, ``jump``), simulator (``native``: MuJoCo C, ``mjx``) and loss
(``joint``, ``task``) one cell: ``cfm_jax.train`` of the robustness study's cell
``home-default`` (``experiments/robustness_study.py``: the defaults before the selection
run, ``home`` babbling, no feedback in ``s*``, the paper's networks and fits; the records
ran on them) with ``--seeds`` seeds (0, 1, ...) and
``--iterations`` iterations, only ``config.simulator`` differing between the simulators.
The two losses of a (task, simulator) share one ``Experiment`` (its compilations).

Outputs, in ``--out``:

* ``cells/<task>/<simulator>-<loss>/``: the record of a finished cell: ``metrics.csv``
  and ``baselines.csv`` (what ``cfm_jax.train`` writes), ``seconds.txt`` (its wall time;
  one line per piece it ran in). A cell with a record is skipped, so the script resumes
  where it stopped (a cell interrupted mid-run resumes from its checkpoints in ``--runs``).
* ``summary.csv``: one row per finished cell: the final tracking MSE (last iteration)
  mean over seeds (each seed averaged over its targets), its 95% bootstrap CI and the std
  over seeds (``report.mean_ci``), the force MSE likewise, the falls at the last
  iteration (fallen runs of seeds x targets), the baselines' tracking MSE and the wall
  time.
* ``index.md``: the table, the paired joint - task difference per task and simulator
  (``report.paired_difference``), whether both simulators' means put the same loss lower
  and whether their intervals overlap (the difference within the seed spread); a block between
  ``<!-- verdict -->`` and ``<!-- /verdict -->`` (the written verdict) is kept when the
  page is rewritten.

Usage:
  python experiments/mjx_vs_native.py                       # 8 cells, 2 seeds, 3 iterations
  python experiments/mjx_vs_native.py --only walk --budget 1800  # a resumable piece
  python experiments/mjx_vs_native.py --budget 0             # the page from finished cells
  python experiments/mjx_vs_native.py --quick --runs /tmp/m --out /tmp/m  # smoke test
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import time

import _study
import robustness_study

import cfm_jax  # (via _study first: it sets the XLA flag before JAX starts)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = ("walk", "jump")
SIMULATORS = ("native", "mjx")
LOSSES = ("joint", "task")
RECORD_FILES = ("metrics.csv", "baselines.csv", "seconds.txt")


@dataclasses.dataclass(frozen=True)
class Cell:
    task: str
    simulator: str
    loss: str

    @property
    def name(self) -> str:
        return f"{self.task}/{self.simulator}-{self.loss}"


def cells(tasks) -> list[Cell]:
    return [Cell(t, s, loss) for t in tasks for s in SIMULATORS for loss in LOSSES]


def config_for(task: str, simulator: str, seeds: int, iterations: int, quick: bool):
    """The robustness study's cell of ``task`` with the defaults before the selection run
    (``home-default``: this study's records ran on them) on ``simulator``."""
    config = robustness_study.find(task, "home-default").config(iterations)
    if quick:
        config = _study.quick_config(config)
    return config.replace(simulator=simulator, loop=dataclasses.replace(config.loop, seeds=seeds))


def record_dir(out: str, cell: Cell) -> str:
    return os.path.join(out, "cells", cell.task, f"{cell.simulator}-{cell.loss}")


def run_dir(runs: str, cell: Cell) -> str:
    return os.path.join(runs, cell.task, f"{cell.simulator}-{cell.loss}")


def finished(out: str, cell: Cell) -> bool:
    return os.path.isfile(os.path.join(record_dir(out, cell), "metrics.csv"))


def run_cell(cell: Cell, experiment, config, args) -> float:
    """Train one cell (or resume it from its checkpoints) and keep its record."""
    run = run_dir(args.runs, cell)
    resume = run if os.path.isdir(os.path.join(run, "checkpoints")) else None

    def progress(iteration, rows):
        print(
            f"  {cell.name} iteration {iteration}: tracking MSE {rows.tracking_mse.mean():.4g}, "
            f"fell {rows.fell.sum():.0f}/{len(rows)}, {time.perf_counter() - start:.0f} s",
            flush=True,
        )

    start = time.perf_counter()
    cfm_jax.train(
        config.replace(loss=cell.loss),
        progress=False,
        out_dir=run,
        experiment=experiment,
        resume=resume,
        progress_fn=progress,
    )
    seconds = time.perf_counter() - start
    with open(os.path.join(run, "seconds.txt"), "a") as f:
        f.write(f"{seconds:.1f}\n")
    os.makedirs(record_dir(args.out, cell), exist_ok=True)
    for name in RECORD_FILES:
        shutil.copyfile(os.path.join(run, name), os.path.join(record_dir(args.out, cell), name))
    return seconds


def cell_row(out: str, cell: Cell) -> dict:
    import pandas as pd

    from cfm_jax.analysis import report

    folder = record_dir(out, cell)
    metrics = pd.read_csv(os.path.join(folder, "metrics.csv"))
    baselines = pd.read_csv(os.path.join(folder, "baselines.csv"))
    final = metrics[metrics.iteration == metrics.iteration.max()]
    per_seed = final.groupby("seed")[["tracking_mse", "force_mse"]].mean()
    tracking, force = report.mean_ci(per_seed.tracking_mse), report.mean_ci(per_seed.force_mse)
    with open(os.path.join(folder, "seconds.txt")) as f:
        seconds = sum(float(line) for line in f if line.strip())
    means = baselines.groupby("baseline").tracking_mse.mean()
    return {
        "task": cell.task,
        "simulator": cell.simulator,
        "loss": cell.loss,
        "seeds": int(final.seed.nunique()),
        "iteration": int(final.iteration.max()),
        "final_mean": tracking["mean"],
        "ci_low": tracking["low"],
        "ci_high": tracking["high"],
        "seed_std": float(per_seed.tracking_mse.std(ddof=1)),
        "seed_min": float(per_seed.tracking_mse.min()),
        "seed_max": float(per_seed.tracking_mse.max()),
        "force_mean": force["mean"],
        "force_low": force["low"],
        "force_high": force["high"],
        "falls": int(round(final.fell.sum())),
        "runs": len(final),
        "oracle_mse": float(means.get("oracle", float("nan"))),
        "pd_only_mse": float(means.get("pd_only", float("nan"))),
        "seconds": seconds,
    }


def paired(out: str, task: str, simulator: str) -> dict | None:
    """joint - task over the seeds both have, final tracking MSE (each seed averaged over
    its targets)."""
    import pandas as pd

    from cfm_jax.analysis import report

    per_loss = {}
    for loss in LOSSES:
        cell = Cell(task, simulator, loss)
        if not finished(out, cell):
            return None
        metrics = pd.read_csv(os.path.join(record_dir(out, cell), "metrics.csv"))
        final = metrics[metrics.iteration == metrics.iteration.max()]
        per_loss[loss] = final.groupby("seed").tracking_mse.mean()
    return report.paired_difference(per_loss["joint"], per_loss["task"])


def page(out: str, rows, args, previous: str) -> str:
    from cfm_jax.analysis import report

    text = report.ci_text
    # What the finished cells ran (the flags of this call may differ: --budget 0).
    seeds = max((r["seeds"] for r in rows), default=args.seeds)
    iterations = max((r["iteration"] for r in rows), default=args.iterations)
    lines = [
        "# MJX against the native simulator: Solo12 walk and jump",
        "",
        "Written by `python experiments/mjx_vs_native.py` (the cells' records are in "
        "`cells/`, the numbers in `summary.csv`). Each cell is `cfm_jax.train` of the "
        "robustness study's default cell (`for_task` defaults: `home` babbling, 2 rollouts "
        "per target at torque noise 0.1, no feedback in `s*`, the paper's networks and fits) "
        f"with {seeds} seeds and {iterations} iterations; only `config.simulator` "
        "differs between the columns' simulators (`native`: MuJoCo C in float64; `mjx`: "
        "MJX in float32). Final tracking MSE: base position and orientation error at the "
        "last iteration, m^2 | rad^2, mean over seeds (each seed averaged over its 5 "
        "targets) [95% percentile bootstrap CI over seeds], and the lowest and highest "
        "seed mean; falls: fallen runs of seeds x targets at the last iteration.",
        "",
        "| task | loss | simulator | final tracking MSE | seed means (min, max) | force MSE (N^2) "
        "| falls | wall time (s) |",
        "|---|---|---|---|---|---|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['loss']} | {r['simulator']} "
            f"| {text({'mean': r['final_mean'], 'low': r['ci_low'], 'high': r['ci_high']})} "
            f"| {r['seed_min']:.3g}, {r['seed_max']:.3g} "
            f"| {text({'mean': r['force_mean'], 'low': r['force_low'], 'high': r['force_high']})} "
            f"| {r['falls']}/{r['runs']} | {r['seconds']:.0f} |"
        )
    lines += [
        "",
        "Baselines (tracking MSE averaged over the 5 targets; the same on every loss):",
        "",
        "| task | simulator | oracle | PD only |",
        "|---|---|---:|---:|",
    ]
    seen = set()
    for r in rows:
        if (r["task"], r["simulator"]) not in seen:
            seen.add((r["task"], r["simulator"]))
            lines.append(
                f"| {r['task']} | {r['simulator']} | {r['oracle_mse']:.3g} "
                f"| {r['pd_only_mse']:.3g} |"
            )
    lines += [
        "",
        "## Does the ranking of the losses agree?",
        "",
        "Paired over seeds: joint minus task, final tracking MSE, mean [95% bootstrap CI] "
        "(negative: joint lower). *Lower loss*: the loss each simulator's mean puts lower "
        "(*clear* when its interval excludes 0). *Overlap*: whether the two simulators' "
        "intervals overlap, i.e. whether their difference is within the seed spread."
        + (
            " With 2 seeds an interval is only the range of the two seeds' differences."
            if seeds == 2
            else ""
        ),  # fmt: skip
        "",
        "| task | native: joint - task | mjx: joint - task | lower loss (native, mjx) "
        "| same lower loss | overlap |",
        "|---|---|---|---|---|---|",
    ]
    for task in TASKS:
        both = {s: paired(args.out, task, s) for s in SIMULATORS}
        if any(v is None for v in both.values()):
            continue
        lower = {}
        for s, v in both.items():
            clear = " (clear)" if v["low"] > 0 or v["high"] < 0 else ""
            lower[s] = ("joint" if v["mean"] < 0 else "task") + clear
        same = lower["native"].split()[0] == lower["mjx"].split()[0]
        overlap = max(v["low"] for v in both.values()) <= min(v["high"] for v in both.values())
        lines.append(
            f"| {task} | {text(both['native'])} | {text(both['mjx'])} "
            f"| {lower['native']}, {lower['mjx']} | {'yes' if same else 'no'} "
            f"| {'yes' if overlap else 'no'} |"
        )
    verdict = re.search(r"<!-- verdict -->\n.*?<!-- /verdict -->\n", previous, flags=re.S)
    lines += ["", verdict.group(0) if verdict else "<!-- verdict -->\n<!-- /verdict -->\n"]
    return "\n".join(lines)


def write_outputs(args, all_cells) -> list[dict]:
    import pandas as pd

    rows = [cell_row(args.out, c) for c in all_cells if finished(args.out, c)]
    os.makedirs(args.out, exist_ok=True)
    pd.DataFrame(rows).to_csv(os.path.join(args.out, "summary.csv"), index=False)
    path = os.path.join(args.out, "index.md")
    previous = open(path).read() if os.path.isfile(path) else ""
    with open(path, "w") as f:
        f.write(page(args.out, rows, args, previous))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", default=os.path.join(ROOT, "results", "mjx_vs_native"))
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "results", "mjx_vs_native"))
    parser.add_argument("--only", default=",".join(TASKS), help="comma-separated tasks")
    parser.add_argument("--simulators", default=",".join(SIMULATORS))
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument(
        "--budget", type=float, default=float("inf"),
        help="seconds: start no further cell after this; the script resumes when started again",
    )  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="tiny networks: a smoke test")
    args = parser.parse_args()
    tasks = [t.strip() for t in args.only.split(",") if t.strip()]
    simulators = [s.strip() for s in args.simulators.split(",") if s.strip()]
    if not tasks or any(t not in TASKS for t in tasks):
        parser.error(f"--only={args.only!r} is not allowed: names from {', '.join(TASKS)}")
    if not simulators or any(s not in SIMULATORS for s in simulators):
        parser.error(f"--simulators={args.simulators!r}: names from {', '.join(SIMULATORS)}")
    from cfm_jax.runs import training

    start = time.perf_counter()
    experiments: dict = {}
    todo = [c for c in cells(tasks) if c.simulator in simulators]
    for cell in todo:
        if finished(args.out, cell):
            print(f"mjx_vs_native: {cell.name} finished before; skipped", flush=True)
            continue
        if time.perf_counter() - start >= args.budget:
            print(f"mjx_vs_native: budget of {args.budget:.0f} s used; stopping", flush=True)
            break
        config = config_for(cell.task, cell.simulator, args.seeds, args.iterations, args.quick)
        key = (cell.task, cell.simulator)
        if key not in experiments:
            experiments.clear()  # one at a time: the compiled functions are large
            experiments[key] = training.Experiment(config)
        print(f"mjx_vs_native: {cell.name} ({args.seeds} seeds, {args.iterations} iterations)",
              flush=True)  # fmt: skip
        seconds = run_cell(cell, experiments[key], config, args)
        print(f"mjx_vs_native: {cell.name} done in {seconds:.0f} s", flush=True)
        write_outputs(args, cells(TASKS))
    rows = write_outputs(args, cells(TASKS))
    print(f"mjx_vs_native: {len(rows)} of {len(cells(TASKS))} cells finished; {args.out}/index.md")
    print(open(os.path.join(args.out, "index.md")).read())


if __name__ == "__main__":
    main()
