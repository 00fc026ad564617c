"""Frozen, validated configuration dataclasses.

Each field is documented once, in its class's ``Attributes:`` (also the CLI's ``--help``).
Every constructor checks its fields and raises :class:`ConfigError` naming the field, the
bad value and what is allowed. Configs round-trip through JSON (:func:`to_dict` /
:func:`from_dict`); :func:`for_task` gives a task's defaults.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

from cfm_jax import _shipped

TASKS = ("inverse_dynamics", "opspace", "walk", "jump")
"""Values of ``Config.task.name``: the library's four, then those of :func:`add_task_name`."""

_BUILT_IN_TASKS = TASKS


def add_task_name(
    name: str,
    default_config: Callable[[], Config] | None = None,
    check: Callable[[TaskConfig], None] | None = None,
    structural: tuple[str, ...] = (),
) -> None:
    """Let ``Config.task.name`` take ``name`` (:func:`cfm_jax.tasks.register` calls this).

    Args:
      name: the task's name; one already in :data:`TASKS` keeps its place.
      default_config: ``default_config() -> Config``, the task's defaults for fields left at
        :data:`TASK_DEFAULT` (inside it they take :data:`GENERIC`'s); None: the generic ones.
      check: ``check(task_config)``, raising :class:`ConfigError` for what the task refuses
        after the fields' own checks; None: nothing more.
      structural: its ``task.*`` fields of :data:`RUNTIME_FIELDS` built into its compiled
        program (``opspace``: ``home``); :func:`structure` keeps them.

    Examples:
      >>> add_task_name("walk", TASK_DEFAULTS["walk"], TASK_CHECKS.get("walk")); TASKS
      ('inverse_dynamics', 'opspace', 'walk', 'jump')
    """
    global TASKS
    if name not in TASKS:
        TASKS = TASKS + (name,)
    for registry, value in ((TASK_DEFAULTS, default_config), (TASK_CHECKS, check)):
        if value is None:
            registry.pop(name, None)
        else:
            registry[name] = value
    TASK_STRUCTURAL[name] = tuple(structural)
    _DEFAULTS_OF.pop(name, None)


class _TaskDefault:
    """The type of :data:`TASK_DEFAULT` (one instance)."""

    def __repr__(self) -> str:
        return "TASK_DEFAULT"

    def __reduce__(self):
        return "TASK_DEFAULT"


TASK_DEFAULT = _TaskDefault()
"""Default of the task-dependent fields (``robot``, ``forward``, ``controller``, ``loop``,
each :class:`TaskConfig` field but ``name``): such a field takes the task's
``default_config()`` value (:data:`TASK_DEFAULTS`). A section given explicitly is taken as
given: to change one field of a task's section, start from :func:`for_task`."""

TASK_DEFAULTS: dict[str, Callable[[], Config]] = {}
"""Each registered task's ``default_config`` (:func:`add_task_name`)."""

TASK_CHECKS: dict[str, Callable[[TaskConfig], None]] = {}
"""Each registered task's ``check`` of a :class:`TaskConfig` (:func:`add_task_name`)."""

TASK_STRUCTURAL: dict[str, tuple[str, ...]] = {}
"""Each registered task's ``structural`` fields (:func:`add_task_name`)."""

_DEFAULTS_OF: dict[str, Config] = {}  # each task's default_config(), made once
_BUILDING: set[str] = set()  # the tasks whose default_config() runs now


def _task_default(name: str, section: str | None, field: str) -> Any:
    """Task ``name``'s value of a field left at :data:`TASK_DEFAULT` (``section`` None: top
    level); :data:`GENERIC`'s while its ``default_config()`` runs or without one."""
    if name not in TASK_DEFAULTS and name in _BUILT_IN_TASKS:
        raise ConfigError(
            f"task.name={name!r}: its defaults are not registered yet (import cfm_jax, "
            "which registers the library's tasks, before making a config)"
        )
    if name in _BUILDING or name not in TASK_DEFAULTS:
        generic = GENERIC[section or "config"][field]
        return generic() if callable(generic) else generic
    if name not in _DEFAULTS_OF:
        _BUILDING.add(name)
        try:
            _DEFAULTS_OF[name] = TASK_DEFAULTS[name]()
        finally:
            _BUILDING.discard(name)
    defaults = _DEFAULTS_OF[name]
    return getattr(getattr(defaults, section) if section else defaults, field)


def _resolve(obj: Any, name: str, section: str | None) -> None:
    """Set the fields of ``obj`` left at :data:`TASK_DEFAULT` to task ``name``'s values."""
    for field in dataclasses.fields(obj):
        if getattr(obj, field.name) is TASK_DEFAULT:
            object.__setattr__(obj, field.name, _task_default(name, section, field.name))


FORWARD_KINDS = ("mlp", "rigid_body")
"""Values of ``Config.forward.kind`` (:mod:`cfm_jax.learning.forward_models`; see
:class:`ForwardModelConfig`)."""


FORWARD_OPTIONS: dict[str, type] = {}
"""Each kind's options dataclass, ``forward.options`` (:func:`add_forward_kind`)."""


def add_forward_kind(name: str, options: type | None = None) -> None:
    """Allow ``name`` as ``forward.kind`` (:func:`cfm_jax.learning.forward_models.register` calls
    this).

    Args:
      name: the new kind's name; a name already in :data:`FORWARD_KINDS` changes nothing.
      options: the kind's options, a frozen dataclass whose defaults are the kind's and whose
        ``__post_init__`` checks them (:func:`fail` with ``forward.options.FIELD``); None:
        the kind takes none.

    Examples:
      >>> add_forward_kind("mlp"); FORWARD_KINDS
      ('mlp', 'rigid_body')
    """
    global FORWARD_KINDS
    if name not in FORWARD_KINDS:
        FORWARD_KINDS = FORWARD_KINDS + (name,)
    if options is None:
        FORWARD_OPTIONS.pop(name, None)
    else:
        FORWARD_OPTIONS[name] = options


def _kind_options(kind: str, value: Any) -> Any:
    """``forward.options`` of ``kind`` made from ``value`` (None, a dict, an options
    dataclass). Fields of other kinds' options are dropped where they hold those kinds'
    defaults (they say nothing: a sweep over ``forward.kind`` carries them) and refused
    otherwise."""
    own = FORWARD_OPTIONS.get(kind)
    if own is not None and isinstance(value, own):
        return value
    given = value
    if value is None:
        value = {}
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if not isinstance(value, dict):
        fail("forward.options", given, "None, a dict of the kind's options or its options object")
    names = [f.name for f in dataclasses.fields(own)] if own is not None else []
    for key, item in value.items():
        if key in names:
            continue
        defaults = [
            f.default
            for other, cls in FORWARD_OPTIONS.items()
            if other != kind
            for f in dataclasses.fields(cls)
            if f.name == key
        ]
        if not defaults or any(item != d for d in defaults):
            allowed = (
                f"an option of forward.kind={kind!r}, one of {names}"
                if names
                else f"no options: forward.kind={kind!r} takes none"
            )
            fail(f"forward.options.{key}", item, allowed)
    return own(**{k: v for k, v in value.items() if k in names}) if own is not None else None


SIMULATORS = ("native", "mjx")
"""Values of ``Config.simulator`` (:mod:`cfm_jax.sim.rollout`)."""


def check_simulator(simulator: str) -> None:
    """Raise :class:`ConfigError` unless ``simulator`` is one of :data:`SIMULATORS`.

    Args:
      simulator: the name to check.

    Raises:
      ConfigError: naming the value and the allowed ones.

    Examples:
      >>> check_simulator("mujoco")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: simulator='mujoco' is not allowed: one of ('native', 'mjx')
    """
    if simulator not in SIMULATORS:
        raise ConfigError(f"simulator={simulator!r} is not allowed: one of {SIMULATORS}")


PAPER_LOSSES = ("joint", "task", "distal", "supervised")
"""The paper's four controller losses (:mod:`cfm_jax.learning.losses`), in reporting order
(``all``)."""

CONTROLLER_LOSSES = PAPER_LOSSES + ("distal_literal",)
"""Values of ``Config.loss``: :data:`PAPER_LOSSES`, ``distal_literal`` (the distal teacher
as a loss over the whole data set, :func:`cfm_jax.learning.losses.distal_literal`) and every loss
registered since (:func:`cfm_jax.learning.losses.register` calls :func:`add_loss_name`)."""


def add_loss_name(name: str) -> None:
    """Allow ``name`` as ``Config.loss`` (:func:`cfm_jax.learning.losses.register` calls this).

    Args:
      name: the new loss's name; a name already in :data:`CONTROLLER_LOSSES` changes nothing.

    Examples:
      >>> add_loss_name("joint"); CONTROLLER_LOSSES
      ('joint', 'task', 'distal', 'supervised', 'distal_literal'...)
    """
    global CONTROLLER_LOSSES
    if name not in CONTROLLER_LOSSES:
        CONTROLLER_LOSSES = CONTROLLER_LOSSES + (name,)


def loss_names(losses, field: str = "losses") -> tuple[str, ...]:
    """The one reading of "several losses": ``"all"`` (the paper's four), a name, a
    comma-separated string of names, or a sequence of names, as a tuple of distinct
    registered names (:data:`CONTROLLER_LOSSES`).

    Args:
      losses: as above.
      field: how the error names the value (``losses``, ``--loss``, ...).

    Raises:
      ConfigError: an unknown or repeated name, or none.

    Examples:
      >>> loss_names("all")
      ('joint', 'task', 'distal', 'supervised')
      >>> loss_names("task, joint")
      ('task', 'joint')
      >>> loss_names(["task", "task"], field="--loss")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: --loss=['task', 'task'] is not allowed: 'all', a name or a
      comma-separated list of distinct names from ('joint', 'task', ..., 'distal_literal'...)
    """
    if isinstance(losses, str) and losses.strip() == "all":
        return tuple(PAPER_LOSSES)
    if isinstance(losses, str):
        names = tuple(s.strip() for s in losses.split(",") if s.strip())
    else:
        try:
            names = tuple(losses)
        except TypeError:
            names = ()
    unknown = [n for n in names if not isinstance(n, str) or n not in CONTROLLER_LOSSES]
    if not names or len(set(names)) != len(names) or unknown:
        fail(
            field,
            losses,
            f"'all', a name or a comma-separated list of distinct names from {CONTROLLER_LOSSES}"
            + (f"; not registered: {unknown}" if unknown else "")
            + " (a loss of your own: cfm_jax.learning.losses.register it first; on the command "
            "line, cfm-jax --import MODULE ..., MODULE registering it)",
        )
    return names


BABBLING_BEFORE = {
    "inverse_dynamics": "reference_pd",
    "opspace": "reference_pd",
    "walk": "oracle",
    "jump": "oracle",
}
"""Each task's babbling before ``loop.babbling`` existed (:func:`from_dict` of old configs)."""

BABBLING = ("home", "reaching", "reference_pd", "oracle")
"""Values of ``Config.loop.babbling`` (:mod:`cfm_jax.tasks.babbling`; see :class:`LoopConfig`)."""


TORQUE_SCALES = ("auto", "inertia", "limit", "coupled", "pose")
"""Values of ``Config.loop.torque_scale`` (see :class:`LoopConfig`): the formulas are in
:meth:`cfm_jax.sim.robots.Robot.torque_scale` and
:meth:`~cfm_jax.sim.robots.Robot.coupled_torque_scale`, why ``auto`` is the arm default in
docs/how-to/own-robot.md."""

COUPLED_NOISE_SCALES = ("auto", "coupled", "pose")
"""The :data:`TORQUE_SCALES` whose babbling noise is ``T n``, the coupled scale at home."""


BABBLING_GAINS = ("lightest", "baseline")
"""Values of ``Config.loop.babbling_gains`` (:func:`cfm_jax.tasks.baselines.babbling_joint_gains`).
The legged and op-space tasks' feedback keeps its own gains either way."""


NORMALISERS = ("babbling", "data", "robot")
"""Values of ``Config.loop.normaliser`` (:class:`cfm_jax.learning.networks.Normaliser`)."""

ROBOT_ACTUATORS = ("strict", "torque")
"""Values of ``Config.robot_actuators`` (see :class:`Config`)."""

DESIRED = ("pd", "next_velocity")
"""Values of ``Config.task.desired`` (see :class:`TaskConfig`)."""
ORACLES = ("period", "step")
"""Values of ``Config.task.oracle`` (see :class:`TaskConfig`)."""
MOTION_FAMILIES = ("test", "selection")
"""Values of ``Config.task.motion_family`` (see :class:`TaskConfig`)."""
CONTROLLER_GOALS = ("desired", "observed")
"""Values of ``Config.controller.goal`` (see :class:`ControllerConfig`)."""

LOSS_FORMS = ("squared", "norm")
"""Values of ``Config.controller.loss_form`` (see :class:`ControllerConfig`)."""

FIT_STARTS = ("warm", "warm_new_optimizer", "fresh")
"""Values of ``forward.start`` and ``controller.start`` (see :class:`ForwardModelConfig`)."""


class ConfigError(ValueError):
    """A configuration field has a value that is not allowed (see :func:`fail`).

    Examples:
      >>> try:
      ...     LoopConfig(seeds=0)
      ... except ConfigError as error:
      ...     print(error)
      loop.seeds=0 is not allowed: a positive integer
    """


def fail(field: str, value: Any, allowed: str) -> None:
    """Raise the library's error for a bad input (config, CLI, sweeps, environments).

    Args:
      field: the input's name as the user wrote it (``loop.seeds``, ``--out``).
      value: the value given.
      allowed: what is allowed, in words.

    Raises:
      ConfigError: ``"{field}={value!r} is not allowed: {allowed}"``.

    Examples:
      >>> fail("loop.seeds", 0, "a positive integer")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: loop.seeds=0 is not allowed: a positive integer
    """
    raise ConfigError(f"{field}={value!r} is not allowed: {allowed}")


def _positive_int(field: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        fail(field, value, "a positive integer")


def _nonnegative_int(field: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        fail(field, value, "an integer >= 0")


def _positive_float(field: str, value: Any) -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        fail(field, value, "a finite number > 0")


def _nonnegative_float(field: str, value: Any) -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        fail(field, value, "a finite number >= 0")


def _layer_sizes(field: str, value: Any) -> None:
    if (
        not isinstance(value, tuple)
        or len(value) == 0
        or any(isinstance(v, bool) or not isinstance(v, int) or v <= 0 for v in value)
    ):
        fail(field, value, "a non-empty tuple of positive integers, e.g. (400, 400, 400)")


def _loss_weights(field: str, value: Any) -> Any:
    """None or the ``(weight, (index, ...))`` groups as tuples of float and int."""
    if value is None:
        return None
    allowed = (
        "None (the task's default) or a non-empty tuple of (weight, (index, ...)) groups: "
        "weight a finite number >= 0, indices distinct integers >= 0"
    )
    if not isinstance(value, tuple | list) or len(value) == 0:
        fail(field, value, allowed)
    groups = []
    for group in value:
        if not isinstance(group, tuple | list) or len(group) != 2:
            fail(field, value, allowed)
        weight, index = group
        if (
            isinstance(weight, bool)
            or not isinstance(weight, int | float)
            or not math.isfinite(weight)
            or weight < 0
        ):
            fail(field, value, allowed)
        if (
            not isinstance(index, tuple | list)
            or len(index) == 0
            or any(isinstance(i, bool) or not isinstance(i, int) or i < 0 for i in index)
            or len(set(index)) != len(index)
        ):
            fail(field, value, allowed)
        groups.append((float(weight), tuple(int(i) for i in index)))
    return tuple(groups)


def check_duration(duration: float, control_dt: float) -> None:
    """Check ``duration`` is a whole number (>= 1) of periods: the path ends at its goal, at rest.

    Args:
      duration: seconds per reach.
      control_dt: control period (s).

    Raises:
      ConfigError: otherwise (relative tolerance 1e-6).

    Examples:
      >>> check_duration(0.015, 0.01)
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.duration=0.015 is not allowed: a whole multiple (>= 1) ...
    """
    ratio = duration / control_dt
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6 * max(ratio, 1.0):
        raise ConfigError(
            f"task.duration={duration!r} is not allowed: a whole multiple (>= 1) of the "
            f"control period {control_dt!r} s"
        )


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """The tracking task (:mod:`cfm_jax.tasks`): its references and the desired quantity ``s*``.

    Attributes:
      name: task name, one of :data:`TASKS`.
      duration: seconds of each reach (quintic, home to target); a multiple of ``control_dt``.
      control_dt: control period (s), a multiple of the MJCF timestep; None: the timestep.
      targets: reaching targets, joint positions ``(nq,)`` (``inverse_dynamics``) or site
        positions ``(x, y, z)`` in m (``opspace``); None: the robot's 5 default targets.
      home: start pose ``(nq,)``; None: the MJCF keyframe ``home``, else ``qpos0``.
      kp: proportional gain (1/s^2) in ``qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``
        (legged tasks: on the base); ``kp = kd = 0``: pure feed-forward.
      kd: derivative gain (1/s) of the same correction.
      joint_kp: legged tasks only: proportional gain (1/s^2) on the joints; None: ``kp``
        (``next_velocity``: 0). Left out, the task's default where ``desired`` is the task's
        default form (the walk: 1000 with ``next_velocity``), else None.
      joint_kd: legged tasks only: derivative gain (1/s) on the joints; None: ``kd``.
      site: ``opspace``: the end-effector site; None: the first of ``ee``, ``flange`` and
        ``attachment_site``.
      motions: legged tasks only: walk durations (s) or jump foot clearances (m), one reference
        each; None: the paper's 5 test references (:mod:`cfm_jax.tasks.locomotion`).
      motion_family: legged tasks only: ``test`` (default; the test references' gait) or
        ``selection``, the gait of :data:`cfm_jax.tasks.locomotion.SELECTION_MOTIONS`, on which
        hyperparameters are chosen: no window of its motions is one of a test motion.
      desired: how the legged tasks build ``s*``, one of :data:`DESIRED`: ``pd`` (default;
        the gains above) or ``next_velocity`` (the authors' code: ``v_ref(t+1) - v(t)``, plus
        ``control_dt joint_kp (q_ref - q)`` on the joints; needs ``kp = kd = 0``, ``joint_kd``
        None). The arm tasks take ``pd`` only.
      oracle: one of :data:`ORACLES`: ``period`` (``inverse_dynamics``'s default: exact over
        the held control period, :func:`cfm_jax.tasks.baselines.over_the_period`) or ``step``
        (the other tasks'; the one-step inverse, what runs recorded before the field used).

    Examples:
      >>> task = TaskConfig(duration=1.0, targets=((0.2, -0.3),))
      >>> task.targets, task.kp
      (((0.2, -0.3),), 100.0)
    """

    name: str = "inverse_dynamics"
    duration: float = TASK_DEFAULT
    control_dt: float | None = TASK_DEFAULT
    targets: tuple[tuple[float, ...], ...] | None = TASK_DEFAULT
    home: tuple[float, ...] | None = TASK_DEFAULT
    kp: float = TASK_DEFAULT
    kd: float = TASK_DEFAULT
    joint_kp: float | None = TASK_DEFAULT
    joint_kd: float | None = TASK_DEFAULT
    site: str | None = TASK_DEFAULT
    motions: tuple[float, ...] | None = TASK_DEFAULT
    motion_family: str = TASK_DEFAULT
    desired: str = TASK_DEFAULT
    oracle: str = TASK_DEFAULT

    def control_period(self, timestep: float) -> float:
        """Seconds between controller steps: ``control_dt``, else the physics ``timestep``.

        Examples:
          >>> TaskConfig().control_period(0.002), TaskConfig(control_dt=0.02).control_period(0.002)
          (0.01, 0.02)
        """
        return self.control_dt if self.control_dt is not None else timestep

    def feedback_frequency(self, control_dt: float) -> float:
        """Angular frequency (rad/s) of the joints' feedback in ``s*``: ``sqrt`` of their ``kp``,
        else their ``kd``, else ``1 / control_dt`` (for
        :meth:`cfm_jax.sim.robots.Robot.torque_scale`).

        Examples:
          >>> TaskConfig().feedback_frequency(0.01)  # kp 100
          10.0
          >>> TaskConfig(kp=0.0, kd=0.0).feedback_frequency(0.004)  # pure feed-forward
          250.0
        """
        kp = self.joint_kp if self.joint_kp is not None else self.kp
        kd = self.joint_kd if self.joint_kd is not None else self.kd
        if kp > 0:
            return math.sqrt(kp)
        if kd > 0:
            return float(kd)
        return 1.0 / control_dt

    def __post_init__(self):
        if not isinstance(self.name, str) or self.name not in TASKS:
            fail("task.name", self.name, f"one of {TASKS}")
        own_joint_kp = self.joint_kp is TASK_DEFAULT
        _resolve(self, self.name, "task")
        if own_joint_kp and self.desired != _task_default(self.name, "task", "desired"):
            # A task's joint_kp is its own s* form's: another form takes the generic gain.
            object.__setattr__(self, "joint_kp", GENERIC["task"]["joint_kp"])
        _positive_float("task.duration", self.duration)
        if self.control_dt is not None:
            _positive_float("task.control_dt", self.control_dt)
            check_duration(self.duration, self.control_dt)
        _nonnegative_float("task.kp", self.kp)
        _nonnegative_float("task.kd", self.kd)
        for field in ("joint_kp", "joint_kd"):
            if getattr(self, field) is not None:
                _nonnegative_float(f"task.{field}", getattr(self, field))
        if not isinstance(self.desired, str) or self.desired not in DESIRED:
            fail("task.desired", self.desired, f"one of {DESIRED}")
        if not isinstance(self.oracle, str) or self.oracle not in ORACLES:
            fail("task.oracle", self.oracle, f"one of {ORACLES}")
        if self.oracle == "period" and self.name != "inverse_dynamics":
            fail("task.oracle", self.oracle, f"'step' for task {self.name!r} (the period-exact "
                 "oracle is the joint-space task's, task.name='inverse_dynamics')")  # fmt: skip
        if not isinstance(self.motion_family, str) or self.motion_family not in MOTION_FAMILIES:
            fail("task.motion_family", self.motion_family, f"one of {MOTION_FAMILIES}")
        if self.name in TASK_CHECKS:
            TASK_CHECKS[self.name](self)
        if self.desired == "next_velocity":
            for field, allowed in (("kp", 0.0), ("kd", 0.0), ("joint_kd", None)):
                if getattr(self, field) != allowed:
                    fail(
                        f"task.{field}",
                        getattr(self, field),
                        f"{allowed!r} with task.desired='next_velocity' (its gains are fixed: "
                        "kp = 0 and kd = 1 / control_dt on the base and the joints, plus "
                        "task.joint_kp on the joints; for other gains set task.desired='pd')",
                    )
        if self.site is not None and (not isinstance(self.site, str) or not self.site):
            fail("task.site", self.site, "None or the name of a site of the robot's MJCF")
        if self.motions is not None:
            allowed = (
                "None, or a non-empty tuple of positive numbers: walk durations (s) for "
                "'walk', jump foot clearances (m) for 'jump'"
            )
            try:
                motions = tuple(float(x) for x in self.motions)
            except (TypeError, ValueError):
                fail("task.motions", self.motions, allowed)
            if not motions or not all(math.isfinite(x) and x > 0 for x in motions):
                fail("task.motions", self.motions, allowed)
            object.__setattr__(self, "motions", motions)
        if self.targets is not None:
            try:
                targets = tuple(tuple(float(x) for x in t) for t in self.targets)
            except (TypeError, ValueError):
                fail(
                    "task.targets",
                    self.targets,
                    "a non-empty tuple of joint-position tuples of numbers",
                )
            if len(targets) == 0 or len({len(t) for t in targets}) != 1:
                fail(
                    "task.targets",
                    self.targets,
                    "a non-empty tuple of joint-position tuples of equal length",
                )
            if not all(math.isfinite(x) for t in targets for x in t):
                fail("task.targets", self.targets, "finite joint positions")
            object.__setattr__(self, "targets", targets)
        if self.home is not None:
            try:
                home = tuple(float(x) for x in self.home)
            except (TypeError, ValueError):
                fail("task.home", self.home, "a tuple of joint positions (numbers)")
            if not all(math.isfinite(x) for x in home):
                fail("task.home", self.home, "finite joint positions")
            object.__setattr__(self, "home", home)


@dataclasses.dataclass(frozen=True)
class ForwardModelConfig:
    """Forward model ``f(s, tau) -> y``: a PETS-style probabilistic ensemble and its fits.

    Attributes:
      hidden: hidden layer widths (ReLU). Paper: ``(400, 400, 400)``.
      ensemble_size: number of ensemble members. Paper: 3.
      learning_rate: Adam learning rate.
      initial_steps: gradient steps on the babbling data before the first iteration.
      steps_per_iteration: gradient steps per iteration of Algorithm 1.
      batch_size: minibatch size (drawn uniformly from the data set, per member).
      min_log_variance: initial lower soft bound of the predicted log-variance; learned (PETS).
      max_log_variance: initial upper soft bound; learned; above ``min_log_variance``.
      start: how each refit starts, one of :data:`FIT_STARTS`: ``warm`` (default; parameters
        and Adam state carry on), ``warm_new_optimizer`` (new Adam each fit, the authors'
        code) or ``fresh`` (parameters re-initialised from the iteration's key, new Adam).
      kind: one of :data:`FORWARD_KINDS`: ``mlp`` (default; the paper's text) or
        ``rigid_body`` (the authors' Solo12 code: ``qdd = M(q)^-1 (S tau - h(q, qd)) +
        residual(s, tau)``, the ensemble the residual; :mod:`cfm_jax.learning.rigid_body`).
      options: the kind's own settings (:data:`FORWARD_OPTIONS`): its options object or a
        dict of its fields, checked by the kind; None: its defaults. ``rigid_body``:
        :class:`cfm_jax.learning.rigid_body.RigidBodyOptions` (``nominal``, ``mass_scale``);
        ``mlp``: none.

    Examples:
      >>> ForwardModelConfig(hidden=[64, 64]).hidden  # lists become tuples
      (64, 64)
    """

    hidden: tuple[int, ...] = (400, 400, 400)
    ensemble_size: int = 3
    learning_rate: float = 1e-3
    initial_steps: int = 1000
    steps_per_iteration: int = 200
    batch_size: int = 256
    min_log_variance: float = -10.0
    max_log_variance: float = 0.5
    start: str = "warm"
    kind: str = "mlp"
    options: Any = None

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden))
        _layer_sizes("forward.hidden", self.hidden)
        _positive_int("forward.ensemble_size", self.ensemble_size)
        _positive_float("forward.learning_rate", self.learning_rate)
        _nonnegative_int("forward.initial_steps", self.initial_steps)
        _nonnegative_int("forward.steps_per_iteration", self.steps_per_iteration)
        _positive_int("forward.batch_size", self.batch_size)
        for name in ("min_log_variance", "max_log_variance"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                fail(f"forward.{name}", value, "a finite number")
            if not math.isfinite(value):
                fail(f"forward.{name}", value, "a finite number")
        if self.min_log_variance >= self.max_log_variance:
            fail(
                "forward.min_log_variance",
                self.min_log_variance,
                f"a number below forward.max_log_variance={self.max_log_variance}",
            )
        if self.start not in FIT_STARTS:
            fail("forward.start", self.start, f"one of {FIT_STARTS}")
        if self.kind not in FORWARD_KINDS:
            fail("forward.kind", self.kind, f"one of {FORWARD_KINDS}")
        object.__setattr__(self, "options", _kind_options(self.kind, self.options))


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """Controller (inverse model) ``g(s, s*) -> tau``, outputs squashed into the torque limits.

    Attributes:
      hidden: hidden layer widths (ReLU). Paper: ``(300, 200, 100)``.
      learning_rate: Adam learning rate.
      initial_steps: gradient steps before the first iteration (after f's initial fit).
      steps_per_iteration: gradient steps per iteration of Algorithm 1.
      batch_size: minibatch size (rows drawn uniformly with replacement).
      goal: the goal input in training (at run time always ``s*``), one of
        :data:`CONTROLLER_GOALS`: ``desired`` (default; the paper's eq. 4) or ``observed``
        (the authors' code: the observed next state in ``s*``'s coordinates; ``supervised``
        always uses it).
      loss_form: one of :data:`LOSS_FORMS`: ``norm`` (default; per-sample norms of weighted
        coordinate groups, the authors' code, :func:`cfm_jax.learning.losses.grouped`) or
        ``squared`` (sums of squares, the paper's text).
      loss_weights: ``norm`` only: groups ``((weight, (index, ...)), ...)`` of the forward
        model's output ``y``; None: the task's ``loss_weights()``.
      start: how each refit starts, one of :data:`FIT_STARTS` (as ``forward.start``).
      full_batch: True: each step every filled row of the data set (the authors' code;
        ``batch_size`` unused); False: minibatches.

    Examples:
      >>> ControllerConfig(hidden=(32,), initial_steps=50).steps_per_iteration
      200
    """

    hidden: tuple[int, ...] = (300, 200, 100)
    learning_rate: float = 1e-3
    initial_steps: int = 1000
    steps_per_iteration: int = 200
    batch_size: int = 256
    goal: str = "desired"
    loss_form: str = "norm"
    loss_weights: tuple | None = None
    start: str = "warm"
    full_batch: bool = False

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden))
        _layer_sizes("controller.hidden", self.hidden)
        _positive_float("controller.learning_rate", self.learning_rate)
        _nonnegative_int("controller.initial_steps", self.initial_steps)
        _nonnegative_int("controller.steps_per_iteration", self.steps_per_iteration)
        _positive_int("controller.batch_size", self.batch_size)
        if self.goal not in CONTROLLER_GOALS:
            fail("controller.goal", self.goal, f"one of {CONTROLLER_GOALS}")
        if self.loss_form not in LOSS_FORMS:
            fail("controller.loss_form", self.loss_form, f"one of {LOSS_FORMS}")
        weights = _loss_weights("controller.loss_weights", self.loss_weights)
        if weights is not None and self.loss_form != "norm":
            fail(
                "controller.loss_weights",
                self.loss_weights,
                'None unless controller.loss_form="norm" (the squared form weights every '
                "coordinate alike)",
            )
        object.__setattr__(self, "loss_weights", weights)
        if self.start not in FIT_STARTS:
            fail("controller.start", self.start, f"one of {FIT_STARTS}")
        if not isinstance(self.full_batch, bool):
            fail("controller.full_batch", self.full_batch, "True or False")


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Algorithm 1: motor babbling, then iterations of rollout / refit f / refit g.

    Attributes:
      iterations: iterations of Algorithm 1 (default 4, for every task: the CLI's and
        Python's default alike; the studies give theirs).
      seeds: number of independent runs (seeds ``Config.seed + k``), a ``vmap`` axis.
      babbling: the initial data, one of :data:`BABBLING`, each with torque noise:
        ``reaching`` (default; PD feedback reaching random poses within the joint limits),
        ``home`` (holding the start pose), ``reference_pd`` (PD on the test references) or
        ``oracle`` (the oracle on them); the last two only to study their effect.
      babbling_rollouts: babbling rollouts per target (each ``targets x steps`` transitions).
      babbling_noise: std of the babbling torque noise, a fraction of each joint's torque scale.
      torque_scale: scale of the babbling noise, f's torque input and g's output, one of
        :data:`TORQUE_SCALES`: ``auto`` (default; :func:`cfm_jax.learning.algorithm.scale_kind`),
        ``coupled`` (alike accelerations at home, with the joints' coupling), ``pose`` (that at
        each state's own pose, through MJX's ``M(q)``; the babbling noise stays ``coupled``'s),
        ``inertia`` (at home, each joint alone) or ``limit`` (the limits).
      babbling_gains: the babbling's joint PD gains, one of :data:`BABBLING_GAINS`:
        ``lightest`` (default; by each joint's lightest inertia over the poses it may visit,
        or its damping where that outweighs it; stable everywhere) or ``baseline`` (the
        PD-only baseline's).
      normaliser: both networks' scaling, one of :data:`NORMALISERS`: ``babbling`` (default;
        the initial data's statistics), ``data`` (the data set's, before every refit) or
        ``robot`` (fixed, from the MJCF and the task: :mod:`cfm_jax.tasks.scales`).
      restart_on_terminal: the data of each iteration from a rollout that starts again from
        the reference after each terminal step (a legged robot's fall), so that a controller
        that falls early still collects data of the whole motion; the metrics stay those of
        the rollout without restarts (default False: the data end at the first fall).
      checkpoint_every: checkpoint every this many iterations (and after the initial fit and
        the last iteration) when ``train`` has an output directory; 0: none.
      checkpoint_keep: number of most recent checkpoints kept.

    Examples:
      >>> LoopConfig(iterations=3, seeds=2).babbling_rollouts
      2
    """

    iterations: int = 4
    seeds: int = 1
    babbling: str = "reaching"
    babbling_rollouts: int = 2
    babbling_noise: float = 0.1
    torque_scale: str = "auto"
    babbling_gains: str = "lightest"
    normaliser: str = "babbling"
    restart_on_terminal: bool = False
    checkpoint_every: int = 1
    checkpoint_keep: int = 3

    def __post_init__(self):
        _nonnegative_int("loop.iterations", self.iterations)
        _positive_int("loop.seeds", self.seeds)
        if self.babbling not in BABBLING:
            fail("loop.babbling", self.babbling, f"one of {BABBLING}")
        _positive_int("loop.babbling_rollouts", self.babbling_rollouts)
        _nonnegative_float("loop.babbling_noise", self.babbling_noise)
        if not isinstance(self.torque_scale, str) or self.torque_scale not in TORQUE_SCALES:
            fail("loop.torque_scale", self.torque_scale, f"one of {TORQUE_SCALES}")
        if not isinstance(self.babbling_gains, str) or self.babbling_gains not in BABBLING_GAINS:
            fail("loop.babbling_gains", self.babbling_gains, f"one of {BABBLING_GAINS}")
        if not isinstance(self.normaliser, str) or self.normaliser not in NORMALISERS:
            fail("loop.normaliser", self.normaliser, f"one of {NORMALISERS}")
        if not isinstance(self.restart_on_terminal, bool):
            fail("loop.restart_on_terminal", self.restart_on_terminal, "True or False")
        _nonnegative_int("loop.checkpoint_every", self.checkpoint_every)
        _positive_int("loop.checkpoint_keep", self.checkpoint_keep)


@dataclasses.dataclass(frozen=True)
class Config:
    """A whole experiment: robot, task, both models, the controller loss and the loop.

    Attributes:
      robot: a registered robot name (``iiwa14``, ``two_link_arm``, ``solo12``) or an MJCF
        path (:func:`cfm_jax.sim.robots.load`).
      loss: the controller loss, one of :data:`CONTROLLER_LOSSES`.
      seed: base seed; run ``k`` of ``loop.seeds`` uses ``seed + k``.
      simulator: physics of the rollouts, one of :data:`SIMULATORS`: ``native`` (MuJoCo C in
        a host callback; exact, fast on CPU) or ``mjx`` (MuJoCo MJX, on the device).
      task: a :class:`TaskConfig`.
      forward: a :class:`ForwardModelConfig`.
      controller: a :class:`ControllerConfig`.
      loop: a :class:`LoopConfig`.
      robot_actuators: one of :data:`ROBOT_ACTUATORS`: ``strict`` (default; torque motors
        only) or ``torque`` (each joint servo becomes a torque motor at load time,
        :func:`cfm_jax.sim.robots.convert`).
      robot_torque_limit: with ``robot_actuators="torque"``, the limit (N m or N) of servos
        whose file gives none: None (an error), one number, or one per hinge/slide joint.

    Examples:
      >>> config = Config(robot="two_link_arm", loss="task", loop=LoopConfig(seeds=3))
      >>> config.loss, config.loop.seeds, config.forward.hidden
      ('task', 3, (400, 400, 400))
    """

    robot: str = TASK_DEFAULT
    loss: str = "joint"
    seed: int = 0
    simulator: str = "native"
    task: TaskConfig = dataclasses.field(default_factory=TaskConfig)
    forward: ForwardModelConfig = TASK_DEFAULT
    controller: ControllerConfig = TASK_DEFAULT
    loop: LoopConfig = TASK_DEFAULT
    robot_actuators: str = "strict"
    robot_torque_limit: tuple[float, ...] | None = None

    def __post_init__(self):
        if not isinstance(self.task, TaskConfig):
            fail("task", self.task, "a TaskConfig")
        _resolve(self, self.task.name, None)
        if self.robot_actuators not in ROBOT_ACTUATORS:
            fail("robot_actuators", self.robot_actuators, f"one of {ROBOT_ACTUATORS}")
        limit = self.robot_torque_limit
        if isinstance(limit, int | float) and not isinstance(limit, bool):
            limit = (float(limit),)
        if isinstance(limit, list):
            limit = tuple(limit)
        if limit is not None and (
            not isinstance(limit, tuple)
            or not limit
            or any(
                isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
                or v <= 0
                for v in limit
            )
        ):  # fmt: skip
            fail(
                "robot_torque_limit",
                self.robot_torque_limit,
                "None, a finite number > 0 (all joints) or a tuple of them (one per joint)",
            )
        if limit is not None:
            limit = tuple(float(v) for v in limit)
        object.__setattr__(self, "robot_torque_limit", limit)
        if not isinstance(self.robot, str) or not self.robot:
            fail("robot", self.robot, "a registered robot name or a path to an MJCF file")
        if not (os.path.sep in self.robot or self.robot.endswith(".xml")):
            # A name (not a path, which is read lazily): one of the shipped robots.
            if self.robot not in _shipped.registered():
                fail(
                    "robot",
                    self.robot,
                    f"a registered robot name {_shipped.registered()} or a path to an MJCF "
                    "file (containing a path separator or ending in .xml)",
                )
        if self.loss not in CONTROLLER_LOSSES:
            allowed = (
                f"one of {CONTROLLER_LOSSES} (a loss of your own: cfm_jax.learning.losses.register "
                "it before the config is made; on the command line, cfm-jax --import MODULE "
                "train ..., MODULE registering it)"
            )
            if isinstance(self.loss, str) and "," in self.loss:
                allowed += (
                    " (a config holds one loss: the config.json of a several-loss run lists "
                    "them, each loss's own is OUT/<loss>/config.json; cfm-jax train --config "
                    "takes the list)"
                )
            fail("loss", self.loss, allowed)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            fail("seed", self.seed, "an integer >= 0")
        if self.simulator not in SIMULATORS:
            fail("simulator", self.simulator, f"one of {SIMULATORS}")
        for name, cls in (
            ("task", TaskConfig),
            ("forward", ForwardModelConfig),
            ("controller", ControllerConfig),
            ("loop", LoopConfig),
        ):
            if not isinstance(getattr(self, name), cls):
                fail(name, getattr(self, name), f"a {cls.__name__}")

    def replace(self, **changes) -> Config:
        """A copy with top-level fields replaced (validated again).

        Args:
          **changes: new values of top-level fields (``robot``, ``loss``, ``task``, ...).

        Examples:
          >>> Config().replace(loss="distal").loss
          'distal'
        """
        return dataclasses.replace(self, **changes)


def for_task(task: str, **changes) -> Config:
    """The default :class:`Config` of ``task`` (:data:`TASK_DEFAULTS`; the CLI's ``--task``),
    top-level ``changes`` replaced: ``Config(task=TaskConfig(name=task)).replace(**changes)``.

    Args:
      task: one of :data:`TASKS`.
      changes: top-level fields to replace (``robot``, ``loss``, ``loop``, ...).

    Raises:
      ConfigError: an unknown task or a bad value in ``changes``.

    Examples:
      >>> walk = for_task("walk")
      >>> walk.robot, walk.task.control_dt, walk.task.desired, walk.forward.kind
      ('solo12', 0.004, 'next_velocity', 'rigid_body')
    """
    if task not in TASKS:
        fail("task.name", task, f"one of {TASKS}")
    return Config(task=TaskConfig(name=task)).replace(**changes)


GENERIC: dict[str, dict[str, Any]] = {
    "config": {
        "robot": "iiwa14",
        "forward": ForwardModelConfig,
        "controller": ControllerConfig,
        "loop": LoopConfig,
    },
    "task": {
        "duration": 2.0,
        "control_dt": 0.01,
        "targets": None,
        "home": None,
        "kp": 100.0,
        "kd": 20.0,
        "joint_kp": None,
        "joint_kd": None,
        "site": None,
        "motions": None,
        "motion_family": "test",
        "desired": "pd",
        "oracle": "step",
    },
}
"""Generic value of each field left at :data:`TASK_DEFAULT` by section (``config``: top
level; a class: its defaults), where a task's ``default_config`` does not state one."""


SECTIONS = {"task": TaskConfig, "forward": ForwardModelConfig, "controller": ControllerConfig,
            "loop": LoopConfig}  # fmt: skip
"""The sections of a :class:`Config`, by field name."""


def _field_names(cls) -> set[str]:
    return {field.name for field in dataclasses.fields(cls)}


def _naming_the_section(cls) -> None:
    """Give ``cls``'s constructor an error that says where a misplaced field belongs:
    ``Config(iterations=2)`` names ``Config(loop=LoopConfig(iterations=...))``."""
    generated = cls.__init__
    own = _field_names(cls)

    @functools.wraps(generated)
    def __init__(self, *args, **kwargs):
        unknown = [name for name in kwargs if name not in own]
        if unknown:
            name = unknown[0]
            homes = [(key, section) for key, section in SECTIONS.items()
                     if section is not cls and name in _field_names(section)]  # fmt: skip
            if name in _field_names(Config) and cls is not Config:
                hint = f"it is a field of Config: Config({name}=...)"
            elif homes:
                key, section = homes[0]
                hint = (f"it is a field of {section.__name__}: "
                        f"Config({key}={section.__name__}({name}=...))")  # fmt: skip
            else:
                hint = f"the fields are {sorted(own)}"
            raise TypeError(f"{cls.__name__}() got an unexpected keyword argument {name!r}: "
                            f"{hint}")  # fmt: skip
        generated(self, *args, **kwargs)

    cls.__init__ = __init__


for _cls in (Config, *SECTIONS.values()):
    _naming_the_section(_cls)


def to_dict(config: Config) -> dict:
    """Plain nested dict (JSON-serialisable) of a :class:`Config`.

    Args:
      config: the config.

    Examples:
      >>> to_dict(Config())["task"]["kp"]
      100.0
    """
    return dataclasses.asdict(config)


DERIVED = ("robot_conversion",)
"""Keys a run's ``config.json`` may hold beside the fields; :func:`from_dict` ignores them."""


def from_dict(data: dict) -> Config:
    """Inverse of :func:`to_dict`; lists are accepted for tuples, :data:`DERIVED` keys ignored.

    Missing fields take their defaults, except in configs written before the field existed:
    ``loop.babbling`` then takes :data:`BABBLING_BEFORE`'s, ``task.desired`` ``"pd"`` and
    ``task.oracle`` ``"step"`` (what ran).

    Args:
      data: a dict as written by :func:`to_dict` (a run's ``config.json``).

    Raises:
      ConfigError: an unknown field or a value that is not allowed.

    Examples:
      >>> config = Config(loss="task", loop=LoopConfig(seeds=2))
      >>> from_dict(to_dict(config)) == config
      True
    """
    sections = {
        "task": TaskConfig,
        "forward": ForwardModelConfig,
        "controller": ControllerConfig,
        "loop": LoopConfig,
    }
    top_fields = {f.name for f in dataclasses.fields(Config)}
    if not isinstance(data, dict):
        fail("config", data, "a JSON object of the fields of Config (as config.json)")
    data = {k: v for k, v in data.items() if k not in DERIVED}
    unknown = set(data) - top_fields
    if unknown:
        fail("config", sorted(unknown), f"known top-level fields are {sorted(top_fields)}")
    kwargs = {}
    for key, value in data.items():
        if key in sections:
            cls = sections[key]
            fields = {f.name for f in dataclasses.fields(cls)}
            if not isinstance(value, dict):
                fail(key, value, f"an object of the fields {sorted(fields)}")
            if key == "forward":
                value = upgrade_forward(value)
            bad = set(value) - fields
            if bad:
                fail(key, sorted(bad), f"known fields of {key} are {sorted(fields)}")
            value = dict(value)
            if key == "task" and value.get("targets") is not None:
                value["targets"] = tuple(tuple(t) for t in value["targets"])
            for tuple_field in ("hidden", "home", "motions"):
                if isinstance(value.get(tuple_field), list):
                    value[tuple_field] = tuple(value[tuple_field])
            task = data.get("task", {}).get("name", TaskConfig.name)
            if key == "loop" and "babbling" not in value and task in BABBLING_BEFORE:
                # Written before loop.babbling existed: it babbled as BABBLING_BEFORE says.
                value["babbling"] = BABBLING_BEFORE[task]
            if key == "task" and "desired" not in value:
                # Written before task.desired existed: every task's s* was the PD form then
                # (today a task's default may differ: the walk's is next_velocity).
                value["desired"] = "pd"
            if key == "task" and "oracle" not in value:
                value["oracle"] = "step"  # written before task.oracle: the one-step oracle ran
            kwargs[key] = cls(**value)
        else:
            kwargs[key] = value
    return Config(**kwargs)


def upgrade_forward(forward: dict) -> dict:
    """A ``forward`` section of a ``config.json`` in today's fields: written before
    ``forward.options``, it had the ``rigid_body`` kind's ``nominal`` and
    ``nominal_mass_scale`` beside the shared fields.

    Args:
      forward: the section as read.

    Examples:
      >>> upgrade_forward({"kind": "rigid_body", "nominal": None, "nominal_mass_scale": 1.2})
      {'kind': 'rigid_body', 'options': {'nominal': None, 'mass_scale': 1.2}}
      >>> upgrade_forward({"kind": "mlp", "nominal": None, "nominal_mass_scale": 1.0})
      {'kind': 'mlp', 'options': None}
    """
    if "nominal" not in forward and "nominal_mass_scale" not in forward:
        return forward
    forward = dict(forward)
    options = {"nominal": forward.pop("nominal", None)}
    options["mass_scale"] = forward.pop("nominal_mass_scale", 1.0)
    if forward.get("kind", "mlp") != "rigid_body" and options == {
        "nominal": None,
        "mass_scale": 1.0,
    }:
        options = None  # the other kinds' defaults: they had no options
    forward.setdefault("options", options)
    return forward


RUNTIME_FIELDS = (
    "seed",
    "task.kp",
    "task.kd",
    "task.joint_kp",
    "task.joint_kd",
    "task.targets",
    "task.home",
    "task.desired",
    "forward.learning_rate",
    "controller.learning_rate",
    "forward.min_log_variance",
    "forward.max_log_variance",
    "loop.babbling",
    "loop.babbling_noise",
    "loop.babbling_gains",
    "loop.checkpoint_every",
    "loop.checkpoint_keep",
)
"""Fields that do not change the compiled program (checkpointing and seed are not part of it,
the others are its arguments, :class:`cfm_jax.learning.algorithm.Knobs`): configs that differ only
in these and ``loss`` share a :class:`cfm_jax.learning.algorithm.Experiment` (see :func:`structure`,
docs/how-to/sweep.md)."""


def structure(config: Config) -> dict:
    """The part of ``config`` that shapes its compiled program (equal structures share an
    :class:`cfm_jax.learning.algorithm.Experiment`): :func:`to_dict` without ``loss`` and
    :data:`RUNTIME_FIELDS`, with the number of ``task.targets`` (None: the default set) and
    the task's :data:`TASK_STRUCTURAL` fields.

    Args:
      config: a :class:`Config`.

    Examples:
      >>> a = Config(seed=1, task=TaskConfig(kp=50.0, targets=((0.1,) * 7, (0.2,) * 7)))
      >>> b = Config(loss="task", task=TaskConfig(targets=((0.3,) * 7, (0.4,) * 7)))
      >>> structure(a) == structure(b), structure(a)["task"]["targets"]
      (True, 2)
      >>> structure(a) == structure(Config(task=TaskConfig(duration=1.0)))
      False
    """
    tree = to_dict(config)
    del tree["loss"]
    for path in RUNTIME_FIELDS:
        *parents, name = path.split(".")
        node = tree
        for parent in parents:
            node = node[parent]
        del node[name]
    task = config.task
    tree["task"]["targets"] = None if task.targets is None else len(task.targets)
    for field in TASK_STRUCTURAL.get(task.name, ()):
        tree["task"][field] = getattr(task, field)
    return tree


def seeds_of(config: Config) -> Sequence[int]:
    """The seeds of ``config``'s runs: ``seed, seed + 1, ..., seed + loop.seeds - 1``.

    Args:
      config: a :class:`Config`.

    Examples:
      >>> seeds_of(Config(seed=5, loop=LoopConfig(seeds=3)))
      (5, 6, 7)
    """
    return tuple(range(config.seed, config.seed + config.loop.seeds))


def differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two config dicts, with both values, sorted.

    Args:
      old: a config dict (:func:`to_dict`), for example a run's.
      new: another one.
      prefix: prefix of the dotted names (used by the recursion).

    Examples:
      >>> differences({"loss": "task", "loop": {"seeds": 1}},
      ...             {"loss": "task", "loop": {"seeds": 3}})
      ['loop.seeds (1 in the run, 3 now)']
    """
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += differences(a, b, name + ".")
        elif a != b:
            out.append(f"{name} ({a!r} in the run, {b!r} now)")
    return out
