"""The library's arm tracking tasks as Gymnasium environments, for SAC and PPO (docs/peers.md).

:class:`TrackingEnv` wraps the library's own task object (:func:`cfm_jax.tasks.make`): the
same robot, references, control period, torque limits, start state, MuJoCo C physics
(:class:`cfm_jax.sim.native.Stepper`) and tracking error as the ``native`` simulator. An episode
is one reference. The observation is the controller's input ``(s_t, s*_t)`` scaled by the
robot's own scales (:func:`cfm_jax.tasks.scales.robot_scales`), float32. The action ``a`` in
``[-1, 1]`` becomes a torque by one of :data:`ACTIONS`:

* ``limit``: ``a * tau_max``;
* ``scale``: the controller's own squashing
  (:meth:`cfm_jax.learning.networks.Normaliser.torque_output`, the torque scale of
  ``config.loop.torque_scale``; ``pose``: at home) of ``u = reach * a``, where every joint
  gets to ``tanh(1)`` (76%) of its limit (:func:`action_reach`);
* ``residual``: the task's PD feedback torque (the PD-only baseline's,
  :meth:`cfm_jax.tasks.JointSpaceTask.feedback`) plus ``residual_scale`` times the ``scale``
  torque of ``a``, clipped to the limits as :func:`cfm_jax.sim.rollout.run` clips: ``a = 0`` is
  PD-only. Residual-RL practice scales the residual down (a small ``residual_scale``) so that
  early exploration perturbs the feedback instead of overriding it.

The reward is minus the next state's squared tracking error times ``reward_scale`` (with 1,
an episode's mean ``-reward`` is :func:`cfm_jax.sim.rollout.tracking_mse`). Episodes end after
the reference's steps, or when the simulation diverges (``info["diverged"]``).

``render_mode="rgb_array"`` makes :meth:`TrackingEnv.render` return the current frame
(MuJoCo's offscreen renderer, :mod:`cfm_jax.sim.render`; needs OpenGL). The environments are
registered with Gymnasium under :data:`IDS` when this module is imported:
``gymnasium.make("cfm_jax.envs:cfm_jax/Tracking-v0")`` imports it and builds the quickstart
task (the iiwa14's joint-space reaches); keyword arguments reach :func:`make`.

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
from cfm_jax.learning import networks
from cfm_jax.sim import native, rollout
from cfm_jax.tasks import scales

REFERENCES = ("training", "test")
"""Values of :class:`TrackingEnv`'s ``references``."""
ACTIONS = ("limit", "scale", "residual")
"""Values of :class:`TrackingEnv`'s ``action`` (see the module)."""
RENDER_WIDTH, RENDER_HEIGHT = 320, 240
"""The size of :meth:`TrackingEnv.render`'s frames (at most the model's offscreen size)."""
REACH = 1.0
"""``u = REACH x limit_j / T_jj`` drives joint ``j`` alone to ``tanh(REACH)`` of its limit. One,
not more: the torques a task needs are a small part of the limits (PD-only's on the iiwa14's
reaches: ``|u| <= 0.31``), and a larger reach squeezes them into a smaller part of the
action box, where the peers' exploration (a unit Gaussian in SB3) is too coarse."""


def action_reach(torque_limit, torque_scale) -> float:
    """The controller output ``u`` of the action ``a = 1`` (``scale``/``residual`` actions):
    ``REACH x max_j limit_j / T_jj``, so that every joint can get to ``tanh(REACH)`` (76%) of
    its limit through :meth:`cfm_jax.learning.networks.Normaliser.torque_output` while a unit action
    still means alike accelerations on every joint.

    Args:
      torque_limit: ``(n,)`` each joint's torque limit.
      torque_scale: ``(n,)`` or ``(n, n)`` torque scale ``T``
        (:func:`cfm_jax.learning.algorithm.torque_scale`), or None (the limits: ``REACH``).

    Returns:
      The factor ``reach`` of ``u = reach x a`` (float).

    Examples:
      >>> action_reach(np.array([10.0, 4.0]), np.array([5.0, 4.0]))
      2.0
    """
    limit = np.asarray(torque_limit, np.float64)
    if torque_scale is None:
        return REACH
    scale = np.asarray(torque_scale, np.float64)
    diagonal = np.diag(scale) if scale.ndim == 2 else scale
    return float(REACH * np.max(limit / diagonal))


class TrackingEnv(gymnasium.Env):
    """An arm tracking task of the library as a Gymnasium environment (see the module).

    Args:
      config: a :class:`cfm_jax.config.Config` (its robot, task and servo conversion; the
        learner's fields are not used). ``simulator`` must be ``native``.
      references: one of :data:`REFERENCES`: ``training``, reaches drawn as the ``reaching``
        babbling draws them (:mod:`cfm_jax.tasks.babbling`), from the environment's seed, blind to
        the test references; or ``test``, the task's test references in turn (evaluation).
      experiment: an :class:`cfm_jax.learning.algorithm.Experiment` of ``config`` to take the robot
        and task from (saves building them again), or None.
      action: one of :data:`ACTIONS` (see the module): ``limit``, ``scale`` or ``residual``.
      reward_scale: a positive factor of the reward (the peers: ``1 / PD-only's MSE``, so that
        PD-only's reward is about -1 a step).
      residual_scale: the factor of the policy's torque on top of the PD feedback
        (``residual`` only; 1 for the other actions).
      render_mode: None, or ``"rgb_array"``: :meth:`render` returns the current frame,
        ``(RENDER_HEIGHT, RENDER_WIDTH, 3)`` uint8.

    Attributes:
      task: the library's task object.
      robot: its :class:`cfm_jax.sim.robots.Robot`.
      control_dt: the control period (s); an episode is ``task.steps`` of them.

    Raises:
      ConfigError: a legged task, the ``mjx`` simulator, an unknown ``references`` or
        ``action``, a ``reward_scale`` or ``residual_scale`` that is not a positive number, or
        a ``residual_scale`` other than 1 without the ``residual`` action.

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

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}
    """Gymnasium's metadata: the render modes, and render_fps of the default control period
    (0.01 s); each environment holds its own copy with ``1 / control_dt``."""

    def __init__(
        self,
        config: config_lib.Config,
        references: str = "training",
        experiment=None,
        action: str = "limit",
        reward_scale: float = 1.0,
        residual_scale: float = 1.0,
        render_mode: str | None = None,
    ):
        from cfm_jax.learning import algorithm
        from cfm_jax.learning.algorithm import Experiment

        if references not in REFERENCES:
            config_lib.fail("references", references, f"one of {REFERENCES}")
        if action not in ACTIONS:
            config_lib.fail("action", action, f"one of {ACTIONS}")
        if not (isinstance(reward_scale, (int, float)) and 0 < reward_scale < np.inf):
            config_lib.fail("reward_scale", reward_scale, "a finite number > 0")
        if not (isinstance(residual_scale, (int, float)) and 0 < residual_scale < np.inf):
            config_lib.fail("residual_scale", residual_scale, "a finite number > 0")
        if action != "residual" and residual_scale != 1.0:
            config_lib.fail("residual_scale", residual_scale, "1 unless action='residual'")
        if render_mode not in (None, *self.metadata["render_modes"]):
            config_lib.fail("render_mode", render_mode, "None or 'rgb_array'")
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
        experiment = experiment or Experiment.shared(config)
        self.task, self.robot = experiment.task, experiment.robot
        self.control_dt = self.task.control_dt
        self.references = references
        task, robot = self.task, self.robot
        self._stepper = native.Stepper(robot.mj_model, rollout.substeps(robot, self.control_dt))
        self._limit = np.asarray(robot.torque_limit, np.float32)
        self._fns = _compiled(task, robot)
        self.action = action
        self.reward_scale = float(reward_scale)
        self.residual_scale = float(residual_scale)
        self.torque_scale = algorithm.torque_scale(config, robot)
        self.reach = action_reach(robot.torque_limit, self.torque_scale)
        if action != "limit":
            self._torque = _action_torque(
                task, robot, self.torque_scale, self.reach, action, self.residual_scale
            )
        size = task.state_dim + task.desired_dim
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (task.action_dim,), np.float32)
        self._next_target = 0
        self._reference = None
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.control_dt)}
        self._renderer = None

    def render(self):
        """The current state as an RGB frame ``(RENDER_HEIGHT, RENDER_WIDTH, 3)`` uint8
        (``render_mode="rgb_array"``; the free camera of :func:`cfm_jax.sim.render.render_frames`),
        or None without a render mode.

        Raises:
          RuntimeError: before :meth:`reset`.
          cfm_jax.sim.render.RenderUnavailable: no offscreen OpenGL context can be made.
        """
        if self.render_mode is None:
            return None
        if self._reference is None:
            raise RuntimeError("TrackingEnv.render before reset")
        from cfm_jax.sim import render

        if self._renderer is None:
            self._renderer = render.FrameRenderer(
                self.robot.mj_model, width=RENDER_WIDTH, height=RENDER_HEIGHT
            )
        return self._renderer.frame(np.asarray(self._qpos), np.asarray(self._qvel))

    def close(self):
        """Release the renderer, if one was made."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()

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
        """One control period with the torque of ``action`` (see the module) held.

        Args:
          action: ``(action_dim,)`` in ``[-1, 1]`` (clipped).

        Returns:
          ``(observation, reward, terminated, truncated, info)``; ``info["tracking_error"]`` the
          task's error vector of the next state (float32), ``info["diverged"]``.
        """
        if self._reference is None:
            raise RuntimeError("TrackingEnv.step before reset")
        action = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        if self.action == "limit":
            ctrl = self._fns.ctrl(action * self._limit)
        else:
            ref_t = jax.tree.map(lambda x: x[self._t], self._reference)
            ctrl = self._torque.ctrl(action, ref_t, self._qpos, self._qvel, self._feat)
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
        reward = -self.reward_scale * float(np.mean(np.square(error, dtype=np.float64)))
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
    :func:`cfm_jax.sim.rollout.run`, so the same actions give the same states and errors."""

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


class _ActionTorque(NamedTuple):
    """``torque(a, ref_t, q, qd, f)``: the torque of a ``scale``/``residual`` action (clipped to
    the limits); ``ctrl``: the same as the actuators' controls."""

    torque: Any
    ctrl: Any


def _action_torque(
    task, robot, torque_scale, reach: float, action: str, residual_scale: float = 1.0
) -> _ActionTorque:
    """The compiled torque of ``action`` (``scale`` or ``residual``): the controller's squashing
    of the library (:meth:`cfm_jax.learning.networks.Normaliser.torque_output`) with
    ``torque_scale``; for ``residual``, ``residual_scale`` times it plus the task's PD feedback."""
    from cfm_jax.sim import rollout as rollout_lib

    normaliser = networks.Normaliser.identity(
        task.state_dim,
        task.output_dim,
        robot.torque_limit,
        task.desired_index,
        torque_scale=torque_scale,
    )
    limit = jnp.asarray(robot.torque_limit, jnp.float32)

    def torque(a, ref_t, q, qd, f):
        tau = normaliser.torque_output(jnp.float32(reach) * a)
        if action == "residual":
            step = rollout_lib.Step(
                t=jnp.int32(0),
                qpos=q,
                qvel=qd,
                features=f,
                state=task.state(q, qd, f),
                desired=task.desired(ref_t, q, qd, f),
                reference=ref_t,
            )
            tau = jnp.float32(residual_scale) * tau + task.feedback(step)
        return jnp.clip(tau, -limit, limit)

    return _ActionTorque(
        torque=jax.jit(torque), ctrl=jax.jit(lambda *a: robot.torque_to_ctrl(torque(*a)))
    )


def make(task: str = "inverse_dynamics", robot: str | None = None, **kwargs) -> TrackingEnv:
    """A :class:`TrackingEnv` of ``task``'s defaults (:func:`cfm_jax.config.for_task`), on
    ``robot`` if given: what the registered ids (:data:`IDS`) build.

    Args:
      task: an arm task, ``inverse_dynamics`` or ``opspace``.
      robot: a registered robot name or an MJCF path; None: the task's robot.
      kwargs: :class:`TrackingEnv`'s other arguments (``config`` replaces the defaults).

    Examples:
      >>> env = make(robot="two_link_arm")
      >>> env.task.action_dim
      2
    """
    config = kwargs.pop("config", None) or config_lib.for_task(task)
    if robot is not None:
        config = config.replace(robot=robot)
    return TrackingEnv(config, **kwargs)


IDS = {
    "cfm_jax/Tracking-v0": {"task": "inverse_dynamics"},
    "cfm_jax/OpSpaceTracking-v0": {"task": "opspace"},
}
"""Gymnasium ids registered at import, each :func:`make` with these arguments."""

for _id, _kwargs in IDS.items():
    if _id not in gymnasium.envs.registry:
        gymnasium.register(_id, entry_point="cfm_jax.envs:make", kwargs=_kwargs)
