"""The kinds of forward model (``Config.forward.kind``), :class:`cfm_jax.learning.networks.Model`
each: ``mlp``, the PETS ensemble, and ``rigid_body`` (:mod:`cfm_jax.learning.rigid_body`). A new
kind is a ``make`` and a :func:`register` call (docs/concepts/method.md).
"""

from __future__ import annotations

from collections.abc import Callable

from cfm_jax import config as config_lib
from cfm_jax.config import ConfigError, ForwardModelConfig
from cfm_jax.learning import networks, rigid_body

REGISTRY: dict[str, Callable] = {}
"""Every registered kind by name: ``make(forward_config, robot, task) -> Model``."""

DESCRIBE: dict[str, Callable] = {}
"""Each kind's ``describe(options) -> str`` (:func:`register`), for :func:`describe`."""


def register(
    kind: str,
    make_model: Callable,
    options: type | None = None,
    describe_options: Callable | None = None,
) -> None:
    """Register a kind of forward model, so that ``forward.kind`` may name it.

    Args:
      kind: its name.
      make_model: ``make_model(forward_config, robot, task) -> cfm_jax.learning.networks.Model``.
      options: the kind's settings, a frozen dataclass that checks its fields
        (``forward.options``, :func:`cfm_jax.config.add_forward_kind`); None: none.
      describe_options: ``describe_options(options) -> str``, the options worth naming in
        a report (``""``: none); None: none are named.

    Raises:
      ValueError: ``kind`` is not a non-empty string, or is registered already.

    Examples:
      >>> register("mlp", lambda forward, robot, task: None)
      Traceback (most recent call last):
      ValueError: kind='mlp' is not allowed: a forward model of that name exists
    """
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"kind={kind!r} is not allowed: a non-empty string")
    if kind in REGISTRY:
        raise ValueError(f"kind={kind!r} is not allowed: a forward model of that name exists")
    config_lib.add_forward_kind(kind, options)
    REGISTRY[kind] = make_model
    if describe_options is not None:
        DESCRIBE[kind] = describe_options


def describe(forward: ForwardModelConfig) -> str:
    """How a summary names the forward model: its kind and the options it describes.

    Args:
      forward: the :class:`cfm_jax.config.ForwardModelConfig`.

    Examples:
      >>> from cfm_jax import config
      >>> describe(config.ForwardModelConfig(kind="rigid_body", options={"mass_scale": 1.2}))
      "`forward.kind='rigid_body'` (`forward.options.mass_scale=1.2`)"
    """
    text = f"`forward.kind={forward.kind!r}`"
    details = DESCRIBE[forward.kind](forward.options) if forward.kind in DESCRIBE else ""
    return f"{text} ({details})" if details else text


def make(forward: ForwardModelConfig, robot, task) -> networks.Model:
    """The forward model of ``forward.kind`` for a robot and task.

    Args:
      forward: the :class:`cfm_jax.config.ForwardModelConfig`.
      robot: the :class:`cfm_jax.sim.robots.Robot`.
      task: the task object (:func:`cfm_jax.tasks.make`).

    Raises:
      ConfigError: no kind of that name, or the kind does not fit the robot or task.

    Examples:
      >>> from cfm_jax import config, tasks
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> task = tasks.make(arm, config.TaskConfig(duration=0.1), control_dt=0.01)
      >>> make(config.ForwardModelConfig(hidden=(8,)), arm, task).terms is None
      True
    """
    if forward.kind not in REGISTRY:
        raise ConfigError(f"forward.kind={forward.kind!r} is not allowed: one of {tuple(REGISTRY)}")
    return REGISTRY[forward.kind](forward, robot, task)


def _mlp(forward: ForwardModelConfig, robot, task) -> networks.Model:
    """The ``mlp`` kind: the PETS ensemble over the task's output."""
    del robot
    return networks.ensemble(forward, task.output_dim, task.action_dim)


register("mlp", _mlp)
register("rigid_body", rigid_body.make, rigid_body.RigidBodyOptions, rigid_body.describe)
