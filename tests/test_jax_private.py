"""Private JAX APIs (cfm_jax/_jax_private.py): used in that module only, found in the
installed JAX, and each with a public fallback that gives the same results."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax import _jax_private, _xla
from cfm_jax.sim import native, robots

PACKAGE = Path(__file__).resolve().parent.parent / "cfm_jax"
PRIVATE = re.compile(r"^\s*(from\s+jax\._src\b|import\s+jax\._src\b)|jax\._src\.\w+\(", re.M)


def test_no_other_module_uses_a_private_jax_api():
    users = [
        str(path.relative_to(PACKAGE))
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "_jax_private.py" and PRIVATE.search(path.read_text())
    ]
    assert users == []
    assert PRIVATE.search((PACKAGE / "_jax_private.py").read_text())  # the pattern matches


def test_the_installed_jax_has_what_the_library_uses():
    """With the JAX this library pins, the fast paths are on (a JAX upgrade that drops a
    private API fails here, not silently slower)."""
    assert _jax_private.host_callback_lowering() is not None
    jnp.zeros(1).block_until_ready()
    assert _jax_private.backends_are_initialized() is True
    assert _xla.backend_started() is True


def test_missing_private_apis_give_none(monkeypatch):
    from jax._src import callback, xla_bridge

    monkeypatch.delattr(callback, "emit_python_callback")
    monkeypatch.delattr(xla_bridge, "backends_are_initialized")
    assert _jax_private.host_callback_lowering() is None
    assert _jax_private.backends_are_initialized() is None
    assert _xla.backend_started() is False  # not known: no warning about the flag


@pytest.fixture
def fresh_native(monkeypatch):
    """native builds its primitive once per process; start it again for this test."""
    monkeypatch.setattr(native, "_PRIMITIVE", None)
    monkeypatch.setattr(native, "FAST_CALLBACK", None)


def test_host_step_without_the_private_api_falls_back_with_the_same_results(
    monkeypatch, fresh_native
):
    arm = robots.load("two_link_arm")
    stepper = native.Stepper(arm.mj_model, n_sub=3, threads=1)
    rng = np.random.default_rng(3)
    q, qd, u = (jnp.asarray(rng.uniform(-1, 1, (4, 2)), jnp.float32) for _ in range(3))

    def run():
        step = jax.jit(jax.vmap(lambda a, b, c: native.host_step(stepper, a, b, c)))
        return [np.asarray(x) for x in step(q, qd, u)]

    monkeypatch.setattr(_jax_private, "host_callback_lowering", lambda: None)
    public = run()
    assert native.FAST_CALLBACK is False  # the fallback: jax.pure_callback
    monkeypatch.undo()
    native._PRIMITIVE, native.FAST_CALLBACK = None, None
    private = run()
    # The direct host callback exists for XLA:CPU only; on a GPU both runs fall back.
    assert native.FAST_CALLBACK is (jax.default_backend() == "cpu")
    for a, b in zip(public, private, strict=True):
        np.testing.assert_array_equal(a, b)
    # Oracle: MuJoCo C stepped directly by the Stepper, no JAX.
    want = stepper(np.asarray(q), np.asarray(qd), np.asarray(u))
    for a, w in zip(public, want, strict=True):
        np.testing.assert_array_equal(a, np.asarray(w, np.float32))


def test_host_step_on_another_backend_uses_pure_callback(monkeypatch, fresh_native):
    # On a GPU the direct host callback (registered for XLA:CPU only) is not used: the step
    # goes through jax.pure_callback and FAST_CALLBACK says False (it stayed None on the
    # H100 of 2026-11-27). The backend's name is what host_step decides on.
    arm = robots.load("two_link_arm")
    stepper = native.Stepper(arm.mj_model, n_sub=2, threads=1)
    rng = np.random.default_rng(5)
    q, qd, u = (jnp.asarray(rng.uniform(-1, 1, (3, 2)), jnp.float32) for _ in range(3))
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    got = jax.jit(jax.vmap(lambda a, b, c: native.host_step(stepper, a, b, c)))(q, qd, u)
    assert native.FAST_CALLBACK is False and native._PRIMITIVE is None
    want = stepper(np.asarray(q), np.asarray(qd), np.asarray(u))  # MuJoCo C, no JAX
    for a, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(w, np.float32))
