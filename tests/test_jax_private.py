"""Private JAX APIs (cfm_jax/_jax_private.py): used in that module only, found in the
installed JAX, and each with a public fallback that gives the same results."""

from __future__ import annotations

import re
from pathlib import Path

import jax.numpy as jnp

from cfm_jax import _jax_private, _xla

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
    """With the JAX this library pins, the private API it reads is there (a JAX upgrade that
    drops it fails here, not silently)."""
    jnp.zeros(1).block_until_ready()
    assert _jax_private.backends_are_initialized() is True
    assert _xla.backend_started() is True


def test_missing_private_apis_give_none(monkeypatch):
    from jax._src import xla_bridge

    monkeypatch.delattr(xla_bridge, "backends_are_initialized")
    assert _jax_private.backends_are_initialized() is None
    assert _xla.backend_started() is False  # not known: no warning about the flag
