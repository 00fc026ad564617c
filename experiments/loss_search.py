"""Each loss at its own best (issue 43, item 1): a hyperparameter search per loss on an equal
budget, on selection motions and selection seeds only, by a rule written before its first
trial.

The rule (``RULE``, also in the ``chosen_<task>.json`` it writes) is fixed before any trial
runs:

* One Optuna study per (task, loss), the same for every loss: TPE (``TPESampler``, seed
  ``SAMPLER_SEED``, the first ``STARTUP`` trials random), ``TRIALS`` trials, the search space
  ``SPACE`` of the task's family (the learner's shared factors, the same for every loss; no
  loss has options of its own in the config, and a factor a loss ignores, the controller
  goal for ``supervised``, stays in its space so that every loss searches the same space).
* A trial trains its loss from the task's library defaults with the trial's values, on the
  task's selection motions (arm: the targets of ``references.SELECTION_SEED``; legged:
  ``task.motion_family="selection"`` for the durations or heights of
  ``select_defaults.SELECTION_WALKS`` / ``SELECTION_JUMPS``, no window of which is one of a
  test motion) and the seeds ``SEEDS`` (no test cell uses them), for the task's iterations.
* Its score is the selection run's (``select_defaults.RULE``) for that loss alone:
  ``log10`` of the final tracking MSE per run, a failed run (fell, diverged, not finite)
  scoring ``log10(1000 x PD-only)`` on its target or its own score if higher; the mean over
  targets, then over seeds. Lower is better.
* The loss's configuration for the comparison "each at its best" is its trial with the
  lowest score (ties: the earlier trial). The test cells then run each loss with its own
  configuration, beside the shared defaults.
* Amendment 2 (``AMENDMENT_DEFAULTS``, after every study's 12 trials): each study then also
  scores the shared defaults (``defaults_values``), one trial queued after its TPE trials,
  and the lowest of the 13 is the loss's choice; on the walk no TPE trial of the joint, task
  or distal loss had left the failure floor, while the defaults walk.

Resumable: each study lives in a journal file (``--out/<task>/<loss>/journal.log``, a few
kB, committed with the records so that a fresh machine resumes it); a trial killed while
running is marked failed on the next start and its values are tried again first, so the
trials' values do not depend on where the search was cut. The finished trials are written to
``--out`` after every trial (``trials_<task>.csv``: one row per trial;
``chosen_<task>.json``: the rule and each loss's lowest-scoring trial; ``index.md`` and
``search_<task>.png``: the same as a page, with each loss's best score so far per trial).

Usage:
  python experiments/loss_search.py --task inverse_dynamics --budget 3000   # a piece
  python experiments/loss_search.py --losses joint,task &   # two pieces side by side,
  python experiments/loss_search.py --losses distal,supervised   # a core each
  python experiments/loss_search.py --quick --out /tmp/q                     # smoke test
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time

import _study
import pandas as pd
import select_defaults

import cfm_jax
from cfm_jax import config as config_lib
from cfm_jax.learning import losses as losses_lib

RULE = (
    "One TPE study per (task, loss), the same for every loss: sampler seed {seed}, {startup} "
    "random trials first, {trials} trials in all, the family's search space. A trial trains "
    "its loss from the task's library defaults with the trial's values on the selection "
    "motions (arm: the SELECTION_SEED targets; legged: motion_family='selection') and the "
    "selection seeds {seeds}. Score: the selection run's, for that loss alone (log10 final "
    "tracking MSE per run; a failed run scores log10(1000 x PD-only) or its own if higher; "
    "mean over targets, then seeds); lower is better. A loss's configuration 'at its best' "
    "is its lowest-scoring trial (ties: the earlier). Written before the first trial."
)
SIZING = (
    "Measured before the first trial (2 cores, nothing beside it): the inverse-dynamics cell "
    "of the arm's defaults on the selection targets, 3 seeds x 10 iterations, the four losses "
    "in one batched call, 487 s, about 122 s per loss (a trial trains one loss alone: about "
    "140 s). The first selection run measured the walk's cell (30 iterations) at 2.6x the "
    "inverse-dynamics one: about 360 s per walk trial. 12 trials per loss: about 1.9 h for "
    "inverse dynamics and 4.8 h for the walk, in pieces over sessions. So the search runs on "
    "one task per family, as the first selection did (inverse dynamics, walk), and op-space "
    "and the jump take their family's per-loss configuration; decided on the cost alone, "
    "before any trial."
)
AMENDMENT = (
    "2026-11-28, after 16 inverse-dynamics trials (the 4 random startup draws of each loss "
    "and joint's trial 4): the sampler was seeded once per process, so a piece that started "
    "anew drew its first random trial with the seed's first draw again (supervised's trial 3 "
    "repeated its trial 0's values; its score equal to the last bit, the determinism of a "
    "trial). From then on a trial's sampler is seeded SAMPLER_SEED + the number of finished "
    "trials before it (its values depend on the study's history only, not on where a piece "
    "was cut or a trial killed), a loss's missing startup "
    "draws are queued first, and the budget counts trials with distinct values."
)
AMENDMENT_DEFAULTS = (
    "2026-11-28, after the 12 trials of every loss on both tasks: on the walk no trial of the "
    "joint, task or distal loss left the failure floor (best -0.184: every run fell), while "
    "the task's shared defaults, run once by the trial's protocol (the same selection walks, "
    "seeds and iterations, one core; the four losses in one call), scored joint -3.05, task "
    "-3.03, distal -2.63, supervised -1.25: twelve TPE trials did not find a point of the "
    "space the shared defaults already are. So every study, of every loss and task alike, "
    "also scores the shared defaults (the task's library defaults, a point of the space), "
    "one trial queued after its 12 TPE trials (so the TPE trials' values stay as they "
    "were drawn), and a loss's configuration 'at its best' is its lowest-scoring trial of "
    "the 13. The original rule's choices, kept in the trial records, are reported beside."
)
AMENDMENTS = (AMENDMENT, AMENDMENT_DEFAULTS)
CORES = {"inverse_dynamics": 2, "walk": 1}
"""The cores a task's trials run on (the process's CPU affinity; XLA's CPU pool has as many
threads, and the thread count changes a trial's numbers): the inverse-dynamics trials ran on
both of our 2 cores; the walk's run pinned to one (``taskset -c N``, a process per core on
disjoint ``--losses``), decided before its first trial because jaxlib 0.10 stalls for good
when as many large batched LAPACK calls run at once as the pool has threads (see
``comparison.CORES``), and the walk's 18 x 18 mass matrices reach that size sooner."""
SAMPLER_SEED = 43
STARTUP = 4
TRIALS = 12
SEEDS = (100, 101, 102)
"""Selection seeds: the test cells use seeds 10-19, the first selection run 0-2."""
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
"""The repository: the records' default folder is in its docs, wherever the command runs."""
ITERATIONS = {"inverse_dynamics": 10, "opspace": 10, "walk": 30, "jump": 30}

CATEGORICAL = {
    "normaliser": ("loop.normaliser", config_lib.NORMALISERS),
    "forward model": ("forward.kind", config_lib.FORWARD_KINDS),
    "controller goal": ("controller.goal", config_lib.CONTROLLER_GOALS),
    "loss form": ("controller.loss_form", config_lib.LOSS_FORMS),
    "fit start": ("forward+controller.start", config_lib.FIT_STARTS),
}
FAMILY_CATEGORICAL = {
    "arm": {"babbling": ("loop.babbling", ("reaching", "home"))},
    "legged": {"s*": ("task.desired", config_lib.DESIRED)},
}
LOG_UNIFORM = {
    "forward learning rate": ("forward.learning_rate", (1e-4, 3e-3)),
    "controller learning rate": ("controller.learning_rate", (1e-4, 3e-3)),
}
"""The search space: the factors of the first selection run (categorical) and the two
learning rates (log-uniform), per family; the same for every loss."""


def space(task: str) -> dict:
    """``{factor: (dotted path, values or (low, high))}`` of ``task``'s family."""
    family = select_defaults.family(task)
    return {**CATEGORICAL, **FAMILY_CATEGORICAL[family], **LOG_UNIFORM}


def suggest(trial, task: str) -> dict:
    """The trial's values, ``{dotted path: value}`` (``forward+controller.start`` sets both)."""
    changes = {}
    for name, (path, values) in space(task).items():
        if name in LOG_UNIFORM:
            value = trial.suggest_float(name, *values, log=True)
        else:
            value = trial.suggest_categorical(name, list(values))
        for one in select_defaults.factor_paths(path):
            changes[one] = value
    return changes


def defaults_values(task: str) -> dict:
    """The task's shared defaults (its library defaults, ``config.for_task``) as a point of its
    search space, ``{factor: value}``: the values of the trial that every study also scores
    (:data:`AMENDMENT_DEFAULTS`)."""
    config = _study.for_task(task, robot=select_defaults.ROBOT[task])
    values = {}
    for name, (path, _) in space(task).items():
        found = set()
        for one in select_defaults.factor_paths(path):
            value = config
            for part in one.split("."):
                value = getattr(value, part)
            found.add(value)
        if len(found) != 1:
            raise ValueError(f"{task}: the defaults set {path} to {sorted(found)}: not a point "
                             f"of the search space (one value for {name!r})")  # fmt: skip
        values[name] = found.pop()
    return values


def is_defaults(frame: pd.DataFrame, task: str) -> pd.Series:
    """The rows of a trial record (``trials_<task>.csv``) that are the shared-defaults trial."""
    mask = pd.Series(True, index=frame.index)
    for name, value in defaults_values(task).items():
        mask &= frame[name] == value
    return mask


def complete(frame: pd.DataFrame, task: str, loss: str, trials: int = TRIALS) -> bool:
    """Whether ``loss``'s study in the trial record ``frame`` has all its trials: ``trials``
    TPE trials with distinct values, and the shared-defaults trial."""
    mine = frame[frame["loss"] == loss]
    defaults = is_defaults(mine, task)
    tpe = mine[~defaults][list(space(task))].drop_duplicates()
    return len(tpe) >= trials and bool(defaults.any())


def trial_config(task: str, changes: dict, quick: bool = False) -> config_lib.Config:
    """The task's library defaults on its selection motions with ``changes``."""
    config = _study.for_task(task, robot=select_defaults.ROBOT[task])
    motions = select_defaults.selection_motions(task, config)
    if task in ("walk", "jump"):
        motions["motion_family"] = "selection"
    config = _study.with_changes(config, {
        "loop.iterations": ITERATIONS[task],
        **{f"task.{k}": v for k, v in motions.items()},
        **changes,
    })  # fmt: skip
    if quick:
        config = _study.quick_config(config)
        config = config.replace(loop=dataclasses.replace(config.loop, iterations=1))
    return config


def score(metrics: pd.DataFrame, baselines: pd.DataFrame) -> float:
    """The trial's score under :data:`RULE` (one loss: mean over seeds of the mean over
    targets of the selection run's per-run score at the last iteration)."""
    frame = select_defaults.scores(metrics, baselines)
    return float(select_defaults.seed_scores(frame).mean(axis=0).mean())


def sampler(finished: int):
    """The sampler of a trial drawn after ``finished`` finished trials: TPE seeded with
    ``SAMPLER_SEED + finished``, so that a trial's values depend on the study's history
    only, not on the piece (the process) it runs in nor on trials killed before it.
    (Seeded once per process, as the first piece did, a piece that starts anew draws its
    first random trial with the seed's first draw again: the supervised loss's
    inverse-dynamics trial 3 repeated its trial 0.)"""
    import optuna

    return optuna.samplers.TPESampler(seed=SAMPLER_SEED + finished, n_startup_trials=STARTUP)


def study(runs: str, task: str, loss: str):
    import optuna

    folder = os.path.join(runs, task, loss)
    os.makedirs(folder, exist_ok=True)
    backend = optuna.storages.journal.JournalFileBackend(os.path.join(folder, "journal.log"))
    return optuna.create_study(
        study_name=f"{task}-{loss}",
        storage=optuna.storages.JournalStorage(backend),
        sampler=sampler(0),
        direction="minimize",
        load_if_exists=True,
    )


def ask(search):
    """The study's next trial, drawn by the :func:`sampler` of its finished trials (a queued
    trial: the queued values)."""
    import optuna

    finished = search.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    search.sampler = sampler(len(finished))
    return search.ask()


def _key(params: dict) -> str:
    return json.dumps(params, sort_keys=True)


def distinct(search, task: str | None = None) -> int:
    """The study's finished trials with distinct values: the budget ``TRIALS`` counts these
    (a trial that repeats an earlier one's values adds nothing). With ``task``: its TPE
    trials only (the shared-defaults trial not counted)."""
    import optuna

    done = search.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    keys = {_key(t.params) for t in done}
    if task is not None:
        keys.discard(_key(defaults_values(task)))
    return len(keys)


def _queue_defaults(search, task: str) -> bool:
    """Queue the shared-defaults trial unless the study has it (finished, running or queued);
    whether the study still needs it."""
    import optuna

    alive = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.WAITING,
             optuna.trial.TrialState.RUNNING)  # fmt: skip
    values = defaults_values(task)
    have = {_key(_values(t)): t.state for t in search.get_trials(deepcopy=False, states=alive)}
    if _key(values) not in have:
        search.enqueue_trial(values)
    return have.get(_key(values)) != optuna.trial.TrialState.COMPLETE


def _values(trial) -> dict:
    """A trial's values; a queued one's are its fixed values (its params are set when asked)."""
    return trial.params or trial.system_attrs.get("fixed_params", {})


def _fill_startup(searches, runs: str, task: str) -> None:
    """Every loss searches from the same ``STARTUP`` random draws: the values any loss's
    study (all four journals in ``runs``) has among its first ``STARTUP`` trials that one of
    ``searches`` lacks are queued there, to be tried next."""
    import optuna

    startup = {}
    for loss in losses_lib.PAPER_LOSSES:
        if os.path.exists(os.path.join(runs, task, loss, "journal.log")):
            for t in study(runs, task, loss).get_trials(deepcopy=False):
                if t.number < STARTUP and _values(t):
                    startup.setdefault(_key(_values(t)), _values(t))
    alive = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.WAITING,
             optuna.trial.TrialState.RUNNING)  # fmt: skip
    for search in searches.values():
        have = {_key(_values(t)) for t in search.get_trials(deepcopy=False, states=alive)}
        for key, params in startup.items():
            if key not in have:
                search.enqueue_trial(params)


def _recover(search) -> None:
    """A trial left running by a killed piece: failed, and its values tried again first."""
    import optuna

    for trial in search.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        search.tell(trial.number, state=optuna.trial.TrialState.FAIL)
        search.enqueue_trial(trial.params)


def next_loss(searches: dict, task: str, trials: int = TRIALS) -> str | None:
    """The loss (a key of ``searches``, in their order) whose study runs the next trial, None
    when every study has all its trials. Round-robin: the study with the fewest finished
    trials first, so that a piece cut short leaves every loss with about as many. A study
    with its ``trials`` TPE trials gets the shared-defaults trial queued
    (:data:`AMENDMENT_DEFAULTS`) only then, so that its TPE trials' values are as drawn."""
    done = {loss: distinct(search, task) for loss, search in searches.items()}
    for loss, search in searches.items():
        if done[loss] >= trials and _queue_defaults(search, task):
            done[loss] = trials - 0.5  # one to run: the shared defaults
    todo = [loss for loss in searches if done[loss] < trials]
    return min(todo, key=lambda name: (done[name], list(searches).index(name)), default=None)


def run_trial(search, task: str, loss: str, args) -> dict:
    """Ask, train (seeds vmapped), score, tell; the trial's record."""
    trial = ask(search)
    changes = suggest(trial, task)
    config = trial_config(task, changes, args.quick)
    seeds = list(SEEDS[:2] if args.quick else SEEDS)
    start = time.perf_counter()
    result = cfm_jax.train(config.replace(seed=seeds[0], loop=dataclasses.replace(
        config.loop, seeds=len(seeds))), progress=False, losses=[loss])  # fmt: skip
    seconds = time.perf_counter() - start
    value = score(result.metrics, result.baselines)
    if not math.isfinite(value):
        raise RuntimeError(f"{task}/{loss} trial {trial.number}: score {value}")
    trial.set_user_attr("seconds", round(seconds, 1))
    search.tell(trial, value)
    return {"task": task, "loss": loss, "trial": trial.number, "score": value,
            "seconds": round(seconds, 1), **trial.params}  # fmt: skip


def records(runs: str, tasks, loss_names) -> pd.DataFrame:
    """Every finished trial of the studies in ``runs``."""
    import optuna

    rows = []
    for task in tasks:
        for loss in loss_names:
            if not os.path.exists(os.path.join(runs, task, loss, "journal.log")):
                continue
            for t in study(runs, task, loss).get_trials(
                deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)
            ):
                rows.append({"task": task, "loss": loss, "trial": t.number, "score": t.value,
                             "seconds": t.user_attrs.get("seconds"), **t.params})  # fmt: skip
    return pd.DataFrame(rows)


def chosen(trials: pd.DataFrame) -> dict:
    """Per task and loss, the lowest-scoring trial (ties: the earlier) and its values."""
    out = {}
    for (task, loss), frame in trials.groupby(["task", "loss"], sort=False):
        best = frame.sort_values(["score", "trial"]).iloc[0]
        values = {k: v for k, v in best.items() if k not in ("task", "loss", "seconds")}
        out.setdefault(task, {})[loss] = {k: (v.item() if hasattr(v, "item") else v)
                                          for k, v in values.items() if pd.notna(v)}  # fmt: skip
    return out


def write_records(out: str, task: str, loss_names, trials: int) -> pd.DataFrame:
    """``trials_<task>.csv`` and ``chosen_<task>.json`` in ``out`` from the studies there."""
    frame = records(out, [task], loss_names)
    if not frame.empty:
        rule = RULE.format(seed=SAMPLER_SEED, startup=STARTUP, trials=trials, seeds=list(SEEDS))
        # Written whole, then renamed: two pieces side by side never leave a half file.
        for name, text in (
            (f"trials_{task}.csv", frame.to_csv(index=False)),
            (
                f"chosen_{task}.json",
                json.dumps(
                    {"rule": rule, "amendments": list(AMENDMENTS), "chosen": chosen(frame)},
                    indent=1,
                ),
            ),
        ):
            part = os.path.join(out, f".{name}.{os.getpid()}")
            with open(part, "w") as f:
                f.write(text)
            os.replace(part, os.path.join(out, name))
        write_page(out, trials)
    return frame


def write_page(out: str, trials: int = TRIALS) -> str:
    """``index.md`` in ``out``: the rule, sizing and amendment, per task and loss the chosen
    trial, the best score so far per trial (``search_<task>.png``) and every trial."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rule = RULE.format(seed=SAMPLER_SEED, startup=STARTUP, trials=trials, seeds=list(SEEDS))
    lines = [
        "# Each loss at its own best: the per-loss search",
        "",
        "Written by `experiments/loss_search.py` after every trial (issue 43).",
        "",
        f"Rule: {rule}",
        "",
        f"Sizing: {SIZING}",
        "",
        *(f"Amendment {k}: {text}\n" for k, text in enumerate(AMENDMENTS, 1)),
        "Cores: "
        + ", ".join(f"{task} trials on {n}" for task, n in CORES.items())
        + " (the process's CPU affinity, `CORES`; one core avoids jaxlib 0.10's LAPACK stall).",
        "",
    ]
    for task in ITERATIONS:
        path = os.path.join(out, f"trials_{task}.csv")
        if not os.path.isfile(path):
            continue
        frame = pd.read_csv(path)
        names = list(space(task))
        best = chosen(frame)[task]
        fig, ax = plt.subplots(figsize=(5, 3))
        lines += [
            f"## {task}",
            "",
            f"![best score so far](search_{task}.png)",
            "",
            "| loss | trials (distinct values) | lowest score | its trial | "
            + " | ".join(names)
            + " |",
            "|---|---:|---:|---:|" + "---|" * len(names),
        ]
        for loss, f in frame.groupby("loss", sort=False):
            f = f.sort_values("trial")
            ax.step(range(len(f)), f.score.cummin(), where="post", label=loss)
            values = " | ".join(_f(best[loss].get(n)) for n in names)
            lines.append(
                f"| {loss} | {len(f)} ({len(f[names].drop_duplicates())}) | "
                f"{best[loss]['score']:.3f} | {best[loss]['trial']} | {values} |"
            )
        ax.set(xlabel="finished trial", ylabel="lowest score so far (log10 MSE)", title=task)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"search_{task}.png"), dpi=100, metadata={"Software": None})
        plt.close(fig)
        lines += [
            "",
            "Every trial (score: lower is better; seconds: its wall time, at times beside "
            "another piece; the shared-defaults trial marked):",
            "",
            "| loss | trial | score | seconds | " + " | ".join(names) + " |",
            "|---|---:|---:|---:|" + "---|" * len(names),
        ]
        defaults = is_defaults(frame, task)
        for i, row in frame.iterrows():
            mark = " (shared defaults)" if defaults[i] else ""
            lines.append(
                f"| {row['loss']} | {row['trial']}{mark} | {row['score']:.3f} | "
                f"{row['seconds']} | " + " | ".join(_f(row[n]) for n in names) + " |"
            )
        lines.append("")
    text = "\n".join(lines) + "\n"
    with open(os.path.join(out, "index.md"), "w") as f:
        f.write(text)
    return text


def _f(value) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="inverse_dynamics", choices=sorted(ITERATIONS))
    parser.add_argument("--losses", default=",".join(losses_lib.PAPER_LOSSES))
    parser.add_argument("--trials", type=int, default=TRIALS, help="trials per loss in all")
    parser.add_argument("--budget", type=float, default=math.inf,
                        help="seconds: start no trial after this (a piece)")  # fmt: skip
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "results", "loss_search"))
    parser.add_argument("--quick", action="store_true", help="tiny networks, 1 iteration")
    args = parser.parse_args(argv)
    cores = _study.cores()
    if not args.quick and cores != CORES.get(args.task, 1):
        parser.error(f"--task={args.task}: its trials run on {CORES.get(args.task, 1)} core(s) "
                     f"(CORES) and this process may run on {cores}: start it as "
                     "taskset -c 0 python experiments/loss_search.py ...")  # fmt: skip
    loss_names = [s for s in args.losses.split(",") if s]
    bad = sorted(set(loss_names) - set(losses_lib.PAPER_LOSSES))
    if bad:
        parser.error(f"--losses: {bad} not allowed; choose from {list(losses_lib.PAPER_LOSSES)}")
    start = time.perf_counter()
    searches = {loss: study(args.out, args.task, loss) for loss in loss_names}
    for search in searches.values():
        _recover(search)
    _fill_startup(searches, args.out, args.task)
    # Round-robin over the losses, a trial each, so that a piece cut short leaves every loss
    # with about the same number of trials.
    while time.perf_counter() - start < args.budget:
        loss = next_loss(searches, args.task, args.trials)
        if loss is None:
            break
        row = run_trial(searches[loss], args.task, loss, args)
        print(f"loss_search: {args.task}/{loss} trial {row['trial']}: score "
              f"{row['score']:.3f} in {row['seconds']:.0f} s", flush=True)  # fmt: skip
        # Every loss's journal, not only this piece's: two pieces may run side by side on
        # disjoint --losses (a process per core) and write the same records.
        write_records(args.out, args.task, losses_lib.PAPER_LOSSES, args.trials)  # nothing lost
    trials = write_records(args.out, args.task, losses_lib.PAPER_LOSSES, args.trials)
    print(f"loss_search: {len(trials)} trials recorded in {args.out}")


if __name__ == "__main__":
    sys.exit(main())
