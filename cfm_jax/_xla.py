"""XLA:CPU configuration that MJX needs to be fast, applied before JAX's backend starts.

Measured on a 2-core CPU (mujoco-mjx 3.17, jax 0.10): with XLA:CPU's fusion emitters (the
default) the cost of MJX kinematics grows exponentially with kinematic-chain depth inside a
vmapped step; the 7-DoF iiwa (depth 8) stepped at ~114 steps/s at batch 16.
``--xla_cpu_use_fusion_emitters=false`` brings it to ~1e5 steps/s. The flag is read once,
when the backend initialises (the first computation), so it must be in ``XLA_FLAGS`` before
that, even if ``jax`` was already imported.

Which XLA knows the flag. XLA aborts the whole process (a C++ fatal error, no Python
exception) at the first computation when ``XLA_FLAGS`` holds a flag it does not know, so
the flag is set only where the running jaxlib is known to accept it, decided from jaxlib's
version string (read from the installed package's metadata, without starting JAX):

- jaxlib 0.10.0 and 0.10.2 accept it (0.10.2: the whole test suite runs with it; 0.10.0: a
  computation under the flag ran here, 2026-11-26, while an unknown flag aborted the same
  way); 0.10.1 lies between them and is taken to accept it too;
- jaxlib 0.11.2 aborts on it ("Unknown flag in XLA_FLAGS: --xla_cpu_use_fusion_emitters=false",
  on an H100 machine, 2026-11-26; XLA had retired the legacy CPU emitters the flag fell back
  to, openxla/xla#48001).

So :data:`LAST_SERIES_WITH_FLAG` is 0.10: any later jaxlib, or one whose version cannot be
read, runs without the flag (never an abort; MJX on CPU may then be slower, unmeasured on
jaxlib 0.11+). A flag the user put in ``XLA_FLAGS`` themselves is removed, with a warning,
where the running jaxlib would abort on it.
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import warnings

from cfm_jax import _jax_private

FAST_FLAG = "--xla_cpu_use_fusion_emitters=false"
_FLAG_NAME = "--xla_cpu_use_fusion_emitters"

# The jaxlib (major, minor) series whose XLA accepts FAST_FLAG (evidence: module docstring);
# the first is the oldest pyproject allows.
FIRST_SERIES_WITH_FLAG = (0, 10)
LAST_SERIES_WITH_FLAG = (0, 10)


class SlowBackendWarning(UserWarning):
    """JAX started before cfm_jax could set the XLA flag MJX needs on CPU."""


class UnknownFlagWarning(UserWarning):
    """``XLA_FLAGS`` held a flag the running XLA does not know (it would abort the process)."""


def _is_flag(entry: str) -> bool:
    """Whether one entry of ``XLA_FLAGS`` sets :data:`FAST_FLAG`'s flag (any value)."""
    return entry.split("=")[0] == _FLAG_NAME


def _flag_present(flags: str) -> bool:
    return any(_is_flag(f) for f in flags.split())


def jaxlib_version() -> str | None:
    """The installed jaxlib's version string, read without importing it; None if not found."""
    try:
        return importlib.metadata.version("jaxlib")
    except importlib.metadata.PackageNotFoundError:
        return None


def flag_known(version: str | None) -> bool:
    """True when the XLA of jaxlib ``version`` (a version string) accepts :data:`FAST_FLAG`.

    Decided from the (major, minor) series against :data:`LAST_SERIES_WITH_FLAG`; a version
    that cannot be parsed (or None) counts as not known, the choice that cannot abort.

    Examples:
      >>> flag_known("0.10.2"), flag_known("0.11.2"), flag_known("0.12.0.dev20261101")
      (True, False, False)
      >>> flag_known(None), flag_known("garbage")
      (False, False)
    """
    if version is None:
        return False
    match = re.match(r"(\d+)\.(\d+)", version)
    if match is None:
        return False
    series = (int(match.group(1)), int(match.group(2)))
    return FIRST_SERIES_WITH_FLAG <= series <= LAST_SERIES_WITH_FLAG


def configure() -> bool:
    """Put :data:`FAST_FLAG` into ``XLA_FLAGS`` where it helps and cannot abort.

    Returns True when nothing slows MJX down that cfm_jax could have helped: the flag is in
    force (set here or by the user), or the running jaxlib has no such flag (0.11 and later).
    Returns False when JAX's backend was already initialised without the flag on a jaxlib
    that knows it; a :class:`SlowBackendWarning` then says what to do. Where the running
    jaxlib does not know the flag and the user set it, it is removed from ``XLA_FLAGS``
    (:class:`UnknownFlagWarning`): XLA would abort the process at the first computation.
    Idempotent.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    version = jaxlib_version()
    if not flag_known(version):
        if _flag_present(flags) and not backend_started():
            kept = " ".join(f for f in flags.split() if not _is_flag(f))
            os.environ["XLA_FLAGS"] = kept
            warnings.warn(
                f"XLA_FLAGS held {_FLAG_NAME}, which the XLA of jaxlib {version} does not "
                "know: XLA would abort this process at its first computation. cfm_jax "
                f"removed it (XLA_FLAGS is now {kept!r}); remove it where you set it.",
                UnknownFlagWarning,
                stacklevel=3,
            )
        return True
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
    """True when nothing cfm_jax could set is missing for MJX's speed on CPU.

    On a jaxlib that knows :data:`FAST_FLAG`: the flag is in the environment (and so, if the
    backend started after, in force). On a later jaxlib, which has no such flag: always True.
    """
    if not flag_known(jaxlib_version()):
        return True
    return _flag_present(os.environ.get("XLA_FLAGS", ""))
