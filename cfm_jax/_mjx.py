"""``mujoco.mjx``, imported without the lines its optional Warp back end prints.

``import mujoco.mjx`` tries ``import warp`` and, when the optional NVIDIA Warp packages are
not installed, prints ``Failed to import warp: ...`` and ``Failed to import mujoco_warp:
...`` to stdout (mujoco-mjx 3.x). The library never uses that back end, so those two lines
are dropped here; anything else printed while importing is printed as it was. Every module
of the library imports MJX as ``from cfm_jax._mjx import mjx``.
"""

from __future__ import annotations

import contextlib
import io
import sys

if "mujoco.mjx" in sys.modules:  # imported before (by the user): nothing to capture
    from mujoco import mjx
else:
    _printed = io.StringIO()
    with contextlib.redirect_stdout(_printed):
        from mujoco import mjx
    for _line in _printed.getvalue().splitlines():
        if not _line.startswith(("Failed to import warp:", "Failed to import mujoco_warp:")):
            print(_line)

__all__ = ["mjx"]
