"""Each task owns its defaults (issue 44, item 2): a config that names a task is that task's
experiment, however it is made (``Config``, ``for_task``, the task's ``default_config``, the
CLI), and a task registered outside the library brings its own defaults."""

import json
import subprocess
import sys

import pytest

from cfm_jax import cli, config, tasks
from cfm_jax.config import Config, ConfigError, LoopConfig, TaskConfig

# What the docs state of each task's defaults (README, docs/concepts), written out by hand.
STATED = {
    "inverse_dynamics": {"robot": "iiwa14", "task.control_dt": 0.01, "task.kp": 100.0,
                         "task.desired": "pd", "forward.kind": "mlp",
                         "loop.babbling": "reaching", "loop.torque_scale": "auto"},
    "opspace": {"robot": "iiwa14", "task.control_dt": 0.01, "task.kp": 100.0,
                "forward.kind": "mlp", "loop.babbling": "reaching",
                "loop.torque_scale": "inertia"},
    "walk": {"robot": "solo12", "task.control_dt": 0.004, "task.kp": 0.0, "task.kd": 0.0,
             "task.joint_kp": 1000.0, "task.desired": "next_velocity", "forward.kind": "rigid_body",
             "forward.hidden": (1000, 500, 500), "controller.loss_form": "squared",
             "loop.babbling": "home", "loop.normaliser": "data", "loop.torque_scale": "limit"},
}  # fmt: skip
STATED["jump"] = {**STATED["walk"], "task.joint_kp": None}  # the walk's own s* feedback


def value(cfg: Config, path: str):
    obj = cfg
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


@pytest.mark.parametrize("name", ["inverse_dynamics", "opspace", "walk", "jump"])
def test_every_way_of_naming_a_task_gives_its_experiment(name):
    bare = Config(task=TaskConfig(name=name))
    assert bare == config.for_task(name) == tasks.load(name).default_config()
    assert bare.task.name == name
    for path, stated in STATED[name].items():
        assert value(bare, path) == stated, path
    # The CLI starts from the same config and, given no flag, runs it: the config each
    # loss of `cfm-jax train --task NAME` runs (issue 67: iterations included).
    assert cli._prescan(["--task", name]) == bare
    # Through JSON (a run's config.json) it reads back as the same experiment.
    assert config.from_dict(json.loads(json.dumps(config.to_dict(bare)))) == bare


def test_fields_given_win_over_the_task_defaults_and_sections_are_whole():
    walk = TaskConfig(name="walk", duration=3.0)
    assert (walk.duration, walk.control_dt, walk.desired) == (3.0, 0.004, "next_velocity")
    # A walk with PD gains in s*: desired says so, the gains given are taken.
    pd = TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0, joint_kp=2000.0)
    assert (pd.kp, pd.joint_kp, pd.control_dt) == (100.0, 2000.0, 0.004)
    # The walk's joint_kp (1000) is its next-velocity s*'s: the PD form left without one takes
    # the generic None (the joints' gains are kp's), given one takes it, as is None given.
    assert TaskConfig(name="walk", desired="pd", kp=100.0, kd=20.0).joint_kp is None
    assert TaskConfig(name="walk").joint_kp == 1000.0
    assert TaskConfig(name="walk", joint_kp=None).joint_kp is None
    with pytest.raises(ConfigError, match=r"task.kp=100.0 .*set task.desired='pd'"):
        TaskConfig(name="walk", kp=100.0)
    # The robot given wins; the sections left out are the task's.
    cfg = Config(robot="two_link_arm", task=TaskConfig(name="walk"))
    assert cfg.robot == "two_link_arm" and cfg.forward.kind == "rigid_body"
    # A section given is taken as given: its fields' defaults are the generic ones.
    cfg = Config(task=TaskConfig(name="walk"), loop=LoopConfig(seeds=2))
    assert (cfg.loop.seeds, cfg.loop.babbling) == (2, "reaching")
    assert cfg.controller == config.for_task("walk").controller


def test_a_task_config_written_before_desired_existed_reads_as_what_ran():
    # Every s* was the PD form before task.desired existed, whatever the walk's default now.
    data = config.to_dict(config.for_task("walk"))
    data["task"].update(kp=100.0, kd=20.0)
    del data["task"]["desired"]
    task = config.from_dict(data).task
    assert (task.desired, task.kp, task.kd, task.control_dt) == ("pd", 100.0, 20.0, 0.004)


def test_a_task_registered_outside_the_library_brings_its_defaults_and_checks():
    # In a fresh interpreter: registering adds to the process's registries for good.
    code = """
from cfm_jax import config, tasks
from cfm_jax.config import Config, LoopConfig, TaskConfig
from cfm_jax.tasks import inverse_dynamics

def hover_defaults():
    return Config(robot="two_link_arm", task=TaskConfig(name="hover", duration=1.0),
                  loop=LoopConfig(seeds=2))

tasks.register("hover", inverse_dynamics.make, hover_defaults)
tasks.register("plain", inverse_dynamics.make)

def gentle(task):
    if task.kp > 60:
        config.fail("task.kp", task.kp, "at most 60 for task 'gentle'")

tasks.register("gentle", inverse_dynamics.make, check=gentle, structural=("kp",))
shape = [config.structure(Config(task=TaskConfig(name=n, kp=k)))
         for n in ("plain", "gentle") for k in (10.0, 20.0)]  # kp: runtime, unless structural
hover = Config(task=TaskConfig(name="hover"))
plain = Config(task=TaskConfig(name="plain", kp=50.0, joint_kp=5.0))  # no check: taken
try:
    TaskConfig(name="gentle", kp=70.0)
except config.ConfigError as error:
    refused = str(error).replace(" ", "_")
from cfm_jax import cli
assert cli._prescan(["--task", "hover"]) == hover  # the CLI's config is Python's
print(hover.robot, hover.task.duration, hover.task.kp, hover.loop.seeds,
      hover == config.for_task("hover"), plain.robot, plain.task.kp, plain.task.duration,
      plain.loop == LoopConfig(), plain.task.joint_kp, TaskConfig(name="gentle", kp=50.0).kp,
      refused, shape[0] == shape[1], shape[2] == shape[3])
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [
        "two_link_arm", "1.0", "100.0", "2", "True", "iiwa14", "50.0", "2.0", "True", "5.0",
        "50.0", "task.kp=70.0_is_not_allowed:_at_most_60_for_task_'gentle'", "True", "False",
    ]  # fmt: skip


def test_a_field_a_task_builds_into_its_program_is_structure():
    # opspace's home (its oracle's null-space posture) is compiled in; inverse dynamics's
    # is a runtime value: two configs differing only there share a program or not.
    for name, shared in (("opspace", False), ("inverse_dynamics", True)):
        base = config.for_task(name)
        moved = base.replace(task=TaskConfig(name=name, home=(0.1,) * 7))
        assert (config.structure(base) == config.structure(moved)) is shared, name
    assert config.structure(config.for_task("opspace"))["task"]["home"] is None
