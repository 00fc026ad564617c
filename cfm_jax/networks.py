"""Forward model and controller as ``(init, apply)`` pairs of pure functions (Flax linen).

* Forward model ``f(s, tau) -> qdd``: an ensemble of probabilistic MLPs (PETS, Chua et al.
  2018): each member outputs a Gaussian mean and a log-variance softly bounded between
  learned limits. Inputs and outputs are normalised with statistics of the data
  (:class:`Normaliser`); the members are one parameter pytree with a leading member axis.
* Controller ``g(s, qdd*) -> tau``: an MLP whose output is squashed into the torque limits,
  ``tau = tau_max * tanh(raw)``.

Both models work in the space the desired state ``s*`` is given in (joint accelerations),
so the task and joint losses compare like with like.

Examples:
  >>> import jax, jax.numpy as jnp
  >>> norm = Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
  >>> fm = forward_model(hidden=(8,), ensemble_size=2, nv=2)
  >>> params = fm.init(jax.random.key(0), state_dim=4)
  >>> mean, log_var = fm.apply(params, norm, jnp.zeros(4), jnp.zeros(2))
  >>> mean.shape, log_var.shape
  ((2, 2), (2, 2))
"""

from __future__ import annotations

from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from cfm_jax import losses


@struct.dataclass
class Normaliser:
    """Centres and scales of the networks' inputs and outputs: statistics of the babbling
    data (fitted once), of the whole data set (refitted before every fit) or fixed physical
    scales of the robot, as ``Config.loop.normaliser`` says (:func:`from_data`,
    :func:`from_scales`).

    Attributes:
      state_mean: ``(state_dim,)`` mean of the learning state.
      state_std: ``(state_dim,)`` standard deviation of the learning state.
      output_mean: ``(output_dim,)`` mean of the observed quantity the forward model
        predicts (joint accelerations for the joint-space task); the forward model's
        outputs, the observed quantity and (by ``desired_index``) the desired quantity are
        normalised with it and ``output_std``.
      output_std: ``(output_dim,)`` standard deviation of the same quantity.
      torque_limit: ``(action_dim,)`` the torque limits: the bound of the controller's
        output, and the scale of the torques where ``torque_scale`` is None.
      torque_scale: ``(action_dim,)`` scale of the torques
        (:meth:`cfm_jax.robots.Robot.torque_scale`), or None: the torque limits. The
        forward model takes ``tau / scale``; the controller puts out
        ``torque_limit tanh(u)`` (None) or ``torque_limit tanh(torque_scale u /
        torque_limit)``, whose slope at 0 is ``torque_scale``.
      desired_index: static tuple, the entries of the output the desired quantity specifies
        (``None``: all of them, in order).

    Examples:
      >>> norm = Normaliser.from_data(jnp.array([[0.0], [2.0]]), jnp.array([[1.0], [3.0]]),
      ...                             torque_limit=jnp.ones(1))
      >>> norm.state_mean.tolist(), norm.state_std.tolist(), norm.output(jnp.array([3.0])).tolist()
      ([1.0], [1.0], [1.0])
    """

    state_mean: jax.Array
    state_std: jax.Array
    output_mean: jax.Array
    output_std: jax.Array
    torque_limit: jax.Array
    desired_index: tuple[int, ...] | None = struct.field(pytree_node=False, default=None)
    torque_scale: jax.Array | None = None

    @classmethod
    def identity(
        cls, state_dim: int, output_dim: int, torque_limit, desired_index=None, torque_scale=None
    ) -> Normaliser:
        return cls(
            jnp.zeros(state_dim),
            jnp.ones(state_dim),
            jnp.zeros(output_dim),
            jnp.ones(output_dim),
            jnp.asarray(torque_limit, jnp.float32),
            _index(desired_index, output_dim),
            _scale(torque_scale),
        )

    @classmethod
    def from_data(
        cls, states, observed, torque_limit, weights=None, desired_index=None, torque_scale=None
    ) -> Normaliser:
        """Statistics of ``states (n, state_dim)`` and ``observed (n, output_dim)``.

        ``weights (n,)`` (0 or 1) masks rows out (for example non-finite ones); standard
        deviations are floored at 1e-3.
        """
        floor = 1e-3
        n = states.shape[0]
        weights = jnp.ones(n) if weights is None else weights.astype(jnp.float32)
        total = jnp.maximum(jnp.sum(weights), 1.0)

        def moments(x):
            x = jnp.where(weights[:, None] > 0, x, 0.0)
            mean = jnp.sum(weights[:, None] * x, 0) / total
            var = jnp.sum(weights[:, None] * jnp.square(x - mean), 0) / total
            return mean, jnp.maximum(jnp.sqrt(var), floor)

        state_mean, state_std = moments(states)
        output_mean, output_std = moments(observed)
        return cls(
            state_mean,
            state_std,
            output_mean,
            output_std,
            jnp.asarray(torque_limit, jnp.float32),
            _index(desired_index, observed.shape[-1]),
            _scale(torque_scale),
        )

    @classmethod
    def from_scales(
        cls,
        state_mean,
        state_std,
        output_mean,
        output_std,
        torque_limit,
        desired_index=None,
        torque_scale=None,
    ) -> Normaliser:
        """A normaliser of given centres and scales (for example the robot's fixed
        physical scales, :func:`cfm_jax.tasks.scales.robot_scales`), as float32.

        Examples:
          >>> norm = Normaliser.from_scales([1.0], [2.0], [0.0], [4.0], [1.0])
          >>> norm.state(jnp.array([3.0])).tolist(), norm.output(jnp.array([2.0])).tolist()
          ([1.0], [0.5])
        """
        state_mean, state_std, output_mean, output_std, torque_limit = (
            jnp.asarray(x, jnp.float32)
            for x in (state_mean, state_std, output_mean, output_std, torque_limit)
        )
        return cls(
            state_mean,
            state_std,
            output_mean,
            output_std,
            torque_limit,
            _index(desired_index, output_mean.shape[-1]),
            _scale(torque_scale),
        )

    def state(self, s):
        return (s - self.state_mean) / self.state_std

    def torque(self, tau):
        """Scaled torque ``(..., action_dim)``: ``tau / torque_scale`` (None: the limits;
        a matrix scale ``T``: ``T^-1 tau``)."""
        scale = self.torque_limit if self.torque_scale is None else self.torque_scale
        if scale.ndim == 2:  # a coupled scale T: T^-1 tau
            return jnp.linalg.solve(scale, tau[..., None])[..., 0]
        return tau / scale

    def torque_output(self, u):
        """The controller's torque for its network's output ``u``: ``torque_limit tanh(u)``,
        or with a ``torque_scale`` ``torque_limit tanh(torque_scale u / torque_limit)``
        (slope ``torque_scale`` at 0, bounded by the limits)."""
        if self.torque_scale is None:
            return self.torque_limit * jnp.tanh(u)
        if self.torque_scale.ndim == 2:  # a coupled scale T
            return self.torque_limit * jnp.tanh((u @ self.torque_scale.T) / self.torque_limit)
        return self.torque_limit * jnp.tanh(self.torque_scale * u / self.torque_limit)

    def output(self, y):
        """Normalised observed / predicted quantity ``(..., output_dim)``."""
        return (y - self.output_mean) / self.output_std

    def output_inverse(self, y_normalised):
        return y_normalised * self.output_std + self.output_mean

    def select(self, y):
        """The entries ``desired_index`` of an output ``(..., output_dim)``."""
        return y if self.desired_index is None else y[..., jnp.asarray(self.desired_index)]

    def desired(self, d):
        """Normalised desired quantity ``(..., desired_dim)`` (the output's statistics at
        ``desired_index``)."""
        return (d - self.select(self.output_mean)) / self.select(self.output_std)


def _scale(torque_scale):
    """None, or the torque scale as float32."""
    return None if torque_scale is None else jnp.asarray(torque_scale, jnp.float32)


def _index(desired_index, output_dim: int):
    """``None`` when the desired quantity is the whole output in order, else a tuple."""
    if desired_index is None:
        return None
    index = tuple(int(i) for i in desired_index)
    return None if index == tuple(range(output_dim)) else index


class _MLP(nn.Module):
    hidden: tuple[int, ...]
    out: int

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        return nn.Dense(self.out)(x)


def _one_batch(params) -> int:
    del params
    return 1


def _unchanged(params, runtime):
    del runtime
    return params


class Model(NamedTuple):
    """A network as pure functions: ``(init, apply)``, and for a forward model its whole
    contract with the learning loop, which calls these and knows nothing of the
    parameters (a new kind of forward model is a :class:`Model` and one
    :func:`cfm_jax.forward_models.register`).

    Attributes:
      init: ``init(key, state_dim) -> params``.
      apply: ``apply(params, normaliser, state, other) -> output`` (see
        :func:`forward_model` and :func:`controller`).
      terms: forward models only: ``terms(state (..., state_dim)) -> pytree (..., ...)``,
        what the model needs per transition besides ``(s, tau)``, computed once when a
        transition enters the data set (:attr:`cfm_jax.dataset.Transitions.terms`) and
        passed on as ``terms=``; None (the ``mlp`` ensemble, the controller): none.
      objective: forward models: ``objective(params, normaliser, batch) -> scalar``, the
        training loss of a fit step on ``batch`` (:class:`cfm_jax.dataset.Transitions`
        with a leading axis of ``batches(params)`` minibatches, each of ``(rows, ...)``);
        None for a controller.
      predict: forward models: ``predict(params, normaliser, state (..., state_dim), tau
        (..., action_dim), terms=None) -> (..., output_dim)``, the prediction in normalised
        output units (``normaliser.output_inverse`` gives physical units) that the
        controller losses and the metrics use; None for a controller.
      batches: forward models: ``batches(params) -> int``, the minibatches drawn for each
        fit step (the ensemble: one per member); default 1.
      start: forward models: ``start(params, runtime) -> params``, the parameters a fit
        starts from (called on fresh ``init`` parameters), given the forward section's
        runtime values (``runtime``: ``{field: float32}`` of the ``forward.*`` fields of
        :data:`cfm_jax.config.RUNTIME_FIELDS` but the learning rate; the ensemble sets its
        log-variance bounds from them); default: unchanged.

    Examples:
      >>> g = controller(hidden=(8,), nv=2)
      >>> params = g.init(jax.random.key(0), state_dim=4)
      >>> norm = Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.ones(2))
      >>> g.apply(params, norm, jnp.zeros((3, 4)), jnp.zeros((3, 2))).shape
      (3, 2)
    """

    init: Any
    apply: Any
    terms: Any = None
    objective: Any = None
    predict: Any = None
    batches: Any = _one_batch
    start: Any = _unchanged


LOG_VARIANCE_BOUND_PENALTY = 0.01
"""Weight of the PETS penalty on the ensemble's learned log-variance bounds."""


def pets(init, apply, terms=None) -> Model:
    """The forward :class:`Model` of a PETS-style ensemble: ``apply(params, normaliser,
    state, tau, per_member=False, terms=None) -> (mean, log_variance)``, each ``(members,
    ..., output)``, over parameters ``{"members": (members, ...) leaves, "min_log_variance",
    "max_log_variance"}`` (:func:`forward_model`; the ``rigid_body`` kind adds physics to
    its mean). The contract it gets: ``objective`` the mean Gaussian NLL of the observed
    quantity over members and rows, member ``e`` scored on minibatch ``e`` only, plus
    :data:`LOG_VARIANCE_BOUND_PENALTY` times the learned bounds (PETS); ``predict`` the mean
    over members; ``batches`` the members; ``start`` sets both bounds to the runtime's
    ``min_log_variance`` and ``max_log_variance``.

    Args:
      init: ``init(key, state_dim) -> params``.
      apply: the ensemble's ``apply`` (above).
      terms: ``terms(state)``, what ``apply`` needs per transition, or None.

    Returns:
      A :class:`Model`.

    Examples:
      >>> fm = forward_model(hidden=(8,), ensemble_size=3, nv=2)  # pets(...) of the MLPs
      >>> params = fm.init(jax.random.key(0), state_dim=4)
      >>> fm.batches(params)
      3
      >>> bounds = {"min_log_variance": -5.0, "max_log_variance": 1.0}
      >>> fm.start(params, bounds)["min_log_variance"].tolist()
      [-5.0, -5.0]
    """

    def objective(params, normaliser: Normaliser, batch):
        extra = {} if batch.terms is None else {"terms": batch.terms}
        mean, log_var = apply(
            params, normaliser, batch.state, batch.action, per_member=True, **extra
        )
        nll = losses.gaussian_nll(mean, log_var, normaliser.output(batch.observed))
        bounds = jnp.sum(params["max_log_variance"]) - jnp.sum(params["min_log_variance"])
        return jnp.mean(nll) + LOG_VARIANCE_BOUND_PENALTY * bounds

    def predict(params, normaliser: Normaliser, state, tau, terms=None):
        extra = {} if terms is None else {"terms": terms}
        mean, _ = apply(params, normaliser, state, tau, **extra)
        return jnp.mean(mean, axis=0)

    def batches(params) -> int:
        return jax.tree.leaves(params["members"])[0].shape[0]

    def start(params, runtime):
        lower, upper = runtime["min_log_variance"], runtime["max_log_variance"]
        return {
            **params,
            "min_log_variance": jnp.full_like(params["min_log_variance"], lower),
            "max_log_variance": jnp.full_like(params["max_log_variance"], upper),
        }

    return Model(init, apply, terms, objective, predict, batches, start)


def forward_model(
    hidden: tuple[int, ...],
    ensemble_size: int,
    nv: int,
    min_log_variance: float = -10.0,
    max_log_variance: float = 0.5,
    action_dim: int | None = None,
) -> Model:
    """Probabilistic ensemble ``f(s, tau)`` predicting the normalised observed quantity.

    ``nv`` is the output size (the joint accelerations for the joint-space task; in
    general the task's ``output_dim``), ``action_dim`` the size of ``tau`` (default ``nv``).
    ``apply(params, normaliser, state (..., state_dim), tau (..., action_dim))`` returns
    ``(mean, log_variance)``, each ``(ensemble_size, ..., nv)``, in normalised units
    (``normaliser.output``). With ``per_member=True`` the inputs carry a leading member axis
    ``(ensemble_size, ..., ·)`` and member ``e`` sees only ``state[e], tau[e]`` (used to
    train every member on its own minibatches). Log-variance bounds follow PETS:
    ``lv = max - softplus(max - raw); lv = min + softplus(lv - min)`` with learned ``max``
    and ``min``.

    Args:
      hidden: hidden layer widths (ReLU).
      ensemble_size: number of members ``E``.
      nv: output size (the task's ``output_dim``).
      min_log_variance: initial lower bound of the log-variance (learned).
      max_log_variance: initial upper bound (learned).
      action_dim: size of ``tau`` (default ``nv``).

    Returns:
      A :class:`Model`; ``init(key, state_dim)`` gives ``{"members": (E, ...) leaves,
      "max_log_variance": (nv,), "min_log_variance": (nv,)}``.

    Examples:
      >>> norm = Normaliser.identity(state_dim=4, output_dim=3, torque_limit=jnp.ones(2))
      >>> fm = forward_model(hidden=(8,), ensemble_size=3, nv=3, action_dim=2)
      >>> params = fm.init(jax.random.key(0), state_dim=4)
      >>> mean, log_var = fm.apply(params, norm, jnp.zeros((5, 4)), jnp.zeros((5, 2)))
      >>> mean.shape, bool(jnp.all(log_var <= 0.5))
      ((3, 5, 3), True)
    """
    mlp = _MLP(hidden=hidden, out=2 * nv)
    action_dim = nv if action_dim is None else action_dim

    def init(key, state_dim: int):
        keys = jax.random.split(key, ensemble_size)
        dummy = jnp.zeros((1, state_dim + action_dim))
        members = jax.vmap(lambda k: mlp.init(k, dummy))(keys)
        return {
            "members": members,
            "max_log_variance": jnp.full((nv,), max_log_variance, jnp.float32),
            "min_log_variance": jnp.full((nv,), min_log_variance, jnp.float32),
        }

    def apply(params, normaliser: Normaliser, state, tau, per_member: bool = False, terms=None):
        del terms  # the ensemble needs nothing but (s, tau)
        x = jnp.concatenate([normaliser.state(state), normaliser.torque(tau)], -1)
        in_axes = (0, 0) if per_member else (0, None)
        out = jax.vmap(mlp.apply, in_axes=in_axes)(params["members"], x)
        mean, raw = jnp.split(out, 2, axis=-1)
        upper, lower = params["max_log_variance"], params["min_log_variance"]
        log_variance = upper - jax.nn.softplus(upper - raw)
        log_variance = lower + jax.nn.softplus(log_variance - lower)
        return mean, log_variance

    return pets(init, apply)


def ensemble(forward, output_dim: int, action_dim: int) -> Model:
    """The PETS ensemble a forward-model config describes (:func:`forward_model` with its
    ``hidden``, ``ensemble_size`` and log-variance bounds) over an output of
    ``output_dim`` from ``action_dim`` torques: the ``mlp`` kind, and the residual of the
    ``rigid_body`` kind.

    Args:
      forward: a :class:`cfm_jax.config.ForwardModelConfig`.
      output_dim: the task's output size.
      action_dim: the task's number of torques.

    Returns:
      A :class:`Model`.

    Examples:
      >>> from cfm_jax.config import ForwardModelConfig
      >>> fm = ensemble(ForwardModelConfig(hidden=(8,), ensemble_size=2), 3, 2)
      >>> fm.init(jax.random.key(0), state_dim=4)["max_log_variance"].shape
      (3,)
    """
    return forward_model(
        forward.hidden,
        forward.ensemble_size,
        output_dim,
        forward.min_log_variance,
        forward.max_log_variance,
        action_dim=action_dim,
    )


def controller(hidden: tuple[int, ...], nv: int, desired_dim: int | None = None) -> Model:
    """Controller ``g(s, s*) -> tau``, squashed into the torque limits.

    ``nv`` is the number of torques (``action_dim``), ``desired_dim`` the size of the
    desired quantity ``s*`` (default ``nv``: a desired joint acceleration).
    ``apply(params, normaliser, state (..., state_dim), desired (..., desired_dim))`` returns
    ``tau (..., nv)`` with ``|tau| < normaliser.torque_limit``.

    Args:
      hidden: hidden layer widths (ReLU).
      nv: number of torques (``action_dim``).
      desired_dim: size of ``s*`` (default ``nv``).

    Returns:
      A :class:`Model`.

    Examples:
      >>> norm = Normaliser.identity(state_dim=4, output_dim=2, torque_limit=jnp.array([5.0, 1.0]))
      >>> g = controller(hidden=(8,), nv=2)
      >>> tau = g.apply(g.init(jax.random.key(0), 4), norm, jnp.ones(4), 100 * jnp.ones(2))
      >>> bool(jnp.all(jnp.abs(tau) <= jnp.array([5.0, 1.0])))
      True
    """
    mlp = _MLP(hidden=hidden, out=nv)
    desired_dim = nv if desired_dim is None else desired_dim

    def init(key, state_dim: int):
        return mlp.init(key, jnp.zeros((1, state_dim + desired_dim)))

    def apply(params, normaliser: Normaliser, state, desired):
        x = jnp.concatenate([normaliser.state(state), normaliser.desired(desired)], -1)
        return normaliser.torque_output(mlp.apply(params, x))

    return Model(init, apply)
