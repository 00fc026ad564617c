"""Where the shipped robot files are and their names: the lowest layer, so that
:mod:`cfm_jax.config` and :mod:`cfm_jax.sim.robots` use it without importing each other."""

from __future__ import annotations

import importlib.resources
import pathlib

ROBOT_PACKAGE = "cfm_jax._robot_files"


def robot_dir():
    """The package data ``cfm_jax._robot_files``, else the source checkout's ``robots/``."""
    try:
        return importlib.resources.files(ROBOT_PACKAGE)
    except ModuleNotFoundError:
        return pathlib.Path(__file__).resolve().parent.parent / "robots"


def registered() -> tuple[str, ...]:
    """Sorted names of the shipped robots (see :func:`cfm_jax.sim.robots.registered`)."""
    files = robot_dir()
    return tuple(sorted(p.name[:-4] for p in files.iterdir() if p.name.endswith(".xml")))
