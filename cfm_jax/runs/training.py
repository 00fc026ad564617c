"""Algorithm 1's impure shell: :func:`train` runs
:meth:`cfm_jax.learning.algorithm.Experiment.run` (the start, the iterations, the final
evaluation) with a :class:`cfm_jax.runs.recorder.Recorder` per loss (result files,
checkpoints and resume, stopped seeds, ``progress_fn``), the progress display and the
replay of a recorded data set."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from cfm_jax import config as config_lib
from cfm_jax.config import loss_names
from cfm_jax.learning import algorithm
from cfm_jax.learning.algorithm import (  # noqa: F401 (Knobs, METRIC_COLUMNS: re-exports)
    METRIC_COLUMNS,
    Experiment,
    Knobs,
    TrainState,
    _concatenate,
    _index,
)
from cfm_jax.runs import checkpoint as ckpt_lib
from cfm_jax.runs.recorder import Recorder, progress_bar
from cfm_jax.sim import dataset

# Experiment, TrainState, Knobs and METRIC_COLUMNS are imported here for the shell's use
# and as the names a user of train() reaches for; their home is algorithm.
__all__ = ["TrainResult", "recorded_for", "rollout_qpos", "train"]


@dataclasses.dataclass
class TrainResult:
    """What :func:`train` returns (its columns: docs/how-to/metrics.md).

    Attributes:
      config: the config that was run.
      metrics: one row per (seed, iteration, target); iteration ``i`` is measured on the
        rollout of the controller after ``i`` refits.
      baselines: oracle and PD-only tracking MSE per target.
      state: the final :class:`TrainState`, leaves with a leading seed axis (a run of several
        losses: ``(loss, seed)`` axes).
      rms_reach: RMS reaching distance of the targets (rad), the scale for tracking errors.
      seconds: wall time of the run (s).
      compile_seconds: wall time of the first iteration run, its compilation included (s;
        NaN when none ran).
      stopped: the seeds stopped by a non-finite loss or parameter, ``{"loss", "seed",
        "iteration", "quantity"}`` each; they keep their last good state and have no rows
        from then on.
      warnings: MuJoCo's warnings, captured instead of printed (``{message: count}``).
      losses: the losses of a run of several (``train(..., losses=...)``), else ``()``.

    Examples:
      >>> metrics = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [0, 0],
      ...                         "target": [0, 0], "tracking_mse": [0.25, 0.75]})
      >>> baselines = pd.DataFrame({"baseline": ["pd_only"], "target": [0], "tracking_mse": [4.0]})
      >>> result = TrainResult(None, metrics, baselines, None, rms_reach=2.0,
      ...                      seconds=0.0, compile_seconds=0.0)
      >>> result.summary()[["tracking_mse_mean", "seeds", "rmse_over_reach"]]
               tracking_mse_mean  seeds  rmse_over_reach
      joint                  0.5    2.0         0.353553
      pd_only                4.0    NaN         1.000000
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
    losses: tuple[str, ...] = ()

    def of(self, loss: str) -> TrainResult:
        """The result of one loss of a run of several (``train(..., losses=...)``): its rows,
        its state (seed axis only), its stopped seeds; the run's baselines and times.

        Args:
          loss: one of :attr:`losses`.

        Raises:
          ValueError: ``loss`` was not one of the run's losses.

        Examples:
          >>> result = cfm_jax.train(config, losses=("joint", "task"))  # doctest: +SKIP
          >>> result.of("task").metrics.loss.unique().tolist()  # doctest: +SKIP
          ['task']
        """
        if loss not in self.losses:
            raise ValueError(
                f"loss={loss!r} is not allowed: this result holds the losses {self.losses}"
                if self.losses
                else f"loss={loss!r} is not allowed: this is a run of one loss, "
                f"{self.config.loss!r}; use the result itself"
            )
        i = self.losses.index(loss)
        return dataclasses.replace(
            self,
            config=self.config.replace(loss=loss),
            metrics=self.metrics[self.metrics["loss"] == loss].reset_index(drop=True),
            state=_index(self.state, i),
            stopped=[entry for entry in self.stopped if entry["loss"] == loss],
            losses=(),
        )

    def policy(self, seed: int | None = None, experiment: Experiment | None = None):
        """The learned controller of one seed as a plain function, to run on a robot or in a
        simulator of your own (brax's ``make_inference_fn``)::

            tau = policy(q, qd, s_star)            # features=...: see below

        ``q``, ``qd``: the robot's joint positions and velocities (MuJoCo's ``qpos``,
        ``qvel``); ``s_star``: the desired quantity the controller was trained to reach, the
        task's ``s*`` (for the joint-space arm task the desired joint accelerations
        ``qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``,
        :func:`cfm_jax.tasks.references.desired_acceleration`; for the op-space task the site's);
        ``tau``: the joint torques, clipped to the robot's limits as the library's rollout
        clips them (``data.ctrl = tau`` for torque actuators; servo-converted robots:
        ``robot.torque_to_ctrl``). ``features``: the task's extra measurements
        (``task.features``; the legged tasks' foot contact forces); None computes them from
        ``q`` and ``qd``, which the arm tasks allow. Jitted; one call per control step. A
        worked example in MuJoCo: docs/how-to/use-the-controller.md.

        Args:
          seed: which seed (a number of ``config.seed .. config.seed + loop.seeds - 1``);
            None: the first.
          experiment: an :class:`Experiment` of the run's config to take the task from, or
            None (:meth:`Experiment.shared`).

        Raises:
          ValueError: a run of several losses (take ``result.of(loss).policy()``), or a seed
            the run does not have.

        Examples:
          >>> policy = cfm_jax.train(config).policy()  # doctest: +SKIP
          >>> tau = policy(data.qpos, data.qvel, s_star)  # doctest: +SKIP
        """
        if self.losses:
            raise ValueError(
                f"this result holds several losses {self.losses}: take one first, "
                "result.of(loss).policy(seed)"
            )
        first, count = self.config.seed, self.config.loop.seeds
        seed = first if seed is None else seed
        if not isinstance(seed, int) or not first <= seed < first + count:
            config_lib.fail("seed", seed, f"one of the run's seeds, {first} to {first + count - 1}")
        one = _index(self.state, seed - first)
        experiment = experiment or Experiment.shared(self.config)
        task, controller = experiment.task, experiment.setup.controller
        limit = jnp.asarray(experiment.robot.torque_limit, jnp.float32)

        robot = experiment.robot
        spec = jax.ShapeDtypeStruct
        try:  # do the task's features follow from q and qd (the arm tasks)?
            jax.eval_shape(task.features, spec((robot.nq,), jnp.float32),
                           spec((robot.nv,), jnp.float32), None)  # fmt: skip
            from_state = True
        except (TypeError, IndexError):  # the legged tasks read the simulator's sensors
            from_state = False

        @jax.jit
        def apply(q, qd, s_star, features):
            if features is None:
                features = task.features(q, qd, None)
            state = task.state(q, qd, features)
            tau = controller.apply(one.controller_params, one.normaliser, state, s_star)
            return jnp.clip(tau, -limit, limit)

        def policy(q, qd, s_star, features=None):
            if features is None and not from_state:
                raise ValueError(
                    f"the {self.config.task.name} task's controller sees measurements "
                    "beyond q and qd (task.features of the simulator's sensors): give "
                    "features=..."
                )
            if features is not None:
                features = jnp.asarray(features, jnp.float32)
            return apply(*(jnp.asarray(x, jnp.float32) for x in (q, qd, s_star)), features)

        return policy

    @property
    def params(self) -> dict:
        """Final parameters: ``{"forward": ..., "controller": ...}`` (leading seed axis)."""
        return {"forward": self.state.forward_params, "controller": self.state.controller_params}

    def final(self) -> pd.DataFrame:
        """Rows of the last iteration."""
        return self.metrics[self.metrics.iteration == self.metrics.iteration.max()]

    def summary(self, **options) -> pd.DataFrame:
        """The table ``cfm-jax train`` prints and writes to ``summary.md``:
        :func:`cfm_jax.analysis.report.summary` of the result, with ``options`` (``column=``,
        ...)."""
        from cfm_jax.analysis import report

        return report.summary(self.metrics, self.baselines, self.rms_reach, **options)


def train(
    config: config_lib.Config,
    progress: bool = True,
    out_dir: str | Mapping[str, str | None] | None = None,
    experiment: Experiment | None = None,
    resume: str | Mapping[str, str | None] | None = None,
    data: str | dataset.Recorded | None = None,
    progress_fn: Callable[[int, pd.DataFrame], object] | None = None,
    losses: str | Sequence[str] | None = None,
) -> TrainResult:
    """Run Algorithm 1 for every seed of ``config`` (seeds as a vmap axis), and for several
    controller losses at once (``losses``: the loss as a batch axis of the same programs).

    Writes the result files (``metrics.csv`` after every iteration) and checkpoints; stops a
    seed whose update went non-finite (:attr:`TrainResult.stopped`) while the others go on; a
    diverged rollout is an outcome, recorded in the metrics (docs/how-to/resume.md). With
    ``losses``, every loss starts from the same babbling data and initial fit of f, and each
    loss's numbers are those of a run of that loss alone (docs/how-to/sweep.md).

    Args:
      config: a :class:`cfm_jax.config.Config`.
      progress: show a progress bar.
      out_dir: directory for the result files (created), or None; with ``losses``, each loss's
        files go to ``out_dir/<loss>`` (or ``out_dir[loss]``, a mapping of folders).
      experiment: an :class:`Experiment` to reuse, built for a config that differs from
        ``config`` at most in the loss and :data:`cfm_jax.config.RUNTIME_FIELDS`; None: the
        one this process keeps for ``config`` (:meth:`Experiment.shared`).
      resume: the ``out_dir`` of an interrupted run of ``config``: continue from its newest
        valid checkpoint (results go there unless ``out_dir`` says otherwise), bit for bit;
        with ``losses``, each loss with checkpoints in its folder (``resume/<loss>`` or
        ``resume[loss]``) resumes, the others start afresh.
      data: a recorded data set to replay instead of collecting data (:func:`recorded_for`):
        f and g trained from scratch with ``config.loss``, the controller still rolled out.
      progress_fn: called as ``progress_fn(iteration, rows)`` after each iteration and the
        final evaluation with its rows of :attr:`TrainResult.metrics` (as in brax's ``train``;
        with ``losses``, once per loss).
      losses: None (``config.loss`` alone), or distinct loss names (``"all"``: the paper's
        four) trained together: the result's ``state`` then has a leading loss axis and
        :meth:`TrainResult.of` gives each loss's result.

    Raises:
      ValueError: ``experiment`` was built for a config of another structure.
      ConfigError: ``out_dir`` holds a run, ``resume`` one of another config, ``data``
        does not fit, or ``losses`` names an unknown loss (the fields are named).
      CheckpointError: the newest checkpoint is corrupt (the previous valid one is offered).

    Examples:
      >>> config = cfm_jax.Config(robot="iiwa14", loss="joint")
      >>> result = cfm_jax.train(config, out_dir="results/run")  # doctest: +SKIP
      >>> result = cfm_jax.train(config, resume="results/run")  # doctest: +SKIP
      >>> every = cfm_jax.train(config, losses="all", out_dir="results/all")  # doctest: +SKIP
      >>> every.of("task").summary()  # doctest: +SKIP
    """
    start = time.perf_counter()
    names = (config.loss,) if losses is None else loss_names(losses)
    several = losses is not None
    for name, folder in (("out_dir", out_dir), ("resume", resume)):
        if isinstance(folder, Mapping) and not several:
            config_lib.fail(name, folder, "a folder; a mapping {loss: folder} needs losses")
    recorders = {}  # each loss's record, made first: they check out_dir and resume
    for name in names:
        run_resume = _run_dir(resume, name, several)
        if several and run_resume is not None and not ckpt_lib.has_steps(run_resume):
            run_resume = None  # a loss that never reached its first checkpoint starts afresh
        run_out = _run_dir(out_dir or resume, name, several)
        recorders[name] = Recorder(config.replace(loss=name), run_out, run_resume, progress_fn)
    exp = experiment if experiment is not None else Experiment.shared(config)
    knobs = exp.knobs_for(config)  # refuses a config of another structure
    rms_reach = exp.task_for(config).tracking_scale
    keys = jax.vmap(jax.random.key)(jnp.asarray(config_lib.seeds_of(config), jnp.uint32))
    recorded = None if data is None else recorded_for(exp, config, data)
    for recorder in recorders.values():
        recorder.open(exp.metric_columns)
    label = f"{config.robot} {','.join(names)}"
    try:
        with progress_bar(progress) as bar:
            task = bar.add_task(
                f"{label}: babbling + initial fit", total=config.loop.iterations + 2
            )

            def shown(steps, next_stage):
                bar.advance(task, steps)
                if next_stage is not None:
                    bar.update(task, description=f"{label}: {next_stage}")

            states, compile_seconds = exp.run(recorders, keys, knobs, recorded, shown)
    finally:  # a run stopped by an exception keeps its last checkpoint whole
        for recorder in recorders.values():
            recorder.flush()
    baselines = exp.baselines(knobs)
    for name in names:
        recorders[name].finish(_index(states[name], 0), baselines, recorded)
    return TrainResult(
        config=config,
        metrics=pd.concat([r.metrics() for r in recorders.values()], ignore_index=True),
        baselines=baselines,
        state=_concatenate([states.pop(name) for name in names])
        if several
        else _index(states[names[0]], 0),
        rms_reach=rms_reach,
        seconds=time.perf_counter() - start,
        compile_seconds=compile_seconds,
        stopped=[entry for r in recorders.values() for entry in r.stopped],
        warnings=_take_warnings(),
        losses=names if several else (),
    )


def _run_dir(folder, loss: str, several: bool) -> str | None:
    """A loss's result folder: ``folder[loss]`` of a mapping, ``folder/<loss>`` in a run of
    several losses, else ``folder``."""
    if folder is None or isinstance(folder, Mapping):
        return None if folder is None else folder.get(loss)
    return os.path.join(folder, loss) if several else folder


def _take_warnings() -> dict:
    from cfm_jax.sim import native

    return native.take_warnings()


def rollout_qpos(result, *, seed: int = 0, experiment=None) -> np.ndarray:
    """Joint positions ``(targets, steps, nq)`` at the start of each control step of one seed's
    final controller, rolled out again as in the final evaluation (for :mod:`cfm_jax.sim.render`).

    Args:
      result: a :class:`TrainResult`.
      seed: index into the run's seeds.
      experiment: the :class:`Experiment` of ``result.config`` to reuse (None:
        :meth:`Experiment.shared`).

    Raises:
      ValueError: ``seed`` out of range.

    Examples:
      >>> qpos = rollout_qpos(cfm_jax.train(config, progress=False))  # doctest: +SKIP
    """
    seeds = result.config.loop.seeds
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < seeds:
        raise ValueError(f"seed={seed!r} is not allowed: an index in [0, {seeds})")
    exp = experiment if experiment is not None else Experiment.shared(result.config)
    state = jax.tree.map(lambda x: x[seed : seed + 1], result.state)
    policy = jax.vmap(exp.learned_policy)(state)
    keys = jax.vmap(algorithm.evaluation_key)(state)  # as Experiment.evaluate
    out = exp.rollout(policy, keys, exp.knobs_for(result.config))
    # The state at the start of every control step begins with qpos for every task
    # ([q, qdot] for the arms, [qpos, foot forces, qvel] for the legged robots).
    return np.asarray(out.transitions.state[0, :, :, : exp.robot.nq])


def recorded_for(exp: Experiment, config: config_lib.Config, data) -> dataset.Recorded:
    """Load ``data`` and check that ``config`` (on ``exp``) can replay it.

    Args:
      exp: the :class:`cfm_jax.learning.algorithm.Experiment` of ``config``.
      config: the config that would replay the data.
      data: a path to a run's ``dataset.npz``, or a :class:`cfm_jax.sim.dataset.Recorded`.

    Raises:
      ConfigError: the file cannot be read, or its seeds, iterations, sizes or babbling do
        not fit ``config`` (the message says what would fit).

    Examples:
      >>> arm = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.1))
      >>> recorded_for(Experiment(arm), arm, "no_such_run/dataset.npz")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: ...no_such_run/dataset.npz...
    """
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
