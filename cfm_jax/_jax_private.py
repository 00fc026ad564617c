"""Every use of a private JAX API in cfm_jax, each with its public fallback.

JAX's private modules (``jax._src``) change without notice. The library uses two things
from them; each function here returns None when its private API is missing, and the
caller then takes the public path with the same results:

* :func:`host_callback_lowering`: XLA's host callback emitted directly
  (``jax._src.callback.emit_python_callback``), what ``cfm_jax.native.host_step``
  lowers its primitive to on CPU: ~7 us per call instead of ~95 us. Fallback:
  ``jax.pure_callback`` (``cfm_jax.native.FAST_CALLBACK`` says which is in use).
* :func:`backends_are_initialized`: whether JAX has started a backend
  (``jax._src.xla_bridge.backends_are_initialized``), so that
  ``cfm_jax._xla.configure`` can warn when its XLA flag came too late. Fallback: not
  known, no warning (the flag is still set for the next process).

Nothing else in the library may import ``jax._src`` (``tests/test_jax_private.py``
checks the sources). JAX is imported inside the functions: ``cfm_jax._xla`` must run
before JAX is first imported.
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
    """Marks a primitive as needing devices while it is lowered
    (``jax._src.dispatch.prim_requires_devices_during_lowering.add``)."""


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
    """Whether JAX has initialised a backend in this process; None where this JAX version
    does not say."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return None
