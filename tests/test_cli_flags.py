"""``cfm-jax train``/``sweep``/``config`` take every config field as a nested flag; --config
is the base and only the flags given override it; ``cfm-jax config`` prints what --config
reads; nothing but the library's own lines is printed (cfm_jax/cli.py, cfm_jax/_mjx.py).

Oracles: configs built by hand with ``dataclasses.replace`` from ``config.for_task`` (the
flags must reach exactly those fields); the file written by the test itself for
--config; for the output, an empty stderr and no line of another package's messages.
"""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys

import pytest
from tiny import assert_own_output

from cfm_jax import cli
from cfm_jax import config as config_lib


def printed_config(argv, monkeypatch, capsys) -> dict:
    """``cfm-jax config ARGV`` in-process: the JSON it prints."""
    monkeypatch.setattr(sys, "argv", ["cfm-jax", "config", *argv])
    cli.main()
    return json.loads(capsys.readouterr().out)


def cli_default(task: str = "inverse_dynamics") -> config_lib.Config:
    """What the CLI runs without flags: the task's defaults, as Python's ``Config``."""
    return config_lib.for_task(task)


@pytest.mark.parametrize(
    ("flags", "section", "changes"),
    [
        (["--task.kd", "5"], "task", {"kd": 5.0}),
        (["--forward.learning-rate", "3e-4"], "forward", {"learning_rate": 3e-4}),
        (["--controller.hidden", "8", "16"], "controller", {"hidden": (8, 16)}),
        (["--loop.babbling", "reaching"], "loop", {"babbling": "reaching"}),
        (["--task.targets", "[[0.5, 0.5]]"], "task", {"targets": ((0.5, 0.5),)}),
        (["--control_dt", "0.02"], "task", {"control_dt": 0.02}),  # the short flags
        (["--seeds", "3", "--iterations", "2"], "loop", {"seeds": 3, "iterations": 2}),
    ],
)
def test_a_nested_flag_reaches_its_config_field(flags, section, changes, monkeypatch, capsys):
    printed = printed_config(flags, monkeypatch, capsys)
    base = cli_default()
    expected = base.replace(**{section: dataclasses.replace(getattr(base, section), **changes)})
    assert config_lib.from_dict(printed) == expected
    assert printed == json.loads(json.dumps(config_lib.to_dict(expected)))


def test_a_kinds_options_are_flags_and_follow_the_kind(monkeypatch, capsys):
    # --forward.options.FIELD reaches the kind's options; choosing another kind starts from
    # that kind's options (the walk's rigid_body options do not follow it to the mlp).
    flags = ["--forward.kind", "rigid_body", "--forward.options.mass-scale", "0.8"]
    printed = printed_config(flags, monkeypatch, capsys)
    base = cli_default()
    forward = dataclasses.replace(base.forward, kind="rigid_body", options={"mass_scale": 0.8})
    assert config_lib.from_dict(printed) == base.replace(forward=forward)
    assert printed["forward"]["options"] == {"nominal": None, "mass_scale": 0.8}
    walk = printed_config(["--task", "walk", "--forward.kind", "mlp"], monkeypatch, capsys)
    assert walk["forward"]["kind"] == "mlp" and walk["forward"]["options"] is None
    with pytest.raises(SystemExit):  # the mlp takes no options: one error line, exit 2
        printed_config(["--forward.options.mass-scale", "0.8"], monkeypatch, capsys)
    assert "forward.options.mass_scale=0.8 is not allowed" in capsys.readouterr().err


def test_config_file_plus_one_flag_changes_only_that_field(tmp_path, monkeypatch, capsys):
    # The case: a walk config with the default --task no longer replaces its task.
    walk = config_lib.for_task("walk")
    path = tmp_path / "walk.json"
    path.write_text(json.dumps(config_lib.to_dict(walk)))
    assert printed_config(["--config", str(path)], monkeypatch, capsys) == json.loads(
        path.read_text()
    )
    printed = printed_config(["--config", str(path), "--loop.babbling-noise", "0.3"],
                             monkeypatch, capsys)  # fmt: skip
    expected = json.loads(path.read_text())
    expected["loop"]["babbling_noise"] = 0.3
    assert printed == expected


@pytest.mark.parametrize("task", config_lib.TASKS)
def test_config_prints_what_python_runs_for_every_task(task, monkeypatch, capsys):
    # Issue 67: one experiment per task, the CLI's and Python's alike in every field (the
    # walk's iterations were 4 in the CLI and 10 in Python), written out field by field.
    printed = printed_config(["--task", task], monkeypatch, capsys)
    python = config_lib.to_dict(config_lib.Config(task=config_lib.TaskConfig(name=task)))
    python = json.loads(json.dumps(python))  # as printed: tuples are JSON lists
    assert printed.keys() == python.keys()
    for key, value in python.items():
        assert printed[key] == value, key
    assert printed["loop"]["iterations"] == 4


def test_config_output_round_trips_through_config(tmp_path, monkeypatch, capsys):
    printed = printed_config(["--task", "walk", "--robot", "solo12"], monkeypatch, capsys)
    assert config_lib.from_dict(printed) == cli_default("walk")
    path = tmp_path / "walk.json"
    path.write_text(json.dumps(printed))
    assert printed_config(["--config", str(path)], monkeypatch, capsys) == printed
    # train builds its config the same way: its flags class parses the same file
    base = cli._prescan(["--config", str(path)])
    assert base == config_lib.from_dict(printed)


KNEELESS_GO2 = "the Go2 without its front-left knee motor"
WEAK_SOLO12 = "the Solo12 with a fifth of its torque"


@pytest.mark.parametrize(
    ("task", "robot", "actuators", "reason"),
    [
        # An arm for a legged task: no floating base (tasks/legged.py's fits).
        ("walk", "iiwa14", "strict", "need a floating base"),
        # A published quadruped with a leg joint that no motor drives (the Go2 with its
        # front-left knee motor removed, written below): the legged tasks drive every leg
        # joint. (A quadruped driven by servos runs, converted at load time.)
        ("jump", KNEELESS_GO2, "strict", "have no torque motor of their own"),
        # A quadruped too weak to stand up its own walk reference (the Solo12 with motors of
        # 0.5 N m, not 2.7): the reference the task would follow falls by its fall rule.
        ("walk", WEAK_SOLO12, "strict", "walk reference falls by the robot's own fall rule"),
        # A planar arm for the op-space task: no 3-D site to control.
        ("opspace", "two_link_arm", "strict", None),
    ],
)
def test_config_refuses_a_robot_its_task_cannot_run_on(
    task, robot, actuators, reason, monkeypatch, capsys, tmp_path
):
    """``cfm-jax config`` refuses, in one line and before any training, what ``cfm-jax robot
    check`` reports the task cannot run on, with the same reason."""
    from pathlib import Path

    from cfm_jax.analysis import robot_check

    if robot == KNEELESS_GO2:
        text = (Path(__file__).parent / "robots" / "quadrupeds" / "go2.xml").read_text()
        motor = '<motor class="knee" name="FL_calf" joint="FL_calf_joint"/>'
        assert text.count(motor) == 1
        robot = str(tmp_path / "go2_kneeless.xml")
        Path(robot).write_text(text.replace(motor, ""))
    if robot == WEAK_SOLO12:
        text = (Path(__file__).parents[1] / "robots" / "solo12.xml").read_text()
        robot = str(tmp_path / "solo12_weak.xml")
        Path(robot).write_text(text.replace('ctrlrange="-2.7 2.7"', 'ctrlrange="-0.5 0.5"'))
    why = robot_check.check(robot, actuators=actuators).tasks[task]
    assert why is not None and (reason is None or reason in why)
    argv = ["cfm-jax", "config", "--task", task, "--robot", robot]
    monkeypatch.setattr(sys, "argv", argv + ["--robot-actuators", actuators])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    line = f"cfm-jax: error: task.name={task!r} does not fit robot={robot!r}: "
    assert captured.err == line + " ".join(why.split()) + "\n"


def test_version_is_the_package_metadata(monkeypatch, capsys):
    from importlib import metadata

    monkeypatch.setattr(sys, "argv", ["cfm-jax", "--version"])
    cli.main()
    assert capsys.readouterr().out.strip() == f"cfm-jax {metadata.version('cfm_jax')}"


def help_text(command, monkeypatch, capsys) -> str:
    """``cfm-jax COMMAND --help`` in-process at 100 columns: it exits 0; the printed text."""
    monkeypatch.setattr(sys, "argv", ["cfm-jax", *command, "--help"])
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 0
    return capsys.readouterr().out


def test_help_has_no_hard_breaks_and_readable_metavars(monkeypatch, capsys):
    text = help_text(["train"], monkeypatch, capsys)
    assert "{None}" not in text and "``" not in text and ":data:" not in text
    for flag in ("--forward.learning-rate", "--loop.babbling", "--task.kd", "--seeds"):
        assert flag in text
    assert text.count("(default: 0.001)") == 2  # both learning rates, each stated once
    # The docstrings' notes of the library default are left out: the hint says it once.
    flat = " ".join(line.strip("│ ") for line in text.splitlines())
    notes = ("(default;", "(default: the param", "(default,", "None (default)", "default warm)")
    for note in notes:
        assert note not in flat, note
    assert "pd (the gains above)" in flat.replace("  ", " ")
    assert "{home,reaching,reference_pd,oracle}" in text


@pytest.mark.parametrize("command", [["train"], ["sweep"], ["config"], ["robot", "check"]])
def test_every_help_shows_examples_whose_flags_exist(command, monkeypatch, capsys):
    """Each command's --help shows its docstring's command lines (tyro drops a docstring's
    Examples section, so they are passed as the description), every flag they use is one
    of that command's flags, and no metavar or default reads as Python."""
    text = help_text(command, monkeypatch, capsys)
    assert "{None}" not in text and "(default: )" not in text and "(default: ())" not in text
    lines = text.splitlines()
    start = lines.index("Examples:")
    examples = [line.strip() for line in lines[start + 1 :] if line.startswith("  cfm-jax ")]
    assert examples and all(line.startswith("cfm-jax ") for line in examples)
    options = "\n".join(lines[start + 1 + len(examples) :])  # the flags' list
    flags = set(re.findall(r"(?m)^[\s│]*(--[\w.-]+)", options))
    flags |= set(re.findall(r", (--[\w.-]+)", options))  # aliases: --seeds INT, --loop.seeds
    assert "--help" in flags and len(flags) > 3
    for example in examples:
        if not example.startswith("cfm-jax " + " ".join(command)):
            continue  # config's second example is a train command line
        for word in example.split():
            if word.startswith("--"):
                assert word in flags, (example, word)


def test_a_run_that_fails_after_creating_out_leaves_no_empty_directory(tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise RuntimeError("failed inside the run")

    monkeypatch.setattr(cli, "_train_losses", fail)  # after the output directory exists
    out = tmp_path / "out"
    argv = ["cfm-jax", "train", "--robot", "two_link_arm", "--out", str(out), "--quiet"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(RuntimeError, match="failed inside the run"):
        cli.main()
    assert not out.exists()
    (tmp_path / "kept").mkdir()  # a directory that existed before is kept, empty or not
    monkeypatch.setattr(sys, "argv", [*argv[:-3], "--out", str(tmp_path / "kept"), "--quiet"])
    with pytest.raises(RuntimeError, match="failed inside the run"):
        cli.main()
    assert (tmp_path / "kept").is_dir()


def test_importing_every_module_and_the_cli_prints_nothing(tmp_path):
    # Negative control: this mujoco's mjx prints the Warp lines when Warp is missing (read
    # from its source, so the check below could fail); then the library's imports print
    # nothing although they import mujoco.mjx.
    import importlib.util

    spec = importlib.util.find_spec("mujoco.mjx.warp")
    if spec is None or importlib.util.find_spec("warp") is not None:
        pytest.skip("no Warp import message to filter on this install")
    assert "Failed to import warp" in open(spec.origin).read()
    imports = (
        "import cfm_jax.cli, cfm_jax.runs.training, cfm_jax.sim.rollout, "
        "cfm_jax.learning.rigid_body, sys; "
        "assert 'mujoco.mjx' in sys.modules"
    )
    done = subprocess.run([sys.executable, "-c", imports], capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert_own_output(done)
    assert done.stdout == ""


# A CLI run on the default simulator prints only the library's own lines: checked on the
# default run's real CLI subprocess, tests/test_train.py::test_cli_train_end_to_end.


@pytest.mark.parametrize(
    "argv",
    [
        ["--override", "task.kp=50,100", "--override", "task.kd=1,2"],
        ["--override", "task.kp=50,100", "task.kd=1,2"],
    ],
)
def test_every_override_is_an_axis_of_the_grid(argv, monkeypatch):
    # A repeated --override kept only the last axis (2 cells instead of 4); one flag with
    # two axes and two flags with one each now give the same grid.
    seen = {}
    monkeypatch.setattr(cli, "_run_sweep", lambda base, names, override, *rest: seen.update(
        override=override))  # fmt: skip
    monkeypatch.setattr(sys, "argv", ["cfm-jax", "sweep", "--robot", "two_link_arm", *argv])
    cli.main()
    assert seen["override"] == ("task.kp=50,100", "task.kd=1,2")


def test_a_several_loss_config_file_gives_its_losses(tmp_path, monkeypatch):
    # The top-level config.json of a several-loss run lists its losses; --config FILE
    # then trains those losses (unless --loss says otherwise), and Python's from_dict
    # refuses it with a message that says where each loss's own config is.
    data = config_lib.to_dict(cli_default())
    data["loss"] = "task,supervised"
    path = tmp_path / "config.json"
    path.write_text(json.dumps(data))
    seen = {}
    monkeypatch.setattr(cli, "_run_train", lambda base, names, *rest: seen.update(
        base=base, names=names))  # fmt: skip
    for extra, names in (([], ["task", "supervised"]), (["--loss", "joint"], ["joint"])):
        monkeypatch.setattr(sys, "argv", ["cfm-jax", "train", "--config", str(path), *extra])
        cli.main()
        assert seen["names"] == names and seen["base"].loss == names[0]
    with pytest.raises(config_lib.ConfigError, match="OUT/<loss>/config.json"):
        config_lib.from_dict(data)
