"""The authors' legged-training options (issue 30): the controller's goal in training, the
``norm`` loss form with coordinate weights, how refits start, full-batch controller fits.

Oracles: hand-computed loss values; a NumPy float64 implementation of the grouped norm and
its central finite differences; a hand-built batch whose goal entries are recognisable; plain
SGD on the filled rows' plain mean; the Adam step count (a warm fit continues it).
Networks are tiny and no rollout is compiled except in the one end-to-end test.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from cfm_jax import config as cfg
from cfm_jax.learning import algorithm, losses, networks
from cfm_jax.sim import dataset

GROUPS = ((1.0, (0, 1, 2)), (10.0, (2,)))


# ---- the norm form ---------------------------------------------------------------------------


def test_grouped_norm_hand_values():
    # p - s* = (0, 2, 0): |.| = 2, the weighted group (entry 2) 0.
    p, d, o = jnp.array([1.0, 2.0, 3.0]), jnp.array([1.0, 0.0, 3.0]), jnp.array([4.0, 2.0, -1.0])
    assert float(losses.controller_loss("task", p, d, o, groups=GROUPS)) == 2.0
    # p - s_a = (-3, 0, 4): 5 + 10 * 4 = 45; joint = 2 + 45.
    assert float(losses.controller_loss("joint", p, d, o, groups=GROUPS)) == 47.0
    # s* specifies entries (0, 2) of y: P p - s* = (1 - 1, 3 - 7) = (0, -4): 4 + 10 * 4.
    select = lambda y: y[..., jnp.array([0, 2])]  # noqa: E731
    task = losses.controller_loss(
        "task", p, jnp.array([1.0, 7.0]), o, select=select, groups=GROUPS, desired_index=(0, 2)
    )
    assert float(task) == 44.0
    # distal: P (p - p_run) + P s_a - s* = (1 - 0 + 4 - 1, 3 - 3 - 1 - 7) = (4, -8):
    # sqrt(80) + 10 * 8.
    run = jnp.array([0.0, 5.0, 3.0])
    distal = losses.controller_loss(
        "distal", p, jnp.array([1.0, 7.0]), o, select=select, predicted_run=run,
        groups=GROUPS, desired_index=(0, 2),
    )  # fmt: skip
    np.testing.assert_allclose(float(distal), np.sqrt(80.0) + 80.0, rtol=1e-6)


def test_legged_default_groups_are_the_authors_task_loss():
    # LeggedTask.loss_weights without loading the robot: nv 18, output 30 (18 + 4 feet x 3).
    from types import SimpleNamespace

    from cfm_jax.tasks.legged import LeggedTask

    fake = SimpleNamespace(robot=SimpleNamespace(nv=18), output_dim=30, BASE_WEIGHT=10.0)
    groups = LeggedTask.loss_weights(fake)
    rng = np.random.default_rng(0)
    p, d = rng.normal(size=30), rng.normal(size=30)
    # |v_p - v*| + |F_p - F*| + 10 |v_p[2:6] - v*[2:6]|, written out.
    authors = (
        np.linalg.norm(p[:18] - d[:18])
        + np.linalg.norm(p[18:] - d[18:])
        + 10 * np.linalg.norm(p[2:6] - d[2:6])
    )
    got = losses.controller_loss("task", jnp.asarray(p), jnp.asarray(d), None, groups=groups)
    np.testing.assert_allclose(float(got), authors, rtol=1e-5)


def _numpy_joint_norm(p, d, o):
    """The joint loss in the norm form, float64 NumPy (the oracle)."""
    total = 0.0
    for weight, index in GROUPS:
        i = list(index)
        total += weight * (np.linalg.norm(p[i] - d[i]) + np.linalg.norm(p[i] - o[i]))
    return total


def test_norm_gradient_matches_finite_differences():
    rng = np.random.default_rng(3)
    p, d, o = (rng.normal(size=3) for _ in range(3))
    grad = jax.grad(lambda x: losses.controller_loss("joint", x, d, o, groups=GROUPS))(
        jnp.asarray(p, jnp.float32)
    )
    h = 1e-6
    numeric = [
        (_numpy_joint_norm(p + h * e, d, o) - _numpy_joint_norm(p - h * e, d, o)) / (2 * h)
        for e in np.eye(3)
    ]
    np.testing.assert_allclose(np.asarray(grad), numeric, rtol=1e-5, atol=1e-6)


def test_norm_gradient_at_zero_error_is_zero_not_nan():
    p = jnp.array([1.0, 2.0, 3.0])
    grad = jax.grad(lambda x: losses.controller_loss("task", x, p, p, groups=GROUPS))(p)
    assert grad.tolist() == [0.0, 0.0, 0.0]


# ---- the goal g is given ---------------------------------------------------------------------


class _Recorder:
    """A controller whose ``apply`` records the goal it is given (tau = 0)."""

    def __init__(self):
        self.goals = []

    def init(self, key, state_dim):
        return {"b": jnp.zeros(2)}

    def apply(self, params, normaliser, state, desired):
        self.goals.append(np.asarray(desired))
        return jnp.zeros(state.shape[:-1] + (2,)) + params["b"]


@pytest.mark.parametrize("loss", ["task", "joint", "distal", "supervised"])
@pytest.mark.parametrize("goal", ["desired", "observed"])
def test_observed_goal_feeds_g_the_observed_entries(loss, goal):
    # Output y has 3 entries; s* specifies entries (1, 2) (as the operational-space task).
    batch = dataset.Transitions(
        state=jnp.zeros((2, 4)),
        desired=jnp.array([[-1.0, -2.0], [-3.0, -4.0]]),
        action=jnp.zeros((2, 2)),
        observed=jnp.array([[10.0, 20.0, 30.0], [40.0, 50.0, 60.0]]),
    )
    norm = networks.Normaliser.identity(4, 3, jnp.ones(2), desired_index=(1, 2))
    fm = networks.forward_model(hidden=(4,), ensemble_size=1, nv=3, action_dim=2)
    g = _Recorder()
    algorithm.controller_objective(
        g.init(None, 4), fm.init(jax.random.key(0), 4), loss, fm, g, norm, batch, goal=goal
    )
    observed_goal = [[20.0, 30.0], [50.0, 60.0]]
    expected = observed_goal if goal == "observed" or loss == "supervised" else batch.desired
    assert len(g.goals) == 1
    np.testing.assert_array_equal(g.goals[0], np.asarray(expected))


# ---- full batch ------------------------------------------------------------------------------


def test_full_batch_step_is_the_mean_over_the_filled_rows():
    rng = np.random.default_rng(5)
    rows = dataset.Transitions(
        *(jnp.asarray(rng.normal(size=(5, k)), jnp.float32) for k in (4, 2, 2, 2))
    )
    data = dataset.add(dataset.empty(8, 4, 2), rows)  # 5 of 8 rows filled
    norm = networks.Normaliser.identity(4, 2, jnp.array([2.0, 1.0]))
    fm = networks.forward_model(hidden=(8,), ensemble_size=2, nv=2)
    g = networks.controller(hidden=(8,), nv=2)
    theta, beta = fm.init(jax.random.key(0), 4), g.init(jax.random.key(1), 4)
    sgd = optax.sgd(0.1)
    for loss in ("joint", "supervised"):
        new, _, value = algorithm.fit_controller(
            loss, fm, g, sgd, beta, sgd.init(beta), theta, norm, data, jax.random.key(2),
            steps=1, batch_size=3, goal="observed", groups=((1.0, (0, 1)),), full_batch=True,
        )  # fmt: skip
        args = (theta, loss, fm, g, norm, rows, "observed", ((1.0, (0, 1)),))
        want_value, grads = jax.value_and_grad(algorithm.controller_objective)(beta, *args)
        want = jax.tree.map(lambda b, d: b - 0.1 * d, beta, grads)
        np.testing.assert_allclose(float(value), float(want_value), rtol=1e-6)
        for x, y in zip(jax.tree.leaves(new), jax.tree.leaves(want), strict=True):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-7)


# ---- how refits start ------------------------------------------------------------------------


def _tiny(**controller):
    fit = dict(hidden=(8,), initial_steps=5, steps_per_iteration=3, batch_size=16)
    forward = dict(fit, start=controller.get("start", "warm"))
    return cfg.Config(
        robot="two_link_arm",
        task=cfg.TaskConfig(duration=0.1),
        forward=cfg.ForwardModelConfig(ensemble_size=2, **forward),
        controller=cfg.ControllerConfig(**fit, **controller),
        loop=cfg.LoopConfig(iterations=1, babbling_rollouts=1),
    )


def _hand_state(setup, knobs):
    task = setup.task
    fp = algorithm.fresh_forward_params(setup, jax.random.key(10), knobs)
    cp = setup.controller.init(jax.random.key(11), task.state_dim)
    adam = optax.adam(1e-3)
    # Adam states that have taken 7 steps (count 7).
    fo = optax.tree_utils.tree_set(adam.init(fp), count=7)
    co = optax.tree_utils.tree_set(adam.init(cp), count=7)
    norm = networks.Normaliser.identity(task.state_dim, task.output_dim, setup.robot.torque_limit)
    data = dataset.empty(4, task.state_dim, task.desired_dim, task.action_dim, task.output_dim)
    return algorithm.TrainState(fp, fo, cp, co, norm, data, jax.random.key(0), jnp.int32(0))


def _count(opt_state):
    return int(optax.tree_utils.tree_get(opt_state, "count"))


def _same(a, b):
    return all(
        np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


@pytest.mark.parametrize("start", ["warm", "warm_new_optimizer", "fresh"])
def test_restart_fits(start):
    config = _tiny(start=start)
    setup = algorithm.Setup.of(config)
    knobs = algorithm.Knobs.of(config, setup.robot, setup.task)
    state = _hand_state(setup, knobs)
    key_fm, key_ctrl = jax.random.key(1), jax.random.key(2)
    new = algorithm.restart_fits(setup, state, key_fm, key_ctrl, knobs)
    for params, opt in (("forward_params", "forward_opt_state"),
                        ("controller_params", "controller_opt_state")):  # fmt: skip
        kept = _same(getattr(new, params), getattr(state, params))
        assert kept == (start != "fresh")
        assert _count(getattr(new, opt)) == (7 if start == "warm" else 0)
    if start == "fresh":  # deterministic: the same keys give the same parameters
        again = algorithm.restart_fits(setup, state, key_fm, key_ctrl, knobs)
        assert _same(again.controller_params, new.controller_params)
        assert _same(again.forward_params, new.forward_params)
        bounds = new.forward_params["max_log_variance"]
        assert np.all(np.asarray(bounds) == config.forward.max_log_variance)


@pytest.mark.parametrize(
    "controller, count",
    [
        (dict(), 5 + 3),  # today: Adam carried from the initial fit into the iteration's
        pytest.param(
            dict(start="warm_new_optimizer", goal="observed", loss_form="norm", full_batch=True),
            3,
            marks=pytest.mark.slow,
        ),
    ],
)
def test_iteration_adam_state_across_fits(controller, count):
    config = _tiny(**controller)
    setup = algorithm.Setup.of(config)
    knobs = algorithm.Knobs.of(config, setup.robot, setup.task)
    state = jax.jit(lambda k, kn: algorithm.init(setup, "joint", k, kn))(jax.random.key(0), knobs)
    assert _count(state.controller_opt_state) == 5
    before = state.controller_params
    state, out = jax.jit(lambda s, kn: algorithm.iteration(setup, "joint", s, kn))(state, knobs)
    assert _count(state.controller_opt_state) == count
    assert _count(state.forward_opt_state) == count
    assert np.isfinite(float(out["controller_loss"]))
    assert not _same(before, state.controller_params)


# ---- config ----------------------------------------------------------------------------------


def test_config_fields_validate_and_round_trip():
    config = cfg.Config(
        forward=cfg.ForwardModelConfig(start="fresh"),
        controller=cfg.ControllerConfig(
            goal="observed", loss_form="norm", loss_weights=[[1, [0, 1]], [10, [1]]],
            start="warm_new_optimizer", full_batch=True,
        ),
    )  # fmt: skip
    assert config.controller.loss_weights == ((1.0, (0, 1)), (10.0, (1,)))
    import json

    assert cfg.from_dict(json.loads(json.dumps(cfg.to_dict(config)))) == config
    assert cfg.structure(config) != cfg.structure(cfg.Config())
    bad = [
        ("controller.goal", dict(goal="target")),
        ("controller.loss_form", dict(loss_form="abs")),
        ("controller.start", dict(start="cold")),
        ("controller.full_batch", dict(full_batch=1)),
        ("controller.loss_weights", dict(loss_form="norm", loss_weights=((1.0, ()),))),
        ("controller.loss_weights", dict(loss_form="norm", loss_weights=((-1.0, (0,)),))),
        ("controller.loss_weights", dict(loss_form="squared", loss_weights=((1.0, (0,)),))),
    ]
    for field, kwargs in bad:
        with pytest.raises(cfg.ConfigError, match=field):
            cfg.ControllerConfig(**kwargs)
    with pytest.raises(cfg.ConfigError, match="forward.start"):
        cfg.ForwardModelConfig(start="cold")
    with pytest.raises(cfg.ConfigError, match="controller.loss_weights"):  # arm output: 2
        algorithm.Setup.of(_tiny(loss_form="norm", loss_weights=((1.0, (0, 2)),)))


# ---- 1-D theory of the observed goal ---------------------------------------------------------


@pytest.mark.parametrize("name", ["task", "joint"])
@pytest.mark.parametrize("cubic", [0.0, 0.1])
def test_observed_goal_fixed_point_matches_a_plain_loop(name, cubic):
    from cfm_jax.analysis import theory

    system = theory.TrueSystem(gain=1.0, offset=0.0, cubic=cubic)
    model = theory.LinearModel(gain=1.2, offset=0.2)
    desired, beta_1 = 1.0, 0.3

    @jax.jit
    def train_offset(beta_0, observed):  # gradient descent to rest on the offset only
        def loss(b):
            controller = theory.AffineController(b, beta_1)
            return theory.controller_loss(name, controller, model, desired, observed, "observed")

        return jax.lax.fori_loop(0, 300, lambda _, b: b - 0.1 * jax.grad(loss)(b), beta_0)

    beta_0, actions = 0.0, []
    for _ in range(40):  # Algorithm 1 with a fixed model: roll out at s_d, train at s_a
        action = beta_0 + beta_1 * desired
        actions.append(action)
        observed = float(theory.true_response(system, action))
        beta_0 = float(train_offset(beta_0, observed))
    fp = theory.observed_goal_fixed_point(name, system, model, desired, beta_1)
    np.testing.assert_allclose(actions[-1], float(fp.action), atol=1e-5)
    # The contraction is the ratio of successive distances to the fixed point.
    ratio = (actions[4] - float(fp.action)) / (actions[3] - float(fp.action))
    np.testing.assert_allclose(ratio, float(fp.contraction), rtol=0.02)
    if cubic == 0.0:  # the closed forms of the docstring
        e_task = (desired - model.offset) / model.gain - desired  # a = 1, b = 0
        a, a_hat = 1.0, model.gain
        want = (
            e_task / (1 + a * beta_1)
            if name == "task"
            else 2 * a_hat * e_task / (2 * a_hat - a + 2 * a * a_hat * beta_1)
        )
        np.testing.assert_allclose(float(fp.error), want, rtol=1e-6)
