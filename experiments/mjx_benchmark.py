"""MJX against the native simulator, per task: rollout throughput and one training iteration.

Not a test: prints numbers and writes them to ``docs/benchmarks_mjx.md`` and into the
``<!-- mjx-benchmark -->`` section of ``docs/benchmarks.md`` (``benchmark.py`` keeps the
section when it rewrites that page). For each task at its default references (targets,
horizon, control rate, oracle; one seed) and for both simulators it measures:

* the rollout of every target (the babbling policy, which carries every branch of the
  mixed policy: controller, feedback, oracle, noise), compiled once: compile + first call,
  then the median of ``--repeats`` calls, and control steps per second (targets x steps
  / time);
* one iteration of Algorithm 1 (rollout, metrics, adding the data, refitting f and g) at
  small networks and fits (``--fit-steps`` Adam steps each), second call (the first
  compiles).

``TASK:ORACLE`` in ``--tasks`` measures a task with another ``task.oracle`` (the default list
has ``inverse_dynamics:step``: the period-exact oracle's cost against the one-step one's).
Networks are small (``hidden=(64,)``) so that the physics is what is measured. Run with
nothing else on the machine. On a GPU the same script measures the GPU (``--tasks`` to
choose).

Usage:
  python experiments/mjx_benchmark.py [--tasks inverse_dynamics,inverse_dynamics:step,...]
      [--repeats 3] [--fit-steps 20] [--out docs/benchmarks_mjx.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import time

import _study

import cfm_jax  # noqa: F401  (first: it sets the XLA flag before JAX starts)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = ("inverse_dynamics", "inverse_dynamics:step", "opspace", "walk", "jump")


def config_for(task: str, simulator: str, fit_steps: int, oracle: str | None = None):
    import dataclasses

    from cfm_jax import config as cfg

    base = cfg.for_task(task)
    if oracle is not None:
        base = base.replace(task=dataclasses.replace(base.task, oracle=oracle))
    return base.replace(
        simulator=simulator,
        forward=cfg.ForwardModelConfig(
            hidden=(64,), ensemble_size=1, initial_steps=fit_steps, steps_per_iteration=fit_steps
        ),
        controller=cfg.ControllerConfig(
            hidden=(64,), initial_steps=fit_steps, steps_per_iteration=fit_steps
        ),
        # the torque scale the page's numbers were measured on
        loop=cfg.LoopConfig(
            iterations=2,
            seeds=1,
            babbling_rollouts=1,
            torque_scale=_study.BEFORE_POSE["loop.torque_scale"],
        ),
    )


def measure(task: str, simulator: str, repeats: int, fit_steps: int, oracle=None) -> dict:
    import jax

    from cfm_jax.runs import training

    exp = training.Experiment(config_for(task, simulator, fit_steps, oracle))
    policy = exp.babbling_policy()
    rollout = jax.jit(exp.rollout_one)
    key = jax.random.key(0)
    start = time.perf_counter()
    jax.block_until_ready(rollout(policy, key))
    first = time.perf_counter() - start
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(rollout(policy, jax.random.key(i + 1)))
        times.append(time.perf_counter() - start)
    rollout_s = statistics.median(times)
    keys = jax.vmap(jax.random.key)(jax.numpy.arange(1, dtype=jax.numpy.uint32))
    state = jax.block_until_ready(exp.init("joint", keys))
    start = time.perf_counter()
    state, _ = jax.block_until_ready(exp.iteration("joint", state))
    iteration_first = time.perf_counter() - start
    start = time.perf_counter()
    jax.block_until_ready(exp.iteration("joint", state))
    iteration_s = time.perf_counter() - start
    steps = exp.task.targets * exp.task.steps
    return {
        "task": task,
        "oracle": exp.config.task.oracle,
        "simulator": simulator,
        "robot": exp.config.robot,
        "targets": exp.task.targets,
        "steps": exp.task.steps,
        "rollout_compile_s": first - rollout_s,
        "rollout_s": rollout_s,
        "steps_per_s": steps / rollout_s,
        "iteration_first_s": iteration_first,
        "iteration_s": iteration_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--fit-steps", type=int, default=20)
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks_mjx.md"))
    parser.add_argument("--results", default=os.path.join(ROOT, "results", "mjx_benchmark"))
    args = parser.parse_args()
    import jax

    from cfm_jax import config as config_lib
    from cfm_jax.analysis import bench

    os.makedirs(args.results, exist_ok=True)
    load = os.getloadavg()[0]
    device = f"{jax.default_backend()} ({jax.devices()[0].device_kind})"
    rows = []
    for item in args.tasks.split(","):
        task, _, oracle = item.partition(":")
        oracle = oracle or None
        for simulator in ("native", "mjx"):
            # one-step-oracle rows keep the file names they had before task.oracle existed
            used = oracle or config_lib.for_task(task).task.oracle
            named = task if used == "step" else f"{task}-{used}"
            path = os.path.join(args.results, f"{jax.default_backend()}-{named}-{simulator}.json")
            if os.path.isfile(path):  # resumable: one file per measured pair
                with open(path) as f:
                    rows.append(json.load(f))
                continue
            row = measure(task, simulator, args.repeats, args.fit_steps, oracle)
            print(json.dumps(row), flush=True)
            with open(path, "w") as f:
                json.dump(row, f)
            rows.append(row)
    lines = [
        f"## MJX and the native simulator per task ({jax.default_backend()})",
        "",
        f"Written by `python experiments/mjx_benchmark.py`, "
        f"{datetime.date.today().isoformat()} ({bench.machine()}; device {device}; load "
        f"average at the start {load:.1f}).",
        "",
        "Each task at its default references, one seed; the rollout of every target with "
        "the babbling policy (every branch of the mixed policy); one iteration of "
        f"Algorithm 1 with `hidden=(64,)` networks and {args.fit_steps} Adam steps per fit "
        "(the second call; the first compiles).",
        "",
        "| task | robot | oracle | simulator | targets x steps | rollout compile (s) "
        "| rollout (s) | control steps/s | iteration (s) | first iteration (s) |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['robot']} | {r.get('oracle', 'step')} | {r['simulator']} "
            f"| {r['targets']} x {r['steps']} "
            f"| {r['rollout_compile_s']:.1f} | {r['rollout_s']:.3f} | {r['steps_per_s']:.0f} "
            f"| {r['iteration_s']:.2f} | {r['iteration_first_s']:.1f} |"
        )
    lines.append("")
    section = "\n".join(lines)
    print(section)
    _study.write_benchmark_section(args.out, "mjx-benchmark", section)


if __name__ == "__main__":
    main()
