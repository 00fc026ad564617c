"""Forward-model and controller losses (paper section III), small pure functions of arrays.

Per-sample losses take ``(..., d)`` arrays and sum over the last axis, shape ``(...)``.
Notation: ``s_p = f(s, g(s, s_d))`` predicted, ``s_d`` desired, ``s_a`` observed next state,
``p' = df/dg dg/dbeta``. Gradients, rest points and the ``squared`` and ``norm`` forms
(``controller.loss_form``): docs/concepts/losses.md.

Every controller loss is a registered function (:func:`register`, :data:`REGISTRY`): the
library's five are registered at the bottom of this module the way a user registers their
own, and ``Config.loss``, the CLI, sweeps and resume accept any registered name.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax.numpy as jnp

from cfm_jax import config as config_lib
from cfm_jax.config import PAPER_LOSSES, ConfigError  # noqa: F401  (re-exported)


def task(predicted_next, desired_next):
    """Task loss ``|s_p - s_d|^2`` (paper eq. 2); at rest where the model predicts ``s_d``.

    Args:
      predicted_next: ``s_p``, shape ``(..., d)``.
      desired_next: ``s_d``, shape ``(..., d)``.

    Examples:
      >>> float(task(jnp.array([1.0]), jnp.array([3.0])))
      4.0
    """
    return jnp.sum(jnp.square(predicted_next - desired_next), axis=-1)


def joint(predicted_next, desired_next, observed_next):
    """Joint loss ``|s_p - s_d|^2 + |s_p - s_a|^2`` (paper eq. 4); at rest at ``(s_d + s_a) / 2``.

    Args:
      predicted_next: ``s_p``, shape ``(..., d)``.
      desired_next: ``s_d``, shape ``(..., d)``.
      observed_next: ``s_a``, shape ``(..., d)``.

    Examples:
      >>> float(joint(jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      5.0
    """
    return task(predicted_next, desired_next) + task(predicted_next, observed_next)


def distal(predicted_next, predicted_run, desired_next, observed_next):
    """Bounded distal-teacher loss ``|s_p - s_p,run + s_a - s_d|^2`` (Jordan & Rumelhart 1992).

    At ``g = tau_run`` its gradient is the distal teacher's ``2 p' (s_a - s_d)`` (paper III-D);
    unlike :func:`distal_literal` it is bounded below.

    Args:
      predicted_next: ``s_p``, shape ``(..., d)``.
      predicted_run: ``s_p,run = f(s, tau_run)``, shape ``(..., d)``; no controller parameter.
      desired_next: ``s_d``, shape ``(..., d)``.
      observed_next: ``s_a``, shape ``(..., d)``.

    Examples:
      >>> float(distal(jnp.array([1.0]), jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      9.0
    """
    return task(predicted_next - predicted_run + observed_next, desired_next)


def distal_literal(predicted_next, desired_next, observed_next):
    """The distal teacher written literally, ``|s_p - s_d|^2 - |s_p - s_a|^2`` (for studies).

    Its gradient is ``2 p' (s_a - s_d)`` at any ``g``: linear in ``s_p``, it has no rest point for a
    held ``s_a`` and is unbounded below, so long training on earlier outcomes diverges.

    Args:
      predicted_next: ``s_p``, shape ``(..., d)``.
      desired_next: ``s_d``, shape ``(..., d)``.
      observed_next: ``s_a``, shape ``(..., d)``.

    Examples:
      >>> float(distal_literal(jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      3.0
    """
    return task(predicted_next, desired_next) - task(predicted_next, observed_next)


def supervised(predicted_action, executed_action):
    """Supervised inverse loss ``|g(s, s_a) - tau_run|^2`` (paper eq. 3); no forward model.

    Args:
      predicted_action: ``g(s, s_a)``, shape ``(..., m)``.
      executed_action: ``tau_run``, shape ``(..., m)``.

    Examples:
      >>> float(supervised(jnp.array([1.0, 0.0]), jnp.array([0.0, 2.0])))
      5.0
    """
    return jnp.sum(jnp.square(predicted_action - executed_action), axis=-1)


def controller_loss(
    name,
    predicted_next,
    desired_next,
    observed_next,
    select=None,
    predicted_run=None,
    groups=None,
    desired_index=None,
):
    """A model-based controller loss by name, comparing the selection ``P`` of ``s_p`` with ``s_d``.

    With ``P`` the selection: ``task = |P s_p - s_d|^2``, ``joint`` adds the whole prediction error
    ``|s_p - s_a|^2``, ``distal`` and ``distal_literal`` use the error signal ``P s_a - s_d``.

    Args:
      name: ``"task"``, ``"joint"``, ``"distal"`` or ``"distal_literal"``.
      predicted_next: ``s_p``, everything the forward model predicts, shape ``(..., d_out)``.
      desired_next: ``s_d``, shape ``(..., d)``.
      observed_next: ``s_a``, shape ``(..., d_out)``.
      select: ``P``, picks the ``d`` entries ``s_d`` specifies from ``(..., d_out)`` (None: all).
      predicted_run: ``s_p,run = f(s, tau_run)``, shape ``(..., d_out)``; ``distal`` only.
      groups: None (``squared``) or the ``norm`` form's ``((weight, (output index, ...)), ...)``:
        distances become :func:`grouped` norms (in ``s_d``'s entries by :func:`desired_groups`).
      desired_index: the output entries ``select`` picks (None: all); used with ``groups``.

    Raises:
      ValueError: an unknown ``name`` (or ``supervised``), or ``distal`` without
        ``predicted_run``.

    Examples:
      >>> p, d, o = jnp.array([1.0, 2.0]), jnp.array([3.0]), jnp.array([0.0, 2.0])
      >>> float(controller_loss("joint", p, d, o, select=lambda y: y[..., :1]))
      5.0
    """
    loss = get(name)
    if not loss.forward:
        raise ValueError(
            f"loss={loss.name!r} is not a model-based controller loss: it compares actions "
            "(algorithm.controller_objective computes it); model-based: "
            f"{tuple(n for n, entry in REGISTRY.items() if entry.forward)}"
        )
    if loss.run and predicted_run is None:
        raise ValueError(f"loss={loss.name!r} needs predicted_run = f(s, tau_run)")
    if select is None:
        select = lambda y: y  # noqa: E731
    if groups is None:  # squared: every distance a sum of squares
        d_desired = d_output = task
    else:  # norm: weighted sums of per-group Euclidean norms
        in_desired = desired_groups(groups, desired_index)

        def d_desired(x, y):
            return grouped(x - y, in_desired)

        def d_output(x, y):
            return grouped(x - y, groups)

    quantities = Quantities(
        predicted=select(predicted_next),
        predicted_next=predicted_next,
        desired=desired_next,
        observed_next=observed_next,
        observed=select(observed_next),
        run=None if predicted_run is None else select(predicted_run),
    )
    return loss.fn(quantities, d_desired, d_output)


class Quantities(NamedTuple):
    """What a model-based loss receives (:func:`register`), in normalised units, each with the
    minibatch's leading axes.

    Attributes:
      predicted: ``P s_p``, the prediction's entries that ``s*`` specifies.
      predicted_next: ``s_p``, everything the forward model predicts.
      desired: ``s_d`` (``s*``).
      observed_next: ``s_a``, the observed next state (the model's output coordinates).
      observed: ``P s_a``.
      run: ``P s_p,run = P f(s, tau_run)`` for a loss registered with ``run=True``; None else.

    Examples:
      >>> x = jnp.array([[1.0, 2.0]])
      >>> q = Quantities(x[:, :1], x, jnp.array([[3.0]]), x, x[:, :1], None)
      >>> float(REGISTRY["task"].fn(q, task, task)[0])  # |P s_p - s_d|^2
      4.0
    """

    predicted: Any
    predicted_next: Any
    desired: Any
    observed_next: Any
    observed: Any
    run: Any


def _task(q, d_desired, d_output):
    del d_output
    return d_desired(q.predicted, q.desired)


def _joint(q, d_desired, d_output):
    return d_desired(q.predicted, q.desired) + d_output(q.predicted_next, q.observed_next)


def _distal(q, d_desired, d_output):
    del d_output
    return d_desired(q.predicted - q.run + q.observed, q.desired)


def _distal_literal(q, d_desired, d_output):
    del d_output
    return d_desired(q.predicted, q.desired) - d_desired(q.predicted, q.observed)


def _supervised(predicted_action, executed_action, distance):
    return distance(predicted_action, executed_action)


class Loss(NamedTuple):
    """A registered controller loss (:func:`register`).

    Attributes:
      name: its name (``Config.loss``).
      fn: the per-sample loss: with ``forward``, ``fn(q, d_desired, d_output)``, ``q`` the
        :class:`Quantities`; without, ``fn(predicted_action, executed_action, d_action)``.
      forward: whether it goes through the forward model (``s_p = f(s, g(s, s*))``); if not,
        it compares the controller's action ``g(s, P s_a)`` with the executed ``tau_run``.
      run: whether it needs ``P f(s, tau_run)`` (``q.run``).

    Examples:
      >>> REGISTRY["distal"].forward, REGISTRY["distal"].run
      (True, True)
    """

    name: str
    fn: Callable
    forward: bool = True
    run: bool = False


REGISTRY: dict[str, Loss] = {}
"""Every controller loss by name (:func:`register`): the library's five, then the user's."""


def register(name: str, fn: Callable, *, forward: bool = True, run: bool = False) -> Loss:
    """Register a controller loss, so that ``Config.loss``, ``cfm_jax.train(config,
    losses=...)``, ``cfm-jax train --loss``, sweeps and resume accept ``name``.

    The contract. ``fn`` returns the per-sample loss (the minibatch's leading shape; the
    update takes its mean and differentiates it in the controller's parameters only):

    * ``forward=True`` (model-based, like ``task``, ``joint``, ``distal``):
      ``fn(q, d_desired, d_output)``. ``q`` is a :class:`Quantities` (``P s_p``, ``s_p``,
      ``s_d``, ``s_a``, ``P s_a`` and, with ``run=True``, ``P f(s, tau_run)``);
      ``d_desired(x, y)`` and ``d_output(x, y)`` are the distances of the config's
      ``controller.loss_form`` in ``s*``'s entries and in the forward model's output
      (sums of squares for ``squared``, weighted group norms for ``norm``). Write the loss
      with them and it follows the form.
    * ``forward=False`` (like ``supervised``: no forward model in the controller's loss):
      ``fn(predicted_action, executed_action, d_action)``, the controller's action
      ``g(s, P s_a)`` and the executed ``tau_run`` in the forward model's scaled torque
      units, ``d_action(x, y)`` the form's distance.

    Register before the config that names the loss is made (for the CLI:
    ``cfm-jax --import MODULE train ...``, where ``MODULE`` registers it on import).

    Args:
      name: a new name (a non-empty string without commas or spaces).
      fn: the per-sample loss, a pure JAX function (traced inside the compiled update).
      forward: see above.
      run: the loss needs ``P f(s, tau_run)`` (``forward`` losses only).

    Returns:
      the registered :class:`Loss`.

    Raises:
      ValueError: a bad or taken name, ``fn`` not callable, ``run`` without ``forward``.

    Examples:
      >>> def mix(q, d_desired, d_output):  # 0.7 task + 0.3 joint, in either form
      ...     return 0.7 * d_desired(q.predicted, q.desired) + 0.3 * (
      ...         d_desired(q.predicted, q.desired) + d_output(q.predicted_next, q.observed_next))
      >>> # register("mix", mix); then Config(loss="mix") trains it (docs/concepts/losses.md)
      >>> register("task", mix)
      Traceback (most recent call last):
      ValueError: name='task' is not allowed: a controller loss of that name exists
    """
    if not isinstance(name, str) or not name or any(c in name for c in ", \t\n"):
        raise ValueError(f"name={name!r} is not allowed: a non-empty string without commas "
                         "or spaces")  # fmt: skip
    if name in REGISTRY:
        raise ValueError(f"name={name!r} is not allowed: a controller loss of that name exists")
    if not callable(fn):
        raise ValueError(f"fn={fn!r} is not allowed: a function")
    if run and not forward:
        raise ValueError("run=True is not allowed without forward=True: f(s, tau_run) is the "
                         "forward model's")  # fmt: skip
    loss = Loss(name, fn, bool(forward), bool(run))
    REGISTRY[name] = loss
    config_lib.add_loss_name(name)
    return loss


def get(loss) -> Loss:
    """The registered :class:`Loss` of a name (a :class:`Loss` is returned as it is).

    Args:
      loss: a registered name or a :class:`Loss`.

    Raises:
      ConfigError: no loss of that name is registered.

    Examples:
      >>> get("distal").run, get("supervised").forward
      (True, False)
    """
    if isinstance(loss, Loss):
        return loss
    if loss not in REGISTRY:
        raise ConfigError(f"loss={loss!r} is not allowed: one of {tuple(REGISTRY)} (register "
                          "a loss of your own with cfm_jax.learning.losses.register)")  # fmt: skip
    return REGISTRY[loss]


for _name, _fn, _forward, _run in (
    ("joint", _joint, True, False),
    ("task", _task, True, False),
    ("distal", _distal, True, True),
    ("supervised", _supervised, False, False),
    ("distal_literal", _distal_literal, True, False),
):
    register(_name, _fn, forward=_forward, run=_run)


def safe_norm(x):
    """Euclidean norm over the last axis, gradient 0 at ``x = 0`` (``jnp.linalg.norm``'s is NaN).

    Args:
      x: shape ``(..., d)``.

    Examples:
      >>> import jax
      >>> float(safe_norm(jnp.array([3.0, 4.0]))), jax.grad(safe_norm)(jnp.zeros(2)).tolist()
      (5.0, [0.0, 0.0])
    """
    squares = jnp.sum(jnp.square(x), axis=-1)
    positive = squares > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squares, 1.0)), 0.0)


def grouped(error, groups):
    """Weighted sum of group norms ``sum_k w_k |error[..., I_k]|``, the ``norm`` form's distance.

    Args:
      error: shape ``(..., d)``.
      groups: ``((weight, (index, ...)), ...)``, static indices into the last axis.

    Examples:
      >>> float(grouped(jnp.array([3.0, 4.0, 1.0]), ((1.0, (0, 1)), (2.0, (2,)))))  # 5 + 2 * 1
      7.0
    """
    total = 0.0
    for weight, index in groups:
        total = total + weight * safe_norm(error[..., jnp.asarray(index)])
    return total


def desired_groups(groups, desired_index):
    """Groups over the forward model's output as groups over the desired entries ``desired_index``.

    Each group keeps the selected entries, renumbered as positions in ``s_d``; empty groups go.

    Args:
      groups: ``((weight, (output index, ...)), ...)``.
      desired_index: the output entries ``s_d`` specifies, or None (all, in order).

    Examples:
      >>> desired_groups(((1.0, (0, 1, 2)), (5.0, (0,))), desired_index=(1, 2))
      ((1.0, (0, 1)),)
    """
    if desired_index is None:
        return tuple(groups)
    position = {int(i): j for j, i in enumerate(desired_index)}
    out = []
    for weight, index in groups:
        kept = tuple(position[i] for i in index if i in position)
        if kept:
            out.append((weight, kept))
    return tuple(out)


def squared_error(predicted, target):
    """Sum of squared errors over the last axis.

    Args:
      predicted: shape ``(..., d)``.
      target: shape ``(..., d)``.

    Examples:
      >>> float(squared_error(jnp.array([1.0, 2.0]), jnp.array([0.0, 0.0])))
      5.0
    """
    return jnp.sum(jnp.square(predicted - target), axis=-1)


def gaussian_nll(mean, log_variance, target):
    """Twice the Gaussian NLL minus its constant (PETS): ``sum (target - mean)^2 / var + log var``.

    Args:
      mean: predicted mean, shape ``(..., d)``.
      log_variance: predicted ``log var``, shape ``(..., d)``.
      target: observed value, shape ``(..., d)``.

    Examples:
      >>> float(gaussian_nll(jnp.array([0.0]), jnp.array([0.0]), jnp.array([2.0])))
      4.0
    """
    return jnp.sum(jnp.square(target - mean) * jnp.exp(-log_variance) + log_variance, axis=-1)


def __getattr__(name):
    """``losses.CONTROLLER_LOSSES``: the config's registered names as they are now (a copy
    bound at import would miss the losses registered since)."""
    if name == "CONTROLLER_LOSSES":
        return config_lib.CONTROLLER_LOSSES
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
