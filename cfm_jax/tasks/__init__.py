"""The tasks: what the learning problem is, one module per task, and a registry.

A *task* object tells :func:`cfm_jax.rollout.run` and :mod:`cfm_jax.training` what to
track and what the controller is given (its interface is documented on
:class:`JointSpaceTask`). Each task lives in its own module and is registered here under
the names ``Config.task.name`` takes:

* ``inverse_dynamics``: :class:`JointSpaceTask` (:mod:`cfm_jax.tasks.inverse_dynamics`),
* ``opspace``: :class:`OperationalSpaceTask` (:mod:`cfm_jax.tasks.operational_space`),
* ``walk`` and ``jump``: :class:`LeggedTask` (:mod:`cfm_jax.tasks.legged`).

The references they follow are in :mod:`cfm_jax.references` (joint-space and Cartesian
reaching, the legged recordings padded) and :mod:`cfm_jax.locomotion` (the Solo12
recordings); the arms' oracles and PD baselines in :mod:`cfm_jax.baselines`.

A new task is one new module with a ``make(robot, task_config, control_dt, simulator)``
and one call of :func:`register`; :func:`make` then builds it for any config that names
it.

Examples:
  >>> from cfm_jax import config, robots, tasks
  >>> sorted(tasks.REGISTRY) == sorted(config.TASKS)
  True
  >>> tasks.load("walk").default_config().robot
  'solo12'
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

from cfm_jax import config as config_lib
from cfm_jax.config import ConfigError, TaskConfig
from cfm_jax.tasks import inverse_dynamics, legged, operational_space
from cfm_jax.tasks.inverse_dynamics import JointSpaceTask
from cfm_jax.tasks.legged import LeggedTask
from cfm_jax.tasks.operational_space import OperationalSpaceTask

__all__ = [
    "REGISTRY",
    "JointSpaceTask",
    "LeggedTask",
    "OperationalSpaceTask",
    "TaskSpec",
    "load",
    "make",
    "register",
]


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """A registered task.

    Attributes:
      name: the name ``Config.task.name`` takes.
      make: ``make(robot, task_config, control_dt, simulator) -> task``; raises
        :class:`cfm_jax.config.ConfigError` when the task does not fit the robot.
      default_config: ``default_config() -> Config``, the task's defaults (with
        ``task.name`` set to ``name``).

    Examples:
      >>> spec = load("inverse_dynamics")
      >>> spec.name, spec.default_config().task.name
      ('inverse_dynamics', 'inverse_dynamics')
    """

    name: str
    make: Callable[[Any, TaskConfig, float], Any]
    default_config: Callable[[], config_lib.Config]


REGISTRY: dict[str, TaskSpec] = {}
"""Every registered task by name (:func:`register`)."""


def register(
    name: str,
    make: Callable,
    default_config: Callable | None = None,
    check: Callable | None = None,
    structural: tuple[str, ...] = (),
) -> TaskSpec:
    """Register a task under ``name``, so that configs may name it.

    Args:
      name: the task's name; it also becomes a name ``Config.task.name`` accepts.
      make: ``make(robot, task_config, control_dt, simulator) -> task``.
      default_config: ``default_config() -> Config``, the task's defaults: every field a
        config of this task leaves at :data:`cfm_jax.config.TASK_DEFAULT` takes its value
        (:func:`cfm_jax.config.add_task_name`); inside it such fields take the generic
        values (:data:`cfm_jax.config.GENERIC`), so it states only what differs. None: the
        generic values.
      check: ``check(task_config)``, what the task refuses of a
        :class:`cfm_jax.config.TaskConfig` of its name (raises
        :class:`cfm_jax.config.ConfigError`), run when such a config is made; None:
        nothing more than the fields' own checks.
      structural: the runtime ``task.*`` fields (:data:`cfm_jax.config.RUNTIME_FIELDS`)
        whose values the task builds into its compiled program; configs that differ in them
        do not share one (:func:`cfm_jax.config.structure`).

    Returns:
      The :class:`TaskSpec`.

    Raises:
      ValueError: ``name`` is not a non-empty string, or is registered already.

    Examples:
      >>> # not run: it would add "my_task" to the registry for the rest of the session
      >>> spec = register("my_task", lambda robot, task, dt, sim: None)  # doctest: +SKIP
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name={name!r} is not allowed: a non-empty string")
    if name in REGISTRY:
        raise ValueError(f"name={name!r} is not allowed: a task of that name is registered")
    config_lib.add_task_name(name, default_config, check, structural)
    if default_config is None:

        def default_config():
            return config_lib.Config(task=TaskConfig(name=name))

    REGISTRY[name] = TaskSpec(name, make, default_config)
    return REGISTRY[name]


def load(name: str) -> TaskSpec:
    """The registered task ``name``.

    Args:
      name: a name of :data:`REGISTRY`.

    Returns:
      Its :class:`TaskSpec`.

    Raises:
      ConfigError: no task of that name is registered (the message lists them).

    Examples:
      >>> load("opspace").default_config().task.name
      'opspace'
    """
    if name not in REGISTRY:
        raise ConfigError(f"task.name={name!r} is not allowed: one of {tuple(REGISTRY)}")
    return REGISTRY[name]


def make(robot, task: TaskConfig, control_dt: float, simulator: str = "native"):
    """The task object of a :class:`cfm_jax.config.TaskConfig` for a robot.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`; its ``name`` chooses the registered
        task: :class:`JointSpaceTask` (``inverse_dynamics``), :class:`OperationalSpaceTask`
        (``opspace``) or :class:`LeggedTask` (``walk``, ``jump``).
      control_dt: control period (s), a multiple of the robot's timestep.
      simulator: ``Config.simulator``: ``"native"`` or ``"mjx"`` (with ``mjx`` every part of
        the task that runs inside a rollout is JAX, no host callback).

    Returns:
      The task object.

    Raises:
      ConfigError: the task does not fit the robot (the message says why), or no task of
        that name is registered.

    Examples:
      >>> from cfm_jax import config, robots
      >>> arm = robots.load("two_link_arm")
      >>> task = make(arm, config.TaskConfig(duration=1.0), control_dt=0.01)
      >>> type(task).__name__, task.targets, task.steps
      ('JointSpaceTask', 5, 100)
    """
    return load(task.name).make(robot, task, control_dt, simulator)


register(
    "inverse_dynamics",
    inverse_dynamics.make,
    inverse_dynamics.default_config,
    inverse_dynamics.check_config,
)
register(
    "opspace",
    operational_space.make,
    operational_space.default_config,
    inverse_dynamics.check_config,
    structural=("home",),  # the Khatib oracle's null-space posture, in its host callback
)
register("walk", legged.make, functools.partial(legged.default_config, "walk"))
register("jump", legged.make, functools.partial(legged.default_config, "jump"))
