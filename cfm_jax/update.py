"""Model updates: minibatch gradient steps under ``lax.scan`` with Optax.

* :func:`fit_forward`: the forward ensemble by Gaussian NLL (PETS), every member on its own
  minibatches, in normalised acceleration units.
* :func:`fit_controller`: the controller with the chosen controller loss. The gradient is
  taken with respect to the controller parameters only (``jax.grad`` of
  :func:`controller_objective` in its first argument), so the forward model is never
  changed by a controller loss.

All functions are pure and jittable; the loss name is a static Python string.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from cfm_jax import dataset, losses, networks

# Weight of the PETS penalty on the learned log-variance bounds.
LOG_VARIANCE_BOUND_PENALTY = 0.01


def forward_objective(forward_params, forward, normaliser, batch: dataset.Transitions):
    """Mean Gaussian NLL of the observed acceleration over members and minibatch rows.

    ``batch`` fields have a leading member axis ``(ensemble, batch, ...)``: member ``e`` is
    scored on ``batch[e]`` only.
    """

    mean, log_var = forward.apply(
        forward_params, normaliser, batch.state, batch.action, per_member=True
    )
    nll = losses.gaussian_nll(mean, log_var, normaliser.output(batch.observed))
    bounds = jnp.sum(forward_params["max_log_variance"]) - jnp.sum(
        forward_params["min_log_variance"]
    )
    return jnp.mean(nll) + LOG_VARIANCE_BOUND_PENALTY * bounds


def controller_objective(
    controller_params, forward_params, loss: str, forward, controller, normaliser, batch
):
    """Mean controller loss over a minibatch (normalised acceleration / torque units).

    * ``task``, ``joint``, ``distal``: through ``s_p = f(s, g(s, s*))`` (ensemble mean),
      with ``s*`` the desired and ``s_a`` the observed quantity of each transition (only
      the entries ``normaliser.desired_index`` of ``s_p`` and ``s_a`` are compared with
      ``s*``; see :func:`cfm_jax.losses.controller_loss`).
    * ``supervised``: ``|g(s, P s_a) - tau_run|^2`` with torques divided by their limits
      (``P s_a`` the observed values of the desired entries).
    """
    if loss == "supervised":
        achieved = normaliser.select(batch.observed)
        predicted = controller.apply(controller_params, normaliser, batch.state, achieved)
        scale = normaliser.torque_limit
        return jnp.mean(losses.supervised(predicted / scale, batch.action / scale))
    tau = controller.apply(controller_params, normaliser, batch.state, batch.desired)
    predicted = networks.ensemble_mean(forward, forward_params, normaliser, batch.state, tau)
    per_sample = losses.controller_loss(
        loss,
        predicted,
        normaliser.desired(batch.desired),
        normaliser.output(batch.observed),
        select=None if normaliser.desired_index is None else normaliser.select,
    )
    return jnp.mean(per_sample)


def fit_forward(forward, optimizer, params, opt_state, normaliser, data, key, steps, batch_size):
    """``steps`` Adam steps of :func:`forward_objective`; returns params, state, mean loss."""
    members = jax.tree.leaves(params["members"])[0].shape[0]

    def one_step(carry, step_key):
        params, opt_state = carry
        keys = jax.random.split(step_key, members)
        batch = jax.vmap(lambda k: dataset.sample(data, k, batch_size))(keys)
        value, grads = jax.value_and_grad(forward_objective)(params, forward, normaliser, batch)
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
):
    """``steps`` Adam steps of :func:`controller_objective` in the controller parameters."""

    def one_step(carry, step_key):
        params, opt_state = carry
        batch = dataset.sample(data, step_key, batch_size)
        value, grads = jax.value_and_grad(controller_objective)(
            params, forward_params, loss, forward, controller, normaliser, batch
        )
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), value

    (params, opt_state), values = jax.lax.scan(
        one_step, (params, opt_state), jax.random.split(key, steps)
    )
    return params, opt_state, jnp.mean(values) if steps else jnp.float32(jnp.nan)
