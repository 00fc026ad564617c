"""Model updates: minibatch gradient steps under ``lax.scan`` with Optax, pure and jittable.

:func:`fit_forward` fits the forward model by its own ``objective`` (the ensemble's: Gaussian
NLL, each member on its own minibatches); :func:`fit_controller` fits the controller by
:func:`controller_objective`, differentiated in the controller's parameters only, so a
controller loss never changes the forward model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from cfm_jax import dataset, losses


def controller_objective(
    controller_params,
    forward_params,
    loss,
    forward,
    controller,
    normaliser,
    batch,
    goal: str = "desired",
    groups=None,
    weights=None,
):
    """Mean controller loss over a minibatch, in normalised units (the controller's training loss).

    Model-based losses (``loss.forward``) compare ``s_p = f(s, g(s, s*))`` (ensemble mean)
    with ``s*`` (:func:`cfm_jax.losses.controller_loss`); the others, like ``supervised``,
    compare ``g(s, P s_a)`` with ``tau_run`` in the forward model's scaled torque units (a
    norm in the ``norm`` form).
    ``goal="observed"`` gives ``g`` the observed ``P s_a`` for ``s*``; see docs/concepts/losses.md.

    Args:
      controller_params: the controller's parameters (differentiated).
      forward_params: the forward ensemble's parameters (held fixed).
      loss: a registered :class:`cfm_jax.losses.Loss` or its name (:func:`cfm_jax.losses.get`).
      forward: the forward :class:`cfm_jax.networks.Model`.
      controller: the controller :class:`cfm_jax.networks.Model`.
      normaliser: the :class:`cfm_jax.networks.Normaliser`.
      batch: :class:`cfm_jax.dataset.Transitions` ``(batch, ...)``.
      goal: ``"desired"`` or ``"observed"`` (static; else ValueError).
      groups: None (``squared`` form) or the ``norm`` form's groups (static).
      weights: None (a plain mean) or ``(batch,)`` row weights: ``sum w L / max(sum w, 1)``.

    Examples:
      >>> from cfm_jax import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> theta, beta = fm.init(jax.random.key(0), 4), g.init(jax.random.key(1), 4)
      >>> grads = jax.grad(controller_objective)(beta, theta, "joint", fm, g, norm, rows)
      >>> jax.tree.structure(grads) == jax.tree.structure(beta)
      True
    """
    if goal not in ("desired", "observed"):
        raise ValueError(f"goal={goal!r} is not allowed: 'desired' or 'observed'")
    loss = losses.get(loss)
    if not loss.forward:
        achieved = normaliser.select(batch.observed)
        predicted = controller.apply(controller_params, normaliser, batch.state, achieved)
        # In the scaled torque space the forward model's input uses (tau / S, T^-1 tau, or
        # the limits): a unit error there moves every joint alike, so the wrist's small
        # torques weigh as much as the shoulder's large ones.
        predicted, executed = normaliser.torque(predicted), normaliser.torque(batch.action)
        distance = losses.supervised if groups is None else _norm_distance
        return _mean(loss.fn(predicted, executed, distance), weights)
    goal_input = batch.desired if goal == "desired" else normaliser.select(batch.observed)
    tau = controller.apply(controller_params, normaliser, batch.state, goal_input)
    predicted = forward.predict(forward_params, normaliser, batch.state, tau, terms=batch.terms)
    predicted_run = None
    if loss.run:  # f(s, tau_run): no controller parameter in it
        predicted_run = forward.predict(
            forward_params, normaliser, batch.state, batch.action, terms=batch.terms
        )
    per_sample = losses.controller_loss(
        loss,
        predicted,
        normaliser.desired(batch.desired),
        normaliser.output(batch.observed),
        select=None if normaliser.desired_index is None else normaliser.select,
        predicted_run=predicted_run,
        groups=groups,
        desired_index=normaliser.desired_index,
    )
    return _mean(per_sample, weights)


def _norm_distance(x, y):
    """The ``norm`` form's distance between actions: ``|x - y|``."""
    return losses.safe_norm(x - y)


def _mean(per_sample, weights):
    """``jnp.mean(per_sample)``, or its mean weighted by ``weights`` (rows of weight 0 out)."""
    if weights is None:
        return jnp.mean(per_sample)
    per_sample = jnp.where(weights > 0, per_sample, 0.0)  # a NaN in an empty row stays out
    return jnp.sum(weights * per_sample) / jnp.maximum(jnp.sum(weights), 1.0)


def fit_forward(forward, optimizer, params, opt_state, normaliser, data, key, steps, batch_size):
    """``steps`` optimiser steps of the forward model's ``objective`` under ``lax.scan``.

    Args:
      forward: the forward :class:`cfm_jax.networks.Model`.
      optimizer: an ``optax`` optimiser.
      params: its parameters.
      opt_state: ``optimizer``'s state for them.
      normaliser: the :class:`cfm_jax.networks.Normaliser`.
      data: the :class:`cfm_jax.dataset.Dataset` to sample from.
      key: PRNG key.
      steps: number of steps (static; 0 returns the inputs and a NaN loss).
      batch_size: rows per minibatch; each step draws ``forward.batches(params)`` (static).

    Returns:
      ``(params, opt_state, mean loss over the steps)``.

    Examples:
      >>> from cfm_jax import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> data = dataset.add(dataset.empty(16, state_dim=4, nv=2), rows)
      >>> params, opt = fm.init(jax.random.key(0), 4), optax.adam(1e-2)
      >>> params, state, first = fit_forward(fm, opt, params, opt.init(params), norm, data,
      ...                                    jax.random.key(1), steps=20, batch_size=4)
      >>> _, _, later = fit_forward(fm, opt, params, state, norm, data, jax.random.key(2),
      ...                           steps=20, batch_size=4)
      >>> bool(later < first)
      True
    """
    batches = forward.batches(params)

    def one_step(carry, step_key):
        params, opt_state = carry
        keys = jax.random.split(step_key, batches)
        batch = jax.vmap(lambda k: dataset.sample(data, k, batch_size))(keys)
        value, grads = jax.value_and_grad(forward.objective)(params, normaliser, batch)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), value

    (params, opt_state), values = jax.lax.scan(
        one_step, (params, opt_state), jax.random.split(key, steps)
    )
    return params, opt_state, jnp.mean(values) if steps else jnp.float32(jnp.nan)


def fit_controller(
    loss,
    forward,
    controller,
    optimizer,
    params,
    opt_state,
    forward_params,
    normaliser,
    data,
    key,
    steps,
    batch_size,
    goal="desired",
    groups=None,
    full_batch=False,
):
    """``steps`` optimiser steps of :func:`controller_objective` in the controller's parameters.

    Args:
      loss: a registered :class:`cfm_jax.losses.Loss` or its name (static).
      forward: the forward :class:`cfm_jax.networks.Model`.
      controller: the controller :class:`cfm_jax.networks.Model`.
      optimizer: an ``optax`` optimiser.
      params: the controller's parameters.
      opt_state: ``optimizer``'s state for them.
      forward_params: the forward ensemble's parameters (not changed).
      normaliser: the :class:`cfm_jax.networks.Normaliser`.
      data: the :class:`cfm_jax.dataset.Dataset` to sample from.
      key: PRNG key.
      steps: number of steps (static; 0 returns the inputs and a NaN loss).
      batch_size: rows per step (static; not used with ``full_batch``).
      goal: ``"desired"`` or ``"observed"`` (static; :func:`controller_objective`).
      groups: None (``squared`` form) or the ``norm`` form's groups (static).
      full_batch: False: a minibatch drawn with replacement per step; True: every row of the
        buffer, its empty rows weighted 0 (static).

    Returns:
      ``(params, opt_state, mean loss over the steps)``.

    Examples:
      >>> from cfm_jax import networks
      >>> norm = networks.Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
      >>> rows = dataset.Transitions(*(jnp.ones((10, d)) for d in (4, 2, 2, 2)))
      >>> data = dataset.add(dataset.empty(16, state_dim=4, nv=2), rows)
      >>> g = networks.controller(hidden=(8,), nv=2)
      >>> beta, opt = g.init(jax.random.key(1), 4), optax.adam(1e-3)
      >>> beta, state, loss = fit_controller("task", fm, g, opt, beta, opt.init(beta),
      ...                                    fm.init(jax.random.key(0), 4), norm, data,
      ...                                    jax.random.key(2), steps=5, batch_size=4)
      >>> loss.shape
      ()
    """

    filled = None
    if full_batch:
        filled = (jnp.arange(data.capacity) < data.size).astype(jnp.float32)

    def one_step(carry, step_key):
        params, opt_state = carry
        batch = data.data if full_batch else dataset.sample(data, step_key, batch_size)
        value, grads = jax.value_and_grad(controller_objective)(
            params,
            forward_params,
            loss,
            forward,
            controller,
            normaliser,
            batch,
            goal,
            groups,
            filled,
        )
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), value

    (params, opt_state), values = jax.lax.scan(
        one_step, (params, opt_state), jax.random.split(key, steps)
    )
    return params, opt_state, jnp.mean(values) if steps else jnp.float32(jnp.nan)
