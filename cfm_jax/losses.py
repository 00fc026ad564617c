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
"""

from __future__ import annotations

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
    name, predicted_next, desired_next, observed_next, select=None, predicted_run=None
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
    if select is None:
        select = lambda y: y  # noqa: E731
    if name == "task":
        return task(select(predicted_next), desired_next)
    if name == "joint":
        return task(select(predicted_next), desired_next) + task(predicted_next, observed_next)
    if name == "distal":
        if predicted_run is None:
            raise ValueError("loss='distal' needs predicted_run = f(s, tau_run)")
        return distal(
            select(predicted_next), select(predicted_run), desired_next, select(observed_next)
        )
    if name == "distal_literal":
        return distal_literal(select(predicted_next), desired_next, select(observed_next))
    raise ValueError(
        f"loss={name!r} is not a model-based controller loss; allowed: 'task', 'joint', "
        "'distal', 'distal_literal' ('supervised' is computed by losses.supervised)"
    )


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
