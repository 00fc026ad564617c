"""Fixed-capacity ring buffer of transitions, a pytree whose shapes never change (so the
training iteration compiles once): :func:`empty`, :func:`add`, :func:`sample`; a run's data
sets are written by :func:`save` and read back by :func:`load`.
"""

from __future__ import annotations

import json
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cfm_jax._files import atomic_path


class Transitions(NamedTuple):
    """A batch of transitions ``(n, ...)``.

    Attributes:
      state: the task's state ``s_t``, ``(n, state_dim)``.
      desired: the desired quantity ``s*_t``, ``(n, desired_dim)``.
      action: the executed torque ``tau_run``, ``(n, action_dim)``.
      observed: the observed quantity the forward model predicts, ``(n, output_dim)``.
      terms: the forward model's per-transition terms (``Model.terms``, computed when the
        row is added; :func:`save` omits them), a pytree of ``(n, ...)`` arrays, or None.
      pose: the pose scale's term at ``state``, ``(n, k, k)``, added as ``terms``, or None.

    Examples:
      >>> Transitions(*(jnp.zeros((3, d)) for d in (4, 2, 2, 2))).state.shape
      (3, 4)
    """

    state: jax.Array
    desired: jax.Array
    action: jax.Array
    observed: jax.Array
    terms: Any = None
    pose: Any = None


RECORDED_FIELDS = ("state", "desired", "action", "observed")
"""The fields of :class:`Transitions` that :func:`save` writes."""


@struct.dataclass
class Dataset:
    """Ring buffer: ``data`` holds ``capacity`` rows; rows ``[0, size)`` are filled.

    Attributes:
      data: :class:`Transitions` with leaves ``(capacity, ...)``.
      size: number of filled rows (int32 scalar).
      insert: the next row to write (int32 scalar).

    Examples:
      >>> data = empty(capacity=8, state_dim=4, nv=2)
      >>> data.capacity, int(data.size), int(data.insert)
      (8, 0, 0)
    """

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
    terms: Any = None,
    pose: Any = None,
) -> Dataset:
    """An empty :class:`Dataset` of ``capacity`` float32 zero rows.

    Args:
      capacity: number of rows.
      state_dim: size of the state ``s``.
      nv: size of the desired quantity ``s*``.
      action_dim: size of the action (default ``nv``).
      output_dim: size of the observed quantity (default ``nv``).
      terms: the forward model's terms of one row (a pytree giving the shapes), or None.
      pose: the pose term of one row (its shape), or None.

    Examples:
      >>> empty(capacity=8, state_dim=4, nv=2, output_dim=5).data.observed.shape
      (8, 5)
    """
    dims = (state_dim, nv, action_dim or nv, output_dim or nv)
    data = Transitions(*(jnp.zeros((capacity, d), jnp.float32) for d in dims))
    rows = jax.tree.map(lambda x: jnp.zeros((capacity,) + jnp.shape(x), jnp.float32), (terms, pose))
    data = data._replace(terms=rows[0], pose=rows[1])
    return Dataset(data, jnp.int32(0), jnp.int32(0))


def add(dataset: Dataset, batch: Transitions, valid=None) -> Dataset:
    """A new :class:`Dataset` with the ``valid`` rows of ``batch`` appended in order, the
    oldest rows overwritten when full (invalid rows, e.g. of a diverged rollout, take no space).

    Args:
      dataset: the :class:`Dataset`.
      batch: :class:`Transitions` ``(n, ...)`` with ``n <= capacity``.
      valid: ``(n,)`` booleans, the rows to add (None: all).

    Raises:
      ValueError: ``n`` larger than the capacity.

    Examples:
      >>> data = empty(capacity=4, state_dim=1, nv=1)
      >>> batch = Transitions(*(jnp.arange(3.0)[:, None] for _ in range(4)))
      >>> data = add(add(data, batch), batch)  # 6 rows into 4: the first two overwritten
      >>> int(data.size), data.data.state[:, 0].tolist()
      (4, [1.0, 2.0, 2.0, 0.0])
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


def resized(dataset: Dataset, capacity: int) -> Dataset:
    """``dataset`` with ``capacity`` rows: grown, the rows in order (a full ring's oldest
    first), zero rows added and the next row after the last filled one; cut, rows dropped.

    Args:
      dataset: a :class:`Dataset` (no leading seed axis: ``jax.vmap`` it over seeds).
      capacity: the new number of rows, at least the filled ones.

    Examples:
      >>> rows = Transitions(*(jnp.ones((4, d)) for d in (2, 1, 1, 1)))
      >>> full = add(empty(capacity=4, state_dim=2, nv=1), rows)  # full: the next row is 0
      >>> grown = resized(full, 6)
      >>> grown.capacity, int(grown.size), int(grown.insert), grown.data.state[:, 0].tolist()
      (6, 4, 4, [1.0, 1.0, 1.0, 1.0, 0.0, 0.0])
    """
    n = dataset.capacity
    if capacity <= n:
        data = jax.tree.map(lambda x: x[:capacity], dataset.data)
        return dataset.replace(data=data, insert=dataset.insert % capacity)
    shift = jnp.where(dataset.size >= n, dataset.insert, 0)  # a full ring: oldest row first

    def grow(x):
        x = jnp.roll(x, -shift, axis=0)
        return jnp.concatenate([x, jnp.zeros((capacity - n,) + x.shape[1:], x.dtype)])

    data = jax.tree.map(grow, dataset.data)
    return dataset.replace(data=data, insert=dataset.size.astype(dataset.insert.dtype))


def sample(dataset: Dataset, key, batch_size: int) -> Transitions:
    """:class:`Transitions` of ``batch_size`` rows drawn uniformly (with replacement) from
    the filled part.

    Args:
      dataset: the :class:`Dataset`.
      key: PRNG key.
      batch_size: number of rows (static).

    Examples:
      >>> data = add(empty(capacity=8, state_dim=1, nv=1),
      ...            Transitions(*(jnp.ones((2, 1)) for _ in range(4))))
      >>> batch = sample(data, jax.random.key(0), batch_size=5)
      >>> batch.state.shape, float(batch.state.min())  # never an empty row
      ((5, 1), 1.0)
    """
    rows = jax.random.randint(key, (batch_size,), 0, jnp.maximum(dataset.size, 1))
    return jax.tree.map(lambda x: x[rows], dataset.data)


def filled(dataset: Dataset) -> Transitions:
    """The filled rows, :class:`Transitions` ``(size, ...)`` (host side: not jittable).

    Args:
      dataset: the :class:`Dataset`.

    Examples:
      >>> filled(empty(capacity=8, state_dim=1, nv=1)).action.shape
      (0, 1)
    """
    n = int(dataset.size)
    return jax.tree.map(lambda x: x[:n], dataset.data)


class Recorded(NamedTuple):
    """A run's data sets, one per seed, in collection order (its ``dataset.npz``, read by
    :func:`load`); the input of a replay, ``cfm_jax.train(config, data=...)``.

    Attributes:
      transitions: :class:`Transitions` ``(seeds, rows, ...)``; row ``i < size[k]`` is valid.
      size: ``(seeds,)`` filled rows per seed.
      segments: ``(seeds, 1 + iterations)`` rows added by babbling and by each iteration.
      seeds: the run's seeds, ``(seeds,)``.
      config: the run's config as a dict (:func:`cfm_jax.config.to_dict`).

    Examples:
      >>> Recorded._fields  # load(path) reads one: see save
      ('transitions', 'size', 'segments', 'seeds', 'config')
    """

    transitions: Transitions
    size: np.ndarray
    segments: np.ndarray
    seeds: np.ndarray
    config: dict

    @property
    def iterations(self) -> int:
        return self.segments.shape[1] - 1

    def chunk(self, segment: int, rows: int) -> tuple[Transitions, np.ndarray]:
        """Segment ``segment`` (0: babbling, ``i``: iteration ``i``) of every seed, padded to
        ``rows`` rows: ``(transitions (seeds, rows, ...), valid (seeds, rows))``."""
        seeds = self.size.shape[0]
        start = np.concatenate([np.zeros((seeds, 1), np.int64), np.cumsum(self.segments, 1)], 1)
        fields = [getattr(self.transitions, name) for name in RECORDED_FIELDS]
        out = [np.zeros((seeds, rows) + x.shape[2:], np.float32) for x in fields]
        valid = np.zeros((seeds, rows), bool)
        for k in range(seeds):
            n = int(self.segments[k, segment])
            if n > rows:
                raise ValueError(f"segment {segment} of seed {k} has {n} rows, more than {rows}")
            lo = int(start[k, segment])
            for buffer, x in zip(out, fields, strict=True):
                buffer[k, :n] = x[k, lo : lo + n]
            valid[k, :n] = True
        return Transitions(*out), valid


def save(path: str, data: Dataset, segments, seeds, config: dict) -> None:
    """Write the filled rows of a seed-batched :class:`Dataset` to ``.npz``, atomically.

    Args:
      path: the file to write.
      data: a :class:`Dataset` with leaves ``(seeds, ...)``.
      segments: as :attr:`Recorded.segments`; each row adds up to that seed's ``size``.
      seeds: the run's seeds, ``(seeds,)``.
      config: the run's config as a dict (:func:`cfm_jax.config.to_dict`).

    Raises:
      ValueError: segments that do not add up to the sizes.

    Examples:
      >>> import os, tempfile
      >>> one = add(empty(capacity=4, state_dim=1, nv=1),
      ...           Transitions(*(jnp.ones((3, 1)) for _ in range(4))))
      >>> two = jax.tree.map(lambda x: jnp.stack([x, x]), one)  # two seeds
      >>> path = os.path.join(tempfile.mkdtemp(), "dataset.npz")
      >>> save(path, two, segments=[[2, 1], [2, 1]], seeds=[0, 1], config={"robot": "x"})
      >>> recorded = load(path)
      >>> recorded.size.tolist(), recorded.iterations
      ([3, 3], 1)
    """
    size = np.asarray(data.size)
    if not np.all(np.asarray(segments).sum(axis=1) == size):
        raise ValueError(f"segments {np.asarray(segments).tolist()} do not add up to {size}")
    rows = int(size.max())
    arrays = {name: np.asarray(getattr(data.data, name))[:, :rows] for name in RECORDED_FIELDS}
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(
            f,
            size=size,
            segments=np.asarray(segments, np.int64),
            seeds=np.asarray(seeds, np.int64),
            config=np.frombuffer(json.dumps(config).encode(), np.uint8),
            **arrays,
        )


def load(path: str) -> Recorded:
    """The :class:`Recorded` data sets of a file written by :func:`save`.

    Args:
      path: the ``.npz`` file (a run's ``OUT/<loss>/dataset.npz``).

    Raises:
      FileNotFoundError: no such file.
      ValueError: the file is not a cfm_jax data set.

    Examples:
      >>> load("no/such/dataset.npz")
      Traceback (most recent call last):
      ...
      FileNotFoundError: data='no/such/dataset.npz': no such file (a run writes OUT/dataset.npz)
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"data={path!r}: no such file (a run writes OUT/dataset.npz)")
    with np.load(path) as f:
        missing = {"size", "segments", "seeds", "config", *RECORDED_FIELDS} - set(f.files)
        if missing:
            raise ValueError(f"data={path!r} is not a cfm_jax data set: no {sorted(missing)}")
        return Recorded(
            Transitions(*(f[name] for name in RECORDED_FIELDS)),
            f["size"],
            f["segments"],
            f["seeds"],
            json.loads(bytes(f["config"]).decode()),
        )
