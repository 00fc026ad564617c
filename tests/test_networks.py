"""Forward ensemble, controller and normaliser (cfm_jax/learning/networks.py).

Oracles: the documented bounds (torque limits; the PETS soft log-variance bounds, whose
worst-case overshoot is derived below), applying each member's parameters on its own, and
numpy statistics of the unmasked rows.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax.learning import networks

STATE_DIM, NV = 4, 2
LIMIT = jnp.array([20.0, 10.0])


def normaliser():
    return networks.Normaliser.identity(STATE_DIM, NV, LIMIT)


def test_controller_outputs_within_torque_limits_for_large_inputs():
    ctrl = networks.controller(hidden=(16, 16), nv=NV)
    params = ctrl.init(jax.random.key(0), STATE_DIM)
    key_s, key_d = jax.random.split(jax.random.key(1))
    state = 1e4 * jax.random.normal(key_s, (256, STATE_DIM))
    desired = 1e4 * jax.random.normal(key_d, (256, NV))
    tau = jax.jit(ctrl.apply)(params, normaliser(), state, desired)
    assert tau.shape == (256, NV)
    assert np.all(np.isfinite(np.asarray(tau)))
    # tanh saturates to exactly +-1 in float32 for these inputs, so |tau| <= limit (equal at
    # saturation): the bound is exact, no tolerance.
    assert np.all(np.abs(np.asarray(tau)) <= np.asarray(LIMIT))
    # and the squashing is really used: large inputs reach (near) the limits on both joints
    assert np.all(np.max(np.abs(np.asarray(tau)), axis=0) > 0.99 * np.asarray(LIMIT))


def test_controller_is_limit_times_tanh_of_mlp():
    # Changing only the torque limit scales the output proportionally.
    ctrl = networks.controller(hidden=(8,), nv=NV)
    params = ctrl.init(jax.random.key(2), STATE_DIM)
    s, d = jnp.linspace(-1, 1, STATE_DIM), jnp.array([0.3, -0.7])
    a = ctrl.apply(params, networks.Normaliser.identity(STATE_DIM, NV, jnp.ones(NV)), s, d)
    b = ctrl.apply(params, normaliser(), s, d)
    np.testing.assert_allclose(np.asarray(b), np.asarray(a) * np.asarray(LIMIT), rtol=1e-6)
    assert np.all(np.abs(np.asarray(a)) < 1.0)


@pytest.mark.parametrize("scale", [1.0, 1e3, 1e6])
def test_forward_log_variance_within_learned_bounds(scale):
    low, high = -10.0, 0.5
    fm = networks.forward_model(
        hidden=(16,), ensemble_size=3, nv=NV, min_log_variance=low, max_log_variance=high
    )
    params = fm.init(jax.random.key(0), STATE_DIM)
    # Learned bounds: move them away from the initial values to check the learned ones count.
    params["max_log_variance"] = jnp.array([1.0, -1.0])
    params["min_log_variance"] = jnp.array([-3.0, -5.0])
    key_s, key_t = jax.random.split(jax.random.key(3))
    state = scale * jax.random.normal(key_s, (500, STATE_DIM))
    tau = scale * jax.random.normal(key_t, (500, NV))
    mean, log_var = jax.jit(fm.apply)(params, normaliser(), state, tau)
    assert mean.shape == log_var.shape == (3, 500, NV)
    lv = np.asarray(log_var, np.float64)
    upper = np.asarray(params["max_log_variance"], np.float64)
    lower = np.asarray(params["min_log_variance"], np.float64)
    assert np.all(np.isfinite(lv))
    # lv1 = max - softplus(max - raw) < max; lv = min + softplus(lv1 - min) > min. The second
    # softplus can overshoot max: softplus(x) = x + log(1 + e^-x) is increasing, so
    # lv <= max + log(1 + exp(-(max - min))) (PETS has the same overshoot). Float32 rounding
    # of values of size <= 5: allow 1e-5.
    overshoot = np.log1p(np.exp(-(upper - lower)))
    assert np.all(lv >= lower - 1e-5)
    assert np.all(lv <= upper + overshoot + 1e-5)
    if scale >= 1e3:
        # Huge inputs push the raw output to both extremes: the bounds are reached.
        assert np.any(lv < lower + 0.1) or np.any(lv > upper - 0.1)


def test_forward_per_member_equals_members_applied_separately():
    members = 3
    fm = networks.forward_model(hidden=(16, 8), ensemble_size=members, nv=NV)
    params = fm.init(jax.random.key(4), STATE_DIM)
    norm = networks.Normaliser(
        jnp.array([0.1, -0.2, 0.3, 0.0]),
        jnp.array([1.5, 0.5, 2.0, 1.0]),
        jnp.zeros(NV),
        jnp.ones(NV),
        LIMIT,
    )
    keys = jax.random.split(jax.random.key(5), 2)
    state = jax.random.normal(keys[0], (members, 7, STATE_DIM))
    tau = 5.0 * jax.random.normal(keys[1], (members, 7, NV))
    mean, log_var = jax.jit(fm.apply, static_argnames="per_member")(
        params, norm, state, tau, per_member=True
    )
    assert mean.shape == (members, 7, NV)
    for e in range(members):
        # A one-member ensemble holding member e's parameters, applied to member e's inputs.
        single = dict(params, members=jax.tree.map(lambda x, e=e: x[e : e + 1], params["members"]))
        m_e, lv_e = fm.apply(single, norm, state[e], tau[e])
        # Same float32 ops on the same numbers; vmap may reorder nothing here, but allow
        # 1e-6 relative for a possible different matmul blocking.
        np.testing.assert_allclose(np.asarray(mean[e]), np.asarray(m_e[0]), rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(
            np.asarray(log_var[e]), np.asarray(lv_e[0]), rtol=1e-6, atol=1e-6
        )
    # Without per_member every member sees the same input: member e's row differs from the
    # per-member result whenever the inputs differ.
    shared_mean, _ = fm.apply(params, norm, state[0], tau[0])
    np.testing.assert_allclose(
        np.asarray(shared_mean[0]), np.asarray(mean[0]), rtol=1e-6, atol=1e-6
    )
    assert not np.allclose(np.asarray(shared_mean[1]), np.asarray(mean[1]))


def test_forward_members_differ_and_predict_is_their_mean():
    fm = networks.forward_model(hidden=(8,), ensemble_size=4, nv=NV)
    params = fm.init(jax.random.key(6), STATE_DIM)
    s, t = jnp.ones((5, STATE_DIM)), jnp.ones((5, NV))
    mean, _ = fm.apply(params, normaliser(), s, t)
    assert not np.allclose(np.asarray(mean[0]), np.asarray(mean[1]))  # independent inits
    np.testing.assert_allclose(
        np.asarray(fm.predict(params, normaliser(), s, t)),
        np.asarray(mean).mean(axis=0),
        rtol=1e-6,
        atol=1e-7,  # float32 mean of 4 numbers
    )


def test_normaliser_from_data_with_weights_equals_numpy_of_unmasked_rows():
    rng = np.random.default_rng(0)
    n = 40
    states = rng.normal(2.0, 3.0, (n, STATE_DIM)).astype(np.float32)
    accel = rng.normal(-1.0, 0.5, (n, NV)).astype(np.float32)
    weights = rng.random(n) < 0.7
    # masked rows hold garbage, including non-finite values: they must not leak in
    states[~weights] = np.nan
    accel[~weights][:, 0] = np.inf
    accel[np.flatnonzero(~weights)[0]] = [np.inf, -np.inf]
    # a constant column: its std is floored at 1e-3
    states[:, 3] = np.where(weights, 7.0, np.nan)
    norm = jax.jit(networks.Normaliser.from_data)(
        jnp.asarray(states), jnp.asarray(accel), LIMIT, jnp.asarray(weights)
    )
    kept_s = states[weights].astype(np.float64)
    kept_a = accel[weights].astype(np.float64)
    # float32 sums of 30-odd numbers of size ~5: rtol 1e-5 (numpy in float64 as the oracle).
    np.testing.assert_allclose(np.asarray(norm.state_mean), kept_s.mean(0), rtol=1e-5)
    expected_std = np.maximum(kept_s.std(0), 1e-3)
    np.testing.assert_allclose(np.asarray(norm.state_std), expected_std, rtol=1e-5)
    assert float(norm.state_std[3]) == pytest.approx(1e-3)
    np.testing.assert_allclose(np.asarray(norm.output_mean), kept_a.mean(0), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(norm.output_std), kept_a.std(0), rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(norm.torque_limit), np.asarray(LIMIT))


def test_normaliser_from_data_without_weights_and_roundtrip():
    rng = np.random.default_rng(1)
    states = rng.normal(size=(25, STATE_DIM))
    accel = rng.normal(3.0, 2.0, size=(25, NV))
    norm = networks.Normaliser.from_data(jnp.asarray(states), jnp.asarray(accel), LIMIT)
    np.testing.assert_allclose(
        np.asarray(norm.state_mean), states.mean(0), rtol=1e-5, atol=1e-6
    )  # float32, values ~1: atol for means near 0
    np.testing.assert_allclose(np.asarray(norm.output_std), accel.std(0), rtol=1e-5)
    x = jnp.asarray(accel, jnp.float32)
    # output_inverse(output(x)) = x up to float32 rounding of values ~5: atol 1e-5
    np.testing.assert_allclose(np.asarray(norm.output_inverse(norm.output(x))), accel, atol=1e-5)
    z = np.asarray(norm.output(x))
    np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-5)
    np.testing.assert_allclose(z.std(0), 1.0, rtol=1e-5)
