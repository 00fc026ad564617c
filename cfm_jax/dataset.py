"""Fixed-capacity ring-buffer data set of transitions, as a pytree.

Shapes never change, so the training iteration compiles once: ``add`` writes a batch of
transitions at the insertion point (overwriting the oldest when full), ``sample`` draws
uniform minibatches from the filled part. Transitions flagged invalid (for example from a
rollout whose simulator state went non-finite) are not added.

Example:
  >>> import jax, jax.numpy as jnp
  >>> data = empty(capacity=4, state_dim=2, nv=1)
  >>> batch = Transitions(*(jnp.ones((3, d)) for d in (2, 1, 1, 1)))
  >>> data = add(data, batch, valid=jnp.array([True, False, True]))
  >>> int(data.size)
  2
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct


class Transitions(NamedTuple):
    """A batch of transitions ``(n, ...)``.

    Attributes:
      state: the task's state ``s_t`` (``[q, qdot]`` for the arm tasks), ``(n, state_dim)``.
      desired: the desired quantity ``s*_t`` (the desired next-step joint acceleration
        ``qdd*_t`` for the joint-space task), ``(n, desired_dim)``.
      action: executed torque ``tau_run``, ``(n, action_dim)``.
      observed: the observed quantity the forward model predicts (the acceleration
        ``(qdot_{t+1} - qdot_t) / dt`` for the joint-space task), ``(n, output_dim)``.
    """

    state: jax.Array
    desired: jax.Array
    action: jax.Array
    observed: jax.Array


@struct.dataclass
class Dataset:
    """Ring buffer: ``data`` holds ``capacity`` rows; rows ``[0, size)`` are filled."""

    data: Transitions
    size: jax.Array  # int32 scalar: number of filled rows
    insert: jax.Array  # int32 scalar: next row to write

    @property
    def capacity(self) -> int:
        return self.data.state.shape[0]


def empty(
    capacity: int,
    state_dim: int,
    nv: int,
    action_dim: int | None = None,
    output_dim: int | None = None,
) -> Dataset:
    """An empty data set for ``capacity`` transitions; ``nv`` is the desired quantity's size,
    ``action_dim`` and ``output_dim`` default to it (the joint-space task)."""
    dims = (state_dim, nv, action_dim or nv, output_dim or nv)
    data = Transitions(*(jnp.zeros((capacity, d), jnp.float32) for d in dims))
    return Dataset(data, jnp.int32(0), jnp.int32(0))


def add(dataset: Dataset, batch: Transitions, valid=None) -> Dataset:
    """Append the ``valid`` rows of ``batch`` (all if None), oldest rows overwritten when full.

    Rows are written in order; invalid rows take no space. ``batch`` must not be larger than
    the capacity.
    """
    n = batch.state.shape[0]
    capacity = dataset.capacity
    if n > capacity:
        raise ValueError(f"batch of {n} transitions exceeds the data set capacity {capacity}")
    valid = jnp.ones(n, bool) if valid is None else valid
    offset = jnp.cumsum(valid) - 1  # position among the valid rows
    rows = jnp.where(valid, (dataset.insert + offset) % capacity, capacity)  # capacity: drop
    data = jax.tree.map(
        lambda buffer, new: buffer.at[rows].set(new.astype(buffer.dtype), mode="drop"),
        dataset.data,
        batch,
    )
    count = jnp.sum(valid).astype(jnp.int32)
    return Dataset(
        data,
        jnp.minimum(dataset.size + count, capacity).astype(jnp.int32),
        ((dataset.insert + count) % capacity).astype(jnp.int32),
    )


def sample(dataset: Dataset, key, batch_size: int) -> Transitions:
    """``batch_size`` rows drawn uniformly (with replacement) from the filled part."""
    rows = jax.random.randint(key, (batch_size,), 0, jnp.maximum(dataset.size, 1))
    return jax.tree.map(lambda x: x[rows], dataset.data)


def filled(dataset: Dataset) -> Transitions:
    """The filled rows as a host-side view (not jittable: the size is data-dependent)."""
    n = int(dataset.size)
    return jax.tree.map(lambda x: x[:n], dataset.data)
