"""Ring-buffer data set (cfm_jax/sim/dataset.py) against a plain Python list reference.

Oracle: a Python list that appends the valid rows one by one and keeps the last
``capacity`` of them, laid out in ring order (row ``i`` of the buffer holds the transition
written ``i (mod capacity)``-th). All values are small integers stored in float32, so the
comparisons are exact.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax.sim import dataset

STATE_DIM, NV = 3, 2


def make_batch(start, n):
    """Transitions whose every entry encodes its global row id (start + i)."""
    ids = np.arange(start, start + n, dtype=np.float32)[:, None]
    return dataset.Transitions(
        state=jnp.asarray(ids + np.zeros((1, STATE_DIM), np.float32)),
        desired=jnp.asarray(ids * 10 + np.zeros((1, NV), np.float32)),
        action=jnp.asarray(ids * 100 + np.zeros((1, NV), np.float32)),
        observed=jnp.asarray(-ids + np.zeros((1, NV), np.float32)),
    )


class RingReference:
    """Plain Python ring buffer: a list of row ids and the write pointer."""

    def __init__(self, capacity):
        self.capacity = capacity
        self.rows = [None] * capacity
        self.size = 0
        self.insert = 0

    def add(self, ids, valid):
        for i, ok in zip(ids, valid, strict=True):
            if ok:
                self.rows[self.insert] = i
                self.insert = (self.insert + 1) % self.capacity
                self.size = min(self.size + 1, self.capacity)


def assert_matches(data, ref):
    assert int(data.size) == ref.size
    assert int(data.insert) == ref.insert
    state = np.asarray(data.data.state)
    for row, i in enumerate(ref.rows):
        if i is None:
            continue
        np.testing.assert_array_equal(state[row], np.full(STATE_DIM, i, np.float32))
        np.testing.assert_array_equal(np.asarray(data.data.desired[row]), np.full(NV, 10.0 * i))
        np.testing.assert_array_equal(np.asarray(data.data.action[row]), np.full(NV, 100.0 * i))
        np.testing.assert_array_equal(np.asarray(data.data.observed[row]), np.full(NV, -1.0 * i))


def test_empty():
    data = dataset.empty(capacity=7, state_dim=STATE_DIM, nv=NV)
    assert data.capacity == 7
    assert int(data.size) == 0 and int(data.insert) == 0
    assert data.data.state.shape == (7, STATE_DIM)
    assert data.data.observed.shape == (7, NV)
    assert data.data.state.dtype == jnp.float32


def test_add_wraps_around_like_a_python_ring():
    capacity = 5
    data = dataset.empty(capacity, STATE_DIM, NV)
    ref = RingReference(capacity)
    add = jax.jit(dataset.add)
    start = 0
    # batch sizes that fill, exactly hit, and wrap past the end several times
    for n in (3, 2, 4, 5, 1, 3):
        batch = make_batch(start, n)
        valid = np.ones(n, bool)
        data = add(data, batch, jnp.asarray(valid))
        ref.add(range(start, start + n), valid)
        start += n
        assert_matches(data, ref)
    assert ref.size == capacity


def test_invalid_rows_are_dropped_and_take_no_space():
    capacity = 6
    data = dataset.empty(capacity, STATE_DIM, NV)
    ref = RingReference(capacity)
    rng = np.random.default_rng(1)
    add = jax.jit(dataset.add)
    start = 0
    for n in (4, 5, 6, 3, 6):
        valid = rng.random(n) < 0.6
        data = add(data, make_batch(start, n), jnp.asarray(valid))
        ref.add(range(start, start + n), valid)
        start += n
        assert_matches(data, ref)
    # all-invalid batch: nothing changes
    before = jax.tree.map(np.asarray, data)
    data = add(data, make_batch(start, 4), jnp.zeros(4, bool))
    assert_matches(data, ref)
    jax.tree.map(np.testing.assert_array_equal, before, jax.tree.map(np.asarray, data))


def test_add_default_valid_is_all_rows():
    data = dataset.add(dataset.empty(4, STATE_DIM, NV), make_batch(0, 3))
    ref = RingReference(4)
    ref.add(range(3), [True] * 3)
    assert_matches(data, ref)


def test_add_casts_to_buffer_dtype():
    batch = jax.tree.map(lambda x: x.astype(jnp.int32), make_batch(0, 2))
    data = dataset.add(dataset.empty(3, STATE_DIM, NV), batch)
    assert data.data.state.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(data.data.action[:2, 0]), [0.0, 100.0])


def test_add_rejects_batch_larger_than_capacity():
    with pytest.raises(ValueError, match="exceeds the data set capacity 3"):
        dataset.add(dataset.empty(3, STATE_DIM, NV), make_batch(0, 4))


def test_sample_draws_only_filled_rows():
    capacity = 50
    data = dataset.empty(capacity, STATE_DIM, NV)
    # 7 filled rows, ids 1..7 (row id 0 would be indistinguishable from the zero padding)
    data = dataset.add(data, make_batch(1, 7))
    batch = jax.jit(dataset.sample, static_argnums=2)(data, jax.random.key(0), 2000)
    ids = np.asarray(batch.state[:, 0])
    assert batch.state.shape == (2000, STATE_DIM)
    assert set(ids.tolist()) == set(range(1, 8))  # never an unfilled row, every filled one
    # Rows stay consistent across fields.
    np.testing.assert_array_equal(np.asarray(batch.action[:, 0]), 100 * ids)
    np.testing.assert_array_equal(np.asarray(batch.observed[:, 1]), -ids)
    # Uniform: 2000 draws over 7 rows, each count ~ Binomial(2000, 1/7): mean 285.7, sd 15.6;
    # 6 sd (94) bounds a false failure below 1e-8 per row.
    counts = np.bincount(ids.astype(int), minlength=8)[1:]
    assert np.all(np.abs(counts - 2000 / 7) < 94), counts


def test_sample_after_wrap_draws_all_rows():
    data = dataset.empty(4, STATE_DIM, NV)
    data = dataset.add(data, make_batch(1, 3))
    data = dataset.add(data, make_batch(4, 3))  # ids 1..6 written, buffer keeps 3..6
    batch = dataset.sample(data, jax.random.key(3), 400)
    assert set(np.asarray(batch.state[:, 0]).astype(int).tolist()) == {3, 4, 5, 6}


def test_filled_returns_first_size_rows():
    data = dataset.add(
        dataset.empty(5, STATE_DIM, NV), make_batch(1, 3), valid=jnp.array([True, False, True])
    )
    rows = dataset.filled(data)
    np.testing.assert_array_equal(np.asarray(rows.state[:, 0]), [1.0, 3.0])
    assert rows.action.shape == (2, NV)


def test_add_inside_jit_and_scan_compiles_once():
    # The training loop adds a batch per iteration inside a compiled function: shapes of the
    # data set must not change.
    capacity, n, rounds = 8, 3, 5
    batches = jax.tree.map(
        lambda *xs: jnp.stack(xs), *[make_batch(k * n, n) for k in range(rounds)]
    )
    valid = jnp.asarray(np.random.default_rng(2).random((rounds, n)) < 0.7)

    traces = []

    @jax.jit
    def fill(data, batches, valid):
        def body(data, xs):
            batch, ok = xs
            data = dataset.add(data, batch, ok)
            traces.append("body")  # Python runs only while tracing
            return data, data.size

        traces.append("fill")
        return jax.lax.scan(body, data, (batches, valid))

    # Once from empty and once more from a partly filled set: the second call must reuse
    # the first compilation (the carry's shapes and dtypes do not change with its contents).
    partly = fill(dataset.empty(capacity, STATE_DIM, NV), batches, ~valid)[0]
    assert int(partly.size) > 0
    data, sizes = fill(dataset.empty(capacity, STATE_DIM, NV), batches, valid)
    fill(partly, batches, valid)
    assert traces == ["fill", "body"]  # one trace of fill, the scan body traced once
    assert fill._cache_size() == 1  # one compiled executable for all three calls
    ref = RingReference(capacity)
    expected_sizes = []
    for k in range(rounds):
        ref.add(range(k * n, k * n + n), np.asarray(valid[k]))
        expected_sizes.append(ref.size)
    assert_matches(data, ref)
    np.testing.assert_array_equal(np.asarray(sizes), expected_sizes)
