"""Tests of cfm_jax.analysis.theory against independent oracles.

Oracles: the paper's gradient formulas (section III-B/C), hand-derived closed forms, plain
Python loops of the iteration written with hand-derived updates (no JAX), and numpy's least
squares. Random cases come from a fixed seed. JAX runs in float32 here, so comparisons use
tolerances of a few hundred float32 ulps of O(1) quantities (1e-5) unless an amplification
factor is stated next to the tolerance.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax.analysis import theory
from cfm_jax.learning import losses

RNG_SEED = 20210301
F32_ATOL = 1e-5


def random_linear_cases(num_cases, gain_ratio_range=(0.6, 3.0), seed=RNG_SEED):
    """Linear systems and biased linear models with positive gains, ``a_hat / a`` in range."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(num_cases):
        a = rng.uniform(0.5, 2.0)
        b = rng.uniform(-1.0, 1.0)
        ratio = rng.uniform(*gain_ratio_range)
        system = theory.TrueSystem(a, b, 0.0)
        model = theory.LinearModel(ratio * a, b + rng.uniform(-0.5, 0.5))
        desired = rng.uniform(-2.0, 2.0)
        cases.append((system, model, desired))
    return cases


def h(system, tau):
    return system.gain * tau + system.offset + system.cubic * tau**3


def f(model, tau):
    return model.gain * tau + model.offset


# ----------------------------------------------------------------------------- gradients


def test_gradients_match_paper_formulas():
    rng = np.random.default_rng(RNG_SEED)
    grad = jax.jit(theory.controller_gradient, static_argnums=0)
    for _ in range(20):
        controller = theory.AffineController(rng.normal(), rng.normal())
        model = theory.LinearModel(rng.normal(), rng.normal())
        s_d, s_a = rng.normal(), rng.normal()
        s_p = f(model, controller.offset + controller.gain * s_d)
        dg_dbeta = np.array([1.0, s_d])  # g = beta_0 + beta_1 s_d
        f_prime = model.gain
        expected = {
            "task": 2 * f_prime * dg_dbeta * (s_p - s_d),
            "joint": 2 * f_prime * dg_dbeta * (2 * s_p - s_d - s_a),
            "distal": 2 * f_prime * dg_dbeta * (s_a - s_d),
        }
        for name, want in expected.items():
            got = grad(name, controller, model, s_d, s_a)
            scale = 1.0 + np.abs(want).max()
            np.testing.assert_allclose([got.offset, got.gain], want, atol=F32_ATOL * scale)
        tau_run = rng.normal()
        got = grad("supervised", controller, model, s_d, s_a, tau_run)
        g_of_observed = controller.offset + controller.gain * s_a
        want = 2 * (g_of_observed - tau_run) * np.array([1.0, s_a])
        np.testing.assert_allclose(
            [got.offset, got.gain], want, atol=F32_ATOL * (1 + np.abs(want).max())
        )


def test_losses_are_the_library_losses():
    controller = theory.AffineController(0.3, -0.7)
    model = theory.LinearModel(1.3, 0.2)
    s_d, s_a = 0.9, -0.4
    s_p = jnp.array([1.3 * (0.3 - 0.7 * 0.9) + 0.2])
    for name in theory.MODEL_BASED_LOSSES:
        # The theory's distal teacher is the paper's 1-D argument: the gradient 2 f' g'
        # (s_a - s_d) with s_a held, i.e. the literal form (losses.distal_literal).
        library = "distal_literal" if name == "distal" else name
        want = losses.controller_loss(library, s_p, jnp.array([s_d]), jnp.array([s_a]))
        got = theory.controller_loss(name, controller, model, s_d, s_a)
        np.testing.assert_allclose(got, want, rtol=1e-6)


def test_loss_landscape_gradient_is_derivative_of_loss():
    model = theory.LinearModel(0.8, 0.3)
    actions = jnp.linspace(-2.0, 2.0, 9)
    for name in theory.MODEL_BASED_LOSSES:
        loss, grad = jax.jit(theory.loss_landscape, static_argnums=0)(
            name, model, 1.0, -0.5, actions
        )
        # The loss is a polynomial of degree <= 2 in tau, so the central difference is exact
        # for ANY step up to rounding; a wide step keeps the rounding small. Its error is
        # that of the two float32 loss values divided by 2 step: a few ulps of max|loss|
        # (<= 9.6 at the shifted actions) / step. Bound used: 4 ulps, 4 * 1.2e-7 * 9.6 / 0.5
        # = 9e-6 for joint.
        # Measured (float32 CPU): 4.8e-7 at step 0.5 (2.0e-5 at step 1e-2, the old test's
        # step, which needed atol 2e-3).
        step = 0.5
        plus, _ = theory.loss_landscape(name, model, 1.0, -0.5, actions + step)
        minus, _ = theory.loss_landscape(name, model, 1.0, -0.5, actions - step)
        plus, minus = np.asarray(plus, np.float64), np.asarray(minus, np.float64)
        atol = 4 * np.finfo(np.float32).eps * max(np.abs(plus).max(), np.abs(minus).max()) / step
        np.testing.assert_allclose(grad, (plus - minus) / (2 * step), rtol=0, atol=atol)
        assert loss.shape == (9,)


@pytest.mark.parametrize("right_sign", [True, False])
def test_distal_descent_moves_actual_state_towards_desired(right_sign):
    """A small distal-teacher step moves s_a towards s_d iff the model's slope has h's sign."""
    rng = np.random.default_rng(RNG_SEED + 1)
    grad = jax.jit(theory.controller_gradient, static_argnums=0)
    for _ in range(20):
        system = theory.TrueSystem(rng.uniform(0.5, 2.0), rng.normal(), rng.uniform(0.0, 0.5))
        slope = rng.uniform(0.2, 3.0) * (1.0 if right_sign else -1.0)
        model = theory.LinearModel(slope, rng.normal())
        tau, s_d = rng.normal(), rng.normal()
        s_a = h(system, tau)
        controller = theory.AffineController(tau, 0.0)
        g = grad("distal", controller, model, s_d, s_a)
        new_tau = tau - 1e-3 * float(g.offset)
        before, after = abs(s_a - s_d), abs(h(system, new_tau) - s_d)
        assert (after < before) == right_sign


# ----------------------------------------------------------------------------- equilibria


def test_rest_action_zeroes_the_gradient_and_matches_closed_form():
    grad = jax.jit(theory.controller_gradient, static_argnums=0)
    for system, model, s_d in random_linear_cases(15):
        s_a = h(system, 0.3)
        for name, want in (
            ("task", (s_d - model.offset) / model.gain),
            ("joint", ((s_d + s_a) / 2 - model.offset) / model.gain),
        ):
            tau = theory.rest_action(name, model, s_d, s_a)
            np.testing.assert_allclose(tau, want, rtol=1e-5, atol=F32_ATOL)
            g = grad(name, theory.AffineController(tau, 0.0), model, s_d, s_a)
            assert abs(float(g.offset)) < 1e-4 * (1 + abs(model.gain)) ** 2
    assert np.isnan(theory.rest_action("distal", theory.LinearModel(1.0, 0.0), 1.0, 0.0))


def test_joint_fixed_point_closed_forms():
    """tau* = (s_d - 2 b_hat + b) / (2 a_hat - a) and e_joint = e_task 2 a_hat / (2 a_hat - a)."""
    for system, model, s_d in random_linear_cases(15):
        a, b, a_hat, b_hat = system.gain, system.offset, model.gain, model.offset
        joint = theory.fixed_point("joint", system, model, s_d)
        task = theory.fixed_point("task", system, model, s_d)
        np.testing.assert_allclose(
            joint.action, (s_d - 2 * b_hat + b) / (2 * a_hat - a), rtol=1e-5, atol=F32_ATOL
        )
        e_task = a * (s_d - b_hat) / a_hat + b - s_d
        np.testing.assert_allclose(task.error, e_task, rtol=1e-5, atol=F32_ATOL)
        # amplification 2 a_hat / (2 a_hat - a) <= 6 for a_hat / a >= 0.6
        np.testing.assert_allclose(
            joint.error, e_task * 2 * a_hat / (2 * a_hat - a), rtol=1e-5, atol=6 * F32_ATOL
        )
        np.testing.assert_allclose(joint.contraction, a / (2 * a_hat), rtol=1e-6)
        # with a right-sign gain above a / 2 the joint loss's error is never smaller
        assert abs(float(joint.error)) >= abs(float(task.error)) - 6 * F32_ATOL


def python_iteration(
    name, system, model, s_d, tau0, *, refit, inner_steps, learning_rate, num_iters, beta_1=None
):
    """Plain-Python Algorithm 1 with hand-written updates; returns the actions tau_k."""
    a_hat, b_hat = model.gain, model.offset
    tau, actions = tau0, []
    for _ in range(num_iters):
        actions.append(tau)
        s_a = h(system, tau)
        if refit == "latest":
            b_hat = s_a - a_hat * tau
        if name == "supervised":
            if refit == "latest":  # beta_0 = tau - beta_1 s_a, then act on s_d
                tau = tau + beta_1 * (s_d - s_a)
            continue
        if name == "distal":
            for _ in range(inner_steps):
                tau -= learning_rate * 2 * a_hat * (s_a - s_d)
            continue
        target = s_d if name == "task" else (s_d + s_a) / 2
        if inner_steps is None:
            tau = (target - b_hat) / a_hat
        else:
            weight = 1.0 if name == "task" else 2.0
            for _ in range(inner_steps):
                s_p = a_hat * tau + b_hat
                grad = 2 * a_hat * (s_p - s_d) + (weight - 1) * 2 * a_hat * (s_p - s_a)
                tau -= learning_rate * grad
    return np.array(actions)


LINEAR_CONFIGS = [
    ("task", "none", None),
    ("joint", "none", None),
    ("task", "none", 3),
    ("joint", "none", 3),
    ("distal", "none", 2),
    ("task", "latest", None),
    ("joint", "latest", None),
    ("joint", "latest", 4),
    ("distal", "latest", 3),
    ("supervised", "latest", None),
]


@pytest.mark.parametrize("name,refit,inner_steps", LINEAR_CONFIGS)
def test_closed_form_fixed_points_match_iteration(name, refit, inner_steps):
    learning_rate = 0.05
    iterate = jax.jit(theory.iterate, static_argnames=("name", "num_iters", "refit", "inner_steps"))
    checked = 0
    for system, model, s_d in random_linear_cases(12, gain_ratio_range=(0.8, 2.5)):
        beta_1 = 1.0 / model.gain
        controller = theory.AffineController(-model.offset * beta_1, beta_1)
        fp = theory.fixed_point(
            name,
            system,
            model,
            s_d,
            refit=refit,
            inner_steps=inner_steps,
            learning_rate=learning_rate,
            controller=controller,
        )
        lam = float(fp.contraction)
        if abs(lam) > 0.9:  # slowly or not converging for this draw: nothing to compare
            continue
        checked += 1
        tau0 = (controller.offset + beta_1 * s_d) if name == "supervised" else s_d + 0.7
        actions = python_iteration(
            name,
            system,
            model,
            s_d,
            tau0,
            refit=refit,
            inner_steps=inner_steps,
            learning_rate=learning_rate,
            num_iters=400,
            beta_1=beta_1,
        )
        np.testing.assert_allclose(actions[-1], fp.action, rtol=1e-5, atol=F32_ATOL)
        np.testing.assert_allclose(
            h(system, actions[-1]) - s_d, fp.error, rtol=1e-5, atol=F32_ATOL * (1 + system.gain)
        )
        # contraction factor = ratio of successive distances to the fixed point (linear map)
        gaps = actions[:4] - actions[-1]
        assert abs(gaps[0]) > 1e-3 or lam == 0.0
        if lam != 0.0:
            # lam is float32, rho = 1 - eta k a_hat^2 loses a few bits to cancellation
            np.testing.assert_allclose(gaps[1] / gaps[0], lam, rtol=1e-5, atol=1e-7)
            np.testing.assert_allclose(gaps[2] / gaps[1], lam, rtol=1e-5, atol=1e-7)
        elif lam == 0.0:
            np.testing.assert_allclose(gaps[1:], 0.0, atol=1e-9)
        start = controller if name == "supervised" else theory.AffineController(tau0, 0.0)
        trace = iterate(
            name,
            system,
            model,
            start,
            s_d,
            num_iters=400,
            refit=refit,
            inner_steps=inner_steps,
            learning_rate=learning_rate,
        )
        np.testing.assert_allclose(
            trace.actions[:5], actions[:5], rtol=1e-5, atol=F32_ATOL * 10
        )  # up to 1/(1-0.9) accumulated rounding
        np.testing.assert_allclose(trace.actions[-1], fp.action, rtol=1e-5, atol=F32_ATOL * 10)
    assert checked >= 5


def test_diverging_joint_iteration_when_model_gain_below_half():
    system = theory.TrueSystem(1.0, 0.0)
    model = theory.biased_model(system, gain_ratio=0.45)
    fp = theory.fixed_point("joint", system, model, 1.0)
    np.testing.assert_allclose(fp.contraction, 1.0 / 0.9, rtol=1e-6)
    trace = theory.iterate(
        "joint", system, model, theory.AffineController(2.0, 0.0), 1.0, num_iters=40
    )
    gaps = np.abs(np.asarray(trace.actions) - float(fp.action))
    assert gaps[-1] > 10 * gaps[0]


def test_cubic_consistent_rest_matches_python_iteration():
    """Misspecified model (linear model of a cubic actuator): Newton root vs iteration limit."""
    rng = np.random.default_rng(RNG_SEED + 2)
    rest = jax.jit(theory.consistent_rest_action, static_argnums=0)
    checked = 0
    for _ in range(20):
        system = theory.TrueSystem(
            rng.uniform(0.5, 1.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.2, 0.3)
        )
        model = theory.LinearModel(system.gain * rng.uniform(1.0, 2.0), rng.uniform(-0.5, 0.5))
        s_d = rng.uniform(-1.0, 1.0)
        for name in ("joint", "distal"):
            tau_star = float(rest(name, system, model, s_d))
            if name == "joint":
                lam = theory.true_slope(system, tau_star) / (2 * model.gain)
                tau = tau_star + 0.05
                for _ in range(300):
                    tau = ((s_d + h(system, tau)) / 2 - model.offset) / model.gain
            else:  # distal: h(tau*) = s_d; bisection on the monotone branch as oracle
                lam = 0.0
                lo, hi = tau_star - 0.3, tau_star + 0.3
                if (h(system, lo) - s_d) * (h(system, hi) - s_d) > 0:
                    continue
                for _ in range(200):
                    mid = 0.5 * (lo + hi)
                    if (h(system, lo) - s_d) * (h(system, mid) - s_d) <= 0:
                        hi = mid
                    else:
                        lo = mid
                tau = 0.5 * (lo + hi)
            if abs(lam) > 0.9:
                continue
            checked += 1
            np.testing.assert_allclose(tau_star, tau, rtol=1e-5, atol=F32_ATOL)
            fp = theory.fixed_point(name, system, model, s_d, inner_steps=1)
            np.testing.assert_allclose(fp.action, tau, rtol=1e-5, atol=F32_ATOL)
    assert checked >= 20


def test_refit_on_all_data_of_linear_system_is_exact():
    """Exact refit: task reaches s_d after one update; joint halves the error; supervised exact."""
    system = theory.TrueSystem(1.7, -0.3)
    babble = jnp.array([-1.0, 0.5, 1.0])
    start = theory.AffineController(2.0, 0.0)
    model = theory.LinearModel(0.9, 0.4)  # forgotten: the refit uses only data
    task = theory.iterate(
        "task", system, model, start, 0.8, num_iters=6, refit="all", babble_actions=babble
    )
    np.testing.assert_allclose(task.errors[1:], 0.0, atol=F32_ATOL)
    np.testing.assert_allclose(task.model_gains, 1.7, rtol=1e-5)
    joint = theory.iterate(
        "joint", system, model, start, 0.8, num_iters=6, refit="all", babble_actions=babble
    )
    errors = np.asarray(joint.errors)
    np.testing.assert_allclose(errors[1:] / errors[:-1], 0.5, rtol=1e-4)
    sup = theory.iterate(
        "supervised",
        system,
        model,
        theory.AffineController(),
        0.8,
        num_iters=3,
        refit="all",
        babble_actions=babble,
    )
    np.testing.assert_allclose(sup.errors[1:], 0.0, atol=F32_ATOL)
    np.testing.assert_allclose(sup.controller_gains, 1 / 1.7, rtol=1e-5)


def test_fit_line_matches_numpy_ridge():
    rng = np.random.default_rng(RNG_SEED + 3)
    x, y = rng.normal(size=7), rng.normal(size=7)
    prior, weight = (0.4, -0.2), 0.7
    design = np.vstack([np.column_stack([x, np.ones(7)]), np.sqrt(weight) * np.eye(2)])
    target = np.concatenate([y, np.sqrt(weight) * np.array(prior)])
    want = np.linalg.lstsq(design, target, rcond=None)[0]
    m = theory.data_moments(x, y)
    got = theory.fit_line(m.count, m.sum_x, m.sum_xx, m.sum_y, m.sum_xy, *prior, weight)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=F32_ATOL)
    inverse = theory.fit_inverse(m, theory.AffineController(), 0.0)
    np.testing.assert_allclose(
        [inverse.gain, inverse.offset], np.polyfit(y, x, 1), rtol=1e-4, atol=F32_ATOL
    )


def test_sweep_matches_single_fixed_points():
    system = theory.TrueSystem(1.2, 0.1, 0.0)
    gains, offsets = jnp.array([0.7, 1.0, 1.6]), jnp.array([-0.3, 0.0, 0.25])
    table = theory.sweep_model_bias(
        system, 0.9, gains, offsets, num_iters=200, distal_steps=5, learning_rate=0.05
    )
    assert table["joint_error"].shape == (9,)
    for i in range(9):
        model = theory.biased_model(system, table["gain_ratio"][i], table["offset_error"][i])
        for name in ("task", "joint"):
            fp = theory.fixed_point(name, system, model, 0.9)
            np.testing.assert_allclose(table[f"{name}_error"][i], fp.error, atol=F32_ATOL)
            np.testing.assert_allclose(
                table[f"{name}_iterated_error"][i], fp.error, atol=10 * F32_ATOL
            )  # contraction <= 0.72
        np.testing.assert_allclose(table["distal_iterated_error"][i], 0.0, atol=F32_ATOL)
    # exact model: every loss rests at the target
    exact = int(
        np.flatnonzero(
            (np.asarray(gains) == 1.0).repeat(3) & (np.tile(np.asarray(offsets), 3) == 0.0)
        )[0]
    )
    for name in theory.THEORY_LOSSES:
        assert abs(float(table[f"{name}_error"][exact])) < F32_ATOL


def test_invalid_arguments():
    system, model = theory.TrueSystem(), theory.LinearModel()
    with pytest.raises(ValueError, match="no rest point"):
        theory.fixed_point("distal", system, model, 1.0)
    with pytest.raises(ValueError, match="refit"):
        theory.fixed_point("task", system, model, 1.0, refit="sometimes")
    with pytest.raises(ValueError, match="no rest point"):
        theory.iterate("distal", system, model, theory.AffineController(), 1.0, num_iters=2)
