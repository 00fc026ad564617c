"""Choosing the defaults fairly: every option of the learner compared with all four losses
alike, on motions that are not the test motions, by a rule written before the run.

The rule (``RULE``, also on the page this script writes) is fixed before any cell runs:

* A run is one (loss, seed, target) at the last iteration. Its score is
  ``log10(final tracking MSE)``; a run that fell (legged tasks) or diverged (its simulation
  blew up), or whose error is not finite, is a failure and scores
  ``log10(1000 x PD-only MSE on that target)`` or its own score if that is higher: a
  failure is never better than tracking 1000 times worse than the plain PD baseline.
* A cell's score is the mean over the four losses (``joint``, ``task``, ``distal``,
  ``supervised``) of the mean over seeds of the mean over targets. Every loss weighs the
  same; no option is chosen on runs of one loss.
* Factors are varied one at a time from a stated base (``BASE``; a full grid does not fit,
  see ``SIZING``), on one task per family (``SELECTED_ON``: inverse dynamics for the arm,
  walking for the legged robot); the other task of the family takes its family's choice,
  and the headline rerun shows it there with each changed factor's old value. For each
  factor the value whose cell has the lowest score is the default; the paired difference
  to the base cell over seeds (mean over losses) is given with its 95% bootstrap interval,
  and called *clear* when the interval excludes 0.

After the factors, each task's ``chosen_together`` cell runs every chosen value in one
config on the same motions, a check that choices made one factor at a time also work
together (``TOGETHER``); it chooses nothing. Where it failed (walk), a second round
(``SECOND_ROUND``, ``ROUND_TWO``) applies the same rule from round 1's best cell to the
factors in which that cell and ``chosen_together`` differ; its choices replace round 1's
for those factors (``CHOSEN``: the family's defaults).

A task the factors are not chosen on may have a check of its own (``TASK_CHECKS``,
``TASK_CHECK``): named factors varied, by the same rule, from its family's defaults on its own
selection motions (``defaults_cell``); a value the rule picks there overrides the family's for
that task only (``TASK_CHOSEN``).

The motions: the arm tasks reach the five targets of
``references.default_targets(..., seed=references.SELECTION_SEED)`` (joint space) or the
end-effector positions of those poses (op-space), never a test target; the legged tasks
follow walks of ``SELECTION_WALKS`` seconds and jumps of ``SELECTION_JUMPS`` m, never a
test reference (``locomotion.WALK_DURATIONS`` / ``JUMP_HEIGHTS``).

Outputs: the runs in ``--runs`` (one :func:`cfm_jax.sweep` folder per cell, resumable) and,
in ``--out``, each finished cell's record (``cells/<task>/<cell>/``: ``metrics.csv``,
``baselines.csv``, ``seconds.txt``, ``config.json``), ``selection.csv`` (one row per task,
cell and loss), ``curves.csv`` (the score per iteration) and ``index.md`` (the tables).

Usage:
  python experiments/select_defaults.py --budget 3000            # a resumable piece
  python experiments/select_defaults.py --only walk --budget 0   # tables of finished cells
  python experiments/select_defaults.py --only opspace           # op-space's own check
  python experiments/select_defaults.py --quick --runs /tmp/s --out /tmp/s  # smoke test
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
from cfm_jax.sim import robots
from cfm_jax.tasks import references

RULE = (
    "Score of a run (loss, seed, target at the last iteration): log10 of its final tracking "
    "MSE; a run that fell or diverged, or whose error is not finite, scores "
    "log10(1000 x the PD-only MSE on that target), or its own score if higher. Score of a "
    "cell: mean over the four losses of the mean over seeds of the mean over targets. Per "
    "factor, the value with the lowest cell score is the default; its paired difference to "
    "the base over seeds (mean over losses), 95% bootstrap CI, is *clear* when the interval "
    "excludes 0. Written before the run; all losses alike; motions other than the test ones."
)
FAILURE_FACTOR = 1000.0

SELECTION_WALKS = (1.25, 1.75, 2.25, 2.75)
"""Walk durations (s) of the selection: none of them a test horizon (1.0 ... 3.0 by 0.5)."""
SELECTION_JUMPS = (0.065, 0.095, 0.125, 0.155)
"""Jump foot clearances (m) of the selection: none of them a test height (0.05 ... 0.17)."""

SIZING = (
    "Measured first cells (3 seeds, on 2 CPU cores shared with other work): inverse "
    "dynamics base 1187 s (10 iterations), walk base 3069 s (30 iterations). The "
    "one-factor-at-a-time plan has 9 cells per task: about 3 h per arm task and 5 to 8 h "
    "per legged task, 16 to 22 h for all four. The factors are therefore varied on one task "
    "per family (inverse dynamics and walk), and op-space and jumping take their family's "
    "choice; decided before any factor cell ran, on the cost alone."
)
TOGETHER = (
    "The last cell of each task's first round, `chosen_together`, runs every chosen value in "
    "one config (round 1's choices) on the same motions: a check that the choices, made one factor "
    "at a time, also work together; it chooses nothing. Added after the rule had chosen, "
    "when the headline walk cells on the defaults (test motions) fell more often than this "
    "run's single-factor walk cells."
)
ROUND_TWO = (
    "Written after `chosen_together` failed on the walk and before any round-2 cell ran. "
    "Round 1's best walk cell (`forward_model=rigid_body`, score -2.338, 13/48 failed) and "
    "`chosen_together` (-0.431, 41/48) differ only in the factors whose round-1 choice was not "
    "the round-2 base's and left the base's value: the normaliser (`robot`) and the fit start "
    "(`warm_new_optimizer`). Round 2 applies the same rule to these factors from "
    "`forward_model=rigid_body`, on the same motions, seeds and iterations, all losses alike: "
    "normaliser `data` (the round-2 base) / `babbling` / `robot`, fit start `warm` (the base) "
    "/ `warm_new_optimizer`; `fresh` is not rerun (all 48 runs of its round-1 cell failed). "
    "The factors whose round-1 choice was the base's value stay at it (they are the same in "
    "both cells). Its choices replace round 1's for these two factors; if both leave the "
    "round-2 base, a round-2 `chosen_together` checks them together."
)
TASK_CHECK = (
    "Written after the headline op-space cell on the defaults (robustness study, test "
    "targets) missed its goal (seed 3 of 5: no loss below PD-only), and before any op-space "
    "selection cell ran. The factors were chosen on inverse dynamics only (Sizing), and the "
    "op-space robustness cells point at the initial data (`babbling=home`, 3 seeds: joint and "
    "supervised below PD-only in 15/15 runs). So op-space checks that one factor, and only "
    "it: both values run from the arm's defaults (the base: `chosen_together`, the family's "
    "choices on op-space's selection targets, the end-effector positions of the selection "
    "poses), same seeds, iterations and rule, all losses alike. If `home` scores lower, "
    "op-space's default babbling becomes `home` (for op-space only; inverse dynamics keeps "
    "its own choice) and the headline op-space cell is rerun; otherwise nothing changes."
)
WALK_CHECK = (
    "Written on 2026-11-29, after the diagnosis of the walk's falls (docs/locomotion.md, \"Why "
    'the learned walks fall": the data ended at the first fall, so the walk was learnt one '
    "stretch at a time) and before any cell of this check ran. The library gained one option "
    "for it, `loop.restart_on_terminal` (each iteration's data from a rollout that starts again "
    "from the reference after each fall; the metrics stay those of the rollout without "
    "restarts). The walk checks that one factor, and only it: both values from the family's "
    "defaults (the base: the defaults cell of round 2, already run), on the walk's selection "
    "motions, same seeds, iterations and rule, all losses alike. If `True` scores lower, the "
    "walk's default becomes `True` (the walk only: the jump's learned controllers do not "
    "fall) and the headline walk cells are rerun; otherwise nothing changes."
)
WALK_FEEDBACK_CHECK = (
    "Second check, written on 2026-12-01 before its cell ran. The restart check did not move "
    "the defaults, and the learned walks still fall (shared defaults, 20 seeds of the test "
    "walks: failed runs joint 22/100, task 10/100, distal 20/100, supervised 50/100). At a "
    "fall the states lie off the reference where the data has barely been (docs/locomotion.md). "
    "The authors' `s*` asks for the reference's next velocity only, so a joint position error "
    "a learned controller makes is never asked back; PD-only, with position feedback, falls "
    "in no walk. The check adds joint position feedback to `s*` "
    "(`task.joint_kp`: `s* = v_ref(t+1) - v(t) + control_dt joint_kp (q_ref - q)` on the "
    "joints, the base as before), one value fixed before any run: 1000/s^2, a position-error "
    "time constant of 1 / (joint_kp control_dt) = 0.25 s, about one gait cycle, and a third of "
    "the Solo12 reference PD's stiffness per joint inertia at home (mean 3032/s^2). A pilot "
    "of that value alone (1 seed, 10 iterations, the four losses, these selection walks) "
    "fell in 3 of 16 walks at iteration 10, against 12 of 16 for the defaults cell's seed 0: "
    "reason enough to run the check, not a result. The check runs it from the family's "
    "defaults, same seeds, iterations, motions and rule, all losses alike. If it scores "
    "lower, the walk's default becomes `joint_kp=1000` (the walk only) and the walk's "
    "headline cells are rerun; otherwise nothing changes."
)
CHECK_TEXTS = {"opspace": TASK_CHECK, "walk": WALK_CHECK + "\n\n" + WALK_FEEDBACK_CHECK}
"""Per task with its own check: why it runs and what it decides, written before it ran."""
ARM = ("inverse_dynamics", "opspace")
LEGGED = ("walk", "jump")
SELECTED_ON = {"arm": "inverse_dynamics", "legged": "walk"}
"""The task on which each family's factors are chosen (see ``SIZING``)."""
TASK_CHECKS = {
    "opspace": (("babbling", "loop.babbling", ("reaching", "home")),),
    "walk": (
        ("restart after a fall", "loop.restart_on_terminal", (False, True)),
        ("joint position feedback in s*", "task.joint_kp", (None, 1000.0)),
    ),
}
"""Per task the factors are not chosen on: factors checked on it from its family's defaults
(``CHECK_TEXTS``; on a task the factors are chosen on, after its rounds), the defaults'
value first."""
ROBOT = _study.ROBOT
ITERATIONS = {"inverse_dynamics": 10, "opspace": 10, "walk": 30, "jump": 30}
SEEDS = 3

# The base every factor is varied from, per task family, and the factors: (name, dotted
# config path, values). The base's value of each factor comes first.
BASE = {
    "arm": {"loop.normaliser": "data", "loop.babbling": "reaching"},
    "legged": {"loop.normaliser": "data", "task.desired": "next_velocity"},
}
FACTORS = {
    "arm": (
        ("normaliser", "loop.normaliser", ("data", "babbling", "robot")),
        ("babbling", "loop.babbling", ("reaching", "home")),
        ("forward model", "forward.kind", ("mlp", "rigid_body")),
        ("controller goal", "controller.goal", ("desired", "observed")),
        ("loss form", "controller.loss_form", ("squared", "norm")),
        ("fit start", "forward+controller.start", ("warm", "warm_new_optimizer", "fresh")),
    ),
    "legged": (
        ("normaliser", "loop.normaliser", ("data", "babbling", "robot")),
        ("s*", "task.desired", ("next_velocity", "pd")),
        ("forward model", "forward.kind", ("mlp", "rigid_body")),
        ("controller goal", "controller.goal", ("desired", "observed")),
        ("loss form", "controller.loss_form", ("squared", "norm")),
        ("fit start", "forward+controller.start", ("warm", "warm_new_optimizer", "fresh")),
    ),
}


SECOND_ROUND = {
    "legged": {
        "from": ("forward model", "rigid_body"),
        "factors": (
            ("fit start", "forward+controller.start", ("warm", "warm_new_optimizer")),
            ("normaliser", "loop.normaliser", ("data", "robot", "babbling")),
        ),
    },
}
"""Per family with a second round (``ROUND_TWO``): the round-1 cell it starts from (factor,
value) and its factors, the round-2 base's value first."""


ROUND_ONE_CHOSEN = {
    "arm": {"loop.normaliser": "babbling", "controller.loss_form": "norm"},
    "legged": {
        "loop.normaliser": "robot",
        "forward.kind": "rigid_body",
        "forward.start": "warm_new_optimizer",
        "controller.start": "warm_new_optimizer",
    },
}
"""What round 1 chose per family where it left the base's value (a test recomputes it from
the records): round 1's ``chosen_together`` cell runs them in one config."""

ROUND_TWO_MOVED = {"legged": ("fit start",)}
"""Per family: the second round's factors whose choice left the round-2 base's value (set
from the round-2 records by hand, checked by a test); a round-2 ``together`` cell runs when
there is more than one."""

CHOSEN = {
    "arm": ROUND_ONE_CHOSEN["arm"],
    "legged": {
        "forward.kind": "rigid_body",
        "forward.start": "warm_new_optimizer",
        "controller.start": "warm_new_optimizer",
    },
}
"""The family's defaults where they are not the base's value: round 1's choices, with a
second round's (``SECOND_ROUND``) in place of round 1's for its factors. A test recomputes
them from the records and checks that ``config.for_task`` gives the base with these."""

TASK_CHOSEN: dict[str, dict] = {"walk": {"task.joint_kp": 1000.0}}
"""Per task with a check (``TASK_CHECKS``): the values its check chose where they left the
family's defaults (set from the records by hand, checked by a test); ``config.for_task``
gives them in place of ``CHOSEN``'s for that task only (the same test checks it)."""


def family(task: str) -> str:
    return "legged" if task in LEGGED else "arm"


def factor_paths(path: str) -> list[str]:
    """The dotted config paths a factor's path sets: ``forward+controller.<field>`` is both
    networks' field (one factor), any other path itself."""
    if path.startswith("forward+controller."):
        field = path.split(".", 1)[1]
        return [f"forward.{field}", f"controller.{field}"]
    return [path]


def _factor_path(factors, name: str) -> str:
    """The config path of factor ``name`` (of ``factors``)."""
    return next(p for n, p, _ in factors if n == name)


def _factor_values(factors, name: str, value: str) -> dict:
    """The dotted-path values that set factor ``name`` (of ``factors``) to ``value``."""
    return dict.fromkeys(factor_paths(_factor_path(factors, name)), value)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell: a task, and the factor changed from the base (None: the base itself), or
    (``together``) every factor at its chosen value: a check that the choices made one at a
    time also work together; it chooses nothing. ``round=2``: a cell of the second round
    (``SECOND_ROUND``), whose base is a round-1 cell; its ``together`` runs :data:`CHOSEN`.
    ``check``: a factor of the task's own check (``TASK_CHECKS``), changed from the family's
    defaults (:data:`CHOSEN`)."""

    task: str
    factor: str | None = None
    value: str | None = None
    together: bool = False
    round: int = 1
    check: bool = False

    @property
    def name(self) -> str:
        prefix = "check_" if self.check else "" if self.round == 1 else f"round{self.round}_"
        if self.together:
            return prefix + "chosen_together"
        if self.factor is None:
            return "base"
        return prefix + f"{self.factor.replace(' ', '_').replace('*', 'star')}={self.value}"

    def changes(self) -> dict:
        """The dotted-path values of this cell: the options before the selection
        (``_study.BEFORE_SELECTION``, so that the cell stays what it was when the defaults
        change), the base's, then (round 2) the round-2 base's factor, then the factor's."""
        fam = family(self.task)
        values = {**_study.BEFORE_SELECTION, **BASE[fam]}
        if self.check:
            values.update(CHOSEN[fam])
            values.update(_factor_values(TASK_CHECKS[self.task], self.factor, self.value))
            return values
        if self.together:
            values.update((ROUND_ONE_CHOSEN if self.round == 1 else CHOSEN)[fam])
            return values
        factors = FACTORS[fam]
        if self.round == 2:
            values.update(_factor_values(FACTORS[fam], *SECOND_ROUND[fam]["from"]))
            factors = SECOND_ROUND[fam]["factors"]
        if self.factor is not None:
            values.update(_factor_values(factors, self.factor, self.value))
        return values

    def config(self, iterations: int | None = None) -> config_lib.Config:
        task = self.task
        config = _study.for_task(task, robot=ROBOT[task])
        changes = {
            "loop.iterations": ITERATIONS[task] if iterations is None else iterations,
            **self.changes(),
            **{f"task.{k}": v for k, v in selection_motions(task, config).items()},
        }
        return _study.with_changes(config, changes)


def selection_motions(task: str, config: config_lib.Config) -> dict:
    """The task fields that put a config on the selection's motions."""
    if task == "walk":
        return {"motions": SELECTION_WALKS}
    if task == "jump":
        return {"motions": SELECTION_JUMPS}
    robot = robots.load(config.robot)
    home = robot.home if config.task.home is None else np.asarray(config.task.home)
    if task == "inverse_dynamics":
        targets = references.driven_targets(robot, home, references.SELECTION_SEED)
    else:
        targets = references.default_cartesian_targets(
            robot, config.task.site, home, references.SELECTION_SEED
        )
    return {"targets": tuple(tuple(float(x) for x in t) for t in targets)}


def round_two_base(task: str) -> Cell | None:
    """The round-1 cell a second round starts from (None: the family has no second round)."""
    second = SECOND_ROUND.get(family(task))
    return None if second is None else Cell(task, *second["from"])


def round_two_cells(task: str) -> list[Cell]:
    """The second round's factor cells (its base is :func:`round_two_base`), then its
    ``together`` cell when its choices leave the round-2 base in more than one factor."""
    second = SECOND_ROUND.get(family(task))
    if second is None:
        return []
    cells = [Cell(task, n, v, round=2) for n, _, values in second["factors"] for v in values[1:]]
    moved = ROUND_TWO_MOVED.get(family(task), ())
    return cells + ([Cell(task, together=True, round=2)] if len(moved) > 1 else [])


def defaults_cell(task: str) -> Cell:
    """The cell whose config is the family's defaults (:data:`CHOSEN`) on the selection's
    motions: round 1's ``chosen_together``, or with a second round its ``together`` cell,
    the cell of its one moved factor, or its base when none moved."""
    second = SECOND_ROUND.get(family(task))
    if second is None:
        return Cell(task, together=True)
    moved = ROUND_TWO_MOVED.get(family(task), ())
    if len(moved) > 1:
        return Cell(task, together=True, round=2)
    if not moved:
        return round_two_base(task)
    # A moved factor left the round-2 base's value: CHOSEN holds its value.
    path = factor_paths(_factor_path(second["factors"], moved[0]))[0]
    return Cell(task, moved[0], CHOSEN[family(task)][path], round=2)


def check_cells(task: str) -> list[Cell]:
    """The cells of ``task``'s own check (``TASK_CHECKS``; none without one): each checked
    factor's other values, from the family's defaults."""
    return [Cell(task, n, v, check=True)
            for n, _, values in TASK_CHECKS.get(task, ()) for v in values[1:]]  # fmt: skip


def cells_of(task: str) -> list[Cell]:
    """The cells this script runs for ``task``. On a task the factors are chosen on: the
    base, then each factor's other values (one at a time), then the chosen values together;
    then the second round's cells, if the family has one. On another task: its check, if it
    has one (the family's defaults, :func:`defaults_cell`, then :func:`check_cells`)."""
    if task != SELECTED_ON[family(task)]:
        checks = check_cells(task)
        return [defaults_cell(task)] + checks if checks else []
    cells = [Cell(task)]
    for name, _, values in FACTORS[family(task)]:
        cells += [Cell(task, name, v) for v in values[1:]]
    return cells + [Cell(task, together=True)] + round_two_cells(task) + check_cells(task)


def run_dir(runs: str, cell: Cell) -> str:
    return os.path.join(runs, cell.task, cell.name)


def record_dir(out: str, cell: Cell) -> str:
    return os.path.join(out, "cells", cell.task, cell.name)


RECORD_FILES = ("metrics.csv", "baselines.csv", "seconds.txt", "summary.md")


def keep_record(runs: str, out: str, cell: Cell) -> None:
    _study.keep_record(run_dir(runs, cell), record_dir(out, cell), RECORD_FILES)


def finished(runs: str, out: str, cell: Cell) -> bool:
    if not _study.recorded(record_dir(out, cell)):
        keep_record(runs, out, cell)
    return _study.recorded(record_dir(out, cell))


def run_cell(cell: Cell, args) -> float:
    """Run (or resume) one cell; returns the wall time of this piece in seconds."""
    config = cell.config(args.iterations)
    seeds = SEEDS
    if args.quick:
        config = _study.quick_config(config)
        config = config.replace(loop=dataclasses.replace(config.loop, iterations=1))
        seeds = 2
    os.makedirs(record_dir(args.out, cell), exist_ok=True)
    with open(os.path.join(record_dir(args.out, cell), "config.json"), "w") as f:
        json.dump(config_lib.to_dict(config), f, indent=1)
    seconds = _study.timed_sweep(
        config, seeds, list(losses.PAPER_LOSSES), run_dir(args.runs, cell), args.quiet
    )
    keep_record(args.runs, args.out, cell)
    return seconds


# ----- the rule ---------------------------------------------------------------------------


def failed(frame: pd.DataFrame) -> pd.Series:
    """Runs that count as failures: the library's one rule
    (:func:`cfm_jax.analysis.report.failed_runs`: diverged or fell), and a non-finite error."""
    return report.failed_runs(frame) | ~np.isfinite(frame["tracking_mse"].astype(float))


def scores(metrics: pd.DataFrame, baselines: pd.DataFrame) -> pd.DataFrame:
    """Per (loss, seed, iteration, target): ``score`` and ``failed`` under :data:`RULE`."""
    pd_only = baselines[baselines["baseline"] == "pd_only"].set_index("target")["tracking_mse"]
    frame = metrics.copy()
    frame["failed"] = failed(frame)
    floor = np.log10(FAILURE_FACTOR * frame["target"].map(pd_only).astype(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.log10(frame["tracking_mse"].astype(float))
    own = own.where(np.isfinite(own), np.inf)
    frame["score"] = np.where(frame["failed"], np.maximum(floor, own), own)
    frame.loc[frame["failed"] & ~np.isfinite(frame["score"]), "score"] = floor
    return frame


def seed_scores(frame: pd.DataFrame, iteration: int | None = None) -> pd.DataFrame:
    """``(loss, seed) -> score`` at ``iteration`` (None: the last): the mean over targets."""
    last = frame["iteration"].max() if iteration is None else iteration
    at = frame[frame["iteration"] == last]
    return at.groupby(["loss", "seed"])["score"].mean().unstack("loss")


def cell_score(frame: pd.DataFrame, iteration: int | None = None) -> float:
    """Mean over the four losses of the mean over seeds (:data:`RULE`)."""
    return float(seed_scores(frame, iteration).mean(axis=0).mean())


def paired(frame: pd.DataFrame, base: pd.DataFrame) -> dict:
    """Cell minus base over the same seeds (each seed: mean over losses), with a 95%
    percentile bootstrap interval over seeds."""
    a = seed_scores(frame).mean(axis=1)
    b = seed_scores(base).mean(axis=1)
    common = a.index.intersection(b.index)
    diff = (a[common] - b[common]).to_numpy()
    low, high = report.bootstrap_ci(diff)
    return {"mean": float(np.mean(diff)), "low": low, "high": high}


def load(out: str, cell: Cell) -> pd.DataFrame:
    folder = record_dir(out, cell)
    return scores(
        pd.read_csv(os.path.join(folder, "metrics.csv")),
        pd.read_csv(os.path.join(folder, "baselines.csv")),
    )


def choices(frames: dict, task: str, round: int = 1) -> dict:
    """Per factor of ``task``'s family in ``round``: ``(chosen value, line)`` under
    :data:`RULE` from the cells' scored frames (:func:`load`); the value is None while a cell
    of it is missing. Round 2 starts from :func:`round_two_base` with ``SECOND_ROUND``'s
    factors."""
    if round == 1:
        base, factors = Cell(task), FACTORS[family(task)]
    else:
        base, factors = round_two_base(task), SECOND_ROUND[family(task)]["factors"]
    return _choose(frames, base, factors, lambda n, v: Cell(task, n, v, round=round))


def check_choices(frames: dict, task: str) -> dict:
    """Per factor of ``task``'s own check (``TASK_CHECKS``): ``(chosen value, line)`` under
    :data:`RULE`, against the family's defaults (:func:`defaults_cell`)."""
    return _choose(frames, defaults_cell(task), TASK_CHECKS.get(task, ()),
                   lambda n, v: Cell(task, n, v, check=True))  # fmt: skip


def _choose(frames: dict, base: Cell, factors, cell) -> dict:
    """Per factor ``(name, path, values)``: ``(chosen value, line)`` under :data:`RULE`; the
    first value's cell is ``base``, another value's ``cell(name, value)``."""
    chosen = {}
    for name, _, values in factors:
        options = [base] + [cell(name, v) for v in values[1:]]
        have = [(v, frames[c]) for v, c in zip(values, options, strict=True) if c in frames]
        if len(have) < len(values):
            chosen[name] = (None, f"{name}: not all cells finished ({len(have)}/{len(values)})")
            continue
        best_value, best = min(have, key=lambda vf: cell_score(vf[1]))
        if best_value == values[0]:
            chosen[name] = (best_value, f"{name}: **{best_value}** (the base's value)")
        else:
            stats = paired(best, frames[base])
            clear = ", clear" if stats["high"] < 0 else ", not clear"
            chosen[name] = (best_value, f"{name}: **{best_value}** ({report.ci_text(stats)} "
                                        f"against {values[0]}{clear})")  # fmt: skip
    return chosen


def final_choices(frames: dict, task: str) -> dict:
    """``factor -> chosen value``: round 1's choices (None while a cell is missing), with a
    finished second round's in place of round 1's for its factors (until every round-2 cell
    has finished, round 1's stand)."""
    chosen = {name: value for name, (value, _) in choices(frames, task).items()}
    if family(task) in SECOND_ROUND:
        second = {n: v for n, (v, _) in choices(frames, task, round=2).items()}
        if all(v is not None for v in second.values()):
            chosen.update(second)
    return chosen


def _table(frames, base, task, names, rows, curves, own=None) -> list[str]:
    """A markdown table of ``frames`` (cell -> scored frame) against ``base``; appends each
    cell's rows to ``selection.csv``'s ``rows`` and ``curves.csv``'s ``curves``, except for
    ``own``: a cell of another table shown again here as the base."""
    lines = [
        "| cell | score | " + " | ".join(names) + " | failed | vs base [95% CI] |",
        "|---|---:|" + "---:|" * len(names) + "---:|---|",
    ]
    for cell, frame in frames.items():
        per_loss = seed_scores(frame).mean(axis=0)
        last = frame[frame["iteration"] == frame["iteration"].max()]
        fails = int(last["failed"].sum())
        is_base = base is None or frame is base
        vs = "" if is_base else report.ci_text(paired(frame, base))
        lines.append(
            f"| {cell.name}{' (base)' if cell == own else ''} | {cell_score(frame):.3f} | "
            + " | ".join(f"{per_loss.get(n, np.nan):.3f}" for n in names)
            + f" | {fails}/{len(last)} | {vs} |"
        )
        if cell == own:
            continue
        for loss in names:
            sub = last[last["loss"] == loss]
            rows.append({
                "task": task, "round": cell.round, "cell": cell.name, "factor": cell.factor,
                "value": cell.value,
                "loss": loss, "score": float(per_loss.get(loss, np.nan)),
                "failed": int(sub["failed"].sum()), "runs": len(sub),
                "median_tracking_mse": float(sub["tracking_mse"].median()),
            })  # fmt: skip
        for it in sorted(frame["iteration"].unique()):
            at = frame[frame["iteration"] == it]
            curves.append({
                "task": task, "round": cell.round, "cell": cell.name, "iteration": int(it),
                "score": cell_score(frame, it), "failed": int(at["failed"].sum()),
                "runs": len(at),
            })  # fmt: skip
    return lines


def tables(out: str, tasks) -> str:
    """``selection.csv``, ``curves.csv`` and the page ``index.md``; returns the page. The
    page holds ``tasks`` and every other task with records in ``out``, so that two pieces
    run side by side (``--only inverse_dynamics`` and ``--only walk``) never drop each
    other's tables."""
    tasks = [t for t in ARM + LEGGED
             if t in tasks or os.path.isdir(os.path.join(out, "cells", t))]  # fmt: skip
    rows, curves = [], []
    lines = [
        "# Choosing the defaults: the selection run",
        "",
        "Written by `experiments/select_defaults.py`. **The rule, fixed before the run:** " + RULE,
        "",
        f"Failure floor: {FAILURE_FACTOR:g} x PD-only. Seeds per cell: {SEEDS}. Iterations: "
        + ", ".join(f"{t} {ITERATIONS[t]}" for t in tasks)
        + ". Motions: arm targets of `references.default_targets(..., seed="
        f"{references.SELECTION_SEED})`; walks {SELECTION_WALKS} s; jumps {SELECTION_JUMPS} m.",
        "",
        "**Sizing.** " + SIZING,
        "",
        "**Together.** " + TOGETHER,
    ]
    for task in tasks:
        cells = [c for c in cells_of(task) if _study.recorded(record_dir(out, c))]
        base_text = ", ".join(f"`{k}={v}`" for k, v in BASE[family(task)].items())
        lines += ["", f"## {task} ({ROBOT[task]}; base: {base_text})", ""]
        chosen_on = SELECTED_ON[family(task)]
        if task != chosen_on:
            lines += [f"Not a task the factors are chosen on: takes the choice made on "
                      f"{chosen_on} (see Sizing).", ""]  # fmt: skip
        if task != chosen_on and task in TASK_CHECKS:
            lines += [f"### {task}, its own check (base: `{defaults_cell(task).name}`, the "
                      "family's defaults)", "", CHECK_TEXTS[task], ""]  # fmt: skip
        if not cells:
            lines.append("No cell finished yet.")
            continue
        frames = {c: load(out, c) for c in cells}
        names = list(losses.PAPER_LOSSES)
        if task != chosen_on:
            lines += _table(frames, frames.get(defaults_cell(task)), task, names, rows, curves)
            lines += ["", "Chosen per checked factor (against the family's defaults):", ""]
            lines += [f"* {line}" for _, line in check_choices(frames, task).values()]
            continue
        first = {c: f for c, f in frames.items() if c.round == 1 and not c.check}
        lines += _table(first, first.get(Cell(task)), task, names, rows, curves)
        lines += ["", "Chosen per factor (lowest score; *clear* when the paired interval "
                  "against the base excludes 0):", ""]  # fmt: skip
        lines += [f"* {line}" for _, line in choices(frames, task).values()]
        together = Cell(task, together=True)
        base = frames.get(Cell(task))
        if together in frames and base is not None:
            frame = frames[together]
            last = frame[frame["iteration"] == frame["iteration"].max()]
            fails = f"{int(last['failed'].sum())}/{len(last)}"
            lines += ["", f"The chosen values together (`{together.name}`, round 1's choices "
                      f"on these motions; it chooses nothing): score "
                      f"{cell_score(frame):.3f}, {report.ci_text(paired(frame, base))} "
                      f"against the base; {fails} failed."]  # fmt: skip
        second = round_two_base(task)
        if second is None or task != chosen_on:
            continue
        lines += ["", f"### {task}, round 2 (base: `{second.name}`)", "", ROUND_TWO, ""]
        later = {c: f for c, f in frames.items() if c.round == 2}
        if second in frames:
            later = {second: frames[second], **later}
        lines += _table(later, frames.get(second), task, names, rows, curves, own=second)
        lines += ["", "Chosen per factor in round 2 (against the round-2 base):", ""]
        lines += [f"* {line}" for _, line in choices(frames, task, round=2).values()]
        final = final_choices(frames, task)
        if all(v is not None for v in final.values()):
            lines += ["", "The family's defaults (round 1, with round 2 for its factors): "
                      + ", ".join(f"{n} **{v}**" for n, v in final.items()) + "."]  # fmt: skip
            cell = defaults_cell(task)
            if cell in frames:
                frame = frames[cell]
                last = frame[frame["iteration"] == frame["iteration"].max()]
                lines[-1] += (f" On these motions they are the cell `{cell.name}`: score "
                              f"{cell_score(frame):.3f}, {int(last['failed'].sum())}/"
                              f"{len(last)} failed.")  # fmt: skip
        if task in TASK_CHECKS:
            base = defaults_cell(task)
            lines += ["", f"### {task}, its own check (base: `{base.name}`, the family's "
                      "defaults)", "", CHECK_TEXTS[task], ""]  # fmt: skip
            checked = {c: f for c, f in frames.items() if c.check}
            if base in frames:
                checked = {base: frames[base], **checked}
            lines += _table(checked, frames.get(base), task, names, rows, curves, own=base)
            lines += ["", "Chosen per checked factor (against the family's defaults):", ""]
            lines += [f"* {line}" for _, line in check_choices(frames, task).values()]
    os.makedirs(out, exist_ok=True)
    pd.DataFrame(rows).to_csv(os.path.join(out, "selection.csv"), index=False)
    pd.DataFrame(curves).to_csv(os.path.join(out, "curves.csv"), index=False)
    page = "\n".join(lines) + "\n"
    with open(os.path.join(out, "index.md"), "w") as f:
        f.write(page)
    return page


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", default="results/selection", help="the runs (large)")
    parser.add_argument("--out", default="docs/results/selection", help="records, tables")
    parser.add_argument(
        "--only", default=",".join(SELECTED_ON.values()),
        help="comma-separated tasks (default: the tasks the factors are chosen on)",
    )  # fmt: skip
    parser.add_argument("--iterations", type=int, default=None, help="default: per task")
    parser.add_argument(
        "--budget", type=float, default=float("inf"),
        help="seconds: start no further cell after this; started again, the run resumes",
    )  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="smoke test: tiny, no result")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    tasks = _study.tasks_of(parser, args.only, ARM + LEGGED)
    # A generator: a task's cells are made when its turn comes (they may read the records of
    # the tasks before it), as the study always made them.
    cells = (cell for task in tasks for cell in cells_of(task))
    _study.run_cells("select_defaults", cells, args, run_cell, finished,
                     after=lambda: tables(args.out, tasks))  # fmt: skip
    print(tables(args.out, tasks))


if __name__ == "__main__":
    main()
