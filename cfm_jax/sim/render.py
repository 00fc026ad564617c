"""Offscreen pictures and videos of recorded ``qpos`` for any MJCF model (MuJoCo's ``Renderer``;
no display and no ``MUJOCO_GL``: MuJoCo's EGL context); see docs/how-to/render.md."""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cfm_jax._files import atomic_path


class RenderUnavailable(RuntimeError):
    """No OpenGL context could be created (the message says why); see :func:`render_available`.

    Examples:
      >>> issubclass(RenderUnavailable, RuntimeError)
      True
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
    """Whether an offscreen OpenGL context can be made: ``(True, "")`` or ``(False, why)``.

    Examples:
      >>> render_available()[0] or "MUJOCO_GL" in render_available()[1]
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


class FrameRenderer:
    """RGB frames of one model's states through one offscreen renderer (else
    :class:`RenderUnavailable`): what :func:`render_frames` and
    :meth:`cfm_jax.envs.TrackingEnv.render` draw with.

    Args:
      model: a ``mujoco.MjModel``.
      width: image width in pixels (at most the model's ``offwidth``).
      height: image height in pixels (at most ``offheight``).
      camera: a camera name or id, or a dict of free-camera ``distance``, ``azimuth``, etc.
      track: the free camera follows body 1's subtree COM (height fixed by ``lookat``).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> with FrameRenderer(arm.mj_model) as renderer:  # needs OpenGL  # doctest: +SKIP
      ...     renderer.frame(arm.home).shape
      (240, 320, 3)
    """

    def __init__(
        self,
        model,
        width: int = 320,
        height: int = 240,
        camera: str | int | dict | None = None,
        track: bool = True,
    ):
        import mujoco

        self.model, self.camera, self.track = model, camera, track
        width = min(width, model.vis.global_.offwidth)
        height = min(height, model.vis.global_.offheight)
        self._renderer = _renderer(model, height, width)
        self._data = mujoco.MjData(model)

    def frame(self, qpos, qvel=None) -> np.ndarray:
        """The frame ``(height, width, 3)`` uint8 of the state ``qpos`` (and ``qvel``)."""
        import mujoco

        data = self._data
        data.qpos[:] = qpos
        if qvel is not None:
            data.qvel[:] = qvel
        mujoco.mj_forward(self.model, data)
        camera = _camera(self.model, data, self.camera, self.track)
        self._renderer.update_scene(data, camera=camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Release the offscreen renderer."""
        self._renderer.close()

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def render_frames(
    model,
    qpos: np.ndarray,
    *,
    width: int = 320,
    height: int = 240,
    camera: str | int | dict | None = None,
    track: bool = True,
) -> np.ndarray:
    """RGB frames ``(N, height, width, 3)`` uint8 of ``qpos`` (else :class:`RenderUnavailable`).

    Args:
      model: a ``mujoco.MjModel``.
      qpos: ``(N, nq)`` (or one ``(nq,)``) generalised positions.
      width: image width in pixels (at most the model's ``offwidth``).
      height: image height in pixels (at most ``offheight``).
      camera: a camera name or id, or a dict of free-camera ``distance``, ``azimuth``, etc.
      track: the free camera follows body 1's subtree COM (height fixed by ``lookat``).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> render_frames(arm.mj_model, arm.home).shape  # needs OpenGL  # doctest: +SKIP
      (1, 240, 320, 3)
    """
    qpos = np.atleast_2d(np.asarray(qpos, float))
    with FrameRenderer(model, width, height, camera, track) as renderer:
        return np.stack([renderer.frame(q) for q in qpos])


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
    """Render ``n_frames`` evenly spaced states (or ``indices``) side by side into one image.

    Args:
      model: a ``mujoco.MjModel``.
      qpos: ``(T, nq)`` generalised positions.
      path: the image to write (folders are created; the suffix picks the format).
      n_frames: number of states shown when ``indices`` is None.
      indices: the states to show instead.
      width: width of each frame in pixels.
      height: height of each frame in pixels.
      camera: as for :func:`render_frames`.
      track: as for :func:`render_frames`.
      gap: white pixels between frames (the image returned: ``n * (width + gap) - gap`` wide).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> frame_strip(arm.mj_model, [arm.home] * 9, "strip.png")  # needs OpenGL  # doctest: +SKIP
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
    """Write RGB frames as an MP4 (H.264, ``yuv420p``, odd sizes edge-padded; RuntimeError
    without ``cfm_jax[video]``) or a looping GIF, chosen by ``path``'s extension.

    Args:
      frames: ``(N, height, width, 3)`` uint8 RGB images (e.g. :func:`render_frames`).
      path: output file, ``.mp4`` or ``.gif`` (folders are created); returned.
      fps: frames per second of playback, > 0 (ValueError: bad frames, extension or ``fps``).

    Examples:
      >>> import os, tempfile
      >>> frames = np.zeros((5, 32, 48, 3), np.uint8)
      >>> write_video(frames, os.path.join(tempfile.mkdtemp(), "clip.gif"), fps=10).suffix
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
    """Render every ``every``-th state and :func:`write_video` them; returns the frames (real
    time: ``fps = 1 / (every * control_dt)``; ValueError: bad ``every``, ``qpos``, path, fps).

    Args:
      model: a ``mujoco.MjModel`` or a :class:`cfm_jax.sim.robots.Robot`.
      qpos: ``(T, nq)`` generalised positions.
      path: output file, ``.mp4`` or ``.gif``.
      fps: frames per second of playback.
      every: a positive integer: render every ``every``-th state.
      width: as for :func:`render_frames`.
      height: as for :func:`render_frames`.
      camera: as for :func:`render_frames`.
      track: as for :func:`render_frames`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> video(arm, [arm.home] * 20, "arm.gif", fps=20, every=2)  # needs OpenGL  # doctest: +SKIP
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
