"""Atomic writes (cfm_jax/_files.py), the one helper every file the library writes goes
through: the target is the old file or the new one, never a part, and nothing is left
behind."""

from __future__ import annotations

import doctest
import os

import numpy as np
import pytest

from cfm_jax import _files


def test_the_new_content_replaces_the_old_and_no_temporary_file_is_left(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text("old")
    with _files.atomic_path(path) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path)  # same folder: same file system
        with open(tmp, "w") as f:
            f.write("new")
        assert path.read_text() == "old"  # not replaced before the block ends
    assert path.read_text() == "new"
    assert sorted(os.listdir(tmp_path)) == ["metrics.csv"]


def test_an_error_while_writing_leaves_the_old_file_and_no_temporary_file(tmp_path):
    path = tmp_path / "data.npz"
    path.write_bytes(b"old")

    def half_write(tmp):
        with open(tmp, "wb") as f:
            f.write(b"par")
        raise KeyboardInterrupt  # as a crash or Ctrl-C in the middle

    with pytest.raises(KeyboardInterrupt):
        _files.write_atomic(path, half_write)
    assert path.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["data.npz"]


def test_write_text_durable_and_a_writer_given_an_open_file(tmp_path):
    _files.write_text(tmp_path / "MANIFEST.json", '{"a": 1}', durable=True)
    assert (tmp_path / "MANIFEST.json").read_text() == '{"a": 1}'
    # np.savez adds ".npz" to a name without it: give it the open file instead.
    path = tmp_path / "reference.cache"
    with _files.atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, x=np.arange(3))
    np.testing.assert_array_equal(np.load(path)["x"], [0, 1, 2])
    assert sorted(os.listdir(tmp_path)) == ["MANIFEST.json", "reference.cache"]


def test_module_example_runs():
    assert doctest.testmod(_files).failed == 0
