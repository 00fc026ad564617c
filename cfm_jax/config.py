"""Frozen, validated configuration dataclasses.

Every field has a comment; every constructor checks its fields and raises
:class:`ConfigError` naming the field, the bad value and what is allowed. Configs are plain
data: they round-trip through JSON (:func:`to_dict` / :func:`from_dict`).

Examples:
  >>> cfg = Config(loop=LoopConfig(iterations=2, seeds=1))
  >>> cfg.loop.iterations
  2
  >>> cfg.replace(loss="task").loss
  'task'
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

from cfm_jax import _shipped

TASKS = ("inverse_dynamics", "opspace", "walk", "jump")
"""Tasks available for ``Config.task.name``: the library's four, then those added by
:func:`cfm_jax.tasks.register` (:func:`add_task_name`)."""

_BUILT_IN_TASKS = TASKS


def add_task_name(
    name: str,
    default_config: Callable[[], Config] | None = None,
    check: Callable[[TaskConfig], None] | None = None,
    structural: tuple[str, ...] = (),
) -> None:
    """Let ``Config.task.name`` take ``name``, with the task's own defaults
    (:func:`cfm_jax.tasks.register` calls this; the config knows the names and where their
    defaults come from, the task modules know what they mean).

    Args:
      name: the new task's name; a name already in :data:`TASKS` keeps its place.
      default_config: ``default_config() -> Config``, the task's defaults (its module's
        ``default_config``): what every field left at :data:`TASK_DEFAULT` takes in a
        :class:`Config` or :class:`TaskConfig` naming this task. Inside it, such fields take
        the generic values of :data:`GENERIC` (so it states only what differs). None: the
        generic values.
      check: ``check(task_config)``, what the task refuses of a :class:`TaskConfig` of its
        name (raises :class:`ConfigError`, :func:`fail`), run after the fields' own checks
        of type and range; None: nothing more.
      structural: the ``task.*`` fields of :data:`RUNTIME_FIELDS` whose values this task
        builds into its compiled program (``opspace``: ``home``, its oracle's null-space
        posture): :func:`structure` keeps them.

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
"""The default of every field whose value depends on the task (the top-level ``robot``,
``forward``, ``controller`` and ``loop``, and every field of :class:`TaskConfig` but its
``name``): a field left at it takes the value of the task's own ``default_config()``
(:data:`TASK_DEFAULTS`), so ``Config(robot="solo12", task=TaskConfig(name="walk"))``
is the walk's experiment, the same as :func:`for_task` and the CLI's ``--task walk``. A
section given explicitly is taken as given (its own fields' defaults are the generic ones):
to change one field of a task's section, start from :func:`for_task` and replace it."""

TASK_DEFAULTS: dict[str, Callable[[], Config]] = {}
"""The ``default_config`` of each registered task (:func:`add_task_name`, called by
:func:`cfm_jax.tasks.register`; importing :mod:`cfm_jax` registers the library's four)."""

TASK_CHECKS: dict[str, Callable[[TaskConfig], None]] = {}
"""What each registered task refuses of a :class:`TaskConfig` of its name (:func:`add_task_name`):
the fields only other tasks take (the arms refuse the legged tasks' joint gains and
motions, for example)."""

TASK_STRUCTURAL: dict[str, tuple[str, ...]] = {}
"""The runtime ``task.*`` fields each registered task builds into its program
(:func:`add_task_name`; :func:`structure` keeps them)."""

_DEFAULTS_OF: dict[str, Config] = {}  # each task's default_config(), made once
_BUILDING: set[str] = set()  # the tasks whose default_config() runs now


def _task_default(name: str, section: str | None, field: str) -> Any:
    """The value of a field left at :data:`TASK_DEFAULT` in a config of task ``name``:
    the task's ``default_config()``'s (``section`` None: a top-level field), or, while that
    default config itself is made and for a task registered without one, :data:`GENERIC`'s."""
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
    """Replace every field of the frozen dataclass ``obj`` left at :data:`TASK_DEFAULT` by
    task ``name``'s value (:func:`_task_default`)."""
    for field in dataclasses.fields(obj):
        if getattr(obj, field.name) is TASK_DEFAULT:
            object.__setattr__(obj, field.name, _task_default(name, section, field.name))


FORWARD_KINDS = ("mlp", "rigid_body")
"""Kinds of forward model for ``Config.forward.kind`` (see :mod:`cfm_jax.forward_models`):
``mlp``, the PETS ensemble of the paper's text (the default), and ``rigid_body``, the
physics-structured model of the authors' Solo12 code (:mod:`cfm_jax.rigid_body`)."""


def add_forward_kind(name: str) -> None:
    """Allow ``name`` as ``forward.kind`` (called by
    :func:`cfm_jax.forward_models.register`).

    Args:
      name: the new kind's name; a name already in :data:`FORWARD_KINDS` changes nothing.

    Examples:
      >>> add_forward_kind("mlp"); FORWARD_KINDS
      ('mlp', 'rigid_body')
    """
    global FORWARD_KINDS
    if name not in FORWARD_KINDS:
        FORWARD_KINDS = FORWARD_KINDS + (name,)


SIMULATORS = ("native", "mjx")
"""Physics back ends for ``Config.simulator`` (see :mod:`cfm_jax.rollout`)."""


def check_simulator(simulator: str) -> None:
    """Raise :class:`ConfigError` unless ``simulator`` is one of :data:`SIMULATORS` (the
    check of every function that takes a ``simulator`` argument).

    Args:
      simulator: the name to check.

    Raises:
      ConfigError: naming the value and the allowed ones.

    Examples:
      >>> check_simulator("mjx")
      >>> check_simulator("mujoco")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: simulator='mujoco' is not allowed: one of ('native', 'mjx')
    """
    if simulator not in SIMULATORS:
        raise ConfigError(f"simulator={simulator!r} is not allowed: one of {SIMULATORS}")


PAPER_LOSSES = ("joint", "task", "distal", "supervised")
"""The paper's four controller losses, in the order results are reported (``"all"`` in
sweeps and the CLI); the functions are in :mod:`cfm_jax.losses`."""

CONTROLLER_LOSSES = PAPER_LOSSES + ("distal_literal",)
"""Every controller loss name (``Config.loss``): :data:`PAPER_LOSSES` and ``distal_literal``
(the distal teacher written literally as a loss over the whole data set,
:func:`cfm_jax.losses.distal_literal`; for studies of it)."""

BABBLING_BEFORE = {
    "inverse_dynamics": "reference_pd",
    "opspace": "reference_pd",
    "walk": "oracle",
    "jump": "oracle",
}
"""How each task babbled before ``loop.babbling`` existed (what :func:`from_dict` reads
for a config that has a ``loop`` without it)."""

BABBLING = ("home", "reaching", "reference_pd", "oracle")
"""Strategies of the initial (motor-babbling) data for ``Config.loop.babbling``
(see :mod:`cfm_jax.babbling`). ``home`` and ``reaching`` know neither the test references
nor the reference controller; ``reference_pd`` and ``oracle`` use them and exist only to
study their effect."""


TORQUE_SCALES = ("inertia", "limit", "coupled")
"""How torques are scaled, for ``Config.loop.torque_scale``
(:meth:`cfm_jax.robots.Robot.torque_scale`, :meth:`cfm_jax.robots.Robot.coupled_torque_scale`).
``inertia`` scales joint ``j``'s torque by ``S_j = F_j + I_j min_k (tau_max_k - F_k) / I_k``
with ``I_j = hypot(M_jj(home), D_j / w)`` (``D`` damping, ``F`` dry friction, ``w`` the
task's feedback frequency, :meth:`TaskConfig.feedback_frequency`): the torque amplitude that
gives it, alone at the start pose, the acceleration amplitude at ``w`` that the least of the
joints' limits gives (without damping and friction: ``M_jj(home) min_k (tau_max_k /
M_kk(home))``, the same acceleration): the babbling noise is that fraction of ``S``, the
forward model takes ``tau / S`` and the controller puts out ``tau_max tanh(S u / tau_max)``.
``coupled`` (the inverse-dynamics task's default since issue 41; ``opspace`` keeps
``inertia``, :func:`for_task`) adds the joints' coupling: the matrix
``T = diag(S) + a (M(home) - diag(M_jj))``, ``a = min_k (tau_max_k - F_k) / I_k``, so that a
scaled torque moves every joint alike at home even where light links hang on heavy ones
(noise ``T n``, inputs ``T^-1 tau``, outputs ``tau_max tanh(T u / tau_max)``); on an arm
whose mass matrix is diagonal at home the two are the same. ``limit`` (the legged tasks'
default) scales every torque by its limit ``tau_max`` (noise, inputs, and ``tau_max
tanh(u)``). All three agree on a robot whose joints all reach the same acceleration at their
limits; on a published arm with light distal links the wrist's limit gives 100x the
acceleration of the shoulder's, and scaled by its limit the wrist's torques that the tracking
needs are 1e-4 of the controller's range and 1e-3 of the babbling noise. Why ``coupled`` is
the default: on the seven published arms of ``tests/robots`` (3 seeds, one H100) every loss
tracked below PD-only on every seed with it, against 21 of 28 (arm, loss) pairs with
``inertia`` (docs/how-to/own-robot.md)."""


BABBLING_GAINS = ("lightest", "baseline")
"""The torque gains of the babbling's joint PD feedback, for ``Config.loop.babbling_gains``
(:func:`cfm_jax.baselines.babbling_joint_gains`): ``lightest`` (default) ``kp``, ``kd``
times each joint's lightest effective inertia over the poses the babbling may visit,
stable wherever it goes; ``baseline`` the PD-only baseline's ``kp``, ``kd`` times
``diag M(home)`` (the babbling before issue 41), which coupled light links without armature
make unstable away from home. The legged tasks' feedback has the references' own gains
either way, and op-space's task-space gains."""


NORMALISERS = ("babbling", "data", "robot")
"""Input and output scaling of both networks for ``Config.loop.normaliser``
(:class:`cfm_jax.networks.Normaliser`): ``babbling`` (statistics of the initial data, fitted
once and frozen; today's default), ``data`` (statistics of the whole data set, recomputed
before every refit of both models) and ``robot`` (fixed physical scales from the MJCF and
the task, :mod:`cfm_jax.tasks.scales`)."""

ROBOT_ACTUATORS = ("strict", "torque")
"""How the robot's actuators are taken (``Config.robot_actuators``): ``strict`` (the
default; torque motors only) or ``torque`` (each servo on a joint replaced by a torque motor
at load time, :func:`cfm_jax.robots.convert`)."""

DESIRED = ("pd", "next_velocity")
"""How the legged tasks build ``s*`` (``Config.task.desired``): ``pd`` (the PD correction
with the gains ``task.kp``, ``task.kd``, ``task.joint_kp``, ``task.joint_kd``) or
``next_velocity`` (the authors' Solo12 code: the desired next velocity, ``kp = 0`` and
``kd = 1 / control_dt`` on every base and joint coordinate)."""
CONTROLLER_GOALS = ("desired", "observed")
"""What the controller is given as its goal while it is trained (``controller.goal``):
``desired`` feeds ``g(s, s*)`` (the paper's text, eq. 4; the default), ``observed`` feeds
``g(s, P s_a)``, the observed next state in the desired quantity's coordinates (the authors'
public Solo12 code). At run time ``g`` is always given ``s*``."""

LOSS_FORMS = ("squared", "norm")
"""Forms of the controller loss (``controller.loss_form``): ``squared`` (sums of squares,
the paper's text) or ``norm`` (per-sample Euclidean norms of weighted coordinate groups, the
authors' public Solo12 code, the default since the selection run; see
:func:`cfm_jax.losses.grouped`)."""

FIT_STARTS = ("warm", "warm_new_optimizer", "fresh")
"""How each refit of a network in an iteration starts (``forward.start``,
``controller.start``): ``warm`` (the default) continues from the parameters and the Adam
state of the previous fit; ``warm_new_optimizer`` keeps the parameters and re-creates Adam
(the authors' public Solo12 code); ``fresh`` re-initialises the parameters (from a key derived
from the iteration's key) and Adam."""


class ConfigError(ValueError):
    """A configuration field has a value that is not allowed.

    The message names the field (dotted for nested configs), the value and what is allowed.

    Examples:
      >>> try:
      ...     LoopConfig(seeds=0)
      ... except ConfigError as error:
      ...     print(error)
      loop.seeds=0 is not allowed: a positive integer
    """


def fail(field: str, value: Any, allowed: str) -> None:
    """Raise the library's error for a bad input: the field, the bad value and what is
    allowed, in the words every check of the library (config, CLI, sweeps, environments)
    uses.

    Args:
      field: the input's name as the user wrote it (``loop.seeds``, ``--out``).
      value: the value given.
      allowed: what is allowed, in words.

    Raises:
      ConfigError: ``"{field}={value!r} is not allowed: {allowed}"``.

    Examples:
      >>> try:
      ...     fail("loop.seeds", 0, "a positive integer")
      ... except ConfigError as error:
      ...     print(error)
      loop.seeds=0 is not allowed: a positive integer
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
    """``None`` or a non-empty tuple of ``(weight, (index, ...))`` groups (lists accepted),
    returned as tuples of float and int."""
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
    """``duration`` must be a whole number (>= 1) of control periods, so that the sampled
    path ends exactly at the goal with zero velocity.

    Args:
      duration: seconds per reach.
      control_dt: control period (s).

    Raises:
      ConfigError: ``duration / control_dt`` is not a whole number >= 1 (relative tolerance
        1e-6).

    Examples:
      >>> check_duration(2.0, 0.01)
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
    """The tracking task: reaching trajectories and desired accelerations.

    ``inverse_dynamics``: joint-space reaching, the controller gets a desired joint
    acceleration. ``opspace``: Cartesian reaching of an end-effector site, the controller
    gets a desired end-effector acceleration (see :mod:`cfm_jax.tasks`). ``walk`` and
    ``jump``: the Solo12's recorded references (see :mod:`cfm_jax.locomotion`).

    Attributes:
      name: task name, one of :data:`TASKS`.
      duration: duration of each reaching trajectory in seconds (home pose to target,
        quintic); a whole multiple of ``control_dt``.
      control_dt: control period in seconds; a multiple of the MJCF timestep (the torque is
        held for ``control_dt / timestep`` physics steps). None: the MJCF timestep.
      targets: reaching targets, one tuple per target: joint positions ``(nq,)``
        (``inverse_dynamics``) or end-effector positions ``(x, y, z)`` in metres
        (``opspace``); None: the robot's 5 default targets.
      home: start pose ``(nq,)``; None: the MJCF keyframe named ``home``, else ``qpos0``.
      kp: proportional gain (1/s^2) of the PD correction in the desired acceleration
        ``qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``; ``kp = kd = 0`` is pure
        feed-forward.
      kd: derivative gain (1/s) of the same PD correction. The legged tasks apply ``kp`` and
        ``kd`` to the base pose and ``joint_kp`` / ``joint_kd`` to the joints.
      joint_kp: legged tasks (``walk``, ``jump``): proportional gain (1/s^2) on the
        actuated joints in the desired acceleration; None: ``kp``. The arm tasks take
        ``kp`` for their joints and reject a value here.
      joint_kd: legged tasks: derivative gain (1/s) on the actuated joints; None: ``kd``.
      site: ``opspace``: the end-effector site of the MJCF; None: the site ``ee``, else
        ``flange``, else ``attachment_site`` (MuJoCo Menagerie's name).
      motions: legged tasks: the references to follow, walk durations (s) for ``walk`` or
        foot clearances (m) for ``jump``, one reference each
        (:func:`cfm_jax.locomotion.walk_reference`, :func:`~cfm_jax.locomotion.jump_reference`);
        None: the paper's 5 test references (:data:`cfm_jax.locomotion.WALK_DURATIONS`,
        :data:`~cfm_jax.locomotion.JUMP_HEIGHTS`). Other motions than the test ones are
        what a choice of defaults is made on (``experiments/select_defaults.py``). The arm
        tasks take ``targets`` and reject a value here.
      desired: how the legged tasks build ``s*``, one of :data:`DESIRED`: ``pd`` (default;
        the gains above) or ``next_velocity`` (the authors' Solo12 code: the desired next
        velocity ``s* = v_ref(t+1) - v(t)``, i.e. ``kp = 0``, ``kd = 1 / control_dt`` on
        the base and the joints; ``kp`` and ``kd`` must then be 0 and ``joint_kp``,
        ``joint_kd`` None). The arm tasks take ``pd`` only.

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
    desired: str = TASK_DEFAULT

    def control_period(self, timestep: float) -> float:
        """Seconds between controller steps: ``control_dt``, or ``timestep`` (the robot's
        physics timestep) where it is None.

        Examples:
          >>> TaskConfig().control_period(0.002), TaskConfig(control_dt=0.02).control_period(0.002)
          (0.01, 0.02)
        """
        return self.control_dt if self.control_dt is not None else timestep

    def feedback_frequency(self, control_dt: float) -> float:
        """The angular frequency (rad/s) of the joints' feedback in ``s*``: ``sqrt`` of the
        joints' ``kp`` (``joint_kp``, else ``kp``); where that is 0, the joints' ``kd`` (the
        rate of a first-order loop); where both are 0 (pure feed-forward), ``1 /
        control_dt``. The frequency at which :meth:`cfm_jax.robots.Robot.torque_scale`
        weighs damping against inertia.

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
        _resolve(self, self.name, "task")
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
        if self.name in TASK_CHECKS:
            TASK_CHECKS[self.name](self)
        if self.desired == "next_velocity":
            for field, allowed in (
                ("kp", 0.0),
                ("kd", 0.0),
                ("joint_kp", None),
                ("joint_kd", None),
            ):
                if getattr(self, field) != allowed:
                    fail(
                        f"task.{field}",
                        getattr(self, field),
                        f"{allowed!r} with task.desired='next_velocity' (its gains are fixed: "
                        "kp = 0 and kd = 1 / control_dt on the base and the joints; for PD "
                        "gains in s* set task.desired='pd')",
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
      initial_steps: gradient steps on the whole data set before the first iteration (after
        babbling).
      steps_per_iteration: gradient steps per iteration of Algorithm 1.
      batch_size: minibatch size (sampled uniformly from the data set, per member).
      min_log_variance: initial lower soft bound of the predicted log-variance (normalised
        units); learned, as in PETS.
      max_log_variance: initial upper soft bound; learned; above ``min_log_variance``.
      start: how each refit in an iteration starts, one of :data:`FIT_STARTS`: ``warm``
        (default; the arm tasks': the parameters and Adam state of the previous fit carry
        on), ``warm_new_optimizer`` (parameters kept, Adam re-created for each fit: the
        authors' public Solo12 code; the legged tasks' default, :func:`for_task`) or
        ``fresh`` (parameters re-initialised each iteration from a key derived from the
        iteration's key, Adam re-created).
      kind: one of :data:`FORWARD_KINDS`: ``"mlp"`` (default; the paper's text: the
        ensemble predicts the output from ``(s, tau)``) or ``"rigid_body"`` (the authors'
        Solo12 code: ``qdd = M(q)^-1 (S tau - h(q, qd)) + residual(s, tau)`` with ``M`` and
        ``h`` of a nominal MuJoCo model and the ensemble as the residual;
        :mod:`cfm_jax.rigid_body`), with every task: the physics fills the output entries
        that are an affine image of ``qacc`` (``opspace``: ``[qacc, J qacc + Jdot qd]``).
      nominal: ``rigid_body`` only: the MJCF file (a path or a registered robot name) of
        the nominal model ``M`` and ``h`` come from; None (default): the robot's own.
      nominal_mass_scale: ``rigid_body`` only: every body mass and inertia of the nominal
        model multiplied by this factor (> 0; default 1.0), to study model bias.

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
    nominal: str | None = None
    nominal_mass_scale: float = 1.0

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
        if self.nominal is not None and (not isinstance(self.nominal, str) or not self.nominal):
            fail("forward.nominal", self.nominal, "None or an MJCF path / robot name")
        _positive_float("forward.nominal_mass_scale", self.nominal_mass_scale)
        if self.kind != "rigid_body":
            for name, default in (("nominal", None), ("nominal_mass_scale", 1.0)):
                if getattr(self, name) != default:
                    fail(
                        f"forward.{name}",
                        getattr(self, name),
                        f"{default!r} unless forward.kind='rigid_body' (forward.kind="
                        f"{self.kind!r} has no nominal model)",
                    )


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """Controller (inverse model) ``g(s, s*) -> tau``, outputs squashed into the torque limits.

    Attributes:
      hidden: hidden layer widths (ReLU). Paper: ``(300, 200, 100)``.
      learning_rate: Adam learning rate.
      initial_steps: gradient steps before the first iteration (after the forward model's
        initial fit).
      steps_per_iteration: gradient steps per iteration of Algorithm 1.
      batch_size: minibatch size (rows drawn uniformly with replacement per step).
      goal: the controller's goal input while it is trained (at run time it is always
        ``s*``), one of
        :data:`CONTROLLER_GOALS`: ``desired`` (default, the paper's eq. 4:
        ``f(s, g(s, s*))``) or ``observed`` (the authors' public Solo12 code: ``g(s, P s_a)``,
        the observed next state in the desired quantity's coordinates; each loss keeps its
        targets; ``supervised`` feeds the observed goal either way).
      loss_form: one of :data:`LOSS_FORMS`: ``norm`` (default, chosen by the selection
        run on the arm: per-sample Euclidean norms of weighted coordinate groups, the
        authors' code; :func:`cfm_jax.losses.grouped`) or ``squared`` (sums of squares,
        every coordinate alike, the paper's text).
      loss_weights: the coordinate groups of the ``norm`` form, ``((weight, (index, ...)),
        ...)`` with indices into the forward model's output ``y``; None: the task's default
        (``task.loss_weights()``: the legged tasks the authors' groups with 10 on the base's
        vertical and angular velocity, the arm tasks one group of weight 1). Only with
        ``loss_form="norm"``.
      start: how each refit in an iteration starts, one of :data:`FIT_STARTS` (as
        ``forward.start``; default ``warm``, the legged tasks' ``warm_new_optimizer``).
      full_batch: False (default): each step a minibatch of ``batch_size`` rows; True: each
        step every filled row of the data set (the authors' code: one batch of the whole
        data set), a mean over the fixed-capacity buffer weighted by the filled-row mask
        (``batch_size`` is then not used).

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
      iterations: iterations of Algorithm 1 (each: roll out g on every target, add the data,
        refit f, refit g).
      seeds: number of independent runs (seeds ``Config.seed + k``), a ``vmap`` axis.
      babbling: the strategy of the initial data, one of :data:`BABBLING`
        (:mod:`cfm_jax.babbling`): ``reaching`` (default; the task's PD feedback tracking
        reaches from the start pose to random poses inside the joint limits, drawn from the
        seed), ``home`` (the same PD feedback holding the start pose; the legged tasks'
        default, :func:`for_task`), ``reference_pd`` (PD tracking of the test references) or
        ``oracle`` (the task's oracle on the test references); each plus Gaussian torque
        noise. The defaults were chosen by the selection run
        (``experiments/select_defaults.py``, docs/results/selection/).
      babbling_rollouts: motor-babbling rollouts per target (each as wide as one rollout of
        the task: ``targets x steps`` transitions).
      babbling_noise: standard deviation of the babbling torque noise, as a fraction of each
        joint's torque scale (``torque_scale``).
      torque_scale: how torques are scaled, one of :data:`TORQUE_SCALES`: ``coupled``
        (default, the inverse-dynamics task's; a matrix with the joints' inertia and their
        coupling at the start pose, so that a scaled torque gives every joint the same
        acceleration), ``inertia`` (its diagonal alone: each joint's own inertia; the
        op-space task's default, :func:`for_task`) or ``limit`` (the legged tasks' default,
        :func:`for_task`; by the torque limits): the babbling noise, the forward model's torque
        input and the controller's output range (:meth:`cfm_jax.robots.Robot.torque_scale`,
        :meth:`cfm_jax.robots.Robot.coupled_torque_scale`).
      babbling_gains: the torque gains of the babbling's joint PD feedback, one of
        :data:`BABBLING_GAINS`: ``lightest`` (default; sized for each joint's lightest
        effective inertia over the poses the babbling visits, stable wherever it goes) or
        ``baseline`` (the PD-only baseline's gains).
      normaliser: the input and output scaling of both networks, one of
        :data:`NORMALISERS`: ``babbling`` (default, the arm tasks'; statistics of the
        initial data, fitted once), ``data`` (the legged tasks' default, :func:`for_task`;
        statistics of the whole data set, recomputed before every refit of both models) or
        ``robot`` (fixed scales from the MJCF and the task:
        :mod:`cfm_jax.tasks.scales`).
      checkpoint_every: save a checkpoint every this many iterations (and after the initial
        fit and the last iteration) when ``train`` has an output directory; 0: none.
      checkpoint_keep: number of most recent checkpoints kept on disk.

    Examples:
      >>> LoopConfig(iterations=3, seeds=2).babbling_rollouts
      2
    """

    iterations: int = 10
    seeds: int = 1
    babbling: str = "reaching"
    babbling_rollouts: int = 2
    babbling_noise: float = 0.1
    torque_scale: str = "coupled"
    babbling_gains: str = "lightest"
    normaliser: str = "babbling"
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
        _nonnegative_int("loop.checkpoint_every", self.checkpoint_every)
        _positive_int("loop.checkpoint_keep", self.checkpoint_keep)


@dataclasses.dataclass(frozen=True)
class Config:
    """A whole experiment: robot, task, both models, the controller loss and the loop.

    Attributes:
      robot: a registered robot name (``"iiwa14"``, ``"two_link_arm"``, ``"solo12"``) or a
        path to an MJCF file (see :func:`cfm_jax.robots.load`).
      loss: the controller loss, one of ``CONTROLLER_LOSSES``: ``joint``, ``task``,
        ``distal``, ``supervised`` (the paper's four) and ``distal_literal`` (the distal
        teacher written literally).
      seed: base seed; run ``k`` of ``loop.seeds`` uses ``seed + k``.
      simulator: physics back end of the rollouts, one of :data:`SIMULATORS`: ``native``
        (MuJoCo's C engine through a host callback; exact, fast on CPU) or ``mjx`` (MuJoCo
        MJX in JAX, on the device).
      task: a :class:`TaskConfig`.
      forward: a :class:`ForwardModelConfig`.
      controller: a :class:`ControllerConfig`.
      loop: a :class:`LoopConfig`.
      robot_actuators: how the robot's actuators are taken, one of :data:`ROBOT_ACTUATORS`:
        ``strict`` (default; torque motors only, a servo is an error) or ``torque`` (each
        servo on a joint, as MuJoCo Menagerie's arms have, replaced by a torque motor on the
        same joint and gear at load time: :func:`cfm_jax.robots.convert`).
      robot_torque_limit: with ``robot_actuators="torque"``, the torque limit (N m or N) of
        servos whose file gives none (no ``forcerange``, no joint ``actuatorfrcrange``):
        None (default; such a servo is an error), one number for all joints, or one per
        hinge/slide joint in model order.

    Examples:
      >>> config = Config(robot="two_link_arm", loss="task", loop=LoopConfig(seeds=3))
      >>> config.loss, config.loop.seeds, config.forward.hidden
      ('task', 3, (400, 400, 400))
      >>> Config(loss="l1")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: loss='l1' is not allowed: one of ('joint', 'task', ...)
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
            allowed = f"one of {CONTROLLER_LOSSES}"
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

        Returns:
          A new :class:`Config`.

        Examples:
          >>> Config().replace(loss="distal").loss
          'distal'
        """
        return dataclasses.replace(self, **changes)


def for_task(task: str, **changes) -> Config:
    """The default :class:`Config` of a task, with top-level ``changes``: the same as
    ``Config(task=TaskConfig(name=task)).replace(**changes)``, the defaults the task's module
    states in its ``default_config()`` (:data:`TASK_DEFAULTS`; how each was chosen is
    written there: :func:`cfm_jax.tasks.inverse_dynamics.default_config`,
    :func:`cfm_jax.tasks.operational_space.default_config`,
    :func:`cfm_jax.tasks.legged.default_config`). The CLI's ``--task`` starts from it.

    Args:
      task: one of :data:`TASKS`.
      changes: keyword arguments, top-level fields to replace afterwards (``robot``,
        ``loss``, ``loop``, ...).

    Returns:
      A :class:`Config`.

    Raises:
      ConfigError: an unknown task or a bad value in ``changes``.

    Examples:
      >>> walk = for_task("walk")
      >>> walk.robot, walk.task.control_dt, walk.task.desired, walk.forward.kind
      ('solo12', 0.004, 'next_velocity', 'rigid_body')
      >>> walk == Config(robot="solo12", task=TaskConfig(name="walk"))
      True
      >>> for_task("inverse_dynamics").loop.torque_scale, for_task("opspace").loop.torque_scale
      ('coupled', 'inertia')
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
        "desired": "pd",
    },
}
"""The generic value of each field left at :data:`TASK_DEFAULT` (a class: its defaults), by
section (``"config"``: the top-level fields): what a task's ``default_config`` does not
state, and every value of a task registered without one."""


def to_dict(config: Config) -> dict:
    """Plain nested dict (JSON-serialisable) of a config.

    Args:
      config: a :class:`Config`.

    Returns:
      ``{"robot": ..., "task": {...}, "forward": {...}, ...}``.

    Examples:
      >>> to_dict(Config())["task"]["kp"]
      100.0
    """
    return dataclasses.asdict(config)


DERIVED = ("robot_conversion",)
"""Keys a run's ``config.json`` may hold beside the fields: derived from them (and from the
robot file) for the reader, ignored by :func:`from_dict`."""


def from_dict(data: dict) -> Config:
    """Inverse of :func:`to_dict`; unknown keys raise :class:`ConfigError` naming them.

    Keys of :data:`DERIVED` (written beside the fields for the reader, as the robot
    conversion of :func:`cfm_jax.report.config_record`) are ignored. Missing fields take
    their defaults, except ``loop.babbling`` in a config written
    before that field existed: those runs babbled as :data:`BABBLING_BEFORE` says, so the
    config reads as what ran.

    Args:
      data: a dict as written by :func:`to_dict` (for example a run's ``config.json``);
        lists where tuples are expected are accepted.

    Returns:
      The validated :class:`Config`.

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
            kwargs[key] = cls(**value)
        else:
            kwargs[key] = value
    return Config(**kwargs)


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
"""Fields whose values do not change the compiled program: the seed and the checkpoint
settings are not part of it; the learning rates, the initial log-variance bounds, the
babbling strategy, noise and gains, the task gains (and ``task.desired``, which sets the legged
gains) and the reference trajectories are arguments of it
(:class:`cfm_jax.algorithm.Knobs`). Configs that differ only in these and in ``loss`` share
one :class:`cfm_jax.experiment.Experiment` and its compilations (a sweep over them compiles
once per loss). Two of them are partly structure (see :func:`structure`): the *number* of
``task.targets`` (None: the default set) and, for ``opspace``, ``task.home`` (the
oracle's null-space posture lives in its host callback). Every other field (robot,
simulator, task name, duration, control period, site, network sizes, ensemble size, step
counts, batch sizes, iterations, seeds, babbling rollouts) builds its own."""


def structure(config: Config) -> dict:
    """The part of ``config`` that shapes its compiled program: :func:`to_dict` without
    ``loss`` and :data:`RUNTIME_FIELDS`, but with the number of ``task.targets`` (None when
    the default targets are used) and the fields the task builds into its program
    (:data:`TASK_STRUCTURAL`: ``opspace``'s ``task.home``). Two configs with equal structures
    can share an :class:`cfm_jax.experiment.Experiment`.

    Args:
      config: a :class:`Config`.

    Returns:
      A nested dict, JSON-serialisable.

    Examples:
      >>> a = Config(seed=1, task=TaskConfig(kp=50.0, targets=((0.1,) * 7, (0.2,) * 7)))
      >>> b = Config(loss="task", task=TaskConfig(targets=((0.3,) * 7, (0.4,) * 7)))
      >>> structure(a) == structure(b)
      True
      >>> structure(a)["task"]["targets"]
      2
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
    """The seeds of the runs in this config: ``seed, seed + 1, ..., seed + seeds - 1``.

    Args:
      config: a :class:`Config`.

    Returns:
      A tuple of ``config.loop.seeds`` ints.

    Examples:
      >>> seeds_of(Config(seed=5, loop=LoopConfig(seeds=3)))
      (5, 6, 7)
    """
    return tuple(range(config.seed, config.seed + config.loop.seeds))


def differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two config dicts, with both values.

    Args:
      old: a config dict (:func:`to_dict`), for example a run's.
      new: another one.
      prefix: prefix of the dotted names (used by the recursion).

    Returns:
      One string per differing field, sorted by name.

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
