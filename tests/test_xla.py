"""The XLA:CPU flag (cfm_jax/_xla.py): set before JAX's backend starts, or a clear warning.

Each case runs in a fresh Python process (the flag is read once per process, when the
backend initialises), with XLA_FLAGS removed from the environment.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from cfm_jax import _xla

FLAG = "--xla_cpu_use_fusion_emitters=false"
# Whether the installed jaxlib knows the flag (0.10.x: the CI here; 0.11+: the GPU check's
# machine, experiments/gpu_check.py). The tests of the flag's effects need a jaxlib that
# knows it; those of a newer jaxlib below pretend its version and run on any.
KNOWN = _xla.flag_known(_xla.jaxlib_version())
needs_flag = pytest.mark.skipif(
    not KNOWN, reason=f"jaxlib {_xla.jaxlib_version()} has no such flag (see _xla.py)"
)


def run(code: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"
    return subprocess.run(
        [sys.executable, "-W", "always", "-c", code],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip


def test_import_first_sets_the_flag_before_the_backend_starts():
    # On the installed jaxlib, whichever it is: the flag where it knows it, none where it does
    # not; the first computation runs (an unknown flag would abort the process here).
    done = run(
        "import cfm_jax, os; from jax._src import xla_bridge; "
        "assert not xla_bridge.backends_are_initialized(); "
        "print('flag', os.environ.get('XLA_FLAGS', '')); print('fast', cfm_jax.FAST_XLA); "
        "import jax.numpy as jnp; jnp.ones(1).block_until_ready()"
    )
    assert done.returncode == 0, done.stderr
    assert (f"flag {FLAG}\n" if KNOWN else "flag \n") in done.stdout
    assert "fast True" in done.stdout
    assert "SlowBackendWarning" not in done.stderr


@needs_flag
def test_jax_imported_but_not_started_is_still_in_time():
    # Importing jax does not start its backend: the flag still takes effect.
    done = run(
        "import jax, jax.numpy\nimport cfm_jax\nprint('fast', cfm_jax.FAST_XLA)\n"
        "import jax.numpy as jnp\njnp.ones(1).block_until_ready()"
    )
    assert done.returncode == 0, done.stderr
    assert "fast True" in done.stdout
    assert "SlowBackendWarning" not in done.stderr


@needs_flag
def test_backend_already_started_warns_clearly():
    done = run(
        "import jax.numpy as jnp; jnp.ones(1).block_until_ready()\n"
        "import cfm_jax, os\n"
        "print('fast', cfm_jax.FAST_XLA, 'flag' in os.environ.get('XLA_FLAGS', ''))\n"
        "from cfm_jax import config\nfrom cfm_jax.runs import training\n"
        "cfg = config.Config(robot='two_link_arm', simulator='mjx')\n"
        "training.Experiment(cfg)\n"
    )
    assert done.returncode == 0, done.stderr
    assert "fast False False" in done.stdout
    # At import, and again when MJX is chosen; both say what to do.
    assert done.stderr.count("SlowBackendWarning") == 2
    assert "Import cfm_jax before running any JAX" in done.stderr
    assert "simulator='native'" in done.stderr


@needs_flag
@pytest.mark.parametrize("preset", [FLAG, f"--xla_cpu_enable_fast_math=false {FLAG}"])
def test_user_flag_is_respected(preset):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["XLA_FLAGS"] = preset
    done = subprocess.run(
        [sys.executable, "-c", "import cfm_jax, os; print(os.environ['XLA_FLAGS'])"],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == preset  # not duplicated, not reordered


# ---- which jaxlib knows the flag: decided from a version string, never an abort ----------
# The oracle for "knows": jaxlib 0.10.x accepts the flag (the suite runs under it; see
# cfm_jax/_xla.py), jaxlib 0.11.2 aborts on it (the H100 report). On a jaxlib newer
# than the 0.10 series no flag may be set, so the running process cannot abort.

# Before cfm_jax is imported, make importlib.metadata report another jaxlib version (what a
# user with that jaxlib installed would have); the real jaxlib 0.10.2 then runs the
# computation, which shows that the import left no flag in XLA_FLAGS to abort on.
_PRETEND = (
    "import importlib.metadata as md\n"
    "_real = md.version\n"
    "md.version = lambda name: {version!r} if name == 'jaxlib' else _real(name)\n"
)


def _versions_case(version: str, code: str, preset: str | None = None):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"
    if preset is not None:
        env["XLA_FLAGS"] = preset
    return subprocess.run(
        [sys.executable, "-W", "always", "-c", _PRETEND.format(version=version) + code],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip


@pytest.mark.parametrize(
    "version, known",
    [
        ("0.10.0", True), ("0.10.2", True), ("0.10.2.dev20261001", True),
        ("0.11.0", False), ("0.11.2", False), ("0.12.0", False), ("1.0.0", False),
        ("0.9.2", False), ("", False), ("not-a-version", False), (None, False),
    ],
)  # fmt: skip
def test_flag_known_from_the_version_string(version, known):
    assert _xla.flag_known(version) is known


def test_installed_jaxlib_is_read_without_importing_jax():
    import importlib.metadata

    assert _xla.jaxlib_version() == importlib.metadata.version("jaxlib")


@pytest.mark.parametrize("version", ["0.11.2", "0.12.0"])
def test_newer_jaxlib_gets_no_flag_and_runs(version):
    done = _versions_case(
        version,
        "import cfm_jax, os\n"
        "print('flags', repr(os.environ.get('XLA_FLAGS', '')), 'fast', cfm_jax.FAST_XLA)\n"
        "import jax.numpy as jnp\nprint('sum', float(jnp.ones(3).sum()))\n"
        "from cfm_jax import _xla\nprint('mjx fast', _xla.fast_path_active())\n",
    )
    assert done.returncode == 0, done.stderr
    assert "flags '' fast True" in done.stdout
    assert "sum 3.0" in done.stdout and "mjx fast True" in done.stdout
    assert "Warning" not in done.stderr  # no SlowBackendWarning telling them to set the flag


def test_newer_jaxlib_removes_a_user_set_flag_with_a_warning():
    done = _versions_case(
        "0.11.2",
        "import cfm_jax, os\nprint('flags', repr(os.environ['XLA_FLAGS']))\n"
        "import jax.numpy as jnp\nprint('sum', float(jnp.ones(3).sum()))\n",
        preset=f"--xla_cpu_enable_fast_math=false {FLAG}",
    )
    assert done.returncode == 0, done.stderr
    assert "flags '--xla_cpu_enable_fast_math=false'" in done.stdout
    assert "UnknownFlagWarning" in done.stderr and "jaxlib 0.11.2" in done.stderr
    assert "sum 3.0" in done.stdout


def test_jaxlib_0_10_still_gets_the_flag():
    # The installed 0.10.2 is read for real in the tests above; here the lowest allowed series.
    done = _versions_case("0.10.0", "import cfm_jax, os\nprint('flags', os.environ['XLA_FLAGS'])\n")
    assert done.returncode == 0, done.stderr
    assert f"flags {FLAG}" in done.stdout


# ---- the persistent compilation cache (issue 46) -------------------------------------------

_CACHED_PROGRAM = (
    "import cfm_jax, jax, jax.numpy as jnp, json; from jax._src import monitoring; "
    "events = []; monitoring.register_event_listener("
    "lambda name, **kw: events.append(name.rsplit('/', 1)[-1]) if 'cache_' in name else None); "
    "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0); "
    "jax.jit(lambda x: jnp.sin(x) @ x.T)(jnp.ones((64, 64))).block_until_ready(); "
    "print(json.dumps([cfm_jax.COMPILATION_CACHE, jax.config.jax_compilation_cache_dir, events]))"
)


def _cache_run(tmp_path, **env) -> list:
    import json

    # Without the test session's own cache (conftest.py) and the variables that set it.
    dropped = ("XLA_FLAGS", _xla.CACHE_VARIABLE, "JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE")
    base = {k: v for k, v in os.environ.items() if not k.startswith(dropped)}
    done = subprocess.run(
        [sys.executable, "-c", _CACHED_PROGRAM], capture_output=True, text=True, timeout=300,
        env={**base, "JAX_PLATFORMS": "cpu", "XDG_CACHE_HOME": str(tmp_path / "xdg"), **env},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_compilation_cache_is_on_by_default_and_a_second_process_loads_the_program(tmp_path):
    # Oracle: JAX's own monitoring events. The first process misses and writes the program
    # under $XDG_CACHE_HOME/cfm_jax/jax; a second process of the same program hits it.
    folder = str(tmp_path / "xdg" / "cfm_jax" / "jax")
    first = _cache_run(tmp_path)
    assert first[:2] == [folder, folder]
    assert "cache_misses" in first[2] and "cache_hits" not in first[2]
    assert os.listdir(folder)
    second = _cache_run(tmp_path)
    assert "cache_hits" in second[2] and "cache_misses" not in second[2]


def test_compilation_cache_folder_and_off_switch(tmp_path):
    own = str(tmp_path / "own")
    assert _cache_run(tmp_path, CFM_JAX_COMPILATION_CACHE=own)[:2] == [own, own]
    for off in ("0", "off", ""):
        cache, jax_dir, events = _cache_run(tmp_path, CFM_JAX_COMPILATION_CACHE=off)
        assert cache is None and jax_dir is None and "cache_hits" not in events
    # A folder the user gave JAX is kept.
    user = str(tmp_path / "user")
    got = _cache_run(tmp_path, JAX_COMPILATION_CACHE_DIR=user)
    assert got[:2] == [user, user]


def test_experiment_compiler_options_reach_xla():
    """``Experiment(config, compiler_options=...)`` compiles its programs with them: an option
    XLA does not know fails the first compile, and without LLVM's optimisation the baselines
    are those of the default build up to float32 rounding."""
    import numpy as np

    import cfm_jax

    config = cfm_jax.Config(robot="two_link_arm", task=cfm_jax.TaskConfig(duration=0.1))
    default = cfm_jax.Experiment(config).baselines()
    fast = cfm_jax.Experiment(config, compiler_options={"xla_backend_optimization_level": 0})
    np.testing.assert_allclose(
        fast.baselines()["tracking_mse"], default["tracking_mse"], rtol=1e-4, atol=1e-12
    )
    with pytest.raises(Exception, match="no_such_xla_option"):
        cfm_jax.Experiment(config, compiler_options={"no_such_xla_option": 1}).baselines()
