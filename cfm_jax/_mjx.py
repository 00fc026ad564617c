"""``mujoco.mjx``, imported without the two ``Failed to import warp`` lines it prints when
the optional Warp back end (never used here) is missing; import MJX from here.
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
