"""The paper's 1-D argument (section III-B/C) as a tool: where each controller loss rests.

Bechtle et al. argue with ``s_p = f_theta(s, g_beta(s, s_d))`` that the task loss rests where
the (possibly biased) forward model predicts the desired state, while the joint loss rests at
``s_p = (s_d + s_a) / 2`` and, iterated with data collection (Algorithm 1), is pushed to
``s_a = s_d``. This module makes every piece of that argument computable, so that it can be
checked, including where it fails.

The 1-D world (the state ``s`` is constant and dropped):

* true system ``s_a = h(tau) = a tau + b + c tau^3`` (:class:`TrueSystem`); ``c != 0`` makes a
  linear model misspecified;
* forward model ``s_p = f(tau) = a_hat tau + b_hat`` (:class:`LinearModel`); its bias is the
  gain ratio ``a_hat / a`` and the offset error ``b_hat - b``;
* controller ``tau = g(s_target) = beta_0 + beta_1 s_target`` (:class:`AffineController`).

The controller losses are those of :mod:`cfm_jax.losses` (task, joint, distal, supervised),
applied to the composition ``f o g`` and differentiated with ``jax.grad``.

Two readings of ``s_a`` (the docs say which result uses which):

* **rollout** (Algorithm 1): ``s_a = h(tau_run)`` is observed with the action executed in the
  last rollout and held fixed while ``g`` is trained;
* **consistent**: ``s_a = h(tau)`` is the system's response to the *current* action, treated
  as data (no gradient flows through ``h``). Its rest points are the fixed points of the
  rollout iteration.

Closed forms (linear system ``c = 0``, one desired state ``s_d``; ``e = s_a - s_d``):

* task rest: ``tau = (s_d - b_hat) / a_hat``, error ``e_task = a (s_d - b_hat) / a_hat + b - s_d``;
* joint rest for a held ``s_a``: ``tau = ((s_d + s_a) / 2 - b_hat) / a_hat``; fixed point of
  the iteration with a fixed model: ``tau* = (s_d - 2 b_hat + b) / (2 a_hat - a)``, error
  ``e_joint = e_task * 2 a_hat / (2 a_hat - a)``, contraction ``a / (2 a_hat)``;
* distal teacher: no rest for a held ``s_a`` (the loss is linear in ``s_p``); ``n`` gradient
  steps of size ``eta`` give ``e_{k+1} = (1 - 2 n eta a a_hat) e_k``, fixed point ``e = 0``;
* model offset refitted on the latest observation (gain kept): task
  ``e_{k+1} = (1 - a / a_hat) e_k``, joint ``e_{k+1} = (1 - a / (2 a_hat)) e_k``, both to 0.

For the nonlinear system replace ``a`` by the local slope ``h'(tau*)``; fixed points are then
found with Newton's method (:func:`consistent_rest_action`).

Examples:
  >>> system = TrueSystem(gain=1.0, offset=0.0)
  >>> model = LinearModel(gain=1.0, offset=0.2)        # offset bias 0.2
  >>> fp = fixed_point("joint", system, model, desired=1.0)
  >>> round(float(fp.error), 3), round(float(fp.contraction), 3)
  (-0.4, 0.5)
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from cfm_jax import losses

THEORY_LOSSES = ("task", "joint", "distal", "supervised")
"""Controller losses studied here, in the order results are reported."""

MODEL_BASED_LOSSES = ("task", "joint", "distal")
"""Losses that go through the forward model (``f o g``)."""

GOALS = ("desired", "observed")
"""The controller's goal while it is trained (``Config.controller.goal``): ``g(s_d)`` (the
paper's eq. 4) or ``g(s_a)`` (the authors' public Solo12 code); see
:func:`observed_goal_fixed_point`."""

REFIT_MODES = ("none", "latest", "all")
"""How the forward model (and the supervised controller) is refitted after each rollout:

* ``"none"``: never, the model stays as given (fixed bias);
* ``"latest"``: only the offset is refitted so the model passes through the latest
  observation ``(tau_k, s_a_k)``; the gain is kept (one point identifies one parameter);
* ``"all"``: least squares on all data so far (babbling data plus every rollout), with an
  optional ridge pull of strength ``prior_weight`` towards the initial model.
"""


class TrueSystem(NamedTuple):
    """True 1-D actuator ``s_a = gain * tau + offset + cubic * tau^3``.

    ``cubic != 0`` makes the linear :class:`LinearModel` a misspecified model class.
    Fields may be scalars or arrays (for ``vmap``).

    Attributes:
      gain: ``a``, the linear gain.
      offset: ``b``, the response to ``tau = 0``.
      cubic: ``c``, the cubic coefficient (0: a linear system).

    Examples:
      >>> system = TrueSystem(gain=2.0, offset=1.0, cubic=0.5)
      >>> float(true_response(system, 2.0))  # 2 * 2 + 1 + 0.5 * 8
      9.0
    """

    gain: jax.Array | float = 1.0
    offset: jax.Array | float = 0.0
    cubic: jax.Array | float = 0.0


class LinearModel(NamedTuple):
    """Forward model ``s_p = gain * tau + offset`` (``a_hat``, ``b_hat``).

    Attributes:
      gain: ``a_hat``, the model's gain.
      offset: ``b_hat``, the model's offset.

    Examples:
      >>> float(model_prediction(LinearModel(gain=2.0, offset=0.5), 1.0))
      2.5
    """

    gain: jax.Array | float = 1.0
    offset: jax.Array | float = 0.0


class AffineController(NamedTuple):
    """Controller ``tau = offset + gain * s_target`` (``beta_0``, ``beta_1``).

    Attributes:
      offset: ``beta_0``, the action for ``s_target = 0``.
      gain: ``beta_1``, the action's slope in the target.

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
      error: actual error ``h(tau*) - s_d``.
      contraction: derivative of the error map ``e_{k+1}(e_k)`` at the fixed point; the
        iteration converges locally iff ``|contraction| < 1``, geometrically with this rate.
        NaN where the map has no such factor (``refit="all"``).

    Examples:
      >>> fp = fixed_point("task", TrueSystem(), LinearModel(1.0, 0.2), desired=1.0)
      >>> round(float(fp.action), 3), round(float(fp.error), 3), float(fp.contraction)
      (0.8, -0.2, 0.0)
    """

    action: jax.Array
    error: jax.Array
    contraction: jax.Array


class IterationTrace(NamedTuple):
    """Per-iteration record of :func:`iterate`, every field of shape ``(num_iters,)``.

    ``actions[k]`` is ``tau_k`` executed in rollout ``k``, ``observed[k] = h(tau_k)``,
    ``errors[k] = observed[k] - s_d``; ``model_*`` is the model after the refit that follows
    rollout ``k``; ``controller_*`` is the controller after the update that follows it.

    Attributes:
      actions: ``tau_k``, the action executed in rollout ``k``.
      observed: ``s_a_k = h(tau_k)``.
      errors: ``s_a_k - s_d``.
      model_gains: ``a_hat`` after the refit that follows rollout ``k``.
      model_offsets: ``b_hat`` after that refit.
      controller_offsets: ``beta_0`` after the controller update that follows rollout ``k``.
      controller_gains: ``beta_1`` after that update.

    Examples:
      >>> tr = iterate("task", TrueSystem(), LinearModel(1.0, 0.2), AffineController(),
      ...              1.0, num_iters=3)
      >>> tr.actions.shape
      (3,)
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
    """Sufficient statistics of pairs ``(x, y)`` = ``(tau, s_a)`` for least-squares lines.

    Every field is a scalar (float, so that it can be a ``scan`` carry).

    Attributes:
      count: the number of pairs ``n``.
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
    """``s_a = a tau + b + c tau^3``, the true system's response.

    Args:
      system: a :class:`TrueSystem` (scalars, or arrays broadcasting with ``action``).
      action: ``tau``, any shape.

    Returns:
      ``s_a``, the broadcast shape of ``action`` and the system's fields.

    Examples:
      >>> float(true_response(TrueSystem(2.0, 1.0, 0.5), 2.0))
      9.0
    """
    return system.gain * action + system.offset + system.cubic * action**3


def true_slope(system: TrueSystem, action):
    """``h'(tau) = a + 3 c tau^2``, the true system's local gain.

    Args:
      system: a :class:`TrueSystem` (scalars, or arrays broadcasting with ``action``).
      action: ``tau``, any shape.

    Returns:
      ``h'(tau)``, the broadcast shape.

    Examples:
      >>> float(true_slope(TrueSystem(gain=1.0, cubic=0.5), 2.0))  # 1 + 3 * 0.5 * 4
      7.0
    """
    return system.gain + 3.0 * system.cubic * jnp.square(action)


def model_prediction(model: LinearModel, action):
    """``s_p = a_hat tau + b_hat``, the forward model's prediction.

    Args:
      model: a :class:`LinearModel` (scalars, or arrays broadcasting with ``action``).
      action: ``tau``, any shape.

    Returns:
      ``s_p``, the broadcast shape.

    Examples:
      >>> float(model_prediction(LinearModel(gain=2.0, offset=0.5), 1.0))
      2.5
    """
    return model.gain * action + model.offset


def controller_action(controller: AffineController, target):
    """``tau = beta_0 + beta_1 s_target``, the controller's action.

    Args:
      controller: an :class:`AffineController` (scalars, or arrays broadcasting with
        ``target``).
      target: ``s_target``, any shape.

    Returns:
      ``tau``, the broadcast shape.

    Examples:
      >>> import jax.numpy as jnp
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

    Returns:
      ``f(tau) - h(tau)``, the broadcast shape.

    Examples:
      >>> round(float(model_error(TrueSystem(1.0, 0.0), LinearModel(1.0, 0.2), 3.0)), 6)
      0.2
    """
    return model_prediction(model, action) - true_response(system, action)


def biased_model(system: TrueSystem, gain_ratio=1.0, offset_error=0.0) -> LinearModel:
    """Linear model with gain ``gain_ratio * a`` and offset ``b + offset_error``.

    The model ignores ``system.cubic``; with ``gain_ratio=1, offset_error=0`` it is exact for
    a linear system.

    Args:
      system: the :class:`TrueSystem` whose gain and offset are biased.
      gain_ratio: ``a_hat / a`` (scalar or array).
      offset_error: ``b_hat - b`` (scalar or array).

    Returns:
      the biased :class:`LinearModel` (fields broadcast as the arguments do).

    Examples:
      >>> biased_model(TrueSystem(2.0, 1.0), gain_ratio=0.5, offset_error=0.1)
      LinearModel(gain=1.0, offset=1.1)
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
    """A model-based controller loss of :mod:`cfm_jax.losses` on ``s_p = f(g(s_d))``.

    ``task``: ``(s_p - s_d)^2``; ``joint``: ``(s_p - s_d)^2 + (s_p - s_a)^2``;
    ``distal``: ``(s_p - s_d)^2 - (s_p - s_a)^2`` (:func:`cfm_jax.losses.distal_literal`:
    with ``s_a`` held, its gradient is the distal teacher's ``2 f' g' (s_a - s_d)`` at every
    step, the paper's 1-D argument; the bounded :func:`cfm_jax.losses.distal` of the
    learning loop has that gradient at the action that was run).

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      controller: an :class:`AffineController` (scalars, or arrays broadcasting with the
        data).
      model: a :class:`LinearModel` (likewise).
      desired: ``s_d``, shape ``(...)``.
      observed: ``s_a``, shape ``(...)``, held fixed.
      goal: ``"desired"`` (``s_p = f(g(s_d))``, the paper) or ``"observed"``
        (``s_p = f(g(s_a))``, the authors' Solo12 code, ``controller.goal``); the targets
        are the same.
    Returns:
      loss of shape ``(...)``.

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
    """Supervised inverse loss ``(g(s_a) - tau_run)^2`` (:func:`cfm_jax.losses.supervised`).

    The controller is fed the observed next state ``s_a`` in place of the desired one.

    Args:
      controller: an :class:`AffineController` (scalars, or arrays broadcasting with the
        data).
      observed: ``s_a``, shape ``(...)``.
      executed_action: ``tau_run``, the action that produced ``s_a``, shape ``(...)``.

    Returns:
      loss of shape ``(...)``.

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
    """``dL/dbeta`` by ``jax.grad`` through ``f o g`` (scalar data).

    For ``task``/``joint`` this equals the paper's ``2 f' g' (s_p - s_d)`` and
    ``2 f' g' (2 s_p - s_d - s_a)`` with ``f' = a_hat`` and ``g' = (1, s_d)``; for ``distal``
    ``2 f' g' (s_a - s_d)``. For ``supervised`` (which needs ``executed_action``) it is
    ``2 (g(s_a) - tau_run) (1, s_a)``.

    Args:
      name: one of :data:`THEORY_LOSSES`.
      controller: an :class:`AffineController` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      observed: ``s_a`` (scalar), held fixed.
      executed_action: ``tau_run`` (scalar), used by the supervised loss.
      goal: ``"desired"`` or ``"observed"`` (:func:`controller_loss`); with ``observed``
        the task and joint gradients are ``2 f' (s_p - s_d) (1, s_a)`` and
        ``2 f' (2 s_p - s_d - s_a) (1, s_a)`` with ``s_p = f(g(s_a))``.
    Returns:
      an :class:`AffineController` holding ``(dL/dbeta_0, dL/dbeta_1)``.

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
    """Model-based loss as a function of the action ``tau`` (controller ``beta_0 = tau``).

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      observed: ``s_a`` (scalar), held fixed.
      actions: the actions ``tau`` to evaluate, shape ``(n,)``.

    Returns:
      ``(loss, dloss/dtau)``, each of shape ``(n,)``; the gradient is ``jax.grad``'s.

    Examples:
      >>> import jax.numpy as jnp
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
    """Rollout reading: the action where the loss's gradient vanishes, ``s_a`` held fixed.

    ``task``: ``f(tau) = s_d``  ->  ``tau = (s_d - b_hat) / a_hat``;
    ``joint``: ``f(tau) = (s_d + s_a) / 2``  ->  ``tau = ((s_d + s_a)/2 - b_hat) / a_hat``;
    ``distal``: the gradient ``2 a_hat (s_a - s_d)`` does not depend on ``tau``: no rest
    unless ``s_a = s_d`` (returns NaN).

    Args:
      name: ``"task"``, ``"joint"`` or ``"distal"``.
      model: a :class:`LinearModel` (scalars or broadcasting arrays).
      desired: ``s_d`` (scalar or array).
      observed: ``s_a`` (scalar or array), held fixed.

    Returns:
      ``tau``, the broadcast shape.

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

    Equivalently the fixed point of the rollout iteration with a fixed model.
    ``task``: ``f(tau) = s_d``; ``joint``: ``2 f(tau) - h(tau) = s_d``; ``distal`` and
    ``supervised``: ``h(tau) = s_d``. Closed form for ``c = 0``
    (joint: ``tau = (s_d - 2 b_hat + b) / (2 a_hat - a)``); otherwise Newton's method
    (derivative by ``jax.grad``) from ``initial_action`` (default: the closed form of the
    system with ``c`` set to 0). With ``c != 0`` the joint equation is cubic and can have up to
    three roots; Newton returns the one it reaches from the start.

    Args:
      name: one of :data:`THEORY_LOSSES`.
      system: a :class:`TrueSystem` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      initial_action: Newton's starting point (scalar); ``None``: the closed form above.
      newton_iterations: Newton steps taken when ``system.cubic != 0``.

    Returns:
      ``tau*`` (scalar; NaN or inf where there is no root, e.g. ``2 a_hat = a`` for the joint
      loss).

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
    """Closed-form fixed point of the iterated Algorithm 1 and its contraction factor.

    The iteration (see :func:`iterate`): roll out ``tau_k``, observe ``s_a = h(tau_k)``,
    refit, update the controller with ``s_a`` held fixed (to rest, or ``n = inner_steps``
    gradient steps of size ``eta = learning_rate`` on ``beta_0``). With ``a' = h'(tau*)``,
    ``rho = 1 - eta * k * a_hat^2`` (``k = 2`` task, ``4`` joint; ``rho^n = 0`` to rest):

    ============  ================================  =========================================
    loss          ``refit="none"``                  ``refit="latest"`` (offset through last point)
    ============  ================================  =========================================
    task          ``f(tau*) = s_d``, ``rho^n``      ``h(tau*) = s_d``, ``1 - (1-rho^n) a'/a_hat``
    joint         ``2f - h = s_d``,                 ``h(tau*) = s_d``,
                  ``rho^n + (1-rho^n) a'/(2a_hat)``  ``1 - (1-rho^n) a'/(2 a_hat)``
    distal        ``h(tau*) = s_d``,                same
                  ``1 - 2 n eta a' a_hat``
    supervised    ``tau* = g_0(s_d)``, ``0``        ``h(tau*) = s_d``, ``1 - a' beta_1``
    ============  ================================  =========================================

    ``refit="all"`` (least squares on all data): the rollouts pile up at the fixed point, so
    every loss's limit is ``h(tau*) = s_d`` if the iteration converges; the rate is
    sublinear when the model class is misspecified, so ``contraction`` is NaN.

    Args:
      name: one of :data:`THEORY_LOSSES`.
      system: a :class:`TrueSystem` of scalars (``vmap`` for arrays).
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d``.
      refit: one of :data:`REFIT_MODES`.
      inner_steps: ``None`` trains to rest (not possible for ``distal``, which needs steps).
      learning_rate: step size of the inner gradient steps.
      controller: initial controller, used by ``supervised`` (its ``tau* = g_0(s_d)`` without
        refit and its gain ``beta_1`` with ``refit="latest"``).
    Returns:
      :class:`FixedPoint`.

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
    """Sufficient statistics of the pairs ``(tau_i, s_a_i)``.

    Args:
      actions: ``tau_i``, shape ``(n,)``.
      observed: ``s_a_i``, shape ``(n,)``.

    Returns:
      :class:`DataMoments` of scalars.

    Examples:
      >>> m = data_moments([0.0, 1.0], [1.0, 3.0])
      >>> float(m.count), float(m.sum_y), float(m.sum_yy)
      (2.0, 4.0, 10.0)
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

    Solves the 2x2 normal equations
    ``[[Sxx + w, Sx], [Sx, n + w]] [k, m] = [Sxy + w k0, Sy + w m0]``.

    Args:
      count: ``n``, the number of pairs.
      sum_x: ``Sx = sum_i x_i``.
      sum_xx: ``Sxx = sum_i x_i^2``.
      sum_y: ``Sy = sum_i y_i``.
      sum_xy: ``Sxy = sum_i x_i y_i``.
      prior_slope: ``k0``, the slope the ridge term pulls towards.
      prior_intercept: ``m0``, the intercept it pulls towards.
      prior_weight: ``w >= 0``; with ``w = 0`` plain least squares (which needs two distinct
        ``x``).

    Returns:
      ``(slope k, intercept m)``, scalars (or arrays, broadcast as the arguments).

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
      prior_weight: ridge weight ``w`` (:func:`fit_line`); 0: plain least squares.

    Returns:
      the fitted :class:`LinearModel`.

    Examples:
      >>> m = data_moments([0.0, 1.0, 2.0], [1.0, 3.0, 5.0])
      >>> fit = fit_model(m, LinearModel())
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
    """Supervised inverse model: least squares ``tau ~ beta_0 + beta_1 s_a`` (closed form of
    minimising :func:`cfm_jax.losses.supervised` over the data, ridge towards ``prior``).

    Args:
      moments: :class:`DataMoments` of the pairs ``(tau_i, s_a_i)``.
      prior: the :class:`AffineController` the ridge term pulls towards.
      prior_weight: ridge weight ``w`` (:func:`fit_line`); 0: plain least squares.

    Returns:
      the fitted :class:`AffineController`.

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
    """Algorithm 1 in 1-D: roll out, observe, (refit), update the controller; repeat.

    Iteration ``k``: execute ``tau_k = g_k(s_d)``, observe ``s_a_k = h(tau_k)``, add the pair
    to the data, refit the model (``refit``), then update the controller with ``s_a_k`` held
    fixed (rollout reading):

    * ``task``/``joint``/``distal``: ``beta_0`` (the action for this target) follows
      ``jax.grad`` of the library loss through ``f o g``: to rest by Newton's method
      (``inner_steps=None``; exact in one step since the loss is quadratic in ``beta_0``) or
      ``inner_steps`` gradient steps of size ``learning_rate``; ``beta_1`` is not trained
      (one target identifies one parameter);
    * ``supervised``: ``refit="none"`` keeps ``controller``; ``"latest"`` sets ``beta_0`` so
      that ``g(s_a_k) = tau_k`` (gain kept); ``"all"`` fits ``g`` to all pairs by least
      squares (:func:`fit_inverse`).

    Args:
      name: one of :data:`THEORY_LOSSES`.
      system: the :class:`TrueSystem` (scalars).
      model: the initial :class:`LinearModel` (scalars).
      controller: the initial :class:`AffineController` (scalars).
      desired: ``s_d`` (scalar).
      num_iters: number of rollouts ``K``.
      refit: one of :data:`REFIT_MODES`.
      inner_steps: gradient steps of the controller update per iteration (``None``: to
        rest, see above).
      learning_rate: step size of those gradient steps.
      babble_actions: actions of the motor-babbling data set (shape ``(n,)``), used by
        ``refit="all"``; with ``None`` the only data are the rollouts.
      prior_weight: ridge weight pulling ``refit="all"`` fits towards the initial model and
        controller (needed when fewer than two distinct actions have been seen).
    Returns:
      :class:`IterationTrace` with fields of shape ``(num_iters,)``.

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
    """One iteration ``tau_{k+1} = T(tau_k)`` with a fixed model (``refit="none"``).

    Runs :func:`iterate` for one rollout from each ``tau_k`` in ``actions``; its fixed point
    is :func:`fixed_point`'s ``action``.

    Args:
      name: one of :data:`THEORY_LOSSES` (``"supervised"`` keeps its action: the controller
        is not updated without a refit).
      system: a :class:`TrueSystem` of scalars.
      model: the fixed :class:`LinearModel` (scalars).
      desired: ``s_d`` (scalar).
      actions: ``tau_k``, shape ``(n,)``.
      inner_steps: gradient steps of the controller update (``None``: to rest).
      learning_rate: step size of those gradient steps.

    Returns:
      ``tau_{k+1}``, shape ``(n,)``.

    Examples:
      >>> import jax.numpy as jnp
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
    """Fixed points, errors and iterated errors per loss over a grid of model biases.

    One ``vmap`` over the flattened grid ``gain_ratio x offset_error`` (model
    ``a_hat = gain_ratio * a``, ``b_hat = b + offset_error``, see :func:`biased_model`).
    Every loss starts from the same action, the task loss's rest ``(s_d - b_hat) / a_hat``
    (the supervised controller starts as the biased model's inverse, ``beta_1 = 1 / a_hat``,
    which gives that action). ``distal`` uses ``distal_steps`` gradient steps per iteration,
    the others ``inner_steps`` (``None``: to rest).

    Args:
      system: a :class:`TrueSystem` of scalars.
      desired: ``s_d`` (scalar).
      gain_ratios: ``a_hat / a`` of the grid, shape ``(G,)``.
      offset_errors: ``b_hat - b`` of the grid, shape ``(O,)``.
      refit: ``"none"`` or ``"latest"`` (``"all"`` forgets the initial model's bias).
      num_iters: rollouts run to measure the iterated error.
      inner_steps: gradient steps per controller update of the task, joint and supervised
        losses (``None``: to rest).
      distal_steps: gradient steps per controller update of the distal-teacher loss.
      learning_rate: step size of those gradient steps.

    Returns:
      dict of arrays of shape ``(G * O,)``: ``gain_ratio``, ``offset_error`` and for each loss
      ``L``: ``L_action`` (``tau*``), ``L_error`` (``h(tau*) - s_d``), ``L_contraction``,
      ``L_iterated_error`` (error of the last rollout of :func:`iterate`).

    Raises:
      ValueError: ``refit="all"``.

    Examples:
      >>> table = sweep_model_bias(TrueSystem(), 1.0, gain_ratios=[1.0, 2.0],
      ...                          offset_errors=[0.0, 0.2], num_iters=20)
      >>> table["joint_error"].shape
      (4,)
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
    """Fixed point of Algorithm 1 when the controller is trained on the *observed* goal
    (``controller.goal="observed"``) with a fixed model: roll out ``tau_k = g(s_d)``, observe
    ``s_a = h(tau_k)``, train the offset ``beta_0`` to rest on the loss of ``s_p = f(g(s_a))``
    (gain ``beta_1 = controller_gain`` held).

    The rest of training pins ``g`` at the observed goal only: ``f(g(s_a)) = s_d`` (task)
    or ``(s_d + s_a) / 2`` (joint). The run-time action is read at the desired goal,
    ``g(s_d) = g(s_a) + beta_1 (s_d - s_a)``, so the fixed point ``s_a = h(tau*)`` solves

    * task: ``f(tau) - s_d + a_hat beta_1 (h(tau) - s_d) = 0``,
    * joint: ``2 f(tau) - h(tau) - s_d + 2 a_hat beta_1 (h(tau) - s_d) = 0``,

    and the action map ``tau_{k+1}(tau_k)`` has the slope (the contraction) ``-beta_1 a'``
    (task) or ``a' (1 / (2 a_hat) - beta_1)`` (joint), ``a' = h'(tau*)``. For a linear system
    the errors are ``e = e_task / (1 + a beta_1)`` (task) and ``e = 2 a_hat e_task / (2 a_hat
    - a + 2 a a_hat beta_1)`` (joint), with ``e_task`` the desired goal's task error; with
    ``beta_1 = 0`` (a controller that ignores its goal) both are the desired goal's.

    Args:
      name: ``"task"`` or ``"joint"``.
      system: a :class:`TrueSystem` of scalars.
      model: a :class:`LinearModel` of scalars.
      desired: ``s_d`` (scalar).
      controller_gain: ``beta_1``, the controller's slope in its goal (held).
      newton_iterations: Newton steps (exact in one for a linear system).

    Returns:
      :class:`FixedPoint`.

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
