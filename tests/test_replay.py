"""Recorded data sets and replays (cfm_jax/sim/dataset.py ``save``/``load``/``Recorded``,
``cfm_jax.train(config, data=...)``).

Oracle: the run that recorded the data. Replaying a run's own data set with the same
config, seed and loss must give that run's metrics and final controller bit for bit (the
replay's evaluation rollout is the very rollout the run collected); the recorded segments
must be the rows each phase added, counted independently from the rollouts' finite flags.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from tiny import cli_command, tiny_config

import cfm_jax
from cfm_jax.config import ConfigError
from cfm_jax.runs import training
from cfm_jax.sim import dataset

TINY = tiny_config()


@pytest.fixture(scope="module")
def experiment():
    return training.Experiment(TINY)


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory, experiment):
    out = tmp_path_factory.mktemp("recorded")
    result = cfm_jax.train(TINY, progress=False, out_dir=str(out), experiment=experiment)
    return result, out / "dataset.npz"


def test_saved_data_set_holds_the_run_in_collection_order(recorded_run, experiment):
    result, path = recorded_run
    recorded = dataset.load(str(path))
    size = np.asarray(result.state.data.size)
    np.testing.assert_array_equal(recorded.size, size)
    np.testing.assert_array_equal(recorded.seeds, [0, 1])
    assert recorded.iterations == TINY.loop.iterations
    # Every rollout of the tiny run stays finite: babbling adds babbling_rollouts rollouts,
    # every iteration one rollout of every target.
    per_rollout = experiment.transitions_per_rollout
    expected = [[TINY.loop.babbling_rollouts * per_rollout] + [per_rollout] * 2] * 2
    np.testing.assert_array_equal(recorded.segments, expected)
    for name in ("state", "desired", "action", "observed"):
        np.testing.assert_array_equal(
            getattr(recorded.transitions, name),
            np.asarray(getattr(result.state.data.data, name))[:, : size.max()],
        )
    chunk, valid = recorded.chunk(2, per_rollout + 3)  # the second iteration, padded
    assert valid.shape == (2, per_rollout + 3) and valid[:, :per_rollout].all()
    assert not valid[:, per_rollout:].any()
    start = expected[0][0] + per_rollout
    np.testing.assert_array_equal(
        chunk.action[:, :per_rollout], recorded.transitions.action[:, start : start + per_rollout]
    )


def test_replaying_own_data_reproduces_the_run_exactly(recorded_run, experiment):
    result, path = recorded_run
    replay = cfm_jax.train(TINY, progress=False, data=str(path), experiment=experiment)
    pd.testing.assert_frame_equal(replay.metrics, result.metrics, check_exact=True)
    for got, want in zip(
        jax_leaves(replay.params["controller"]),
        jax_leaves(result.params["controller"]),
        strict=True,
    ):
        np.testing.assert_array_equal(got, want)


def test_replay_with_another_loss_trains_on_the_same_data(recorded_run, experiment, tmp_path):
    result, path = recorded_run
    other = cfm_jax.train(
        TINY.replace(loss="task"), progress=False, data=str(path), experiment=experiment,
        out_dir=str(tmp_path / "swap"),
    )  # fmt: skip
    # The data set it ends with is the recorded one (no rollout was added) ...
    ended = dataset.load(str(tmp_path / "swap" / "dataset.npz"))
    recorded = dataset.load(str(path))
    np.testing.assert_array_equal(ended.transitions.observed, recorded.transitions.observed)
    np.testing.assert_array_equal(ended.segments, recorded.segments)
    # ... but the controller differs: it was trained with the task loss.
    assert not np.array_equal(
        other.metrics.tracking_mse.to_numpy(), result.metrics.tracking_mse.to_numpy()
    )


def test_replay_rejects_data_that_does_not_fit(recorded_run):
    _, path = recorded_run
    with pytest.raises(ConfigError, match=r"loop.seeds=1 .* holds the data sets of 2 seeds"):
        cfm_jax.train(tiny_config(seeds=1), progress=False, data=str(path))
    with pytest.raises(ConfigError, match=r"loop.iterations=3 .* at most 2"):
        cfm_jax.train(tiny_config(iterations=3), progress=False, data=str(path))
    with pytest.raises(ConfigError, match=r"state has 4 entries per row, this task 14"):
        cfm_jax.train(TINY.replace(robot="iiwa14"), progress=False, data=str(path))
    with pytest.raises(FileNotFoundError, match="no such file"):
        dataset.load(str(path) + ".missing")
    with pytest.raises(ConfigError, match=r"data=.*\.missing.*no such file"):
        cfm_jax.train(TINY, progress=False, data=str(path) + ".missing")


def test_cli_replays_a_recorded_data_set(recorded_run, experiment, tmp_path, monkeypatch,
                                        cli_in_process):  # fmt: skip
    # The CLI's --data runs the same replay: its joint-loss metrics equal the recording run's.
    # In-process (cli.main, on the module's Experiment, whose replay programs the tests
    # above compiled); the CLI's own end-to-end subprocess runs are in test_own_loss.py and
    # test_checkpoint.py.
    result, path = recorded_run
    out = tmp_path / "cli_replay"
    command = cli_command(TINY, tmp_path, out, "joint", seeds=2, iterations=2)
    monkeypatch.setattr(training.Experiment, "shared", classmethod(lambda cls, config: experiment))

    done = cli_in_process(*command[3:], "--data", str(path))
    assert done.returncode == 0, done.stderr[-2000:]
    written = pd.read_csv(out / "joint" / "metrics.csv")
    np.testing.assert_array_equal(
        written.tracking_mse.to_numpy(), result.metrics.tracking_mse.to_numpy()
    )
    done = cli_in_process(*command[3:], "--data", str(tmp_path / "nothing.npz"))
    assert done.returncode == 2 and "no such file" in done.stderr
    assert "Traceback" not in done.stderr


def jax_leaves(tree):
    import jax

    return [np.asarray(x) for x in jax.tree.leaves(tree)]


def test_an_interrupted_replay_resumes_to_the_same_run(
    recorded_run, experiment, tmp_path, monkeypatch
):
    # A replay that stopped after its first iteration (its last checkpoint removed, as a
    # kill before that save would leave it) resumes from the checkpoint of iteration 1 and
    # replays the rest of the recorded data. Oracle: the recording run itself (a replay of
    # a run's own data reproduces it bit for bit, tested above).
    import shutil

    result, path = recorded_run
    out = tmp_path / "replay"
    cfm_jax.train(TINY, progress=False, data=str(path), experiment=experiment, out_dir=str(out))
    last = out / "checkpoints" / str(TINY.loop.iterations)
    assert last.is_dir()
    shutil.rmtree(last)
    calls = []
    iteration_losses = experiment.iteration_losses
    monkeypatch.setattr(
        experiment,
        "iteration_losses",
        lambda *a, **k: calls.append(k["data"] is not None) or iteration_losses(*a, **k),
    )
    resumed = cfm_jax.train(
        TINY, progress=False, data=str(path), experiment=experiment, resume=str(out)
    )
    # It resumed: only the last iteration ran, a replay of the recorded data.
    assert calls == [True] * (TINY.loop.iterations - 1)
    pd.testing.assert_frame_equal(resumed.metrics, result.metrics, check_exact=True)
    # The data set it ends with is the recorded one: the resumed replay added no rows twice.
    ended = dataset.load(str(out / "dataset.npz"))
    recorded = dataset.load(str(path))
    np.testing.assert_array_equal(ended.size, recorded.size)
    np.testing.assert_array_equal(ended.segments, recorded.segments)
    np.testing.assert_array_equal(ended.transitions.observed, recorded.transitions.observed)
