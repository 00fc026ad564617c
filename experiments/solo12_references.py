"""Print the Solo12 default references' numbers and rewrite the figures of docs/locomotion.md.

Usage: ``python experiments/solo12_references.py [OUT_DIR]`` (default ``docs/figures``).
The references are recorded once and cached (:mod:`cfm_jax.tasks.locomotion`); each is also
replayed from a perturbed start (base 5 mm higher, joints +-0.03 rad) to show how well
the feed-forward plus PD reference controller holds it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

import cfm_jax  # noqa: F401  (first: it sets the XLA flag before JAX starts)
from cfm_jax.analysis import plots
from cfm_jax.sim import render, solo12
from cfm_jax.tasks import locomotion


def main(out_dir: str = "docs/figures") -> None:
    """Print the default references' numbers and write the figures of docs/locomotion.md."""
    model = solo12.load_model()
    start = time.perf_counter()
    walks, jumps = locomotion.default_walks(), locomotion.default_jumps()
    print(f"references: {time.perf_counter() - start:.1f} s (cached after the first run)")
    for ref in walks + jumps:
        q0 = ref.qpos[0].copy()
        q0[2] += 0.005
        q0[7:] += 0.03 * np.where(np.arange(12) % 2, 1.0, -1.0)
        run = locomotion.replay(ref, model, qpos0=q0)
        row = locomotion.summary(ref)
        row["perturbed_base_err_m"] = float(np.abs(run.qpos[:, :3] - ref.qpos[:, :3]).max())
        row["perturbed_joint_rms_rad"] = float(np.sqrt(np.mean((run.qpos - ref.qpos)[:, 7:] ** 2)))
        print({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()})
    out = Path(out_dir)
    walk, jump = walks[-1], jumps[3]
    q0 = walk.qpos[0].copy()
    q0[2] += 0.005
    q0[7:] += 0.03 * np.where(np.arange(12) % 2, 1.0, -1.0)
    run = locomotion.replay(walk, model, qpos0=q0)
    sl = slice(0, int(round(1.5 / walk.control_dt)) + 1)
    plots.plot_foot_force(
        walk._replace(foot_force=walk.foot_force[sl]),
        out / "solo12_walk_force_FR.png",
        observed=run.foot_force[sl],
        foot="FR",
        title="trot reference (desired) vs replay from a perturbed start (observed), FR foot",
    )
    ok, why = render.render_available()
    if not ok:
        print(f"skipping pictures: {why}")
        return
    idx = np.linspace(int(0.9 / walk.control_dt), walk.horizon, 6).round().astype(int)
    cam = {"distance": 1.1, "azimuth": 90.0, "elevation": -12.0, "lookat": [0, 0, 0.15]}
    render.frame_strip(model, walk.qpos, out / "solo12_walk_strip.png", indices=idx, camera=cam)
    apex = int(np.argmax(jump.qpos[:, 2]))
    idx = [int(0.05 / jump.control_dt), int(0.4 / jump.control_dt), apex - 25, apex, apex + 40]
    idx.append(jump.horizon)
    cam = {"distance": 1.1, "azimuth": 90.0, "elevation": -5.0, "lookat": [0, 0, 0.25]}
    render.frame_strip(
        model, jump.qpos, out / "solo12_jump_strip.png", indices=idx, camera=cam, track=False
    )
    print(f"figures in {out}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
