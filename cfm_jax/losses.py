"""Forward-model and controller losses (paper section III).

Every function here is a small pure function of arrays; none of them knows about networks.
The gradient path is chosen where ``jax.grad`` is called (see ``cfm_jax.update``): the
controller losses are differentiated with respect to the controller parameters only, so
the forward model is never changed by them.

Notation (1-D, paper section III-B): ``s_p = f_theta(s, g_beta(s, s_d))`` is the predicted
next state, ``s_d`` the desired next state, ``s_a`` the observed (actual) next state, and
``p' = df/dg * dg/dbeta``.

Shapes: every per-sample loss takes arrays of shape ``(..., d)`` and returns the sum of
squares over the last axis, shape ``(...)``. Means over batches are taken by the caller.

Two forms (``controller.loss_form``): ``squared`` (the paper's text, the default) and
``norm``, where every distance ``|x - y|^2`` of a controller loss becomes the weighted sum of
per-sample Euclidean norms of coordinate groups, ``sum_k w_k |x[I_k] - y[I_k]|``
(:func:`grouped`; the authors' public Solo12 code).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp

# The loss names live with the other names of choices in the config, the bottom of the
# import graph; re-exported here, next to the functions they name.
from cfm_jax.config import CONTROLLER_LOSSES, PAPER_LOSSES  # noqa: F401


def task(predicted_next, desired_next):
    """Task loss ``L = |s_p - s_d|^2`` (paper eq. 2).

    1-D gradient: ``dL/dbeta = 2 p' (s_p - s_d)``; at rest where the *model* predicts the
    desired state, ``s_p = s_d``, whatever the model's bias.

    Args:
      predicted_next: ``f(s, g(s, s*))``, shape ``(..., d)``.
      desired_next: ``s*``, shape ``(..., d)``.
    Returns:
      shape ``(...)``.

    Examples:
      >>> float(task(jnp.array([1.0]), jnp.array([3.0])))
      4.0
    """
    return jnp.sum(jnp.square(predicted_next - desired_next), axis=-1)


def joint(predicted_next, desired_next, observed_next):
    """Joint loss ``L = |s_p - s_d|^2 + |s_p - s_a|^2`` (paper eq. 4, its contribution).

    1-D gradient: ``dL/dbeta = 2 p' (2 s_p - s_d - s_a)``; at rest where
    ``s_p = (s_d + s_a) / 2``.

    Args:
      predicted_next: ``f(s, g(s, s*))``, shape ``(..., d)``.
      desired_next: ``s*``, shape ``(..., d)``.
      observed_next: next state observed on the robot, shape ``(..., d)``.
    Returns:
      shape ``(...)``.

    Examples:
      >>> float(joint(jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      5.0
    """
    return task(predicted_next, desired_next) + task(predicted_next, observed_next)


def distal(predicted_next, predicted_run, desired_next, observed_next):
    """Distal-teacher loss (Jordan & Rumelhart 1992) in a bounded form:
    ``L = |s_p - s_p,run + s_a - s_d|^2``, with ``s_p,run = f(s, tau_run)`` the model's
    prediction for the action that was run (held fixed: it does not depend on the
    controller's parameters).

    1-D gradient: ``dL/dbeta = 2 p' (s_p - s_p,run + s_a - s_d)``; at ``g = tau_run``
    (``s_p = s_p,run``) it is ``2 p' (s_a - s_d)``, the distal teacher's update (paper
    section III-D, up to its sign convention and a factor): the outcome error of the
    action that was run, carried back through the model. ``L >= 0``, so unlike
    :func:`distal_literal` it is bounded below; it is at rest where the model predicts the
    run outcome corrected by the observed error, ``s_p = s_p,run - (s_a - s_d)``.

    Args:
      predicted_next: ``f(s, g(s, s*))``, shape ``(..., d)``.
      predicted_run: ``f(s, tau_run)``, shape ``(..., d)``.
      desired_next: ``s*``, shape ``(..., d)``.
      observed_next: next state observed on the robot, shape ``(..., d)``.

    Returns:
      shape ``(...)``.

    Examples:
      >>> float(distal(jnp.array([1.0]), jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      9.0
    """
    return task(predicted_next - predicted_run + observed_next, desired_next)


def distal_literal(predicted_next, desired_next, observed_next):
    """The distal teacher written literally as a loss, ``L = |s_p - s_d|^2 - |s_p - s_a|^2``,
    over the whole data set (``loss="distal_literal"``; for studies of it).

    1-D gradient: ``dL/dbeta = 2 p' (s_a - s_d)`` for every sample, at any ``g``. It is
    linear in ``s_p``, so it has no rest point for a held ``s_a`` and is unbounded below:
    trained for many steps on observed outcomes of earlier controllers it diverges. The
    bounded :func:`distal` has the same gradient at the action that was run.

    Args:
      predicted_next: ``f(s, g(s, s*))``, shape ``(..., d)``.
      desired_next: ``s*``, shape ``(..., d)``.
      observed_next: next state observed on the robot, shape ``(..., d)``.

    Returns:
      shape ``(...)``.

    Examples:
      >>> float(distal_literal(jnp.array([1.0]), jnp.array([3.0]), jnp.array([0.0])))
      3.0
    """
    return task(predicted_next, desired_next) - task(predicted_next, observed_next)


def supervised(predicted_action, executed_action):
    """Supervised inverse loss ``L = |g(s_t, s_a) - tau_run|^2`` (paper eq. 3).

    The controller is fed the *observed* next state in place of the desired one and
    regressed onto the action that produced it; no forward model is involved.
    1-D gradient: ``dL/dbeta = 2 g' (g - tau_run)``.

    Args:
      predicted_action: ``g(s, s_a)``, shape ``(..., m)``.
      executed_action: ``tau_run``, shape ``(..., m)``.
    Returns:
      shape ``(...)``.

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
    """Dispatch the model-based controller losses by name (``task``, ``joint``, ``distal``,
    ``distal_literal``).

    With ``P`` the selection ``select``: ``task = |P s_p - s_d|^2``, ``joint = |P s_p - s_d|^2
    + |s_p - s_a|^2`` (the whole prediction error), ``distal = |P (s_p - s_p,run) + P s_a -
    s_d|^2`` and ``distal_literal = |P s_p - s_d|^2 - |P s_p - P s_a|^2`` (error signal
    ``P s_a - s_d`` for both). ``supervised`` does not go through the forward model; call
    :func:`supervised`.

    Args:
      name: ``"task"``, ``"joint"``, ``"distal"`` or ``"distal_literal"``.
      predicted_next: ``s_p = f(s, g(s, s*))``, shape ``(..., d_out)``: everything the
        forward model predicts.
      desired_next: ``s_d = s*``, shape ``(..., d)``.
      observed_next: ``s_a``, the observed quantity, shape ``(..., d_out)``.
      select: ``select(y)`` picks the ``d`` entries of a prediction or observation
        ``(..., d_out)`` that the desired state specifies (``None``: all, ``d = d_out``; for
        example the end-effector acceleration among the joint and end-effector accelerations
        the forward model predicts).
      predicted_run: ``s_p,run = f(s, tau_run)``, shape ``(..., d_out)``; needed by
        ``distal`` only.
      groups: None (the ``squared`` form, every ``|x - y|^2`` above a sum of squares) or
        the ``norm`` form's ``((weight, (output index, ...)), ...)``: every ``|x - y|^2``
        becomes :func:`grouped` of ``x - y``, with the groups over the output for
        ``|s_p - s_a|`` and mapped by :func:`desired_groups` with ``desired_index`` for
        the distances in the desired quantity's coordinates.
      desired_index: the output entries ``select`` picks (None: all); used with
        ``groups`` only.

    Returns:
      shape ``(...)``.

    Raises:
      ValueError: an unknown ``name`` (or ``supervised``), or ``distal`` without
        ``predicted_run``.

    Examples:
      >>> p, d, o = jnp.array([1.0, 2.0]), jnp.array([3.0]), jnp.array([0.0, 2.0])
      >>> float(controller_loss("joint", p, d, o, select=lambda y: y[..., :1]))
      5.0
    """
    if name not in MODEL_BASED:
        raise ValueError(
            f"loss={name!r} is not a model-based controller loss; allowed: 'task', 'joint', "
            "'distal', 'distal_literal' ('supervised' is computed by losses.supervised)"
        )
    if name == "distal" and predicted_run is None:
        raise ValueError("loss='distal' needs predicted_run = f(s, tau_run)")
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

    quantities = _Quantities(
        predicted=select(predicted_next),
        predicted_next=predicted_next,
        desired=desired_next,
        observed_next=observed_next,
        observed=select(observed_next),
        run=None if predicted_run is None else select(predicted_run),
    )
    return MODEL_BASED[name](quantities, d_desired, d_output)


class _Quantities(NamedTuple):
    """What a model-based loss is made of: ``P s_p``, ``s_p``, ``s_d``, ``s_a``, ``P s_a``
    and ``P s_p,run`` (``P`` the selection of the desired quantity's entries)."""

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


MODEL_BASED = {"task": _task, "joint": _joint, "distal": _distal, "distal_literal": _distal_literal}
"""Each model-based controller loss, defined once for both forms
(``controller.loss_form``): ``loss(quantities, d_desired, d_output)`` with the distances
of the form (``squared``: sums of squares; ``norm``: :func:`grouped` norms), used by
:func:`controller_loss` (the update's and the 1-D theory's)."""


def safe_norm(x):
    """Euclidean norm over the last axis, with gradient 0 (a subgradient) where ``x = 0``.

    ``jnp.linalg.norm`` has a NaN gradient at 0, which a sample the model predicts exactly
    would otherwise give.

    Args:
      x: shape ``(..., d)``.

    Returns:
      shape ``(...)``.

    Examples:
      >>> import jax
      >>> float(safe_norm(jnp.array([3.0, 4.0]))), jax.grad(safe_norm)(jnp.zeros(2)).tolist()
      (5.0, [0.0, 0.0])
    """
    squares = jnp.sum(jnp.square(x), axis=-1)
    positive = squares > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squares, 1.0)), 0.0)


def grouped(error, groups):
    """Weighted sum of the Euclidean norms of coordinate groups of ``error``:
    ``sum_k w_k |error[..., I_k]|`` (the ``norm`` form of the controller losses).

    The authors' Solo12 task loss ``|v_p - v*| + |F_p - F*| + 10 |v_p[2:6] - v*[2:6]|`` is
    ``grouped(s_p - s*, ((1, velocities), (1, forces), (10, (2, 3, 4, 5))))``.

    Args:
      error: shape ``(..., d)``.
      groups: ``((weight, (index, ...)), ...)``, indices into the last axis (static).

    Returns:
      shape ``(...)``.

    Examples:
      >>> e = jnp.array([3.0, 4.0, 1.0])
      >>> float(grouped(e, ((1.0, (0, 1)), (2.0, (2,)))))  # 5 + 2 * 1
      7.0
    """
    total = 0.0
    for weight, index in groups:
        total = total + weight * safe_norm(error[..., jnp.asarray(index)])
    return total


def desired_groups(groups, desired_index):
    """Groups over the forward model's output ``y`` as groups over the desired quantity
    ``s* = P y`` (``P``: the entries ``desired_index``): each group keeps the entries ``P``
    selects, renumbered as positions in ``s*``; groups left empty are dropped.

    Args:
      groups: ``((weight, (output index, ...)), ...)``.
      desired_index: the output entries ``s*`` specifies, or None (all, in order).

    Returns:
      ``((weight, (desired position, ...)), ...)``.

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
    """Sum of squared errors over the last axis, ``sum_i (predicted_i - target_i)^2``.

    Args:
      predicted: shape ``(..., d)``.
      target: shape ``(..., d)``.

    Returns:
      shape ``(...)``.

    Examples:
      >>> float(squared_error(jnp.array([1.0, 2.0]), jnp.array([0.0, 0.0])))
      5.0
    """
    return jnp.sum(jnp.square(predicted - target), axis=-1)


def gaussian_nll(mean, log_variance, target):
    """Gaussian negative log-likelihood of ``target`` (PETS, Chua et al. 2018), no constant.

    ``L = sum_i (target_i - mean_i)^2 exp(-log_variance_i) + log_variance_i``
    (twice the NLL minus ``d log 2 pi``). For fixed variance its gradient in ``mean`` is the
    squared error's gradient scaled by ``exp(-log_variance)``.

    Args:
      mean: predicted mean, shape ``(..., d)``.
      log_variance: predicted log-variance, shape ``(..., d)``.
      target: observed value, shape ``(..., d)``.
    Returns:
      shape ``(...)``.

    Examples:
      >>> float(gaussian_nll(jnp.array([0.0]), jnp.array([0.0]), jnp.array([2.0])))
      4.0
    """
    return jnp.sum(jnp.square(target - mean) * jnp.exp(-log_variance) + log_variance, axis=-1)
