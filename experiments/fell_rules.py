"""How much would one fall rule for training and replay change the legged numbers?

The library has one :func:`cfm_jax.solo12.fell` with two named limits: the legged tasks'
``TRAINING_FALL`` (base below 0.10 m, tilt above 0.8 rad, a base-box corner below the
floor; it gives the metric ``fell`` and the terminal step after which a rollout is no
data) and the reference checks' ``REPLAY_FALL`` (the same, but knees count too and the body
must stay 5 mm clear of the floor). This script measures, without changing the training
rule, what switching the training to a rule with knees would do: it runs short legged
trainings with the study's default protocol (:func:`cfm_jax.config.for_task`: babbling
``home``, no feedback in ``s*``, the study's networks; few seeds and iterations) and, for
every rollout of those runs (babbling, each iteration's rollout of the learned controller,
the final evaluation, the oracle and PD-only baselines), finds the first step inside the
target's horizon where each rule says "fell":

* ``training``: ``TRAINING_FALL`` (today's training rule);
* ``replay``: ``REPLAY_FALL`` (knees count, 5 mm clearance);
* ``knees_floor``: knees count, clearance 0.

The rules are evaluated inside the compiled rollouts on the same float32 states that the
training sees (the task's ``record`` gets two more flags, its ``metrics`` the first-fall
step of each rule; the training itself, its data and its ``fell`` are untouched). Since
both knee rules include the training rule, they fall at the same step or earlier.

Printed: per task and source, how many rollouts there are, how many fell under each rule,
in how many the first-fall step differs from the training rule's and by how many steps
(0.004 s each), and how many metric rows (``fell`` per seed, iteration and target) and how
many data rows (``transitions_added``: the steps before the first fall) would change.

Usage:
  python experiments/fell_rules.py                          # walk and jump, ~10 min on 2 cores
  python experiments/fell_rules.py --tasks walk --seeds 1 --iterations 1 --losses joint
  python experiments/fell_rules.py --csv /tmp/fell_rules.csv  # every rollout's steps
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

import cfm_jax  # noqa: F401  (first: it sets the XLA flag before JAX starts)
from cfm_jax import config as config_lib
from cfm_jax import solo12
from cfm_jax.tasks.legged import LeggedTask

RULES = {
    "training": solo12.TRAINING_FALL,
    "replay": solo12.REPLAY_FALL,
    "knees_floor": solo12.FallLimits(body_clearance=0.0),
}
"""The rules compared; ``training`` must stay first (the others are compared with it)."""


def first_fall(fell, active):
    """First step where ``fell`` inside the horizon (``active``), ``(..., steps)`` ->
    ``(...)``; the horizon (the number of active steps) where it never does."""
    xp = jnp if isinstance(fell, jax.Array) else np
    steps = fell.shape[-1]
    index = xp.where(fell & active, xp.arange(steps), steps)
    return xp.minimum(xp.min(index, axis=-1), xp.sum(active, axis=-1))


def instrument() -> None:
    """Make every legged rollout carry each rule's flag (``extras["fell_<rule>"]``) and
    every metrics table each rule's first-fall step (``fall_step_<rule>``); the task's
    ``fell`` and ``terminal`` stay the training rule's."""
    record, metrics = LeggedTask.record, LeggedTask.metrics

    def record_all(self, step, tau, qpos_next, qvel_next, features_next):
        out = record(self, step, tau, qpos_next, qvel_next, features_next)
        for name, limits in RULES.items():
            out[f"fell_{name}"] = solo12.fell(qpos_next, limits=limits, xp=jnp)
        return out

    def metrics_all(self, result):
        out = metrics(self, result)
        active = result.extras["active"]
        for name in RULES:
            step = first_fall(result.extras[f"fell_{name}"], active)
            out[f"fall_step_{name}"] = step.astype(jnp.float32)
        return out

    LeggedTask.record, LeggedTask.metrics = record_all, metrics_all
    LeggedTask.metric_names = tuple(LeggedTask.metric_names) + tuple(
        f"fall_step_{name}" for name in RULES
    )


def config_for(task: str, seeds: int, iterations: int) -> config_lib.Config:
    """The study's default cell (experiments/robustness_study.py: ``for_task``, babbling
    ``home``, default gains) with fewer seeds and iterations."""
    config = config_lib.for_task(task)
    return config.replace(loop=dataclasses.replace(config.loop, seeds=seeds, iterations=iterations))


def run_task(task: str, args) -> pd.DataFrame:
    """One row per rollout: source, seed, iteration, target, horizon, the first-fall step of
    each rule and the training's own ``fell`` metric (where there is one)."""
    config = config_for(task, args.seeds, args.iterations)
    experiment = cfm_jax.Experiment(config)
    horizons = np.array([r.horizon for r in experiment.task.references])
    rows = []
    columns = ["source", "seed", "iteration", "target", "fell"]
    columns += [f"fall_step_{name}" for name in RULES]
    for loss in args.losses.split(","):
        start = time.perf_counter()
        result = cfm_jax.train(config.replace(loss=loss), progress=False, experiment=experiment)
        print(f"  {task} {loss}: {time.perf_counter() - start:.0f} s", flush=True)
        last = config.loop.iterations
        frame = result.metrics.assign(
            source=np.where(result.metrics.iteration == last, f"{loss} final", f"{loss} iteration")
        )
        rows.append(frame[columns])
        if loss == args.losses.split(",")[0]:  # the baselines do not depend on the loss
            base = result.baselines.rename(columns={"baseline": "source"})
            rows.append(base.assign(seed=-1, iteration=-1)[columns])
    # The babbling rollouts, with the keys cfm_jax.train derives from the seeds.
    seeds = config.seed + np.arange(config.loop.seeds)
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds, jnp.uint32))
    babble = jax.device_get(experiment.babbling_rollouts(keys))
    active = np.asarray(babble.extras["active"])  # (seeds, rollouts, targets, steps)
    steps = {name: first_fall(np.asarray(babble.extras[f"fell_{name}"]), active) for name in RULES}
    babbled = []
    for s, r, k in np.ndindex(active.shape[:3]):
        row = {"source": "babbling", "seed": int(seeds[s]), "iteration": r, "target": k}
        row["horizon"] = int(active[s, r, k].sum())  # babbling: every step of the padding
        row["fell"] = float(steps["training"][s, r, k] < row["horizon"])
        row.update({f"fall_step_{name}": float(steps[name][s, r, k]) for name in RULES})
        babbled.append(row)
    rows = [frame.assign(horizon=horizons[frame.target.to_numpy()]) for frame in rows]
    out = pd.concat([*rows, pd.DataFrame(babbled)], ignore_index=True).assign(task=task)
    # The training's fell metric is the training rule's first fall inside the horizon.
    np.testing.assert_array_equal(out.fell, out.fall_step_training < out.horizon)
    return out


def summarise(rollouts: pd.DataFrame, control_dt: float = 0.004) -> pd.DataFrame:
    """Per task and source (babbling, learned iterations, final evaluations, baselines) and
    alternative rule: rollouts, falls under each rule, rollouts whose first-fall step
    differs and by how many steps, and the metric and data rows that would change."""
    frame = rollouts.assign(
        source=rollouts.source.str.replace(r"^\w+ (iteration|final)$", r"learned \1", regex=True)
    )
    lines = []
    for (task, source), group in frame.groupby(["task", "source"], sort=False):
        train = group.fall_step_training.to_numpy()
        horizon = group.horizon.to_numpy()
        for name in list(RULES)[1:]:
            other = group[f"fall_step_{name}"].to_numpy()
            earlier = train - other
            assert np.all(earlier >= 0), "the knee rules include the training rule"
            differs = earlier != 0
            lines.append(
                {
                    "task": task,
                    "source": source,
                    "rule": name,
                    "rollouts": len(group),
                    "fell_training": int(np.sum(train < horizon)),
                    "fell_rule": int(np.sum(other < horizon)),
                    "first_fall_differs": int(differs.sum()),
                    "steps_earlier_median": float(np.median(earlier[differs])) if differs.any()
                    else 0.0,
                    "steps_earlier_max": int(earlier.max()) if len(earlier) else 0,
                    "fell_metric_changes": int(np.sum((train < horizon) != (other < horizon))),
                    "data_rows_lost": int(np.sum(np.minimum(train, horizon) - other)),
                    "data_rows": int(np.sum(np.minimum(train, horizon))),
                }
            )  # fmt: skip
    table = pd.DataFrame(lines)
    table["ms_earlier_max"] = table.steps_earlier_max * control_dt * 1000
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="walk,jump")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--losses", default="joint,task", help="comma-separated")
    parser.add_argument("--csv", default=None, help="write every rollout's steps here")
    args = parser.parse_args()
    instrument()
    start = time.perf_counter()
    rollouts = pd.concat([run_task(task, args) for task in args.tasks.split(",")])
    if args.csv:
        rollouts.to_csv(args.csv, index=False)
    table = summarise(rollouts)
    print(
        f"\n{args.seeds} seeds x {args.iterations} iterations, losses {args.losses}, "
        f"{time.perf_counter() - start:.0f} s; first-fall step of each rollout inside its "
        "horizon, knee rule against the training rule (0.004 s per step):\n"
    )
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.to_string(index=False))


if __name__ == "__main__":
    main()
