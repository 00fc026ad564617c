"""The paper's 1-D argument (section III-B/C) made computable: where each controller loss rests.

A true system ``h`` (:class:`TrueSystem`), a linear model ``f`` and an affine controller ``g``
with the losses of :mod:`cfm_jax.learning.losses` on ``f o g``. Entry points: :func:`rest_action`,
:func:`consistent_rest_action`, :func:`fixed_point`, :func:`iterate` (Algorithm 1) and
:func:`sweep_model_bias`. The closed forms, readings of ``s_a`` and figures: docs/theory.md.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from cfm_jax.learning import losses

THEORY_LOSSES = ("task", "joint", "distal", "supervised")
"""Controller losses studied here, in the order results are reported."""

MODEL_BASED_LOSSES = ("task", "joint", "distal")
"""Losses that go through the forward model (``f o g``)."""

GOALS = ("desired", "observed")
"""The controller's goal while trained (``Config.controller.goal``): ``g(s_d)`` (paper eq. 4) or
``g(s_a)`` (the authors' Solo12 code); see :func:`observed_goal_fixed_point`."""

REFIT_MODES = ("none", "latest", "all")
"""The model's refit after each rollout: ``"none"`` (bias kept), ``"latest"`` (offset through the
latest observation, gain kept) or ``"all"`` (least squares on all data, ridge ``prior_weight``)."""


class TrueSystem(NamedTuple):
    """True 1-D actuator ``s_a = gain * tau + offset + cubic * tau^3`` (scalar or array fields).

    Attributes:
      gain: ``a``.
      offset: ``b``.
      cubic: ``c``; nonzero makes :class:`LinearModel` a misspecified model class.

    Examples:
      >>> TrueSystem(gain=2.0)
      TrueSystem(gain=2.0, offset=0.0, cubic=0.0)
    """

    gain: jax.Array | float = 1.0
    offset: jax.Array | float = 0.0
    cubic: jax.Array | float = 0.0


class LinearModel(NamedTuple):
    """Forward model ``s_p = gain * tau + offset``.

    Attributes:
      gain: ``a_hat``.
      offset: ``b_hat``.

    Examples:
      >>> biased_model(TrueSystem(2.0, 1.0), gain_ratio=0.5, offset_error=0.1)
      LinearModel(gain=1.0, offset=1.1)
    """

    gain: jax.Array | float = 1.0
    offset: jax.Array | float = 0.0


class AffineController(NamedTuple):
    """Controller ``tau = offset + gain * s_target``.

    Attributes:
      offset: ``beta_0``.
      gain: ``beta_1``.

    Examples:
      >>> float(controller_action(AffineController(offset=0.5, gain=2.0), 1.0))
      2.5
    """

    offset: jax.Array | float = 0.0
    gain: jax.Array | float = 0.0


class FixedPoint(NamedTuple):
    """Fixed point of the iterated controller update.

    Attributes:
      action: ``tau*``.
      error: ``h(tau*) - s_d``.
      contraction: slope of the error map ``e_{k+1}(e_k)`` at the fixed point (local
        convergence iff ``|contraction| < 1``, at this rate); NaN for ``refit="all"``.

    Examples:
      >>> fp = fixed_point("task", TrueSystem(), LinearModel(1.0, 0.2), desired=1.0)
      >>> round(float(fp.action), 3), round(float(fp.error), 3), float(fp.contraction)
      (0.8, -0.2, 0.0)
    """

    action: jax.Array
    error: jax.Array
    contraction: jax.Array


class IterationTrace(NamedTuple):
    """Per-rollout record of :func:`iterate`, every field of shape ``(num_iters,)``.

    Attributes:
      actions: ``tau_k``, executed in rollout ``k``.
      observed: ``s_a_k = h(tau_k)``.
      errors: ``s_a_k - s_d``.
      model_gains: ``a_hat`` after the refit that follows rollout ``k``.
      model_offsets: ``b_hat`` after that refit.
      controller_offsets: ``beta_0`` after the update that follows rollout ``k``.
      controller_gains: ``beta_1`` after that update.

    Examples:
      >>> tr = iterate("task", TrueSystem(), LinearModel(1.0, 0.2), AffineController(),
      ...              1.0, num_iters=3)
      >>> [round(float(e), 3) for e in tr.errors]  # tau_0 = 0, then the task loss's rest
      [-1.0, -0.2, -0.2]
    """

    actions: jax.Array
    observed: jax.Array
    errors: jax.Array
    model_gains: jax.Array
    model_offsets: jax.Array
    controller_offsets: jax.Array
    controller_gains: jax.Array


class DataMoments(NamedTuple):
    """Sufficient statistics of pairs ``(x, y) = (tau, s_a)`` for least-squares lines (scalars).

    Attributes:
      count: ``n``.
      sum_x: ``sum_i x_i``.
      sum_xx: ``sum_i x_i^2``.
      sum_y: ``sum_i y_i``.
      sum_yy: ``sum_i y_i^2``.
      sum_xy: ``sum_i x_i y_i``.

    Examples:
      >>> m = data_moments([0.0, 1.0, 2.0], [1.0, 3.0, 5.0])
      >>> float(m.count), float(m.sum_x), float(m.sum_xy)
      (3.0, 3.0, 13.0)
    """

    count: jax.Array
    sum_x: jax.Array
    sum_xx: jax.Array
    sum_y: jax.Array
    sum_yy: jax.Array
    sum_xy: jax.Array


# ----------------------------------------------------------------------------- the 1-D world


def true_response(system: TrueSystem, action):
    """The true system's response ``s_a = a tau + b + c tau^3``.

    Args:
      system: a :class:`TrueSystem` (fields broadcast with ``action``).
      action: ``tau``, any shape.

    Examples:
      >>> float(true_response(TrueSystem(2.0, 1.0, 0.5), 2.0))
      9.0
    """
    return system.gain * action + system.offset + system.cubic * action**3


def true_slope(system: TrueSystem, action):
    """The true system's local gain ``h'(tau) = a + 3 c tau^2``.

    Args:
      system: a :class:`TrueSystem` (fields broadcast with ``action``).
      action: ``tau``, any shape.

    Examples:
      >>> float(true_slope(TrueSystem(gain=1.0, cubic=0.5), 2.0))  # 1 + 3 * 0.5 * 4
      7.0
    """
    return system.gain + 3.0 * system.cubic * jnp.square(action)


def model_prediction(model: LinearModel, action):
    """The forward model's prediction ``s_p = a_hat tau + b_hat``.

    Args:
      model: a :class:`LinearModel` (fields broadcast with ``action``).
      action: ``tau``, any shape.

    Examples:
      >>> float(model_prediction(LinearModel(gain=2.0, offset=0.5), 1.0))
      2.5
    """
    return model.gain * action + model.offset


def controller_action(controller: AffineController, target):
    """The controller's action ``tau = beta_0 + beta_1 s_target``.

    Args:
      controller: an :class:`AffineController` (fields broadcast with ``target``).
      target: ``s_target``, any shape.

    Examples:
      >>> controller_action(AffineController(offset=0.5, gain=2.0), jnp.array([0.0, 1.0]))
      Array([0.5, 2.5], dtype=float32)
    """
    return controller.offset + controller.gain * target


def model_error(system: TrueSystem, model: LinearModel, action):
    """Forward-model prediction error ``m(tau) = f(tau) - h(tau)`` (positive: over-predicts).

    Args:
      system: the :class:`TrueSystem` ``h``.
      model: the :class:`LinearModel` ``f``.
      action: ``tau``, any shape (the fields may broadcast with it).

    Examples:
      >>> round(float(model_error(TrueSystem(1.0, 0.0), LinearModel(1.0, 0.2), 3.0)), 6)
      0.2
    """
    return model_prediction(model, action) - true_response(system, action)


def biased_model(system: TrueSystem, gain_ratio=1.0, offset_error=0.0) -> LinearModel:
    """Linear model with gain ``gain_ratio * a`` and offset ``b + offset_error`` (ignores ``c``).

    Args:
      system: the :class:`TrueSystem` whose gain and offset are biased.
      gain_ratio: ``a_hat / a`` (scalar or array).
      offset_error: ``b_hat - b`` (scalar or array).

    Examples:
      >>> biased_model(TrueSystem(2.0, 1.0), gain_ratio=1.0)  # exact for a linear system
      LinearModel(gain=2.0, offset=1.0)
    """
    return LinearModel(gain=gain_ratio * system.gain, offset=system.offset + offset_error)


# ----------------------------------------------------------------------------- losses, gradients


def controller_loss(
    name: str,
    controller: AffineController,
    model: LinearModel,
    desired,
    observed,
    goal: str = "desired",
):
    """A model-based loss of :mod:`cfm_jax.learning.losses` on ``s_p = f(g(s_d))``, shape ``(...)``.

    ``distal`` is :func:`cfm_jax.learning.losses.distal_literal`: with ``s_a`` held its gradient is
    the distal teacher's ``2 f' g' (s_a - s_d)`` at every step, as in the paper's 1-D argument.

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      controller: an :class:`AffineController` (fields broadcast with the data).
      model: a :class:`LinearModel` (likewise).
      desired: ``s_d``, shape ``(...)``.
      observed: ``s_a``, shape ``(...)``, held fixed.
      goal: one of :data:`GOALS` (else ValueError): ``s_p = f(g(s_d))`` or ``f(g(s_a))``.

    Examples:
      >>> float(controller_loss("joint", AffineController(1.0, 0.0), LinearModel(1.0, 0.0),
      ...                       3.0, 0.0))
      5.0
    """
    if goal not in GOALS:
        raise ValueError(f"goal={goal!r} not in {GOALS}")
    given = desired if goal == "desired" else observed
    predicted = model_prediction(model, controller_action(controller, given))
    return losses.controller_loss(
        "distal_literal" if name == "distal" else name,
        jnp.asarray(predicted)[..., None],
        jnp.asarray(desired, dtype=jnp.result_type(float))[..., None],
        jnp.asarray(observed, dtype=jnp.result_type(float))[..., None],
    )


def supervised_loss(controller: AffineController, observed, executed_action):
    """Supervised inverse loss ``(g(s_a) - tau_run)^2``
    (:func:`cfm_jax.learning.losses.supervised`).

    Args:
      controller: an :class:`AffineController` (fields broadcast with the data).
      observed: ``s_a``, the controller's input, shape ``(...)``.
      executed_action: ``tau_run``, the action that produced ``s_a``, shape ``(...)``.

    Examples:
      >>> float(supervised_loss(AffineController(0.0, 1.0), observed=2.0, executed_action=1.5))
      0.25
    """
    predicted_action = controller_action(controller, observed)
    return losses.supervised(
        jnp.asarray(predicted_action)[..., None],
        jnp.asarray(executed_action, dtype=jnp.result_type(float))[..., None],
    )


def controller_gradient(
    name: str,
    controller: AffineController,
    model: LinearModel,
    desired,
    observed,
    executed_action=None,
    goal: str = "desired",
) -> AffineController:
    """``dL/dbeta`` by ``jax.grad`` through ``f o g``, as ``(dL/dbeta_0, dL/dbeta_1)``.

    Equals the paper's ``2 f' g' (s_p - s_d)`` (task), ``2 f' g' (2 s_p - s_d - s_a)`` (joint) and
    ``2 f' g' (s_a - s_d)`` (distal) with ``f' = a_hat``, ``g' = (1, s_d)`` (``(1, s_a)`` and
    ``s_p = f(g(s_a))`` for ``goal="observed"``); supervised: ``2 (g(s_a) - tau_run) (1, s_a)``.

    Args:
      name: one of :data:`THEORY_LOSSES`.
      controller: an :class:`AffineController` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      observed: ``s_a`` (scalar), held fixed.
      executed_action: ``tau_run`` (scalar), needed by ``supervised`` (else ValueError).
      goal: ``"desired"`` or ``"observed"`` (:func:`controller_loss`).

    Examples:
      >>> g = controller_gradient("task", AffineController(1.0, 0.0), LinearModel(2.0, 0.0),
      ...                         desired=1.0, observed=0.0)
      >>> float(g.offset), float(g.gain)      # 2 * 2 * (2 - 1) * (1, s_d)
      (4.0, 4.0)
    """
    controller = AffineController(
        *(jnp.asarray(p, dtype=jnp.result_type(float)) for p in controller)
    )
    if name == "supervised":
        if executed_action is None:
            raise ValueError("the supervised loss needs executed_action (tau_run)")
        return jax.grad(supervised_loss)(controller, observed, executed_action)
    return jax.grad(controller_loss, argnums=1)(name, controller, model, desired, observed, goal)


def loss_landscape(name: str, model: LinearModel, desired, observed, actions):
    """Model-based loss and its ``jax.grad`` in the action ``tau`` (``beta_0 = tau``), each (n,).

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      observed: ``s_a`` (scalar), held fixed.
      actions: the actions ``tau``, shape ``(n,)``.

    Examples:
      >>> loss, grad = loss_landscape("task", LinearModel(1.0, 0.0), 1.0, 0.0,
      ...                             jnp.array([0.0, 1.0, 2.0]))
      >>> loss.tolist(), grad.tolist()  # (tau - 1)^2 and 2 (tau - 1)
      ([1.0, 0.0, 1.0], [-2.0, 0.0, 2.0])
    """

    def loss_of_action(action):
        return controller_loss(name, AffineController(action, 0.0), model, desired, observed)

    return jax.vmap(loss_of_action)(actions), jax.vmap(jax.grad(loss_of_action))(actions)


# ----------------------------------------------------------------------------- equilibria


def rest_action(name: str, model: LinearModel, desired, observed):
    """Rollout reading: the action where the loss's gradient vanishes for a held ``s_a``.

    Task: ``f(tau) = s_d``; joint: ``f(tau) = (s_d + s_a) / 2``; distal: no rest point, its
    gradient ``2 a_hat (s_a - s_d)`` does not depend on ``tau`` (NaN).

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      model: a :class:`LinearModel` (scalars or broadcasting arrays).
      desired: ``s_d`` (scalar or array).
      observed: ``s_a`` (scalar or array), held fixed.

    Raises:
      ValueError: ``name`` is not a model-based loss.

    Examples:
      >>> float(rest_action("joint", LinearModel(2.0, 0.0), desired=1.0, observed=0.0))
      0.25
    """
    if name == "task":
        target = jnp.asarray(desired, dtype=jnp.result_type(float))
    elif name == "joint":
        target = 0.5 * (jnp.asarray(desired) + jnp.asarray(observed))
    elif name == "distal":
        return jnp.full(jnp.broadcast_shapes(jnp.shape(desired), jnp.shape(observed)), jnp.nan)
    else:
        raise ValueError(f"rest_action: loss={name!r} not in {MODEL_BASED_LOSSES}")
    return (target - model.offset) / model.gain


def _consistent_residual(name, system, model, desired, action):
    if name == "task":  # f(tau) = s_d
        return model_prediction(model, action) - desired
    if name == "joint":  # f(tau) = (s_d + h(tau)) / 2
        return 2.0 * model_prediction(model, action) - true_response(system, action) - desired
    if name in ("distal", "supervised"):  # h(tau) = s_d
        return true_response(system, action) - desired
    raise ValueError(f"loss={name!r} not in {THEORY_LOSSES}")


def _linear_consistent_action(name, system, model, desired):
    if name == "task":
        return (desired - model.offset) / model.gain
    if name == "joint":
        return (desired - 2.0 * model.offset + system.offset) / (2.0 * model.gain - system.gain)
    return (desired - system.offset) / system.gain


def consistent_rest_action(
    name: str,
    system: TrueSystem,
    model: LinearModel,
    desired,
    initial_action=None,
    newton_iterations: int = 40,
):
    """Consistent reading: the action where the gradient vanishes with ``s_a = h(tau)``.

    This is the fixed point of the rollout iteration with a fixed model: task ``f(tau) = s_d``,
    joint ``2 f(tau) - h(tau) = s_d``, distal and supervised ``h(tau) = s_d``. Closed form for
    ``c = 0``, else Newton's method; the cubic joint equation can have three roots, Newton
    returns the one it reaches. NaN or inf where there is no root (joint: ``2 a_hat = a``).

    Args:
      name: one of :data:`THEORY_LOSSES`.
      system: a :class:`TrueSystem` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      initial_action: Newton's start; ``None``: the closed form with ``c = 0``.
      newton_iterations: Newton steps, used when ``system.cubic != 0``.

    Examples:
      >>> float(consistent_rest_action("joint", TrueSystem(1.0, 0.0), LinearModel(1.0, 0.5),
      ...                              desired=1.0))
      0.0
    """
    linear_system = TrueSystem(system.gain, system.offset, 0.0)
    closed = _linear_consistent_action(name, linear_system, model, desired)
    if initial_action is None:
        initial_action = closed

    def residual(action):
        return _consistent_residual(name, system, model, desired, action)

    def newton_step(_, action):
        return action - residual(action) / jax.grad(residual)(action)

    start = jnp.asarray(initial_action, dtype=jnp.result_type(float))
    newton = jax.lax.fori_loop(0, newton_iterations, newton_step, start)
    return jnp.where(jnp.asarray(system.cubic) == 0.0, closed, newton)


def _inner_residual_factor(name, model, inner_steps, learning_rate):
    """``rho^n``: fraction of the distance to the rest point left after ``n`` steps."""
    if inner_steps is None:
        return 0.0
    curvature = {"task": 2.0, "joint": 4.0}[name] * jnp.square(model.gain)
    return (1.0 - learning_rate * curvature) ** inner_steps


def fixed_point(
    name: str,
    system: TrueSystem,
    model: LinearModel,
    desired,
    *,
    refit: str = "none",
    inner_steps: int | None = None,
    learning_rate: float = 0.1,
    controller: AffineController | None = None,
) -> FixedPoint:
    """Closed-form fixed point of the iterated Algorithm 1 (:func:`iterate`) and its contraction.

    The formulas per loss and refit mode are tabulated in docs/theory.md ("Closed forms"), with
    ``a`` replaced by the local slope ``h'(tau*)``; ``refit="all"`` ends at ``h(tau*) = s_d``
    for every converging loss, at a sublinear rate when misspecified (contraction NaN).

    Args:
      name: one of :data:`THEORY_LOSSES`.
      system: a :class:`TrueSystem` of scalars (``vmap`` for arrays).
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d``.
      refit: one of :data:`REFIT_MODES` (else ValueError).
      inner_steps: gradient steps per update; ``None``: to rest (ValueError for ``distal``).
      learning_rate: step size of those steps.
      controller: the initial controller, needed by ``supervised`` (else ValueError).

    Examples:
      >>> fp = fixed_point("joint", TrueSystem(), LinearModel(1.0, 0.2), desired=1.0,
      ...                  refit="latest")
      >>> round(float(fp.error), 6), float(fp.contraction)  # 1 - a / (2 a_hat)
      (0.0, 0.5)
    """
    if refit not in REFIT_MODES:
        raise ValueError(f"refit={refit!r} not in {REFIT_MODES}")
    if name == "distal" and inner_steps is None:
        raise ValueError("the distal-teacher loss has no rest point; pass inner_steps")
    if name == "supervised" and controller is None:
        raise ValueError("the supervised loss needs the initial controller")

    if name == "supervised" and refit == "none":
        action = controller_action(controller, desired)
    elif refit == "none" and name in ("task", "joint"):
        action = consistent_rest_action(name, system, model, desired)
    else:
        action = consistent_rest_action("distal", system, model, desired)
    action = jnp.asarray(action, dtype=jnp.result_type(float))
    error = true_response(system, action) - desired

    slope = true_slope(system, action)
    if refit == "all":
        contraction = jnp.nan * action
    elif name == "distal":
        contraction = 1.0 - 2.0 * inner_steps * learning_rate * slope * model.gain
    elif name == "supervised":
        contraction = 0.0 * action if refit == "none" else 1.0 - slope * controller.gain
    else:
        left = _inner_residual_factor(name, model, inner_steps, learning_rate)
        share = slope / model.gain / (1.0 if name == "task" else 2.0)
        if refit == "none":
            contraction = left + (0.0 if name == "task" else (1.0 - left) * share)
        else:
            contraction = 1.0 - (1.0 - left) * share
    return FixedPoint(action, error, jnp.asarray(contraction) + 0.0 * action)


# ----------------------------------------------------------------------------- iteration


def data_moments(actions, observed) -> DataMoments:
    """:class:`DataMoments` of the pairs ``(tau_i, s_a_i)``.

    Args:
      actions: ``tau_i``, shape ``(n,)``.
      observed: ``s_a_i``, shape ``(n,)``.

    Examples:
      >>> float(data_moments([0.0, 1.0], [1.0, 3.0]).sum_yy)
      10.0
    """
    actions = jnp.asarray(actions, dtype=jnp.result_type(float))
    observed = jnp.asarray(observed, dtype=jnp.result_type(float))
    return DataMoments(
        count=jnp.asarray(actions.shape[0], actions.dtype),
        sum_x=jnp.sum(actions),
        sum_xx=jnp.sum(actions**2),
        sum_y=jnp.sum(observed),
        sum_yy=jnp.sum(observed**2),
        sum_xy=jnp.sum(actions * observed),
    )


def _add_pair(moments: DataMoments, action, observed) -> DataMoments:
    return DataMoments(
        moments.count + 1.0,
        moments.sum_x + action,
        moments.sum_xx + action**2,
        moments.sum_y + observed,
        moments.sum_yy + observed**2,
        moments.sum_xy + action * observed,
    )


def fit_line(count, sum_x, sum_xx, sum_y, sum_xy, prior_slope, prior_intercept, prior_weight):
    """Ridge least squares ``min sum_i (k x_i + m - y_i)^2 + w ((k - k0)^2 + (m - m0)^2)``.

    Args:
      count: ``n``, the number of pairs.
      sum_x: ``sum_i x_i``.
      sum_xx: ``sum_i x_i^2``.
      sum_y: ``sum_i y_i``.
      sum_xy: ``sum_i x_i y_i``.
      prior_slope: ``k0``.
      prior_intercept: ``m0``.
      prior_weight: ``w >= 0``; 0: plain least squares (needs two distinct ``x``).

    Returns:
      ``(k, m)``, the slope and intercept (broadcast as the arguments).

    Examples:
      >>> m = data_moments([0.0, 1.0, 2.0], [1.0, 3.0, 5.0])  # y = 2 x + 1
      >>> k, b = fit_line(m.count, m.sum_x, m.sum_xx, m.sum_y, m.sum_xy, 0.0, 0.0, 0.0)
      >>> round(float(k), 4), round(float(b), 4)
      (2.0, 1.0)
    """
    a11, a12, a22 = sum_xx + prior_weight, sum_x, count + prior_weight
    r1, r2 = sum_xy + prior_weight * prior_slope, sum_y + prior_weight * prior_intercept
    det = a11 * a22 - a12 * a12
    return (a22 * r1 - a12 * r2) / det, (a11 * r2 - a12 * r1) / det


def fit_model(moments: DataMoments, prior: LinearModel, prior_weight=0.0) -> LinearModel:
    """Least-squares forward model ``s_a ~ a_hat tau + b_hat`` (ridge towards ``prior``).

    Args:
      moments: :class:`DataMoments` of the pairs ``(tau_i, s_a_i)``.
      prior: the :class:`LinearModel` the ridge term pulls towards.
      prior_weight: ridge weight (:func:`fit_line`).

    Examples:
      >>> fit = fit_model(data_moments([0.0, 1.0, 2.0], [1.0, 3.0, 5.0]), LinearModel())
      >>> round(float(fit.gain), 4), round(float(fit.offset), 4)
      (2.0, 1.0)
    """
    gain, offset = fit_line(
        moments.count,
        moments.sum_x,
        moments.sum_xx,
        moments.sum_y,
        moments.sum_xy,
        prior.gain,
        prior.offset,
        prior_weight,
    )
    return LinearModel(gain, offset)


def fit_inverse(
    moments: DataMoments, prior: AffineController, prior_weight=0.0
) -> AffineController:
    """Least squares ``tau ~ beta_0 + beta_1 s_a``, the supervised inverse loss's minimiser.

    Args:
      moments: :class:`DataMoments` of the pairs ``(tau_i, s_a_i)``.
      prior: the :class:`AffineController` the ridge term pulls towards.
      prior_weight: ridge weight (:func:`fit_line`).

    Examples:
      >>> m = data_moments([0.0, 1.0, 2.0], [1.0, 3.0, 5.0])  # tau = (s_a - 1) / 2
      >>> inv = fit_inverse(m, AffineController())
      >>> round(float(inv.offset), 4), round(float(inv.gain), 4)
      (-0.5, 0.5)
    """
    gain, offset = fit_line(
        moments.count,
        moments.sum_y,
        moments.sum_yy,
        moments.sum_x,
        moments.sum_xy,
        prior.gain,
        prior.offset,
        prior_weight,
    )
    return AffineController(offset, gain)


@partial(jax.jit, static_argnames=("name", "num_iters", "refit", "inner_steps"))
def iterate(
    name: str,
    system: TrueSystem,
    model: LinearModel,
    controller: AffineController,
    desired,
    *,
    num_iters: int,
    refit: str = "none",
    inner_steps: int | None = None,
    learning_rate=0.1,
    babble_actions=None,
    prior_weight=0.0,
) -> IterationTrace:
    """Algorithm 1 in 1-D: roll out ``tau_k = g_k(s_d)``, observe ``h(tau_k)``, refit, update ``g``.

    The controller update holds ``s_a_k``. Model-based losses train ``beta_0`` only (one target
    identifies one parameter), to rest by Newton's method (exact: the loss is quadratic in
    ``beta_0``) or by ``inner_steps`` gradient steps; ``supervised`` keeps ``g`` (``refit="none"``),
    sets ``g(s_a_k) = tau_k`` (``"latest"``) or fits all pairs (``"all"``, :func:`fit_inverse`).

    Args:
      name: one of :data:`THEORY_LOSSES` (else ValueError).
      system: the :class:`TrueSystem` (scalars).
      model: the initial :class:`LinearModel` (scalars).
      controller: the initial :class:`AffineController` (scalars).
      desired: ``s_d`` (scalar).
      num_iters: number of rollouts.
      refit: one of :data:`REFIT_MODES` (else ValueError).
      inner_steps: gradient steps per update; ``None``: to rest (ValueError for ``distal``).
      learning_rate: step size of those steps.
      babble_actions: babbling actions ``(n,)``, data for ``refit="all"``; ``None``: none.
      prior_weight: ridge weight of ``refit="all"`` towards the initial model and controller
        (needed while fewer than two distinct actions have been seen).

    Examples:
      >>> tr = iterate("joint", TrueSystem(), LinearModel(1.0, 0.2), AffineController(),
      ...              1.0, num_iters=30)
      >>> round(float(tr.errors[-1]), 4)
      -0.4
    """
    if refit not in REFIT_MODES:
        raise ValueError(f"refit={refit!r} not in {REFIT_MODES}")
    if name not in THEORY_LOSSES:
        raise ValueError(f"loss={name!r} not in {THEORY_LOSSES}")
    if name == "distal" and inner_steps is None:
        raise ValueError("the distal-teacher loss has no rest point; pass inner_steps")
    dtype = jnp.result_type(float)
    desired = jnp.asarray(desired, dtype)
    model = LinearModel(*(jnp.asarray(p, dtype) for p in model))
    controller = AffineController(*(jnp.asarray(p, dtype) for p in controller))
    initial_model, initial_controller = model, controller
    if babble_actions is None:
        moments = data_moments(jnp.zeros((0,)), jnp.zeros((0,)))
    else:
        moments = data_moments(babble_actions, true_response(system, babble_actions))

    def offset_loss(offset, gain, model, observed):
        return controller_loss(name, AffineController(offset, gain), model, desired, observed)

    offset_grad = jax.grad(offset_loss)
    offset_curvature = jax.grad(offset_grad)

    def update_controller(controller, model, action, observed, moments):
        if name == "supervised":
            if refit == "latest":
                return AffineController(action - controller.gain * observed, controller.gain)
            if refit == "all":
                return fit_inverse(moments, initial_controller, prior_weight)
            return controller
        offset = controller.offset
        if inner_steps is None:  # to rest: Newton on the (quadratic) loss in beta_0
            for _ in range(2):
                offset = offset - (
                    offset_grad(offset, controller.gain, model, observed)
                    / offset_curvature(offset, controller.gain, model, observed)
                )
        else:

            def step(_, offset):
                return offset - learning_rate * offset_grad(
                    offset, controller.gain, model, observed
                )

            offset = jax.lax.fori_loop(0, inner_steps, step, offset)
        return AffineController(offset, controller.gain)

    def one_iteration(carry, _):
        controller, model, moments = carry
        action = controller_action(controller, desired)
        observed = true_response(system, action)
        moments = _add_pair(moments, action, observed)
        if refit == "latest":
            model = LinearModel(model.gain, observed - model.gain * action)
        elif refit == "all":
            model = fit_model(moments, initial_model, prior_weight)
        controller = update_controller(controller, model, action, observed, moments)
        record = (
            action,
            observed,
            observed - desired,
            model.gain,
            model.offset,
            controller.offset,
            controller.gain,
        )
        return (controller, model, moments), record

    _, records = jax.lax.scan(one_iteration, (controller, model, moments), None, length=num_iters)
    return IterationTrace(*records)


def iterated_action_map(
    name: str,
    system: TrueSystem,
    model: LinearModel,
    desired,
    actions,
    *,
    inner_steps: int | None = None,
    learning_rate=0.1,
):
    """One rollout ``tau_{k+1} = T(tau_k)`` of :func:`iterate` with a fixed model, per ``tau_k``.

    Its fixed point is :func:`fixed_point`'s ``action``.

    Args:
      name: one of :data:`THEORY_LOSSES` (``"supervised"`` keeps its action: no refit).
      system: a :class:`TrueSystem` of scalars.
      model: the fixed :class:`LinearModel` (scalars).
      desired: ``s_d`` (scalar).
      actions: ``tau_k``, shape ``(n,)``.
      inner_steps: gradient steps per update (``None``: to rest).
      learning_rate: step size of those steps.

    Examples:
      >>> nxt = iterated_action_map("joint", TrueSystem(), LinearModel(1.0, 0.2), 1.0,
      ...                           jnp.array([0.0, 0.6]))
      >>> [round(float(a), 4) for a in nxt]  # ((s_d + h(tau)) / 2 - b_hat) / a_hat
      [0.3, 0.6]
    """

    def next_action(action):
        trace = iterate(
            name,
            system,
            model,
            AffineController(action, 0.0),
            desired,
            num_iters=1,
            inner_steps=inner_steps,
            learning_rate=learning_rate,
        )
        return trace.controller_offsets[0]

    return jax.vmap(next_action)(actions)


# ----------------------------------------------------------------------------- sweep


def sweep_model_bias(
    system: TrueSystem,
    desired,
    gain_ratios,
    offset_errors,
    *,
    refit: str = "none",
    num_iters: int = 50,
    inner_steps: int | None = None,
    distal_steps: int = 5,
    learning_rate=0.1,
) -> dict[str, jax.Array]:
    """Fixed points and iterated errors per loss over a grid of model biases, in one ``vmap``.

    Every loss starts from the task loss's rest ``(s_d - b_hat) / a_hat`` (the supervised
    controller as the biased model's inverse) on the model :func:`biased_model` gives.

    Args:
      system: a :class:`TrueSystem` of scalars.
      desired: ``s_d`` (scalar).
      gain_ratios: ``a_hat / a`` of the grid, shape ``(G,)``.
      offset_errors: ``b_hat - b`` of the grid, shape ``(O,)``.
      refit: ``"none"`` or ``"latest"``.
      num_iters: rollouts run for the iterated error.
      inner_steps: gradient steps per update of the other losses (``None``: to rest).
      distal_steps: gradient steps per update of the distal-teacher loss.
      learning_rate: step size of those steps.

    Returns:
      Arrays of shape ``(G * O,)``: ``gain_ratio``, ``offset_error`` and per loss ``L``:
      ``L_action``, ``L_error``, ``L_contraction`` (:class:`FixedPoint`) and
      ``L_iterated_error`` (the last rollout's error of :func:`iterate`).

    Raises:
      ValueError: ``refit="all"``, which forgets the initial model's bias.

    Examples:
      >>> table = sweep_model_bias(TrueSystem(), 1.0, gain_ratios=[1.0, 2.0],
      ...                          offset_errors=[0.0, 0.2], num_iters=20)
      >>> [round(float(e), 3) for e in table["task_error"]]  # (1 - b_hat) / a_hat - 1
      [0.0, -0.2, -0.5, -0.6]
    """
    if refit == "all":
        raise ValueError("refit='all' does not depend on the initial model's bias")
    grid_gain, grid_offset = jnp.meshgrid(
        jnp.asarray(gain_ratios), jnp.asarray(offset_errors), indexing="ij"
    )

    def one_case(gain_ratio, offset_error):
        model = biased_model(system, gain_ratio, offset_error)
        inverse = AffineController(-model.offset / model.gain, 1.0 / model.gain)
        start = AffineController(controller_action(inverse, desired), 0.0)
        row = {}
        for name in THEORY_LOSSES:
            steps = distal_steps if name == "distal" else inner_steps
            controller = inverse if name == "supervised" else start
            fp = fixed_point(
                name,
                system,
                model,
                desired,
                refit=refit,
                inner_steps=steps,
                learning_rate=learning_rate,
                controller=inverse,
            )
            trace = iterate(
                name,
                system,
                model,
                controller,
                desired,
                num_iters=num_iters,
                refit=refit,
                inner_steps=steps,
                learning_rate=learning_rate,
            )
            row[f"{name}_action"] = fp.action
            row[f"{name}_error"] = fp.error
            row[f"{name}_contraction"] = fp.contraction
            row[f"{name}_iterated_error"] = trace.errors[-1]
        return row

    table = jax.jit(jax.vmap(one_case))(grid_gain.ravel(), grid_offset.ravel())
    return {"gain_ratio": grid_gain.ravel(), "offset_error": grid_offset.ravel(), **table}


def observed_goal_fixed_point(
    name: str,
    system: TrueSystem,
    model: LinearModel,
    desired,
    controller_gain,
    newton_iterations: int = 40,
) -> FixedPoint:
    """Fixed point of Algorithm 1 with ``g`` trained on the observed goal and a fixed model.

    Training the offset to rest pins ``f(g(s_a))`` at ``s_d`` (task) or ``(s_d + s_a) / 2``
    (joint), while the rollout reads ``g(s_d) = g(s_a) + beta_1 (s_d - s_a)``; the resulting
    equations, errors and contractions: docs/theory.md ("The observed goal").

    Args:
      name: ``"task"`` or ``"joint"``.
      system: a :class:`TrueSystem` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      controller_gain: ``beta_1``, the controller's slope in its goal (held).
      newton_iterations: Newton steps (one is exact for a linear system).

    Raises:
      ValueError: ``name`` is not ``task`` or ``joint``.

    Examples:
      >>> fp = observed_goal_fixed_point("joint", TrueSystem(), LinearModel(1.0, 0.2),
      ...                                desired=1.0, controller_gain=1.0)
      >>> round(float(fp.error), 4), round(float(fp.contraction), 4)  # 2 e_task / 3, -1/2
      (-0.1333, -0.5)
    """
    if name not in ("task", "joint"):
        raise ValueError(f"observed_goal_fixed_point: loss={name!r} not in ('task', 'joint')")
    beta_1 = jnp.asarray(controller_gain, dtype=jnp.result_type(float))
    pull = model.gain * beta_1

    def residual(action):
        outcome = true_response(system, action)
        if name == "task":
            return model_prediction(model, action) - desired + pull * (outcome - desired)
        return (
            2.0 * model_prediction(model, action)
            - outcome
            - desired
            + 2.0 * pull * (outcome - desired)
        )

    def newton_step(_, action):
        return action - residual(action) / jax.grad(residual)(action)

    start = (jnp.asarray(desired, dtype=jnp.result_type(float)) - model.offset) / model.gain
    action = jax.lax.fori_loop(0, newton_iterations, newton_step, start)
    slope = true_slope(system, action)
    if name == "task":
        contraction = -beta_1 * slope
    else:
        contraction = slope * (0.5 / model.gain - beta_1)
    return FixedPoint(action, true_response(system, action) - desired, contraction)
