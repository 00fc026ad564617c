"""The Solo12 study (paper section IV-B, Fig. 5, Fig. 6, Table I): learn to walk or jump
with each controller loss.

Runs ``cfm-jax train --robot solo12 --task {walk,jump} --loss all --seeds 5
--iterations 10`` (the four losses one after another, sharing babbling data and the
initial forward fit; an interrupted run resumes with ``--resume``; a finished run is only
re-evaluated) and writes, into ``--out``, besides the CLI's files (``metrics.csv``,
``baselines.csv``, ``summary.md``, ``learning_curves.png``):

* ``table_1.md``: the paper's Table I for this task: at the last iteration, the
  foot-force tracking MSE (N^2) per loss, mean and std over seeds x targets, and the 95%
  bootstrap CI over seeds (each seed averaged over its targets); the falls
  (fallen runs out of seeds x targets, and the seeds whose every horizon finished without
  a fall); the base position (m^2) and orientation (rad^2) tracking MSE. The oracle
  (reference controller) and the joint PD alone are given for scale.
* ``falls.png``: the share of fallen rollouts per iteration and loss.
* ``frames_<loss>.png``: frames of the first seed's learned controller on the longest
  target (the paper's walking image sequence; needs offscreen GL, ``MUJOCO_GL=egl``).
* ``force_<loss>.png``: desired, observed and forward-model-predicted force of the front
  right foot over that rollout (the paper's Fig. 6).

Usage:
  python experiments/solo_study.py --task walk --out results/solo_walk
  python experiments/solo_study.py --task jump --out results/solo_jump
  python experiments/solo_study.py --task jump --out /tmp/q --quick   # 1 seed, 1 iteration
  python experiments/solo_study.py --task walk --out results/solo_walk \
      --sweep results/robustness/walk/home-default   # the tables and pictures of a sweep

With ``--sweep SWEEP_DIR`` nothing is trained: the table, the falls and the pictures are
drawn from a finished ``cfm_jax.sweep`` of the losses on this task (its ``metrics.csv``,
``baselines.csv`` and each cell's run, ``cells/<cell id>/run``), for example the
robustness study's default cell, which runs the same config as this script (the same
numbers: a sweep cell is ``cfm_jax.train`` of its config).
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np
import pandas as pd

FOOT = "FR"  # the paper's Fig. 6 shows the front right foot


def study_config(task: str):
    """The config this script trains (before its seeds and iterations): the task's defaults
    as the records were made (``_study.for_task``: the walk's ``s*`` without joint position
    feedback), the robustness study's default cell's."""
    import _study

    return _study.for_task(task)


def table_1(metrics: pd.DataFrame, baselines: pd.DataFrame) -> pd.DataFrame:
    """Last-iteration force MSE, falls and base tracking per loss (and the baselines)."""
    from cfm_jax.analysis import report
    from cfm_jax.learning import losses

    def row(frame: pd.DataFrame, seeds: str) -> dict:
        ci = ""
        if "seed" in frame:  # the baselines have no seeds
            stats = report.mean_ci(frame.groupby("seed").force_mse.mean())
            ci = f"[{report._format(stats['low'])}, {report._format(stats['high'])}]"
        return {
            "force MSE mean (N^2)": frame.force_mse.mean(),
            "force MSE std": frame.force_mse.std(ddof=0),
            "95% CI over seeds": ci,
            "falls (runs)": f"{int(frame.fell.sum())} / {len(frame)}",
            "seeds without a fall": seeds,
            "base position MSE (m^2)": frame.base_position_mse.mean(),
            "base orientation MSE (rad^2)": frame.base_orientation_mse.mean(),
        }

    final = metrics[metrics.iteration == metrics.iteration.max()]
    rows = {}
    for loss in [name for name in losses.CONTROLLER_LOSSES if name in set(final["loss"])]:
        frame = final[final["loss"] == loss]
        per_seed = frame.groupby("seed").fell.max()
        rows[loss] = row(frame, f"{int((per_seed == 0).sum())} / {len(per_seed)}")
    for name, frame in baselines.groupby("baseline", sort=False):
        rows[name] = row(frame, "-")
    return pd.DataFrame.from_dict(rows, orient="index")


def plot_falls(metrics: pd.DataFrame, path: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    for loss, frame in metrics.groupby("loss", sort=False):
        share = frame.groupby("iteration").fell.mean()
        ax.plot(share.index, share.to_numpy(), marker="o", label=loss)
    ax.set_xlabel("iteration")
    ax.set_ylabel("fallen rollouts (share)")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def pictures(out: str, config, loss: str, run_dir: str | None = None) -> dict:
    """Roll out the first seed's final controller of ``loss`` (its finished run in
    ``run_dir``, default ``out/<loss>``) on the longest target; write its frame strip and
    the force plot of the front right foot into ``out``. Returns what was drawn."""
    import jax

    from cfm_jax.analysis import plots
    from cfm_jax.runs import training
    from cfm_jax.sim import render

    run_dir = run_dir or os.path.join(out, loss)
    experiment = training.Experiment(config.replace(loss=loss))
    result = training.train(
        config.replace(loss=loss), progress=False, experiment=experiment, resume=run_dir
    )
    state = jax.tree.map(lambda x: x[0], result.state)  # first seed
    task = experiment.task
    rollout_ = experiment.rollout_one(experiment.learned_policy(state), jax.random.key(0))
    target = task.targets - 1  # the longest walk, the highest jump
    ref = task.references[target]
    n = ref.horizon
    from cfm_jax.learning import algorithm

    # The forward model's per-transition terms where its kind has them (rigid_body: M^-1 S
    # and -M^-1 h of each state), as the library's metrics compute them.
    t = algorithm.with_terms(experiment.setup, rollout_.transitions)
    t = jax.tree.map(lambda x: x[target], t)
    norm = state.normaliser
    predicted = norm.output_inverse(
        experiment.forward.predict(state.forward_params, norm, t.state, t.action, terms=t.terms)
    )
    feet = task.feet
    observed = np.asarray(t.observed[:n, -3 * feet :]).reshape(n, feet, 3)
    predicted = np.asarray(predicted[:n, -3 * feet :]).reshape(n, feet, 3)
    fell = np.asarray(rollout_.extras["fell"][target, :n])
    first_fall = int(np.argmax(fell)) if fell.any() else None
    plots.plot_foot_force(
        ref,
        os.path.join(out, f"force_{loss}.png"),
        observed=observed,
        predicted=predicted,
        foot=FOOT,
        title=f"{config.task.name}, {loss} loss, seed {config.seed}: {FOOT} foot force"
        + ("" if first_fall is None else f" (fell at {first_fall * ref.control_dt:.2f} s)"),
    )
    drawn = {"loss": loss, "target": target, "fell_at_step": first_fall}
    qpos = np.asarray(t.state[:n, : task.robot.nq])  # s = [qpos, forces, qvel]
    ok, why = render.render_available()
    if ok:
        # The camera follows the base horizontally at a fixed height, so a jump shows.
        lookat = [float(qpos[0, 0]), float(qpos[0, 1]), float(qpos[0, 2])]
        render.frame_strip(
            task.robot.mj_model,
            qpos,
            os.path.join(out, f"frames_{loss}.png"),
            n_frames=8,
            camera={"lookat": lookat, "distance": 1.0, "azimuth": 90.0, "elevation": -5.0},
        )
    else:
        drawn["frames"] = f"not rendered: {why}"
    return drawn


def _from_sweep(sweep_dir: str, task: str):
    """A finished sweep's folder, its base config (the first cell's, any loss) and each
    loss's run folder; names what is missing or of another task."""
    from cfm_jax import config as config_lib

    path = os.path.join(sweep_dir, "cells.csv")
    if not os.path.isfile(os.path.join(sweep_dir, "metrics.csv")) or not os.path.isfile(path):
        raise SystemExit(
            f"--sweep={sweep_dir!r}: not a finished cfm_jax.sweep folder (it needs "
            "metrics.csv and cells.csv)"
        )
    cells = pd.read_csv(path)
    run_dirs = {row.loss: os.path.join(sweep_dir, "cells", row.cell, "run")
                for row in cells.itertuples()}  # fmt: skip
    with open(os.path.join(sweep_dir, "cells", cells.cell.iloc[0], "config.json")) as f:
        config = config_lib.from_dict(json.load(f))
    if config.task.name != task:
        raise SystemExit(
            f"--sweep={sweep_dir!r} holds task {config.task.name!r}, not --task={task!r}"
        )
    return sweep_dir, config, run_dirs


def main() -> None:
    from cfm_jax import cli
    from cfm_jax import config as config_lib
    from cfm_jax.analysis import report

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", choices=("walk", "jump"), required=True)
    parser.add_argument("--out", default=None)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--loss", default="all")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--quick", action="store_true", help="1 seed, 1 iteration (CI)")
    parser.add_argument(
        "--figures-only", action="store_true", help="only redraw the table and pictures of OUT"
    )
    parser.add_argument(
        "--pictures", default="joint,task", help="losses whose rollouts are drawn ('' none)"
    )
    parser.add_argument(
        "--sweep", default=None, metavar="SWEEP_DIR",
        help="draw from a finished cfm_jax.sweep of this task instead of training",
    )  # fmt: skip
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.iterations = 1, 1
    out = args.out or f"results/solo_{args.task}"
    if args.sweep:
        source, config, run_dirs = _from_sweep(args.sweep, args.task)
        os.makedirs(out, exist_ok=True)
    else:
        if not args.figures_only:
            os.makedirs(out, exist_ok=True)
            base = os.path.join(out, "study_config.json")
            with open(base, "w") as f:
                json.dump(config_lib.to_dict(study_config(args.task)), f, indent=1)
            cli.train(
                config=base,
                task=args.task,
                loss=args.loss,
                seeds=args.seeds,
                iterations=args.iterations,
                out=out,
                resume=args.resume,
                quiet=args.quiet,
            )
        source = out
        with open(os.path.join(out, "config.json")) as f:
            config = config_lib.from_dict(json.load(f))
        run_dirs = {
            name: os.path.join(out, name)
            for name in os.listdir(out)
            if os.path.isdir(os.path.join(out, name, "checkpoints"))
        }
    metrics = pd.read_csv(os.path.join(source, "metrics.csv"))
    baselines = pd.read_csv(os.path.join(source, "baselines.csv"))
    table = table_1(metrics, baselines)
    with open(os.path.join(out, "table_1.md"), "w") as f:
        f.write(report.protocol(config) + "\n\n" + report.markdown(table) + "\n")
    print(table.to_string())
    plot_falls(metrics, os.path.join(out, "falls.png"), f"solo12 {args.task}")
    drawn = [
        pictures(out, config, loss, run_dirs[loss])
        for loss in [s for s in args.pictures.split(",") if s]
        if loss in run_dirs
    ]
    with open(os.path.join(out, "pictures.json"), "w") as f:
        json.dump(drawn, f, indent=2)
    print(json.dumps(drawn))


if __name__ == "__main__":
    main()
