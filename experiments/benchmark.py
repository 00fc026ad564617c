"""Write docs/benchmarks.md: ``cfm-jax bench`` for both robots plus scaling sweeps.

Not a test: prints numbers and writes them to ``docs/benchmarks.md``. Everything is
measured by :mod:`cfm_jax.analysis.bench` (see its docstring for what each number means):

* ``cfm-jax bench`` for the iiwa14 (with the training iteration and the PyTorch
  reference) and for Solo12 (rollouts) at batch 16;
* rollout throughput of the library's closed loop and of ``mujoco.rollout`` versus batch
  (1 to 256);
* forward-ensemble updates per second per seed versus vmapped seeds (1 to 8), inside one
  ``lax.scan`` of updates.

Usage:
  python experiments/benchmark.py [--solo12 PATH] [--repeats 3]
"""

from __future__ import annotations

import argparse
import datetime
import os
import time

import cfm_jax  # noqa: F401  (sets the XLA flag before JAX starts)
from cfm_jax.analysis import bench

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def seed_scaling(seed_counts, fit_steps: int, repeats: int) -> list[dict]:
    """Forward-ensemble updates/s per seed with ``seeds`` vmapped fits (iiwa sizes)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from cfm_jax.learning import algorithm, networks
    from cfm_jax.sim import dataset

    state_dim, nv, rows = 14, 7, 15000
    rng = np.random.default_rng(0)
    flat = dataset.Transitions(
        *(jnp.asarray(rng.normal(size=(rows, d)), jnp.float32) for d in (state_dim, nv, nv, nv))
    )
    data = dataset.add(dataset.empty(rows, state_dim, nv), flat)
    norm = networks.Normaliser.from_data(flat.state, flat.observed, jnp.full(nv, 50.0))
    forward = networks.forward_model((400, 400, 400), 3, nv)
    optimizer = optax.adam(1e-3)
    out = []
    for seeds in seed_counts:
        keys = jax.random.split(jax.random.key(0), seeds)
        params = jax.vmap(lambda k: forward.init(k, state_dim))(keys)
        opt_state = jax.vmap(optimizer.init)(params)
        fit = jax.jit(
            jax.vmap(
                lambda p, o, k: algorithm.fit_forward(
                    forward, optimizer, p, o, norm, data, k, fit_steps, 256
                )
            )
        )
        jax.block_until_ready(fit(params, opt_state, keys))
        best = min(
            _timed(lambda fit=fit, p=params, o=opt_state, k=keys: fit(p, o, k))
            for _ in range(repeats)
        )
        out.append(dict(seeds=seeds, per_seed=fit_steps / best, total=seeds * fit_steps / best))
    for row in out:
        row["efficiency"] = row["per_seed"] / out[0]["per_seed"]
    return out


def _timed(fn) -> float:
    import jax

    start = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default_solo = os.path.join(ROOT, "robots", "solo12.xml")
    parser.add_argument("--solo12", default=default_solo, help="Solo12 MJCF")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks.md"))
    args = parser.parse_args()
    r = args.repeats

    iiwa = bench.run("iiwa14", batch=16, repeats=r)
    print(bench.table(iiwa), flush=True)
    solo = bench.run(args.solo12, batch=16, repeats=r, train=False)
    print(bench.table(solo), flush=True)
    sweeps = []
    for name, robot in (("iiwa14", "iiwa14"), ("solo12", args.solo12)):
        b = bench.Bench.load(robot)
        for batch in (1, 4, 16, 64, 256):
            row = bench.measure_rollout(b, batch, 200, r)
            sweeps.append(dict(robot=name, **row))
            print(sweeps[-1], flush=True)
    seeds = seed_scaling((1, 2, 4, 8), fit_steps=50, repeats=r)
    print(seeds, flush=True)

    def rollout_line(name, x):
        return (
            f"| {name} | {x['batch']} | {x['rollout_steps_per_s']:,.0f} | "
            f"{x['native_steps_per_s']:,.0f} | {x['ratio']:.2f} | {x['rollout_compile_s']:.1f} |"
        )

    head = [
        "| robot | batch | cfm_jax closed loop (steps/s) | mujoco.rollout 2 threads, open "
        "loop (steps/s) | ratio | compile (s) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    headline = head + [rollout_line("iiwa14", iiwa), rollout_line("solo12", solo)]
    sweep = head + [rollout_line(x["robot"], x) for x in sweeps]
    it = iiwa
    breakdown = [
        "| part | seconds | share of the parts |",
        "|---|---:|---:|",
    ]
    parts = ("rollout_s", "forward_update_s", "controller_update_s")
    total = sum(it[p] for p in parts)
    for p in parts:
        breakdown.append(f"| {p[:-2].replace('_', ' ')} | {it[p]:.3f} | {it[p] / total:.0%} |")
    breakdown.append(f"| **one iteration, compiled as one function** | {it['iteration_s']:.3f} | |")
    updates = [
        "| update (batch 256) | cfm_jax (updates/s) | PyTorch 1 thread | PyTorch 2 threads "
        "| cfm_jax / best PyTorch |",
        "|---|---:|---:|---:|---:|",
    ]
    if it.get("torch_version"):
        for n, label in (("forward", "forward ensemble 3 x 400^3, NLL"),
                         ("controller", "controller 300-200-100, joint loss")):  # fmt: skip
            updates.append(
                f"| {label} | {it[f'{n}_updates_per_s']:.1f} | "
                f"{it[f'torch_{n}_updates_per_s_1t']:.1f} | "
                f"{it[f'torch_{n}_updates_per_s_2t']:.1f} | "
                f"{it[f'{n}_speedup_vs_torch']:.2f}x |"
            )
    seed_table = [
        "| vmapped seeds | updates/s per seed | updates/s total | per-seed rate vs 1 seed |",
        "|---:|---:|---:|---:|",
    ] + [
        f"| {x['seeds']} | {x['per_seed']:.1f} | {x['total']:.1f} | {x['efficiency']:.2f} |"
        for x in seeds
    ]
    with open(os.path.join(ROOT, "docs", "benchmarks_notes.md")) as f:
        notes = f.read()
    # The sections of sweep_benchmark.py, mjx_benchmark.py and gpu_check.py, kept as they are.
    for name, marker in (
        ("benchmarks_gpu.md", "gpu-check"),
        ("benchmarks_mjx.md", "mjx-benchmark"),
        ("benchmarks_sweep.md", "sweep-benchmark"),
    ):
        path = os.path.join(ROOT, "docs", name)
        if os.path.isfile(path):
            with open(path) as f:
                notes = f"<!-- {marker} -->\n" + f.read() + f"<!-- /{marker} -->\n\n" + notes
    text = (
        "# Benchmarks\n\n"
        f"Written by `python experiments/benchmark.py`, {datetime.date.today().isoformat()}.\n\n"
        f"- Machine: {iiwa['machine']}\n- Versions: {iiwa['versions']}, "
        f"torch {it.get('torch_version')}\n"
        f"- Peak memory of the iiwa bench process: {iiwa['peak_memory_mib']:.0f} MiB\n\n"
        "## Acceptance runs (`cfm-jax bench --robot R --batch 16 --json`)\n\n"
        + "\n".join(headline)
        + "\n\nOne training iteration (iiwa14, 5 targets x 200 control steps, 200 forward and "
        "200 controller Adam steps at batch 256), compiled as one function: "
        f"{it['iteration_s']:.2f} s, compile {it['iteration_compile_s']:.1f} s, "
        f"recompiled after the first call: {it['recompiled_after_first']}.\n\n"
        + "\n".join(breakdown)
        + "\n\n"
        + "\n".join(updates)
        + "\n\n## Rollout throughput versus batch\n\n"
        + "\n".join(sweep)
        + "\n\n## Forward-ensemble updates versus vmapped seeds\n\n"
        "50 Adam steps of the 3 x 400^3 ensemble at batch 256 per member inside one "
        "`lax.scan`, `vmap`ped over seeds.\n\n" + "\n".join(seed_table) + "\n\n" + notes
    )
    with open(args.out, "w") as f:
        f.write(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
