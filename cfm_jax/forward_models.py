"""The kinds of forward model (``Config.forward.kind``) and a registry of them.

Every kind is a :class:`cfm_jax.networks.Model` built by ``make(forward_config, robot,
task)`` and registered here under its name:

* ``mlp`` (default): the PETS ensemble of the paper's text,
  :func:`cfm_jax.networks.forward_model`;
* ``rigid_body``: ``M^-1 (S tau - h)`` of a nominal MuJoCo model plus the ensemble as a
  residual, as in the authors' Solo12 code (:mod:`cfm_jax.rigid_body`).

A kind owns its contract with the learning loop (the fields of
:class:`cfm_jax.networks.Model`: ``init``, ``objective``, ``predict``, ``batches``,
``start``; :func:`cfm_jax.networks.pets` gives the ensemble's); the shared update and
algorithm code call them and know none of its parameters. A kind that needs more than
``(s, tau)`` per transition gives the model a ``terms(state)`` function: the learning loop
stores its output with each transition when it enters the data set and passes it on as
``terms=`` (:attr:`cfm_jax.dataset.Transitions.terms`). A new kind is one module with a
``make`` and one call of :func:`register`, in the library or outside it
(``tests/test_forward_kinds.py``).

Examples:
  >>> from cfm_jax import config
  >>> sorted(REGISTRY) == sorted(config.FORWARD_KINDS)
  True
"""

from __future__ import annotations

from collections.abc import Callable

from cfm_jax import config as config_lib
from cfm_jax import networks, rigid_body
from cfm_jax.config import ConfigError, ForwardModelConfig

REGISTRY: dict[str, Callable] = {}
"""Every registered kind by name: ``make(forward_config, robot, task) -> Model``."""


def register(kind: str, make_model: Callable) -> None:
    """Register a kind of forward model, so that ``forward.kind`` may name it.

    Args:
      kind: its name.
      make_model: ``make_model(forward_config, robot, task) -> cfm_jax.networks.Model``.

    Raises:
      ValueError: ``kind`` is not a non-empty string, or is registered already.

    Examples:
      >>> # not run: it would add "my_kind" to the registry for the rest of the session
      >>> register("my_kind", lambda forward, robot, task: None)  # doctest: +SKIP
    """
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"kind={kind!r} is not allowed: a non-empty string")
    if kind in REGISTRY:
        raise ValueError(f"kind={kind!r} is not allowed: a forward model of that name exists")
    config_lib.add_forward_kind(kind)
    REGISTRY[kind] = make_model


def make(forward: ForwardModelConfig, robot, task) -> networks.Model:
    """The forward model of ``forward.kind`` for a robot and task.

    Args:
      forward: the :class:`cfm_jax.config.ForwardModelConfig`.
      robot: the :class:`cfm_jax.robots.Robot`.
      task: the task object (:func:`cfm_jax.tasks.make`).

    Returns:
      A :class:`cfm_jax.networks.Model`.

    Raises:
      ConfigError: no kind of that name, or the kind does not fit the robot or task.

    Examples:
      >>> from cfm_jax import config, robots, tasks
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
register("rigid_body", rigid_body.make)
