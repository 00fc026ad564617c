"""Videos of rollouts (cfm_jax.sim.render.write_video, video; cfm_jax.runs.training.rollout_qpos)
from real offscreen frames. Skipped with the reason when no OpenGL context can be created."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
from tiny import tiny_config

from cfm_jax.runs import training
from cfm_jax.sim import render

OK, WHY = render.render_available()
needs_gl = pytest.mark.skipif(not OK, reason=f"no offscreen OpenGL: {WHY}")


@pytest.fixture(scope="module")
def swing(arm):
    """12 states of the arm swinging its shoulder by 1.2 rad, rendered at 96 x 64."""
    qpos = arm.home + np.linspace(0.0, 1.2, 12)[:, None] * np.array([1.0, 0.0])
    return qpos, render.render_frames(arm.mj_model, qpos, width=96, height=64, track=False)


@needs_gl
def test_gif_and_mp4_hold_the_rendered_frames(swing, tmp_path):
    _, frames = swing
    assert np.abs(frames[0].astype(int) - frames[-1]).mean() > 1.0  # the arm moved
    gif = iio.imread(render.write_video(frames, tmp_path / "a.gif", fps=10), index=None)
    assert gif.shape == frames.shape
    assert np.abs(gif[..., :3].astype(int) - frames).mean() < 4.0  # palette quantisation
    meta = iio.immeta(tmp_path / "a.gif")
    assert meta["duration"] == 100 and meta["loop"] == 0
    mp4_path = render.write_video(frames, tmp_path / "sub" / "a.mp4", fps=25)
    mp4 = iio.imread(mp4_path, index=None, plugin="FFMPEG")
    assert mp4.shape == frames.shape
    assert np.abs(mp4.astype(int) - frames).mean() < 4.0  # lossy, but the same pictures
    # frame order is kept: each decoded frame is closest to its own source frame
    distance = np.abs(mp4[:, None].astype(int) - frames[None]).mean(axis=(2, 3, 4))
    np.testing.assert_array_equal(distance.argmin(axis=1), np.arange(len(frames)))
    assert iio.immeta(mp4_path, plugin="FFMPEG")["fps"] == 25.0


@needs_gl
def test_mp4_pads_odd_sizes(swing, tmp_path):
    _, frames = swing
    odd = frames[:, :63, :95]
    mp4 = iio.imread(render.write_video(odd, tmp_path / "odd.mp4"), index=None, plugin="FFMPEG")
    assert mp4.shape == (12, 64, 96, 3)


@needs_gl
def test_video_renders_every_nth_state(arm, swing, tmp_path):
    qpos, frames = swing
    out = render.video(arm, qpos, tmp_path / "v.gif", every=5, width=96, height=64, track=False)
    assert out.shape == (3, 64, 96, 3)  # states 0, 5, 10
    np.testing.assert_array_equal(out, frames[::5])  # the same renderer, the same pictures
    assert iio.imread(tmp_path / "v.gif", index=None).shape[0] == 3


def test_bad_inputs_raise_clear_errors(arm, tmp_path):
    frames = np.zeros((2, 8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="extension"):
        render.write_video(frames, tmp_path / "a.avi")
    with pytest.raises(ValueError, match="uint8"):
        render.write_video(frames.astype(float), tmp_path / "a.gif")
    with pytest.raises(ValueError, match="uint8"):
        render.write_video(frames[0], tmp_path / "a.gif")
    with pytest.raises(ValueError, match="fps"):
        render.write_video(frames, tmp_path / "a.gif", fps=0)
    with pytest.raises(ValueError, match="nq=2"):
        render.video(arm, np.zeros((3, 5)), tmp_path / "a.gif")
    with pytest.raises(ValueError, match="every"):
        render.video(arm, np.zeros((3, 2)), tmp_path / "a.gif", every=0)
    with pytest.raises(ValueError, match="extension"):
        render.video(arm, np.zeros((3, 2)), tmp_path / "a.png")


def test_rollout_qpos_is_the_final_evaluation_rollout():
    import cfm_jax

    config = tiny_config(iterations=1, seeds=2)
    experiment = cfm_jax.Experiment(config)
    result = cfm_jax.train(config, progress=False, experiment=experiment)
    qpos = training.rollout_qpos(result, seed=1, experiment=experiment)
    task = experiment.task
    assert qpos.shape == (task.targets, task.steps, experiment.robot.nq)
    reference = task.reference_np.q
    np.testing.assert_allclose(qpos[:, 0], reference[:, 0], atol=1e-6)  # starts at home
    # Its squared tracking error over the steps it holds is part of the final evaluation's
    # (which also counts the position after the last step), per target.
    partial = np.sum((qpos[:, 1:] - reference[:, 1 : task.steps]) ** 2, axis=(1, 2))
    final = result.final()
    full = (
        final[final.seed == config.seed + 1].tracking_mse.to_numpy()
        * task.steps
        * experiment.robot.nq
    )
    assert np.all(partial <= full * (1 + 1e-4) + 1e-9)
    assert np.all(partial >= 0.5 * full - 1e-9) or np.all(full < 1e-6)
    other = training.rollout_qpos(result, seed=0, experiment=experiment)
    assert np.abs(other - qpos).max() > 1e-6  # each seed has its own controller
    with pytest.raises(ValueError, match="seed"):
        training.rollout_qpos(result, seed=2, experiment=experiment)
