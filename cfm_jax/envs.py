"""The library's arm tracking tasks as Gymnasium environments, for SAC and PPO (docs/peers.md).

:class:`TrackingEnv` wraps the library's own task object (:func:`cfm_jax.tasks.make`): the
same robot, references, control period, torque limits, start state, MuJoCo C physics
(:class:`cfm_jax.native.Stepper`) and tracking error as the ``native`` simulator. An episode
is one reference. The observation is the controller's input ``(s_t, s*_t)`` scaled by the
robot's own scales (:func:`cfm_jax.tasks.scales.robot_scales`), float32; the action ``a`` in
``[-1, 1]`` is the torque ``a * tau_max``; the reward is minus the mean square of the next
state's tracking error (an episode's mean ``-reward`` is :func:`cfm_jax.rollout.tracking_mse`).
Episodes are truncated after the reference's steps and terminated when the simulation
diverges (``info["diverged"]``, with the reward of the last good state).

Needs ``gymnasium`` (``pip install "cfm_jax[peers]"``). The legged tasks are not wrapped yet.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax import config as config_lib
from cfm_jax import native, networks, rollout
from cfm_jax.tasks import scales

REFERENCES = ("training", "test")
"""Values of :class:`TrackingEnv`'s ``references``."""


class TrackingEnv(gymnasium.Env):
    """An arm tracking task of the library as a Gymnasium environment (see the module).

    Args:
      config: a :class:`cfm_jax.config.Config` (its robot, task and servo conversion; the
        learner's fields are not used). ``simulator`` must be ``native``.
      references: one of :data:`REFERENCES`: ``training``, reaches drawn as the ``reaching``
        babbling draws them (:mod:`cfm_jax.babbling`), from the environment's seed, blind to
        the test references; or ``test``, the task's test references in turn (evaluation).
      experiment: an :class:`cfm_jax.experiment.Experiment` of ``config`` to take the robot
        and task from (saves building them again), or None.

    Attributes:
      task: the library's task object.
      robot: its :class:`cfm_jax.robots.Robot`.
      control_dt: the control period (s); an episode is ``task.steps`` of them.

    Raises:
      ConfigError: a legged task, the ``mjx`` simulator, or an unknown ``references``.

    Examples:
      >>> import numpy as np
      >>> from cfm_jax import config
      >>> cfg = config.Config(robot="two_link_arm", task=config.TaskConfig(duration=0.1))
      >>> env = TrackingEnv(cfg)
      >>> obs, info = env.reset(seed=0)
      >>> obs.shape, env.action_space.shape, env.task.steps, env.control_dt
      ((6,), (2,), 10, 0.01)
      >>> obs, reward, terminated, truncated, info = env.step(np.zeros(2, np.float32))
      >>> bool(reward <= 0), terminated, truncated
      (True, False, False)
    """

    metadata = {"render_modes": []}

    def __init__(self, config: config_lib.Config, references: str = "training", experiment=None):
        from cfm_jax.experiment import Experiment

        if references not in REFERENCES:
            config_lib.fail("references", references, f"one of {REFERENCES}")
        if config.simulator != "native":
            config_lib.fail(
                "simulator",
                config.simulator,
                "'native' (the environment steps MuJoCo C on the host)",
            )
        if config.task.name not in ("inverse_dynamics", "opspace"):
            config_lib.fail(
                "task.name",
                config.task.name,
                "an arm task ('inverse_dynamics', 'opspace'): the legged tasks are not wrapped yet",
            )
        experiment = experiment or Experiment(config)
        self.task, self.robot = experiment.task, experiment.robot
        self.control_dt = self.task.control_dt
        self.references = references
        task, robot = self.task, self.robot
        self._stepper = native.Stepper(robot.mj_model, rollout.substeps(robot, self.control_dt))
        self._limit = np.asarray(robot.torque_limit, np.float32)
        self._fns = _compiled(task, robot)
        size = task.state_dim + task.desired_dim
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (task.action_dim,), np.float32)
        self._next_target = 0
        self._reference = None

    def _pick(self, seed_target: int | None):
        """One reference ``(steps + 1, ...)``: a drawn training reach or a test target."""
        if self.references == "test":
            k = self._next_target if seed_target is None else int(seed_target)
            if not 0 <= k < self.task.targets:
                config_lib.fail("target", k, f"0 to {self.task.targets - 1}")
            self._next_target = (k + 1) % self.task.targets
            return jax.tree.map(lambda x: x[k], self.task.reference)
        key = jax.random.key(int(self.np_random.integers(2**31)))
        return jax.tree.map(lambda x: x[0], self._fns.training(key))

    def _observation(self):
        ref_t = jax.tree.map(lambda x: x[self._t], self._reference)
        state, desired = self._fns.observe(ref_t, self._qpos, self._qvel, self._feat)
        return np.asarray(self._fns.normalise(state, desired))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode at the task's start state of a new reference.

        Args:
          seed: seeds the environment's generator; with ``references="test"`` the references
            start again at the first.
          options: ``{"target": k}`` with ``references="test"``: follow test reference ``k``
            (else the next in turn).

        Returns:
          ``(observation, info)``; ``info["target"]``: the test reference, None for a training one.
        """
        super().reset(seed=seed)
        if seed is not None:  # a seeded environment starts its test references again
            self._next_target = 0
        target = (options or {}).get("target")
        # As NumPy arrays: indexing them each step costs nothing (a JAX array's index is
        # a dispatched operation, 60% of a step's time).
        self._reference = jax.tree.map(np.asarray, self._pick(target))
        self._qpos, self._qvel, self._feat = self._fns.start(self._reference)
        self._t = 0
        shown = (self._next_target - 1) % self.task.targets
        info = {"target": shown if self.references == "test" else None}
        return self._observation(), info

    def step(self, action):
        """One control period with the torque ``action * tau_max`` held.

        Args:
          action: ``(action_dim,)`` in ``[-1, 1]`` (clipped).

        Returns:
          ``(observation, reward, terminated, truncated, info)``; ``info["tracking_error"]`` the
          task's error vector of the next state (float32), ``info["diverged"]``.
        """
        if self._reference is None:
            raise RuntimeError("TrackingEnv.step before reset")
        tau = np.clip(np.asarray(action, np.float32), -1.0, 1.0) * self._limit
        ctrl = self._fns.ctrl(tau)
        qpos, qvel, sensors = self._stepper(
            np.asarray(self._qpos, np.float32),
            np.asarray(self._qvel, np.float32),
            np.asarray(ctrl, np.float32),
        )
        diverged = not (rollout.good(qpos) and rollout.good(qvel))
        ref_next = jax.tree.map(lambda x: x[self._t + 1], self._reference)
        if diverged:
            qpos, qvel, features = self._qpos, self._qvel, self._feat
            error = np.asarray(self._fns.error(ref_next, qpos, qvel, features))
            observation = None
        else:
            features, error, observation = self._fns.after(ref_next, qpos, qvel, sensors)
            error = np.asarray(error)
        reward = -float(np.mean(np.square(error, dtype=np.float64)))
        self._qpos, self._qvel, self._feat = qpos, qvel, features
        self._t += 1
        truncated = self._t >= self.task.steps and not diverged
        info = {"tracking_error": error, "diverged": diverged}
        # After the last step the goal is the reference's last point (index steps).
        if observation is None:
            observation = self._observation()
        return np.asarray(observation), reward, diverged, truncated, info


class _Compiled(NamedTuple):
    """The task's own functions, compiled once per task: the same float32 operations as
    :func:`cfm_jax.rollout.run`, so the same actions give the same states and errors."""

    observe: Any
    normalise: Any
    after: Any
    ctrl: Any
    error: Any
    start: Any
    training: Any


@functools.lru_cache(maxsize=16)
def _compiled(task, robot) -> _Compiled:
    """:class:`_Compiled` of ``task`` on ``robot``, shared by environments of one task object."""
    normaliser = networks.Normaliser.from_scales(
        **scales.robot_scales(task),
        torque_limit=robot.torque_limit,
        desired_index=task.desired_index,
    )

    def observe(ref_t, q, qd, f):
        return task.state(q, qd, f), task.desired(ref_t, q, qd, f)

    def normalise(s, d):
        return jnp.concatenate([normaliser.state(s), normaliser.desired(d)])

    def after(ref_next, q, qd, sensors):
        """A step's features, tracking error and next observation, in one call."""
        f = task.features(q, qd, sensors)
        return f, task.tracking_error(ref_next, q, qd, f), normalise(*observe(ref_next, q, qd, f))

    return _Compiled(
        observe=jax.jit(observe),
        normalise=jax.jit(normalise),
        after=jax.jit(after),
        ctrl=jax.jit(robot.torque_to_ctrl),
        error=jax.jit(task.tracking_error),
        start=jax.jit(task.start),
        training=jax.jit(lambda key: task.babbling_reference("reaching", key)),
    )
