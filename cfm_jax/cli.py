"""Command-line program ``cfm-jax`` (tyro turns the typed signatures into flags).

Examples:
  cfm-jax train --robot iiwa14 --task inverse_dynamics --loss all --seeds 3 \\
      --iterations 10 --out results/iiwa
  cfm-jax sweep --robot iiwa14 --task inverse_dynamics --losses joint,task --seeds 2 \\
      --iterations 1 --override task.kp=50,100 --out results/sweep
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import inspect
import json
import os
import re
import sys
import tempfile
import time
from typing import Annotated

import tyro
from tyro.conf import arg as tyro_arg

import cfm_jax  # (sets the XLA flag before JAX starts)
from cfm_jax import config as config_lib
from cfm_jax._files import write_atomic, write_text
from cfm_jax.analysis import plots, report


def train(
    robot: str | None = None,
    task: str | None = None,
    loss: str = "all",
    seeds: int | None = None,
    iterations: int | None = None,
    out: str = "results/train",
    seed: int | None = None,
    config: str | None = None,
    simulator: str | None = None,
    resume: bool = False,
    data: str | None = None,
    control_dt: float | None = None,
    site: str | None = None,
    babbling: str | None = None,
    quiet: bool = False,
    tensorboard: str | None = None,
    restart: bool = False,
) -> None:
    """Learn a tracking controller with Algorithm 1 and compare controller losses.

    Writes OUT/config.json, OUT/metrics.csv (one row per loss, seed, iteration, target;
    rewritten after every iteration), OUT/baselines.csv, OUT/summary.md and
    OUT/learning_curves.png, and prints the table of final tracking error per loss.

    Args:
      robot: registered robot name (iiwa14, two_link_arm, solo12) or path to an MJCF
        file (default: the task's robot, iiwa14 for the arm tasks and solo12 for walk and
        jump).
      task: task name (inverse_dynamics, opspace, walk, jump); None: the config file's,
        else inverse_dynamics.
      loss: a controller loss (joint, task, distal, supervised, distal_literal, or one
        registered with cfm_jax.learning.losses.register: cfm-jax --import MODULE train ...), a
        comma-separated list of them, or "all" (the paper's four).
      seeds: number of seeds (run together as a vmap axis); None: the config's (1).
      iterations: iterations of Algorithm 1; None: the config file's, else the task's (4).
      out: output directory.
      seed: first seed; None: the config's (0).
      config: JSON file of a full config (as written to config.json); the arguments above
        that are not None override its robot, task, seeds, iterations and seed. Without
        it, the task's defaults (cfm_jax.config.for_task: for walk and jump the paper's
        quadruped networks and 250 Hz control).
      simulator: physics back end, native (MuJoCo C) or mjx; default: the config's (native).
      resume: continue an interrupted run in OUT (same flags and config; a larger
        --loop.iterations continues a finished one for more iterations): every loss
        resumes from its newest valid checkpoint in OUT/<loss>/checkpoints (finished losses
        are only re-evaluated), losses without checkpoints start fresh.
      restart: start the run in OUT again from nothing (for a run whose checkpoints are all
        damaged): what OUT holds is first moved aside, whole, to OUT.replaced-TIME (nothing
        is deleted).
      data: replay a recorded data set instead of collecting data (a run's
        OUT/<loss>/dataset.npz): every loss trains f and g from scratch on it, revealed
        iteration by iteration as it was recorded; the controller is evaluated on the
        robot every iteration. --seeds must equal the recorded run's.
      control_dt: control period in seconds (default: the config's or the task's).
      site: opspace: the end-effector site of the MJCF (default: "ee", else "flange", else
        "attachment_site").
      babbling: the initial data, loop.babbling (home, reaching, reference_pd, oracle; see
        cfm_jax.tasks.babbling); default: the config's (the task's default: reaching for the arm
        tasks, home for the legged ones).
      quiet: no progress bar.
      tensorboard: also write TensorBoard event files to this folder (needs tensorboardX:
        pip install 'cfm_jax[tensorboard]'): after every iteration one scalar per loss and
        metric, tag LOSS/METRIC, the mean over seeds and targets (cfm_jax.analysis.tensorboard).

    Examples:
      On the command line (``cfm-jax train --help`` lists every flag)::

          cfm-jax train --robot iiwa14 --loss all --seeds 3 --iterations 10 --out results/id
          cfm-jax train --robot iiwa14 --loss all --seeds 3 --out results/id --resume

      >>> # not run: it trains (minutes) and writes /tmp/quick
      >>> train(robot="two_link_arm", iterations=1, out="/tmp/quick")  # doctest: +SKIP
    """
    names = _losses(loss)
    base = _base_config(
        robot, task, names[0], seed, seeds, iterations, config, simulator, control_dt, site
    )
    if babbling is not None:
        base = base.replace(loop=dataclasses.replace(base.loop, babbling=babbling))
    _run_train(base, names, out, resume, data, quiet, tensorboard, restart)


def _run_train(base, names, out, resume, data, quiet, tensorboard=None, restart=False) -> None:
    """Train every loss of ``names`` on ``base`` into ``out`` and print the tables
    (``restart``: after the checks, what ``out`` holds is moved aside, :func:`_move_aside`)."""
    from cfm_jax.analysis import tensorboard as tensorboard_lib
    from cfm_jax.runs import checkpoint
    from cfm_jax.runs import training as train_lib

    if tensorboard is not None and not tensorboard_lib.available():
        config_lib.fail("--tensorboard", tensorboard, tensorboard_lib.MISSING)
    start = time.perf_counter()
    _check_out(out)
    experiment = train_lib.Experiment.shared(base)  # checks robot, config: nothing written yet
    if data is not None:  # a bad --data is refused before anything is written
        train_lib.recorded_for(experiment, base, data)
    runs = [out] + [os.path.join(out, name) for name in names]
    if resume and not any(os.path.isfile(os.path.join(run, "config.json")) for run in runs):
        config_lib.fail(
            "--out",
            out,
            "--resume continues a run, and there is none here (no config.json in it or in "
            "its loss folders); start it without --resume",
        )
    if resume and restart:
        config_lib.fail(
            "--restart",
            True,
            "--resume continues the run in --out and --restart starts it "
            "again from nothing: give one of them",
        )
    if restart and os.path.isdir(out) and os.listdir(out):
        aside = _move_aside(out)
        print(f"cfm-jax: --restart: the old run in {out} is now in {aside}", file=sys.stderr)
    if not resume:  # a new run would meet the old one's checkpoints after its babbling
        held = [name for name in names if checkpoint.has_steps(os.path.join(out, name))]
        if held:
            config_lib.fail(
                "--out",
                out,
                f"it already holds checkpoints of a run (losses {held}); add --resume to "
                "continue that run, or give another --out",
            )
    with _removed_if_empty(out), contextlib.ExitStack() as stack:
        os.makedirs(out, exist_ok=True)
        writer = None
        if tensorboard is not None:
            writer = stack.enter_context(tensorboard_lib.TensorBoardWriter(tensorboard))
        frames, result, notes = _train_losses(
            base, names, out, resume, data, quiet, experiment, progress_fn=writer
        )
    wall = time.perf_counter() - start
    _print_train(base, experiment, frames, result, notes, out, wall)


def _move_aside(out: str) -> str:
    """Move the folder ``out`` whole to ``OUT.replaced-<UTC time>`` (a number added if that
    exists) and return the new path: ``--restart`` deletes nothing."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = f"{os.path.normpath(out)}.replaced-{stamp}"
    number = 1
    while os.path.exists(aside):
        number += 1
        aside = f"{os.path.normpath(out)}.replaced-{stamp}-{number}"
    os.rename(out, aside)
    return aside


def _train_losses(base, names, out, resume, data, quiet, experiment, progress_fn=None):
    """Train the losses together (:func:`cfm_jax.train` with ``losses``: one babbling and
    initial fit of f per seed), each into OUT/<loss>; the top-level metrics.csv
    is rewritten after every iteration from the losses' own files, the other combined files
    at the end. ``progress_fn`` (e.g. the TensorBoard writer) is called as train calls it."""
    from cfm_jax.runs import training as train_lib

    def iteration_done(iteration, rows):
        # train wrote OUT/<loss>/metrics.csv (every row of that loss so far, restored ones
        # included) just before calling this
        paths = [os.path.join(out, name, "metrics.csv") for name in names]
        _write_metrics(out, [_read_csv(path) for path in paths if os.path.isfile(path)])
        if progress_fn is not None:
            progress_fn(iteration, rows)

    result = train_lib.train(
        base,
        progress=not quiet,
        out_dir=out,
        experiment=experiment,
        resume=out if resume else None,
        data=data,
        progress_fn=iteration_done,
        losses=names,
    )
    frames, notes = [], []
    for name in names:
        own = result.of(name)
        frames.append(own.metrics)
        notes += _notes(name, dataclasses.replace(own, warnings={}))
    if result.warnings:
        counts = ", ".join(f"{text} ({n}x)" for text, n in result.warnings.items())
        notes.append(f"MuJoCo warnings (captured, not printed): {counts}")
    _write_outputs(out, frames, result, base, experiment.task, notes, names)
    return frames, result, notes


def _read_csv(path: str):
    import pandas as pd

    return pd.read_csv(path)


def _write_metrics(out: str, frames) -> None:
    """OUT/metrics.csv: the rows of ``frames``, written whole and renamed into place."""
    metrics = _concat(frames)
    write_atomic(os.path.join(out, "metrics.csv"), lambda tmp: metrics.to_csv(tmp, index=False))


def _print_train(base, experiment, frames, result, notes, out, wall) -> None:
    """Print the summary table, the paired comparison and what failed."""
    task, seeds = base.task.name, base.loop.seeds
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
    """The config of :func:`train`'s arguments: the --config file (else the task's defaults,
    :func:`cfm_jax.config.for_task`, what Python's ``Config`` gives) with the arguments
    that are not None: robot, task, seed, seeds, iterations, simulator, control_dt and
    site; and ``loss``."""
    if config is not None:
        base = config_lib.from_dict(_read_config(config))
    else:
        base = config_lib.for_task(task or "inverse_dynamics")
    data = config_lib.to_dict(base)
    data["loss"] = loss
    for section, name, value in (
        (None, "robot", robot),
        (None, "seed", seed),
        (None, "simulator", simulator),
        ("task", "name", task),
        ("task", "control_dt", control_dt),
        ("task", "site", site),
        ("loop", "seeds", seeds),
        ("loop", "iterations", iterations),
    ):
        if value is not None:
            (data if section is None else data[section])[name] = value
    return config_lib.from_dict(data)


def _check_out(out: str) -> None:
    """One ``cfm-jax: error:`` line, before any work, for an ``--out`` that is a file or a
    folder that cannot be created (a file on its path, no write permission)."""
    if os.path.exists(out) and not os.path.isdir(out):
        config_lib.fail("--out", out, "it is a file; give a folder (new or existing)")
    above = os.path.abspath(out)
    while not os.path.exists(above):
        above = os.path.dirname(above)
    if not os.path.isdir(above):
        config_lib.fail("--out", out, f"the folder cannot be created: {above} is a file")
    if not os.path.isdir(out) and not os.access(above, os.W_OK | os.X_OK):
        config_lib.fail("--out", out, f"the folder cannot be created: {above} is not writable")
    if not os.path.isdir(out):  # what os.access cannot see (root; a read-only or virtual
        try:  # file system): make a folder there and take it away again, nothing left
            os.rmdir(tempfile.mkdtemp(dir=above))
        except OSError as error:
            config_lib.fail("--out", out, f"the folder cannot be created: {error.strerror}")


@contextlib.contextmanager
def _removed_if_empty(out: str):
    """Remove the directory ``out`` if it did not exist before and the block failed with it
    still empty (a failed run leaves no empty output directory behind)."""
    existed = os.path.isdir(out)
    try:
        yield
    except BaseException:
        if not existed and os.path.isdir(out) and not any(os.scandir(out)):
            os.rmdir(out)
        raise


def _read_config(path: str) -> dict:
    """The JSON of ``--config``; a missing or unreadable file, or text that is not JSON,
    raises :class:`cfm_jax.config.ConfigError` naming the file."""
    allowed = "a JSON file of a full config (as a run's config.json)"
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        config_lib.fail("--config", path, f"{allowed}; there is no such file")
    except IsADirectoryError:
        config_lib.fail("--config", path, f"{allowed}; it is a directory")
    except (OSError, UnicodeDecodeError) as error:
        config_lib.fail("--config", path, f"{allowed}; it cannot be read ({error})")
    except json.JSONDecodeError as error:
        config_lib.fail("--config", path, f"{allowed}; it is not JSON ({error})")


def sweep(
    robot: str | None = None,
    task: str | None = None,
    losses: str = "all",
    seeds: int | None = None,
    iterations: int | None = None,
    out: str = "results/sweep",
    override: tuple[str, ...] = (),
    seed: int | None = None,
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
    OUT/metrics.csv and, with pyarrow installed, OUT/metrics.parquet (one row per cell,
    seed, iteration, target, with a column per override), OUT/baselines.csv, OUT/cells.csv,
    OUT/sweep.json,
    OUT/summary.md (the protocol line; mean and std over seeds at the last iteration, a
    bootstrap 95% CI over seeds and the paired comparison of the joint loss) and
    OUT/curves.png, and prints the summary table.

    Args:
      robot: registered robot name (iiwa14, two_link_arm, solo12) or path to an MJCF
        file (default: the task's robot, iiwa14 for the arm tasks and solo12 for walk and
        jump).
      task: task name (inverse_dynamics, opspace, walk, jump); None: the config file's,
        else inverse_dynamics.
      losses: "all" (the paper's four: joint, task, distal, supervised), or a
        comma-separated list of controller losses (those and distal_literal).
      seeds: number of seeds (a vmap axis inside every cell); None: the config's (1).
      iterations: iterations of Algorithm 1; None: the config file's, else the task's (4).
      out: output directory.
      override: grid axes, each PATH=V1,V2,... (values parsed as JSON numbers, true/false,
        null, else text) or PATH=[JSON list] for values that contain commas, e.g.
        --override task.kp=50,100 controller.learning_rate=1e-3,3e-4
        'task.targets=[[[0.5,0.5]],[[1.0,0.2]]]'.
      seed: first seed; None: the config's (0).
      config: JSON file of a full config (as written to config.json); the arguments above
        that are not None override its robot, task, seeds, iterations and seed. Without
        it, the task's defaults (cfm_jax.config.for_task).
      simulator: physics back end, native (MuJoCo C) or mjx; default: the config's (native).
      control_dt: control period in seconds (default: the config's or the task's).
      site: opspace: the end-effector site of the MJCF (default: "ee", else "flange", else
        "attachment_site").
      backend: local (this process) or ray (each cell a Ray task; pip install 'cfm_jax[ray]').
      address: ray: address of an existing cluster (host:port or auto); default: start a
        local one on this machine.
      max_retries: ray: retries of a cell whose worker process died.
      quiet: no progress output.

    Examples:
      On the command line (``cfm-jax sweep --help`` lists every flag)::

          cfm-jax sweep --robot iiwa14 --losses joint,task --seeds 3 --out results/s
          cfm-jax sweep --losses all --override task.kp=50,100 --backend ray --out results/kp
          cfm-jax sweep --override task.kp=50,100 controller.learning_rate=1e-3,3e-4 --out results/g

      >>> # not run: it runs a sweep (minutes) and writes /tmp/sweep
      >>> sweep(robot="two_link_arm", iterations=1, out="/tmp/sweep")  # doctest: +SKIP
    """
    names = _losses(losses, flag="--losses")
    base = _base_config(
        robot, task, names[0], seed, seeds, iterations, config, simulator, control_dt, site
    )
    _run_sweep(base, names, override, out, backend, address, max_retries, quiet)


def _run_sweep(base, names, override, out, backend, address, max_retries, quiet) -> None:
    """Run the sweep of ``base`` over ``names`` and the ``override`` axes; print its table."""
    from cfm_jax.runs import sweeps

    grid_axes: dict = {}
    for text in override:
        path, values = _override(text)
        if path in grid_axes:
            config_lib.fail(
                "--override", text, f"{path} is already an axis of this sweep; give each path once"
            )
        grid_axes[path] = values
    _check_out(out)
    start = time.perf_counter()
    with _removed_if_empty(out):
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
    return list(config_lib.loss_names(spec, flag))


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


def _write_outputs(out, frames, result, base, task, notes=(), names=None) -> None:
    """Write the combined files after every loss, so finished losses are never lost; each
    is written whole and renamed into place (cfm_jax._files). The top-level config.json
    is the run's shared config with ``"loss"`` the run's losses (``names``, comma-separated:
    ``cfm-jax train --config`` takes it), each loss's own in OUT/<loss>/config.json."""
    metrics = _concat(frames)
    _write_metrics(out, frames)
    baselines = result.baselines
    write_atomic(os.path.join(out, "baselines.csv"), lambda tmp: baselines.to_csv(tmp, index=False))
    record = report.config_record(base)  # per-loss configs: OUT/<loss>/config.json
    record["loss"] = ",".join(names or [base.loss])
    write_text(os.path.join(out, "config.json"), json.dumps(record, indent=2))
    table = report.summary(metrics, result.baselines, result.rms_reach)
    text = report.protocol(base) + "\n\n" + report.markdown(table)
    if metrics["loss"].nunique() > 1:  # the joint loss (else the first) against the others
        text += "\n\n" + report.paired_markdown(report.paired_table(metrics, reference=None))
    if notes:
        text += "\n\nWhat failed:\n\n" + "\n".join(f"* {line}" for line in notes)
    write_text(os.path.join(out, "summary.md"), text + "\n")
    plots.plot_learning_curves(
        metrics,
        os.path.join(out, "learning_curves.png"),
        result.baselines,
        title=f"{base.robot} {base.task.name}",
        tracking_label=f"{task.tracking_name} ({task.tracking_unit}$^2$)",
        output_unit=task.output_unit,
    )


_UNSET = "\x00"  # the value of a config flag that was not given (tyro needs a str)

_SECTIONS = {
    "task": config_lib.TaskConfig,
    "forward": config_lib.ForwardModelConfig,
    "controller": config_lib.ControllerConfig,
    "loop": config_lib.LoopConfig,
}

_CHOICES = {  # fields whose values are a known set (the config checks them)
    "task.name": "TASKS",
    "task.desired": "DESIRED",
    "forward.start": "FIT_STARTS",
    "forward.kind": "FORWARD_KINDS",
    "controller.goal": "CONTROLLER_GOALS",
    "controller.loss_form": "LOSS_FORMS",
    "controller.start": "FIT_STARTS",
    "loop.babbling": "BABBLING",
    "loop.normaliser": "NORMALISERS",
    "simulator": "SIMULATORS",
    "robot_actuators": "ROBOT_ACTUATORS",
}

_JSON_FIELDS = ("task.targets", "controller.loss_weights")  # nested tuples: one JSON value

_SHORT = {  # the short flags of earlier versions, kept as aliases of the nested ones
    "task.name": "--task",
    "task.control_dt": "--control-dt",
    "task.site": "--site",
    "loop.seeds": "--seeds",
    "loop.iterations": "--iterations",
    "loop.babbling": "--babbling",
}

_TOP_FIELDS = ("robot", "seed", "simulator", "robot_actuators", "robot_torque_limit")

_TOP_HELP = {
    "robot": "registered robot name (iiwa14, two_link_arm, solo12) or path to an MJCF file; "
    "the default follows --task (solo12 for walk and jump).",
    "seed": "first seed; run k of loop.seeds uses seed + k.",
    "simulator": "physics back end: native (MuJoCo C, exact, fast on CPU) or mjx (MuJoCo MJX "
    "in JAX, on the device).",
    "robot_actuators": "strict: torque motors only; torque: each servo on a joint (position, "
    "velocity, intvelocity, general with a bias or gain) replaced by a torque motor on the "
    "same joint and gear (docs/how-to/own-robot.md).",
    "robot_torque_limit": "with --robot-actuators torque: torque limit of servos whose file "
    "has no forcerange or joint actuatorfrcrange; one number for all joints or one per joint.",
    "config": "JSON file of a full config (a run's config.json, or the output of cfm-jax "
    "config): the base of every config flag; only the flags given override it. Without it, "
    "the task's defaults (cfm_jax.config.for_task), as in Python.",
}


def _plain(text: str) -> str:
    """Docstring text as one plain paragraph: no line breaks, no reST roles or literals; a
    :data: reference to a tuple of allowed names in config.py is replaced by its names."""

    def role(match):
        target = match[1].lstrip("~")
        value = getattr(config_lib, target, None)
        return ", ".join(value) if isinstance(value, tuple) else target

    text = re.sub(r":\w+:`([^`]+)`", role, " ".join(text.split()))
    return text.replace("``", "")


def _attribute_help(cls) -> dict[str, str]:
    """Each field's paragraph of the ``Attributes:`` section of ``cls``'s docstring (none
    without one: a user's registered kind need not write it)."""
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    if "Attributes:" not in lines:
        return {}
    found, name = {}, None
    for line in lines[lines.index("Attributes:") + 1 :]:
        if line and not line.startswith("  "):
            break
        match = re.match(r"  (\w+): (.*)", line)
        if match:
            name = match[1]
            found[name] = match[2]
        elif name and line.strip():
            found[name] += " " + line.strip()
    return {key: _without_default(_plain(value)) for key, value in found.items()}


def _without_default(text: str) -> str:
    """A field's help without the docstring's note of the library default ("pd (default;
    ...)", "None (default): ...", "(...; default warm)"): the flag's hint states the
    default once, and it is the base config's (a --config file's value where given)."""
    text = re.sub(r" \(default\)", "", text)
    text = re.sub(r"\(default[;:,] ", "(", text)
    return re.sub(r"; default [\w.]+\)", ")", text)


def _shown(value) -> str:
    if isinstance(value, tuple) and all(isinstance(v, int | float) for v in value):
        return " ".join(str(v) for v in value)
    if isinstance(value, tuple):
        return json.dumps(value)
    return str(value)


def _metavar(path: str, type_text: str) -> str:
    optional = "|None" if "None" in type_text else ""
    if path in _CHOICES:
        return "{" + ",".join(getattr(config_lib, _CHOICES[path])) + "}" + optional
    if path in _JSON_FIELDS:
        return "JSON" + optional
    if path in ("robot", "forward.options.nominal"):
        return "NAME|FILE.xml" + optional
    element = "INT" if "int" in type_text else "FLOAT" if "float" in type_text else "TEXT"
    if type_text.startswith("tuple"):
        return f"{element} [{element} ...]" + optional
    return element + optional


def _flag(path: str, type_text: str, default, help_text: str, aliases=()):
    """A tyro field for one config field: parsed as text (the config checks the value and
    names field, value and what is allowed), its default the base config's."""
    hint = f"(default: {_shown(default)})"
    if type_text == "bool":
        return Annotated[bool, tyro_arg(help=help_text, aliases=aliases)], default
    kind = tuple[str, ...] if type_text.startswith("tuple") and path not in _JSON_FIELDS else str
    sentinel = (_UNSET,) if kind is not str else _UNSET
    meta = _metavar(path, type_text)
    return (
        Annotated[kind, tyro_arg(help=help_text, metavar=meta, help_behavior_hint=hint,
                                 aliases=aliases)],
        sentinel,
    )  # fmt: skip


def _value(path: str, type_text: str, given):
    """The config value of a flag's text (``_UNSET`` when the flag was not given)."""
    if given in (_UNSET, (_UNSET,)) or type_text == "bool":
        return given
    optional = "None" in type_text
    if isinstance(given, tuple):
        if optional and given in (("None",), ("null",)):
            return None
        return tuple(_number(text, "float" in type_text) for text in given)
    if optional and given in ("None", "null"):
        return None
    if path in _JSON_FIELDS:
        try:
            return json.loads(given)
        except json.JSONDecodeError as error:
            config_lib.fail(path, given, f"None or a JSON list, e.g. [[0.5, 0.5]] ({error})")
    if type_text.startswith("str"):
        return given
    return _number(given, type_text.startswith("float"))


def _number(text: str, as_float: bool):
    """JSON of ``text`` (a number, a list), else the text itself for the config to refuse."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        return text
    if as_float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _flags_class(command: str, base: config_lib.Config, extra: list):
    """The tyro dataclass of ``command``: ``extra`` (its own flags), the top-level config
    fields and one nested group per config section, defaults from ``base``."""
    fields = list(extra)
    top_types = {f.name: f.type for f in dataclasses.fields(config_lib.Config)}
    for name in _TOP_FIELDS:
        fields.append((name, *_flag(name, top_types[name], getattr(base, name), _TOP_HELP[name])))
    fields.append(("config", Annotated[str | None, tyro_arg(help=_TOP_HELP["config"],
                   metavar="FILE", help_behavior_hint="")], None))  # fmt: skip
    for section, cls in _SECTIONS.items():
        helps = _attribute_help(cls)
        group = []
        for field in dataclasses.fields(cls):
            path = f"{section}.{field.name}"
            if path == "forward.options":
                options = _options_class(base.forward)
                group.append(("options", options, dataclasses.field(default_factory=options)))
                continue
            aliases = (_SHORT[path],) if path in _SHORT else ()
            value = getattr(getattr(base, section), field.name)
            group.append((field.name, *_flag(path, field.type, value, helps[field.name], aliases)))
        group_cls = dataclasses.make_dataclass(
            f"{section}",
            [(n, t, d if isinstance(d, dataclasses.Field) else dataclasses.field(default=d))
             for n, t, d in group],
        )  # fmt: skip
        group_cls.__doc__ = _plain(inspect.cleandoc(cls.__doc__).split("\n\n")[0])
        fields.append((section, group_cls, dataclasses.field(default_factory=group_cls)))
    flags = dataclasses.make_dataclass(
        command,
        [f if isinstance(f[2], dataclasses.Field) else (f[0], f[1], dataclasses.field(default=f[2]))
         for f in fields],
    )  # fmt: skip
    return flags


def _option_fields():
    """``{name: (type, help, default)}`` of every registered kind's options (the
    ``forward.options`` flags: one flag per name, checked by the kind in use; the default
    is the first kind's that has the field)."""
    found: dict[str, tuple[str, str, object]] = {}
    for kind, cls in config_lib.FORWARD_OPTIONS.items():
        helps = _attribute_help(cls)
        for field in dataclasses.fields(cls):
            text = f"forward.kind={kind}: {helps.get(field.name, 'its own option')}"
            default = field.default
            if field.name in found:
                _, earlier, default = found[field.name]
                text = earlier + "; " + text
            found[field.name] = (_type_text(field.type), text, default)
    return found


def _type_text(annotation) -> str:
    """A field's annotation as text: the library's modules postpone annotations (strings); a
    user's class may not (``float``, ``tuple[float, ...]``)."""
    if isinstance(annotation, str):
        return annotation
    return annotation.__name__ if isinstance(annotation, type) else str(annotation)


def _options_class(forward: config_lib.ForwardModelConfig):
    """The tyro group of the ``forward.options`` flags, defaults from ``forward``'s options
    (another kind's fields: theirs)."""
    group = []
    for name, (type_text, help_text, default) in _option_fields().items():
        value = getattr(forward.options, name, default)  # None has no such attribute
        group.append((name, *_flag(f"forward.options.{name}", type_text, value, help_text)))
    options = dataclasses.make_dataclass(
        "options", [(n, t, dataclasses.field(default=d)) for n, t, d in group]
    )
    options.__doc__ = "the forward-model kind's own options (checked by the kind in use)."
    return options


def _prescan(argv: list[str], losses: list | None = None) -> config_lib.Config:
    """The base config of a command line: the --config file, else the defaults of its
    --task (cfm_jax.config.for_task: what Python's ``Config`` of that task is). A file of a
    several-loss run (``"loss": "joint,task"``, the top-level config.json) gives its first
    loss, and its list is appended to ``losses`` (the default of --loss)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--config")
    parser.add_argument("--task", "--task.name", dest="task")
    known, _ = parser.parse_known_args(argv)
    if known.config is not None:
        data = _read_config(known.config)
        loss = data.get("loss") if isinstance(data, dict) else None
        if isinstance(loss, str) and "," in loss:
            names = _losses(loss)
            data = {**data, "loss": names[0]}
            if losses is not None:
                losses.append(",".join(names))
        return config_lib.from_dict(data)
    task = known.task or "inverse_dynamics"
    if task not in config_lib.TASKS:
        config_lib.fail("task.name", task, f"one of {config_lib.TASKS}")
    return config_lib.for_task(task)


def _config_of(flags, base: config_lib.Config, loss: str) -> config_lib.Config:
    """``base`` with the config flags that were given (validated by the config)."""
    data = config_lib.to_dict(base)
    top_types = {f.name: f.type for f in dataclasses.fields(config_lib.Config)}
    for name in _TOP_FIELDS:
        value = _value(name, top_types[name], getattr(flags, name))
        if value not in (_UNSET, (_UNSET,)):
            data[name] = value
    data["loss"] = loss
    for section, cls in _SECTIONS.items():
        group = getattr(flags, section)
        for field in dataclasses.fields(cls):
            if f"{section}.{field.name}" == "forward.options":
                continue
            value = _value(f"{section}.{field.name}", field.type, getattr(group, field.name))
            if value not in (_UNSET, (_UNSET,)):
                data[section][field.name] = value
    given = {}
    for name, (type_text, _, _) in _option_fields().items():
        value = _value(f"forward.options.{name}", type_text, getattr(flags.forward.options, name))
        if value not in (_UNSET, (_UNSET,)):
            given[name] = value
    # The base's options are its kind's: another --forward.kind starts from that kind's.
    same_kind = data["forward"]["kind"] == base.forward.kind
    options = dict(data["forward"]["options"] or {}) if same_kind else {}
    data["forward"]["options"] = {**options, **given} or None
    return config_lib.from_dict(data)


_OUT_HELP = "output directory."


def _loss_names() -> str:
    """The registered loss names, said once (config), with the way to add one."""
    return (", ".join(config_lib.CONTROLLER_LOSSES) + "; a loss of your own: cfm-jax --import "
            "MODULE COMMAND ..., MODULE calling cfm_jax.learning.losses.register")  # fmt: skip


_PAPER_NAMES = ", ".join(config_lib.PAPER_LOSSES)
_QUIET_HELP = "no progress output."


def _train_command(argv: list[str]) -> None:
    listed: list[str] = []  # the losses of a --config file of a several-loss run
    base = _prescan(argv, listed)
    extra = [
        ("loss", Annotated[str, tyro_arg(metavar="NAMES", help="a controller loss "
         f"({_loss_names()}), a comma-separated list of them, or all (the paper's four); "
         "default: all, or the losses a --config file lists.")],
         listed[0] if listed else "all"),
        ("out", Annotated[str, tyro_arg(metavar="DIR", help=_OUT_HELP)], "results/train"),
        ("resume", Annotated[bool, tyro_arg(help="continue an interrupted run in --out (same "
         "flags and config; a larger --loop.iterations continues a finished run for more "
         "iterations): every loss resumes from its newest valid checkpoint in "
         "OUT/LOSS/checkpoints (finished losses are only re-evaluated); losses without "
         "checkpoints start fresh.")], False),
        ("restart", Annotated[bool, tyro_arg(help="start the run in --out again from nothing "
         "(for a run whose checkpoints are all damaged): what --out holds is first moved "
         "aside, whole, to OUT.replaced-TIME (nothing is deleted).")], False),
        ("data", Annotated[str | None, tyro_arg(metavar="FILE", help_behavior_hint="", help=
         "replay a recorded data set (a run's OUT/LOSS/dataset.npz) instead of collecting "
         "data: every loss trains f and g from scratch on it, revealed iteration by iteration "
         "as it was recorded; the controller is evaluated on the robot every iteration. "
         "--seeds must equal the recorded run's.")], None),
        ("quiet", Annotated[bool, tyro_arg(help="no progress bar.")], False),
        ("tensorboard", Annotated[str | None, tyro_arg(metavar="DIR", help_behavior_hint="",
         help="also write TensorBoard event files to DIR (needs tensorboardX: pip install "
         "'cfm_jax[tensorboard]'): after every iteration one scalar per loss and metric, tag "
         "LOSS/METRIC, the mean over seeds and targets.")], None),
    ]  # fmt: skip
    flags_cls = _flags_class("train", base, extra)
    flags = _parse(flags_cls, argv, "train", _description(train))
    names = _losses(flags.loss)
    _run_train(_config_of(flags, base, names[0]), names, flags.out, flags.resume, flags.data,
               flags.quiet, flags.tensorboard, flags.restart)  # fmt: skip


def _sweep_command(argv: list[str]) -> None:
    listed: list[str] = []  # the losses of a --config file of a several-loss run
    base = _prescan(argv, listed)
    extra = [
        ("losses", Annotated[str, tyro_arg(metavar="NAMES", help="all (the paper's four: "
         f"{_PAPER_NAMES}), or a comma-separated list of controller losses ({_loss_names()}); "
         "default: all, or the losses a --config file lists.")],
         listed[0] if listed else "all"),
        ("out", Annotated[str, tyro_arg(metavar="DIR", help=_OUT_HELP)], "results/sweep"),
        ("override", Annotated[tuple[tuple[str, ...], ...], tyro.conf.UseAppendAction,
         tyro_arg(metavar="PATH=VALUES [...]", help=
         "grid axes, each PATH=V1,V2,... (values parsed as JSON numbers, true/false, null, "
         "else text) or PATH=[JSON list] for values that contain commas (see the examples "
         "above); several after one --override or one per --override, the grid is every "
         "combination; default: no axis, one cell.", help_behavior_hint="")], ()),
        ("backend", Annotated[str, tyro_arg(metavar="{local,ray}", help="local (this process) "
         "or ray (each cell a Ray task; pip install 'cfm_jax[ray]').")], "local"),
        ("address", Annotated[str | None, tyro_arg(metavar="HOST:PORT", help_behavior_hint="",
         help="ray: address of an existing cluster (host:port or auto); default: start a "
         "local one on this machine.")], None),
        ("max_retries", Annotated[int, tyro_arg(metavar="INT", help="ray: retries of a cell "
         "whose worker process died.")], 3),
        ("quiet", Annotated[bool, tyro_arg(help=_QUIET_HELP)], False),
    ]  # fmt: skip
    flags_cls = _flags_class("sweep", base, extra)
    flags = _parse(flags_cls, argv, "sweep", _description(sweep))
    names = _losses(flags.losses, flag="--losses")
    axes = tuple(text for group in flags.override for text in group)  # each --override
    _run_sweep(_config_of(flags, base, names[0]), names, axes, flags.out,
               flags.backend, flags.address, flags.max_retries, flags.quiet)  # fmt: skip


def _config_command(argv: list[str]) -> None:
    base = _prescan(argv)
    extra = [
        ("loss", Annotated[str, tyro_arg(metavar="NAME",
         help=f"the controller loss ({_loss_names()}).")], base.loss),
    ]  # fmt: skip
    flags_cls = _flags_class("config", base, extra)
    flags = _parse(flags_cls, argv, "config", _description(print_config))
    config = _config_of(flags, base, flags.loss)
    from cfm_jax.analysis import robot_check

    robot_check.refuse_unfit(config)  # what training would refuse, refused now
    print(json.dumps(config_lib.to_dict(config), indent=2))


def print_config() -> None:
    """Print the config that cfm-jax train runs with the same flags, as JSON (the file
    --config reads); a robot that does not load or that the task cannot run on is refused
    here, with the reason cfm-jax robot check gives.

    Examples:
      cfm-jax config --task walk > walk.json
      cfm-jax train --config walk.json --forward.learning-rate 3e-4 --out results/walk
    """
    _config_command([])


def robot_check(
    file: Annotated[str, tyro.conf.Positional, tyro_arg(metavar="NAME|FILE.xml")],
    robot_actuators: Annotated[str, tyro_arg(metavar="{strict,torque}")] = "strict",
    robot_torque_limit: Annotated[
        tuple[float, ...] | None, tyro_arg(metavar="N [N ...]", help_behavior_hint="")
    ] = None,
) -> None:
    """Load an MJCF file as cfm-jax train would and print what it
    found: joints and ranges, each actuator's kind and torque limit with its source, floating
    base, sites, keyframes, and which tasks can run (and why not). Exit status 0 when
    inverse_dynamics can run.

    Args:
      file: registered robot name or path to an MJCF file.
      robot_actuators: strict (torque motors only) or torque (servos replaced by motors).
      robot_torque_limit: limit of servos whose file has none (one, or one per joint).

    Examples:
      cfm-jax robot check path/to/ur5e.xml --robot-actuators torque
    """
    from cfm_jax.analysis import robot_check as checker

    config_lib.Config(robot_actuators=robot_actuators, robot_torque_limit=robot_torque_limit)
    found = checker.check(file, robot_actuators, robot_torque_limit)
    print(found.text)
    if not found.ok:
        raise SystemExit(1)


def _robot_command(argv: list[str]) -> None:
    if argv[:1] != ["check"]:
        tyro.extras.subcommand_cli_from_dict(
            {"check": robot_check}, prog="cfm-jax robot", args=argv
        )
        return
    _parse(robot_check, argv[1:], "robot check", _description(robot_check, config_flags=False))


def _parse(target, argv: list[str], command: str, description: str):
    """``tyro.cli`` of one command with its help text given as the description, which tyro
    prints as given (from a docstring it would drop the Examples section)."""
    return tyro.cli(target, args=argv, prog=f"cfm-jax {command}", description=description)


def _description(function, config_flags: bool = True) -> str:
    """A command's help text: the docstring's first paragraph as one line, then (for the
    commands that take the config's flags) how those flags work, then its command-line
    examples as they are (to copy and paste)."""
    doc = inspect.cleandoc(function.__doc__)
    head = " ".join(doc.split("\n\n")[0].split())
    commands = [line.strip() for line in doc.splitlines() if line.strip().startswith("cfm-jax ")]
    text = head
    if config_flags:
        text += "\n\nEvery field of the config is a flag (--SECTION.FIELD VALUE); --config "
        text += "FILE is the base and only the flags given override it."
    if commands:
        text += "\n\nExamples:\n" + "\n".join(f"  {line}" for line in commands)
    return text


def main() -> None:
    """Entry point of the ``cfm-jax`` command: dispatch to ``train``, ``sweep``, ``config``,
    ``robot check`` or ``bench`` (tyro); ``cfm-jax --version`` prints the installed version.

    Examples:
      >>> import sys
      >>> # not run: the help is printed and main() exits (SystemExit)
      >>> sys.argv = ["cfm-jax", "train", "--help"]  # doctest: +SKIP
      >>> main()  # doctest: +SKIP
    """
    import sys

    from cfm_jax.analysis import bench
    from cfm_jax.runs.checkpoint import CheckpointError
    from cfm_jax.sim.robots import RobotError

    argv = sys.argv[1:]
    commands = {
        "train": _train_command,
        "sweep": _sweep_command,
        "config": _config_command,
        "robot": _robot_command,
    }
    try:
        argv = _imports(argv)
        if argv[:1] == ["--version"]:
            print(f"cfm-jax {_version()}")
        elif argv[:1] and argv[0] in commands:
            commands[argv[0]](argv[1:])
        else:  # the list of commands, and bench
            tyro.extras.subcommand_cli_from_dict(
                {
                    "train": train,
                    "sweep": sweep,
                    "config": print_config,
                    "bench": bench.bench,
                    "robot": robot_check,
                },
                prog="cfm-jax",
                description=f"cfm-jax {_version()}: coupled forward and inverse models "
                "(Bechtle et al., ICRA 2021). cfm-jax COMMAND --help lists a command's flags. "
                "cfm-jax --import MODULE COMMAND ... first imports MODULE (a module name or a "
                ".py file), which may register losses, forward kinds or tasks of your own.",
            )
    except (config_lib.ConfigError, RobotError, CheckpointError) as error:
        one_line = " ".join(str(error).split())  # MuJoCo's parser messages span lines
        print(f"cfm-jax: error: {one_line}", file=sys.stderr)
        raise SystemExit(2) from None
    except RuntimeError as error:
        from cfm_jax.runs.sweeps import SweepError

        if not isinstance(error, SweepError):
            raise
        print(f"cfm-jax: error: {error}", file=sys.stderr)
        raise SystemExit(1) from None


def _imports(argv: list[str]) -> list[str]:
    # Import the modules of the leading ``--import MODULE`` options (repeatable; a module
    # name importable from the working directory, or a ``.py`` file), in order, so that what
    # they register (:func:`cfm_jax.learning.losses.register`,
    # :func:`cfm_jax.learning.forward_models.register`, :func:`cfm_jax.tasks.register`) is known
    # before the command parses; the rest of ``argv``.
    #
    # Raises:
    #   ConfigError: ``--import`` without a value, or a module that cannot be imported.
    import importlib
    import importlib.util
    import os
    import sys

    while argv and (argv[0] == "--import" or argv[0].startswith("--import=")):
        if argv[0] == "--import":
            if len(argv) < 2:
                config_lib.fail("--import", None, "a module name or a .py file")
            name, argv = argv[1], argv[2:]
        else:
            name, argv = argv[0].split("=", 1)[1], argv[1:]
        try:
            if name.endswith(".py"):
                path = os.path.abspath(name)
                if not os.path.isfile(path):
                    raise ImportError(f"no file {path}")
                module = os.path.splitext(os.path.basename(path))[0]
                spec = importlib.util.spec_from_file_location(module, path)
                loaded = importlib.util.module_from_spec(spec)
                sys.modules[module] = loaded
                spec.loader.exec_module(loaded)
            else:
                if os.getcwd() not in sys.path and "" not in sys.path:
                    sys.path.insert(0, os.getcwd())
                importlib.import_module(name)
        except ImportError as error:
            config_lib.fail("--import", name, f"a module Python can import or a .py file ({error})")
    return argv


def _version() -> str:
    """The installed package's version (its metadata), else ``cfm_jax.__version__``."""
    from importlib import metadata

    try:
        return metadata.version("cfm_jax")
    except metadata.PackageNotFoundError:
        return cfm_jax.__version__


if __name__ == "__main__":
    main()
