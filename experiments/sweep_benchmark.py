"""Benchmark: what sharing one compilation across runtime overrides saves in a sweep.

Not a test: prints numbers and writes them to ``docs/benchmarks_sweep.md`` and into the
marked section of ``docs/benchmarks.md``. One sweep of the iiwa14 inverse-dynamics task
(the paper's networks, short fits) over ``controller.learning_rate`` and ``task.kp``
(runtime fields: arguments of the compiled functions) is run twice from a cold process
state: as ``cfm_jax.sweep`` runs it (one ``Experiment`` for every cell), and with a fresh
``Experiment`` per cell (what every cell cost before these values became arguments).
Both must give the same table bit for bit; the script says so and fails otherwise.

    python experiments/sweep_benchmark.py            # 2 x 2 cells, about 3 minutes
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time

import _study

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _config(iterations: int, seeds: int):
    from cfm_jax import config as cfg

    base = cfg.for_task("inverse_dynamics", robot="iiwa14")
    return base.replace(
        forward=cfg.ForwardModelConfig(initial_steps=100, steps_per_iteration=50),
        controller=cfg.ControllerConfig(initial_steps=100, steps_per_iteration=50),
        # the torque scale the page's numbers were measured on
        loop=cfg.LoopConfig(
            iterations=iterations, seeds=seeds, torque_scale=_study.BEFORE_POSE["loop.torque_scale"]
        ),
    )


def _run(config, overrides, fresh: bool) -> tuple[float, object, int, list[dict]]:
    """Wall time, result, number of Experiments built and their compilation counts."""
    import cfm_jax
    from cfm_jax.learning import algorithm
    from cfm_jax.runs import sweeps

    built = []

    def runner(cell_config, run_dir):
        if fresh:
            algorithm.clear_shared()
        before = set(map(id, algorithm._SHARED.values()))
        output = sweeps.run_cell(cell_config, run_dir)
        built.extend(e for e in algorithm._SHARED.values() if id(e) not in before)
        return output

    algorithm.clear_shared()
    start = time.perf_counter()
    result = cfm_jax.sweep(
        config, seeds=config.loop.seeds, losses=["joint"], overrides=overrides,
        runner=runner, progress=False,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    counts = [e.compilations() for e in built]
    return seconds, result, len(built), counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks_sweep.md"))
    args = parser.parse_args()
    import pandas as pd

    from cfm_jax.analysis import bench

    load = os.getloadavg()[0]
    config = _config(args.iterations, args.seeds)
    overrides = {"controller.learning_rate": [1e-3, 3e-4], "task.kp": [50.0, 100.0]}
    cells = 1
    for values in overrides.values():
        cells *= len(values)
    shared_s, shared, shared_built, shared_counts = _run(config, overrides, fresh=False)
    print(f"shared: {shared_s:.1f} s, {shared_built} Experiment(s)", shared_counts, flush=True)
    fresh_s, fresh, fresh_built, _ = _run(config, overrides, fresh=True)
    print(f"fresh per cell: {fresh_s:.1f} s, {fresh_built} Experiment(s)", flush=True)
    columns = [c for c in shared.metrics.columns if c != "cell"]
    pd.testing.assert_frame_equal(shared.metrics[columns], fresh.metrics[columns], check_exact=True)
    iteration = shared_counts[0].get("refit[joint]")  # the iteration's compiled refits
    lines = [
        "## Sweeps: one compilation across runtime overrides",
        "",
        f"Written by `python experiments/sweep_benchmark.py`, "
        f"{datetime.date.today().isoformat()} ({bench.machine()}; load average at the "
        f"start {load:.1f}).",
        "",
        f"iiwa14 `inverse_dynamics`, the paper's networks, {args.seeds} seeds vmapped, "
        f"{args.iterations} iterations, fits of 100 then 50 Adam steps; the joint loss; "
        f"overrides `controller.learning_rate` = 1e-3, 3e-4 and `task.kp` = 50, 100 "
        f"({cells} cells). Both ways give the same table bit for bit (checked by the script).",
        "",
        "| how the cells run | Experiments built | wall time (s) | per cell (s) |",
        "|---|---:|---:|---:|",
        f"| `cfm_jax.sweep`: values are arguments, one `Experiment` | {shared_built} | "
        f"{shared_s:.1f} | {shared_s / cells:.1f} |",
        f"| a fresh `Experiment` per cell (each compiles again, as before) | {fresh_built} | "
        f"{fresh_s:.1f} | {fresh_s / cells:.1f} |",
        "",
        f"Programs compiled by the shared experiment: {shared_counts[0]}: the iteration "
        f"{iteration} time(s) for all {cells} cells; the rollout once per batch shape "
        "(babbling, evaluation, baselines).",
        "",
    ]
    section = "\n".join(lines)
    print(section)
    _study.write_benchmark_section(args.out, "sweep-benchmark", section)


if __name__ == "__main__":
    sys.exit(main())
