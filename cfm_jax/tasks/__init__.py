"""The tasks and their registry: ``inverse_dynamics`` (:class:`JointSpaceTask`, which gives
every task's interface), ``opspace`` (:class:`OperationalSpaceTask`), ``walk`` and ``jump``
(:class:`LeggedTask`). A new task is a module with a ``make`` and a :func:`register` call.

With them what a task is built from: the motions to track (:mod:`.references`, the walk and
jump in :mod:`.locomotion`), the non-learned controllers compared against
(:mod:`.baselines`), the initial data (motor babbling, :mod:`.babbling`) and the torque
scales (:mod:`.scales`). Above :mod:`cfm_jax.sim`, below :mod:`cfm_jax.learning`.
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
      make: ``make(robot, task_config, control_dt, simulator) -> task``.
      default_config: ``default_config() -> Config``, the task's defaults.
      fits: ``fits(robot) -> note``, whether the task can run on a robot (``cfm-jax robot
        check``): raises :class:`cfm_jax.config.ConfigError` saying why not, else returns a
        note for the report ("" or, for example, the site it takes); None: not checked.

    Examples:
      >>> load("walk").default_config().robot
      'solo12'
    """

    name: str
    make: Callable[[Any, TaskConfig, float], Any]
    default_config: Callable[[], config_lib.Config]
    fits: Callable[[Any], str] | None = None


REGISTRY: dict[str, TaskSpec] = {}
"""Every registered task by name (:func:`register`)."""


def register(
    name: str,
    make: Callable,
    default_config: Callable | None = None,
    check: Callable | None = None,
    structural: tuple[str, ...] = (),
    fits: Callable | None = None,
) -> TaskSpec:
    """Register a task under ``name``, so that configs may name it.

    Args:
      name: the task's name, for ``Config.task.name``.
      make: ``make(robot, task_config, control_dt, simulator) -> task``.
      default_config: ``default_config() -> Config``, stating only what differs from the
        generic values (:func:`cfm_jax.config.add_task_name`); None: the generic values.
      check: ``check(task_config)``, raising :class:`cfm_jax.config.ConfigError` for what
        the task refuses; None: nothing more than the fields' own checks.
      structural: the runtime ``task.*`` fields the task builds into its compiled program
        (:func:`cfm_jax.config.structure`).
      fits: ``fits(robot) -> note`` (:class:`TaskSpec`), for ``cfm-jax robot check``; None:
        the check reports the task as not checked.

    Raises:
      ValueError: ``name`` is not a non-empty string, or is registered already.

    Examples:
      >>> register("opspace", operational_space.make)
      Traceback (most recent call last):
      ValueError: name='opspace' is not allowed: a task of that name is registered
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name={name!r} is not allowed: a non-empty string")
    if name in REGISTRY:
        raise ValueError(f"name={name!r} is not allowed: a task of that name is registered")
    config_lib.add_task_name(name, default_config, check, structural)
    if default_config is None:

        def default_config():
            return config_lib.Config(task=TaskConfig(name=name))

    REGISTRY[name] = TaskSpec(name, make, default_config, fits)
    return REGISTRY[name]


def load(name: str) -> TaskSpec:
    """The :class:`TaskSpec` registered as ``name``.

    Args:
      name: a name of :data:`REGISTRY`.

    Raises:
      ConfigError: no task of that name (the message lists them).

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
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`; its ``name`` chooses the task.
      control_dt: control period (s), a multiple of the robot's timestep.
      simulator: ``"native"`` or ``"mjx"`` (with ``mjx`` the rollout has no host callback).

    Raises:
      ConfigError: no such task, or it does not fit the robot (the message says why).

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> task = make(arm, TaskConfig(duration=1.0), control_dt=0.01)
      >>> type(task).__name__, task.targets, task.steps
      ('JointSpaceTask', 5, 100)
    """
    return load(task.name).make(robot, task, control_dt, simulator)


register(
    "inverse_dynamics",
    inverse_dynamics.make,
    inverse_dynamics.default_config,
    inverse_dynamics.check_config,
    fits=inverse_dynamics.fits,
)
register(
    "opspace",
    operational_space.make,
    operational_space.default_config,
    inverse_dynamics.check_config,
    structural=("home",),  # the Khatib oracle's null-space posture, in its host callback
    fits=operational_space.fits,
)
for _name in ("walk", "jump"):
    register(
        _name,
        legged.make,
        functools.partial(legged.default_config, _name),
        fits=functools.partial(legged.fits, name=_name),
    )
