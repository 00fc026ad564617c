"""Command-line program ``cfm-jax`` (tyro turns the typed signatures into flags).

Examples:
  cfm-jax train --robot iiwa14 --task inverse_dynamics --loss all --seeds 3 \\
      --iterations 10 --out results/iiwa
  cfm-jax sweep --robot iiwa14 --task inverse_dynamics --losses joint,task --seeds 2 \\
      --iterations 1 --override task.kp=50,100 --out results/sweep
"""

from __future__ import annotations

import dataclasses
import json
import os
import time

import cfm_jax  # noqa: F401  (sets the XLA flag before JAX starts)
from cfm_jax import config as config_lib
from cfm_jax import losses, plots, report


def train(
    robot: str | None = None,
    task: str = "inverse_dynamics",
    loss: str = "all",
    seeds: int = 1,
    iterations: int = 4,
    out: str = "results/train",
    seed: int = 0,
    config: str | None = None,
    simulator: str | None = None,
    resume: bool = False,
    data: str | None = None,
    control_dt: float | None = None,
    site: str | None = None,
    babbling: str | None = None,
    quiet: bool = False,
) -> None:
    """Learn a tracking controller with Algorithm 1 and compare controller losses.

    Writes OUT/config.json, OUT/metrics.csv (one row per loss, seed, iteration, target;
    rewritten after every iteration), OUT/baselines.csv, OUT/summary.md and
    OUT/learning_curves.png, and prints the table of final tracking error per loss.

    Args:
      robot: registered robot name (iiwa14, two_link_arm, solo12) or path to an MJCF
        file (default: the task's robot, iiwa14 for the arm tasks and solo12 for walk and
        jump).
      task: task name (inverse_dynamics, opspace, walk, jump).
      loss: a controller loss (joint, task, distal, supervised, distal_literal), a
        comma-separated list of them, or "all" (the paper's four).
      seeds: number of seeds (run together as a vmap axis).
      iterations: iterations of Algorithm 1.
      out: output directory.
      seed: first seed.
      config: JSON file of a full config (as written to config.json); the flags above
        override its robot, task, seeds, iterations and seed. Without it, the task's
        defaults (cfm_jax.config.for_task: for walk and jump the paper's quadruped
        networks and 250 Hz control).
      simulator: physics back end, native (MuJoCo C) or mjx; default: the config's (native).
      resume: continue an interrupted run in OUT (same flags and config): every loss
        resumes from its newest valid checkpoint in OUT/<loss>/checkpoints (finished losses
        are only re-evaluated), losses without checkpoints start fresh.
      data: replay a recorded data set instead of collecting data (a run's
        OUT/<loss>/dataset.npz): every loss trains f and g from scratch on it, revealed
        iteration by iteration as it was recorded; the controller is evaluated on the
        robot every iteration. --seeds must equal the recorded run's.
      control_dt: control period in seconds (default: the config's or the task's).
      site: opspace: the end-effector site of the MJCF (default: "ee", else "flange").
      babbling: the initial data, loop.babbling (home, reaching, reference_pd, oracle; see
        cfm_jax.babbling); default: the config's (home).
      quiet: no progress bar.

    Examples:
      On the command line (``cfm-jax train --help`` lists every flag)::

          cfm-jax train --robot iiwa14 --loss all --seeds 3 --iterations 10 --out results/id
          cfm-jax train --robot iiwa14 --loss all --seeds 3 --out results/id --resume

      >>> train(robot="two_link_arm", iterations=1, out="/tmp/quick")  # doctest: +SKIP
    """
    from cfm_jax import training as train_lib

    names = _losses(loss)
    base = _base_config(
        robot, task, names[0], seed, seeds, iterations, config, simulator, control_dt, site
    )
    if babbling is not None:
        base = base.replace(loop=dataclasses.replace(base.loop, babbling=babbling))
    start = time.perf_counter()
    experiment = train_lib.Experiment(base)  # checks robot and config: nothing written yet
    if data is not None:  # a bad --data is refused before anything is written
        train_lib._recorded_for(experiment, base, data)
    os.makedirs(out, exist_ok=True)
    frames, result, notes = [], None, []
    for name in names:
        run_dir = os.path.join(out, name)
        can_resume = resume and os.path.isdir(os.path.join(run_dir, "checkpoints"))
        result = train_lib.train(
            base.replace(loss=name),
            progress=not quiet,
            out_dir=run_dir,
            experiment=experiment,
            resume=run_dir if can_resume else None,
            data=data,
        )
        frames.append(result.metrics)
        notes += _notes(name, result)
        _write_outputs(out, frames, result, base, experiment.task, notes)
    wall = time.perf_counter() - start
    metrics = _concat(frames)
    table = report.summary(metrics, result.baselines, result.rms_reach)
    label, unit = experiment.task.tracking_name, experiment.task.tracking_unit
    report.print_summary(
        table,
        title=f"{base.robot} {task}: final tracking MSE ({unit}^2), mean/std over "
        f"{seeds} seed(s) x targets, 95% CI over seeds; wall time {wall:.0f} s\n"
        + report.protocol(base).replace("`", ""),
        tracking=f"{label} ({unit}^2)",
    )
    if metrics["loss"].nunique() > 1:
        paired = report.paired_table(metrics, reference=None)  # joint (else the first loss)
        report.print_paired(paired, title=f"{base.robot} {task}: tracking MSE, paired by seed")
    for line in notes:
        print(line)
    print(
        f"RMS reaching distance {result.rms_reach:.4f} {unit}. Results in {out}/ "
        f"(metrics.csv, summary.md, learning_curves.png)"
    )


def _base_config(
    robot, task, loss, seed, seeds, iterations, config, simulator, control_dt, site
) -> config_lib.Config:
    """The config of the flags: the task's defaults (or the --config file) with the flags'
    robot, task, loss, seed, seeds, iterations, simulator, control_dt and site."""
    base = config_lib.for_task(task)
    if config is not None:
        base = config_lib.from_dict(_read_config(config))
    task_fields = {**config_lib.to_dict(base)["task"], "name": task}
    if control_dt is not None:
        task_fields["control_dt"] = control_dt
    if site is not None:
        task_fields["site"] = site
    return config_lib.Config(
        robot=base.robot if robot is None else robot,
        loss=loss,
        seed=seed,
        simulator=base.simulator if simulator is None else simulator,
        task=config_lib.TaskConfig(**task_fields),
        forward=base.forward,
        controller=base.controller,
        loop=config_lib.LoopConfig(
            **{**config_lib.to_dict(base)["loop"], "iterations": iterations, "seeds": seeds}
        ),
    )


def _read_config(path: str) -> dict:
    """The JSON of ``--config``; a missing or unreadable file, or text that is not JSON,
    raises :class:`cfm_jax.config.ConfigError` naming the file."""
    allowed = "a JSON file of a full config (as a run's config.json)"
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        config_lib._fail("--config", path, f"{allowed}; there is no such file")
    except IsADirectoryError:
        config_lib._fail("--config", path, f"{allowed}; it is a directory")
    except (OSError, UnicodeDecodeError) as error:
        config_lib._fail("--config", path, f"{allowed}; it cannot be read ({error})")
    except json.JSONDecodeError as error:
        config_lib._fail("--config", path, f"{allowed}; it is not JSON ({error})")


def sweep(
    robot: str | None = None,
    task: str = "inverse_dynamics",
    losses: str = "all",
    seeds: int = 1,
    iterations: int = 4,
    out: str = "results/sweep",
    override: tuple[str, ...] = (),
    seed: int = 0,
    config: str | None = None,
    simulator: str | None = None,
    control_dt: float | None = None,
    site: str | None = None,
    backend: str = "local",
    address: str | None = None,
    max_retries: int = 3,
    quiet: bool = False,
) -> None:
    """Run a grid of experiments (override values x losses, seeds vmapped in each cell).

    Writes OUT/cells/<cell>/ as each cell finishes (a re-run skips finished cells), then
    OUT/metrics.csv and OUT/metrics.parquet (one row per cell, seed, iteration, target,
    with a column per override), OUT/baselines.csv, OUT/cells.csv, OUT/sweep.json,
    OUT/summary.md (the protocol line; mean and std over seeds at the last iteration, the
    95% bootstrap CI over seeds and the paired comparison of the joint loss) and
    OUT/curves.png,
    and prints the summary table.

    Args:
      robot: registered robot name (iiwa14, two_link_arm, solo12) or path to an MJCF
        file (default: the task's robot, iiwa14 for the arm tasks and solo12 for walk and
        jump).
      task: task name (inverse_dynamics, opspace, walk, jump).
      losses: "all" (the paper's four: joint, task, distal, supervised), or a
        comma-separated list of controller losses (those and distal_literal).
      seeds: number of seeds (a vmap axis inside every cell).
      iterations: iterations of Algorithm 1.
      out: output directory.
      override: grid axes, each PATH=V1,V2,... (values parsed as JSON numbers, true/false,
        null, else text) or PATH=[JSON list] for values that contain commas, e.g.
        --override task.kp=50,100 controller.learning_rate=1e-3,3e-4
        'task.targets=[[[0.5,0.5]],[[1.0,0.2]]]'.
      seed: first seed.
      config: JSON file of a full config (as written to config.json); the flags above
        override its robot, task, seeds, iterations and seed. Without it, the task's
        defaults (cfm_jax.config.for_task).
      simulator: physics back end, native (MuJoCo C) or mjx; default: the config's (native).
      control_dt: control period in seconds (default: the config's or the task's).
      site: opspace: the end-effector site of the MJCF (default: "ee", else "flange").
      backend: local (this process) or ray (each cell a Ray task; pip install 'cfm_jax[ray]').
      address: ray: address of an existing cluster (host:port or auto); default: start a
        local one on this machine.
      max_retries: ray: retries of a cell whose worker process died.
      quiet: no progress output.

    Examples:
      On the command line (``cfm-jax sweep --help`` lists every flag)::

          cfm-jax sweep --robot iiwa14 --losses joint,task --seeds 3 --out results/s
          cfm-jax sweep --losses all --override task.kp=50,100 --backend ray --out results/kp

      >>> sweep(robot="two_link_arm", iterations=1, out="/tmp/sweep")  # doctest: +SKIP
    """
    from cfm_jax import sweeps

    names = _losses(losses, flag="--losses")
    base = _base_config(
        robot, task, names[0], seed, seeds, iterations, config, simulator, control_dt, site
    )
    grid_axes = dict(_override(text) for text in override)
    start = time.perf_counter()
    result = sweeps.sweep(
        base,
        losses=names,
        overrides=grid_axes,
        out_dir=out,
        backend=backend,
        address=address,
        max_retries=max_retries,
        progress=not quiet,
    )
    ran = int((result.cells["status"] == "ran").sum())
    print(result.markdown())
    print(
        f"{len(result.cells)} cells ({ran} ran, {len(result.cells) - ran} finished before); "
        f"wall time {time.perf_counter() - start:.0f} s. Results in {out}/ (metrics.csv, "
        "metrics.parquet, summary.md, curves.png, cells/)"
    )


def _override(text: str) -> tuple[str, list]:
    """``PATH=V1,V2`` or ``PATH=[JSON list]`` -> ``(PATH, [values])``."""
    path, sep, values = text.partition("=")
    if not sep or not path.strip() or not values.strip():
        raise config_lib.ConfigError(
            f"--override={text!r} is not allowed: PATH=V1,V2,... or PATH=[JSON list], "
            "e.g. task.kp=50,100"
        )
    values = values.strip()
    if values.startswith("["):
        try:
            parsed = json.loads(values)
        except json.JSONDecodeError as error:
            raise config_lib.ConfigError(
                f"--override={text!r} is not allowed: the values are not a JSON list ({error})"
            ) from None
        if not isinstance(parsed, list):
            raise config_lib.ConfigError(f"--override={text!r} is not allowed: a JSON list")
        return path.strip(), parsed
    return path.strip(), [_scalar(v.strip()) for v in values.split(",")]


def _scalar(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _losses(spec: str, flag: str = "--loss") -> list[str]:
    if spec == "all":
        return list(losses.PAPER_LOSSES)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    bad = [n for n in names if n not in losses.CONTROLLER_LOSSES]
    if not names or bad or len(set(names)) != len(names):
        raise config_lib.ConfigError(
            f"{flag}={spec!r} is not allowed: 'all' or a comma-separated list of distinct "
            f"names from {losses.CONTROLLER_LOSSES}"
        )
    return names


def _concat(frames):
    import pandas as pd

    return pd.concat(frames, ignore_index=True)


def _notes(loss: str, result) -> list[str]:
    """Lines naming what failed in a loss's run: diverged rollouts, seeds stopped by a
    non-finite training quantity, MuJoCo's captured warnings (empty when nothing did)."""
    lines = []
    metrics = result.metrics
    if "diverged" in metrics and len(metrics):
        bad = metrics[metrics["diverged"] == 1]
        if len(bad):
            first = bad.iloc[0]
            lines.append(
                f"{loss}: {len(bad)} of {len(metrics)} rollouts diverged (seeds "
                f"{sorted(int(x) for x in bad.seed.unique())}; the first: seed "
                f"{int(first.seed)}, target {int(first.target)}, iteration "
                f"{int(first.iteration)}, control step {int(first.diverged_step)}; all in "
                "metrics.csv, columns diverged and diverged_step)"
            )
    for entry in result.stopped:
        lines.append(
            f"{loss}: seed {entry['seed']} stopped at iteration {entry['iteration']}: its "
            f"{entry['quantity']} became non-finite (its last good state was kept)"
        )
    if result.warnings:
        counts = ", ".join(f"{text} ({n}x)" for text, n in result.warnings.items())
        lines.append(f"{loss}: MuJoCo warnings (captured, not printed): {counts}")
    return lines


def _write_outputs(out, frames, result, base, task, notes=()) -> None:
    """Write the combined files after every loss, so finished losses are never lost."""
    metrics = _concat(frames)
    metrics.to_csv(os.path.join(out, "metrics.csv"), index=False)
    result.baselines.to_csv(os.path.join(out, "baselines.csv"), index=False)
    with open(os.path.join(out, "config.json"), "w") as f:
        json.dump(config_lib.to_dict(base), f, indent=2)  # per-loss configs: OUT/<loss>/
    table = report.summary(metrics, result.baselines, result.rms_reach)
    text = report.protocol(base) + "\n\n" + report.markdown(table)
    if metrics["loss"].nunique() > 1:  # the joint loss (else the first) against the others
        text += "\n\n" + report.paired_markdown(report.paired_table(metrics, reference=None))
    if notes:
        text += "\n\nWhat failed:\n\n" + "\n".join(f"* {line}" for line in notes)
    with open(os.path.join(out, "summary.md"), "w") as f:
        f.write(text + "\n")
    plots.plot_learning_curves(
        metrics,
        os.path.join(out, "learning_curves.png"),
        result.baselines,
        title=f"{base.robot} {base.task.name}",
        tracking_label=f"{task.tracking_name} ({task.tracking_unit}$^2$)",
        output_unit=task.output_unit,
    )


def main() -> None:
    """Entry point of the ``cfm-jax`` command: dispatch to ``train``, ``sweep`` or ``bench``
    (tyro).

    Examples:
      >>> import sys
      >>> sys.argv = ["cfm-jax", "train", "--help"]  # doctest: +SKIP
      >>> main()  # doctest: +SKIP
    """
    import sys

    import tyro

    from cfm_jax import bench
    from cfm_jax.robots import RobotError

    try:
        tyro.extras.subcommand_cli_from_dict({"train": train, "sweep": sweep, "bench": bench.bench})
    except (config_lib.ConfigError, RobotError) as error:
        one_line = " ".join(str(error).split())  # MuJoCo's parser messages span lines
        print(f"cfm-jax: error: {one_line}", file=sys.stderr)
        raise SystemExit(2) from None
    except RuntimeError as error:
        from cfm_jax.sweeps import SweepError

        if not isinstance(error, SweepError):
            raise
        print(f"cfm-jax: error: {error}", file=sys.stderr)
        raise SystemExit(1) from None


if __name__ == "__main__":
    main()
