"""Algorithm 1 of the paper in one place: the whole program from a config to the loss gradient
(docs/concepts/method.md); :func:`cfm_jax.train` is the impure shell around it (result
files, checkpoints, progress: :mod:`cfm_jax.runs.training`, :mod:`cfm_jax.runs.recorder`).

Read top to bottom:

1. **What a run carries**: :class:`Setup` (what a config fixes: robot, task, models; built
   once), :class:`Knobs` (its runtime values, arguments of the compiled programs) and
   :class:`TrainState` (parameters, optimiser states, normaliser, data set, key).
2. **The listing**, pure functions of one seed: :func:`init` (:func:`prepare`: babbling,
   normaliser, fresh models, fit f; then :func:`fit_initial_controller`) and
   :func:`iteration` (:func:`collect`: roll g out and measure before any refit;
   :func:`refit_forward`: add the data, refit f; :func:`refit_controller`: refit g with the
   loss), :func:`evaluate`. Given ``data`` instead of collecting it, they replay a recorded
   data set.
3. **The updates**: :func:`fit_forward` and :func:`fit_controller`, Adam steps under
   ``lax.scan``; :func:`controller_objective` is where a controller loss
   (:mod:`cfm_jax.learning.losses`) meets the forward model and is differentiated.
4. **Rollouts and metrics**: :func:`rollout` on the config's simulator, :func:`metrics`.
5. **Compiled, vmapped over seeds**: :class:`Experiment` jit-compiles these functions once
   per config structure and runs them for every seed (and, one after the other, every loss);
   :meth:`Experiment.run` is the whole run: the start, each iteration, the final evaluation.

Examples:
  >>> from cfm_jax import config as cfg
  >>> fit = dict(hidden=(8,), initial_steps=5, steps_per_iteration=5, batch_size=16)
  >>> config = cfg.Config(
  ...     robot="two_link_arm", task=cfg.TaskConfig(duration=0.1),
  ...     forward=cfg.ForwardModelConfig(ensemble_size=2, **fit),
  ...     controller=cfg.ControllerConfig(**fit),
  ...     loop=cfg.LoopConfig(iterations=1, babbling_rollouts=1))
  >>> setup = Setup.of(config)
  >>> knobs = Knobs.of(config, setup.robot, setup.task)
  >>> state = jax.jit(lambda key, knobs: init(setup, "joint", key, knobs))(
  ...     jax.random.key(0), knobs)
  >>> step = jax.jit(lambda state, knobs: iteration(setup, "joint", state, knobs))
  >>> state, measured = step(state, knobs)
  >>> int(state.iteration), int(state.data.size), measured["tracking_mse"].shape
  (1, 100, (5,))
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import json
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pandas as pd
from flax import struct

from cfm_jax import _xla, tasks
from cfm_jax import config as config_lib
from cfm_jax.learning import forward_models, losses, networks, rigid_body
from cfm_jax.sim import dataset, native, robots
from cfm_jax.sim import rollout as rollout_lib
from cfm_jax.tasks import babbling, scales

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
    "diverged",
    "diverged_step",
    "forward_loss",
    "controller_loss",
)
"""Columns of every metrics table, in order (:func:`metrics`); a task's own follow them."""


@struct.dataclass
class TrainState:
    """What one run carries from iteration to iteration (a pytree; seeds: a leading axis).

    Attributes:
      forward_params: the forward ensemble's parameters (leaves ``(ensemble_size, ...)``).
      forward_opt_state: its Adam state.
      controller_params: the controller's parameters.
      controller_opt_state: its Adam state.
      normaliser: the :class:`cfm_jax.learning.networks.Normaliser` of the last fit
        (``loop.normaliser``).
      data: the :class:`cfm_jax.sim.dataset.Dataset` collected so far.
      key: the PRNG key of the next iteration.
      iteration: completed iterations of Algorithm 1 (int32 scalar).

    Examples:
      >>> int(cfm_jax.train(config).state.iteration[0])  # doctest: +SKIP
      10
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
    """The config's runtime values (:data:`cfm_jax.config.RUNTIME_FIELDS`) as float32 arrays,
    arguments of the compiled functions: configs that differ only in them share compilations.

    Attributes:
      forward_learning_rate: ``forward.learning_rate``.
      controller_learning_rate: ``controller.learning_rate``.
      forward: the other runtime ``forward.*`` fields (the initial log-variance bounds).
      babbling_noise_std: ``loop.babbling_noise`` times the torque scale ``T``,
        ``(action_dim,)`` (``"coupled"``: ``(action_dim, action_dim)``, the noise is ``T n``).
      babbling: the index of ``loop.babbling`` in :data:`cfm_jax.config.BABBLING` (int32).
      torque_scale: :func:`torque_scale`, or None (``"limit"``).
      task: the task's ``values()`` (gains, references); with ``loop.babbling_gains =
        "baseline"`` the babbling's gains are the baseline's.

    Examples:
      >>> config = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.3))
      >>> setup = Setup.of(config)
      >>> knobs = Knobs.of(config, setup.robot, setup.task)
      >>> float(knobs.task["kp"]), knobs.babbling_noise_std.shape  # the coupled scale
      (100.0, (2, 2))
    """

    forward_learning_rate: jax.Array
    controller_learning_rate: jax.Array
    forward: dict
    babbling_noise_std: jax.Array
    babbling: jax.Array
    torque_scale: jax.Array | None
    task: dict

    @classmethod
    def of(cls, config: config_lib.Config, robot, task) -> Knobs:
        """The knobs of ``config`` on ``robot``, with the values of ``task`` (built for it)."""
        own = torque_scale(config, robot)
        scale = np.asarray(robot.torque_limit, np.float64) if own is None else own
        return cls(
            forward_learning_rate=jnp.asarray(config.forward.learning_rate, jnp.float32),
            controller_learning_rate=jnp.asarray(config.controller.learning_rate, jnp.float32),
            forward={
                name: jnp.asarray(getattr(config.forward, name), jnp.float32)
                for section, _, name in (p.partition(".") for p in config_lib.RUNTIME_FIELDS)
                if section == "forward" and name != "learning_rate"
            },
            babbling_noise_std=jnp.asarray(config.loop.babbling_noise * scale, jnp.float32),
            babbling=jnp.asarray(config_lib.BABBLING.index(config.loop.babbling), jnp.int32),
            torque_scale=None if own is None else jnp.asarray(own, jnp.float32),
            task=_babbling_gains(config, task.values()),
        )


@dataclasses.dataclass(frozen=True, eq=False)
class Setup:
    """What Algorithm 1 needs of a config that a run does not change (values: :class:`Knobs`).

    Attributes:
      config: the :class:`cfm_jax.config.Config`.
      robot: the :class:`cfm_jax.sim.robots.Robot`.
      control_dt: seconds between controller steps.
      task: the task (:func:`cfm_jax.tasks.make`).
      forward: the forward model (:func:`cfm_jax.learning.forward_models.make`).
      controller: the controller (:func:`cfm_jax.learning.networks.controller`).
      capacity: rows of the data set (babbling and every iteration's rollout).
      pose_scale: :func:`pose_scale` (``loop.torque_scale = "pose"``), or None.

    Examples:
      >>> setup = Setup.of(cfm_jax.Config(robot="two_link_arm"))
      >>> setup.capacity, setup.transitions_per_rollout  # 2 babbling rollouts + 4 iterations
      (6000, 1000)
    """

    config: config_lib.Config
    robot: Any
    control_dt: float
    task: Any
    forward: Any
    controller: Any
    capacity: int
    pose_scale: Callable | None = None

    @classmethod
    def of(cls, config: config_lib.Config) -> Setup:
        """The setup of ``config``: loads the robot, builds the task and the networks.

        Raises:
          ConfigError: ``task.control_dt`` is not a multiple of the robot's time step, or the
            task does not fit the robot.
          RobotError: the robot does not load, or MJX (``simulator='mjx'``,
            ``forward.kind='rigid_body'``) cannot build it (what it lacks is named).
        """
        robot = robots.of_config(config)
        needs_mjx = [
            name
            for name, needed in (
                ("simulator='mjx'", config.simulator == "mjx"),
                ("forward.kind='rigid_body'", config.forward.kind == "rigid_body"),
                ("loop.torque_scale='pose'", config.loop.torque_scale == "pose"),
            )
            if needed
        ]
        if needs_mjx and robot.mjx_error is not None:
            raise robots.RobotError(f"{robot.mjx_error} (asked for: {', '.join(needs_mjx)})")
        task_config = config.task
        control_dt = task_config.control_period(robot.timestep)
        rollout_lib.substeps(robot, control_dt)  # validates control_dt
        task = tasks.make(robot, task_config, control_dt, config.simulator)
        forward = forward_models.make(config.forward, robot, task)
        controller = networks.controller(
            config.controller.hidden, task.action_dim, task.desired_dim
        )
        capacity = data_capacity(task.targets * task.steps, config.loop)
        setup = cls(
            config,
            robot,
            control_dt,
            task,
            forward,
            controller,
            capacity,
            pose_scale(config, robot, task),
        )
        loss_groups(setup)  # validates controller.loss_weights against the task's output
        return setup

    @property
    def transitions_per_rollout(self) -> int:
        """Transitions of one rollout of the task: ``targets * steps``."""
        return self.task.targets * self.task.steps


def _babbling_gains(config: config_lib.Config, values: dict) -> dict:
    """``values`` with the babbling gains of ``loop.babbling_gains`` (``baseline``: the PD's)."""
    if config.loop.babbling_gains == "baseline" and "babbling_gain_p" in values:
        values = {
            **values,
            "babbling_gain_p": values["gain_p"],
            "babbling_gain_d": values["gain_d"],
        }
    return values


def scale_kind(config: config_lib.Config, robot) -> str:
    """The torque scale ``config.loop.torque_scale`` gives on ``robot``: ``"auto"`` (the
    default) is ``"pose"`` where MJX builds the robot, else ``"coupled"``
    (docs/results/torque_scale_decision.md); any other value is itself.

    Args:
      config: a :class:`cfm_jax.config.Config`.
      robot: its :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> scale_kind(cfm_jax.Config(), robots.load("two_link_arm"))
      'pose'
    """
    kind = config.loop.torque_scale
    if kind == "auto":
        return "pose" if robot.mjx_error is None else "coupled"
    return kind


def torque_scale(config: config_lib.Config, robot) -> np.ndarray | None:
    """The torque scale :func:`scale_kind` names, at the task's feedback frequency (float64):
    ``"inertia"`` :meth:`cfm_jax.sim.robots.Robot.torque_scale`, ``(action_dim,)``; ``"coupled"``
    and ``"pose"`` :meth:`cfm_jax.sim.robots.Robot.coupled_torque_scale`; ``"limit"`` None.

    Args:
      config: a :class:`cfm_jax.config.Config`.
      robot: its :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> limit = cfm_jax.Config(loop=cfm_jax.LoopConfig(torque_scale="limit"))
      >>> torque_scale(limit, robots.load("two_link_arm")) is None
      True
    """
    kind = scale_kind(config, robot)
    if kind == "limit":
        return None
    frequency = _feedback_frequency(config, robot)
    if kind in ("coupled", "pose"):
        return robot.coupled_torque_scale(frequency)
    return robot.torque_scale(frequency)


def _feedback_frequency(config: config_lib.Config, robot) -> float:
    """The task's PD feedback frequency at its control period on ``robot``."""
    return config.task.feedback_frequency(config.task.control_period(robot.timestep))


def pose_scale(config: config_lib.Config, robot, task) -> Callable | None:
    """``loop.torque_scale = "pose"``: the coupled scale :func:`torque_scale` ``T`` at each
    state's own pose, ``T(q) = T + a (M(q) - M(home))`` (``a`` the acceleration the scale gives
    every joint, :meth:`cfm_jax.sim.robots.Robot.coupled_torque_scale`; ``M`` the actuated dofs'
    block, by MJX); this function returns the added term, ``states -> (..., k, k)``, for
    :attr:`cfm_jax.learning.networks.Normaliser.pose_scale`. None for the other scales.

    Args:
      config: a :class:`cfm_jax.config.Config`.
      robot: its :class:`cfm_jax.sim.robots.Robot` (one MJX builds).
      task: the task built for it (its ``configuration(state) -> (qpos, qvel)``).

    Examples:
      >>> pose = cfm_jax.LoopConfig(torque_scale="pose")
      >>> setup = Setup.of(cfm_jax.Config(robot="two_link_arm", loop=pose))
      >>> home = setup.task.state(setup.robot.home, jnp.zeros(2), None)
      >>> bool(jnp.allclose(jax.jit(setup.pose_scale)(home), 0.0, atol=1e-4))  # T(home) = T
      True
    """
    if scale_kind(config, robot) != "pose":
        return None
    acceleration = robot.scale_acceleration(_feedback_frequency(config, robot))
    dofs = np.asarray(robot.actuated_dofs)
    home = jnp.asarray(robot.mass_matrix(robot.home)[np.ix_(dofs, dofs)], jnp.float32)
    mass = rigid_body.mass_function(robot.mj_model, dofs, task.configuration)

    def added(states):
        return jnp.float32(acceleration) * (mass(states) - home)

    return added


# ----- the listing ----------------------------------------------------------------------


def init(setup: Setup, loss: str, key, knobs: Knobs, data=None) -> TrainState:
    """The start of Algorithm 1 for one seed: :func:`prepare`, then :func:`fit_initial_controller`.

    Args:
      setup: the run's :class:`Setup`.
      loss: the controller's loss (:data:`cfm_jax.config.LOSSES`).
      key: the seed's PRNG key.
      knobs: the runtime values.
      data: ``(transitions, valid)`` to start from instead of babbling (a replay), or None.

    Examples:
      >>> state = init(setup, "joint", jax.random.key(0), knobs)  # doctest: +SKIP
    """
    state, key_controller = prepare(setup, key, knobs, data)
    return fit_initial_controller(setup, loss, state, key_controller, knobs)


def prepare(setup: Setup, key, knobs: Knobs, data=None) -> tuple[TrainState, jax.Array]:
    """The loss-independent part of :func:`init` (babbling unless ``data`` is given, normaliser,
    fit of f): every loss of a comparison starts from it. Returns the state and the key of
    :func:`fit_initial_controller`.

    Args:
      setup: the run's :class:`Setup`.
      key: the seed's PRNG key.
      knobs: the runtime values.
      data: ``(transitions, valid)`` to start from instead of babbling, or None.

    Examples:
      >>> state, key_fit = prepare(setup, jax.random.key(0), knobs)  # doctest: +SKIP
    """
    key_babble, key_fit = jax.random.split(key, 2)
    if data is None:
        data = collected(babble_all(setup, key_babble, knobs))
    return _start(setup, *data, key_fit, knobs)


def iteration(
    setup: Setup, loss: str, state: TrainState, knobs: Knobs, data=None
) -> tuple[TrainState, dict]:
    """One iteration of Algorithm 1 for one seed: roll g out, measure, add the data, refit f and g.
    Returns the next state and the :func:`metrics`, with the refits' losses: :func:`collect`,
    then the loss-independent :func:`refit_forward`, then :func:`refit_controller` with ``loss``.

    Args:
      setup: the run's :class:`Setup`.
      loss: the controller's loss.
      state: the seed's :class:`TrainState`.
      knobs: the runtime values.
      data: ``(transitions, valid)`` to add instead of the rollout's (a replay), or None.

    Examples:
      >>> state, measured = iteration(setup, "joint", state, knobs)  # doctest: +SKIP
    """
    out, chunk = collect(setup, state, knobs)
    state, out["forward_loss"], key = refit_forward(setup, state, chunk if data is None else data,
                                                     knobs)  # fmt: skip
    state, out["controller_loss"] = refit_controller(setup, loss, state, key, knobs)
    return state, out


def collect(setup: Setup, state: TrainState, knobs: Knobs) -> tuple[dict, tuple]:
    """The rollout of an iteration: roll g out on every target and measure it (:func:`metrics`,
    before any refit). Returns the metrics and the rollout's data ``(transitions, valid)``.
    The only part of :func:`iteration` that runs the simulator.

    Args:
      setup: the run's :class:`Setup`.
      state: the seed's :class:`TrainState`.
      knobs: the runtime values.

    Examples:
      >>> measured, (rows, valid) = collect(setup, state, knobs)  # doctest: +SKIP
    """
    _, key_rollout, _, _ = jax.random.split(state.key, 4)
    policy = learned_policy(setup, state)
    result = rollout(setup, policy, key_rollout, knobs)
    result = result._replace(transitions=with_terms(setup, result.transitions))
    measured = metrics(setup, state, result)
    if not setup.config.loop.restart_on_terminal:
        return measured, collected(result)
    # The data from a second rollout that starts again after each fall (the same key: the
    # same rollout up to the first fall); the metrics stay those of the rollout above.
    again = _run(setup, _task_of(setup, knobs), policy, key_rollout, restart=True)
    measured["transitions_added"] = jnp.sum(data_mask(again), axis=-1).astype(jnp.float32)
    return measured, collected(again)


def refit_forward(
    setup: Setup, state: TrainState, data, knobs: Knobs
) -> tuple[TrainState, jax.Array, jax.Array]:
    """The part of :func:`iteration` after the rollout that does not depend on the controller's
    loss: add ``data`` to the data set, refit f; the state has the next key and iteration
    count. Returns ``(state, the refit's mean loss, key of the controller's refit)``.

    Args:
      setup: the run's :class:`Setup`.
      state: the seed's :class:`TrainState` (before the iteration).
      data: ``(transitions, valid)``, :func:`collect`'s or a recorded chunk (a replay).
      knobs: the runtime values.

    Examples:
      >>> state, loss, key = refit_forward(setup, state, chunk, knobs)  # doctest: +SKIP
    """
    cfg = setup.config
    key, _, key_fit_fm, key_fit_ctrl = jax.random.split(state.key, 4)
    chunk, valid = data
    chunk = with_terms(setup, chunk)
    state = state.replace(data=dataset.add(state.data, chunk, valid))
    if cfg.loop.normaliser == "data":  # statistics of all data, before both refits
        norm = data_normaliser(setup, state.data, state.normaliser.torque_scale)
        state = state.replace(normaliser=norm)
    state = restart_fits(setup, state, key_fit_fm, key_fit_ctrl, knobs)
    state, forward_loss = _fit_forward(
        setup, state, key_fit_fm, cfg.forward.steps_per_iteration, knobs
    )
    return state.replace(key=key, iteration=state.iteration + 1), forward_loss, key_fit_ctrl


def refit_controller(
    setup: Setup, loss: str, state: TrainState, key, knobs: Knobs
) -> tuple[TrainState, jax.Array]:
    """The controller's refit of an iteration with ``loss`` (``controller.steps_per_iteration``
    updates through the refitted f); returns the state and the mean training loss.

    Args:
      setup: the run's :class:`Setup`.
      loss: the controller's loss.
      state: the state of :func:`refit_forward`.
      key: the key it returned.
      knobs: the runtime values.

    Examples:
      >>> state, value = refit_controller(setup, "task", state, key, knobs)  # doctest: +SKIP
    """
    steps = setup.config.controller.steps_per_iteration
    return _fit_controller(setup, loss, state, key, steps, knobs)


def evaluate(setup: Setup, state: TrainState, result: rollout_lib.Rollout) -> dict:
    """The :func:`metrics` of a rollout with no refit after it (the final evaluation: NaN losses).

    Args:
      setup: the run's :class:`Setup`.
      state: the seed's :class:`TrainState`.
      result: the rollout of :func:`learned_policy` with :func:`evaluation_key`.

    Examples:
      >>> evaluate(setup, state, result)["forward_loss"]  # doctest: +SKIP
      Array(nan, dtype=float32)
    """
    out = metrics(setup, state, result)
    out["forward_loss"] = jnp.float32(jnp.nan)
    out["controller_loss"] = jnp.float32(jnp.nan)
    return out


def evaluation_key(state: TrainState):
    """The final evaluation's key, ``fold_in(state.key, 1)`` (``state.key`` is not consumed).

    Args:
      state: a :class:`TrainState` (or anything with a ``key``).

    Examples:
      >>> from types import SimpleNamespace
      >>> key = jax.random.key(3)
      >>> bool((jax.random.key_data(evaluation_key(SimpleNamespace(key=key)))
      ...       == jax.random.key_data(jax.random.fold_in(key, 1))).all())
      True
    """
    return jax.random.fold_in(state.key, 1)


# ----- the steps --------------------------------------------------------------------------


def babble_all(setup: Setup, key, knobs: Knobs) -> rollout_lib.Rollout:
    """``loop.babbling_rollouts`` rollouts of :func:`babbling_policy` on the babbling reference
    of ``knobs.babbling`` (a runtime value: one compilation serves every strategy).

    Args:
      setup: the run's :class:`Setup`.
      key: the babbling's key (one per rollout is split from it).
      knobs: the runtime values.

    Examples:
      >>> arm = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.3))
      >>> setup = Setup.of(arm)
      >>> babble_all(setup, jax.random.key(0), Knobs.of(arm, setup.robot, setup.task)).finite.shape
      (2, 5, 30)
    """
    count = setup.config.loop.babbling_rollouts
    policy = _broadcast(babbling_policy(setup, knobs), count)
    keys = jax.random.split(key, count)
    return jax.vmap(functools.partial(_babble, setup), in_axes=(0, 0, None))(policy, keys, knobs)


def _babble(
    setup: Setup, policy: rollout_lib.MixedPolicy, key, knobs: Knobs
) -> rollout_lib.Rollout:
    """One babbling rollout (``reaching`` draws its goals from a key folded out of ``key``)."""
    task = _task_of(setup, knobs)
    key_goals = jax.random.fold_in(key, babbling.GOAL_STREAM)
    references = [
        functools.partial(task.babbling_reference, strategy, key_goals)
        for strategy in config_lib.BABBLING
    ]
    return _run(setup, task.for_babbling(jax.lax.switch(knobs.babbling, references)), policy, key)


def babbling_policy(setup: Setup, knobs: Knobs) -> rollout_lib.MixedPolicy:
    """The babbling controller of ``loop.babbling`` (:mod:`cfm_jax.tasks.babbling`) plus Gaussian
    torque noise of std ``knobs.babbling_noise_std``.

    Args:
      setup: the run's :class:`Setup`.
      knobs: the runtime values (``knobs.babbling`` may be traced).

    Examples:
      >>> config = cfm_jax.Config(robot="two_link_arm", loop=cfm_jax.LoopConfig(babbling="oracle"))
      >>> setup = Setup.of(config)
      >>> policy = babbling_policy(setup, Knobs.of(config, setup.robot, setup.task))
      >>> float(policy.oracle_weight), float(policy.feedback_weight)
      (1.0, 0.0)
    """
    # knobs.babbling is a runtime value: pick each strategy's weights by indexing.
    weights = [babbling.policy_weights(strategy) for strategy in config_lib.BABBLING]
    chosen = {
        name: jnp.asarray([w.get(name, 0.0) for w in weights], jnp.float32)[knobs.babbling]
        for name in ("oracle", "feedback")
    }
    return mixed_policy(setup, **chosen, noise_std=knobs.babbling_noise_std)


def _start(
    setup: Setup, chunk: dataset.Transitions, valid, key, knobs: Knobs
) -> tuple[TrainState, jax.Array]:
    """The data set and normaliser of the initial ``chunk``, fresh parameters and the initial
    fit of f; returns the state and the key of the controller's initial fit."""
    cfg, task = setup.config, setup.task
    key, key_fm, key_ctrl, key_fit_fm, key_fit_ctrl = jax.random.split(key, 5)
    chunk = with_terms(setup, chunk)
    empty = dataset.empty(
        setup.capacity,
        task.state_dim,
        task.desired_dim,
        task.action_dim,
        task.output_dim,
        *jax.tree.map(lambda x: x[0], (chunk.terms, chunk.pose)),
    )
    data = dataset.add(empty, chunk, valid)
    if cfg.loop.normaliser == "babbling":
        normaliser = networks.Normaliser.from_data(
            chunk.state,
            chunk.observed,
            setup.robot.torque_limit,
            weights=valid,
            desired_index=task.desired_index,
            torque_scale=knobs.torque_scale,
            pose_scale=setup.pose_scale,
        )
    elif cfg.loop.normaliser == "robot":
        normaliser = networks.Normaliser.from_scales(
            **scales.robot_scales(task),
            torque_limit=setup.robot.torque_limit,
            desired_index=task.desired_index,
            torque_scale=knobs.torque_scale,
            pose_scale=setup.pose_scale,
        )
    else:  # "data"
        normaliser = data_normaliser(setup, data, knobs.torque_scale)
    forward_params = setup.forward.start(setup.forward.init(key_fm, task.state_dim), knobs.forward)
    controller_params = setup.controller.init(key_ctrl, task.state_dim)
    state = TrainState(
        forward_params,
        _forward_optimizer(knobs).init(forward_params),
        controller_params,
        _controller_optimizer(knobs).init(controller_params),
        normaliser,
        data,
        key,
        jnp.int32(0),
    )
    state, _ = _fit_forward(setup, state, key_fit_fm, cfg.forward.initial_steps, knobs)
    return state, key_fit_ctrl


def data_normaliser(setup: Setup, data: dataset.Dataset, torque_scale=None) -> networks.Normaliser:
    """The ``loop.normaliser = "data"`` normaliser: statistics of the data set's filled rows
    (:func:`cfm_jax.learning.networks.Normaliser.from_data`), recomputed before every refit.

    Args:
      setup: the run's :class:`Setup`.
      data: the :class:`cfm_jax.sim.dataset.Dataset`.
      torque_scale: the run's torque scale (:attr:`Knobs.torque_scale`), or None (the limits).

    Examples:
      >>> norm = data_normaliser(setup, state.data, knobs.torque_scale)  # doctest: +SKIP
    """
    filled = jnp.arange(data.capacity) < data.size
    return networks.Normaliser.from_data(
        data.data.state,
        data.data.observed,
        setup.robot.torque_limit,
        weights=filled,
        desired_index=setup.task.desired_index,
        torque_scale=torque_scale,
        pose_scale=setup.pose_scale,
    )


def fit_initial_controller(
    setup: Setup, loss: str, state: TrainState, key, knobs: Knobs
) -> TrainState:
    """The controller's initial fit with ``loss`` (``controller.initial_steps`` updates).

    Args:
      setup: the run's :class:`Setup`.
      loss: the controller's loss.
      state: the state of :func:`prepare`.
      key: the key :func:`prepare` returned.
      knobs: the runtime values.

    Examples:
      >>> state = fit_initial_controller(setup, "task", state, key_fit, knobs)  # doctest: +SKIP
    """
    steps = setup.config.controller.initial_steps
    state, _ = _fit_controller(setup, loss, state, key, steps, knobs)
    return state


def restart_fits(setup: Setup, state: TrainState, key_forward, key_controller, knobs: Knobs):
    """Start the iteration's refits as ``forward.start`` and ``controller.start`` say: ``warm``
    keeps parameters and Adam state, ``warm_new_optimizer`` re-creates Adam, ``fresh`` also
    re-initialises the parameters (from the fit's key folded with :data:`FRESH_SALT`).

    Args:
      setup: the run's :class:`Setup`.
      state: the state before the refits.
      key_forward: the forward refit's key.
      key_controller: the controller refit's key.
      knobs: the runtime values.

    Examples:
      >>> restart_fits(setup, state, key_fm, key_ctrl, knobs) is state  # warm  # doctest: +SKIP
      True
    """
    cfg, task = setup.config, setup.task
    start = cfg.forward.start
    if start == "fresh":
        params = fresh_forward_params(setup, jax.random.fold_in(key_forward, FRESH_SALT), knobs)
        state = state.replace(forward_params=params)
    if start != "warm":
        opt_state = _forward_optimizer(knobs).init(state.forward_params)
        state = state.replace(forward_opt_state=opt_state)
    start = cfg.controller.start
    if start == "fresh":
        key = jax.random.fold_in(key_controller, FRESH_SALT)
        state = state.replace(controller_params=setup.controller.init(key, task.state_dim))
    if start != "warm":
        opt_state = _controller_optimizer(knobs).init(state.controller_params)
        state = state.replace(controller_opt_state=opt_state)
    return state


FRESH_SALT = 0x5EED
"""Folded into a refit's key for its ``fresh`` parameters (the fit's own key is unchanged)."""


def fresh_forward_params(setup: Setup, key, knobs: Knobs):
    """New forward-model parameters with the initial log-variance bounds of ``knobs``.

    Args:
      setup: the run's :class:`Setup`.
      key: the PRNG key of the initialisation.
      knobs: the runtime values.

    Examples:
      >>> arm = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.3))
      >>> setup = Setup.of(arm)
      >>> knobs = Knobs.of(arm, setup.robot, setup.task)
      >>> params = fresh_forward_params(setup, jax.random.key(0), knobs)
      >>> params["min_log_variance"].tolist(), params["max_log_variance"].tolist()
      ([-10.0, -10.0], [0.5, 0.5])
    """
    return setup.forward.start(setup.forward.init(key, setup.task.state_dim), knobs.forward)


def loss_groups(setup: Setup):
    """The controller loss's groups ``((weight, (output index, ...)), ...)``: None for
    ``controller.loss_form = "squared"``; for ``"norm"`` ``controller.loss_weights``, else
    the task's ``loss_weights()``, else one group of weight 1 over the whole output.

    Args:
      setup: the run's :class:`Setup`.

    Raises:
      ConfigError: an index of ``controller.loss_weights`` is not in ``0 .. output_dim - 1``.

    Examples:
      >>> norm = cfm_jax.ControllerConfig(loss_form="norm")
      >>> loss_groups(Setup.of(cfm_jax.Config(robot="two_link_arm", controller=norm)))
      ((1.0, (0, 1)),)
    """
    cfg, task = setup.config.controller, setup.task
    if cfg.loss_form == "squared":
        return None
    if cfg.loss_weights is not None:
        for _, index in cfg.loss_weights:
            if max(index) >= task.output_dim:
                raise config_lib.ConfigError(
                    f"controller.loss_weights={cfg.loss_weights!r} is not allowed: indices "
                    f"of the task's output y, 0 .. {task.output_dim - 1}"
                )
        return cfg.loss_weights
    if hasattr(task, "loss_weights"):
        return tuple(task.loss_weights())
    return ((1.0, tuple(range(task.output_dim))),)


def _fit_forward(
    setup: Setup, state: TrainState, key, steps: int, knobs: Knobs
) -> tuple[TrainState, jax.Array]:
    """``steps`` forward-model updates on ``state.data``; returns the state and mean loss."""
    params, opt_state, loss = fit_forward(
        setup.forward,
        _forward_optimizer(knobs),
        state.forward_params,
        state.forward_opt_state,
        state.normaliser,
        state.data,
        key,
        steps,
        setup.config.forward.batch_size,
    )
    return state.replace(forward_params=params, forward_opt_state=opt_state), loss


def _fit_controller(
    setup: Setup, loss: str, state: TrainState, key, steps: int, knobs: Knobs
) -> tuple[TrainState, jax.Array]:
    """``steps`` controller updates with ``loss`` through f; returns the state and mean loss."""
    params, opt_state, mean_loss = fit_controller(
        loss,
        setup.forward,
        setup.controller,
        _controller_optimizer(knobs),
        state.controller_params,
        state.controller_opt_state,
        state.forward_params,
        state.normaliser,
        state.data,
        key,
        steps,
        setup.config.controller.batch_size,
        goal=setup.config.controller.goal,
        groups=loss_groups(setup),
        full_batch=setup.config.controller.full_batch,
    )
    return state.replace(controller_params=params, controller_opt_state=opt_state), mean_loss


def _forward_optimizer(knobs: Knobs):
    """Adam at ``knobs.forward_learning_rate`` (its state does not hold the rate, so states of
    configs that differ in it are interchangeable)."""
    return optax.adam(knobs.forward_learning_rate)


def _controller_optimizer(knobs: Knobs):
    return optax.adam(knobs.controller_learning_rate)


# ----- the updates: gradient steps under lax.scan ----------------------------------------
#
# fit_forward fits the forward model by its own objective (the ensemble's Gaussian NLL, each
# member on its own minibatches); fit_controller fits the controller by controller_objective,
# differentiated in the controller's parameters only, so a controller loss never changes
# the forward model.


def controller_objective(
    controller_params,
    forward_params,
    loss,
    forward,
    controller,
    normaliser,
    batch,
    goal: str = "desired",
    groups=None,
    weights=None,
):
    """Mean controller loss over a minibatch, in normalised units (the controller's training loss).

    Model-based losses (``loss.forward``) compare ``s_p = f(s, g(s, s*))`` (ensemble mean)
    with ``s*`` (:func:`cfm_jax.learning.losses.controller_loss`); the others, like ``supervised``,
    compare ``g(s, P s_a)`` with ``tau_run`` in the forward model's scaled torque units (a
    norm in the ``norm`` form).
    ``goal="observed"`` gives ``g`` the observed ``P s_a`` for ``s*``; see docs/concepts/losses.md.

    Args:
      controller_params: the controller's parameters (differentiated).
      forward_params: the forward ensemble's parameters (held fixed).
      loss: a registered :class:`cfm_jax.learning.losses.Loss` or its name
        (:func:`cfm_jax.learning.losses.get`).
      forward: the forward :class:`cfm_jax.learning.networks.Model`.
      controller: the controller :class:`cfm_jax.learning.networks.Model`.
      normaliser: the :class:`cfm_jax.learning.networks.Normaliser`.
      batch: :class:`cfm_jax.sim.dataset.Transitions` ``(batch, ...)``.
      goal: ``"desired"`` or ``"observed"`` (static; else ValueError).
      groups: None (``squared`` form) or the ``norm`` form's groups (static).
      weights: None (a plain mean) or ``(batch,)`` row weights: ``sum w L / max(sum w, 1)``.

    Examples:
      >>> from cfm_jax.learning import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> theta, beta = fm.init(jax.random.key(0), 4), g.init(jax.random.key(1), 4)
      >>> grads = jax.grad(controller_objective)(beta, theta, "joint", fm, g, norm, rows)
      >>> jax.tree.structure(grads) == jax.tree.structure(beta)
      True
    """
    if goal not in ("desired", "observed"):
        raise ValueError(f"goal={goal!r} is not allowed: 'desired' or 'observed'")
    loss = losses.get(loss)
    normaliser = normaliser.at_rows(batch)
    if not loss.forward:
        achieved = normaliser.select(batch.observed)
        predicted = controller.apply(controller_params, normaliser, batch.state, achieved)
        # In the scaled torque space the forward model's input uses (tau / S, T^-1 tau, or
        # the limits): a unit error there moves every joint alike, so the wrist's small
        # torques weigh as much as the shoulder's large ones.
        predicted = normaliser.torque(predicted, batch.state)
        executed = normaliser.torque(batch.action, batch.state)
        distance = losses.supervised if groups is None else _norm_distance
        return _mean(loss.fn(predicted, executed, distance), weights)
    goal_input = batch.desired if goal == "desired" else normaliser.select(batch.observed)
    tau = controller.apply(controller_params, normaliser, batch.state, goal_input)
    predicted = forward.predict(forward_params, normaliser, batch.state, tau, terms=batch.terms)
    predicted_run = None
    if loss.run:  # f(s, tau_run): no controller parameter in it
        predicted_run = forward.predict(
            forward_params, normaliser, batch.state, batch.action, terms=batch.terms
        )
    per_sample = losses.controller_loss(
        loss,
        predicted,
        normaliser.desired(batch.desired),
        normaliser.output(batch.observed),
        select=None if normaliser.desired_index is None else normaliser.select,
        predicted_run=predicted_run,
        groups=groups,
        desired_index=normaliser.desired_index,
    )
    return _mean(per_sample, weights)


def _norm_distance(x, y):
    """The ``norm`` form's distance between actions: ``|x - y|``."""
    return losses.safe_norm(x - y)


def _mean(per_sample, weights):
    """``jnp.mean(per_sample)``, or its mean weighted by ``weights`` (rows of weight 0 out)."""
    if weights is None:
        return jnp.mean(per_sample)
    per_sample = jnp.where(weights > 0, per_sample, 0.0)  # a NaN in an empty row stays out
    return jnp.sum(weights * per_sample) / jnp.maximum(jnp.sum(weights), 1.0)


def fit_forward(forward, optimizer, params, opt_state, normaliser, data, key, steps, batch_size):
    """``steps`` optimiser steps of the forward model's ``objective`` under ``lax.scan``.

    Args:
      forward: the forward :class:`cfm_jax.learning.networks.Model`.
      optimizer: an ``optax`` optimiser.
      params: its parameters.
      opt_state: ``optimizer``'s state for them.
      normaliser: the :class:`cfm_jax.learning.networks.Normaliser`.
      data: the :class:`cfm_jax.sim.dataset.Dataset` to sample from.
      key: PRNG key.
      steps: number of steps (static; 0 returns the inputs and a NaN loss).
      batch_size: rows per minibatch; each step draws ``forward.batches(params)`` (static).

    Returns:
      ``(params, opt_state, mean loss over the steps)``.

    Examples:
      >>> from cfm_jax.learning import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> data = dataset.add(dataset.empty(16, state_dim=4, nv=2), rows)
      >>> params, opt = fm.init(jax.random.key(0), 4), optax.adam(1e-2)
      >>> params, state, first = fit_forward(fm, opt, params, opt.init(params), norm, data,
      ...                                    jax.random.key(1), steps=20, batch_size=4)
      >>> _, _, later = fit_forward(fm, opt, params, state, norm, data, jax.random.key(2),
      ...                           steps=20, batch_size=4)
      >>> bool(later < first)
      True
    """
    batches = forward.batches(params)

    def value_and_grad(params, step_key):
        keys = jax.random.split(step_key, batches)
        batch = jax.vmap(lambda k: dataset.sample(data, k, batch_size))(keys)
        return jax.value_and_grad(forward.objective)(params, normaliser, batch)

    return _scan_steps(value_and_grad, optimizer, params, opt_state, key, steps)


def data_capacity(transitions_per_rollout: int, loop, iterations: int | None = None) -> int:
    """Rows of a run's data set: the babbling's rollouts and one rollout per iteration.

    Args:
      transitions_per_rollout: rows one rollout adds (targets x steps).
      loop: the run's :class:`cfm_jax.config.LoopConfig` (``babbling_rollouts``, ``iterations``).
      iterations: the iterations to hold instead of ``loop.iterations``.

    Examples:
      >>> from cfm_jax.config import LoopConfig
      >>> data_capacity(500, LoopConfig(babbling_rollouts=2, iterations=4))
      3000
    """
    iterations = loop.iterations if iterations is None else iterations
    return transitions_per_rollout * (loop.babbling_rollouts + iterations)


def _scan_steps(value_and_grad, optimizer, params, opt_state, key, steps: int):
    """``steps`` optimiser steps under ``lax.scan``, each on ``value_and_grad(params, key)``
    with a key of its own split from ``key``; returns ``(params, opt_state, mean value)``
    (a NaN value for 0 steps)."""

    def one_step(carry, step_key):
        params, opt_state = carry
        value, grads = value_and_grad(params, step_key)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), value

    (params, opt_state), values = jax.lax.scan(
        one_step, (params, opt_state), jax.random.split(key, steps)
    )
    return params, opt_state, jnp.mean(values) if steps else jnp.float32(jnp.nan)


def fit_controller(
    loss,
    forward,
    controller,
    optimizer,
    params,
    opt_state,
    forward_params,
    normaliser,
    data,
    key,
    steps,
    batch_size,
    goal="desired",
    groups=None,
    full_batch=False,
):
    """``steps`` optimiser steps of :func:`controller_objective` in the controller's parameters.

    Args:
      loss: a registered :class:`cfm_jax.learning.losses.Loss` or its name (static).
      forward: the forward :class:`cfm_jax.learning.networks.Model`.
      controller: the controller :class:`cfm_jax.learning.networks.Model`.
      optimizer: an ``optax`` optimiser.
      params: the controller's parameters.
      opt_state: ``optimizer``'s state for them.
      forward_params: the forward ensemble's parameters (not changed).
      normaliser: the :class:`cfm_jax.learning.networks.Normaliser`.
      data: the :class:`cfm_jax.sim.dataset.Dataset` to sample from.
      key: PRNG key.
      steps: number of steps (static; 0 returns the inputs and a NaN loss).
      batch_size: rows per step (static; not used with ``full_batch``).
      goal: ``"desired"`` or ``"observed"`` (static; :func:`controller_objective`).
      groups: None (``squared`` form) or the ``norm`` form's groups (static).
      full_batch: False: a minibatch drawn with replacement per step; True: every row of the
        buffer, its empty rows weighted 0 (static).

    Returns:
      ``(params, opt_state, mean loss over the steps)``.

    Examples:
      >>> from cfm_jax.learning import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> data = dataset.add(dataset.empty(16, state_dim=4, nv=2), rows)
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> beta, opt = g.init(jax.random.key(1), 4), optax.adam(1e-3)
      >>> beta, state, loss = fit_controller("task", fm, g, opt, beta, opt.init(beta),
      ...                                    fm.init(jax.random.key(0), 4), norm, data,
      ...                                    jax.random.key(2), steps=5, batch_size=4)
      >>> loss.shape
      ()
    """

    filled = None
    if full_batch:
        filled = (jnp.arange(data.capacity) < data.size).astype(jnp.float32)

    def value_and_grad(params, step_key):
        batch = data.data if full_batch else dataset.sample(data, step_key, batch_size)
        return jax.value_and_grad(controller_objective)(
            params,
            forward_params,
            loss,
            forward,
            controller,
            normaliser,
            batch,
            goal,
            groups,
            filled,
        )

    return _scan_steps(value_and_grad, optimizer, params, opt_state, key, steps)


def rollout(
    setup: Setup, policy: rollout_lib.MixedPolicy, key, knobs: Knobs
) -> rollout_lib.Rollout:
    """Roll ``policy`` out on every target (task values of ``knobs``, the config's simulator).

    Args:
      setup: the run's :class:`Setup`.
      policy: a :class:`cfm_jax.sim.rollout.MixedPolicy` (:func:`learned_policy`,
        :func:`mixed_policy`).
      key: the rollout's key (its torque noise).
      knobs: the runtime values.

    Examples:
      >>> arm = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.3))
      >>> setup = Setup.of(arm)
      >>> knobs = Knobs.of(arm, setup.robot, setup.task)
      >>> rollout(setup, mixed_policy(setup, oracle=1.0), jax.random.key(0), knobs).finite.shape
      (5, 30)
    """
    return _run(setup, _task_of(setup, knobs), policy, key)


def _run(
    setup: Setup, task, policy: rollout_lib.MixedPolicy, key, restart: bool = False
) -> rollout_lib.Rollout:
    """Roll ``policy`` out on ``task`` (of ``setup``'s structure) with the config's simulator
    (``restart``: :func:`cfm_jax.sim.rollout.run`'s)."""
    simulator = setup.config.simulator
    return rollout_lib.run(
        task,
        rollout_lib.mixed_policy(task, setup.controller, policy, simulator),
        key,
        simulator=simulator,
        restart=restart,
    )


def _task_of(setup: Setup, knobs: Knobs):
    return setup.task.with_values(knobs.task)


def mixed_policy(setup: Setup, **weights) -> rollout_lib.MixedPolicy:
    """A :class:`cfm_jax.sim.rollout.MixedPolicy` with no learned controller (a placeholder, weight
    0).

    Args:
      setup: the run's :class:`Setup`.
      weights: ``oracle``, ``feedback`` and ``noise_std``, as
        :meth:`cfm_jax.sim.rollout.MixedPolicy.of` takes them.

    Examples:
      >>> pd_only = mixed_policy(Setup.of(cfm_jax.Config(robot="two_link_arm")), feedback=1.0)
      >>> float(pd_only.feedback_weight), float(pd_only.controller_weight)
      (1.0, 0.0)
    """
    task = setup.task
    dummy = setup.controller.init(jax.random.key(0), task.state_dim)
    # A placeholder controller (weight 0 here; a learned one takes its place with its own
    # normaliser): its normaliser has the run's structure, a torque scale (its value
    # unused) or None.
    structure = {"limit": None, "inertia": np.ones(task.action_dim),
                 "coupled": np.eye(task.action_dim), "pose": np.eye(task.action_dim)}  # fmt: skip
    norm = networks.Normaliser.identity(
        task.state_dim,
        task.output_dim,
        setup.robot.torque_limit,
        task.desired_index,
        torque_scale=structure[scale_kind(setup.config, setup.robot)],
        pose_scale=setup.pose_scale,
    )
    return rollout_lib.MixedPolicy.of(dummy, norm, task.action_dim, **weights)


def learned_policy(setup: Setup, state: TrainState) -> rollout_lib.MixedPolicy:
    """The learned controller of ``state`` alone (weight 1; no oracle, feedback or noise).

    Args:
      setup: the run's :class:`Setup`.
      state: one seed's :class:`TrainState`.

    Examples:
      >>> float(learned_policy(setup, state).controller_weight)  # doctest: +SKIP
      1.0
    """
    return rollout_lib.MixedPolicy.of(
        state.controller_params, state.normaliser, setup.task.action_dim, controller=1.0
    )


def with_terms(setup: Setup, transitions: dataset.Transitions) -> dataset.Transitions:
    """``transitions`` with the forward model's per-transition ``terms`` of their states and
    the pose scale's ``pose`` term (:func:`pose_scale`), computed once where they enter the
    data set or the metrics (each unchanged where the run has none, as ``mlp`` or a scale
    other than pose, or where it is set).

    Args:
      setup: the run's :class:`Setup`.
      transitions: :class:`cfm_jax.sim.dataset.Transitions` with any leading axes.

    Examples:
      >>> setup = Setup.of(cfm_jax.Config(robot="two_link_arm"))
      >>> rows = dataset.Transitions(*(jnp.zeros((3, d)) for d in (4, 2, 2, 2)))
      >>> with_terms(setup, rows).terms is None  # the mlp kind
      True
    """
    if setup.pose_scale is not None and transitions.pose is None:
        transitions = transitions._replace(pose=setup.pose_scale(transitions.state))
    if setup.forward.terms is None or transitions.terms is not None:
        return transitions
    return transitions._replace(terms=setup.forward.terms(transitions.state))


def collected(result: rollout_lib.Rollout) -> tuple[dataset.Transitions, jax.Array]:
    """A rollout's transitions as data-set rows, one leading axis, and the mask of those that
    are data (:func:`data_mask`), ``(transitions, valid)``.

    Args:
      result: a :class:`cfm_jax.sim.rollout.Rollout`, leading axes ``([rollouts,] targets, steps)``.

    Examples:
      >>> arm = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.3))
      >>> setup = Setup.of(arm)
      >>> knobs = Knobs.of(arm, setup.robot, setup.task)
      >>> rows, valid = collected(babble_all(setup, jax.random.key(0), knobs))
      >>> rows.state.shape, valid.shape  # 2 rollouts x 5 targets x 30 steps
      ((300, 4), (300,))
    """
    lead = result.finite.ndim
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[lead:]), result.transitions)
    return flat, data_mask(result).reshape(-1)


# ----- metrics ----------------------------------------------------------------------------


def metrics(setup: Setup, state: TrainState, result: rollout_lib.Rollout) -> dict:
    """Per-target metrics ``{name: (targets,) array}`` of a rollout of the current models:
    ``prediction_error`` and ``predicted_task_error`` (over the steps before the first terminal
    step) and :func:`rollout_metrics`; the columns: docs/how-to/metrics.md.

    Args:
      setup: the run's :class:`Setup`.
      state: the seed's :class:`TrainState` (the models that were rolled out).
      result: their rollout.

    Examples:
      >>> sorted(metrics(setup, state, result))[:3]  # doctest: +SKIP
      ['finite_fraction', 'prediction_error', 'predicted_task_error']
    """
    t = with_terms(setup, result.transitions)
    norm = state.normaliser.at_rows(t)
    forward, controller = setup.forward, setup.controller
    predicted = norm.output_inverse(
        forward.predict(state.forward_params, norm, t.state, t.action, terms=t.terms)
    )
    tau = controller.apply(state.controller_params, norm, t.state, t.desired)
    predicted_task = norm.select(
        norm.output_inverse(
            forward.predict(state.forward_params, norm, t.state, tau, terms=t.terms)
        )
    )
    step_mean = _step_mean(result, before_terminal=True)
    return {
        "prediction_error": step_mean(predicted - t.observed),
        "predicted_task_error": step_mean(predicted_task - t.desired),
        **rollout_metrics(setup, result),
    }


def rollout_metrics(setup: Setup, result: rollout_lib.Rollout) -> dict:
    """The per-target metrics of a rollout that need no model (the baselines' table):
    ``tracking_mse``, ``finite_fraction``, ``transitions_added``, :func:`divergence` and the
    task's own; means over the steps inside each target's horizon.

    Args:
      setup: the run's :class:`Setup`.
      result: a rollout.

    Examples:
      >>> rollout_metrics(setup, result)["tracking_mse"].shape  # doctest: +SKIP
      (5,)
    """
    return {
        "tracking_mse": _step_mean(result)(result.tracking_error),
        "finite_fraction": jnp.mean(result.finite.astype(jnp.float32), axis=-1),
        "transitions_added": jnp.sum(data_mask(result), axis=-1).astype(jnp.float32),
        **divergence(result),
        **setup.task.metrics(result),
    }


def divergence(result: rollout_lib.Rollout) -> dict:
    """``diverged`` (1.0 or 0.0) and ``diverged_step`` (the first bad control step, -1.0 when
    none) per rollout, float32.

    Args:
      result: a :class:`cfm_jax.sim.rollout.Rollout` (its ``finite``, ``(..., steps)``).

    Examples:
      >>> from types import SimpleNamespace
      >>> result = SimpleNamespace(finite=jnp.array([[True, True, True], [True, False, False]]))
      >>> {k: v.tolist() for k, v in divergence(result).items()}
      {'diverged': [0.0, 1.0], 'diverged_step': [-1.0, 1.0]}
    """
    diverged = ~result.finite[..., -1]
    good_steps = jnp.sum(result.finite.astype(jnp.int32), axis=-1)
    return {
        "diverged": diverged.astype(jnp.float32),
        "diverged_step": jnp.where(diverged, good_steps, -1).astype(jnp.float32),
    }


def data_mask(result: rollout_lib.Rollout):
    """Steps that become data: finite, inside the horizon and before the first terminal step (a
    legged robot's fall), where the task marks those.

    Args:
      result: a :class:`cfm_jax.sim.rollout.Rollout`.

    Examples:
      >>> from types import SimpleNamespace
      >>> fell = jnp.array([[False, True, False]])
      >>> result = SimpleNamespace(finite=jnp.ones((1, 3), bool), extras={"terminal": fell})
      >>> data_mask(result).tolist()  # no data from the step of the fall on
      [[True, False, False]]
    """
    steps = _steps(result, before_terminal=True)
    return result.finite if steps is None else result.finite & steps


def _step_mean(result: rollout_lib.Rollout, before_terminal: bool = False):
    """``x (targets, steps, k) -> (targets,)``: mean of ``x^2`` over components and the steps of
    :func:`_steps` (every step when the task masks none)."""
    steps = _steps(result, before_terminal)
    if steps is None:
        return lambda x: jnp.mean(jnp.square(x), axis=(-2, -1))
    weights = steps.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(weights, axis=-1), 1.0)
    return lambda x: jnp.sum(jnp.mean(jnp.square(x), axis=-1) * weights, axis=-1) / count


def _steps(result: rollout_lib.Rollout, before_terminal: bool):
    """``(targets, steps)`` mask of the steps inside each target's horizon and, with
    ``before_terminal``, before the first fall (after a restart: every step but the falls;
    a fallen body's dynamics are not the models' to learn); None when the task marks neither."""
    extras = result.extras if isinstance(result.extras, dict) else {}
    masks = [extras["active"]] if "active" in extras else []
    if before_terminal and "restarted" in extras:  # started again after each fall
        masks.append(~extras["terminal"])
    elif before_terminal and "terminal" in extras:
        masks.append(jnp.cumsum(extras["terminal"].astype(jnp.int32), axis=-1) == 0)
    return functools.reduce(jnp.logical_and, masks) if masks else None


def _broadcast(tree, n: int):
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), tree)


# ----- compiled, vmapped over seeds -----------------------------------------------------


class Experiment:
    """One config's static pieces (robot, reference, models) and its compiled functions.

    Build once and reuse across losses and across the values of
    :data:`cfm_jax.config.RUNTIME_FIELDS`: those are arguments (:class:`Knobs`), so each function
    compiles once per experiment. Every method takes the loss and, optionally, the
    :class:`Knobs` of another config (:meth:`knobs_for`). Its only impurity is the caching of
    compiled functions and of host-side results (the loss-independent start, the baselines).

    Args:
      config: the :class:`cfm_jax.config.Config` to build for.
      compiler_options: XLA options for every program it compiles (``jax.jit``'s
        ``compiler_options``), or None. ``{"xla_backend_optimization_level": 0}`` compiles
        two to three times faster on CPU and runs slower: for short runs, such as a check
        of a new robot on MJX, where compiling takes longer than running; the numbers move
        in float32's last digits.

    Attributes:
      config: that config.
      setup: its :class:`Setup`; ``robot``, ``task``, ``forward``,
        ``controller``, ``control_dt``, ``capacity`` are its fields.
      knobs: the :class:`Knobs` of ``config``.

    Examples:
      >>> from cfm_jax import config as cfg
      >>> exp = Experiment(cfg.Config(robot="two_link_arm", task=cfg.TaskConfig(duration=0.3)))
      >>> exp.task.targets, exp.task.steps, exp.state_dim
      (5, 30, 4)
      >>> other = exp.config.replace(seed=4, task=cfg.TaskConfig(duration=0.3, kp=25.0))
      >>> float(exp.knobs_for(other).task["kp"]), float(exp.knobs.task["kp"])
      (25.0, 100.0)
      >>> exp.knobs_for(other.replace(task=cfg.TaskConfig(duration=0.5)))
      Traceback (most recent call last):
      ...
      ValueError: the experiment was built for a config that differs in more than the loss ...
    """

    def __init__(self, config: config_lib.Config, compiler_options: dict | None = None):
        self.config = config
        self.compiler_options = dict(compiler_options) if compiler_options else None
        _xla.use_compilation_cache()  # CFM_JAX_COMPILATION_CACHE=0 turns it off
        if config.simulator == "mjx" and jax.default_backend() == "cpu":
            _xla.warn_if_slow_mjx()
        self.setup = Setup.of(config)
        self._compiled: dict = {}  # name -> jitted function
        self._cache: dict = {}  # host-side results: prepared states, baselines, tasks
        self.knobs = Knobs.of(config, self.robot, self.task)

    @classmethod
    def shared(cls, config: config_lib.Config) -> Experiment:
        """The experiment kept for ``config``'s :func:`cfm_jax.config.structure` and robot model
        bytes (an edited MJCF: a new one), built on first use; :data:`SHARED_EXPERIMENTS` kept."""
        robot = robots.of_config(config)  # a bad robot fails here, named
        structure = json.dumps(config_lib.structure(config), sort_keys=True)
        key = (structure, native.model_digest(robot.mj_model))
        if key in _SHARED:
            _SHARED.move_to_end(key)
            return _SHARED[key]
        experiment = _SHARED[key] = cls(config)
        while len(_SHARED) > SHARED_EXPERIMENTS:
            _SHARED.popitem(last=False)
        return experiment

    # The setup's parts, as attributes of the experiment.
    robot = property(lambda self: self.setup.robot)
    task = property(lambda self: self.setup.task)
    control_dt = property(lambda self: self.setup.control_dt)
    forward = property(lambda self: self.setup.forward)
    controller = property(lambda self: self.setup.controller)
    capacity = property(lambda self: self.setup.capacity)
    state_dim = property(lambda self: self.setup.task.state_dim)
    transitions_per_rollout = property(lambda self: self.setup.transitions_per_rollout)

    @property
    def metric_columns(self) -> tuple[str, ...]:
        """Columns of the metrics table: :data:`METRIC_COLUMNS`, the task's."""
        return METRIC_COLUMNS + tuple(self.task.metric_names)

    # ----- which configs run on this experiment -------------------------------------------

    def compatible(self, config: config_lib.Config) -> bool:
        """True when ``config`` can run on these compilations (no :meth:`differences`)."""
        return not self.differences(config)

    def differences(self, config: config_lib.Config) -> list[str]:
        """Fields outside ``loss`` and the runtime fields where ``config`` differs, both values."""
        return [
            d.replace(" in the run,", " in the experiment,")
            for d in config_lib.differences(
                config_lib.structure(self.config), config_lib.structure(config)
            )
        ]

    def knobs_for(self, config: config_lib.Config) -> Knobs:
        """The :class:`Knobs` of ``config``, a config :meth:`compatible` with this one.

        Raises:
          ValueError: ``config`` differs in a field that changes the compiled program (named).
        """
        diff = self.differences(config)
        if diff:
            raise ValueError(
                "the experiment was built for a config that differs in more than the loss "
                "and the runtime fields (cfm_jax.config.RUNTIME_FIELDS): "
                + "; ".join(diff)
                + "; build an Experiment for this config"
            )
        return Knobs.of(config, self.robot, self.task_for(config))

    def task_for(self, config: config_lib.Config):
        """The task object of a :meth:`compatible` ``config``: this experiment's, or one built on
        the host (the last 8 kept). Its :meth:`values` go to the compiled functions; its host
        attributes (``tracking_scale``, the NumPy references) describe ``config``."""
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

    # ----- one seed, uncompiled (for callers that transform them themselves) ---------------

    def rollout_one(
        self, policy: rollout_lib.MixedPolicy, key, knobs: Knobs | None = None
    ) -> rollout_lib.Rollout:
        """:func:`rollout` for one seed (``knobs`` None: this experiment's)."""
        return rollout(self.setup, policy, key, self._knobs(knobs))

    def babbling_policy(self, knobs: Knobs | None = None) -> rollout_lib.MixedPolicy:
        """:func:`babbling_policy` of ``knobs`` (None: this experiment's)."""
        return babbling_policy(self.setup, self._knobs(knobs))

    def learned_policy(self, state: TrainState) -> rollout_lib.MixedPolicy:
        """:func:`learned_policy` (one seed's ``state``)."""
        return learned_policy(self.setup, state)

    # ----- compiled, vmapped over seeds ---------------------------------------------------

    def _jit(self, name, fn, **kwargs):
        if name not in self._compiled:
            self._compiled[name] = jax.jit(fn, compiler_options=self.compiler_options, **kwargs)
        return self._compiled[name]

    def _vmapped(self, fn, *args, in_axes):
        return jax.vmap(functools.partial(fn, self.setup, *args), in_axes=in_axes)

    def compilations(self) -> dict[str, int]:
        """How many programs each compiled function holds, ``{name: count}`` (one per argument
        shape; the values of :class:`Knobs` add none)."""
        return {name: fn._cache_size() for name, fn in self._compiled.items()}

    def init(self, loss: str, keys, knobs: Knobs | None = None) -> TrainState:
        """:func:`init` for every seed of ``keys``: :meth:`prepare` (shared by
        every loss), then the controller's initial fit with ``loss``."""
        knobs = self._knobs(knobs)
        prepared, key_fit = self.prepare(keys, knobs)
        return self._fit_initial(loss, prepared, key_fit, knobs)

    def prepare(self, keys, knobs: Knobs | None = None) -> tuple[TrainState, jax.Array]:
        """:func:`prepare` for every seed of ``keys`` (cached for the last
        keys and knobs), in two programs: the babbling rollouts (the simulator), then the
        start from their data (normaliser, models, fit of f; no simulator, so JAX's
        persistent compilation cache keeps it)."""
        knobs = self._knobs(knobs)
        cache_key = _fingerprint((jax.random.key_data(keys), knobs))
        cached = self._cache.get("prepared")
        if cached is None or cached[0] != cache_key:

            def babble(key, knobs):
                key_babble, _ = jax.random.split(key, 2)
                return collected(babble_all(self.setup, key_babble, knobs))

            data = self._jit("babbling_data", jax.vmap(babble, in_axes=(0, None)))(keys, knobs)
            self._cache["prepared"] = (cache_key, self._prepare_from_data(keys, knobs, data))
        return self._cache["prepared"][1]

    def _prepare_from_data(self, keys, knobs: Knobs, data):
        def from_data(key, knobs, chunk, valid):
            return prepare(self.setup, key, knobs, (chunk, valid))

        fn = jax.vmap(from_data, in_axes=(0, None, 0, 0))
        return self._jit("prepare_from_data", fn)(keys, knobs, *data)

    def init_from_data(
        self, loss: str, keys, chunk: dataset.Transitions, valid, knobs: Knobs | None = None
    ) -> TrainState:
        """:meth:`init` from given babbling data (``chunk``, ``valid`` with a seed axis); the keys
        are used as :meth:`init` uses them, so the same data and seed give the same state."""
        knobs = self._knobs(knobs)
        prepared, key_fit = self._prepare_from_data(keys, knobs, (chunk, valid))
        return self._fit_initial(loss, prepared, key_fit, knobs)

    def _fit_initial(self, loss: str, prepared, key_fit, knobs: Knobs) -> TrainState:
        fn = self._vmapped(fit_initial_controller, loss, in_axes=(0, 0, None))
        return self._jit(f"init/{loss}", fn)(prepared, key_fit, knobs)

    def iteration(self, loss: str, state: TrainState, knobs: Knobs | None = None):
        """:func:`iteration` for every seed: ``(state, metrics)``."""
        fn = self._vmapped(iteration, loss, in_axes=(0, None))
        return self._jit(f"iteration/{loss}", fn)(state, self._knobs(knobs))

    def replay_iteration(
        self, loss: str, state: TrainState, chunk, valid, knobs: Knobs | None = None
    ):
        """:meth:`iteration` on given data (``chunk``, ``valid`` with seed axes), not collected."""

        def replay(state, knobs, chunk, valid):
            return iteration(self.setup, loss, state, knobs, (chunk, valid))

        fn = jax.vmap(replay, in_axes=(0, None, 0, 0))
        return self._jit(f"replay/{loss}", fn)(state, self._knobs(knobs), chunk, valid)

    # ----- compiled, over losses and seeds -------------------------------------------------
    #
    # Losses trained together share what does not depend on the loss: the babbling data and
    # the start from them (:meth:`prepare`, once per seed) and the compiled rollout program
    # (one compile for every loss). Everything else runs, one loss after the other, through
    # the programs of that loss trained alone: a loss's numbers never depend on which losses
    # ran beside it, by construction. A loss axis inside one program does not give that:
    # vmapped over losses x seeds, the networks' matrix products compile for another batch
    # size and round differently in the last bits; as a lax.map over the losses (this
    # library's form until 2026-11-28), XLA compiles the loop's body apart, and the
    # rigid-body models' rollouts and refits came out different from the loss alone in the
    # last bits. The simulator and the updates run one loss after the other in either form;
    # what a loss axis saved was compiling the forward model's refit once, not per loss.
    # The programs keep a leading loss axis of length 1 (the single-loss programs' form
    # since issue 46, so that single-loss numbers stay what they were).

    def init_each(self, losses, keys, knobs: Knobs | None = None, data=None) -> list[TrainState]:
        """:meth:`init` for each loss of ``losses`` and every seed of ``keys``: :meth:`prepare`
        once per seed (every loss starts from it, with the same key), then each loss's initial
        controller fit. One state per loss, its leaves with leading ``(1, seed)`` axes.

        Args:
          losses: distinct controller-loss names.
          keys: one PRNG key per seed.
          knobs: the runtime values (None: this experiment's).
          data: babbling data ``(chunk, valid)`` with a seed axis instead of babbling, or None.

        Examples:
          >>> # not run: the initial fits take seconds to minutes
          >>> joint, task = exp.init_each(("joint", "task"), keys)  # doctest: +SKIP
          >>> joint.iteration.shape  # (1, seeds)  # doctest: +SKIP
          (1, 3)
        """
        losses, knobs = config_lib.loss_names(losses), self._knobs(knobs)
        if data is None:
            prepared, key_fit = self.prepare(keys, knobs)
        else:
            prepared, key_fit = self._prepare_from_data(keys, knobs, data)

        def program(loss):
            def fit(prepared, key_fit, knobs):
                fn = functools.partial(fit_initial_controller, self.setup, loss)
                return _stack([jax.vmap(fn, in_axes=(0, 0, None))(prepared, key_fit, knobs)])

            return self._jit(f"init[{loss}]", fit)

        return [program(loss)(prepared, key_fit, knobs) for loss in losses]

    def iteration_losses(self, losses, state: TrainState, knobs: Knobs | None = None, data=None):
        """:func:`iteration` for every loss and seed of ``state`` (leading ``(loss, seed)``
        axes) in two programs: :func:`collect` (the simulator, shared by the losses), then
        :func:`refit_forward` and the loss's :func:`refit_controller` (no simulator: the
        persistent compilation cache keeps it). Each loss's slice is that loss trained alone,
        bit for bit. Returns ``(state, metrics)``, metrics with leading ``(loss, seed)`` axes.

        Args:
          losses: the losses of ``state``'s first axis, in order.
          state: the :class:`TrainState` of the last call or of :meth:`init_each` (one loss),
            or those stacked along their first axis.
          knobs: the runtime values (None: this experiment's).
          data: ``(chunk, valid)`` with a seed axis to add instead of the rollouts' (a replay:
            every loss adds the same data), or None.

        Examples:
          >>> # not run: an iteration trains (seconds)
          >>> state, metrics = exp.iteration_losses(("joint", "task"), state)  # doctest: +SKIP
          >>> metrics["tracking_mse"].shape  # (losses, seeds, targets)  # doctest: +SKIP
          (2, 3, 5)
        """
        losses, knobs = config_lib.loss_names(losses), self._knobs(knobs)
        if len(losses) == 1:  # no copy of the state
            return self._iteration_of_one(losses[0], state, knobs, data)
        steps = [
            self._iteration_of_one(loss, _slice(state, i), knobs, data)
            for i, loss in enumerate(losses)
        ]
        return _concatenate([s for s, _ in steps]), _concatenate([m for _, m in steps])

    def _iteration_of_one(self, loss: str, state: TrainState, knobs: Knobs, data):
        """One loss's iteration, ``state`` with leading ``(1, seed)`` axes."""

        def collect_all(state, knobs):
            fn = functools.partial(collect, self.setup)
            return _stack([jax.vmap(fn, in_axes=(0, None))(_index(state, 0), knobs)])

        def refit(state, data, knobs):
            state, data = _index((state, data), 0)
            fn = functools.partial(refit_forward, self.setup)
            state, forward_loss, key = jax.vmap(fn, in_axes=(0, 0, None))(state, data, knobs)
            fn = functools.partial(refit_controller, self.setup, loss)
            state, controller_loss = jax.vmap(fn, in_axes=(0, 0, None))(state, key, knobs)
            return _stack([(state, forward_loss, controller_loss)])

        out, collected = self._jit("collect[1]", collect_all)(state, knobs)
        if data is not None:  # a replay: the recorded data
            collected = jax.tree.map(lambda x: x[None], data)
        state, out["forward_loss"], out["controller_loss"] = self._jit(f"refit[{loss}]", refit)(
            state, collected, knobs
        )
        return state, out

    # ----- the whole run: the start, every iteration, the final evaluation ----------------

    def run(self, records, keys, knobs: Knobs | None = None, data=None, progress=None):
        """Algorithm 1 for each loss of ``records`` and every seed of ``keys``: :meth:`init_each`
        (or a loss's resumed state), each iteration for each loss that has reached it
        (:meth:`iteration_losses`, one loss after the other), the final :meth:`evaluate`.
        Returns each loss's final state (leading ``(1, seed)`` axes) and the first
        iteration's wall time, its compilation included (NaN: none ran).

        Args:
          records: ``{loss: record}``, told each step: ``record.continued_from`` (the
            iterations of a run continued for more, or None), ``start(template) -> (state,
            first iteration)``, ``iteration(i, state, previous, metrics) -> state to go on
            from``, ``record(iteration, metrics)`` (:class:`cfm_jax.runs.recorder.Recorder`).
          keys: one PRNG key per seed.
          knobs: the runtime values (None: this experiment's).
          data: a :class:`cfm_jax.sim.dataset.Recorded` to replay, or None.
          progress: ``progress(steps, next_stage)`` after the start, each iteration and the
            final evaluation (``loop.iterations + 2`` steps in all), or None.
        """
        knobs, names = self._knobs(knobs), tuple(records)
        iterations, per_rollout = self.config.loop.iterations, self.transitions_per_rollout
        progress = progress or (lambda steps, next_stage: None)
        chunk = None
        if data is not None:
            chunk = data.chunk(0, self.config.loop.babbling_rollouts * per_rollout)
        initial = self.init_each(names, keys, knobs, data=chunk)
        states, firsts = {}, {}
        for name in names:
            template, ran = _index(initial.pop(0), 0), records[name].continued_from
            if ran is None:
                start, firsts[name] = records[name].start(template)
            else:  # a run continued for more iterations: restored as it was, its data set grown
                start, firsts[name] = records[name].start(self.resized(template, ran))
                start = self.resized(start)
            del template
            states[name] = _stack([start])
            del start
        earliest, compile_seconds = min(firsts.values()), float("nan")

        def stage(i):  # what comes after i iterations
            return f"iteration {i + 1}" if i < iterations else "final evaluation"

        progress(1 + earliest, stage(earliest))
        for i in range(earliest, iterations):  # a resumed loss goes on from its own iteration
            t0 = time.perf_counter()
            chunk = None if data is None else data.chunk(i + 1, per_rollout)
            for name in (name for name in names if firsts[name] <= i):
                new, metrics = self.iteration_losses((name,), states[name], knobs, data=chunk)
                metrics = jax.device_get(_index(metrics, 0))
                one = _index(new, 0)
                previous = functools.partial(_index, states[name], 0)  # copied only if needed
                kept = records[name].iteration(i, one, previous, metrics)
                # A seed stopped by a non-finite update keeps its previous state.
                states[name] = new if kept is one else _stack([kept])
                del new, one, previous, kept
            if np.isnan(compile_seconds):
                compile_seconds = time.perf_counter() - t0
            progress(1, stage(i + 1))
        for name in names:
            final = self.evaluate(_index(states[name], 0), knobs)
            records[name].record(iterations, jax.device_get(final))
        progress(1, None)
        return states, compile_seconds

    def resized(self, state: TrainState, iterations: int | None = None) -> TrainState:
        """``state`` (leading seed axis) with a data set of :func:`data_capacity` rows for
        ``iterations`` iterations (None: ``loop.iterations``)."""
        capacity = data_capacity(self.transitions_per_rollout, self.config.loop, iterations)
        data = jax.vmap(functools.partial(dataset.resized, capacity=capacity))(state.data)
        return state.replace(data=data)

    def rollout(
        self, policy: rollout_lib.MixedPolicy, keys, knobs: Knobs | None = None
    ) -> rollout_lib.Rollout:
        """Rollouts of ``policy`` (a leading seed axis) for ``keys``, compiled once per shape."""
        fn = self._vmapped(rollout, in_axes=(0, 0, None))
        return self._jit("rollout", fn)(policy, keys, self._knobs(knobs))

    def babbling_rollouts(self, keys, knobs: Knobs | None = None) -> rollout_lib.Rollout:
        """:func:`babble_all` per seed: the babbling rollouts ``(seeds,
        loop.babbling_rollouts, ...)`` that :meth:`init` starts from (for inspection)."""
        fn = self._vmapped(babble_all, in_axes=(0, None))
        key_babble = jax.vmap(lambda k: jax.random.split(k, 2)[0])(keys)
        return self._jit("babble", fn)(key_babble, self._knobs(knobs))

    def evaluate(self, state: TrainState, knobs: Knobs | None = None) -> dict:
        """Metrics of a rollout of the current controllers, every seed
        (:func:`evaluate`, key :func:`evaluation_key`)."""
        keys = jax.vmap(evaluation_key)(state)
        policy = jax.vmap(self.learned_policy)(state)
        result = self.rollout(policy, keys, knobs)
        fn = self._vmapped(evaluate, in_axes=(0, 0))
        return self._jit("evaluate", fn)(state, result)

    def baselines(self, knobs: Knobs | None = None) -> pd.DataFrame:
        """Tracking MSE per target of the oracle (MuJoCo inverse dynamics) and PD-only
        (with the task values of ``knobs``: gains and references; cached per knobs)."""
        knobs = self._knobs(knobs)
        cache = self._cache.setdefault("baselines", {})
        cache_key = _fingerprint(knobs.task)
        if cache_key in cache:
            return cache[cache_key].copy()
        policies = {
            "oracle": mixed_policy(self.setup, oracle=1.0),
            "pd_only": mixed_policy(self.setup, feedback=1.0),
        }
        rows = []
        metrics_fn = jax.vmap(functools.partial(rollout_metrics, self.setup))
        for name, policy in policies.items():
            keys = jax.random.split(jax.random.key(0), 1)
            result = self.rollout(jax.tree.map(lambda x: x[None], policy), keys, knobs)
            metrics = jax.device_get(metrics_fn(result))
            names = ["tracking_mse", *self.task.metric_names]
            for k in range(self.task.targets):
                row = {"baseline": name, "target": k}
                row.update({m: float(np.asarray(metrics[m])[0, k]) for m in names})
                rows.append(row)
        cache[cache_key] = pd.DataFrame(rows)
        return cache[cache_key].copy()


def _stack(trees):
    """The pytrees ``trees`` stacked along a new leading axis."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _concatenate(trees):
    """The pytrees ``trees`` joined along their leading axis (one tree: itself, no copy)."""
    if len(trees) == 1:
        return trees[0]
    return jax.tree.map(lambda *xs: jnp.concatenate(xs), *trees)


def _slice(tree, i: int):
    """Entry ``i`` of a pytree's leading axis, the axis kept (length 1)."""
    return jax.tree.map(lambda x: x[i : i + 1], tree)


def _index(tree, i: int):
    """Entry ``i`` of a pytree's leading axis."""
    return jax.tree.map(lambda x: x[i], tree)


SHARED_EXPERIMENTS = 4
"""Experiments :meth:`Experiment.shared` keeps per process (also per Ray worker)."""
_SHARED: collections.OrderedDict = collections.OrderedDict()


def clear_shared() -> None:
    """Drops the experiments :meth:`Experiment.shared` keeps (their programs and data).

    Examples:
      >>> clear_shared(); len(_SHARED)
      0
    """
    _SHARED.clear()


def _fingerprint(tree) -> bytes:
    """Bytes that identify the values, shapes and dtypes of a pytree of arrays."""
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        leaf = np.asarray(leaf)
        digest.update(f"{leaf.dtype}{leaf.shape}".encode())
        digest.update(leaf.tobytes())
    return digest.digest()
