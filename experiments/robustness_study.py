"""Which controller loss wins where: the paper's four losses under the faithful protocol and
under the choices the library made before it, with confidence intervals over seeds.

The cells (``CELLS``), each one :func:`cfm_jax.sweep` of the four losses (``joint``,
``task``, ``distal``, ``supervised``) with the same seeds, 10 iterations, each a set of
``changes`` (dotted config paths) to :func:`cfm_jax.config.for_task`:

* ``defaults`` of each task (iiwa14 ``inverse_dynamics`` and ``opspace``, Solo12 ``walk``
  and ``jump``; 5 seeds): the library's defaults, the headline results.
* ``iterations=30`` of ``walk`` and ``jump`` (5 seeds): the same defaults run for the
  authors' 30 iterations (their Solo12 code's count, the selection run's legged curves),
  whatever ``--iterations`` says: whether the legged learners go on improving after 10.
* One cell per default that the selection run (``select_defaults.py``) changed, with its
  old value and the other defaults kept (3 seeds, named ``<field>=<old value>``, found by
  comparing ``for_task`` with ``_study.BEFORE_SELECTION``): what each change is worth.
* ``round1-defaults`` of ``walk`` and ``jump`` and ``round1-iterations=30`` of ``walk``
  (5 seeds): the legged defaults of the selection run's first round, which its second
  round replaced (pinned: ``_study.ROUND_ONE_LEGGED``).
* The cells that ran before the selection run, on the options of that time
  (``BEFORE_SELECTION``, pinned so that their records stay reproducible) and named by
  their initial data and ``s*`` gains: ``home-default`` of each task (the defaults then,
  5 seeds); iiwa14 ``reference_pd-default`` (the arm's babbling before the faithful
  protocol); Solo12 ``walk`` and ``jump`` with babbling ``oracle`` (the reference
  controller, 4 rollouts at torque noise 0.3) and/or gains ``pilot_tuned`` (``kp = 100``,
  ``kd = 20`` on the base, ``joint_kp = 2000``, ``joint_kd = 50``), chosen then on pilots
  of the joint loss alone (3 seeds). Each of their records holds the ``config.json`` it
  ran (one seed's; every loss the same but ``loss``).

Outputs: the runs in ``--runs`` (``<task>/<cell>/``: what the sweep writes, one folder per
loss, checkpoints; an interrupted cell resumes from its checkpoints, so run the study in
pieces with ``--budget``), and in ``--out``:

* ``cells/<task>/<cell>/``: the record of each finished cell (its sweep's
  ``metrics.csv``, ``baselines.csv``, ``summary.md``, ``curves.png``, ``seconds.txt``,
  the wall time of each piece it ran in, and ``config.json``). The tables are made from
  these; a cell with a record is not run again, also from a fresh clone without the runs.

* ``summary.csv``: one row per (robot, task, cell, loss) of the finished cells (``label``
  says what the cell is): ``seeds``, ``final_mean``, ``final_std`` (over the seed means),
  ``ci_low``, ``ci_high``
  (95% percentile bootstrap over seeds, each seed averaged over its targets) of the task's
  tracking MSE at the last iteration; ``joint_minus``, ``joint_minus_low``,
  ``joint_minus_high`` (the paired comparison over seeds: joint minus this loss, negative =
  joint better); for walk and jump also ``force_mean``, ``force_ci_low``,
  ``force_ci_high`` (foot-force MSE, N^2), ``falls`` and ``runs`` (seed x target runs that
  fell at the last iteration, of all); ``seconds`` (the cell's wall time).
* ``who_wins.md``: per task and cell, each loss's mean and CI and which loss is lowest,
  with the paired interval of that loss against each other one (``clear``: every interval
  excludes 0).
* ``<task>.png``: each cell's final error per loss, mean and 95% CI (log scale).

Usage:
  python experiments/robustness_study.py                       # full size, hours
  python experiments/robustness_study.py --budget 3000         # a resumable piece
  python experiments/robustness_study.py --only walk --budget 0  # tables of finished cells
  python experiments/robustness_study.py --quick --runs /tmp/r --out /tmp/r  # smoke test
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os

import _study
import numpy as np
import pandas as pd

from cfm_jax import config as config_lib
from cfm_jax.analysis import report
from cfm_jax.learning import losses

BEFORE = _study.BEFORE_SELECTION
"""The options every task had before the selection run chose the defaults: the cells that
ran then pin them (``before(...)``), so their records stay reproducible."""

ORACLE_BABBLING = {
    "loop.babbling": "oracle",
    "loop.babbling_rollouts": 4,
    "loop.babbling_noise": 0.3,
}
"""The legged tasks' babbling before the faithful protocol: the reference controller, 4
rollouts per target at torque noise 0.3 (chosen on pilots of the joint loss)."""

PILOT_GAINS = {"task.kp": 100.0, "task.kd": 20.0, "task.joint_kp": 2000.0, "task.joint_kd": 50.0}
"""The legged ``s*`` gains chosen before on pilots of the joint loss alone."""

DEFAULTS = "defaults"
"""The name of each task's headline cell: the library's defaults."""


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell of the study: a robot and task, what differs from the task's defaults
    (``changes``: pairs of dotted config path and value, applied to
    :func:`cfm_jax.config.for_task`; none in the headline cell), the number of seeds.
    ``name`` is the cell's folder under ``cells/<task>/``, ``label`` what the tables say."""

    robot: str
    task: str
    name: str
    changes: tuple = ()
    seeds: int = 3
    label: str = ""
    before_selection: bool = False
    iterations: int | None = None
    """The cell's own number of iterations; None: the study's (``--iterations``)."""

    @property
    def default(self) -> bool:
        return self.name == DEFAULTS

    @property
    def path(self) -> str:
        return f"{self.task}/{self.name}"

    @property
    def tick(self) -> str:
        """A short name for a figure's axis."""
        return f"before:\n{self.name}" if self.before_selection else self.name.replace("=", "=\n")

    def config(self, iterations: int) -> config_lib.Config:
        """The cell's config: the task's defaults with ``changes``, run for the cell's own
        iterations when it has them, else ``iterations``."""
        config = _study.for_task(self.task, robot=self.robot)
        iterations = iterations if self.iterations is None else self.iterations
        return _study.with_changes(config, {**dict(self.changes), "loop.iterations": iterations})


def before(*groups: dict) -> tuple:
    """The options before the selection run with ``groups`` (dicts of dotted paths) on top."""
    changes = dict(BEFORE)
    for group in groups:
        changes.update(group)
    return tuple(changes.items())


def _value(config: config_lib.Config, path: str):
    section, field = path.split(".")
    return getattr(getattr(config, section), field)


def changed_factors(task: str) -> dict:
    """The options whose default the selection run changed for ``task``, with their old
    values (dotted path: value)."""
    config = _study.for_task(task)
    chosen = {p: v for p, v in BEFORE.items() if p not in _study.BEFORE_TORQUE_SCALING}
    return {p: v for p, v in chosen.items() if _value(config, p) != v}


def old_value_cells(task: str, robot: str) -> tuple:
    """One cell per default the selection run changed, with its old value (3 seeds), the
    other defaults kept: what each change is worth on the test motions. The two networks'
    fit starts (``forward.start``, ``controller.start``) are one factor, as in the
    selection run."""
    changed = changed_factors(task)
    starts = {p: changed.pop(p) for p in ("forward.start", "controller.start") if p in changed}
    groups = [{p: v} for p, v in changed.items()]
    if starts:
        groups.append({p: BEFORE[p] for p in ("forward.start", "controller.start")})
    cells = []
    for changes in groups:
        path, value = next(iter(changes.items()))
        name = f"{path.split('.')[1]}={value}"
        label = f"defaults with {name} (its value before the selection)"
        cells.append(Cell(robot, task, name, tuple(changes.items()), 3, label))
    return tuple(cells)


ROBOTS = _study.ROBOT
ROUND_ONE = _study.ROUND_ONE_LEGGED
_ON_ROUND_ONE = "the defaults of the selection's first round (before its second)"
_BEFORE = {"before_selection": True}
_ON_BEFORE = "before the selection run: "
CELLS = (
    # The headline cells (the library's defaults, 5 seeds), then one cell per default the
    # selection run changed with its old value, then the cells that ran before it (their
    # records keep the old folder names <babbling>-<gains>).
    *(Cell(ROBOTS[t], t, DEFAULTS, (), 5, "defaults") for t in ROBOTS),
    # The legged defaults at the authors' 30 iterations: in the selection run the walks'
    # falls kept dropping after iteration 10 (rigid_body cell: 9 to 10 of 12 runs per
    # model-based loss at iteration 10, 2 at 30).
    *(Cell(ROBOTS[t], t, "iterations=30", (), 5, "defaults, 30 iterations (the authors' count)",
           iterations=30)
      for t in ("walk", "jump")),
    *(c for t in ROBOTS for c in old_value_cells(t, ROBOTS[t])),
    # The legged cells that ran on the first selection round's defaults, before its second
    # round changed them (pinned: ``_study.ROUND_ONE_LEGGED``).
    *(Cell(ROBOTS[t], t, "round1-defaults", tuple(ROUND_ONE.items()), 5, _ON_ROUND_ONE)
      for t in ("walk", "jump")),
    Cell("solo12", "walk", "round1-iterations=30", tuple(ROUND_ONE.items()), 5,
         _ON_ROUND_ONE + ", 30 iterations", iterations=30),
    *(Cell(ROBOTS[t], t, "home-default", before(), 5, _ON_BEFORE + "its defaults", **_BEFORE)
      for t in ROBOTS),
    Cell("iiwa14", "inverse_dynamics", "reference_pd-default",
         before({"loop.babbling": "reference_pd"}), 3,
         _ON_BEFORE + "its defaults with reference_pd babbling", **_BEFORE),
    *(Cell("solo12", t, f"{b}-{g}", before(bb, gg), 3,
           f"{_ON_BEFORE}its defaults with {b} babbling, {g} gains", **_BEFORE)
      for t in ("walk", "jump")
      for b, bb, g, gg in (("oracle", ORACLE_BABBLING, "pilot_tuned", PILOT_GAINS),
                           ("home", {}, "pilot_tuned", PILOT_GAINS),
                           ("oracle", ORACLE_BABBLING, "default", {}))),
)  # fmt: skip


def find(task: str, name: str) -> Cell:
    """The cell of ``task`` named ``name`` (its folder name)."""
    for cell in CELLS:
        if (cell.task, cell.name) == (task, name):
            return cell
    names = [c.name for c in CELLS if c.task == task]
    raise KeyError(f"no cell {name!r} of task {task!r}; the cells are {names}")


TASK_ORDER = ("inverse_dynamics", "opspace", "walk", "jump")
UNITS = {
    "inverse_dynamics": "rad^2",
    "opspace": "m^2",
    "walk": "m^2 | rad^2",
    "jump": "m^2 | rad^2",
}


def run_dir(runs: str, cell: Cell) -> str:
    """Where a cell runs: the sweep's folder (large: checkpoints and data sets)."""
    return os.path.join(runs, cell.task, cell.name)


def record_dir(out: str, cell: Cell) -> str:
    """The small record of a finished cell next to the tables (``RECORD_FILES``): what the
    tables are made of, kept with them so that a fresh clone skips the cell."""
    return os.path.join(out, "cells", cell.task, cell.name)


RECORD_FILES = ("metrics.csv", "baselines.csv", "seconds.txt", "summary.md", "curves.png")


def keep_record(runs: str, out: str, cell: Cell) -> None:
    """Copy a finished run's ``RECORD_FILES`` to :func:`record_dir` (when it has them)."""
    _study.keep_record(run_dir(runs, cell), record_dir(out, cell), RECORD_FILES)


def finished(runs: str, out: str, cell: Cell) -> bool:
    """A cell is finished when its record exists, or its sweep wrote the tables of all its
    losses (then the record is made)."""
    if not _study.recorded(record_dir(out, cell)):
        keep_record(runs, out, cell)
    return _study.recorded(record_dir(out, cell))


def run_cell(cell: Cell, args) -> float:
    """Run (or resume) one cell; returns its wall time in seconds."""
    config = cell.config(args.iterations)
    seeds, losses_ = cell.seeds, "all"
    if args.quick:
        quick = _study.quick_config(config)
        config = quick.replace(loop=dataclasses.replace(quick.loop, iterations=1))
        seeds = 2
    os.makedirs(record_dir(args.out, cell), exist_ok=True)
    ran = config.replace(loop=dataclasses.replace(config.loop, seeds=seeds))
    with open(os.path.join(record_dir(args.out, cell), "config.json"), "w") as f:
        json.dump(config_lib.to_dict(ran), f, indent=1, sort_keys=True)
        f.write("\n")
    seconds = _study.timed_sweep(config, seeds, losses_, run_dir(args.runs, cell), args.quiet)
    keep_record(args.runs, args.out, cell)
    return seconds


def _seconds(out: str, cell: Cell) -> float:
    path = os.path.join(record_dir(out, cell), "seconds.txt")
    if not os.path.isfile(path):
        return float("nan")
    with open(path) as f:
        return float(sum(float(line) for line in f if line.strip()))


def cell_rows(out: str, cell: Cell) -> list[dict]:
    """The rows of ``summary.csv`` of a finished cell (from its record)."""
    metrics = pd.read_csv(os.path.join(record_dir(out, cell), "metrics.csv"))
    table = report.summary(metrics)
    paired = report.paired_table(metrics, "joint") if "joint" in set(metrics["loss"]) else None
    legged = cell.task in ("walk", "jump")
    forces = report.summary(metrics, column="force_mse") if legged else None
    final = metrics[metrics["iteration"] == metrics["iteration"].max()]
    rows = []
    for loss in [n for n in losses.CONTROLLER_LOSSES if n in table.index]:
        row = {
            "robot": cell.robot,
            "task": cell.task,
            "cell": cell.name,
            "label": cell.label,
            "loss": loss,
            "seeds": int(table.loc[loss, "seeds"]),
            "final_mean": float(table.loc[loss, "tracking_mse_mean"]),
            "final_std": float(table.loc[loss, "seed_std"]),
            "ci_low": float(table.loc[loss, "ci_low"]),
            "ci_high": float(table.loc[loss, "ci_high"]),
        }
        if paired is not None and loss in paired.index:
            row.update(
                joint_minus=float(paired.loc[loss, "mean_difference"]),
                joint_minus_low=float(paired.loc[loss, "ci_low"]),
                joint_minus_high=float(paired.loc[loss, "ci_high"]),
            )
        if legged:
            fell = final[final["loss"] == loss]["fell"]
            row.update(
                force_mean=float(forces.loc[loss, "force_mse_mean"]),
                force_ci_low=float(forces.loc[loss, "ci_low"]),
                force_ci_high=float(forces.loc[loss, "ci_high"]),
                falls=int(round(fell.sum())),
                runs=len(fell),
            )
        row["seconds"] = _seconds(out, cell)
        rows.append(row)
    return rows


def who_wins(out: str, cells, summary: pd.DataFrame) -> str:
    """The markdown "who wins where" tables, one per task."""
    lines = [
        "# Who wins where",
        "",
        "Final tracking MSE (last iteration) per loss: mean over seeds [95% percentile "
        "bootstrap CI over seeds, each seed averaged over its targets]. *Lowest*: the loss "
        "with the lowest mean; *paired*: that loss minus each other one over the same seeds, "
        "mean [95% CI] (negative: the lowest is better); *clear* when every paired interval "
        "excludes 0. Written by `experiments/robustness_study.py`.",
    ]
    for task in TASK_ORDER:
        task_cells = [c for c in cells if c.task == task]
        if not task_cells:
            continue
        names = list(losses.PAPER_LOSSES)
        lines += ["", f"## {task} ({task_cells[0].robot}; tracking MSE in {UNITS[task]})", ""]
        header = "| cell | seeds | " + " | ".join(names) + " | lowest | paired |"
        lines += [header, "|---|---:|" + "---|" * len(names) + "---|---|"]
        for cell in task_cells:
            rows = summary[(summary.task == task) & (summary.cell == cell.name)]
            label = f"{'**' if cell.default else ''}{cell.label}{'**' if cell.default else ''}"
            if rows.empty:
                lines.append(
                    f"| {label} | {cell.seeds} | "
                    + " | ".join("not run yet" for _ in names)
                    + " | | |"
                )
                continue
            rows = rows.set_index("loss")
            cells_text = []
            for name in names:
                if name not in rows.index:
                    cells_text.append("-")
                    continue
                r = rows.loc[name]
                text = report.ci_text({"mean": r.final_mean, "low": r.ci_low, "high": r.ci_high})
                if "falls" in r and not pd.isna(r.falls):
                    text += f"; falls {int(r.falls)}/{int(r.runs)}"
                cells_text.append(text)
            best = rows.final_mean.idxmin()
            metrics = pd.read_csv(os.path.join(record_dir(out, cell), "metrics.csv"))
            paired = report.paired_table(metrics, best)
            clear = bool(np.all(paired.ci_high < 0)) if len(paired) else False
            paired_text = "; ".join(
                "vs {}: {}".format(
                    loss,
                    report.ci_text({"mean": p.mean_difference, "low": p.ci_low, "high": p.ci_high}),
                )
                for loss, p in paired.iterrows()
            )
            lines.append(
                f"| {label} | {int(rows.seeds.iloc[0])} | "
                + " | ".join(cells_text)
                + f" | **{best}**{' (clear)' if clear else ''} | {paired_text} |"
            )
    return "\n".join(lines) + "\n"


def plot(summary: pd.DataFrame, task: str, path: str) -> str | None:
    """Each finished cell's final error per loss, mean and 95% CI, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frame = summary[summary.task == task]
    if frame.empty:
        return None
    groups = list(dict.fromkeys(frame.cell))
    names = list(losses.PAPER_LOSSES)
    fig, ax = plt.subplots(figsize=(3.0 + 1.9 * len(groups), 3.8))
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        rows = frame[frame.loss == name].set_index("cell")
        xs, ys, err = [], [], []
        for g, group in enumerate(groups):
            if group not in rows.index:
                continue
            r = rows.loc[group]
            xs.append(g + (k - (len(names) - 1) / 2) * width)
            ys.append(r.final_mean)
            err.append([r.final_mean - r.ci_low, r.ci_high - r.final_mean])
        if xs:
            ax.errorbar(
                xs, ys, yerr=np.asarray(err).T, fmt="o", capsize=3, label=name, markersize=4
            )
    ticks = {c.name: c.tick for c in CELLS if c.task == task}
    ax.set_xticks(range(len(groups)), [ticks.get(g, g) for g in groups])
    ax.set_yscale("log")
    ax.set_ylabel(f"final tracking MSE ({UNITS[task]})")
    ax.set_title(f"{task}\nmean and 95% bootstrap CI over seeds", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_outputs(runs: str, out: str, cells) -> pd.DataFrame:
    """``summary.csv``, ``who_wins.md`` and the figures of the finished cells."""
    os.makedirs(out, exist_ok=True)
    rows = [row for cell in cells if finished(runs, out, cell) for row in cell_rows(out, cell)]
    summary = pd.DataFrame(rows)
    columns = ["robot", "task", "cell", "label", "loss", "seeds", "final_mean", "final_std",
               "ci_low", "ci_high"]  # fmt: skip
    if summary.empty:
        summary = pd.DataFrame(columns=columns)
    summary.to_csv(os.path.join(out, "summary.csv"), index=False)
    with open(os.path.join(out, "who_wins.md"), "w") as f:
        f.write(who_wins(out, cells, summary))
    for task in TASK_ORDER:
        plot(summary, task, os.path.join(out, f"{task}.png"))
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", default="results/robustness", help="the runs (large)")
    parser.add_argument("--out", default="docs/results/robustness", help="tables, figures")
    parser.add_argument("--only", default=",".join(TASK_ORDER), help="comma-separated tasks")
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument(
        "--budget", type=float, default=float("inf"),
        help="seconds: start no further cell after this (a cell in flight finishes); the "
        "study resumes where it stopped when started again",
    )  # fmt: skip
    parser.add_argument(
        "--quick", action="store_true",
        help="tiny networks, 2 seeds, 1 iteration: a smoke test of the pipeline, no result",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    tasks = _study.tasks_of(parser, args.only, TASK_ORDER)
    cells = [c for c in CELLS if c.task in tasks]
    _study.run_cells(
        "robustness_study", cells, args, run_cell, finished,
        label=lambda cell: f"({cell.seeds} seeds)",
        after=lambda: write_outputs(args.runs, args.out, CELLS),
    )  # fmt: skip
    summary = write_outputs(args.runs, args.out, CELLS)
    done = sum(finished(args.runs, args.out, c) for c in cells)
    print(f"robustness_study: {done} of {len(cells)} cells finished; tables in {args.out}")
    if not summary.empty:
        print(open(os.path.join(args.out, "who_wins.md")).read())


if __name__ == "__main__":
    main()
