"""Offscreen rendering (cfm_jax/sim/render.py). Skipped with the reason when no OpenGL context can
be created (set MUJOCO_GL=egl on headless Linux)."""

from __future__ import annotations

import matplotlib.image
import mujoco
import numpy as np
import pytest

from cfm_jax.sim import render, solo12

OK, WHY = render.render_available()
needs_gl = pytest.mark.skipif(not OK, reason=f"no offscreen OpenGL: {WHY}")


@pytest.fixture(scope="module")
def model():
    return solo12.load_model()


@needs_gl
def test_render_frames_show_the_robot_moving(model):
    home = model.key("home").qpos
    crouched = home.copy()
    crouched[2] -= 0.06
    frames = render.render_frames(model, np.stack([home, home, crouched]), width=160, height=120)
    assert frames.shape == (3, 120, 160, 3) and frames.dtype == np.uint8
    assert frames[0].std() > 10  # not a blank image
    np.testing.assert_array_equal(frames[0], frames[1])  # deterministic
    assert np.abs(frames[0].astype(int) - frames[2]).mean() > 0.5  # the robot moved


@needs_gl
def test_frame_strip_png(model, tmp_path):
    home = model.key("home").qpos
    qpos = np.repeat(home[None], 10, axis=0)
    qpos[:, 0] = np.linspace(0, 0.5, 10)
    path = tmp_path / "strip.png"
    strip = render.frame_strip(model, qpos, path, n_frames=4, width=100, height=80, gap=4)
    assert strip.shape == (80, 4 * 100 + 3 * 4, 3)
    assert np.all(strip[:, 100:104] == 255)  # white separators
    image = matplotlib.image.imread(str(path))
    assert image.shape[:2] == (80, 412)
    # a named camera of the model works too (fixed side camera)
    strip = render.frame_strip(model, qpos, path, n_frames=2, width=64, height=48, camera="side")
    assert strip.shape == (48, 132, 3)


def test_unavailable_gl_raises_a_clear_error(monkeypatch):
    def broken(*args, **kwargs):
        raise mujoco.FatalError("an OpenGL platform library has not been loaded")

    monkeypatch.setattr(mujoco, "Renderer", broken)
    available, reason = render.render_available()
    assert not available and "MUJOCO_GL=egl" in reason
    with pytest.raises(render.RenderUnavailable, match="OpenGL"):
        render.render_frames(mujoco.MjModel.from_xml_string("<mujoco/>"), np.zeros((1, 0)))
