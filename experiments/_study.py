"""Shared pieces of the study scripts: the flags and the run through cfm_jax.sweep
(iiwa_inverse_dynamics.py), the --quick config (also opspace_study.py), and the section a
benchmark script writes into docs/benchmarks.md (sweep_benchmark.py, mjx_benchmark.py)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import time

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax.runs import sweeps

QUICK_LOSSES = "joint,task"

ROBOT = {"inverse_dynamics": "iiwa14", "opspace": "iiwa14", "walk": "solo12", "jump": "solo12"}
"""The robot of each task in the studies: the paper's."""

BEFORE_TORQUE_SCALING = {"loop.torque_scale": "limit", "loop.babbling_gains": "baseline"}
"""The arms' torque scaling and babbling gains before issue 41 made them robot-aware (every
record made before it ran on these; the legged defaults still are): pinned with
:data:`BEFORE_SELECTION`, not a choice of the selection run."""

BEFORE_SELECTION = {
    **BEFORE_TORQUE_SCALING,
    "loop.babbling": "home",
    "loop.normaliser": "babbling",
    "task.desired": "pd",
    "forward.kind": "mlp",
    "controller.goal": "desired",
    "controller.loss_form": "squared",
    "forward.start": "warm",
    "controller.start": "warm",
}
"""The options of every task before the selection run (``select_defaults.py``) chose the
defaults, as dotted config paths: the studies' cells that ran before it (and the selection
run's cells, which vary one option at a time from these) pin them, so that a cell's record
stays reproducible whatever the defaults become."""


ROUND_ONE_LEGGED = {
    **BEFORE_SELECTION,
    "loop.normaliser": "robot",
    "task.desired": "next_velocity",
    "forward.kind": "rigid_body",
    "forward.start": "warm_new_optimizer",
    "controller.start": "warm_new_optimizer",
}
"""The legged tasks' options chosen by the selection run's first round (the legged defaults
until its second round replaced them), as dotted config paths: the robustness cells that ran
on them pin them (``round1-*``), so that their records stay reproducible."""


BEFORE_POSE = {"loop.torque_scale": "coupled"}
"""The arms' torque scale before issue 64's decision made ``auto`` (pose where MJX builds the
robot) the default (docs/results/torque_scale_decision.md): every study record of an arm task
made before it ran on it, so :func:`for_task` pins it."""


BEFORE_PERIOD = {"task.oracle": "step"}
"""The arms' oracle before session 34 made ``period`` the default: every study record of an
arm task ran the one-step oracle, so :func:`for_task` pins it."""


BEFORE_WALK_FEEDBACK = {"task.joint_kp": None}
"""The walk's ``s*`` before session 35's selection check gave it joint position feedback
(``task.joint_kp``): every study record of the walk ran without it, so :func:`for_task`
pins it."""


def for_task(task: str, **changes) -> config_lib.Config:
    """:func:`cfm_jax.config.for_task` with the torque scale the studies' records were made
    on (:data:`BEFORE_POSE`) where the default would be ``auto``, their one-step oracle
    (:data:`BEFORE_PERIOD`) and the walk's ``s*`` without joint position feedback
    (:data:`BEFORE_WALK_FEEDBACK`): the claims', comparison's, robustness, selection, search
    and benchmark cells stay what they were."""
    config = config_lib.for_task(task, **changes)
    if config.task.oracle == "period":
        config = with_changes(config, BEFORE_PERIOD)
    if config.task.joint_kp is not None and config.task.desired == "next_velocity":
        config = with_changes(config, BEFORE_WALK_FEEDBACK)
    if config.loop.torque_scale != "auto":
        return config
    return with_changes(config, BEFORE_POSE)


def with_changes(config: config_lib.Config, changes) -> config_lib.Config:
    """``config`` with ``changes`` (a mapping or pairs of dotted path ``section.field`` and
    value, e.g. ``{"loop.babbling": "home"}``): the one cell of :func:`cfm_jax.runs.sweeps.grid`
    with those overrides, so paths and values are checked as a sweep checks them."""
    overrides = {path: [value] for path, value in dict(changes).items()}
    return sweeps.grid(config, overrides=overrides)[0].config


def parser(description: str, default_out: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--out", default=default_out)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--losses", default="all", help="'all' or a comma-separated list")
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"tiny networks and fit steps, 2 seeds, 1 iteration, losses {QUICK_LOSSES} "
        "(arm tasks: 0.3 s references): a smoke test of the pipeline, not a result",
    )
    parser.add_argument("--backend", default="local", choices=("local", "ray"))
    parser.add_argument("--address", default=None, help="ray: an existing cluster")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    return parser


def quick_config(config: config_lib.Config) -> config_lib.Config:
    """The same robot and task with 16-unit networks and a few dozen fit steps."""
    task = config.task
    if task.name in ("inverse_dynamics", "opspace"):
        task = dataclasses.replace(task, duration=0.3)
    return config.replace(
        task=task,
        forward=dataclasses.replace(
            config.forward,
            hidden=(16,),
            ensemble_size=min(2, config.forward.ensemble_size),
            initial_steps=20,
            steps_per_iteration=10,
            batch_size=32,
        ),
        controller=dataclasses.replace(
            config.controller,
            hidden=(16,),
            initial_steps=20,
            steps_per_iteration=10,
            batch_size=32,
        ),
        loop=dataclasses.replace(config.loop, babbling_rollouts=1),
    )


def run(config: config_lib.Config, args) -> tuple[cfm_jax.SweepResult, float, config_lib.Config]:
    """The sweep of ``config`` with the flags' seeds, iterations, losses and backend;
    returns the result, its wall time in seconds and the base config that ran."""
    seeds, iterations, losses = args.seeds, args.iterations, args.losses
    if args.quick:
        config = quick_config(config)
        seeds, iterations = 2, 1
        losses = QUICK_LOSSES if losses == "all" else losses
    config = config.replace(loop=dataclasses.replace(config.loop, iterations=iterations))
    names = "all" if losses == "all" else [s.strip() for s in losses.split(",") if s.strip()]
    start = time.perf_counter()
    result = cfm_jax.sweep(
        config,
        seeds=seeds,
        losses=names,
        out_dir=args.out,
        backend=args.backend,
        address=args.address,
        progress=not args.quiet,
    )
    return result, time.perf_counter() - start, config


def timed_sweep(config: config_lib.Config, seeds, losses, out_dir: str, quiet: bool) -> float:
    """:func:`cfm_jax.sweep` of ``config`` into ``out_dir`` (resumed where it stopped); the
    wall time of this piece is appended to ``out_dir/seconds.txt`` and returned."""
    start = time.perf_counter()
    cfm_jax.sweep(config, seeds=seeds, losses=losses, out_dir=out_dir, progress=not quiet)
    seconds = time.perf_counter() - start
    with open(os.path.join(out_dir, "seconds.txt"), "a") as f:
        f.write(f"{seconds:.1f}\n")
    return seconds


def cores() -> int:
    """The cores this process may run on (its CPU affinity; XLA's CPU pool has as many
    threads), or all of the machine's where the OS has no affinity (macOS)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else os.cpu_count() or 1


def tasks_of(parser: argparse.ArgumentParser, only: str, allowed) -> list[str]:
    """The tasks named by ``--only`` (comma-separated); a name not in ``allowed``, or none,
    is a usage error that names the flag, its value and the names allowed."""
    tasks = [t.strip() for t in only.split(",") if t.strip()]
    if not tasks or any(t not in allowed for t in tasks):
        parser.error(f"--only={only!r} is not allowed: names from {', '.join(allowed)}")
    return tasks


def run_cells(script: str, cells, args, run_cell, finished, label=None, after=None) -> bool:
    """Run the unfinished ``cells`` (any iterable) in order, ``run_cell(cell, args)`` each, until
    ``args.budget`` seconds have passed: a cell in flight finishes, and the next start resumes
    where this one stopped (``finished(args.runs, args.out, cell)`` skips the done cells).
    Each start and end is printed as ``script: task/name`` (``label(cell)`` adds to the
    start's line); ``after()`` runs after each cell (a study's tables). Returns whether the
    budget stopped the run."""
    start = time.perf_counter()
    for cell in cells:
        if finished(args.runs, args.out, cell):
            continue
        if time.perf_counter() - start >= args.budget:
            print(f"{script}: budget of {args.budget:.0f} s used; stopping", flush=True)
            return True
        name = f"{cell.task}/{cell.name}"
        print(f"{script}: {name}{' ' + label(cell) if label else ''}", flush=True)
        seconds = run_cell(cell, args)
        print(f"{script}: {name} done in {seconds:.0f} s", flush=True)
        if after is not None:
            after()
    return False


def keep_record(source: str, record: str, files) -> None:
    """Copy a finished run's ``files`` from ``source`` to its small record folder ``record``
    (when ``source`` has a ``metrics.csv``): what a study's tables are made of, kept with
    them so that a fresh clone skips the finished cell."""
    if not os.path.isfile(os.path.join(source, "metrics.csv")):
        return
    os.makedirs(record, exist_ok=True)
    for name in files:
        if os.path.isfile(os.path.join(source, name)):
            shutil.copyfile(os.path.join(source, name), os.path.join(record, name))


def recorded(record: str) -> bool:
    """Whether a record folder holds a finished cell (its ``metrics.csv``)."""
    return os.path.isfile(os.path.join(record, "metrics.csv"))


def write_benchmark_section(out: str, marker: str, section: str) -> None:
    """Write ``section`` to ``out`` and between ``<!-- marker -->`` and ``<!-- /marker -->``
    in docs/benchmarks.md (before "How the numbers are made" the first time), which
    experiments/benchmark.py keeps when it rewrites the page."""
    with open(out, "w") as f:
        f.write(section)
    doc = os.path.join(
        os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "benchmarks.md"
    )
    with open(doc) as f:
        text = f.read()
    begin, end = f"<!-- {marker} -->\n", f"<!-- /{marker} -->\n"
    block = begin + section + end
    if begin in text:
        text = re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda m: block, text, flags=re.S)
    else:
        text = text.replace("## How the numbers are made", block + "\n## How the numbers are made")
    with open(doc, "w") as f:
        f.write(text)
    print(f"wrote {out} and its section of {doc}")
