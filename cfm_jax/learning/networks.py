"""Forward model and controller as ``(init, apply)`` pairs of pure functions (Flax linen).

The forward model ``f(s, tau)`` is an ensemble of probabilistic MLPs (PETS, Chua et al.
2018, :func:`forward_model`); the controller ``g(s, s*) -> tau`` an MLP squashed into the
torque limits (:func:`controller`). Both see inputs scaled by a :class:`Normaliser`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from cfm_jax.learning import losses


@struct.dataclass
class Normaliser:
    """Centres and scales of the networks' inputs and outputs (``Config.loop.normaliser``: of
    the babbling data, of the data set, or the robot's physical scales).

    Attributes:
      state_mean: ``(state_dim,)`` mean of the learning state.
      state_std: ``(state_dim,)`` standard deviation of the learning state.
      output_mean: ``(output_dim,)`` mean of the observed quantity (also used for the
        forward model's outputs and, at ``desired_index``, the desired quantity).
      output_std: ``(output_dim,)`` its standard deviation.
      torque_limit: ``(action_dim,)`` bound of the controller's output.
      torque_scale: ``(action_dim,)`` or ``(action_dim, action_dim)`` torque scale ``T``
        (:meth:`cfm_jax.sim.robots.Robot.torque_scale`), or None: the limits. The forward model
        takes ``T^-1 tau``, the controller puts out ``torque_limit tanh(T u / torque_limit)``.
      desired_index: static, the output entries the desired quantity specifies (None: all).
      pose_scale: static, None or ``pose_scale(states) -> (..., action_dim, action_dim)``
        added to a matrix ``T`` at each state's own pose (``loop.torque_scale = "pose"``:
        :func:`cfm_jax.learning.algorithm.pose_scale`); where no state is given, ``T`` alone.
      pose: None, or the term of the rows at hand (:meth:`at_rows`), used for it.

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
    pose_scale: Callable | None = struct.field(pytree_node=False, default=None)
    pose: jax.Array | None = None

    @classmethod
    def identity(
        cls,
        state_dim: int,
        output_dim: int,
        torque_limit,
        desired_index=None,
        torque_scale=None,
        pose_scale=None,
    ) -> Normaliser:
        return cls(
            jnp.zeros(state_dim),
            jnp.ones(state_dim),
            jnp.zeros(output_dim),
            jnp.ones(output_dim),
            jnp.asarray(torque_limit, jnp.float32),
            _index(desired_index, output_dim),
            _scale(torque_scale),
            pose_scale,
        )

    @classmethod
    def from_data(
        cls,
        states,
        observed,
        torque_limit,
        weights=None,
        desired_index=None,
        torque_scale=None,
        pose_scale=None,
    ) -> Normaliser:
        """Statistics of ``states`` and ``observed`` (rows of nonzero ``weights``; std >= 1e-3)."""
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
            pose_scale,
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
        pose_scale=None,
    ) -> Normaliser:
        """A normaliser of given centres and scales (:func:`cfm_jax.tasks.scales.robot_scales`)."""
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
            pose_scale,
        )

    def at_rows(self, rows):
        """For data-set ``rows``: their stored ``pose`` term stands in for ``pose_scale``."""
        return self if rows.pose is None else self.replace(pose=rows.pose)

    def state(self, s):
        return (s - self.state_mean) / self.state_std

    def torque(self, tau, state=None):
        """Scaled torque: ``tau / torque_scale``, or ``T^-1 tau`` for a matrix ``T`` (at the
        pose of ``state``, ``(..., state_dim)``, with a ``pose_scale``)."""
        scale = self.torque_limit if self.torque_scale is None else self.torque_scale
        if self.pose_scale is not None and state is not None:
            return _positive_definite_solve(self._at_pose(scale, state, tau.shape), tau)
        if scale.ndim == 2:  # a coupled scale T: T^-1 tau
            return jnp.linalg.solve(scale, tau[..., None])[..., 0]
        return tau / scale

    def torque_output(self, u, state=None):
        """The controller's torque for its network's output ``u`` (see ``torque_scale``; at the
        pose of ``state`` with a ``pose_scale``)."""
        if self.torque_scale is None:
            return self.torque_limit * jnp.tanh(u)
        if self.pose_scale is not None and state is not None:
            scale = self._at_pose(self.torque_scale, state, u.shape)
            return self.torque_limit * jnp.tanh((scale @ u[..., None])[..., 0] / self.torque_limit)
        if self.torque_scale.ndim == 2:  # a coupled scale T
            return self.torque_limit * jnp.tanh((u @ self.torque_scale.T) / self.torque_limit)
        return self.torque_limit * jnp.tanh(self.torque_scale * u / self.torque_limit)

    def _at_pose(self, scale, state, shape):
        """``T + pose_scale(state)``, ``shape + (action_dim,)`` (a torque's leading axes)."""
        if scale.ndim != 2:
            raise ValueError("a pose_scale needs a matrix torque_scale (action_dim, action_dim)")
        full = scale + (self.pose_scale(state) if self.pose is None else self.pose)
        return jnp.broadcast_to(full, shape + shape[-1:])

    def output(self, y):
        """Normalised observed / predicted quantity ``(..., output_dim)``."""
        return (y - self.output_mean) / self.output_std

    def output_inverse(self, y_normalised):
        return y_normalised * self.output_std + self.output_mean

    def select(self, y):
        """The entries ``desired_index`` of an output ``(..., output_dim)``."""
        return y if self.desired_index is None else y[..., jnp.asarray(self.desired_index)]

    def desired(self, d):
        """Normalised desired quantity (the output's statistics at ``desired_index``)."""
        return (d - self.select(self.output_mean)) / self.select(self.output_std)


def _positive_definite_solve(a, b):
    """``a^-1 b`` for symmetric positive definite ``a (..., k, k)`` and ``b (..., k)``, by a
    Cholesky factorisation written out in array operations over the leading axes.

    Not ``jnp.linalg.solve``: on the CPU a batch of LAPACK factorisations splits over XLA's
    thread pool and waits there, and two of them at once (the supervised loss's two torques)
    took both threads of a 2-core machine and never returned (jaxlib 0.8, a Gen3 run)."""
    k = a.shape[-1]
    low = [[None] * k for _ in range(k)]  # the Cholesky factor L, a = L L^T, by entries
    for j in range(k):
        diagonal = jnp.sqrt(a[..., j, j] - sum(low[j][m] ** 2 for m in range(j)))
        low[j][j] = diagonal
        for i in range(j + 1, k):
            low[i][j] = (a[..., i, j] - sum(low[i][m] * low[j][m] for m in range(j))) / diagonal
    y = []  # L y = b
    for i in range(k):
        y.append((b[..., i] - sum(low[i][m] * y[m] for m in range(i))) / low[i][i])
    x = [None] * k  # L^T x = y
    for i in reversed(range(k)):
        x[i] = (y[i] - sum(low[m][i] * x[m] for m in range(i + 1, k))) / low[i][i]
    return jnp.stack(x, -1)


def _scale(torque_scale):
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
    """A network as pure functions, and a forward model's whole contract with the learning loop,
    which knows nothing of its parameters (docs/concepts/method.md).

    Attributes:
      init: ``init(key, state_dim) -> params``.
      apply: ``apply(params, normaliser, state, other)`` (:func:`forward_model`,
        :func:`controller`).
      terms: ``terms(state) -> pytree`` that a forward model needs per transition besides
        ``(s, tau)``, stored when it enters the data set and passed as ``terms=``; or None.
      objective: ``objective(params, normaliser, batch) -> scalar``, the loss of a fit step
        (``batch``: :class:`cfm_jax.sim.dataset.Transitions` of ``batches(params)`` minibatches).
      predict: ``predict(params, normaliser, state, tau, terms=None)``, the prediction in
        normalised output units that the controller losses and metrics use.
      batches: ``batches(params) -> int``, minibatches per fit step; default 1.
      start: ``start(params, runtime) -> params``, what a fit starts from given the
        ``forward.*`` runtime values; default: unchanged.

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
    """The forward :class:`Model` of a PETS ensemble ``apply -> (mean, log_variance)``, each
    ``(members, ..., output)``: ``objective`` is the Gaussian NLL with member ``e`` scored on
    minibatch ``e`` plus :data:`LOG_VARIANCE_BOUND_PENALTY` times the learned bounds,
    ``predict`` the members' mean, ``start`` sets the bounds from the runtime values.

    Args:
      init: ``init(key, state_dim) -> {"members", "min_log_variance", "max_log_variance"}``.
      apply: ``apply(params, normaliser, state, tau, per_member=False, terms=None)``.
      terms: ``terms(state)``, what ``apply`` needs per transition, or None.

    Examples:
      >>> fm = forward_model(hidden=(8,), ensemble_size=3, nv=2)  # pets(...) of the MLPs
      >>> params = fm.init(jax.random.key(0), state_dim=4)
      >>> fm.batches(params)
      3
    """

    def objective(params, normaliser: Normaliser, batch):
        normaliser = normaliser.at_rows(batch)
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
    """Probabilistic ensemble ``f(s, tau) -> (mean, log_variance)`` in normalised output units.

    Each output is ``(ensemble_size, ..., nv)``; with ``per_member=True`` member ``e`` sees
    only ``state[e], tau[e]``. Log-variances are softly bounded by learned limits (PETS).

    Args:
      hidden: hidden layer widths (ReLU).
      ensemble_size: number of members.
      nv: output size (the task's ``output_dim``).
      min_log_variance: initial lower bound of the log-variance.
      max_log_variance: initial upper bound.
      action_dim: size of ``tau`` (default ``nv``).

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
        x = jnp.concatenate([normaliser.state(state), normaliser.torque(tau, state)], -1)
        in_axes = (0, 0) if per_member else (0, None)
        out = jax.vmap(mlp.apply, in_axes=in_axes)(params["members"], x)
        mean, raw = jnp.split(out, 2, axis=-1)
        upper, lower = params["max_log_variance"], params["min_log_variance"]
        log_variance = upper - jax.nn.softplus(upper - raw)
        log_variance = lower + jax.nn.softplus(log_variance - lower)
        return mean, log_variance

    return pets(init, apply)


def ensemble(forward, output_dim: int, action_dim: int) -> Model:
    """:func:`forward_model` of a forward-model config: the ``mlp`` kind, ``rigid_body``'s residual.

    Args:
      forward: a :class:`cfm_jax.config.ForwardModelConfig`.
      output_dim: the task's output size.
      action_dim: the task's number of torques.

    Examples:
      >>> fm = ensemble(cfm_jax.config.ForwardModelConfig(hidden=(8,), ensemble_size=2), 3, 2)
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
    """Controller ``g(s, s*) -> tau (..., nv)``, squashed into the torque limits
    (:meth:`Normaliser.torque_output`).

    Args:
      hidden: hidden layer widths (ReLU).
      nv: number of torques (``action_dim``).
      desired_dim: size of ``s*`` (default ``nv``).

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
        return normaliser.torque_output(mlp.apply(params, x), state)

    return Model(init, apply)
