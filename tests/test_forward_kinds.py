"""A forward-model kind owns its contract (issue 44, item 1): a kind written here, outside
the library (a linear model), registered here, trains end to end without editing any
library module; the learning loop calls its ``objective``, ``predict`` and ``start`` and
knows nothing of its parameters."""

import dataclasses
import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
from tiny import tiny_config

import cfm_jax
from cfm_jax import cli
from cfm_jax import config as config_lib
from cfm_jax.learning import forward_models, networks

KIND = "linear_test"


@dataclasses.dataclass(frozen=True)
class LinearOptions:
    """The test kind's own option (``forward.options``), checked by the kind."""

    init_scale: float = 0.1

    def __post_init__(self):
        if not self.init_scale > 0:
            config_lib.fail("forward.options.init_scale", self.init_scale, "a number > 0")


def _register():
    if KIND not in forward_models.REGISTRY:
        forward_models.register(KIND, linear, LinearOptions, lambda o: f"init {o.init_scale:g}")


def linear(forward, robot, task) -> networks.Model:
    """``y = [s, tau] W + b`` in normalised units, fitted by the mean squared error."""
    del robot
    n_in, n_out = task.state_dim + task.action_dim, task.output_dim
    scale = 0.1 if forward is None else forward.options.init_scale

    def init(key, state_dim):
        del state_dim
        return {"w": scale * jax.random.normal(key, (n_in, n_out)), "b": jnp.zeros(n_out)}

    def predict(params, normaliser, state, tau, terms=None):
        del terms
        x = jnp.concatenate([normaliser.state(state), normaliser.torque(tau)], -1)
        return x @ params["w"] + params["b"]

    def objective(params, normaliser, batch):  # batch: (1 minibatch, rows, ...)
        error = predict(params, normaliser, batch.state, batch.action)
        return jnp.mean(jnp.square(error - normaliser.output(batch.observed)))

    return networks.Model(init, predict, objective=objective, predict=predict)


def test_a_kinds_options_are_its_own_checked_by_it_and_saved():
    _register()
    with_options = config_lib.ForwardModelConfig(kind=KIND, options={"init_scale": 0.05})
    assert with_options.options == LinearOptions(0.05)
    assert config_lib.ForwardModelConfig(kind=KIND).options == LinearOptions()
    try:
        config_lib.ForwardModelConfig(kind=KIND, options={"init_scale": -1.0})
    except config_lib.ConfigError as error:
        assert "forward.options.init_scale=-1.0 is not allowed" in str(error)
    else:
        raise AssertionError("the kind's check did not run")
    config = tiny_config().replace(forward=with_options)
    assert config_lib.to_dict(config)["forward"]["options"] == {"init_scale": 0.05}
    assert config_lib.from_dict(config_lib.to_dict(config)) == config
    assert forward_models.describe(with_options) == f"`forward.kind={KIND!r}` (init 0.05)"


def test_the_cli_takes_a_registered_kinds_options_without_attributes_in_its_docstring(
    monkeypatch, capsys
):
    # LinearOptions documents no "Attributes:" section and its annotations are classes, not
    # postponed strings, as a user's class may well be: the CLI, which builds a flag per
    # option from them, failed on every command once such a kind was registered
    # ("'Attributes:' is not in list", then "'float' has no attribute 'startswith'").
    _register()
    monkeypatch.setattr(sys, "argv", ["cfm-jax", "config", "--forward.kind", KIND,
                                      "--forward.options.init-scale", "0.05"])  # fmt: skip
    cli.main()
    printed = json.loads(capsys.readouterr().out)
    assert printed["forward"]["options"] == {"init_scale": 0.05}


def test_a_forward_model_kind_written_outside_the_library_trains_end_to_end():
    _register()
    config = tiny_config(iterations=2, seeds=1)
    config = config.replace(forward=dataclasses.replace(
        config.forward, kind=KIND, learning_rate=1e-2, initial_steps=400, steps_per_iteration=200
    ))  # fmt: skip
    result = cfm_jax.train(config, progress=False)
    assert np.all(np.isfinite(result.metrics.tracking_mse))
    fits = result.metrics[result.metrics.iteration < config.loop.iterations]  # not the last
    assert np.all(np.isfinite(fits.forward_loss))  # evaluation, which fits nothing
    state = jax.tree.map(lambda x: x[0], result.state)  # the one seed
    assert set(state.forward_params) == {"w", "b"}
    # Oracle: the least-squares fit of the same normalised inputs to the same targets
    # (NumPy), the best a linear model can do on this data; the loop's fit of the kind's
    # objective closes most of the gap to it from the best constant prediction (0.73 of it
    # when written: 42.7 -> 30.8, optimum 26.3).
    norm, data = state.normaliser, state.data
    rows = int(data.size)
    t = jax.tree.map(lambda x: np.asarray(x[:rows]), data.data)
    x = np.concatenate([np.asarray(norm.state(t.state)), np.asarray(norm.torque(t.action))], 1)
    x = np.concatenate([x, np.ones((rows, 1))], 1)
    y = np.asarray(norm.output(t.observed), np.float64)
    best = np.mean(np.square(x @ np.linalg.lstsq(x, y, rcond=None)[0] - y))

    def mse(params):
        pred = np.asarray(linear(None, None, _Task(t, y)).predict(params, norm, t.state, t.action))
        return np.mean(np.square(pred - y))

    learned = mse(state.forward_params)
    assert best <= learned * (1 + 1e-4), (best, learned)
    constant = np.mean(np.square(y - y.mean(0)))  # the best prediction that ignores [s, tau]
    assert constant - learned > 0.5 * (constant - best), (best, learned, constant)


@dataclasses.dataclass
class _Task:
    """The sizes :func:`linear` reads of a task, from the data."""

    transitions: object
    targets: np.ndarray

    @property
    def state_dim(self):
        return self.transitions.state.shape[1]

    @property
    def action_dim(self):
        return self.transitions.action.shape[1]

    @property
    def output_dim(self):
        return self.targets.shape[1]
