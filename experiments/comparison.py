"""The comparison of the four losses that the claims page rests on (issue 43): on each task's
test motions, 10 seeds, the losses under the library's shared defaults and each loss at its
own best (its configuration from the per-loss search, ``loss_search.py``).

The cells (:func:`cells`), per task (iiwa14 ``inverse_dynamics`` and ``opspace``, Solo12
``walk`` and ``jump``):

* ``shared``: the four losses in one sweep, the task's library defaults.
* ``own-<loss>``: that loss alone, the task's defaults with the values of its lowest-scoring
  search trial (``docs/results/loss_search/chosen_<task>.json``). The search ran on one task
  per family (``inverse_dynamics``, ``walk``; ``loss_search.SIZING``): ``opspace`` takes the
  arm's choice, ``jump`` the legged one. An own cell runs only once its loss's search has
  all its trials (``loss_search.TRIALS`` TPE trials with distinct values, then the
  shared-defaults trial: ``loss_search.AMENDMENT_DEFAULTS``), so that no test cell sees a
  half-finished search.

A shared cell reuses each finished own run of its task whose config is the shared cell's for
that loss (:func:`reuse_own_runs`; on the Solo12 the joint, task and distal losses chose the
shared defaults): a loss trained beside the others is the same computation as that loss
alone, bit for bit (``cfm_jax.train``; tests/test_train.py), so it would only repeat it.

Every cell: the seeds 10-29 in blocks of ``SEEDS`` (:data:`BLOCKS`: 10-19 ran for issue 43,
20-29 for issue 68's exact test; no selection used any of them: the first selection run used
0-2, the per-loss search 100-102), the test motions of ``cfm_jax.config.for_task``, the
iterations the search scored at (``loss_search.ITERATIONS``: 10 for the arm, 30 for the
legged tasks, the authors' count), so that a loss is tested at the budget it was chosen at.

Outputs: the runs in ``--runs`` (large: one sweep folder per cell; an interrupted cell
resumes from its checkpoints, so a piece may be killed at any time and started again), and
the record of each finished cell in ``--out/cells/<task>/<cell>/`` (``metrics.csv``,
``baselines.csv``, ``summary.md``, ``seconds.txt``: the wall time of each piece,
``config.json``: the config that ran, one seed's); a cell with a record is not run again,
also on a fresh clone. ``experiments/claims.py`` reads the records.

Usage (one core per process, ``CORES``; two processes on disjoint tasks side by side):
  taskset -c 0 python experiments/comparison.py --only inverse_dynamics --budget 3000
  taskset -c 1 python experiments/comparison.py --only walk --cells own
  taskset -c 1 python experiments/comparison.py --only walk --cells own --losses supervised
  python experiments/comparison.py --quick --runs /tmp/c --out /tmp/c  # smoke test
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys

import _study
import loss_search
import pandas as pd
import select_defaults

from cfm_jax import config as config_lib
from cfm_jax.learning import losses as losses_lib
from cfm_jax.runs import sweeps

TASKS = ("inverse_dynamics", "opspace", "walk", "jump")
SEEDS = 10
"""Seeds per block of a cell (one sweep of that many seeds)."""
FIRST_SEED = 10
"""The first block's seeds are 10-19: disjoint from every selection's (``select_defaults``:
0-2, ``loss_search.SEEDS``: 100-102)."""
BLOCKS = (10, 20)
"""The first seed of each block of ``SEEDS`` seeds: seeds 10-29, 20 per cell. Issue 68 sized
this from the claims page's exact paired test (``docs/results/claims_plan.md``, written
before the second block ran): with Holm over the primary family of 50 comparisons an exact
sign-flip test needs at least 11 seeds to reach its first level (2 / 2^n <= 0.05 / 50),
and 20 leave it room for a few seeds of the other sign. The first block (10-19) ran for
issue 43; each block is its own sweep, recorded apart (:func:`record_dir`)."""
ITERATIONS = loss_search.ITERATIONS
CORES = 1
"""Every cell runs in a process pinned to one core (``taskset -c N``), so that XLA's CPU pool
has one thread: jaxlib 0.10.x (this registry's newest) splits a large batched LAPACK call
(Cholesky, LU, triangular solve) over that pool and waits for the parts, and when as many such
calls run at once as the pool has threads, every thread waits and the process stalls for
good (the 10-seed inverse-dynamics cell did, twice, at its final evaluation, with two
threads; jaxlib 0.11.1 removed that path). A pool of one runs the parts inline. The thread
count also changes the numbers (XLA's matrix products split their work by it), so all cells
share one; two pinned processes side by side (``--only``) use both cores."""
SIZING = (
    "Sized before the first cell from the robustness study's records (5 seeds, the four "
    "losses in one sweep, 2 cores): inverse dynamics 1247 s and op-space 2229 s at 10 "
    "iterations, walk 2453 s and jump 2654 s at 30. Twice the seeds: a shared cell about "
    "2500, 4500, 4900 and 5300 s (4.8 h); the own cells, one loss each with its own babbling "
    "and initial fit, about as much again: about 10 h of 2-core time, in pieces of a "
    "session, two processes side by side (--only) where the cores allow. The first cell "
    "run (inverse dynamics, shared) checks the estimate; its seconds.txt is its record."
)
SHARED = "shared"
ROOT = loss_search.ROOT
SEARCH_OUT = os.path.join(ROOT, "docs", "results", "loss_search")


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell: a task, its losses (all four, or one at its own configuration) and the
    ``changes`` to the task's defaults (dotted config paths)."""

    task: str
    name: str
    losses: tuple
    changes: tuple = ()
    first_seed: int = FIRST_SEED

    @property
    def own(self) -> bool:
        return self.name != SHARED

    @property
    def folder(self) -> str:
        """The cell's folder under its task: its name for the first block, ``<name>/seeds-
        <first>-<last>`` for a later block (:data:`BLOCKS`)."""
        if self.first_seed == FIRST_SEED:
            return self.name
        return f"{self.name}/seeds-{self.first_seed}-{self.first_seed + SEEDS - 1}"

    def block(self, first_seed: int) -> Cell:
        """The same cell on the block of seeds that starts at ``first_seed``."""
        return dataclasses.replace(self, first_seed=first_seed)

    def config(self, seeds: int = SEEDS, quick: bool = False) -> config_lib.Config:
        """The cell's config: the task's defaults with ``changes``, its iterations and seeds
        (``first_seed`` first)."""
        config = _study.for_task(self.task, robot=_study.ROBOT[self.task])
        changes = {**dict(self.changes), "loop.iterations": ITERATIONS[self.task]}
        config = _study.with_changes(config, changes)
        if quick:
            config = _study.quick_config(config)
            config = config.replace(loop=dataclasses.replace(config.loop, iterations=1))
        return config.replace(seed=self.first_seed,
                              loop=dataclasses.replace(config.loop, seeds=seeds))  # fmt: skip


def searched_on(task: str) -> str:
    """The task whose per-loss search chose ``task``'s own configurations."""
    return select_defaults.SELECTED_ON[select_defaults.family(task)]


def own_changes(task: str, loss: str, search_out: str = SEARCH_OUT) -> tuple | None:
    """``loss``'s chosen values for ``task`` as (dotted path, value) pairs, or None while its
    search (on :func:`searched_on` ``task``) lacks trials (:func:`loss_search.complete`:
    ``loss_search.TRIALS`` TPE trials with distinct values and the shared-defaults trial)."""
    searched = searched_on(task)
    path = os.path.join(search_out, f"trials_{searched}.csv")
    if not os.path.isfile(path):
        return None
    trials = pd.read_csv(path)
    if not loss_search.complete(trials, searched, loss):
        return None
    best = loss_search.chosen(trials)[searched][loss]
    with open(os.path.join(search_out, f"chosen_{searched}.json")) as f:
        if json.load(f)["chosen"][searched][loss] != best:
            raise RuntimeError(f"chosen_{searched}.json disagrees with trials_{searched}.csv "
                               f"for {loss}: run loss_search.py to rewrite them")  # fmt: skip
    changes = {}
    for name, (dotted, _) in loss_search.space(searched).items():
        for one in select_defaults.factor_paths(dotted):
            changes[one] = best[name]
    return tuple(sorted(changes.items()))


def cells(tasks=TASKS, search_out: str = SEARCH_OUT, blocks=BLOCKS) -> list[Cell]:
    """Per block of seeds (:data:`BLOCKS`): the shared cell of each task, then the own cells
    whose search is complete; a later block runs a task's own cells before its shared cell
    (which then reuses the own runs of its config, :func:`reuse_own_runs`)."""
    out = []
    for first in blocks:
        own = {t: [Cell(t, f"own-{loss}", (loss,), changes, first)
                   for loss in losses_lib.PAPER_LOSSES
                   if (changes := own_changes(t, loss, search_out)) is not None]
               for t in tasks}  # fmt: skip
        shared = [Cell(t, SHARED, losses_lib.PAPER_LOSSES, (), first) for t in tasks]
        if first == FIRST_SEED:  # the order issue 43 ran its cells in
            out += shared + [c for t in tasks for c in own[t]]
        else:
            out += [c for t, s in zip(tasks, shared, strict=True) for c in (*own[t], s)]
    return out


def pending(tasks=TASKS, search_out: str = SEARCH_OUT) -> list[str]:
    """The own cells that wait for their search, as ``task/own-loss``."""
    return [f"{t}/own-{loss}" for t in tasks for loss in losses_lib.PAPER_LOSSES
            if own_changes(t, loss, search_out) is None]  # fmt: skip


def run_dir(runs: str, cell: Cell) -> str:
    """The cell's sweep folder (large; not committed)."""
    return os.path.join(runs, cell.task, cell.folder)


def record_dir(out: str, cell: Cell) -> str:
    """The cell's record folder (committed): ``out/cells/<task>/<folder>``."""
    return os.path.join(out, "cells", cell.task, cell.folder)


def finished(runs: str, out: str, cell: Cell) -> bool:
    """Whether ``cell`` has a record (kept from its finished sweep if it has none yet)."""
    if not _study.recorded(record_dir(out, cell)):
        _study.keep_record(run_dir(runs, cell), record_dir(out, cell),
                           select_defaults.RECORD_FILES)  # fmt: skip
    return _study.recorded(record_dir(out, cell))


def run_cell(cell: Cell, args) -> float:
    """Run (or resume) one cell; its wall time in seconds."""
    seeds = 2 if args.quick else SEEDS
    cores = _study.cores()
    if cores != CORES and not args.quick:
        raise SystemExit(f"comparison: this process may run on {cores} cores; every cell runs "
                         f"on {CORES} (CORES): start it as taskset -c 0 python "
                         "experiments/comparison.py ...")  # fmt: skip
    config = cell.config(seeds, args.quick)
    os.makedirs(record_dir(args.out, cell), exist_ok=True)
    with open(os.path.join(record_dir(args.out, cell), "config.json"), "w") as f:
        json.dump(config_lib.to_dict(config), f, indent=1, sort_keys=True)
        f.write("\n")
    base = config.replace(loop=dataclasses.replace(config.loop, seeds=1))
    if not cell.own:
        ids = [c.id for c in sweeps.grid(base, seeds=seeds, losses=list(cell.losses))]
        reused = reuse_own_runs(cell, args.runs, ids)
        if reused and not args.quiet:
            print(f"comparison: {cell.task}/{cell.name} reuses the finished own runs of "
                  f"{', '.join(reused)} (the same configs)", flush=True)  # fmt: skip
    seconds = _study.timed_sweep(base, seeds, list(cell.losses), run_dir(args.runs, cell),
                                 args.quiet)  # fmt: skip
    finished(args.runs, args.out, cell)
    return seconds


def selected(found, which: str, losses) -> list[Cell]:
    """The cells of ``found`` that ``--cells which`` (all, shared, own) and ``--losses``
    (the own cells of these losses; the shared cell has all four) select."""
    return [c for c in found
            if (which == "all" or (which == "own") == c.own)
            and (not c.own or c.losses[0] in losses)]  # fmt: skip


def reuse_own_runs(cell: Cell, runs: str, ids) -> list[str]:
    """The losses of the shared ``cell`` whose own cell's sweep holds a finished run of the
    same config, a cell of one of the shared sweep's ``ids`` (``cfm_jax.runs.sweeps.cell_id``:
    ``<loss>-<hash of the whole config>``), copied now into the shared cell's sweep folder.
    The sweep loads them as finished (their ``seconds`` those of the own runs) and trains only
    the other losses. A loss trained beside the others is the same computation as that loss
    alone, bit for bit (``cfm_jax.train``, tests/test_train.py), so training it again would
    only repeat it; the copy is of the own run's files, not of its checkpoints."""
    reused = []
    shared_cells = os.path.join(run_dir(runs, cell), "cells")
    for loss in cell.losses:
        own = Cell(cell.task, f"own-{loss}", (loss,), (), cell.first_seed)
        own_cells = os.path.join(run_dir(runs, own), "cells")
        if not os.path.isdir(own_cells):
            continue
        for name in sorted(set(os.listdir(own_cells)) & set(ids)):
            source, target = os.path.join(own_cells, name), os.path.join(shared_cells, name)
            if not all(os.path.isfile(os.path.join(source, f)) for f in _CELL_FILES):
                continue  # not finished
            if os.path.isfile(os.path.join(target, "metrics.csv")):
                continue  # finished there already
            os.makedirs(target, exist_ok=True)
            for f in _CELL_FILES:  # metrics.csv last: it marks the cell finished
                shutil.copyfile(os.path.join(source, f), os.path.join(target, f))
            reused.append(loss)
    return reused


_CELL_FILES = ("config.json", "cell.json", "baselines.csv", "metrics.csv")
"""A finished sweep cell's files (``cfm_jax.runs.sweeps``), in the order they are written."""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", default=os.path.join(ROOT, "results", "comparison"))
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "results", "comparison"))
    parser.add_argument("--search", default=SEARCH_OUT, help="the per-loss search's records")
    parser.add_argument("--only", default=",".join(TASKS), help="comma-separated tasks")
    parser.add_argument("--cells", default="all", choices=("all", "shared", "own"))
    parser.add_argument("--losses", default=",".join(losses_lib.PAPER_LOSSES),
                        help="comma-separated: the own cells of these losses only (two "
                             "processes on one task's own cells side by side)")  # fmt: skip
    parser.add_argument("--blocks", default=",".join(map(str, BLOCKS)),
                        help="comma-separated first seeds: the blocks of seeds to run "
                             f"(each {SEEDS} seeds; default: all, {BLOCKS})")  # fmt: skip
    parser.add_argument("--budget", type=float, default=float("inf"),
                        help="seconds: start no further cell after this (a piece)")  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="tiny networks, 2 seeds, 1 it.")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    tasks = _study.tasks_of(parser, args.only, TASKS)
    losses = [n.strip() for n in args.losses.split(",") if n.strip()]
    if not losses or set(losses) - set(losses_lib.PAPER_LOSSES):
        parser.error(f"--losses={args.losses!r} is not allowed: names from "
                     f"{', '.join(losses_lib.PAPER_LOSSES)}")  # fmt: skip
    try:
        blocks = [int(b) for b in args.blocks.split(",") if b.strip()]
    except ValueError:
        blocks = []
    if not blocks or set(blocks) - set(BLOCKS):
        parser.error(f"--blocks={args.blocks!r} is not allowed: first seeds from {BLOCKS}")
    todo = selected(cells(tasks, args.search, blocks), args.cells, losses)
    _study.run_cells("comparison", todo, args, run_cell, finished,
                     label=lambda cell: f"({', '.join(cell.losses)})")  # fmt: skip
    done = sum(finished(args.runs, args.out, c) for c in todo)
    print(f"comparison: {done} of {len(todo)} cells finished; records in {args.out}")
    waiting = pending(tasks, args.search) if args.cells != "shared" else []
    if waiting:
        print(f"comparison: waiting for their search: {', '.join(waiting)}")


if __name__ == "__main__":
    sys.exit(main())
