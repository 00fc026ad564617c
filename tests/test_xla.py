"""The XLA:CPU flag (cfm_jax/_xla.py): set before JAX's backend starts, or a clear warning.

Each case runs in a fresh Python process (the flag is read once per process, when the
backend initialises), with XLA_FLAGS removed from the environment.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

FLAG = "--xla_cpu_use_fusion_emitters=false"


def run(code: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"
    return subprocess.run(
        [sys.executable, "-W", "always", "-c", code],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip


def test_import_first_sets_the_flag_before_the_backend_starts():
    done = run(
        "import cfm_jax, os; from jax._src import xla_bridge; "
        "assert not xla_bridge.backends_are_initialized(); "
        "print('flag', os.environ['XLA_FLAGS']); print('fast', cfm_jax.FAST_XLA); "
        "import jax.numpy as jnp; jnp.ones(1).block_until_ready()"
    )
    assert done.returncode == 0, done.stderr
    assert f"flag {FLAG}" in done.stdout and "fast True" in done.stdout
    assert "SlowBackendWarning" not in done.stderr


def test_jax_imported_but_not_started_is_still_in_time():
    # Importing jax does not start its backend: the flag still takes effect.
    done = run(
        "import jax, jax.numpy\nimport cfm_jax\nprint('fast', cfm_jax.FAST_XLA)\n"
        "import jax.numpy as jnp\njnp.ones(1).block_until_ready()"
    )
    assert done.returncode == 0, done.stderr
    assert "fast True" in done.stdout
    assert "SlowBackendWarning" not in done.stderr


def test_backend_already_started_warns_clearly():
    done = run(
        "import jax.numpy as jnp; jnp.ones(1).block_until_ready()\n"
        "import cfm_jax, os\n"
        "print('fast', cfm_jax.FAST_XLA, 'flag' in os.environ.get('XLA_FLAGS', ''))\n"
        "from cfm_jax import config, training\n"
        "cfg = config.Config(robot='two_link_arm', simulator='mjx')\n"
        "training.Experiment(cfg)\n"
    )
    assert done.returncode == 0, done.stderr
    assert "fast False False" in done.stdout
    # At import, and again when MJX is chosen; both say what to do.
    assert done.stderr.count("SlowBackendWarning") == 2
    assert "Import cfm_jax before running any JAX" in done.stderr
    assert "simulator='native'" in done.stderr


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
