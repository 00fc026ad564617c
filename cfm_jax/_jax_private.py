"""Every use of a private JAX API (``jax._src``) in cfm_jax: each function returns None
where its private API is missing, and the caller takes a public path. Nothing else may
import ``jax._src`` (``tests/test_jax_private.py``); JAX is imported late, for ``_xla``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple


class HostCallback(NamedTuple):
    """The private pieces of a primitive lowered to XLA's host callback."""

    emit: Callable[..., Any]
    """``jax._src.callback.emit_python_callback``."""
    op_sharding: Callable[..., Any]
    """``jax._src.callback._callback_op_sharding``."""
    requires_devices: Callable[[Any], None]
    """``jax._src.dispatch.prim_requires_devices_during_lowering.add``."""


def host_callback_lowering() -> HostCallback | None:
    """The private host-callback API of this JAX version, or None where it is missing."""
    try:
        from jax._src import callback, dispatch

        return HostCallback(
            callback.emit_python_callback,
            callback._callback_op_sharding,
            dispatch.prim_requires_devices_during_lowering.add,
        )
    except (ImportError, AttributeError):
        return None


def backends_are_initialized() -> bool | None:
    """Whether JAX has initialised a backend; None where this JAX version does not say."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return None
