"""Shared test setup.

``import cfm_jax`` must come before any JAX computation in the test process: it sets
``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` (see cfm_jax/_xla.py), without which MJX on
the iiwa compiles and runs about 1000x slower.

The suite runs in two pytest-xdist workers, a test file at a time each
(``-n 2 --dist loadfile`` in pyproject.toml). :data:`LONGEST_FIRST` puts the longest files
at the front of the queue, so that neither worker is left with a long file at the end.

JAX's persistent compilation cache is on for the test session, in a fresh temporary folder
(removed at exit; a ``JAX_COMPILATION_CACHE_DIR`` set by the caller is used as it is). Many
tests build their own ``Experiment`` of the same small config, so the same XLA programs are
compiled again and again; with the cache the second compile is a read from disk. The
variables are in the environment, so the scripts and notebooks the tests start in
subprocesses share the cache. A cached executable is the one XLA compiled from the same
program, so results are unchanged; programs with host callbacks (the native simulator's
rollouts) are never cached by JAX.
"""

import atexit
import os
import shutil
import tempfile

if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="cfm_jax_test_xla_cache_")
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

import cfm_jax  # noqa: E402, F401
from cfm_jax import robots  # noqa: E402

# Also when JAX was imported before this file (a plugin) and read the variables too early.
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update(
    "jax_persistent_cache_min_compile_time_secs",
    float(os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")),
)
jax.config.update(
    "jax_persistent_cache_min_entry_size_bytes",
    int(os.environ.get("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")),
)


# The longest test files (``pytest --durations``), started first; the rest follow in
# collection order. Only the order changes, never which tests run.
LONGEST_FIRST = (
    "test_learning_mjx.py",
    "test_sweep.py",
    "test_notebooks.py",
    "test_checkpoint.py",
    "test_train.py",
    "test_legged_task.py",
    "test_learning.py",
    "test_mjx_tasks.py",
    "test_replay.py",
    "test_opspace_task.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FIRST)))  # stable


# The robots most test files use, loaded once per worker (robots.load parses the MJCF).
@pytest.fixture(scope="session")
def iiwa():
    return robots.load("iiwa14")


@pytest.fixture(scope="session")
def arm():
    return robots.load("two_link_arm")


@pytest.fixture(scope="session")
def solo():
    return robots.load("solo12")
