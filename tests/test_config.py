"""Config validation (cfm_jax/config.py): every validated field rejects bad values with a
ConfigError naming the field, showing the bad value and saying what is allowed; JSON round
trip; unknown keys rejected.

Oracle: the documented rules of each field (comments in config.py), written out below as
(field, bad value, fragment of the "allowed" text) rows.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re

import pytest

from cfm_jax import config
from cfm_jax.config import (
    Config,
    ConfigError,
    ControllerConfig,
    ForwardModelConfig,
    LoopConfig,
    TaskConfig,
)

POSITIVE_INT = "a positive integer"
NONNEG_INT = "an integer >= 0"
POSITIVE_FLOAT = "a finite number > 0"
NONNEG_FLOAT = "a finite number >= 0"
LAYERS = "a non-empty tuple of positive integers"

# (dataclass, keyword, bad value, field name in the message, fragment of what is allowed)
BAD = [
    (TaskConfig, "name", "walking", "task.name", "inverse_dynamics"),
    (TaskConfig, "name", 3, "task.name", "inverse_dynamics"),
    (TaskConfig, "duration", 0.0, "task.duration", POSITIVE_FLOAT),
    (TaskConfig, "duration", -1.0, "task.duration", POSITIVE_FLOAT),
    (TaskConfig, "duration", math.inf, "task.duration", POSITIVE_FLOAT),
    (TaskConfig, "duration", True, "task.duration", POSITIVE_FLOAT),
    (TaskConfig, "control_dt", 0.0, "task.control_dt", POSITIVE_FLOAT),
    (TaskConfig, "control_dt", math.nan, "task.control_dt", POSITIVE_FLOAT),
    (TaskConfig, "kp", -1.0, "task.kp", NONNEG_FLOAT),
    (TaskConfig, "kp", math.nan, "task.kp", NONNEG_FLOAT),
    (TaskConfig, "kd", -0.1, "task.kd", NONNEG_FLOAT),
    (TaskConfig, "kd", "20", "task.kd", NONNEG_FLOAT),
    (TaskConfig, "targets", (), "task.targets", "non-empty"),
    (TaskConfig, "targets", ((0.0, 1.0), (0.0,)), "task.targets", "equal length"),
    (TaskConfig, "targets", ((0.0, math.nan),), "task.targets", "finite joint positions"),
    (TaskConfig, "home", (0.0, math.inf), "task.home", "finite joint positions"),
    (ForwardModelConfig, "hidden", (), "forward.hidden", LAYERS),
    (ForwardModelConfig, "hidden", (400, 0), "forward.hidden", LAYERS),
    (ForwardModelConfig, "hidden", (400, 2.5), "forward.hidden", LAYERS),
    (ForwardModelConfig, "hidden", (True,), "forward.hidden", LAYERS),
    (ForwardModelConfig, "ensemble_size", 0, "forward.ensemble_size", POSITIVE_INT),
    (ForwardModelConfig, "ensemble_size", 3.0, "forward.ensemble_size", POSITIVE_INT),
    (ForwardModelConfig, "learning_rate", 0.0, "forward.learning_rate", POSITIVE_FLOAT),
    (ForwardModelConfig, "initial_steps", -1, "forward.initial_steps", NONNEG_INT),
    (ForwardModelConfig, "steps_per_iteration", 1.5, "forward.steps_per_iteration", NONNEG_INT),
    (ForwardModelConfig, "batch_size", 0, "forward.batch_size", POSITIVE_INT),
    (ForwardModelConfig, "batch_size", False, "forward.batch_size", POSITIVE_INT),
    (
        ForwardModelConfig,
        "min_log_variance",
        math.nan,
        "forward.min_log_variance",
        "a finite number",
    ),
    (ForwardModelConfig, "max_log_variance", "big", "forward.max_log_variance", "a finite number"),
    (
        ForwardModelConfig,
        "min_log_variance",
        0.5,
        "forward.min_log_variance",
        "below forward.max_log_variance=0.5",
    ),
    (ControllerConfig, "hidden", ((),), "controller.hidden", LAYERS),
    (ControllerConfig, "hidden", (-3,), "controller.hidden", LAYERS),
    (ControllerConfig, "learning_rate", -1e-3, "controller.learning_rate", POSITIVE_FLOAT),
    (ControllerConfig, "initial_steps", -5, "controller.initial_steps", NONNEG_INT),
    (ControllerConfig, "steps_per_iteration", -1, "controller.steps_per_iteration", NONNEG_INT),
    (ControllerConfig, "batch_size", 0, "controller.batch_size", POSITIVE_INT),
    (LoopConfig, "iterations", -1, "loop.iterations", NONNEG_INT),
    (LoopConfig, "seeds", 0, "loop.seeds", POSITIVE_INT),
    (LoopConfig, "babbling_rollouts", 0, "loop.babbling_rollouts", POSITIVE_INT),
    (LoopConfig, "babbling_noise", -0.1, "loop.babbling_noise", NONNEG_FLOAT),
    (LoopConfig, "checkpoint_every", -1, "loop.checkpoint_every", NONNEG_INT),
    (LoopConfig, "checkpoint_every", 1.5, "loop.checkpoint_every", NONNEG_INT),
    (LoopConfig, "checkpoint_keep", 0, "loop.checkpoint_keep", POSITIVE_INT),
    (Config, "robot", "", "robot", "registered robot name"),
    (Config, "robot", None, "robot", "registered robot name"),
    (Config, "loss", "mse", "loss", "'distal', 'supervised', 'distal_literal')"),
    (Config, "seed", -1, "seed", NONNEG_INT),
    (Config, "seed", 1.0, "seed", NONNEG_INT),
    (Config, "task", {"duration": 1.0}, "task", "a TaskConfig"),
    (Config, "forward", ControllerConfig(), "forward", "a ForwardModelConfig"),
    (Config, "controller", None, "controller", "a ControllerConfig"),
    (Config, "loop", {}, "loop", "a LoopConfig"),
]


@pytest.mark.parametrize(
    "cls, keyword, bad, field, allowed",
    BAD,
    ids=[f"{row[3]}={row[2]!r}" for row in BAD],
)
def test_each_field_rejects_bad_values(cls, keyword, bad, field, allowed):
    with pytest.raises(ConfigError) as info:
        cls(**{keyword: bad})
    message = str(info.value)
    # The message starts with "<field>=<repr of the bad value>" and says what is allowed.
    assert message.startswith(f"{field}={bad!r}"), message
    assert allowed in message, message


# Targets/home that are not sequences of numbers (a flat tuple for one target is an easy
# mistake) must raise ConfigError naming the field, not a bare TypeError/ValueError.
MALFORMED = [
    ("targets", (0.1, 0.2), "task.targets"),
    ("targets", (("a", 0.0),), "task.targets"),
    ("home", 0.5, "task.home"),
    ("home", ("x",), "task.home"),
]


@pytest.mark.parametrize(
    "keyword, bad, field", MALFORMED, ids=[f"{r[0]}={r[1]!r}" for r in MALFORMED]
)
def test_malformed_targets_and_home_raise_config_error(keyword, bad, field):
    with pytest.raises(ConfigError) as info:
        TaskConfig(**{keyword: bad})
    assert str(info.value).startswith(f"{field}={bad!r}")


@pytest.mark.parametrize("duration, control_dt", [(0.105, 0.01), (0.004, 0.01), (1.0, 0.3)])
def test_duration_must_be_whole_control_periods(duration, control_dt):
    # A quintic sampled every control_dt only ends at the goal (zero velocity) when the
    # duration is a whole number of periods.
    with pytest.raises(ConfigError) as info:
        TaskConfig(duration=duration, control_dt=control_dt)
    assert str(info.value).startswith(f"task.duration={duration!r}")


def test_whole_control_periods_are_accepted():
    assert TaskConfig(duration=0.3, control_dt=0.01).duration == 0.3
    assert TaskConfig(duration=1.2, control_dt=0.3).duration == 1.2


@pytest.mark.parametrize("bad", ["bullet", "MJX", None, 3])
def test_unknown_simulator(bad):
    with pytest.raises(ConfigError) as info:
        Config(simulator=bad)
    assert str(info.value).startswith(f"simulator={bad!r}")
    assert "native" in str(info.value) and "mjx" in str(info.value)


def test_config_error_is_a_value_error():
    # Callers that catch ValueError (e.g. argument parsers) see config errors too.
    assert issubclass(ConfigError, ValueError)


def test_defaults_are_valid_and_match_the_paper():
    # Paper section IV: forward 3 x 400, 3 members; controller 300-200-100.
    cfg = Config()
    assert cfg.forward.hidden == (400, 400, 400)
    assert cfg.forward.ensemble_size == 3
    assert cfg.controller.hidden == (300, 200, 100)
    assert cfg.loss == "joint"


def test_normalisation_of_sequences():
    # Lists become tuples, targets and home become float tuples (hashable, JSON-stable).
    task = TaskConfig(targets=[[0, 1], [2, 3]], home=[1, 2])
    assert task.targets == ((0.0, 1.0), (2.0, 3.0))
    assert all(isinstance(x, float) for t in task.targets for x in t)
    assert task.home == (1.0, 2.0)
    assert ForwardModelConfig(hidden=[8, 4]).hidden == (8, 4)


def test_replace_validates_again():
    cfg = Config()
    assert cfg.replace(loss="task").loss == "task"
    with pytest.raises(ConfigError, match=r"^loss='nope'"):
        cfg.replace(loss="nope")


def test_json_round_trip():
    cfg = Config(
        robot="two_link_arm",
        loss="distal",
        seed=3,
        task=TaskConfig(
            duration=0.5,
            control_dt=None,
            targets=((0.1, 0.2), (0.3, -0.4)),
            home=(0.0, 0.5),
            kp=0.0,
            kd=0.0,
        ),
        forward=ForwardModelConfig(
            hidden=(16, 8),
            ensemble_size=2,
            batch_size=32,
            min_log_variance=-5.0,
            max_log_variance=1.0,
        ),
        controller=ControllerConfig(hidden=(12,), learning_rate=3e-4),
        loop=LoopConfig(iterations=0, seeds=2, babbling_noise=0.0),
    )
    text = json.dumps(config.to_dict(cfg))
    back = config.from_dict(json.loads(text))
    assert back == cfg
    # and JSON of the default config too (targets/home None)
    default = Config()
    assert config.from_dict(json.loads(json.dumps(config.to_dict(default)))) == default


def test_from_dict_partial_uses_defaults():
    cfg = config.from_dict({"loss": "task", "forward": {"ensemble_size": 5}})
    assert cfg.loss == "task"
    assert cfg.forward.ensemble_size == 5
    assert cfg.forward.hidden == ForwardModelConfig().hidden
    assert cfg.task == TaskConfig()


def test_from_dict_rejects_unknown_top_level_key():
    with pytest.raises(ConfigError) as info:
        config.from_dict({"loss": "task", "learning_rate": 1e-3})
    message = str(info.value)
    assert "learning_rate" in message
    assert "known top-level fields" in message


@pytest.mark.parametrize("section", ["task", "forward", "controller", "loop"])
def test_from_dict_rejects_unknown_section_key(section):
    with pytest.raises(ConfigError) as info:
        config.from_dict({section: {"no_such_field": 1}})
    message = str(info.value)
    assert message.startswith(f"{section}=['no_such_field']"), message
    assert f"known fields of {section}" in message


def test_from_dict_validates_values():
    with pytest.raises(ConfigError, match=r"^forward\.batch_size=0"):
        config.from_dict({"forward": {"batch_size": 0}})


def test_seeds_of():
    cfg = Config(seed=4, loop=LoopConfig(seeds=3))
    assert tuple(config.seeds_of(cfg)) == (4, 5, 6)


def test_for_task_defaults():
    from cfm_jax import config as config_lib

    walk = config_lib.for_task("walk")
    assert (walk.robot, walk.task.name, walk.task.control_dt) == ("solo12", "walk", 0.004)
    assert walk.forward.hidden == (1000, 500, 500) and walk.forward.ensemble_size == 1
    assert walk.controller.hidden == (300, 300, 300)  # the paper's quadruped networks
    # The selection run's choices for the legged tasks (docs/results/selection/).
    assert (walk.task.desired, walk.forward.kind, walk.loop.normaliser) == (
        "next_velocity", "rigid_body", "data")  # fmt: skip
    assert (walk.forward.start, walk.controller.start, walk.controller.loss_form) == (
        "warm_new_optimizer", "warm_new_optimizer", "squared")  # fmt: skip
    arm = config_lib.for_task("opspace", seed=3)
    assert arm.task.name == "opspace" and arm.seed == 3
    assert arm.forward == config_lib.ForwardModelConfig()  # the arm defaults
    with pytest.raises(config_lib.ConfigError, match="task.name='swim' is not allowed"):
        config_lib.for_task("swim")
    # Legged tasks: no PD gains (s* is the desired next velocity, kp 0 and kd 1/control_dt
    # implied by task.desired), the walk with joint position feedback 1000/s^2 (its
    # selection check), the jump without (joint_kp None: 0); arms: kp 100, kd 20.
    assert (walk.task.kp, walk.task.kd, walk.task.joint_kp, walk.task.joint_kd) == (
        0.0, 0.0, 1000.0, None)  # fmt: skip
    jump = config_lib.for_task("jump").task
    assert (jump.kp, jump.kd, jump.joint_kp, jump.joint_kd) == (0.0, 0.0, None, None)
    assert (arm.task.kp, arm.task.kd, arm.task.joint_kp, arm.task.joint_kd) == (
        100.0, 20.0, None, None)  # fmt: skip
    from cfm_jax.tasks import babbling

    # Every task's initial data knows nothing of the test references: the arms reach to
    # random poses, the legged robot holds its standing pose (the selection run's choices).
    for name in config_lib.TASKS:
        expected = "home" if name in ("walk", "jump") else "reaching"
        assert config_lib.for_task(name).loop.babbling == expected
        assert not babbling.uses_reference(config_lib.for_task(name).loop.babbling)


@pytest.mark.parametrize("field", ["joint_kp", "joint_kd"])
def test_joint_gains_are_for_the_legged_tasks_only(field):
    with pytest.raises(ConfigError) as info:
        TaskConfig(**{field: 500.0})  # inverse_dynamics
    message = str(info.value)
    assert message.startswith(f"task.{field}=500.0 is not allowed"), message
    assert "'walk' and 'jump'" in message and "task.kp and task.kd" in message
    with pytest.raises(ConfigError, match=rf"task.{field}=-1.0 .* >= 0"):
        TaskConfig(name="jump", desired="pd", **{field: -1.0})
    assert getattr(TaskConfig(name="jump", desired="pd", **{field: 0}), field) == 0


def test_a_config_written_before_loop_babbling_reads_as_what_ran():
    from cfm_jax import config as config_lib

    for task, before in (("inverse_dynamics", "reference_pd"), ("walk", "oracle")):
        data = config_lib.to_dict(config_lib.for_task(task))
        del data["loop"]["babbling"]
        assert config_lib.from_dict(data).loop.babbling == before
    # A config that names its strategy keeps it; one without a loop section: the default.
    data = config_lib.to_dict(config_lib.for_task("walk"))
    assert config_lib.from_dict(data).loop.babbling == "home"
    assert config_lib.from_dict({"robot": "iiwa14"}).loop.babbling == "reaching"


def test_the_oracle_is_the_period_one_for_the_arms_and_the_one_step_one_in_old_records():
    assert config.TaskConfig().oracle == "period"
    for task in ("opspace", "walk", "jump"):
        assert config.TaskConfig(name=task).oracle == "step"
        with pytest.raises(config.ConfigError, match=rf"task.oracle='period' .* task '{task}'"):
            config.TaskConfig(name=task, oracle="period")
    with pytest.raises(config.ConfigError, match=r"task.oracle='exact' .* \('period', 'step'\)"):
        config.TaskConfig(oracle="exact")
    data = config.to_dict(config.Config())
    assert config.from_dict(data).task.oracle == "period"
    del data["task"]["oracle"]  # a config.json written before the field: the one-step oracle ran
    assert config.from_dict(data).task.oracle == "step"


def test_motions_are_for_the_legged_tasks_only():
    walk = config.TaskConfig(name="walk", motions=[1.25, 2.75])
    assert walk.motions == (1.25, 2.75)
    assert config.from_dict(config.to_dict(config.Config(task=walk))).task == walk
    with pytest.raises(config.ConfigError, match=r"task.motions=\(1.0,\) .* 'inverse_dynamics'"):
        config.TaskConfig(motions=(1.0,))
    for bad in ((), (0.0,), (-1.0,), (float("nan"),), ("a",), 3.0):
        with pytest.raises(config.ConfigError, match="task.motions=.*positive numbers"):
            config.TaskConfig(name="jump", motions=bad)


@pytest.mark.parametrize(
    "cls",
    [
        config.TaskConfig,
        config.ForwardModelConfig,
        config.ControllerConfig,
        config.LoopConfig,
        config.Config,
    ],
)
def test_each_field_is_documented_once_where_the_cli_help_comes_from(cls):
    # The docstring's Attributes section is the one description of a field: the API page
    # shows it and the CLI builds its --help from it (cli._attribute_help). No second
    # description (a comment above the field) to drift from it.
    import inspect

    from cfm_jax import cli

    fields = [f.name for f in dataclasses.fields(cls)]
    documented = cli._attribute_help(cls)
    assert list(documented) == fields  # every field, in order, once
    assert all(len(text) > 10 for text in documented.values())
    body = inspect.getsource(cls).split('"""')[2]  # after the docstring
    lines = body.splitlines()
    for i, line in enumerate(lines):
        name = line.strip().split(":")[0]
        if name in fields and i > 0:
            assert not lines[i - 1].strip().startswith("#"), f"{cls.__name__}.{name}"


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: Config(iterations=2), "Config(loop=LoopConfig(iterations=...))"),
        (lambda: Config(kp=100.0), "Config(task=TaskConfig(kp=...))"),
        (lambda: LoopConfig(robot="iiwa14"), "it is a field of Config: Config(robot"),
        (lambda: Config(nonsense=1), "the fields are ['controller', 'forward'"),
    ],
)
def test_a_field_in_the_wrong_section_names_its_section(make, words):
    # Oracle: where each field is declared (dataclasses.fields), written out by hand here.
    with pytest.raises(TypeError, match=re.escape(words)):
        make()
    # The constructors, replace and the JSON round trip still take every real field.
    made = Config(loop=LoopConfig(iterations=2), seed=3)
    assert made.loop.iterations == 2 and made.replace(seed=4).seed == 4
    assert config.from_dict(config.to_dict(made)) == made
