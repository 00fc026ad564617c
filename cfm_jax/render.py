"""Offscreen pictures of recorded trajectories for any MJCF model (MuJoCo's ``Renderer``).

:func:`render_frames` turns a sequence of ``qpos`` into RGB images, :func:`frame_strip` lays
a few of them side by side into one PNG (like the paper's walking image sequence).

OpenGL: ``mujoco`` picks its GL backend from ``MUJOCO_GL`` when it is imported. Without a
display (``$DISPLAY`` unset) and without ``MUJOCO_GL``, the default GLFW backend cannot start,
so this module uses MuJoCo's EGL context instead (headless, works with Mesa). When no backend
works, :class:`RenderUnavailable` is raised with the reason; :func:`render_available` asks
without raising, so callers can skip pictures with a clear message.

Examples:
  >>> import mujoco
  >>> from cfm_jax import render
  >>> # not run: it needs offscreen OpenGL (MUJOCO_GL=egl or osmesa), which CI may lack
  >>> model = mujoco.MjModel.from_xml_path("robots/solo12.xml")  # doctest: +SKIP
  >>> render.frame_strip(model, qpos_seq, "walk.png", n_frames=6)  # doctest: +SKIP
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cfm_jax._files import atomic_path


class RenderUnavailable(RuntimeError):
    """No OpenGL context could be created (the message says why and what to try).

    Examples:
      >>> # not run: it needs offscreen OpenGL (MUJOCO_GL=egl or osmesa), which CI may lack
      >>> try:
      ...     frames = render_frames(model, qpos)  # doctest: +SKIP
      ... except RenderUnavailable as error:
      ...     print(error)  # doctest: +SKIP
    """


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
    """Whether an offscreen OpenGL context can be created here.

    Returns:
      ``(True, "")`` when it can, else ``(False, reason)``.

    Examples:
      >>> ok, why = render_available()
      >>> isinstance(ok, bool) and (ok or "MUJOCO_GL" in why)
      True
    """
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
    """RGB frames of the states ``qpos (N, nq)``, offscreen.

    Args:
      model: a ``mujoco.MjModel``.
      qpos: ``(N, nq)`` generalised positions (one ``(nq,)`` state is accepted too).
      width: image width in pixels (at most the model's ``offwidth``).
      height: image height in pixels (at most the model's ``offheight``).
      camera: a camera name or id of the model, or a dict of free-camera settings
        (``distance``, ``azimuth``, ``elevation``, ``lookat``); default a side view (azimuth
        90, the camera on the -y side looking along +y) of the first body's subtree COM.
      track: the free camera follows that COM (height fixed when ``lookat`` is given).

    Returns:
      ``(N, height, width, 3)`` uint8.

    Raises:
      RenderUnavailable: no OpenGL context.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> # not run: it needs offscreen OpenGL (MUJOCO_GL=egl or osmesa), which CI may lack
      >>> frames = render_frames(arm.mj_model, arm.home, width=64, height=48)  # doctest: +SKIP
      >>> frames.shape  # doctest: +SKIP
      (1, 48, 64, 3)
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
    """Render a few states side by side into one PNG (like the paper's image sequences).

    Args:
      model: a ``mujoco.MjModel``.
      qpos: ``(T, nq)`` generalised positions.
      path: the PNG to write (folders are created).
      n_frames: number of evenly spaced states to show (when ``indices`` is None).
      indices: the states to show instead.
      width: width of each frame in pixels.
      height: height of each frame in pixels.
      camera: as for :func:`render_frames`.
      track: as for :func:`render_frames`.
      gap: white pixels between frames.

    Returns:
      The strip image ``(height, n * width + (n - 1) * gap, 3)`` uint8.

    Raises:
      RenderUnavailable: no OpenGL context.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> # not run: it needs offscreen OpenGL (MUJOCO_GL=egl or osmesa), which CI may lack
      >>> strip = frame_strip(arm.mj_model, [arm.home] * 10, "/tmp/strip.png", n_frames=3,
      ...                     width=64, height=48, gap=4)  # doctest: +SKIP
      >>> strip.shape  # doctest: +SKIP
      (48, 200, 3)
    """
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
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    with atomic_path(path) as tmp, open(tmp, "wb") as f:  # written whole, renamed into place
        matplotlib.image.imsave(f, strip, format=fmt)
    return strip


VIDEO_FORMATS = (".mp4", ".gif")
"""File extensions :func:`write_video` and :func:`video` can write."""


def write_video(frames: np.ndarray, path: str | os.PathLike, *, fps: float = 30.0) -> Path:
    """Write RGB frames as an MP4 (H.264) or an animated GIF, chosen by ``path``'s extension.

    MP4 goes through imageio's ffmpeg plugin (``imageio-ffmpeg`` ships its own ffmpeg
    binary; ``pip install "cfm_jax[video]"``), with ``yuv420p`` pixels so browsers and
    notebooks play it; frames of odd width or height are padded by one edge pixel. GIF goes
    through Pillow and loops forever.

    Args:
      frames: ``(N, height, width, 3)`` uint8 RGB images, for example from
        :func:`render_frames`.
      path: output file ending in ``.mp4`` or ``.gif`` (folders are created).
      fps: frames per second of playback, > 0.

    Returns:
      The path written.

    Raises:
      ValueError: frames of the wrong shape or dtype, an unknown extension or a bad ``fps``.
      RuntimeError: MP4 asked for and imageio's ffmpeg plugin is not installed.

    Examples:
      >>> import numpy as np, tempfile, os
      >>> frames = np.zeros((5, 32, 48, 3), np.uint8)
      >>> frames[:, :, :24] = 255  # left half white
      >>> out = write_video(frames, os.path.join(tempfile.mkdtemp(), "clip.gif"), fps=10)
      >>> out.suffix
      '.gif'
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or not len(frames):
        raise ValueError(
            f"frames must be a non-empty uint8 array (N, height, width, 3); got dtype "
            f"{frames.dtype} and shape {frames.shape}"
        )
    if not (isinstance(fps, int | float) and np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps={fps!r} is not allowed: a finite number > 0")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in VIDEO_FORMATS:
        raise ValueError(f"path={str(path)!r}: the extension must be one of {VIDEO_FORMATS}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        import imageio.v3 as iio

        # GIF frame durations are whole hundredths of a second in most players.
        duration_ms = max(10, int(round(100.0 / fps)) * 10)
        with atomic_path(path) as tmp:  # written whole, renamed into place
            iio.imwrite(tmp, frames, extension=".gif", duration=duration_ms, loop=0)
        return path
    try:
        import imageio.v2 as iio2
        import imageio_ffmpeg  # noqa: F401 - only to give a clear error when it is missing
    except ImportError as err:
        raise RuntimeError(
            f"writing {str(path)!r} needs imageio's ffmpeg plugin: pip install "
            '"cfm_jax[video]" (or imageio-ffmpeg); a .gif needs no plugin'
        ) from err
    pad_h, pad_w = frames.shape[1] % 2, frames.shape[2] % 2
    if pad_h or pad_w:
        frames = np.pad(frames, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)), mode="edge")
    with atomic_path(path, suffix=suffix) as tmp:  # written whole, renamed into place
        writer = iio2.get_writer(
            tmp,
            format="FFMPEG",
            fps=float(fps),
            codec="libx264",
            pixelformat="yuv420p",
            macro_block_size=1,
            output_params=["-crf", "18"],
        )
        try:
            for frame in frames:
                writer.append_data(frame)
        finally:
            writer.close()
    return path


def video(
    model,
    qpos: np.ndarray,
    path: str | os.PathLike,
    *,
    fps: float = 30.0,
    every: int = 1,
    width: int = 320,
    height: int = 240,
    camera: str | int | dict | None = None,
    track: bool = True,
) -> np.ndarray:
    """Render the states ``qpos (T, nq)`` offscreen and write them as an MP4 or a GIF.

    A state every ``every`` steps is rendered; with states ``control_dt`` apart, real time
    is ``fps = 1 / (every * control_dt)``.

    Args:
      model: a ``mujoco.MjModel`` or a :class:`cfm_jax.robots.Robot` (its ``mj_model``).
      qpos: ``(T, nq)`` generalised positions, one per frame before subsampling.
      path: output file, ``.mp4`` or ``.gif`` (see :func:`write_video`).
      fps: frames per second of playback.
      every: render every ``every``-th state (a positive integer).
      width: image width in pixels (at most the model's offscreen buffer,
        ``<visual><global offwidth>``).
      height: image height in pixels (at most ``offheight``).
      camera: a camera name or id of the model, or a dict of free-camera settings (as for
        :func:`render_frames`).
      track: let the free camera follow the robot (as for :func:`render_frames`).

    Returns:
      The frames written, ``(ceil(T / every), height, width, 3)`` uint8.

    Raises:
      RenderUnavailable: no OpenGL context (set ``MUJOCO_GL=egl`` on headless Linux).
      ValueError: a bad ``every``, ``qpos`` of the wrong width, or a bad path or ``fps``.

    Examples:
      >>> import numpy as np
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> qpos = arm.home + np.linspace(0, 1, 20)[:, None] * np.array([1.0, -1.0])
      >>> # not run: it needs offscreen OpenGL (MUJOCO_GL=egl or osmesa), which CI may lack
      >>> frames = video(arm, qpos, "/tmp/arm.gif", fps=20, every=2)  # doctest: +SKIP
      >>> frames.shape  # doctest: +SKIP
      (10, 240, 320, 3)
    """
    model = getattr(model, "mj_model", model)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every={every!r} is not allowed: a positive integer")
    qpos = np.atleast_2d(np.asarray(qpos, float))
    if qpos.shape[-1] != model.nq:
        raise ValueError(f"qpos has {qpos.shape[-1]} columns; the model has nq={model.nq}")
    if Path(path).suffix.lower() not in VIDEO_FORMATS:  # fail before the rendering work
        raise ValueError(f"path={str(path)!r}: the extension must be one of {VIDEO_FORMATS}")
    frames = render_frames(
        model, qpos[::every], width=width, height=height, camera=camera, track=track
    )
    write_video(frames, path, fps=fps)
    return frames
