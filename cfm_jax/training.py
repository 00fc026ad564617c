"""Algorithm 1's impure shell: :func:`train` runs the compiled functions of an
:class:`cfm_jax.experiment.Experiment` (the pure :mod:`cfm_jax.algorithm`, vmapped over seeds)
and does everything around them that touches the world: the progress display, the
``progress_fn`` callback, the result files (metrics after every iteration, config,
baselines, data set), Orbax checkpoints and resume, the divergence checks, and the replay
of a recorded data set.

Examples:
  >>> from cfm_jax import config as cfg
  >>> small = cfg.Config(robot="two_link_arm", loop=cfg.LoopConfig(iterations=1))
  >>> # not run: it trains (compiling an iteration takes tens of seconds)
  >>> result = train(small, progress=False)  # doctest: +SKIP
  >>> result.metrics.columns[:4].tolist()  # doctest: +SKIP
  ['loss', 'seed', 'iteration', 'target']
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from cfm_jax import algorithm, dataset, report
from cfm_jax import config as config_lib
from cfm_jax._files import write_atomic, write_text
from cfm_jax.algorithm import METRIC_COLUMNS, Knobs, TrainState  # noqa: F401 (Knobs: re-export)
from cfm_jax.experiment import Experiment

# Experiment, TrainState, Knobs and METRIC_COLUMNS are imported here for the shell's use
# and as the names a user of train() reaches for; their home is experiment and algorithm.
__all__ = ["DivergenceError", "TrainResult", "rollout_qpos", "train"]


@dataclasses.dataclass
class TrainResult:
    """What :func:`train` returns.

    Attributes:
      config: the config that was run.
      metrics: one row per (seed, iteration, target), columns :data:`METRIC_COLUMNS` and
        the task's own metrics (``Experiment.metric_columns``).
        Iteration ``i`` is measured on the rollout of the controller after ``i`` refits
        (``0``: after babbling and the initial fit); ``forward_loss`` and
        ``controller_loss`` are the mean training losses of the refit that followed.
      baselines: oracle and PD-only tracking MSE per target.
      state: the final :class:`TrainState` (parameters, optimiser states, data set, key),
        leaves with a leading seed axis.
      rms_reach: RMS reaching distance of the targets (rad), the scale for tracking errors.
      seconds: wall time of the run (s).
      compile_seconds: wall time of the first iteration this call ran (s), which includes
        compiling it; NaN when the run had no iteration to run.
      stopped: the seeds stopped by a non-finite training quantity, one dict each:
        ``{"loss", "seed", "iteration", "quantity"}`` (``quantity``: ``forward_loss``,
        ``controller_loss``, ``forward-model parameters`` or ``controller parameters``).
        Such a seed keeps the state of its last good iteration, and has no metrics rows
        from the iteration it stopped at on.
      warnings: MuJoCo warnings captured while stepping (``{message: count}``, see
        :func:`cfm_jax.native.take_warnings`); they are not printed.

    Examples:
      >>> # not run: it trains (minutes)
      >>> result = cfm_jax.train(config, progress=False)  # doctest: +SKIP
      >>> result.final().tracking_mse.mean()  # doctest: +SKIP
      >>> result.baselines.groupby("baseline").tracking_mse.mean()  # doctest: +SKIP
    """

    config: config_lib.Config
    metrics: pd.DataFrame
    baselines: pd.DataFrame
    state: TrainState
    rms_reach: float
    seconds: float
    compile_seconds: float
    stopped: list = dataclasses.field(default_factory=list)
    warnings: dict = dataclasses.field(default_factory=dict)

    @property
    def params(self) -> dict:
        """Final parameters: ``{"forward": ..., "controller": ...}`` (leading seed axis)."""
        return {"forward": self.state.forward_params, "controller": self.state.controller_params}

    def final(self) -> pd.DataFrame:
        """Rows of the last iteration."""
        return self.metrics[self.metrics.iteration == self.metrics.iteration.max()]

    def summary(self, **options) -> pd.DataFrame:
        """The table ``cfm-jax train`` prints and writes to ``summary.md``: final tracking
        MSE per loss (mean and std over seeds and targets, the 95% bootstrap CI of the mean
        over seeds), the oracle and PD-only baselines, and the tracking RMSE over the RMS
        reaching distance; :func:`cfm_jax.report.summary` of ``metrics``, ``baselines`` and
        ``rms_reach``. ``options`` go to it (``column=``, ``iteration=``,
        ``confidence=``); :func:`cfm_jax.report.markdown` prints it as markdown.

        Examples:
          A result built by hand (a real one: ``result = cfm_jax.train(config)``):

          >>> import pandas as pd
          >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1],
          ...                         "iteration": [0, 0], "target": [0, 0],
          ...                         "tracking_mse": [0.25, 0.75]})
          >>> baselines = pd.DataFrame({"baseline": ["pd_only"], "target": [0],
          ...                           "tracking_mse": [4.0]})
          >>> result = TrainResult(None, metrics, baselines, None, rms_reach=2.0,
          ...                      seconds=0.0, compile_seconds=0.0)
          >>> result.summary()[["tracking_mse_mean", "seeds", "rmse_over_reach"]]
                   tracking_mse_mean  seeds  rmse_over_reach
          joint                  0.5    2.0         0.353553
          pd_only                4.0    NaN         1.000000
        """
        from cfm_jax import report

        return report.summary(self.metrics, self.baselines, self.rms_reach, **options)


def _rows(loss, seeds, iteration, metrics, columns=METRIC_COLUMNS) -> list[dict]:
    metrics = jax.tree.map(np.asarray, metrics)
    targets = metrics["tracking_mse"].shape[1]
    rows = []
    for s, seed in enumerate(seeds):
        for k in range(targets):
            row = {"loss": loss, "seed": seed, "iteration": iteration, "target": k}
            for name in columns[4:]:
                value = metrics[name][s]
                row[name] = float(value[k] if np.ndim(value) else value)
            rows.append(row)
    return rows


class DivergenceError(RuntimeError):
    """Training produced a non-finite quantity.

    :func:`train` no longer raises it: a diverged rollout is recorded in the metrics
    (``diverged``) and a non-finite loss or parameter stops one seed
    (:attr:`TrainResult.stopped`). Kept for code that catches it.

    Examples:
      >>> # not run: it trains (minutes) and writes results/run
      >>> try:
      ...     result = cfm_jax.train(config, out_dir="results/run")  # doctest: +SKIP
      ... except DivergenceError as error:
      ...     print(error)  # doctest: +SKIP
      iteration 3, seed 1: controller_loss became non-finite (NaN or Inf). The last good ...
    """


def _nonfinite(state: TrainState, metrics: dict, n_seeds: int) -> list[str | None]:
    """Per seed, the first quantity of an update that is non-finite (a training loss or
    the parameters of a model), or None. A diverged *rollout* is not in this list: it is an
    outcome of the controller, recorded in the metrics (``diverged``)."""
    checks = [
        ("forward_loss", ~np.isfinite(np.asarray(metrics["forward_loss"]))),
        ("controller_loss", ~np.isfinite(np.asarray(metrics["controller_loss"]))),
    ]
    for name, params in (
        ("forward-model parameters", state.forward_params),
        ("controller parameters", state.controller_params),
    ):
        finite = [
            np.asarray(jnp.all(jnp.isfinite(x.reshape(x.shape[0], -1)), axis=1))
            for x in jax.tree.leaves(params)
        ]
        checks.append((name, ~np.all(np.stack(finite), axis=0)))
    out: list[str | None] = [None] * n_seeds
    for name, bad in checks:
        bad = np.asarray(bad).reshape(n_seeds, -1)
        for s in range(n_seeds):
            if out[s] is None and np.any(bad[s]):
                out[s] = name
    return out


def _keep_seeds(new: TrainState, old: TrainState, keep_old: np.ndarray) -> TrainState:
    """``new`` with the seeds where ``keep_old`` is True taken from ``old``."""
    index = np.flatnonzero(keep_old)

    def pick(a, b):
        return a.at[index].set(b[index])

    return jax.tree.map(pick, new, old)


def train(
    config: config_lib.Config,
    progress: bool = True,
    out_dir: str | None = None,
    experiment: Experiment | None = None,
    resume: str | None = None,
    data: str | dataset.Recorded | None = None,
    progress_fn: Callable[[int, pd.DataFrame], object] | None = None,
) -> TrainResult:
    """Run Algorithm 1 for every seed of ``config`` (seeds as a vmap axis).

    Impure shell: shows progress, writes ``out_dir/metrics.csv`` after every iteration (so
    a crash loses at most the iteration in flight), ``out_dir/config.json``,
    ``out_dir/baselines.csv`` and Orbax checkpoints of the whole state in
    ``out_dir/checkpoints/`` (``loop.checkpoint_every``, ``loop.checkpoint_keep``). After
    every iteration the losses and parameters are checked: a seed whose update made one of
    them non-finite is stopped (it keeps its last good state, is listed in
    :attr:`TrainResult.stopped` and ``out_dir/stopped.json``, and has no rows from then
    on); the other seeds go on. A rollout whose simulation diverged is an outcome, not an
    error: it is recorded (``diverged``, ``diverged_step``) and its finite transitions
    before the divergence are data (:func:`cfm_jax.rollout.run`). MuJoCo's warnings are
    captured, not printed (:attr:`TrainResult.warnings`). Everything under it is pure and
    compiled.

    Args:
      config: a :class:`cfm_jax.config.Config`.
      progress: show a progress bar (rich).
      out_dir: directory for result files (created), or None.
      experiment: a prebuilt :class:`Experiment` to reuse its compiled functions
        (optional): one built for a config that differs from ``config`` at most in the loss
        and :data:`cfm_jax.config.RUNTIME_FIELDS` (seed, learning rates, babbling noise,
        task gains, reference trajectories, checkpointing); another raises ``ValueError``
        naming the fields.
      resume: the ``out_dir`` of an interrupted run of the same config: continue from its
        newest valid checkpoint (results go to ``out_dir``, default ``resume``). The
        metrics equal those of an uninterrupted run bit for bit.
      data: replay a recorded data set (a path to a run's ``dataset.npz`` or a
        :class:`cfm_jax.dataset.Recorded`) instead of collecting data: f and g are
        trained from scratch with ``config.loss`` on the recorded babbling data, then each
        iteration adds the rows the recorded run collected in that iteration (its seed
        ``k`` for run ``k``) and refits f and g. The controller is still rolled out on
        the robot every iteration, for the metrics only. With the run's own data, seed
        and loss this reproduces the run exactly.
      progress_fn: called as ``progress_fn(iteration, metrics)`` after each iteration
        (``0 .. loop.iterations - 1``) and after the final evaluation
        (``loop.iterations``), with that iteration's rows of :attr:`TrainResult.metrics`
        (a DataFrame, one row per seed and target), as brax's ``train`` calls its
        ``progress_fn``: for live plots or logging to a tracker. Iterations restored from
        a checkpoint (``resume``) are not passed again.

    Returns:
      A :class:`TrainResult`.

    Raises:
      ValueError: ``experiment`` was built for a config of another structure.
      ConfigError: ``resume`` names a run of a different config (the fields are listed).
      CheckpointError: the newest checkpoint is corrupt (the previous valid one is offered).

    Examples:
      >>> import cfm_jax
      >>> config = cfm_jax.Config(robot="iiwa14", loss="joint")
      >>> # not run: it trains (minutes) and writes results/run
      >>> result = cfm_jax.train(config, out_dir="results/run")  # doctest: +SKIP
      >>> result.metrics.groupby("iteration").tracking_mse.agg(["mean", "std"])  # doctest: +SKIP
      >>> result = cfm_jax.train(config, resume="results/run")  # doctest: +SKIP
    """
    from cfm_jax import checkpoint as ckpt_lib

    start = time.perf_counter()
    saved_config = report.config_record(config)  # config.json, checkpoints, data set: once
    if experiment is not None:
        knobs = experiment.knobs_for(config)  # refuses a config of another structure
    if resume is None and out_dir and ckpt_lib.has_steps(out_dir):
        raise config_lib.ConfigError(
            f"out_dir={out_dir!r} is not allowed: it already holds checkpoints of a run; "
            f"pass resume={out_dir!r} to continue it, or give another out_dir"
        )
    if resume is not None:
        out_dir = out_dir or resume
        saved_path = os.path.join(resume, "config.json")
        if not os.path.isfile(saved_path):
            raise config_lib.ConfigError(
                f"resume={resume!r} is not allowed: no config.json there (not a run directory)"
            )
        with open(saved_path) as f:
            saved = json.load(f)
        diff = config_lib.differences(saved, saved_config)
        if diff:
            raise config_lib.ConfigError(
                f"resume={resume!r} is not allowed: the run there has a different config in "
                + "; ".join(diff)
            )
    exp = experiment if experiment is not None else Experiment(config)
    if experiment is None:
        knobs = exp.knobs
    seeds = config_lib.seeds_of(config)
    recorded = None if data is None else _recorded_for(exp, config, data)
    checkpointer = None
    if out_dir:
        os.makedirs(out_dir, exist_ok=True)
        write_text(os.path.join(out_dir, "config.json"), json.dumps(saved_config, indent=2))
        if config.loop.checkpoint_every > 0:
            checkpointer = ckpt_lib.Checkpointer(
                os.path.join(resume or out_dir, "checkpoints"), keep=config.loop.checkpoint_keep
            )
    rows: list[dict] = []

    def write_metrics():
        if out_dir:
            frame = pd.DataFrame(rows, columns=list(exp.metric_columns))
            write_atomic(
                os.path.join(out_dir, "metrics.csv"), lambda tmp: frame.to_csv(tmp, index=False)
            )

    stopped: list[dict] = []

    def record(iteration, metrics):
        new = _rows(config.loss, seeds, iteration, metrics, exp.metric_columns)
        gone = {entry["seed"] for entry in stopped}
        new = [row for row in new if row["seed"] not in gone]
        rows.extend(new)
        write_metrics()
        if progress_fn is not None:
            progress_fn(iteration, pd.DataFrame(new, columns=list(exp.metric_columns)))

    last_saved = [None]

    def save(state, done: int, final: bool = False):
        if checkpointer is None:
            return
        if final or done % config.loop.checkpoint_every == 0:
            meta = {"rows": rows, "config": saved_config, "stopped": stopped}
            checkpointer.save(done, state, meta)
            last_saved[0] = done

    with _progress(progress) as bar:
        total = config.loop.iterations + 2
        task = bar.add_task(f"{config.robot} {config.loss}: babbling + initial fit", total=total)
        keys = jax.vmap(jax.random.key)(jnp.asarray(seeds, jnp.uint32))
        if recorded is None:
            state = exp.init(config.loss, keys, knobs)
        else:
            babbling_rows = config.loop.babbling_rollouts * exp.transitions_per_rollout
            chunk = recorded.chunk(0, babbling_rows)
            state = exp.init_from_data(config.loss, keys, *chunk, knobs=knobs)
        jax.block_until_ready(state)
        first = 0
        if resume is not None and checkpointer is not None:
            state, rows, first, stopped[:] = _restore(checkpointer, state)
            last_saved[0] = first
            write_metrics()
        elif first == 0:
            save(state, 0, final=config.loop.iterations == 0)
        bar.advance(task, 1 + first)
        compile_seconds = float("nan")
        for i in range(first, config.loop.iterations):
            bar.update(task, description=f"{config.robot} {config.loss}: iteration {i + 1}")
            t0 = time.perf_counter()
            previous = state
            if recorded is None:
                state, metrics = exp.iteration(config.loss, state, knobs)
            else:
                chunk = recorded.chunk(i + 1, exp.transitions_per_rollout)
                state, metrics = exp.replay_iteration(config.loss, state, *chunk, knobs=knobs)
            metrics = jax.device_get(metrics)
            if i == first:
                compile_seconds = time.perf_counter() - t0
            state = _stop_nonfinite(state, previous, metrics, i, config.loss, seeds, stopped)
            record(i, metrics)
            save(state, i + 1, final=i + 1 == config.loop.iterations)
            bar.advance(task)
        bar.update(task, description=f"{config.robot} {config.loss}: final evaluation")
        final_metrics = jax.device_get(exp.evaluate(state, knobs))
        record(config.loop.iterations, final_metrics)
        baselines = exp.baselines(knobs)
        bar.advance(task)
    if checkpointer is not None:
        checkpointer.close()
    if out_dir:
        write_atomic(
            os.path.join(out_dir, "baselines.csv"), lambda tmp: baselines.to_csv(tmp, index=False)
        )
        if stopped:
            write_text(os.path.join(out_dir, "stopped.json"), json.dumps(stopped, indent=2))
        dataset.save(
            os.path.join(out_dir, "dataset.npz"),
            state.data,
            _segments(config, state, rows, recorded),
            seeds,
            saved_config,
        )
    return TrainResult(
        config=config,
        metrics=pd.DataFrame(rows, columns=list(exp.metric_columns)),
        baselines=baselines,
        state=state,
        rms_reach=exp.task_for(config).tracking_scale,
        seconds=time.perf_counter() - start,
        compile_seconds=compile_seconds,
        stopped=list(stopped),
        warnings=_take_warnings(),
    )


def _take_warnings() -> dict:
    from cfm_jax import native

    return native.take_warnings()


def _stop_nonfinite(state, previous, metrics, iteration, loss, seeds, stopped) -> TrainState:
    """Stop the seeds whose update produced a non-finite loss or parameter: they keep
    ``previous`` (their last good state) from now on and are listed in ``stopped``."""
    n = len(seeds)
    gone = {entry["seed"] for entry in stopped}
    for s, quantity in enumerate(_nonfinite(state, metrics, n)):
        if quantity is not None and seeds[s] not in gone:
            stopped.append(
                {"loss": loss, "seed": int(seeds[s]), "iteration": iteration, "quantity": quantity}
            )
    gone = {entry["seed"] for entry in stopped}
    keep_old = np.array([seed in gone for seed in seeds])
    return _keep_seeds(state, previous, keep_old) if keep_old.any() else state


def rollout_qpos(result, *, seed: int = 0, experiment=None) -> np.ndarray:
    """Joint positions of the learned controller of a training run, rolled out again.

    Rolls the final controller of one seed of ``result`` out on every target of its task
    (the rollout of the run's final evaluation, compiled as :func:`cfm_jax.train` compiles
    it) and returns the positions at the
    start of each control step, ready for :func:`cfm_jax.render.video` or
    :func:`cfm_jax.render.frame_strip` (rendering takes trajectories, not training runs).

    Args:
      result: a :class:`TrainResult`.
      seed: index into the run's seeds (``0 <= seed < config.loop.seeds``).
      experiment: the :class:`Experiment` of ``result.config`` to reuse its
        compiled rollout (built when None).

    Returns:
      ``(targets, steps, nq)`` positions, ``control_dt`` apart (the first ``nq`` entries of
      the task's state, which starts with ``qpos`` for every task).

    Raises:
      ValueError: ``seed`` out of range.

    Examples:
      >>> # not run: it trains (minutes)
      >>> result = cfm_jax.train(config, progress=False)  # doctest: +SKIP
      >>> qpos = rollout_qpos(result)  # doctest: +SKIP
      >>> render.video(robots.load(config.robot), qpos[0], "t0.mp4", fps=100)  # doctest: +SKIP
    """
    seeds = result.config.loop.seeds
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < seeds:
        raise ValueError(f"seed={seed!r} is not allowed: an index in [0, {seeds})")
    exp = experiment if experiment is not None else Experiment(result.config)
    state = jax.tree.map(lambda x: x[seed : seed + 1], result.state)
    policy = jax.vmap(exp.learned_policy)(state)
    keys = jax.vmap(algorithm.evaluation_key)(state)  # as Experiment.evaluate
    out = exp.rollout(policy, keys, exp.knobs_for(result.config))
    # The state at the start of every control step begins with qpos for every task
    # ([q, qdot] for the arms, [qpos, foot forces, qvel] for the legged robots).
    return np.asarray(out.transitions.state[0, :, :, : exp.robot.nq])


def _segments(
    config: config_lib.Config, state: TrainState, rows: list[dict], recorded
) -> np.ndarray:
    """Rows added to each seed's data set by babbling and by each iteration,
    ``(seeds, 1 + iterations)``: an iteration adds its rollout's ``transitions_added``, in
    a replay the recorded segment; babbling the rest."""
    iterations = config.loop.iterations
    size = np.asarray(state.data.size)
    if recorded is not None:
        added = np.asarray(recorded.segments[:, 1 : iterations + 1])
    else:
        frame = pd.DataFrame(rows, columns=["seed", "iteration", "transitions_added"])
        frame = frame[frame.iteration < iterations]
        frame = frame.assign(added=np.round(frame.transitions_added).astype(np.int64))
        table = frame.pivot_table(index="seed", columns="iteration", values="added", aggfunc="sum")
        # A stopped seed has no rows from its stop on: it added nothing more.
        table = table.reindex(index=list(config_lib.seeds_of(config)), columns=range(iterations))
        added = table.fillna(0).to_numpy(np.int64)
        added = added.reshape(size.shape[0], iterations)
    return np.concatenate([(size - added.sum(1))[:, None], added], axis=1)


def _recorded_for(exp: Experiment, config: config_lib.Config, data) -> dataset.Recorded:
    """Load ``data`` and check that ``config`` (on ``exp``) can replay it."""
    if isinstance(data, str | os.PathLike):
        try:
            recorded = dataset.load(str(data))
        except (FileNotFoundError, ValueError) as error:
            raise config_lib.ConfigError(str(error)) from error
    else:
        recorded = data
    seeds = len(recorded.seeds)
    where = f"data={data!r}" if isinstance(data, str | os.PathLike) else "data"
    if seeds != config.loop.seeds:
        raise config_lib.ConfigError(
            f"loop.seeds={config.loop.seeds} is not allowed with {where}: it holds the data "
            f"sets of {seeds} seeds {recorded.seeds.tolist()}; set loop.seeds={seeds}"
        )
    if config.loop.iterations > recorded.iterations:
        raise config_lib.ConfigError(
            f"loop.iterations={config.loop.iterations} is not allowed with {where}: it holds "
            f"the data of {recorded.iterations} iterations; at most {recorded.iterations}"
        )
    task = exp.task
    dims = dict(
        state=task.state_dim,
        desired=task.desired_dim,
        action=task.action_dim,
        observed=task.output_dim,
    )
    for name, dim in dims.items():
        got = getattr(recorded.transitions, name).shape[-1]
        if got != dim:
            raise config_lib.ConfigError(
                f"{where} does not fit robot={config.robot!r}, task.name={task.name!r}: its "
                f"{name} has {got} entries per row, this task {dim} (the recorded run was "
                f"robot={recorded.config.get('robot')!r}, task "
                f"{recorded.config.get('task', {}).get('name')!r})"
            )
    babbling_rows = config.loop.babbling_rollouts * exp.transitions_per_rollout
    most = int(recorded.segments[:, 0].max())
    if most > babbling_rows:
        raise config_lib.ConfigError(
            f"loop.babbling_rollouts={config.loop.babbling_rollouts} is not allowed with "
            f"{where}: its babbling data has {most} rows, more than {babbling_rows}; use the "
            "recorded run's babbling_rollouts"
        )
    per_iteration = int(recorded.segments[:, 1:].max(initial=0))
    if per_iteration > exp.transitions_per_rollout:
        raise config_lib.ConfigError(
            f"{where} does not fit this task: an iteration added {per_iteration} rows, one "
            f"rollout of this task has {exp.transitions_per_rollout}; use the recorded "
            "run's task settings (targets, duration, control_dt)"
        )
    return recorded


def _restore(checkpointer, template: TrainState):
    """Newest usable checkpoint: ``(state, rows, completed iterations)``. Steps left
    incomplete by a kill (no manifest) are skipped with a warning; a corrupt step raises
    :class:`cfm_jax.checkpoint.CheckpointError` offering the previous valid one."""
    import warnings

    from cfm_jax import checkpoint as ckpt_lib

    for step in reversed(checkpointer.steps()):
        problem = checkpointer.problem(step)
        if problem is not None and "is incomplete" in problem:
            warnings.warn(f"skipping checkpoint step {step}: {problem}; removed it", stacklevel=3)
            checkpointer.delete(step)
            continue
        state, meta = checkpointer.restore(step, template)
        rows = [r for r in meta["rows"] if r["iteration"] < step]
        stopped = [e for e in meta.get("stopped", []) if e["iteration"] < step]
        return state, rows, step, stopped
    raise ckpt_lib.CheckpointError(
        f"no usable checkpoint in {checkpointer.directory}: start the run again without resume"
    )


def _progress(enabled: bool):
    """A rich progress bar on a terminal or in a notebook; in a file or a pipe (a log), one
    plain line per step instead (:class:`_PlainProgress`): a bar there shows only at the
    end."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    console = Console()
    if enabled and not console.is_terminal and not console.is_jupyter:
        return _PlainProgress()
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        disable=not enabled,
    )


class _PlainProgress:
    """The part of ``rich.progress.Progress`` that :func:`train` uses, printing one line
    per step, e.g. ``iiwa14 joint: iteration 2: 3/6 (41 s)``, flushed at once."""

    def __enter__(self):
        self.start, self.tasks = time.perf_counter(), {}
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, description: str, total: int) -> int:
        self.tasks[len(self.tasks)] = [description, 0, total]
        return len(self.tasks) - 1

    def update(self, task: int, description: str) -> None:
        self.tasks[task][0] = description

    def advance(self, task: int, steps: int = 1) -> None:
        entry = self.tasks[task]
        entry[1] += steps
        elapsed = time.perf_counter() - self.start
        print(f"{entry[0]}: {entry[1]}/{entry[2]} ({elapsed:.0f} s)", flush=True)
