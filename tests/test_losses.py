"""Losses (cfm_jax/learning/losses.py) against hand-derived values and the paper's 1-D gradients.

Oracles: values computed by hand on small arrays (written out below), and the 1-D gradient
formulas of paper section III-B for the composition ``s_p = f(g(beta))`` with ``g = beta``
(``g' = 1``) and ``f = w g`` (``f' = w``), i.e. ``s_p = w beta``:
  task   dL/dbeta = 2 f' g' (s_p - s_d)
  joint  dL/dbeta = 2 f' g' (2 s_p - s_d - s_a)
  distal dL/dbeta = 2 f' g' (s_a - s_d)   (the bounded form at g = tau_run; the literal form
                                         everywhere)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax.learning import losses

# Small float32 inputs with exactly representable values: the hand-computed results are
# small integers or binary fractions, so float32 arithmetic reproduces them exactly. Where a
# transcendental (exp) is involved the tolerance is a few float32 ulps (rtol 1e-6).
P = jnp.array([[1.0, 2.0], [0.5, -1.0]])  # predicted, (2 samples, d=2)
D = jnp.array([[3.0, 0.0], [0.5, 1.0]])  # desired
A = jnp.array([[0.0, 2.0], [-1.5, -1.0]])  # actual / observed


def test_task_loss_values():
    # sample 0: (1-3)^2 + (2-0)^2 = 8 ; sample 1: 0^2 + (-2)^2 = 4
    out = jax.jit(losses.task)(P, D)
    assert out.shape == (2,)
    np.testing.assert_array_equal(np.asarray(out), [8.0, 4.0])


def test_joint_loss_values():
    # |p-d|^2 = [8, 4]; |p-a|^2: sample 0: 1 + 0 = 1 ; sample 1: 2^2 + 0 = 4 -> [9, 8]
    out = jax.jit(losses.joint)(P, D, A)
    np.testing.assert_array_equal(np.asarray(out), [9.0, 8.0])


R = jnp.array([[0.5, 2.0], [1.0, 0.0]])  # predicted for the action that was run


def test_distal_literal_loss_values():
    # |p-d|^2 - |p-a|^2 = [8 - 1, 4 - 4] = [7, 0]
    out = jax.jit(losses.distal_literal)(P, D, A)
    np.testing.assert_array_equal(np.asarray(out), [7.0, 0.0])


def test_distal_loss_values():
    # |p - r + a - d|^2: sample 0: p - r = (0.5, 0), + a - d = (-3, 2) -> (-2.5, 2): 6.25 + 4
    # = 10.25 ; sample 1: p - r = (-0.5, -1), + a - d = (-2, -2) -> (-2.5, -3): 6.25 + 9 = 15.25
    out = jax.jit(losses.distal)(P, R, D, A)
    np.testing.assert_array_equal(np.asarray(out), [10.25, 15.25])


def test_supervised_loss_values():
    # (1-3)^2 + (2-0)^2 = 8 ; (0.5-0.5)^2 + (-1-1)^2 = 4
    out = jax.jit(losses.supervised)(P, D)
    np.testing.assert_array_equal(np.asarray(out), [8.0, 4.0])


def test_squared_error_values_and_batch_shape():
    # Leading batch axes are kept, the last one is summed: (3, 2, d) -> (3, 2).
    stacked_p = jnp.stack([P, P, D])
    stacked_t = jnp.stack([D, A, D])
    out = jax.jit(losses.squared_error)(stacked_p, stacked_t)
    assert out.shape == (3, 2)
    np.testing.assert_array_equal(np.asarray(out), [[8.0, 4.0], [1.0, 4.0], [0.0, 0.0]])


def test_gaussian_nll_values():
    mean = jnp.array([[0.0, 1.0]])
    log_var = jnp.array([[0.0, np.log(4.0)]])
    target = jnp.array([[2.0, 3.0]])
    # (2-0)^2 e^0 + 0 + (3-1)^2 / 4 + log 4 = 4 + 1 + log 4
    expected = 5.0 + np.log(4.0)
    out = jax.jit(losses.gaussian_nll)(mean, log_var, target)
    assert out.shape == (1,)
    np.testing.assert_allclose(np.asarray(out), [expected], rtol=1e-6)  # exp/log: few ulps


def test_gaussian_nll_mean_gradient_is_scaled_squared_error_gradient():
    # For fixed variance, d/dmean NLL = -2 (t - m) exp(-lv) = exp(-lv) * d/dmean |m - t|^2.
    mean = jnp.array([0.3, -1.2, 2.0])
    log_var = jnp.array([0.7, -0.4, 1.1])
    target = jnp.array([1.0, 0.5, -0.25])
    g_nll = jax.grad(lambda m: losses.gaussian_nll(m, log_var, target))(mean)
    hand = -2.0 * (np.asarray(target) - np.asarray(mean)) * np.exp(-np.asarray(log_var))
    np.testing.assert_allclose(np.asarray(g_nll), hand, rtol=1e-6)  # float32 exp: few ulps
    # and d/dlv = 1 - (t - m)^2 exp(-lv)
    g_lv = jax.grad(lambda lv: losses.gaussian_nll(mean, lv, target))(log_var)
    hand_lv = 1.0 - np.square(np.asarray(target - mean)) * np.exp(-np.asarray(log_var))
    np.testing.assert_allclose(np.asarray(g_lv), hand_lv, rtol=1e-6, atol=1e-6)


# ---- 1-D gradients of the controller losses (paper section III-B) ---------------------------

# (w, beta, s_d, s_a): f' = w, g' = 1, s_p = w beta. Several signs and magnitudes.
CASES = [
    (2.0, 0.5, 3.0, -1.0),
    (-0.5, 1.5, 0.25, 2.0),
    (1.25, -2.0, -1.0, 0.5),
]


def _grad_1d(loss_name, w, beta, s_d, s_a, tau_run=None):
    def loss(b):
        s_p = jnp.array([w * b])  # f(g(beta)) with g(beta) = beta, f(g) = w g
        run = None if tau_run is None else jnp.array([w * tau_run])  # f(tau_run)
        return losses.controller_loss(
            loss_name, s_p, jnp.array([s_d]), jnp.array([s_a]), predicted_run=run
        )

    return float(jax.jit(jax.grad(loss))(jnp.float32(beta)))


@pytest.mark.parametrize("w, beta, s_d, s_a", CASES)
def test_1d_gradients_match_paper_formulas(w, beta, s_d, s_a):
    s_p = w * beta
    f_prime, g_prime = w, 1.0
    expected = {
        "task": 2 * f_prime * g_prime * (s_p - s_d),
        "joint": 2 * f_prime * g_prime * (2 * s_p - s_d - s_a),
        "distal_literal": 2 * f_prime * g_prime * (s_a - s_d),
    }
    for name, value in expected.items():
        # Inputs are binary fractions: the products are exact in float32 up to 1 rounding.
        np.testing.assert_allclose(
            _grad_1d(name, w, beta, s_d, s_a), value, rtol=1e-6, err_msg=name
        )
    # The bounded distal teacher at g = tau_run (tau_run = beta here, as g = beta): the
    # paper's distal gradient.
    np.testing.assert_allclose(
        _grad_1d("distal", w, beta, s_d, s_a, tau_run=beta),
        2 * f_prime * g_prime * (s_a - s_d),
        rtol=1e-6,
    )


def test_distal_gradient_at_the_run_action_nonlinear_1d():
    """The bounded distal loss through a nonlinear model and controller: at g = tau_run its
    gradient is 2 (df/dg)(dg/dbeta)(s_a - s_d), derived by hand:

    g(beta) = beta^2 x (x = 1.5 the controller input), f(s, tau) = s + 0.5 tau^3 (s = 0.25).
    dg/dbeta = 2 beta x; df/dg = 1.5 g^2. At beta = 0.5: g = 0.375, dg/dbeta = 1.5,
    df/dg = 1.5 * 0.140625 = 0.2109375; with s_a = 2, s_d = 1: 2 * 0.2109375 * 1.5 * 1
    = 0.6328125. Away from tau_run the gradient differs (the loss is not linear in s_p).
    """
    x, s, s_d, s_a = 1.5, 0.25, 1.0, 2.0
    f = lambda tau: s + 0.5 * tau**3  # noqa: E731
    g = lambda beta: beta**2 * x  # noqa: E731

    def grad(beta, tau_run):
        def loss(b):
            return losses.distal(
                jnp.array([f(g(b))]), jnp.array([f(tau_run)]), jnp.array([s_d]), jnp.array([s_a])
            )

        return float(jax.jit(jax.grad(loss))(jnp.float32(beta)))

    np.testing.assert_allclose(grad(0.5, tau_run=0.375), 0.6328125, rtol=1e-6)
    # Literal and bounded forms agree there; elsewhere only the literal stays at it.
    literal = jax.grad(
        lambda b: losses.distal_literal(jnp.array([f(g(b))]), jnp.array([s_d]), jnp.array([s_a]))
    )(jnp.float32(0.5))
    np.testing.assert_allclose(float(literal), 0.6328125, rtol=1e-6)
    assert abs(grad(0.9, tau_run=0.375) - 2 * 1.5 * (0.9**2 * x) ** 2 * 2 * 0.9 * x) > 0.1


def test_distal_loss_is_bounded_below_and_literal_is_not():
    """For a held (r, a, d) the bounded loss is >= 0 with minimum 0 at s_p = r - (a - d); the
    literal loss is linear in s_p, |p-d|^2 - |p-a|^2 = 2 p (a - d) + d^2 - a^2, and decreases
    without bound as p -> -inf (here a > d)."""
    r, a, d = jnp.array([0.5]), jnp.array([2.0]), jnp.array([1.0])
    grid = jnp.linspace(-1e3, 1e3, 20001)[:, None]
    bounded = losses.distal(grid, r, d, a)
    assert float(bounded.min()) >= 0.0
    np.testing.assert_allclose(float(losses.distal(r - (a - d), r, d, a)), 0.0)
    literal = losses.distal_literal(grid, d, a)
    # 2 p (a - d) + d^2 - a^2 at p = -1000: -2000 - 3 = -2003, and lower for lower p.
    np.testing.assert_allclose(float(literal.min()), -2003.0)
    assert float(losses.distal_literal(jnp.array([-1e6]), d, a)) < -1e6


def test_1d_supervised_gradient():
    # L = (g - tau)^2 with g = w beta: dL/dbeta = 2 g' (g - tau), g' = w.
    w, beta, tau = 1.5, -0.5, 2.0
    grad = jax.grad(lambda b: losses.supervised(jnp.array([w * b]), jnp.array([tau])))(
        jnp.float32(beta)
    )
    np.testing.assert_allclose(float(grad), 2 * w * (w * beta - tau), rtol=1e-6)


def test_distal_gradient_independent_of_model_bias():
    # With a biased model s_p = w beta + bias, the (literal) distal gradient does not depend on the
    # bias, the task gradient does (it rests where the *model* hits s_d).
    def grad(name, bias):
        def loss(b):
            s_p = jnp.array([2.0 * b + bias])
            return losses.controller_loss(name, s_p, jnp.array([1.0]), jnp.array([3.0]))

        return float(jax.grad(loss)(jnp.float32(0.5)))

    assert grad("distal_literal", 0.0) == grad("distal_literal", 7.0) == 2 * 2.0 * (3.0 - 1.0)
    assert grad("task", 0.0) != grad("task", 7.0)


# ---- dispatch ------------------------------------------------------------------------------


def test_controller_loss_dispatch():
    np.testing.assert_array_equal(
        np.asarray(losses.controller_loss("task", P, D, A)), np.asarray(losses.task(P, D))
    )
    np.testing.assert_array_equal(
        np.asarray(losses.controller_loss("joint", P, D, A)), np.asarray(losses.joint(P, D, A))
    )
    np.testing.assert_array_equal(
        np.asarray(losses.controller_loss("distal_literal", P, D, A)),
        np.asarray(losses.distal_literal(P, D, A)),
    )
    np.testing.assert_array_equal(
        np.asarray(losses.controller_loss("distal", P, D, A, predicted_run=R)),
        np.asarray(losses.distal(P, R, D, A)),
    )
    with pytest.raises(ValueError, match="predicted_run"):
        losses.controller_loss("distal", P, D, A)


@pytest.mark.parametrize("name", ["supervised", "Joint", "mse", ""])
def test_controller_loss_unknown_name(name):
    with pytest.raises(ValueError) as info:
        losses.controller_loss(name, P, D, A)
    message = str(info.value)
    assert repr(name) in message
    for allowed in ("'task'", "'joint'", "'distal'", "'distal_literal'"):
        assert allowed in message
