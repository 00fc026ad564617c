"""A loss of your own, from outside the library (issue 66): one function and one
``cfm_jax.learning.losses.register`` call in the user's file; it trains from the command line
(``cfm-jax --import``), from Python, and resumes. Also the CLI's end-to-end run: the files
it promises, on a real subprocess of the entry point.

Oracles: the library's own ``joint`` loss (a user's loss written as the joint loss must give
its numbers bit for bit, through the registry, the CLI and the batched programs); the CLI's
numbers against a Python run of the same config (bit for bit); the files the CLI promises.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
from tiny import assert_own_output, tiny_config

from cfm_jax import config as config_lib

TINY = tiny_config()  # test_train.py's TINY
TINY = TINY.replace(
    loop=dataclasses.replace(TINY.loop, torque_scale="limit", babbling_gains="baseline")
)
TARGETS = 5  # default targets of every robot

USER_FILE = """
from cfm_jax.learning import losses


def my_joint(q, d_desired, d_output):  # the joint loss, written by a user
    return d_desired(q.predicted, q.desired) + d_output(q.predicted_next, q.observed_next)


def mix(q, d_desired, d_output):  # 0.7 task + 0.3 joint
    task = d_desired(q.predicted, q.desired)
    return 0.7 * task + 0.3 * (task + d_output(q.predicted_next, q.observed_next))


losses.register("my_joint", my_joint)
losses.register("mix", mix)
"""

PYTHON_RUN = """
import json, sys
import my_losses  # registers the user's losses
import cfm_jax
from cfm_jax import config as config_lib

config = config_lib.from_dict(json.load(open(sys.argv[1])))
experiment = cfm_jax.Experiment(config)  # built once, for both calls
trained = cfm_jax.train(config, progress=False, out_dir=sys.argv[2], experiment=experiment)
resumed = cfm_jax.train(config, progress=False, resume=sys.argv[3], experiment=experiment)
trained.metrics.to_csv(sys.argv[2] + "/trained.csv", index=False)
resumed.metrics.to_csv(sys.argv[2] + "/resumed.csv", index=False)
"""


def _numbers(frame: pd.DataFrame) -> pd.DataFrame:
    """The computed columns of a metrics table (not the loss name, not times)."""
    keep = [c for c in frame.columns if c != "loss" and "second" not in c and "wall" not in c]
    return frame[keep].reset_index(drop=True)


def _cli(tmp_path, *args, timeout=600):
    command = [sys.executable, "-m", "cfm_jax.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                          cwd=tmp_path)  # fmt: skip


def test_a_users_loss_trains_from_the_cli_and_python_and_resumes(tmp_path, monkeypatch,
                                                                 cli_in_process):  # fmt: skip
    (tmp_path / "my_losses.py").write_text(USER_FILE)
    (tmp_path / "tiny.json").write_text(json.dumps(config_lib.to_dict(TINY)))
    out = tmp_path / "cli"
    losses = "joint,supervised,my_joint,mix"
    done = _cli(tmp_path, "--import", "my_losses.py", "train", "--config", "tiny.json",
                "--loss", losses, "--seeds", "1", "--iterations", "1", "--out", str(out),
                "--quiet")  # fmt: skip
    # The CLI's promises (a real subprocess of the entry point, on a tiny config file).
    assert_own_output(done)  # nothing printed that is not the library's own (issue 26)
    assert "RMS reaching distance" in done.stdout
    metrics = pd.read_csv(out / "metrics.csv")
    assert list(dict.fromkeys(metrics.loss)) == losses.split(",")
    assert len(metrics) == 4 * 1 * 2 * TARGETS  # losses x seeds x (iterations + 1) x targets
    saved = json.loads((out / "config.json").read_text())
    assert saved["loop"]["iterations"] == 1 and saved["loop"]["seeds"] == 1
    assert saved["loss"] == losses  # the run's losses
    assert (out / "learning_curves.png").stat().st_size > 10_000
    assert "supervised" in (out / "summary.md").read_text()
    assert "mix" in (out / "summary.md").read_text()
    assert "pd_only" in done.stdout and "oracle" in done.stdout  # the printed table
    for loss in losses.split(","):
        assert os.path.exists(out / loss / "metrics.csv")
    # The user's joint loss is the library's, bit for bit; the mix is another loss.
    of = {loss: _numbers(metrics[metrics.loss == loss]) for loss in losses.split(",")}
    pd.testing.assert_frame_equal(of["my_joint"], of["joint"], check_exact=True)
    assert not np.array_equal(of["mix"].tracking_mse, of["joint"].tracking_mse)

    # Without the module the run's config names a loss no one registered: one line, exit 2.
    # These two refusals import nothing of the user's: they run in this process (cli.main),
    # in the working directory of the subprocesses.
    monkeypatch.chdir(tmp_path)
    again = ["train", "--config", str(out / "config.json"), "--resume", "--out", str(out)]
    refused = cli_in_process(*again, "--quiet")
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "'my_joint'" in refused.stderr and "--import MODULE" in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1
    missing = cli_in_process("--import", "no_such_module", "config")
    assert missing.returncode == 2 and "--import='no_such_module' is not allowed" in missing.stderr
    # The module by name (importable from the working directory): the config command knows
    # the loss.
    shown = _cli(tmp_path, "--import", "my_losses", "config", "--loss", "mix", timeout=300)
    assert shown.returncode == 0, shown.stderr
    assert '"loss": "mix"' in shown.stdout

    # From Python, in a process of the user's: a fresh run of the mix alone gives the CLI's
    # numbers bit for bit (each loss of a batched run is that loss run alone), and resuming
    # the CLI's finished mix run gives them again.
    (tmp_path / "run.py").write_text(textwrap.dedent(PYTHON_RUN))
    python_out = tmp_path / "python"
    done = subprocess.run(
        [sys.executable, "run.py", str(out / "mix" / "config.json"), str(python_out),
         str(out / "mix")],
        capture_output=True, text=True, timeout=600, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    for name in ("trained.csv", "resumed.csv"):
        got = _numbers(pd.read_csv(python_out / name))
        pd.testing.assert_frame_equal(got, of["mix"], check_exact=True, obj=name)
    assert json.loads((python_out / "config.json").read_text())["loss"] == "mix"
