"""What a training run keeps of itself: the :class:`Recorder` of :func:`cfm_jax.train` (its
files, checkpoints and resume, stopped seeds and ``progress_fn``) and the progress display
(:func:`progress_bar`)."""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from cfm_jax import config as config_lib
from cfm_jax._files import write_atomic, write_text
from cfm_jax.analysis import report
from cfm_jax.learning.algorithm import TrainState
from cfm_jax.runs import checkpoint as ckpt_lib
from cfm_jax.sim import dataset

__all__ = ["PlainProgress", "Recorder", "progress_bar"]


class Recorder:
    """The record of one training run (one loss, every seed); checks ``out_dir`` and ``resume``
    when made, before anything is built or written.

    Args:
      config: the run's :class:`cfm_jax.config.Config`.
      out_dir: directory for the result files, or None (nothing written).
      resume: a run's ``out_dir`` (same config; a larger loop.iterations continues it).
      progress_fn: ``progress_fn(iteration, rows)``, called with each iteration's new rows.

    Raises:
      ConfigError: ``out_dir`` holds checkpoints and ``resume`` is None, or ``resume`` names
        no run directory or a run of another config (listed), or of more iterations.

    Attributes:
      rows: the metric rows so far (dicts, one per seed and target).
      stopped: the seeds stopped by a non-finite update (dicts: loss, seed, iteration,
        quantity).

    Examples:
      >>> seen = []
      >>> config = cfm_jax.Config(robot="two_link_arm", loop=cfm_jax.LoopConfig(seeds=2))
      >>> recorder = Recorder(config, None, progress_fn=lambda i, rows: seen.append(len(rows)))
      >>> recorder.open(["loss", "seed", "iteration", "target", "tracking_mse"])
      >>> recorder.record(0, {"tracking_mse": np.array([[0.5, 0.25], [0.1, 0.2]])})
      >>> recorder.metrics().tracking_mse.tolist(), seen  # 2 seeds x 2 targets
      ([0.5, 0.25, 0.1, 0.2], [4])
    """

    def __init__(
        self,
        config: config_lib.Config,
        out_dir: str | None,
        resume: str | None = None,
        progress_fn: Callable[[int, pd.DataFrame], object] | None = None,
    ):
        self.config, self.resume, self.progress_fn = config, resume, progress_fn
        self.saved_config = report.config_record(config)
        self.seeds = config_lib.seeds_of(config)
        self.rows: list[dict] = []
        self.stopped: list[dict] = []
        self.columns: list[str] = []
        self.checkpointer = None
        # With resume: the run's loop.iterations when this one goes further (None: the same).
        self.continued_from: int | None = None
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
            ran = saved.get("loop", {}).get("iterations")
            now = config.loop.iterations
            same = {**saved, "loop": {**saved.get("loop", {}), "iterations": now}}
            if (
                isinstance(ran, int)
                and ran != now
                and not config_lib.differences(same, self.saved_config)
            ):
                if ran > now:
                    raise config_lib.ConfigError(
                        f"loop.iterations={now!r} is not allowed with resume={resume!r}: the run "
                        f"there goes to {ran} iterations; a run continues for more, not fewer"
                    )
                self.continued_from = ran  # a run (finished or not) continued for more
            else:
                diff = config_lib.differences(saved, self.saved_config)
                if diff:
                    raise config_lib.ConfigError(
                        f"resume={resume!r} is not allowed: the run there has a different "
                        "config in " + "; ".join(diff)
                    )
        self.out_dir = out_dir

    def open(self, columns) -> None:
        """Make ``out_dir``, write ``config.json``, open the checkpoints; ``columns``: row keys."""
        self.columns = list(columns)
        if not self.out_dir:
            return
        os.makedirs(self.out_dir, exist_ok=True)
        config_json = json.dumps(self.saved_config, indent=2)
        write_text(os.path.join(self.out_dir, "config.json"), config_json)
        if self.config.loop.checkpoint_every > 0:
            self.checkpointer = ckpt_lib.Checkpointer(
                os.path.join(self.resume or self.out_dir, "checkpoints"),
                keep=self.config.loop.checkpoint_keep,
            )

    def start(self, state: TrainState) -> tuple[TrainState, int]:
        """``(state, first iteration)``: with ``resume``, the newest usable checkpoint's (its rows
        and stopped seeds restored; ``state``: the template), else (also where no checkpoint is
        complete: a kill before the first) ``state``, saved as step 0."""
        if self.resume is not None and self.checkpointer is not None:
            restored = _restore(self.checkpointer, state)
            if restored is not None:
                state, self.rows, first, self.stopped = restored
                self._write_metrics()
                return state, first
            warnings.warn(
                f"no complete checkpoint in {self.checkpointer.directory} (the run was stopped "
                "before its first was written): it starts from the beginning",
                stacklevel=3,
            )
        self._save(state, 0, final=self.config.loop.iterations == 0)
        return state, 0

    def iteration(self, i: int, state: TrainState, previous, metrics) -> TrainState:
        """After iteration ``i``: stop the seeds whose update went non-finite (they keep
        ``previous``: the state before the iteration, or a function that returns it, called
        only then), :meth:`record` the metrics, checkpoint when due; the state to go on from."""
        state = _stop_nonfinite(state, previous, metrics, i, self.config.loss, self.seeds,
                                self.stopped)  # fmt: skip
        self.record(i, metrics)
        self._save(state, i + 1, final=i + 1 == self.config.loop.iterations)
        return state

    def record(self, iteration: int, metrics) -> None:
        """Add the rows of ``metrics`` (none of stopped seeds), rewrite ``metrics.csv`` and call
        ``progress_fn``; ``iteration`` ``loop.iterations`` is the final evaluation."""
        new = rows_of(self.config.loss, self.seeds, iteration, metrics, self.columns)
        gone = {entry["seed"] for entry in self.stopped}
        new = [row for row in new if row["seed"] not in gone]
        self.rows.extend(new)
        self._write_metrics()
        if self.progress_fn is not None:
            self.progress_fn(iteration, pd.DataFrame(new, columns=self.columns))

    def finish(self, state: TrainState, baselines: pd.DataFrame, recorded) -> None:
        """Close the checkpoints; write ``baselines.csv``, ``stopped.json`` (if a seed stopped) and
        the data set (segments of the replayed ``recorded``, or None)."""
        if self.checkpointer is not None:
            self.checkpointer.close()
        if not self.out_dir:
            return
        write_atomic(
            os.path.join(self.out_dir, "baselines.csv"),
            lambda tmp: baselines.to_csv(tmp, index=False),
        )
        if self.stopped:
            write_text(
                os.path.join(self.out_dir, "stopped.json"), json.dumps(self.stopped, indent=2)
            )
        segments = _segments(self.config, state, self.rows, recorded)
        path = os.path.join(self.out_dir, "dataset.npz")
        dataset.save(path, state.data, segments, self.seeds, self.saved_config)

    def flush(self) -> None:
        """Finish writing the last checkpoint (saves run in the background), so a run stopped by
        an exception leaves it complete."""
        if self.checkpointer is not None:
            self.checkpointer.wait()

    def metrics(self) -> pd.DataFrame:
        """The rows so far as a DataFrame."""
        return pd.DataFrame(self.rows, columns=self.columns)

    def _write_metrics(self) -> None:
        if self.out_dir:
            frame = self.metrics()
            path = os.path.join(self.out_dir, "metrics.csv")
            write_atomic(path, lambda tmp: frame.to_csv(tmp, index=False))

    def _save(self, state: TrainState, done: int, final: bool = False) -> None:
        if self.checkpointer is None:
            return
        if final or done % self.config.loop.checkpoint_every == 0:
            meta = {"rows": self.rows, "config": self.saved_config, "stopped": self.stopped}
            self.checkpointer.save(done, state, meta)


def rows_of(loss, seeds, iteration, metrics, columns) -> list[dict]:
    """One row per seed and target of an iteration's per-seed ``metrics``.

    Args:
      loss: the loss name (the ``loss`` column).
      seeds: the seeds, in the order of the metrics' leading axis.
      iteration: the ``iteration`` column.
      metrics: dict of arrays ``(seeds, targets)`` or ``(seeds,)``.
      columns: the metric columns; the first four are ``loss, seed, iteration, target``.

    Examples:
      >>> rows_of("joint", [0], 2, {"tracking_mse": np.array([[0.5, 0.25]])},
      ...         ["loss", "seed", "iteration", "target", "tracking_mse"])[1]
      {'loss': 'joint', 'seed': 0, 'iteration': 2, 'target': 1, 'tracking_mse': 0.25}
    """
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


def _nonfinite(state: TrainState, metrics: dict, n_seeds: int) -> list[str | None]:
    """Per seed, the first non-finite quantity of an update (a training loss or a model's
    parameters), or None. A diverged rollout is not one: it is recorded in the metrics."""
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


def _stop_nonfinite(state, previous, metrics, iteration, loss, seeds, stopped) -> TrainState:
    """Stop the seeds whose update went non-finite: they keep ``previous`` (a state, or a
    function that returns it) and join ``stopped``."""
    n = len(seeds)
    gone = {entry["seed"] for entry in stopped}
    for s, quantity in enumerate(_nonfinite(state, metrics, n)):
        if quantity is not None and seeds[s] not in gone:
            stopped.append(
                {"loss": loss, "seed": int(seeds[s]), "iteration": iteration, "quantity": quantity}
            )
    gone = {entry["seed"] for entry in stopped}
    keep_old = np.array([seed in gone for seed in seeds])
    if not keep_old.any():
        return state
    index = np.flatnonzero(keep_old)
    previous = previous() if callable(previous) else previous
    return jax.tree.map(lambda a, b: a.at[index].set(b[index]), state, previous)


def _segments(
    config: config_lib.Config, state: TrainState, rows: list[dict], recorded
) -> np.ndarray:
    """``(seeds, 1 + iterations)`` rows added by babbling and by each iteration (its
    ``transitions_added``, or in a replay the recorded segment)."""
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


def _restore(checkpointer, template: TrainState):
    """Newest usable checkpoint, ``(state, rows, completed iterations, stopped)``, or None where
    no step is complete: a step a kill left incomplete is removed with a warning; a corrupt one
    raises ``CheckpointError``."""
    for step in reversed(checkpointer.steps()):
        problem = checkpointer.problem(step)
        if problem is not None and "is incomplete" in problem:
            warnings.warn(f"skipping checkpoint step {step}: {problem}; removed it", stacklevel=4)
            checkpointer.delete(step)
            continue
        state, meta = checkpointer.restore(step, template)
        rows = [r for r in meta["rows"] if r["iteration"] < step]
        stopped = [e for e in meta.get("stopped", []) if e["iteration"] < step]
        return state, rows, step, stopped
    return None


def progress_bar(enabled: bool):
    """A rich progress bar on a terminal or in a notebook, else (a log) :class:`PlainProgress`:
    in a file a bar shows only at the end.

    Args:
      enabled: False: nothing is shown (``--quiet``).

    Examples:
      >>> with progress_bar(False) as bar:
      ...     bar.advance(bar.add_task("arm joint: babbling", total=1))
    """
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
        return PlainProgress()
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        disable=not enabled,
    )


class PlainProgress:
    """The part of ``rich.progress.Progress`` that :func:`cfm_jax.train` uses, printing one line
    per step, flushed at once.

    Examples:
      >>> with PlainProgress() as bar:
      ...     bar.advance(bar.add_task("arm joint: babbling", total=3))
      arm joint: babbling: 1/3 (0 s)
    """

    def __enter__(self):
        self.start, self.tasks = time.perf_counter(), {}
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, description: str, total: int) -> int:
        """A new line of progress; returns its id."""
        self.tasks[len(self.tasks)] = [description, 0, total]
        return len(self.tasks) - 1

    def update(self, task: int, description: str) -> None:
        """Change the description of ``task``."""
        self.tasks[task][0] = description

    def advance(self, task: int, steps: int = 1) -> None:
        """Count ``steps`` more of ``task`` and print its line."""
        entry = self.tasks[task]
        entry[1] += steps
        elapsed = time.perf_counter() - self.start
        print(f"{entry[0]}: {entry[1]}/{entry[2]} ({elapsed:.0f} s)", flush=True)
