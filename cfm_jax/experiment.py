"""Algorithm 1 compiled: the pure functions of :mod:`cfm_jax.algorithm`, vmapped over seeds,
jit-compiled once per config structure and kept with their config (:class:`Experiment`)."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from cfm_jax import _xla, algorithm, dataset, rollout, tasks
from cfm_jax import config as config_lib
from cfm_jax.algorithm import METRIC_COLUMNS, Knobs, TrainState


class Experiment:
    """One config's static pieces (robot, reference, models) and its compiled functions.

    Build once and reuse across losses and across the values of
    :data:`cfm_jax.config.RUNTIME_FIELDS`: those are arguments (:class:`Knobs`), so each function
    compiles once per experiment. Every method takes the loss and, optionally, the
    :class:`Knobs` of another config (:meth:`knobs_for`). Its only impurity is the caching of
    compiled functions and of host-side results (the loss-independent start, the baselines).

    Args:
      config: the :class:`cfm_jax.config.Config` to build for.

    Attributes:
      config: that config.
      setup: its :class:`cfm_jax.algorithm.Setup`; ``robot``, ``task``, ``forward``,
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

    def __init__(self, config: config_lib.Config):
        self.config = config
        _xla.use_compilation_cache()  # CFM_JAX_COMPILATION_CACHE=0 turns it off
        if config.simulator == "mjx" and jax.default_backend() == "cpu":
            _xla.warn_if_slow_mjx()
        self.setup = algorithm.Setup.of(config)
        self._compiled: dict = {}  # name -> jitted function
        self._cache: dict = {}  # host-side results: prepared states, baselines, tasks
        self.knobs = self.knobs_for(config)

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
        """Columns of the metrics table: :data:`cfm_jax.algorithm.METRIC_COLUMNS`, the task's."""
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
        self, policy: rollout.MixedPolicy, key, knobs: Knobs | None = None
    ) -> rollout.Rollout:
        """:func:`cfm_jax.algorithm.rollout` for one seed (``knobs`` None: this experiment's)."""
        return algorithm.rollout(self.setup, policy, key, self._knobs(knobs))

    def babbling_policy(self, knobs: Knobs | None = None) -> rollout.MixedPolicy:
        """:func:`cfm_jax.algorithm.babbling_policy` of ``knobs`` (None: this experiment's)."""
        return algorithm.babbling_policy(self.setup, self._knobs(knobs))

    def learned_policy(self, state: TrainState) -> rollout.MixedPolicy:
        """:func:`cfm_jax.algorithm.learned_policy` (one seed's ``state``)."""
        return algorithm.learned_policy(self.setup, state)

    # ----- compiled, vmapped over seeds ---------------------------------------------------

    def _jit(self, name, fn, **kwargs):
        if name not in self._compiled:
            self._compiled[name] = jax.jit(fn, **kwargs)
        return self._compiled[name]

    def _vmapped(self, fn, *args, in_axes):
        return jax.vmap(functools.partial(fn, self.setup, *args), in_axes=in_axes)

    def compilations(self) -> dict[str, int]:
        """How many programs each compiled function holds, ``{name: count}`` (one per argument
        shape; the values of :class:`Knobs` add none)."""
        return {name: fn._cache_size() for name, fn in self._compiled.items()}

    def init(self, loss: str, keys, knobs: Knobs | None = None) -> TrainState:
        """:func:`cfm_jax.algorithm.init` for every seed of ``keys``: :meth:`prepare` (shared by
        every loss), then the controller's initial fit with ``loss``."""
        knobs = self._knobs(knobs)
        prepared, key_fit = self.prepare(keys, knobs)
        return self._fit_initial(loss, prepared, key_fit, knobs)

    def prepare(self, keys, knobs: Knobs | None = None) -> tuple[TrainState, jax.Array]:
        """:func:`cfm_jax.algorithm.prepare` for every seed of ``keys`` (cached for the last
        keys and knobs), in two programs: the babbling rollouts (the simulator), then the
        start from their data (normaliser, models, fit of f; no simulator, so JAX's
        persistent compilation cache keeps it)."""
        knobs = self._knobs(knobs)
        cache_key = _fingerprint((jax.random.key_data(keys), knobs))
        cached = self._cache.get("prepared")
        if cached is None or cached[0] != cache_key:

            def babble(key, knobs):
                key_babble, _ = jax.random.split(key, 2)
                return algorithm.collected(algorithm.babble_all(self.setup, key_babble, knobs))

            data = self._jit("babbling_data", jax.vmap(babble, in_axes=(0, None)))(keys, knobs)
            self._cache["prepared"] = (cache_key, self._prepare_from_data(keys, knobs, data))
        return self._cache["prepared"][1]

    def _prepare_from_data(self, keys, knobs: Knobs, data):
        def prepare(key, knobs, chunk, valid):
            return algorithm.prepare(self.setup, key, knobs, (chunk, valid))

        fn = jax.vmap(prepare, in_axes=(0, None, 0, 0))
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
        fn = self._vmapped(algorithm.fit_initial_controller, loss, in_axes=(0, 0, None))
        return self._jit(f"init/{loss}", fn)(prepared, key_fit, knobs)

    def iteration(self, loss: str, state: TrainState, knobs: Knobs | None = None):
        """:func:`cfm_jax.algorithm.iteration` for every seed: ``(state, metrics)``."""
        fn = self._vmapped(algorithm.iteration, loss, in_axes=(0, None))
        return self._jit(f"iteration/{loss}", fn)(state, self._knobs(knobs))

    def replay_iteration(
        self, loss: str, state: TrainState, chunk, valid, knobs: Knobs | None = None
    ):
        """:meth:`iteration` on given data (``chunk``, ``valid`` with seed axes), not collected."""

        def replay(state, knobs, chunk, valid):
            return algorithm.iteration(self.setup, loss, state, knobs, (chunk, valid))

        fn = jax.vmap(replay, in_axes=(0, None, 0, 0))
        return self._jit(f"replay/{loss}", fn)(state, self._knobs(knobs), chunk, valid)

    # ----- compiled, over losses and seeds -------------------------------------------------
    #
    # The loss is a loop axis of one program, not a vmap axis: vmapping the networks over
    # losses x seeds changes the batch size XLA:CPU compiles each matrix product for, and
    # with it the rounding of the last bits (seen on the tiny test networks), so a loss's
    # numbers would depend on which other losses ran beside it. In a loop (lax.map) every
    # loss runs the single-loss program's computation (bit for bit on the tests' tiny
    # configs; the rollouts of the rigid-body iiwa and of the walk can differ from the
    # program alone in the last bits: docs/performance.md, found 2026-11-28); the
    # loss-specific part, the controller's refit, is picked by lax.switch on the loss's
    # index (one branch runs).

    def init_losses(self, losses, keys, knobs: Knobs | None = None, data=None) -> TrainState:
        """:meth:`init` for every loss of ``losses`` and every seed of ``keys``: :meth:`prepare`
        once per seed (every loss starts from it, with the same key), then each loss's initial
        controller fit, all losses in one program. Leaves have leading ``(loss, seed)`` axes.

        Args:
          losses: distinct controller-loss names.
          keys: one PRNG key per seed.
          knobs: the runtime values (None: this experiment's).
          data: babbling data ``(chunk, valid)`` with a seed axis instead of babbling, or None.

        Examples:
          >>> # not run: the initial fits take seconds to minutes
          >>> state = exp.init_losses(("joint", "task"), keys)  # doctest: +SKIP
          >>> state.iteration.shape  # (losses, seeds)  # doctest: +SKIP
          (2, 3)
        """
        losses, knobs = loss_names(losses), self._knobs(knobs)
        if data is None:
            prepared, key_fit = self.prepare(keys, knobs)
        else:
            prepared, key_fit = self._prepare_from_data(keys, knobs, data)

        def fits(prepared, key_fit, knobs):
            def fit(loss, _):
                fn = functools.partial(algorithm.fit_initial_controller, self.setup, loss)
                return jax.vmap(fn, in_axes=(0, 0, None))(prepared, key_fit, knobs)

            return _loop_losses(losses, None, per_loss=fit)

        return self._jit(f"init[{','.join(losses)}]", fits)(prepared, key_fit, knobs)

    def iteration_losses(self, losses, state: TrainState, knobs: Knobs | None = None, data=None):
        """:func:`cfm_jax.algorithm.iteration` for every loss and seed of ``state`` (leading
        ``(loss, seed)`` axes), in two programs, each a loop over the losses vmapped over
        seeds: :func:`cfm_jax.algorithm.collect` (the rollouts and their metrics: the
        simulator), then :func:`cfm_jax.algorithm.refit_forward` and the loss's
        :func:`cfm_jax.algorithm.refit_controller` (no simulator, so JAX's persistent
        compilation cache keeps this program, the larger one). Each loss's slice equals that
        loss's :meth:`iteration` bit for bit on the tests' tiny configs, not on every config
        (XLA compiles the loop's body apart; docs/performance.md). Returns ``(state,
        metrics)``, metrics with leading
        ``(loss, seed)`` axes.

        Args:
          losses: the losses of ``state``'s first axis, in order.
          state: the :class:`TrainState` of :meth:`init_losses` or of the last call.
          knobs: the runtime values (None: this experiment's).
          data: ``(chunk, valid)`` with a seed axis to add instead of the rollouts' (a replay:
            every loss adds the same data), or None.

        Examples:
          >>> # not run: an iteration trains (seconds)
          >>> state, metrics = exp.iteration_losses(("joint", "task"), state)  # doctest: +SKIP
          >>> metrics["tracking_mse"].shape  # (losses, seeds, targets)  # doctest: +SKIP
          (2, 3, 5)
        """
        losses, knobs = loss_names(losses), self._knobs(knobs)

        def collect(state, knobs):
            def one(state):
                fn = functools.partial(algorithm.collect, self.setup)
                return jax.vmap(fn, in_axes=(0, None))(state, knobs)

            return _loop_losses(losses, state, common=one)

        def refit(state, data, knobs):
            def forward(entry):  # the same for every loss: outside the switch, compiled once
                fn = functools.partial(algorithm.refit_forward, self.setup)
                return jax.vmap(fn, in_axes=(0, 0, None))(*entry, knobs)

            def controller(loss, entry):
                state, forward_loss, key = entry
                fn = functools.partial(algorithm.refit_controller, self.setup, loss)
                state, controller_loss = jax.vmap(fn, in_axes=(0, 0, None))(state, key, knobs)
                return state, forward_loss, controller_loss

            return _loop_losses(losses, (state, data), common=forward, per_loss=controller)

        out, collected = self._jit(f"collect[{len(losses)}]", collect)(state, knobs)
        if data is not None:  # a replay: every loss adds the recorded data
            collected = jax.tree.map(lambda x: jnp.broadcast_to(x, (len(losses), *x.shape)), data)
        state, out["forward_loss"], out["controller_loss"] = self._jit(
            f"refit[{','.join(losses)}]", refit
        )(state, collected, knobs)
        return state, out

    def evaluate_losses(self, state: TrainState, knobs: Knobs | None = None) -> dict:
        """:meth:`evaluate` of each loss of a state with leading ``(loss, seed)`` axes, with the
        programs of :meth:`evaluate` (metrics with the same leading axes).

        Args:
          state: the :class:`TrainState` of :meth:`iteration_losses`.
          knobs: the runtime values (None: this experiment's).

        Examples:
          >>> exp.evaluate_losses(state)["tracking_mse"].shape  # doctest: +SKIP
          (2, 3, 5)
        """
        count = state.iteration.shape[0]
        return _stack([self.evaluate(_index(state, i), knobs) for i in range(count)])

    def rollout(
        self, policy: rollout.MixedPolicy, keys, knobs: Knobs | None = None
    ) -> rollout.Rollout:
        """Rollouts of ``policy`` (a leading seed axis) for ``keys``, compiled once per shape."""
        fn = self._vmapped(algorithm.rollout, in_axes=(0, 0, None))
        return self._jit("rollout", fn)(policy, keys, self._knobs(knobs))

    def babbling_rollouts(self, keys, knobs: Knobs | None = None) -> rollout.Rollout:
        """:func:`cfm_jax.algorithm.babble_all` per seed: the babbling rollouts ``(seeds,
        loop.babbling_rollouts, ...)`` that :meth:`init` starts from (for inspection)."""
        fn = self._vmapped(algorithm.babble_all, in_axes=(0, None))
        key_babble = jax.vmap(lambda k: jax.random.split(k, 2)[0])(keys)
        return self._jit("babble", fn)(key_babble, self._knobs(knobs))

    def evaluate(self, state: TrainState, knobs: Knobs | None = None) -> dict:
        """Metrics of a rollout of the current controllers, every seed
        (:func:`cfm_jax.algorithm.evaluate`, key :func:`cfm_jax.algorithm.evaluation_key`)."""
        keys = jax.vmap(algorithm.evaluation_key)(state)
        policy = jax.vmap(self.learned_policy)(state)
        result = self.rollout(policy, keys, knobs)
        fn = self._vmapped(algorithm.evaluate, in_axes=(0, 0))
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
            "oracle": algorithm.mixed_policy(self.setup, oracle=1.0),
            "pd_only": algorithm.mixed_policy(self.setup, feedback=1.0),
        }
        rows = []
        metrics_fn = jax.vmap(functools.partial(algorithm.rollout_metrics, self.setup))
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


def loss_names(losses) -> tuple[str, ...]:
    """``losses`` as a tuple of distinct controller-loss names (``"all"``: the paper's four).

    Args:
      losses: a loss name, a sequence of them, or ``"all"``.

    Raises:
      ConfigError: an unknown or repeated name, or none (a ``ValueError``).

    Examples:
      >>> loss_names("all")
      ('joint', 'task', 'distal', 'supervised')
    """
    if losses == "all":
        return tuple(config_lib.PAPER_LOSSES)
    names = (losses,) if isinstance(losses, str) else tuple(losses)
    if (
        not names
        or len(set(names)) != len(names)
        or any(n not in config_lib.CONTROLLER_LOSSES for n in names)
    ):
        config_lib.fail(
            "losses", losses, f"'all' or distinct names from {config_lib.CONTROLLER_LOSSES}"
        )
    return names


def _loop_losses(losses: tuple[str, ...], xs, common=None, per_loss=None):
    """For each loss and its entry ``x`` of ``xs``'s leading axis (``xs`` None: ``x`` None):
    ``common(x)``, the part that does not depend on the loss, then ``per_loss(loss, ·)`` on
    its result, picked by a ``lax.switch`` on the loss's index (one branch runs; only this
    part is in the program once per loss); results stacked. A ``lax.map`` over the losses;
    one loss: the single-loss program itself. ``common``/``per_loss`` None: the identity."""
    common = common or (lambda x: x)

    def branch(loss):
        return functools.partial(per_loss, loss) if per_loss else lambda x: x

    if len(losses) == 1:
        return _stack([branch(losses[0])(common(None if xs is None else _index(xs, 0)))])
    branches = [branch(loss) for loss in losses]

    def one(entry):
        index, x = entry
        x = common(x)
        return jax.lax.switch(index, branches, x) if per_loss else x

    return jax.lax.map(one, (jnp.arange(len(losses)), xs))


def _stack(trees):
    """The pytrees ``trees`` stacked along a new leading axis."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _index(tree, i: int):
    """Entry ``i`` of a pytree's leading axis."""
    return jax.tree.map(lambda x: x[i], tree)


def _fingerprint(tree) -> bytes:
    """Bytes that identify the values, shapes and dtypes of a pytree of arrays."""
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        leaf = np.asarray(leaf)
        digest.update(f"{leaf.dtype}{leaf.shape}".encode())
        digest.update(leaf.tobytes())
    return digest.digest()
