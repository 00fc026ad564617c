"""Every use of a private JAX API (``jax._src``) in cfm_jax: each function returns None
where its private API is missing, and the caller takes a public path. Nothing else may
import ``jax._src`` (``tests/test_jax_private.py``); JAX is imported late, for ``_xla``.
"""

from __future__ import annotations


def backends_are_initialized() -> bool | None:
    """Whether JAX has initialised a backend; None where this JAX version does not say."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return None
