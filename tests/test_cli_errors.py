"""Every bad command line ends in one ``cfm-jax: error:`` line, exit status 2, nothing
written (cfm_jax/cli.py; the checks in config.py, robots.py, training.py).

Oracle: the command-line contract itself, run in-process through ``cfm_jax.cli.main``: any
other exception (a traceback) fails the test, and so does another exit status, a message
of more than one line, or a file in the output directory.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from cfm_jax import cli
from cfm_jax import config as config_lib
from cfm_jax.sim import robots

BALL = (
    '<mujoco><worldbody><body name="b"><joint name="socket" type="ball"/>'
    '<geom type="sphere" size="0.1" mass="1"/></body></worldbody></mujoco>'
)

# (name, files to write into tmp_path, argv after "cfm-jax", words the message must hold)
CASES = [
    (
        "config missing",
        {},
        ["train", "--config", "{tmp}/missing.json"],
        ["missing.json", "no such file"],
    ),
    (
        "config not JSON",
        {"broken.json": "{not json"},
        ["train", "--config", "{tmp}/broken.json"],
        ["broken.json", "not JSON"],
    ),
    (
        "config a list",
        {"list.json": "[1, 2]"},
        ["train", "--config", "{tmp}/list.json"],
        ["config=[1, 2]", "JSON object"],
    ),
    (
        "config section a number",
        {"sec.json": '{"loop": 3}'},
        ["train", "--config", "{tmp}/sec.json"],
        ["loop=3", "object"],
    ),
    (
        "config unknown field",
        {"unk.json": '{"speed": 1}'},
        ["train", "--config", "{tmp}/unk.json"],
        ["speed", "top-level"],
    ),
    (
        "config is a directory",
        {"dir.json/x": ""},
        ["train", "--config", "{tmp}/dir.json"],
        ["dir.json", "directory"],
    ),
    (
        "loss twice",
        {},
        ["train", "--robot", "two_link_arm", "--loss", "joint,joint"],
        ["joint,joint", "distinct"],
    ),
    ("unknown loss", {}, ["train", "--robot", "two_link_arm", "--loss", "nope"], ["nope"]),
    (
        "sweep loss twice",
        {},
        ["sweep", "--robot", "two_link_arm", "--losses", "task,task"],
        ["task,task", "distinct"],
    ),
    (
        "ball joint, no actuators",
        {"ball.xml": BALL},
        ["train", "--robot", "{tmp}/ball.xml"],
        ["'socket' is mjJNT_BALL"],
    ),
    ("robot file missing", {}, ["train", "--robot", "{tmp}/none.xml"], ["none.xml"]),
    (
        "robot file not MJCF",
        {"bad.xml": "<mujoco><oops"},
        ["train", "--robot", "{tmp}/bad.xml"],
        ["does not parse"],
    ),
    (
        "unknown simulator",
        {},
        ["train", "--robot", "two_link_arm", "--simulator", "warp"],
        ["warp"],
    ),
    ("zero seeds", {}, ["train", "--robot", "two_link_arm", "--seeds", "0"], ["seeds=0"]),
    ("unknown task", {}, ["train", "--task", "juggle"], ["juggle"]),
    (
        "control_dt off the timestep",
        {},
        ["train", "--robot", "two_link_arm", "--control_dt", "0.003"],
        ["0.003"],
    ),
    (
        "unknown babbling",
        {},
        ["train", "--robot", "two_link_arm", "--babbling", "dance"],
        ["dance"],
    ),
    (
        "data file missing",
        {},
        ["train", "--robot", "two_link_arm", "--data", "{tmp}/none.npz"],
        ["none.npz"],
    ),
    (
        "nested flag out of range",
        {},
        ["train", "--robot", "two_link_arm", "--forward.learning-rate", "-1"],
        ["forward.learning_rate=-1.0", "a finite number > 0"],
    ),
    (
        "nested flag not a number",
        {},
        ["train", "--robot", "two_link_arm", "--task.kd", "stiff"],
        ["task.kd='stiff'", "a finite number >= 0"],
    ),
    (
        "nested flag not an integer",
        {},
        ["sweep", "--robot", "two_link_arm", "--controller.batch-size", "2.5"],
        ["controller.batch_size=2.5", "a positive integer"],
    ),
    (
        "nested flag unknown choice",
        {},
        ["train", "--robot", "two_link_arm", "--loop.normaliser", "max"],
        ["loop.normaliser='max'", "'babbling', 'data', 'robot'"],
    ),
    (
        "nested flag bad JSON",
        {},
        ["train", "--robot", "two_link_arm", "--task.targets", "[[0.5,"],
        ["task.targets='[[0.5,'", "JSON list"],
    ),
    (
        "unknown robot name",
        {},
        ["train", "--robot", "ur5"],
        ["robot='ur5'", "'two_link_arm'", "MJCF"],
    ),
    (
        "override without =",
        {},
        ["sweep", "--robot", "two_link_arm", "--override", "task.kp"],
        ["task.kp"],
    ),
    (
        "override of one path twice",
        {},
        ["sweep", "--robot", "two_link_arm", "--override", "task.kp=1,2", "--override",
         "task.kp=3"],
        ["task.kp=3", "already an axis"],
    ),
]  # fmt: skip


# --resume where there is no run: it trained a new run from scratch and exited 0 (issue 67).
CASES.append(
    (
        "resume where there is no run",
        {},
        ["train", "--robot", "two_link_arm", "--loss", "joint,task", "--resume"],
        ["--out=", "--resume continues a run", "there is none here", "without --resume"],
    )
)  # fmt: skip


# A model MJX cannot build (a cylinder-box collision pair) asked for on MJX: the pair named.
CASES.append(
    (
        "model MJX cannot build, on mjx",
        {},
        ["train", "--robot", str(Path(__file__).parent / "cylinder_box_arm.xml"),
         "--simulator", "mjx"],
        ["MJX cannot build", "CYLINDER", "BOX", "simulator='mjx'", "native"],
    )
)  # fmt: skip


@pytest.mark.parametrize(("name", "files", "argv", "words"), CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_error_line_exit_2_nothing_written(
    name, files, argv, words, tmp_path, monkeypatch, capsys
):
    for relative, text in files.items():
        path = tmp_path / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    out = tmp_path / "out"
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    monkeypatch.setattr(sys, "argv", ["cfm-jax", *args, "--out", str(out), "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()  # any other exception is a traceback: the test fails
    assert exit_info.value.code == 2, name
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cfm-jax: error: "), captured.err
    for word in words:
        assert word in lines[0], (word, lines[0])
    assert not out.exists(), f"{name}: {sorted(p.name for p in out.rglob('*'))}"


def test_python_api_raises_the_same_typed_errors(tmp_path):
    with pytest.raises(config_lib.ConfigError, match="JSON object"):
        config_lib.from_dict([1, 2])
    with pytest.raises(config_lib.ConfigError, match="loop=3"):
        config_lib.from_dict({"loop": 3})
    (tmp_path / "ball.xml").write_text(BALL)
    with pytest.raises(robots.RobotError, match="mjJNT_BALL"):
        robots.load(str(tmp_path / "ball.xml"))


def test_a_new_run_into_a_folder_with_checkpoints_is_refused_up_front(
    tmp_path, monkeypatch, capsys
):
    # Without --resume, a run into a folder that holds a run's checkpoints failed only
    # after its babbling, with Orbax's StepAlreadyExistsError traceback. Now: one error
    # line naming the losses and --resume before anything is computed or written; the
    # Python API raises a ConfigError naming resume=.
    from cfm_jax.runs import training

    out = tmp_path / "out"
    (out / "task" / "checkpoints" / "3").mkdir(parents=True)
    before = sorted(str(p) for p in out.rglob("*"))
    argv = ["cfm-jax", "train", "--robot", "two_link_arm", "--loss", "joint,task"]
    monkeypatch.setattr(sys, "argv", [*argv, "--out", str(out), "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cfm-jax: error: --out="), lines
    assert "['task']" in lines[0] and "--resume" in lines[0]
    assert sorted(str(p) for p in out.rglob("*")) == before
    with pytest.raises(config_lib.ConfigError, match="resume="):
        training.train(config_lib.Config(robot="two_link_arm"), out_dir=str(out / "task"))


@pytest.mark.parametrize("command", ["train", "sweep"])
@pytest.mark.parametrize(
    ("out", "words"),
    [
        ("file.txt", ["it is a file"]),
        ("file.txt/sub", ["cannot be created", "is a file"]),
        # a virtual file system: no folder can be made there, even by root, for whom
        # os.access says yes (a FileNotFoundError traceback before)
        ("/proc/cfm_jax_test/out", ["cannot be created"]),
    ],
)
def test_an_out_that_is_a_file_or_cannot_be_made_is_one_error_line(
    command, out, words, tmp_path, monkeypatch, capsys
):
    # All ended in a Python traceback (FileExistsError, NotADirectoryError,
    # FileNotFoundError) after the robot and config were checked; now one error line before
    # any work.
    if out.startswith("/proc") and not os.path.isdir("/proc"):
        pytest.skip("no /proc on this system")
    (tmp_path / "file.txt").write_text("a user's file\n")
    argv = ["cfm-jax", command, "--robot", "two_link_arm", "--out", str(tmp_path / out)]
    monkeypatch.setattr(sys, "argv", [*argv, "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cfm-jax: error: --out="), lines
    for word in words:
        assert word in lines[0], (word, lines[0])
    assert (tmp_path / "file.txt").read_text() == "a user's file\n"


def test_a_checkpoint_that_cannot_be_used_is_one_error_line(tmp_path, monkeypatch, capsys):
    # The library's CheckpointError (a damaged only checkpoint) ended the CLI in a traceback
    # (issue 67); its message, which says what to do, is now the one error line, exit 2.
    from cfm_jax.runs import checkpoint

    message = ("checkpoint step 0 is not usable (its manifest does not parse); no earlier "
               "valid checkpoint exists: start the run again (cfm-jax train --restart moves "
               "the old run aside first)")  # fmt: skip

    def damaged(*args, **kwargs):
        raise checkpoint.CheckpointError(message)

    monkeypatch.setattr(cli, "_run_train", damaged)
    argv = ["cfm-jax", "train", "--robot", "two_link_arm", "--resume"]
    monkeypatch.setattr(sys, "argv", [*argv, "--out", str(tmp_path), "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [f"cfm-jax: error: {message}"]
