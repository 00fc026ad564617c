"""TensorBoard event files (cfm_jax/analysis/tensorboard.py, ``cfm-jax train --tensorboard``): the
scalars read back from the file are the means of the rows the writer was given, and a
missing tensorboardX is one clear error. A real run's event file is compared with its
metrics.csv in tests/test_train.py (``test_cli_run_tensorboard_summary_and_files``).

Oracle: the event file parsed here from its TFRecord framing with tensorboardX's protobuf
classes (not with the writer's own bookkeeping), and means computed with NumPy.
"""

from __future__ import annotations

import glob
import os
import struct
import sys

import numpy as np
import pandas as pd
import pytest

from cfm_jax import cli
from cfm_jax.analysis import tensorboard

NEEDS = "tensorboardX is not installed (pip install 'cfm_jax[tensorboard]')"


def read_scalars(folder) -> dict[str, list[tuple[int, float]]]:
    """``{tag: [(step, value), ...]}`` of the one event file in ``folder``: TFRecords
    (uint64 length, uint32 CRC, the ``Event`` protobuf, uint32 CRC)."""
    from tensorboardX.proto import event_pb2

    (path,) = glob.glob(os.path.join(folder, "events.out.tfevents.*"))
    data = open(path, "rb").read()
    scalars, pos = {}, 0
    while pos < len(data):
        (length,) = struct.unpack("<Q", data[pos : pos + 8])
        event = event_pb2.Event.FromString(data[pos + 12 : pos + 12 + length])
        pos += 12 + length + 4
        for value in event.summary.value:
            scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_scalars_read_back_are_the_means_per_loss_and_iteration(tmp_path):
    pytest.importorskip("tensorboardX", reason=NEEDS)
    rng = np.random.default_rng(0)
    frames = []
    for iteration in range(3):
        rows = pd.DataFrame(
            {"loss": ["joint"] * 4 + ["task"] * 4, "seed": [0, 0, 1, 1] * 2,
             "iteration": iteration, "target": [0, 1] * 4,
             "tracking_mse": rng.uniform(0, 1, 8), "diverged": [True] + [False] * 7}
        )  # fmt: skip
        frames.append(rows)
    with tensorboard.TensorBoardWriter(tmp_path / "tb") as writer:
        for iteration, rows in enumerate(frames):
            writer(iteration, rows)
    scalars = read_scalars(tmp_path / "tb")
    assert set(scalars) == {"joint/tracking_mse", "joint/diverged", "task/tracking_mse",
                            "task/diverged"}  # fmt: skip
    for tag, points in scalars.items():
        loss, column = tag.split("/")
        assert [step for step, _ in points] == [0, 1, 2]
        for (_, value), rows in zip(points, frames, strict=True):
            expected = np.mean(rows[rows.loss == loss][column].to_numpy(float))
            # the event file stores float32: equal up to its rounding
            np.testing.assert_allclose(value, expected, rtol=2**-24, atol=0)
    assert scalars["joint/diverged"][0][1] == 0.25  # one rollout of four diverged


def test_a_metric_measured_nowhere_at_a_step_is_not_written_and_nothing_printed(tmp_path, capsys):
    """The fit losses are NaN at the final evaluation (nothing is fitted): that step is
    left out of their curves (the mean skips NaN rows, so only an all-NaN or infinite mean
    is left out), and tensorboardX prints no NaN warning."""
    pytest.importorskip("tensorboardX", reason=NEEDS)
    nan = float("nan")
    frames = [
        pd.DataFrame({"loss": "joint", "seed": [0, 1], "iteration": 0, "target": 0,
                      "tracking_mse": [0.5, 1.5], "forward_loss": [2.0, nan]}),
        pd.DataFrame({"loss": "joint", "seed": [0, 1], "iteration": 1, "target": 0,
                      "tracking_mse": [0.25, 0.75], "forward_loss": [nan, nan]}),
        pd.DataFrame({"loss": "joint", "seed": [0, 1], "iteration": 2, "target": 0,
                      "tracking_mse": [np.inf, 1.0], "forward_loss": [1.0, 3.0]}),
    ]  # fmt: skip
    with tensorboard.TensorBoardWriter(tmp_path / "tb") as writer:
        for iteration, rows in enumerate(frames):
            writer(iteration, rows)
    scalars = read_scalars(tmp_path / "tb")
    assert scalars == {"joint/tracking_mse": [(0, 1.0), (1, 0.5)],
                       "joint/forward_loss": [(0, 2.0), (2, 2.0)]}  # fmt: skip
    assert writer.written == scalars
    captured = capsys.readouterr()
    assert captured.out + captured.err == ""


def test_missing_tensorboardx_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import fails as if absent
    with pytest.raises(ImportError, match=r"pip install 'cfm_jax\[tensorboard\]'"):
        tensorboard.TensorBoardWriter(tmp_path / "tb")
    monkeypatch.setattr(tensorboard, "available", lambda: False)
    out = tmp_path / "run"
    argv = ["cfm-jax", "train", "--robot", "two_link_arm", "--out", str(out),
            "--tensorboard", str(tmp_path / "tb"), "--quiet"]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as stop:
        cli.main()
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("cfm-jax: error: --tensorboard=")
    assert "tensorboardX" in err and "pip install 'cfm_jax[tensorboard]'" in err
    assert not out.exists() and not (tmp_path / "tb").exists()  # nothing written
