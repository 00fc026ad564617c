"""XLA:CPU configuration that MJX needs to be fast, applied before JAX's backend starts.

Measured on a 2-core CPU (mujoco-mjx 3.17, jax 0.10): with XLA:CPU's fusion emitters (the
default) the cost of MJX kinematics grows exponentially with kinematic-chain depth inside a
vmapped step; the 7-DoF iiwa (depth 8) stepped at ~114 steps/s at batch 16.
``--xla_cpu_use_fusion_emitters=false`` brings it to ~1e5 steps/s. The flag is read once,
when the backend initialises (the first computation), so it must be in ``XLA_FLAGS`` before
that, even if ``jax`` was already imported.
"""

from __future__ import annotations

import os
import warnings

from cfm_jax import _jax_private

FAST_FLAG = "--xla_cpu_use_fusion_emitters=false"


class SlowBackendWarning(UserWarning):
    """JAX started before cfm_jax could set the XLA flag MJX needs on CPU."""


def _flag_present(flags: str) -> bool:
    return any(f.startswith("--xla_cpu_use_fusion_emitters") for f in flags.split())


def configure() -> bool:
    """Put :data:`FAST_FLAG` into ``XLA_FLAGS`` if JAX's backend has not started yet.

    Returns True when the fast configuration is in force (or the user set the flag
    explicitly), False when JAX's backend was already initialised without it; in that case a
    :class:`SlowBackendWarning` says what to do. Idempotent.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if _flag_present(flags):
        return True
    if backend_started():
        warnings.warn(
            "JAX's backend was initialised before cfm_jax was imported, without "
            f"XLA_FLAGS={FAST_FLAG}. With simulator='mjx', MJX rollouts of deep kinematic "
            "chains (the iiwa) will run about 1000x slower on CPU (the default "
            "simulator='native' is not affected). Import cfm_jax before running any JAX "
            f"computation, or start Python with XLA_FLAGS={FAST_FLAG} (restart the "
            "notebook kernel).",
            SlowBackendWarning,
            stacklevel=3,
        )
        return False
    os.environ["XLA_FLAGS"] = (flags + " " + FAST_FLAG).strip()
    return True


def warn_if_slow_mjx() -> None:
    """Warn (:class:`SlowBackendWarning`) when MJX is about to be used without the flag."""
    if not fast_path_active():
        warnings.warn(
            f"simulator='mjx' without XLA_FLAGS={FAST_FLAG} in force (JAX started before "
            "cfm_jax was imported): MJX rollouts of deep kinematic chains will be very slow "
            f"on CPU. Restart Python with XLA_FLAGS={FAST_FLAG}, import cfm_jax first, or "
            "use simulator='native'.",
            SlowBackendWarning,
            stacklevel=3,
        )


def backend_started() -> bool:
    """True when JAX has initialised a backend in this process (XLA flags are then fixed)."""
    import sys

    if "jax" not in sys.modules:
        return False
    return bool(_jax_private.backends_are_initialized())  # None (not known): False


def fast_path_active() -> bool:
    """True when the flag is in the environment and so (if the backend started after) in force."""
    return _flag_present(os.environ.get("XLA_FLAGS", ""))
