"""XLA:CPU configuration that MJX needs to be fast, applied before JAX's backend starts.

:data:`FAST_FLAG` keeps MJX kinematics from slowing exponentially with chain depth. XLA
aborts on a flag it does not know: it is set only on jaxlib 0.10 (docs/performance.md).
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
    """Whether the XLA of jaxlib ``version`` (a version string) accepts :data:`FAST_FLAG`;
    None or an unparsable version counts as not (the choice that cannot abort)."""
    if version is None:
        return False
    match = re.match(r"(\d+)\.(\d+)", version)
    if match is None:
        return False
    series = (int(match.group(1)), int(match.group(2)))
    return FIRST_SERIES_WITH_FLAG <= series <= LAST_SERIES_WITH_FLAG


def configure() -> bool:
    """Set :data:`FAST_FLAG` where it helps and cannot abort (else remove a user's); False if
    JAX already started without it (:class:`SlowBackendWarning`). Idempotent."""
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
    """True unless a jaxlib that knows :data:`FAST_FLAG` runs without it in the environment."""
    if not flag_known(jaxlib_version()):
        return True
    return _flag_present(os.environ.get("XLA_FLAGS", ""))


CACHE_VARIABLE = "CFM_JAX_COMPILATION_CACHE"
"""The environment variable that sets JAX's persistent compilation cache for cfm_jax: unset,
the folder :func:`cache_folder` names; ``0``, ``off`` or empty: no cache; else a folder."""


def cache_folder() -> str | None:
    """Where :func:`use_compilation_cache` keeps compiled programs: :data:`CACHE_VARIABLE`'s
    folder, else ``$XDG_CACHE_HOME/cfm_jax/jax`` (``~/.cache/cfm_jax/jax``); None when the
    variable turns the cache off."""
    value = os.environ.get(CACHE_VARIABLE)
    if value is not None:
        return None if value.strip().lower() in ("", "0", "off", "false", "no") else value
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "cfm_jax", "jax")


def use_compilation_cache() -> str | None:
    """Turn on JAX's persistent compilation cache in :func:`cache_folder` (a second run of the
    same shapes loads its programs instead of compiling them), unless the user set one
    (``jax_compilation_cache_dir``) or turned it off; returns the folder in use, or None.

    The native simulator's rollouts are cached too (their host calls go through an FFI
    target, :mod:`cfm_jax.sim.host`); JAX caches no program with a ``jax.pure_callback``.
    Idempotent."""
    import jax

    current = jax.config.jax_compilation_cache_dir
    if current:
        return current
    folder = cache_folder()
    if folder is None:
        return None
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as error:
        warnings.warn(
            f"the compilation cache folder {folder} cannot be made ({error.strerror}): "
            f"compiling without it; set {CACHE_VARIABLE} to another folder or to 0",
            stacklevel=3,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", folder)
    return folder
