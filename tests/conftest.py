"""Shared test setup.

``import cfm_jax`` must come before any JAX computation in the test process: it sets
``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` (see cfm_jax/_xla.py), without which MJX on
the iiwa compiles and runs about 1000x slower.

The suite runs in two pytest-xdist workers, a test file at a time each
(``-n 2 --dist loadfile --no-loadscope-reorder`` in pyproject.toml). :data:`FILE_SECONDS`
puts the longest files at the front of the queue, so that neither worker is left with a
long file at the end.

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
import subprocess
import sys
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
from cfm_jax.sim import robots  # noqa: E402

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


# Seconds per test file: the full suite with ``--durations=0``, summed per file (two workers
# beside two long studies on 2 cores, 2026-11-29; docs/development.md, "CI time"). Only their
# order matters: the files start longest first and the rest follow in collection order, the
# two workers taking the next file as they free up (``--dist loadfile
# --no-loadscope-reorder``), so that no long file is left for the end. Only the order
# changes, never which tests run. A new long file belongs here. test_learning_mjx.py before
# test_learning.py also lets the native run load the fits' programs that the MJX run put in
# the compilation cache.
FILE_SECONDS = {
    "test_sweep.py": 479,
    "test_dev_robots.py": 416,
    "test_checkpoint.py": 406,
    "test_learning_mjx.py": 338,
    "test_train.py": 313,
    "test_mjx_tasks.py": 305,
    "test_notebooks.py": 265,
    "test_legged_task.py": 255,
    "test_comparison.py": 197,
    "test_docstrings.py": 179,
    "test_own_loss.py": 131,
    "test_servo_robots.py": 96,
    "test_babbling.py": 93,
    "test_replay.py": 81,
    "test_docs.py": 77,
    "test_baselines.py": 76,
    "test_claims.py": 75,
    "test_opspace_task.py": 73,
    "test_normaliser.py": 70,
    "test_xla.py": 68,
    "test_bench.py": 65,
    "test_update.py": 58,
    "test_training_options.py": 48,
    "test_rollout.py": 46,
    "test_rigid_body.py": 46,
    "test_solo12.py": 45,
    "test_networks.py": 44,
    "test_learning.py": 43,
    "test_divergence.py": 41,
    "test_locomotion.py": 41,
    "test_forward_kinds.py": 41,
    "test_coupled_scale.py": 35,
    "test_video.py": 33,
    "test_robot_models.py": 28,
    "test_theory.py": 22,
}


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 0))  # stable


# CFM_JAX_COMPILE_REPORT=DIR: each worker writes DIR/compile_<worker>.json, the seconds of
# JAX's trace, lowering and XLA-compile events per test (this process only, not the CLI
# subprocesses), for docs/development.md's "CI time". Off by default.
_REPORT = os.environ.get("CFM_JAX_COMPILE_REPORT")
_COMPILE_NAMES = (
    "jaxpr_trace_duration",
    "jaxpr_to_mlir_module_duration",
    "backend_compile_duration",
)
_COMPILE_EVENTS = {f"/jax/core/compile/{name}": name for name in _COMPILE_NAMES}
_compile_seconds: dict = {}
_current_test = ["(collection)"]

if _REPORT:
    from jax import monitoring

    def _on_event(event: str, seconds: float, **_) -> None:
        if event in _COMPILE_EVENTS:
            key = (_current_test[0], _COMPILE_EVENTS[event])
            _compile_seconds[key] = _compile_seconds.get(key, 0.0) + seconds

    monitoring.register_event_duration_secs_listener(_on_event)

    def pytest_runtest_setup(item):
        _current_test[0] = item.nodeid

    def pytest_sessionfinish(session):
        import json

        os.makedirs(_REPORT, exist_ok=True)
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(os.path.join(_REPORT, f"compile_{worker}.json"), "w") as f:
            json.dump([[*key, round(s, 3)] for key, s in _compile_seconds.items()], f)


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


@pytest.fixture
def cli_in_process(monkeypatch, capsys):
    """``cli_in_process(*argv)`` runs ``cfm-jax ARGV`` in this process (``cfm_jax.cli.main``)
    and returns its exit status and what it wrote to stdout and stderr as a finished
    subprocess's ``CompletedProcess``; ``sys.argv`` and ``sys.path`` (``--import`` may add a
    directory) are restored after the test. For the commands whose own process is not what
    is tested (docs/development.md, "CI time"): it saves an interpreter and the imports
    (a few seconds each), and the command can reuse the test's ``Experiment`` (patch
    ``training.Experiment``). A command that imports a user's module stays a subprocess."""
    from cfm_jax import cli

    def run(*argv: str) -> subprocess.CompletedProcess:
        monkeypatch.setattr(sys, "argv", ["cfm-jax", *argv])
        monkeypatch.setattr(sys, "path", list(sys.path))
        capsys.readouterr()
        try:
            cli.main()
            code = 0
        except SystemExit as stop:
            code = stop.code
        captured = capsys.readouterr()
        return subprocess.CompletedProcess(list(argv), code, captured.out, captured.err)

    return run
