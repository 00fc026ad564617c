"""Algorithm 1 of the paper: a pure, compiled core inside a thin impure shell.

Pure core (jit + vmap over seeds):

* :meth:`Experiment.init` -- motor babbling (``loop.babbling``, :mod:`cfm_jax.babbling`:
  by default PD holding the start pose plus Gaussian torque noise), normalisation
  statistics from the babbling data, initial fits of the forward model and then the
  controller (with the chosen loss).
* :meth:`Experiment.iteration` -- one iteration: roll the controller out on every target,
  measure the metrics on the new data (before any refit), add the data, refit the forward
  model, refit the controller. One compiled function of one :class:`TrainState`.
* :meth:`Experiment.evaluate` -- the rollout and metrics alone (the final evaluation).

Impure shell: :func:`train` (progress display, result files, tables); it says so below.

Examples:
  >>> from cfm_jax import config as cfg
  >>> small = cfg.Config(robot="two_link_arm", loop=cfg.LoopConfig(iterations=1))
  >>> result = train(small, progress=False)  # doctest: +SKIP
  >>> result.metrics.columns[:4].tolist()  # doctest: +SKIP
  ['loss', 'seed', 'iteration', 'target']
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pandas as pd
from flax import struct

from cfm_jax import _xla, babbling, dataset, networks, robots, rollout, tasks, update
from cfm_jax import config as config_lib
from cfm_jax._files import write_atomic, write_text

METRIC_COLUMNS = (
    "loss",
    "seed",
    "iteration",
    "target",
    "tracking_mse",
    "prediction_error",
    "predicted_task_error",
    "finite_fraction",
    "transitions_added",
    "forward_loss",
    "controller_loss",
)
"""Columns of every metrics table, in order: the run's ``loss``, ``seed``, ``iteration`` and
``target``, then the metrics of every task (see :meth:`Experiment.metrics_one`); a task
adds its own after them (``Experiment.metric_columns``)."""


@struct.dataclass
class TrainState:
    """Everything one run carries from iteration to iteration (a pytree).

    With several seeds every leaf has a leading seed axis ``(seeds, ...)``.

    Attributes:
      forward_params: the forward ensemble's parameters (leaves ``(ensemble_size, ...)``).
      forward_opt_state: its Adam state.
      controller_params: the controller's parameters.
      controller_opt_state: its Adam state.
      normaliser: the :class:`cfm_jax.networks.Normaliser` of the babbling data.
      data: the :class:`cfm_jax.dataset.Dataset` collected so far.
      key: the PRNG key of the next iteration.
      iteration: completed iterations of Algorithm 1 (int32 scalar).

    Examples:
      >>> result = cfm_jax.train(config, progress=False)  # doctest: +SKIP
      >>> int(result.state.iteration[0]), result.state.data.size  # doctest: +SKIP
      (10, Array([3000], dtype=int32))
    """

    forward_params: Any
    forward_opt_state: Any
    controller_params: Any
    controller_opt_state: Any
    normaliser: networks.Normaliser
    data: dataset.Dataset
    key: jax.Array
    iteration: jax.Array  # int32: completed iterations of Algorithm 1


@struct.dataclass
class Knobs:
    """The values of a config that the compiled functions take as arguments (a pytree of
    float32 arrays; see :data:`cfm_jax.config.RUNTIME_FIELDS`). Configs that differ only
    in these share an :class:`Experiment` and its compilations.

    Attributes:
      forward_learning_rate: ``forward.learning_rate``.
      controller_learning_rate: ``controller.learning_rate``.
      forward_log_variance_bounds: ``(forward.min_log_variance,
        forward.max_log_variance)``, the initial soft bounds of the forward model.
      babbling_noise_std: ``loop.babbling_noise`` times each torque limit, ``(action_dim,)``.
      babbling: ``loop.babbling`` as its index in :data:`cfm_jax.config.BABBLING` (int32).
      task: the task's values, ``values()`` of the task built for ``config.task``: the
        gains (``task.kp``, ``task.kd``, ... and what the task derives from them) and, for
        the arm tasks, the reference trajectories (``task.targets``; ``task.home`` for
        ``inverse_dynamics``).

    Examples:
      >>> from cfm_jax import config as cfg
      >>> exp = Experiment(cfg.Config(robot="two_link_arm", task=cfg.TaskConfig(duration=0.3)))
      >>> other = exp.config.replace(seed=4, task=cfg.TaskConfig(duration=0.3, kp=25.0))
      >>> float(exp.knobs_for(other).task["kp"]), float(exp.knobs.task["kp"])
      (25.0, 100.0)
      >>> exp.knobs_for(other.replace(task=cfg.TaskConfig(duration=0.5)))
      Traceback (most recent call last):
      ...
      ValueError: the experiment was built for a config that differs in more than the loss ...
    """

    forward_learning_rate: jax.Array
    controller_learning_rate: jax.Array
    forward_log_variance_bounds: jax.Array
    babbling_noise_std: jax.Array
    babbling: jax.Array
    task: dict


class Experiment:
    """The static pieces of one config (robot, reference, models) and its compiled
    functions. Build once and reuse, also across losses and across the values of
    :data:`cfm_jax.config.RUNTIME_FIELDS` (seed, learning rates, babbling noise, task
    gains, target sets, checkpointing): those are arguments of the compiled functions
    (:class:`Knobs`), so the rollout used for babbling, evaluation and the baselines
    compiles once per experiment, and each loss's iteration compiles once.

    ``config.loss`` and the runtime fields of ``config`` are only the defaults: every
    method takes the loss to use and, optionally, the :class:`Knobs` of another config
    (:meth:`knobs_for`).

    Args:
      config: the :class:`cfm_jax.config.Config` to build for.

    Examples:
      >>> from cfm_jax import config as cfg
      >>> exp = Experiment(cfg.Config(robot="two_link_arm", task=cfg.TaskConfig(duration=0.3)))
      >>> exp.task.targets, exp.task.steps, exp.state_dim
      (5, 30, 4)
      >>> exp.metric_columns[:5]
      ('loss', 'seed', 'iteration', 'target', 'tracking_mse')
    """

    def __init__(self, config: config_lib.Config):
        self.config = config
        if config.simulator == "mjx" and jax.default_backend() == "cpu":
            _xla.warn_if_slow_mjx()
        self.robot = robots.load(config.robot)
        task = config.task
        self.control_dt = task.control_dt if task.control_dt is not None else self.robot.timestep
        rollout.substeps(self.robot, self.control_dt)  # validates control_dt
        self.task = tasks.make(self.robot, task, self.control_dt, config.simulator)
        fm = config.forward
        self.forward = networks.forward_model(
            fm.hidden,
            fm.ensemble_size,
            self.task.output_dim,
            fm.min_log_variance,
            fm.max_log_variance,
            action_dim=self.task.action_dim,
        )
        self.controller = networks.controller(
            config.controller.hidden, self.task.action_dim, self.task.desired_dim
        )
        self.state_dim = self.task.state_dim
        self.transitions_per_rollout = self.task.targets * self.task.steps
        self.capacity = self.transitions_per_rollout * (
            config.loop.babbling_rollouts + config.loop.iterations
        )
        self._compiled: dict = {}  # name -> jitted function
        self._cache: dict = {}  # host-side results: prepared states, baselines, tasks
        self.knobs = self.knobs_for(config)

    @property
    def metric_columns(self) -> tuple[str, ...]:
        """Columns of the metrics table: :data:`METRIC_COLUMNS` and the task's metrics."""
        return METRIC_COLUMNS + tuple(self.task.metric_names)

    def compatible(self, config: config_lib.Config) -> bool:
        """True when ``config`` differs from this experiment's at most in ``loss`` and
        :data:`cfm_jax.config.RUNTIME_FIELDS` (it can then run on this experiment's
        compilations)."""
        return not self.differences(config)

    def differences(self, config: config_lib.Config) -> list[str]:
        """The fields outside ``loss`` and :data:`cfm_jax.config.RUNTIME_FIELDS` in which
        ``config`` differs from this experiment's, with both values (empty: compatible)."""
        return [
            d.replace(" in the run,", " in the experiment,")
            for d in config_differences(
                config_lib.structure(self.config), config_lib.structure(config)
            )
        ]

    def knobs_for(self, config: config_lib.Config) -> Knobs:
        """The :class:`Knobs` of ``config``, a config :meth:`compatible` with this one.

        Args:
          config: the config to run on this experiment's compilations.

        Returns:
          Its :class:`Knobs`.

        Raises:
          ValueError: ``config`` differs in a field that changes the compiled program (the
            fields are listed).
        """
        diff = self.differences(config)
        if diff:
            raise ValueError(
                "the experiment was built for a config that differs in more than the loss "
                "and the runtime fields (cfm_jax.config.RUNTIME_FIELDS): "
                + "; ".join(diff)
                + "; build an Experiment for this config"
            )
        limit = np.asarray(self.robot.torque_limit, np.float64)
        return Knobs(
            forward_learning_rate=jnp.asarray(config.forward.learning_rate, jnp.float32),
            controller_learning_rate=jnp.asarray(config.controller.learning_rate, jnp.float32),
            forward_log_variance_bounds=jnp.asarray(
                [config.forward.min_log_variance, config.forward.max_log_variance], jnp.float32
            ),
            babbling_noise_std=jnp.asarray(config.loop.babbling_noise * limit, jnp.float32),
            babbling=jnp.asarray(config_lib.BABBLING.index(config.loop.babbling), jnp.int32),
            task=self.task_for(config).values(),
        )

    def task_for(self, config: config_lib.Config):
        """The task object of ``config`` (a config :meth:`compatible` with this one): this
        experiment's task when ``config.task`` is its own, else one built for it (on the
        host; kept for the last few task configs). Its :meth:`values` are what the compiled
        functions get; its host attributes (``tracking_scale``, the NumPy references)
        describe ``config``."""
        if config.task == self.config.task:
            return self.task
        key = json.dumps(dataclasses.asdict(config.task), sort_keys=True)
        cache = self._cache.setdefault("tasks", {})
        if key not in cache:
            task = tasks.make(self.robot, config.task, self.control_dt, config.simulator)
            self.task.with_values(task.values())  # the same shapes, or a named error
            cache[key] = task
            while len(cache) > 8:
                cache.pop(next(iter(cache)))
        return cache[key]

    def _knobs(self, knobs: Knobs | None) -> Knobs:
        return self.knobs if knobs is None else knobs

    def _task(self, knobs: Knobs):
        """The task with the values of ``knobs`` (traced inside the compiled functions)."""
        return self.task.with_values(knobs.task)

    @staticmethod
    def forward_optimizer(knobs: Knobs):
        """Adam at ``knobs.forward_learning_rate`` (the optimiser state does not hold the
        rate, so states of configs that differ in it are interchangeable)."""
        return optax.adam(knobs.forward_learning_rate)

    @staticmethod
    def controller_optimizer(knobs: Knobs):
        """Adam at ``knobs.controller_learning_rate``."""
        return optax.adam(knobs.controller_learning_rate)

    # ----- pure functions of one seed ---------------------------------------------------

    def _normaliser_identity(self) -> networks.Normaliser:
        task = self.task
        return networks.Normaliser.identity(
            task.state_dim, task.output_dim, self.robot.torque_limit, task.desired_index
        )

    def _policy(self, **weights) -> rollout.MixedPolicy:
        dummy = self.controller.init(jax.random.key(0), self.state_dim)
        norm = self._normaliser_identity()
        return rollout.MixedPolicy.of(dummy, norm, self.task.action_dim, **weights)

    def rollout_one(
        self, policy: rollout.MixedPolicy, key, knobs: Knobs | None = None
    ) -> rollout.Rollout:
        """Roll a :class:`cfm_jax.rollout.MixedPolicy` out on every target (one seed), with
        the task values of ``knobs`` (None: this experiment's)."""
        return self._run(self._task(self._knobs(knobs)), policy, key)

    def _run(self, task, policy: rollout.MixedPolicy, key) -> rollout.Rollout:
        simulator = self.config.simulator
        return rollout.run(
            task,
            rollout.mixed_policy(task, self.controller, policy, simulator),
            key,
            simulator=simulator,
        )

    def babbling_policy(self, knobs: Knobs | None = None) -> rollout.MixedPolicy:
        """The babbling controller of ``loop.babbling`` (the task's PD feedback, or its
        oracle for ``oracle``; :mod:`cfm_jax.babbling`) plus Gaussian torque noise
        (``loop.babbling_noise`` of each limit)."""
        knobs = self._knobs(knobs)
        weights = babbling.policy_weights(config_lib.BABBLING[int(knobs.babbling)])
        return self._policy(**weights, noise_std=knobs.babbling_noise_std)

    def babble_one(
        self, policy: rollout.MixedPolicy, key, knobs: Knobs | None = None
    ) -> rollout.Rollout:
        """One babbling rollout (one rollout's targets): ``policy`` following the task's
        babbling reference of the strategy ``knobs.babbling`` (a runtime value: one
        compilation serves every strategy; ``reaching`` draws its goals from a key folded
        out of ``key``, the torque noise uses ``key`` itself)."""
        knobs = self._knobs(knobs)
        task = self._task(knobs)
        key_goals = jax.random.fold_in(key, babbling.GOAL_STREAM)
        references = [
            functools.partial(task.babbling_reference, strategy, key_goals)
            for strategy in config_lib.BABBLING
        ]
        return self._run(
            task.with_reference(jax.lax.switch(knobs.babbling, references)), policy, key
        )

    def learned_policy(self, state: TrainState) -> rollout.MixedPolicy:
        return rollout.MixedPolicy.of(
            state.controller_params, state.normaliser, self.task.action_dim, controller=1.0
        )

    def prepare_one(
        self, babbling: rollout.Rollout, key, knobs: Knobs | None = None
    ) -> tuple[TrainState, jax.Array]:
        """The loss-independent start of a run (one seed): normaliser from the babbling data,
        the data set, fresh parameters and the initial fit of the forward model.

        Returns the state (controller initialised, not yet fitted) and the key of the
        controller's initial fit. Every loss of an experiment starts from the same prepared
        state, so losses are compared on the same data and the same initial forward model.
        """
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[3:]), babbling.transitions)
        return self.prepare_from_data_one(flat, _valid(babbling).reshape(-1), key, knobs)

    def prepare_from_data_one(
        self, flat: dataset.Transitions, valid, key, knobs: Knobs | None = None
    ) -> tuple[TrainState, jax.Array]:
        """:meth:`prepare_one` from given transitions ``(n, ...)`` and their ``valid`` mask
        instead of babbling rollouts (the start of :meth:`replay`)."""
        cfg, knobs = self.config, self._knobs(knobs)
        key, key_fm, key_ctrl, key_fit_fm, key_fit_ctrl = jax.random.split(key, 5)
        normaliser = networks.Normaliser.from_data(
            flat.state,
            flat.observed,
            self.robot.torque_limit,
            weights=valid,
            desired_index=self.task.desired_index,
        )
        data = dataset.add(self.empty_dataset(), flat, valid)
        forward_params = self.forward.init(key_fm, self.state_dim)
        lower, upper = knobs.forward_log_variance_bounds
        forward_params = {
            **forward_params,
            "min_log_variance": jnp.full_like(forward_params["min_log_variance"], lower),
            "max_log_variance": jnp.full_like(forward_params["max_log_variance"], upper),
        }
        controller_params = self.controller.init(key_ctrl, self.state_dim)
        forward_opt_state = self.forward_optimizer(knobs).init(forward_params)
        controller_opt_state = self.controller_optimizer(knobs).init(controller_params)
        state = TrainState(
            forward_params,
            forward_opt_state,
            controller_params,
            controller_opt_state,
            normaliser,
            data,
            key,
            jnp.int32(0),
        )
        state, _ = self._fit_forward(state, key_fit_fm, cfg.forward.initial_steps, knobs)
        return state, key_fit_ctrl

    def empty_dataset(self) -> dataset.Dataset:
        """An empty data set of this experiment's capacity and the task's sizes."""
        task = self.task
        return dataset.empty(
            self.capacity, task.state_dim, task.desired_dim, task.action_dim, task.output_dim
        )

    def fit_initial_controller_one(
        self, loss: str, state: TrainState, key, knobs: Knobs | None = None
    ) -> TrainState:
        """The controller's initial fit with ``loss`` on the babbling data (one seed)."""
        steps = self.config.controller.initial_steps
        state, _ = self._fit_controller(loss, state, key, steps, self._knobs(knobs))
        return state

    def _fit_forward(
        self, state: TrainState, key, steps: int, knobs: Knobs
    ) -> tuple[TrainState, jax.Array]:
        """``steps`` forward-model updates on ``state.data``; returns the state and mean loss."""
        params, opt_state, loss = update.fit_forward(
            self.forward,
            self.forward_optimizer(knobs),
            state.forward_params,
            state.forward_opt_state,
            state.normaliser,
            state.data,
            key,
            steps,
            self.config.forward.batch_size,
        )
        return state.replace(forward_params=params, forward_opt_state=opt_state), loss

    def _fit_controller(
        self, loss: str, state: TrainState, key, steps: int, knobs: Knobs
    ) -> tuple[TrainState, jax.Array]:
        """``steps`` controller updates with ``loss`` through ``state``'s forward model."""
        params, opt_state, mean_loss = update.fit_controller(
            loss,
            self.forward,
            self.controller,
            self.controller_optimizer(knobs),
            state.controller_params,
            state.controller_opt_state,
            state.forward_params,
            state.normaliser,
            state.data,
            key,
            steps,
            self.config.controller.batch_size,
        )
        return state.replace(controller_params=params, controller_opt_state=opt_state), mean_loss

    def metrics_one(self, state: TrainState, result: rollout.Rollout) -> dict:
        """Per-target metrics of a rollout of the current models (before any refit).

        * ``tracking_mse``: mean over steps and components of the task's tracking error
          squared (joint-space task: ``(q - q_ref)^2``, rad^2).
        * ``prediction_error``: mean of ``(f(s, tau_run) - y_obs)^2`` over the forward
          model's outputs (joint-space task: accelerations, (rad/s^2)^2).
        * ``predicted_task_error``: mean of ``(P f(s, g(s, s*)) - s*)^2`` over the desired
          entries ``P``.
        * ``finite_fraction``: share of steps whose simulator state stayed finite.
        * ``transitions_added``: the rollout's steps that are data (finite, and inside the
          target's horizon for tasks with horizons of different lengths).
        * the task's own metrics (``task.metric_names``).

        Means are over the steps inside each target's horizon (all steps for the arms);
        ``prediction_error`` and ``predicted_task_error`` only over the steps before the
        first terminal step (a legged robot's fall), the steps that become data.
        """
        t = result.transitions
        norm = state.normaliser
        predicted = norm.output_inverse(
            networks.ensemble_mean(self.forward, state.forward_params, norm, t.state, t.action)
        )
        tau = self.controller.apply(state.controller_params, norm, t.state, t.desired)
        predicted_task = norm.select(
            norm.output_inverse(
                networks.ensemble_mean(self.forward, state.forward_params, norm, t.state, tau)
            )
        )
        step_mean = _step_mean(result, before_terminal=True)
        return {
            "prediction_error": step_mean(predicted - t.observed),
            "predicted_task_error": step_mean(predicted_task - t.desired),
            **self.rollout_metrics(result),
        }

    def rollout_metrics(self, result: rollout.Rollout) -> dict:
        """Per-target metrics of a rollout that need no model: ``tracking_mse``,
        ``finite_fraction``, ``transitions_added`` and the task's own."""
        return {
            "tracking_mse": _step_mean(result)(result.tracking_error),
            "finite_fraction": jnp.mean(result.finite.astype(jnp.float32), axis=-1),
            "transitions_added": jnp.sum(_valid(result), axis=-1).astype(jnp.float32),
            **self.task.metrics(result),
        }

    def iteration_one(
        self, loss: str, state: TrainState, knobs: Knobs | None = None
    ) -> tuple[TrainState, dict]:
        """One iteration of Algorithm 1 for one seed: rollout, metrics, add, refit f, g."""
        cfg, knobs = self.config, self._knobs(knobs)
        key, key_rollout, key_fit_fm, key_fit_ctrl = jax.random.split(state.key, 4)
        result = self.rollout_one(self.learned_policy(state), key_rollout, knobs)
        metrics = self.metrics_one(state, result)
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), result.transitions)
        data = dataset.add(state.data, flat, _valid(result).reshape(-1))
        state = state.replace(data=data)
        state, forward_loss = self._fit_forward(
            state, key_fit_fm, cfg.forward.steps_per_iteration, knobs
        )
        state, controller_loss = self._fit_controller(
            loss, state, key_fit_ctrl, cfg.controller.steps_per_iteration, knobs
        )
        metrics["forward_loss"] = forward_loss
        metrics["controller_loss"] = controller_loss
        new_state = state.replace(key=key, iteration=state.iteration + 1)
        return new_state, metrics

    def replay_iteration_one(
        self,
        loss: str,
        state: TrainState,
        chunk: dataset.Transitions,
        valid,
        knobs: Knobs | None = None,
    ) -> tuple[TrainState, dict]:
        """:meth:`iteration_one` with the data given instead of collected: roll the current
        controller out (for the metrics only), add ``chunk`` (rows with ``valid``), refit f
        and g. Given the chunk a run collected in this iteration, with the same seed and
        loss, this is that run's iteration exactly (the rollout is the same rollout)."""
        cfg, knobs = self.config, self._knobs(knobs)
        key, key_rollout, key_fit_fm, key_fit_ctrl = jax.random.split(state.key, 4)
        result = self.rollout_one(self.learned_policy(state), key_rollout, knobs)
        metrics = self.metrics_one(state, result)
        state = state.replace(data=dataset.add(state.data, chunk, valid))
        state, forward_loss = self._fit_forward(
            state, key_fit_fm, cfg.forward.steps_per_iteration, knobs
        )
        state, controller_loss = self._fit_controller(
            loss, state, key_fit_ctrl, cfg.controller.steps_per_iteration, knobs
        )
        metrics["forward_loss"] = forward_loss
        metrics["controller_loss"] = controller_loss
        return state.replace(key=key, iteration=state.iteration + 1), metrics

    def evaluate_one(self, state: TrainState, result: rollout.Rollout) -> dict:
        metrics = self.metrics_one(state, result)
        metrics["forward_loss"] = jnp.float32(jnp.nan)
        metrics["controller_loss"] = jnp.float32(jnp.nan)
        return metrics

    # ----- compiled, vmapped over seeds (impure only in caching the compiled functions) --

    def _jit(self, name, fn, **kwargs):
        if name not in self._compiled:
            self._compiled[name] = jax.jit(fn, **kwargs)
        return self._compiled[name]

    def compilations(self) -> dict[str, int]:
        """How many programs each compiled function of this experiment holds (one per
        distinct argument shape; values of :class:`Knobs` do not add any).

        Returns:
          ``{name: count}``, e.g. ``{"rollout": 1, "prepare": 1, "init/joint": 1,
          "iteration/joint": 1}``.
        """
        return {name: fn._cache_size() for name, fn in self._compiled.items()}

    def rollout(
        self, policy: rollout.MixedPolicy, keys, knobs: Knobs | None = None
    ) -> rollout.Rollout:
        """Rollouts for a seed axis: ``policy`` leaves and ``keys`` have a leading seed axis.
        Compiled once per experiment and batch shape (evaluation and baselines share it;
        babbling has its own, :meth:`babbling_rollouts`)."""
        fn = self._jit("rollout", jax.vmap(self.rollout_one, in_axes=(0, 0, None)))
        return fn(policy, keys, self._knobs(knobs))

    def init(self, loss: str, keys, knobs: Knobs | None = None) -> TrainState:
        """Babbling, normaliser and initial fits for every seed of ``keys``.

        The loss-independent part (:meth:`prepare_one`) is computed once per set of keys
        and knobs and shared by every loss of this experiment."""
        knobs = self._knobs(knobs)
        prepared, key_fit = self.prepare(keys, knobs)
        return self._fit_initial(loss, prepared, key_fit, knobs)

    def _fit_initial(self, loss: str, prepared, key_fit, knobs: Knobs) -> TrainState:
        fn = jax.vmap(partial(self.fit_initial_controller_one, loss), in_axes=(0, 0, None))
        return self._jit(f"init/{loss}", fn)(prepared, key_fit, knobs)

    def prepare(self, keys, knobs: Knobs | None = None) -> tuple[TrainState, jax.Array]:
        """:meth:`prepare_one` for every seed of ``keys`` (cached for the last keys and
        knobs)."""
        knobs = self._knobs(knobs)
        cache_key = _fingerprint((jax.random.key_data(keys), knobs))
        cached = self._cache.get("prepared")
        if cached is None or cached[0] != cache_key:
            key_babble, key_fit = jax.vmap(lambda k: jax.random.split(k, 2))(keys).swapaxes(0, 1)
            rollouts = self.babbling_rollouts(key_babble, knobs)
            fn = jax.vmap(self.prepare_one, in_axes=(0, 0, None))
            prepared = self._jit("prepare", fn)(rollouts, key_fit, knobs)
            self._cache["prepared"] = (cache_key, prepared)
        return self._cache["prepared"][1]

    def babbling_rollouts(self, keys, knobs: Knobs | None = None) -> rollout.Rollout:
        """``loop.babbling_rollouts`` babbling rollouts per seed, ``(seeds, rollouts, ...)``,
        of the strategy ``knobs.babbling`` (:meth:`babble_one`; compiled once for every
        strategy)."""
        knobs = self._knobs(knobs)
        count = self.config.loop.babbling_rollouts
        seeds = keys.shape[0]
        policy = _broadcast(self.babbling_policy(knobs), seeds * count)
        flat_keys = jax.vmap(lambda k: jax.random.split(k, count))(keys).reshape(-1)
        fn = self._jit("babble", jax.vmap(self.babble_one, in_axes=(0, 0, None)))
        result = fn(policy, flat_keys, knobs)
        return jax.tree.map(lambda x: x.reshape((seeds, count) + x.shape[1:]), result)

    def init_from_data(
        self, loss: str, keys, chunk: dataset.Transitions, valid, knobs: Knobs | None = None
    ) -> TrainState:
        """:meth:`init` with the babbling data given (``chunk`` and ``valid`` with a leading
        seed axis) instead of collected; the keys are used exactly as :meth:`init` uses
        them, so the same data and seed give the same state."""
        knobs = self._knobs(knobs)
        key_fit = jax.vmap(lambda k: jax.random.split(k, 2)[1])(keys)
        fn = jax.vmap(self.prepare_from_data_one, in_axes=(0, 0, 0, None))
        prepared, key_ctrl = self._jit("prepare_from_data", fn)(chunk, valid, key_fit, knobs)
        return self._fit_initial(loss, prepared, key_ctrl, knobs)

    def replay_iteration(
        self, loss: str, state: TrainState, chunk, valid, knobs: Knobs | None = None
    ):
        """:meth:`replay_iteration_one` for every seed (leading seed axes)."""
        fn = jax.vmap(partial(self.replay_iteration_one, loss), in_axes=(0, 0, 0, None))
        return self._jit(f"replay/{loss}", fn)(state, chunk, valid, self._knobs(knobs))

    def iteration(self, loss: str, state: TrainState, knobs: Knobs | None = None):
        """``(state, metrics)`` after one iteration of Algorithm 1 for every seed."""
        fn = jax.vmap(partial(self.iteration_one, loss), in_axes=(0, None))
        return self._jit(f"iteration/{loss}", fn)(state, self._knobs(knobs))

    def evaluate(self, state: TrainState, knobs: Knobs | None = None) -> dict:
        """Metrics of a rollout of the current controllers (no update), every seed.

        The rollout key is derived from the state's key without consuming it."""
        keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(state.key)
        policy = jax.vmap(self.learned_policy)(state)
        result = self.rollout(policy, keys, knobs)
        return self._jit("evaluate", jax.vmap(self.evaluate_one))(state, result)

    def baselines(self, knobs: Knobs | None = None) -> pd.DataFrame:
        """Tracking MSE per target of the oracle (MuJoCo inverse dynamics) and PD-only
        (with the task values of ``knobs``: gains and references; cached per knobs)."""
        knobs = self._knobs(knobs)
        cache = self._cache.setdefault("baselines", {})
        cache_key = _fingerprint(knobs.task)
        if cache_key in cache:
            return cache[cache_key].copy()
        policies = {
            "oracle": self._policy(oracle=1.0),
            "pd_only": self._policy(feedback=1.0),
        }
        rows = []
        for name, policy in policies.items():
            keys = jax.random.split(jax.random.key(0), 1)
            result = self.rollout(_broadcast(policy, 1), keys, knobs)
            metrics = jax.device_get(jax.vmap(self.rollout_metrics)(result))
            names = ["tracking_mse", *self.task.metric_names]
            for k in range(self.task.targets):
                row = {"baseline": name, "target": k}
                row.update({m: float(np.asarray(metrics[m])[0, k]) for m in names})
                rows.append(row)
        cache[cache_key] = pd.DataFrame(rows)
        return cache[cache_key].copy()


def _fingerprint(tree) -> bytes:
    """Bytes that identify the values, shapes and dtypes of a pytree of arrays."""
    import hashlib

    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        leaf = np.asarray(leaf)
        digest.update(f"{leaf.dtype}{leaf.shape}".encode())
        digest.update(leaf.tobytes())
    return digest.digest()


def _step_mean(result: rollout.Rollout, before_terminal: bool = False):
    """``x (targets, steps, k) -> (targets,)``: mean of ``x^2`` over components and over the
    steps of :func:`_steps` (every step when the task masks none)."""
    steps = _steps(result, before_terminal)
    if steps is None:
        return lambda x: jnp.mean(jnp.square(x), axis=(-2, -1))
    weights = steps.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(weights, axis=-1), 1.0)
    return lambda x: jnp.sum(jnp.mean(jnp.square(x), axis=-1) * weights, axis=-1) / count


def _steps(result: rollout.Rollout, before_terminal: bool):
    """``(targets, steps)`` mask of the steps inside each target's horizon
    (``extras["active"]``) and, with ``before_terminal``, before the first terminal step;
    None when the task marks neither (every step counts).

    A task marks a step terminal (``extras["terminal"]``, for example a legged robot that
    fell) when what follows it is not the dynamics the models should learn: the legged
    models have foot-floor contacts only, so a fallen body sinks through the floor.
    """
    extras = result.extras if isinstance(result.extras, dict) else {}
    masks = [extras["active"]] if "active" in extras else []
    if before_terminal and "terminal" in extras:
        masks.append(jnp.cumsum(extras["terminal"].astype(jnp.int32), axis=-1) == 0)
    return functools.reduce(jnp.logical_and, masks) if masks else None


def _valid(result: rollout.Rollout):
    """Steps that become data: finite, inside the horizon when the task has one, and before
    the first terminal step when the task has those."""
    steps = _steps(result, before_terminal=True)
    return result.finite if steps is None else result.finite & steps


def _broadcast(tree, n: int):
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), tree)


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

    Examples:
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

    @property
    def params(self) -> dict:
        """Final parameters: ``{"forward": ..., "controller": ...}`` (leading seed axis)."""
        return {"forward": self.state.forward_params, "controller": self.state.controller_params}

    def final(self) -> pd.DataFrame:
        """Rows of the last iteration."""
        return self.metrics[self.metrics.iteration == self.metrics.iteration.max()]


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

    The message names the iteration, the quantity (simulator state, a loss, parameters), the
    seed, for the simulator the targets, and where the last good checkpoint is.

    Examples:
      >>> try:
      ...     result = cfm_jax.train(config, out_dir="results/run")  # doctest: +SKIP
      ... except DivergenceError as error:
      ...     print(error)  # doctest: +SKIP
      iteration 3, seed 1: controller_loss became non-finite (NaN or Inf). The last good ...
    """


def config_differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two config dicts, with both values.

    Args:
      old: a config dict (:func:`cfm_jax.config.to_dict`), for example a run's.
      new: another one.
      prefix: prefix of the dotted names (used by the recursion).

    Returns:
      One string per differing field, sorted by name.

    Examples:
      >>> config_differences({"loss": "task", "loop": {"seeds": 1}},
      ...                    {"loss": "task", "loop": {"seeds": 3}})
      ['loop.seeds (1 in the run, 3 now)']
    """
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_differences(a, b, name + ".")
        elif a != b:
            out.append(f"{name} ({a!r} in the run, {b!r} now)")
    return out


def _jsonable(config: config_lib.Config) -> dict:
    return json.loads(json.dumps(config_lib.to_dict(config)))


def _check_finite(
    state: TrainState, metrics: dict, iteration: int, seeds, where: str, losses: bool = True
) -> None:
    """Raise :class:`DivergenceError` for the first non-finite quantity, by seed."""
    checks = [("simulator state", np.asarray(metrics["finite_fraction"]) < 1.0)]
    if losses:  # the final evaluation has no refit, its losses are NaN by design
        checks += [
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
    for name, bad in checks:
        bad = np.asarray(bad).reshape(len(seeds), -1)
        for s, seed in enumerate(seeds):
            if np.any(bad[s]):
                detail = ""
                if name == "simulator state":
                    targets = np.flatnonzero(bad[s]).tolist()
                    detail = f" in the rollout of target(s) {targets}"
                raise DivergenceError(
                    f"iteration {iteration}, seed {seed}: {name} became non-finite (NaN or "
                    f"Inf){detail}. {where}"
                )


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
    every iteration the metrics, losses and parameters are checked: a non-finite value
    stops the run with :class:`DivergenceError`, before it is checkpointed. Everything
    under it is pure and compiled.

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
      DivergenceError: a non-finite simulator state, loss or parameter.

    Examples:
      >>> import cfm_jax
      >>> config = cfm_jax.Config(robot="iiwa14", loss="joint")
      >>> result = cfm_jax.train(config, out_dir="results/run")  # doctest: +SKIP
      >>> result.metrics.groupby("iteration").tracking_mse.agg(["mean", "std"])  # doctest: +SKIP
      >>> result = cfm_jax.train(config, resume="results/run")  # doctest: +SKIP
    """
    from cfm_jax import checkpoint as ckpt_lib

    start = time.perf_counter()
    if experiment is not None:
        knobs = experiment.knobs_for(config)  # refuses a config of another structure
    if resume is not None:
        out_dir = out_dir or resume
        saved_path = os.path.join(resume, "config.json")
        if not os.path.isfile(saved_path):
            raise config_lib.ConfigError(
                f"resume={resume!r} is not allowed: no config.json there (not a run directory)"
            )
        with open(saved_path) as f:
            saved = json.load(f)
        diff = config_differences(saved, _jsonable(config))
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
        write_text(
            os.path.join(out_dir, "config.json"), json.dumps(config_lib.to_dict(config), indent=2)
        )
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

    def record(iteration, metrics):
        new = _rows(config.loss, seeds, iteration, metrics, exp.metric_columns)
        rows.extend(new)
        write_metrics()
        if progress_fn is not None:
            progress_fn(iteration, pd.DataFrame(new, columns=list(exp.metric_columns)))

    last_saved = [None]

    def where() -> str:
        if checkpointer is None or last_saved[0] is None:
            return "No checkpoint was written."
        return (
            f"The last good checkpoint (iteration {last_saved[0]}) is in {checkpointer.directory}."
        )

    def save(state, done: int, final: bool = False):
        if checkpointer is None:
            return
        if final or done % config.loop.checkpoint_every == 0:
            checkpointer.save(done, state, {"rows": rows, "config": _jsonable(config)})
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
            state, rows, first = _restore(checkpointer, state)
            last_saved[0] = first
            write_metrics()
        elif first == 0:
            save(state, 0, final=config.loop.iterations == 0)
        bar.advance(task, 1 + first)
        compile_seconds = float("nan")
        for i in range(first, config.loop.iterations):
            bar.update(task, description=f"{config.robot} {config.loss}: iteration {i + 1}")
            t0 = time.perf_counter()
            if recorded is None:
                state, metrics = exp.iteration(config.loss, state, knobs)
            else:
                chunk = recorded.chunk(i + 1, exp.transitions_per_rollout)
                state, metrics = exp.replay_iteration(config.loss, state, *chunk, knobs=knobs)
            metrics = jax.device_get(metrics)
            if i == first:
                compile_seconds = time.perf_counter() - t0
            _check_finite(state, metrics, i, seeds, where())
            record(i, metrics)
            save(state, i + 1, final=i + 1 == config.loop.iterations)
            bar.advance(task)
        bar.update(task, description=f"{config.robot} {config.loss}: final evaluation")
        final_metrics = jax.device_get(exp.evaluate(state, knobs))
        _check_finite(state, final_metrics, config.loop.iterations, seeds, where(), losses=False)
        record(config.loop.iterations, final_metrics)
        baselines = exp.baselines(knobs)
        bar.advance(task)
    if checkpointer is not None:
        checkpointer.close()
    if out_dir:
        write_atomic(
            os.path.join(out_dir, "baselines.csv"), lambda tmp: baselines.to_csv(tmp, index=False)
        )
        dataset.save(
            os.path.join(out_dir, "dataset.npz"),
            state.data,
            _segments(config, state, rows, recorded),
            seeds,
            _jsonable(config),
        )
    return TrainResult(
        config=config,
        metrics=pd.DataFrame(rows, columns=list(exp.metric_columns)),
        baselines=baselines,
        state=state,
        rms_reach=exp.task_for(config).tracking_scale,
        seconds=time.perf_counter() - start,
        compile_seconds=compile_seconds,
    )


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
    keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(state.key)  # as Experiment.evaluate
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
        frame = pd.DataFrame(rows)
        frame = frame[frame.iteration < iterations]
        frame = frame.assign(added=np.round(frame.transitions_added).astype(np.int64))
        table = frame.pivot_table(index="seed", columns="iteration", values="added", aggfunc="sum")
        added = table.reindex(columns=range(iterations)).to_numpy(np.int64)
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
        return state, rows, step
    raise ckpt_lib.CheckpointError(
        f"no usable checkpoint in {checkpointer.directory}: start the run again without resume"
    )


def _progress(enabled: bool):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        disable=not enabled,
    )
