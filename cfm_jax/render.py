"""Offscreen pictures of recorded trajectories for any MJCF model (MuJoCo's ``Renderer``).

:func:`render_frames` turns a sequence of ``qpos`` into RGB images, :func:`frame_strip` lays
a few of them side by side into one PNG (like the paper's walking image sequence).

OpenGL: ``mujoco`` picks its GL backend from ``MUJOCO_GL`` when it is imported. Without a
display (``$DISPLAY`` unset) and without ``MUJOCO_GL``, the default GLFW backend cannot start,
so this module uses MuJoCo's EGL context instead (headless, works with Mesa). When no backend
works, :class:`RenderUnavailable` is raised with the reason; :func:`render_available` asks
without raising, so callers can skip pictures with a clear message.

Example:
  >>> import mujoco
  >>> from cfm_jax import render
  >>> model = mujoco.MjModel.from_xml_path("robots/solo12.xml")  # doctest: +SKIP
  >>> render.frame_strip(model, qpos_seq, "walk.png", n_frames=6)  # doctest: +SKIP
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np


class RenderUnavailable(RuntimeError):
    """No OpenGL context could be created (the message says why and what to try)."""


def _gl_context_class():
    """The GLContext class to use, or None for MuJoCo's own choice."""
    if os.environ.get("MUJOCO_GL") or os.environ.get("DISPLAY") or sys.platform != "linux":
        return None
    try:
        from mujoco.egl import GLContext
    except Exception:  # noqa: BLE001 - any import problem means: let MuJoCo decide
        return None
    return GLContext


def _renderer(model, height: int, width: int):
    import mujoco

    cls = _gl_context_class()
    try:
        if cls is None:
            return mujoco.Renderer(model, height, width)
        from mujoco.rendering.classic import gl_context

        saved = gl_context.GLContext
        gl_context.GLContext = cls  # mujoco.Renderer reads this attribute when it starts
        try:
            return mujoco.Renderer(model, height, width)
        finally:
            gl_context.GLContext = saved
    except Exception as err:  # noqa: BLE001 - GL failures come as several exception types
        raise RenderUnavailable(
            f"cannot create an OpenGL context for offscreen rendering ({err}). On a headless "
            "Linux machine set MUJOCO_GL=egl (or osmesa) before Python starts."
        ) from err


def render_available() -> tuple[bool, str]:
    """``(True, "")`` when an offscreen context can be created, else ``(False, reason)``."""
    import mujoco

    try:
        r = _renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8)
    except RenderUnavailable as err:
        return False, str(err)
    r.close()
    return True, ""


def _camera(model, data, camera, track: bool):
    import mujoco

    if isinstance(camera, str | int):
        return camera
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    spec = {"distance": 1.2, "azimuth": 90.0, "elevation": -15.0, "lookat": None}
    spec.update(camera or {})
    cam.distance, cam.azimuth, cam.elevation = spec["distance"], spec["azimuth"], spec["elevation"]
    if spec["lookat"] is not None:
        cam.lookat[:] = spec["lookat"]
    if track or spec["lookat"] is None:
        body = 1 if model.nbody > 1 else 0
        cam.lookat[:] = data.subtree_com[body]
        if spec["lookat"] is not None:
            cam.lookat[2] = spec["lookat"][2]
    return cam


def render_frames(
    model,
    qpos: np.ndarray,
    *,
    width: int = 320,
    height: int = 240,
    camera: str | int | dict | None = None,
    track: bool = True,
) -> np.ndarray:
    """RGB frames ``(N, height, width, 3)`` uint8 of the states ``qpos (N, nq)``.

    ``camera``: a camera name or id of the model, or a dict of free-camera settings
    (``distance``, ``azimuth``, ``elevation``, ``lookat``); default a side view (azimuth 90,
    the camera on the -y side looking along +y) of the first body's subtree COM. With
    ``track`` the free camera follows that COM (height fixed when ``lookat`` is given).
    Raises :class:`RenderUnavailable` when there is no GL.
    """
    import mujoco

    qpos = np.atleast_2d(np.asarray(qpos, float))
    width = min(width, model.vis.global_.offwidth)
    height = min(height, model.vis.global_.offheight)
    renderer = _renderer(model, height, width)
    data = mujoco.MjData(model)
    frames = []
    try:
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=_camera(model, data, camera, track))
            frames.append(renderer.render().copy())
    finally:
        renderer.close()
    return np.stack(frames)


def frame_strip(
    model,
    qpos: np.ndarray,
    path: str | os.PathLike,
    *,
    n_frames: int = 6,
    indices: Sequence[int] | None = None,
    width: int = 320,
    height: int = 240,
    camera: str | int | dict | None = None,
    track: bool = True,
    gap: int = 4,
) -> np.ndarray:
    """Render ``n_frames`` evenly spaced states of ``qpos (T, nq)`` (or the given
    ``indices``) side by side, separated by ``gap`` white pixels, and save a PNG at ``path``.
    Returns the strip image ``(height, n*width + (n-1)*gap, 3)``."""
    import matplotlib.image

    qpos = np.atleast_2d(np.asarray(qpos, float))
    if indices is None:
        indices = np.linspace(0, len(qpos) - 1, n_frames).round().astype(int)
    frames = render_frames(
        model, qpos[np.asarray(indices)], width=width, height=height, camera=camera, track=track
    )
    n, h, _, _ = frames.shape
    white = np.full((h, gap, 3), 255, np.uint8)
    parts = []
    for i, frame in enumerate(frames):
        parts.append(frame)
        if i < n - 1:
            parts.append(white)
    strip = np.concatenate(parts, axis=1)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(str(path), strip)
    return strip
