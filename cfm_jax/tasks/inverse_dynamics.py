"""The inverse-dynamics task (``inverse_dynamics``, paper section IV-A-1): joint-space
reaching, the controller gets a desired joint acceleration. Its class,
:class:`JointSpaceTask`, also documents the interface every task has."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax import babbling, baselines
from cfm_jax.config import Config, ConfigError, TaskConfig, fail
from cfm_jax.references import (
    Reference,
    as_jax,
    desired_acceleration,
    minimum_jerk,
    reaching,
    rms_reach,
)


class AccelerationOutput(NamedTuple):
    """How the joint accelerations ``qacc`` enter a task's forward-model output ``y``
    (:meth:`JointSpaceTask.acceleration_output`): an affine map that may depend on the
    state, ``y[entries] = scale * (A(s) qacc + b(s))``.

    Attributes:
      entries: the ``k`` output indices the map fills; the other entries of ``y`` are not
        accelerations (the legged tasks' foot forces).
      scale: a constant factor (1, or ``control_dt`` for outputs in velocity units).
      affine: None for ``A = I``, ``b = 0`` (then ``k == nv``), or
        ``affine(qpos (nq,), qvel (nv,)) -> (A (k, nv), b (k,))`` of one state, float32
        and traceable by JAX (no host callback, so that it runs under ``jit`` with either
        simulator): ``opspace`` gives ``A = [I; J(q)]``, ``b = [0; Jdot(q, qd) qd]`` of its
        site.

    The ``rigid_body`` forward model (:mod:`cfm_jax.rigid_body`) puts its physics there.

    Examples:
      >>> out = AccelerationOutput(entries=(0, 1), scale=0.5)
      >>> out.entries, out.scale, out.affine is None
      ((0, 1), 0.5, True)
    """

    entries: tuple[int, ...]
    scale: float = 1.0
    affine: Callable | None = None


class JointSpaceTask:
    """The joint-space tracking task (``inverse_dynamics``) as the learning loop sees it.

    A *task* tells :func:`cfm_jax.rollout.run` and :mod:`cfm_jax.training` what the learning
    problem is; every task has the same attributes and methods (this class documents them):

    * ``state(qpos, qvel, features) -> s``: the learning state (here ``[q, qdot]``).
    * ``desired(ref_t, qpos, qvel, features) -> s*``: the desired quantity the controller is
      given (here ``qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``).
    * ``observed(step, qpos', qvel', features') -> y``: what the forward model predicts,
      measured after the control step (here ``(qdot' - qdot) / control_dt``).
      ``desired_index`` says which entries of ``y`` the desired quantity specifies (all here).
    * ``features(qpos, qvel, sensordata) -> features``: further measurements carried in the
      state (contact forces for legged robots; none here).
    * ``tracking_error(ref_{t+1}, qpos', qvel', features')``: what the tracking MSE is
      taken over (here ``q' - q_ref(t+1)``, rad), ``record(...)`` further per-step
      records, ``metrics(rollout)`` further per-target metrics.
    * ``start(reference) -> (qpos0, qvel0, features0)``: initial state of a rollout.
    * ``entries()``: what each entry of the state and the output is (a position, a
      velocity, an acceleration, a force, ...; :mod:`cfm_jax.tasks.scales`), so that the
      ``robot`` normaliser can scale them from the MJCF.
    * ``babbling_reference(strategy, key)``: the reference the initial data's controller
      follows (:mod:`cfm_jax.babbling`), of the shapes of ``reference``, and
      ``with_reference(reference)``: a copy that follows another reference.
    * ``feedback(step) -> tau``: the PD-only baseline feedback (and, with the babbling's
      own gains, the babbling's: ``for_babbling(reference)``);
      ``oracle_policy(simulator)``: the model-based oracle.
    * ``value_names``, ``values() -> dict`` and ``with_values(values)``: the attributes
      that hold values of the config rather than its structure (here the reference and the
      gains), and a copy of the task that uses other values of the same shapes (traced
      ones, inside compiled code). :class:`cfm_jax.experiment.Experiment` passes them as
      arguments of its compiled functions, so a sweep over the gains or over targets
      compiles once.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      reference: a :class:`Reference` (NumPy, ``(targets, steps + 1, nq)``).
      kp: proportional gain (1/s^2) of the PD correction in the desired acceleration.
      kd: derivative gain (1/s) of the same correction.
      control_dt: control period (a multiple of the robot's timestep).

    Examples:
      >>> from cfm_jax import references, robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = references.quintic(arm.home, arm.home + 0.1, duration=0.5, control_dt=0.01)
      >>> task = JointSpaceTask(arm, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> task.targets, task.steps, task.state_dim, task.desired_dim, task.output_dim
      (1, 50, 4, 2, 2)
    """

    name = "inverse_dynamics"
    # What the tracking MSE measures and its unit, and the squared unit of the forward
    # model's output (for tables and figures).
    tracking_name = "joint-position tracking MSE"
    tracking_unit = "rad"
    output_unit = "(rad/s$^2$)$^2$"
    metric_names: tuple[str, ...] = ()

    def __init__(self, robot, reference: Reference, kp: float, kd: float, control_dt: float):
        self.robot = robot
        self.reference_np = reference
        self.reference = as_jax(reference)
        self.control_dt = float(control_dt)
        self.__dict__.update(self._gains(float(kp), float(kd)))
        k = robot.action_dim
        self.targets, self.steps = reference.q.shape[0], reference.steps
        self.state_dim, self.desired_dim, self.output_dim = 2 * k, k, k
        self.action_dim, self.feature_dim = k, 0
        self.desired_index = tuple(range(k))

    # The controller's joints. An arm whose every joint it drives uses qpos and qvel as they
    # are; one with held or passive joints (a gripper) the entries of the actuated joints.
    def _q(self, qpos):
        return qpos if self.robot.drives_every_dof else qpos[..., self.robot.actuated_qpos]

    def _v(self, qvel):
        return qvel if self.robot.drives_every_dof else qvel[..., self.robot.actuated_dofs]

    @property
    def tracking_scale(self) -> float:
        """RMS reaching distance (rad) of the actuated joints, the scale of the tracking
        error."""
        q = self._q(self.reference_np.q)
        return rms_reach(Reference(q, q, q))

    def _pd_gains(self, kp: float, kd: float):
        """The torque gains of :meth:`feedback` for the acceleration gains ``kp``, ``kd``."""
        gain_p, gain_d = baselines.joint_pd_gains(self.robot, kp, kd, self.reference_np.q[0, 0])
        return self._v(gain_p), self._v(gain_d)

    def _babbling_gains(self, kp: float, kd: float):
        """The torque gains of the babbling's feedback: sized for the lightest inertia of
        each joint over the poses the babbling may visit
        (:func:`cfm_jax.baselines.babbling_joint_gains`)."""
        poses = babbling.pose_sample(self.robot, self.reference_np.q[0, 0])
        return baselines.babbling_joint_gains(self.robot, kp, kd, poses)

    def _gains(self, kp: float, kd: float) -> dict:
        gain_p, gain_d = self._pd_gains(kp, kd)
        babbling_p, babbling_d = self._babbling_gains(kp, kd)
        return {
            "kp": jnp.asarray(kp, jnp.float32),
            "kd": jnp.asarray(kd, jnp.float32),
            "gain_p": jnp.asarray(gain_p, jnp.float32),
            "gain_d": jnp.asarray(gain_d, jnp.float32),
            "babbling_gain_p": jnp.asarray(babbling_p, jnp.float32),
            "babbling_gain_d": jnp.asarray(babbling_d, jnp.float32),
        }

    # The attributes that hold values of the config (reference and gains), not structure.
    value_names: tuple[str, ...] = (
        "reference",
        "kp",
        "kd",
        "gain_p",
        "gain_d",
        "babbling_gain_p",
        "babbling_gain_d",
    )

    def values(self) -> dict:
        """The attributes :attr:`value_names`: the reference (float32 JAX arrays) and the
        gains (``kp``, ``kd`` of the desired acceleration, ``gain_p``, ``gain_d`` of
        :meth:`feedback`), as a dict (a pytree).

        Returns:
          ``{name: value}``; tasks built from configs of the same structure (same task,
          robot, number of targets, duration, control period) have the same keys and shapes.

        Examples:
          >>> from cfm_jax import config, robots
          >>> arm = robots.load("two_link_arm")
          >>> task = make(arm, config.TaskConfig(duration=0.5), control_dt=0.01)
          >>> softer = make(arm, config.TaskConfig(duration=0.5, kp=25.0), control_dt=0.01)
          >>> moved = task.with_values(softer.values())
          >>> float(moved.kp), float(task.kp)
          (25.0, 100.0)
        """
        return {name: getattr(self, name) for name in self.value_names}

    def with_values(self, values: dict):
        """A shallow copy of this task that uses ``values`` (from :meth:`values` of a task of
        the same structure; inside compiled code they may be traced).

        Args:
          values: a dict with the keys :attr:`value_names`, each of the shape of this
            task's.

        Returns:
          The copy; this task is unchanged.

        Raises:
          ValueError: other keys or another shape (the name and both shapes are given).
        """
        import copy

        if set(values) != set(self.value_names):
            raise ValueError(
                f"values has keys {sorted(values)}, this task takes {sorted(self.value_names)}"
            )
        for name in self.value_names:
            mine = [np.shape(x) for x in jax.tree.leaves(getattr(self, name))]
            theirs = [np.shape(x) for x in jax.tree.leaves(values[name])]
            if mine != theirs:
                raise ValueError(
                    f"values[{name!r}] has shapes {theirs}, this task's {mine}: a task of "
                    "another structure (targets, duration, control period)"
                )
        task = copy.copy(self)
        task.__dict__.update(values)
        return task

    def with_reference(self, reference):
        """A shallow copy of this task that follows ``reference`` (a pytree of the shapes of
        :attr:`reference`, traced inside compiled code), for example a babbling reference
        (:meth:`babbling_reference`). Host attributes (``reference_np``,
        ``tracking_scale``) still describe this task's own references."""
        import copy

        task = copy.copy(self)
        task.reference = reference
        return task

    def for_babbling(self, reference):
        """A shallow copy of this task that follows the babbling ``reference``
        (:meth:`with_reference`) with the babbling's feedback gains in place of the PD-only
        baseline's: :meth:`feedback` then uses ``babbling_gain_p``, ``babbling_gain_d``
        (:func:`cfm_jax.baselines.babbling_joint_gains`, stable wherever the babbling
        goes), while the baseline keeps ``gain_p``, ``gain_d``."""
        task = self.with_reference(reference)
        task.gain_p, task.gain_d = self.babbling_gain_p, self.babbling_gain_d
        return task

    def babbling_reference(self, strategy: str, key):
        """The reference the babbling controller follows (:mod:`cfm_jax.babbling`), of the
        shapes of :attr:`reference`: this task's own for ``reference_pd`` and ``oracle``,
        else minimum-jerk paths from the start pose, held (``home``) or to random poses drawn
        with ``key`` (``reaching``). Neither of these depends on the targets."""
        if babbling.uses_reference(strategy):
            return self.reference
        start = self.reference.q[:, 0]  # (targets, nq): every reach starts at home
        goal = start if strategy == "home" else babbling.random_poses(key, self.robot, start)
        return Reference(*minimum_jerk(start, goal, self.steps * self.control_dt, self.control_dt))

    def entries(self) -> dict:
        """What each entry of the state and of the output is, as ``(kind, index)`` pairs of
        :data:`cfm_jax.tasks.scales.KINDS` (the ``robot`` normaliser scales them from the
        MJCF): here the state ``[q, qdot]`` is ``qpos`` then ``qvel`` entries and the output
        the joint accelerations.

        Returns:
          ``{"state": (state_dim pairs), "output": (output_dim pairs)}``.

        Examples:
          >>> from cfm_jax import config, robots
          >>> task = make(robots.load("two_link_arm"), config.TaskConfig(duration=0.5), 0.01)
          >>> task.entries()["state"]
          (('position', 0), ('position', 1), ('velocity', 0), ('velocity', 1))
        """
        positions = self._q(np.arange(self.robot.nq)).tolist()
        dofs = self._v(np.arange(self.robot.nv)).tolist()
        return {
            "state": tuple(("position", i) for i in positions)
            + tuple(("velocity", i) for i in dofs),
            "output": tuple(("acceleration", i) for i in dofs),
        }

    def start(self, reference):
        return (
            reference.q[0],
            jnp.zeros(self.robot.nv, jnp.float32),
            jnp.zeros(0, jnp.float32),
        )

    def state(self, qpos, qvel, features):
        del features
        return jnp.concatenate([self._q(qpos), self._v(qvel)])

    def desired(self, ref_t, qpos, qvel, features):
        del features
        q, qd, qdd = (self._q(x) for x in (ref_t.q, ref_t.qd, ref_t.qdd))
        return desired_acceleration(q, qd, qdd, self._q(qpos), self._v(qvel), self.kp, self.kd)

    def features(self, qpos, qvel, sensors):
        del qpos, qvel, sensors
        return jnp.zeros(0, jnp.float32)

    def observed(self, step, qpos_next, qvel_next, features_next):
        del qpos_next, features_next
        return self._v(qvel_next - step.qvel) / self.control_dt

    def configuration(self, state):
        """``(qpos, qvel)`` of learning states ``(..., state_dim)``: every task's state
        starts with ``qpos`` and ends with ``qvel`` (a task whose state does not overrides
        this). Used by the ``rigid_body`` forward model (:mod:`cfm_jax.rigid_body`). With
        held or passive joints (not in the state) they are taken at rest at ``home``."""
        robot = self.robot
        if robot.drives_every_dof:
            nq, nv = robot.nq, robot.nv
            return state[..., :nq], state[..., state.shape[-1] - nv :]
        k, shape = robot.action_dim, state.shape[:-1]
        qpos = jnp.broadcast_to(jnp.asarray(robot.home, state.dtype), shape + (robot.nq,))
        qvel = jnp.zeros(shape + (robot.nv,), state.dtype)
        return (
            qpos.at[..., robot.actuated_qpos].set(state[..., :k]),
            qvel.at[..., robot.actuated_dofs].set(state[..., k:]),
        )

    def acceleration_output(self):
        """How the joint accelerations enter the forward model's output ``y``: an
        :class:`AccelerationOutput` ``(entries, scale, affine)`` with
        ``y[entries] = scale * (A(s) qacc + b(s))`` (here the whole output, scale 1,
        ``A = I``, ``b = 0``), or None when the output is not an affine image of ``qacc``.
        The ``rigid_body`` forward model puts its physics there; the other entries are the
        residual network's alone.

        Examples:
          >>> from cfm_jax import config, robots, tasks
          >>> arm = robots.load("two_link_arm")
          >>> tasks.make(arm, config.TaskConfig(duration=0.1), 0.01).acceleration_output()
          AccelerationOutput(entries=(0, 1), scale=1.0, affine=None)
        """
        robot = self.robot
        if robot.drives_every_dof:
            return AccelerationOutput(tuple(range(robot.nv)), 1.0)
        select = np.eye(robot.nv, dtype=np.float32)[robot.actuated_dofs]

        def affine(qpos, qvel):  # the actuated joints' accelerations
            del qpos, qvel
            return jnp.asarray(select), jnp.zeros(robot.action_dim, jnp.float32)

        return AccelerationOutput(tuple(range(robot.action_dim)), 1.0, affine)

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        del qvel_next, features_next
        return self._q(qpos_next - ref_next.q)

    def record(self, step, tau, qpos_next, qvel_next, features_next):
        return {}

    def metrics(self, result) -> dict:
        return {}

    def loss_weights(self) -> tuple:
        """The default coordinate groups of the ``norm`` controller loss
        (``controller.loss_form="norm"``, :func:`cfm_jax.losses.grouped`):
        ``((weight, (output index, ...)), ...)`` over the forward model's output ``y``.

        The arm tasks: one group of weight 1, every output entry, so the ``norm`` form is
        the plain Euclidean norm of the error (no coordinate of an arm's acceleration has a
        reason to count more than another; the authors' code weights only the legged
        robot's base).

        Examples:
          >>> from cfm_jax import config, robots, tasks
          >>> arm = robots.load("two_link_arm")
          >>> tasks.make(arm, config.TaskConfig(duration=0.1), 0.01).loss_weights()
          ((1.0, (0, 1)),)
        """
        return ((1.0, tuple(range(self.output_dim))),)

    def feedback(self, step):
        """``K_p (q_ref - q) + K_d (qd_ref - qd)`` with :func:`cfm_jax.baselines.joint_pd_gains`."""
        ref = step.reference
        return self.gain_p * self._q(ref.q - step.qpos) + self.gain_d * self._v(ref.qd - step.qvel)

    def oracle_policy(self, simulator: str):
        """MuJoCo's inverse dynamics of the desired acceleration
        (:func:`cfm_jax.baselines.inverse_dynamics_oracle`); with held or passive joints,
        those held at rest (zero desired acceleration) and the actuated joints' torques."""
        oracle = baselines.inverse_dynamics_oracle(self.robot, simulator)
        robot = self.robot
        if robot.drives_every_dof:
            return oracle

        def policy(step, key):
            qacc = jnp.zeros(step.desired.shape[:-1] + (robot.nv,), step.desired.dtype)
            full = step._replace(desired=qacc.at[..., robot.actuated_dofs].set(step.desired))
            return self._v(oracle(full, key))

        return policy


def require_fixed_base(robot, name: str, every_joint: bool = False) -> None:
    """The arm tasks need a fixed-base arm; ``every_joint``: with every joint actuated
    (no held or passive joint, :class:`cfm_jax.robots.Robot`).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      name: the task's name, for the message.
      every_joint: whether the task also needs every joint driven by the controller.

    Raises:
      ConfigError: ``robot`` has a floating base (a free joint), or with ``every_joint``
        held or passive joints (they are named).

    Examples:
      >>> from cfm_jax import robots
      >>> require_fixed_base(robots.load("two_link_arm"), "opspace")  # passes
    """
    if robot.floating_base:
        raise ConfigError(
            f"task.name={name!r} is not allowed for robot {robot.name!r}: it has a "
            "floating base (a free joint), and this task needs a fixed-base arm"
        )
    others = tuple(robot.held_joints) + tuple(robot.passive_joints)
    if every_joint and others:
        raise ConfigError(
            f"task.name={name!r} is not allowed for robot {robot.name!r}: its joints "
            f"{list(others)} are held or passive (no torque motor of their own), and this "
            "task needs every joint driven by the controller; task.name='inverse_dynamics' "
            "trains the driven joints and holds the others"
        )


def make(robot, task: TaskConfig, control_dt: float, simulator: str = "native") -> JointSpaceTask:
    """The ``inverse_dynamics`` task of a config: joint-space reaching
    (:func:`cfm_jax.references.reaching`) with the config's gains.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`.
      control_dt: control period (s).
      simulator: ``"native"`` or ``"mjx"`` (the same task for both: its simulator-specific
        parts, the oracle, are chosen when a rollout asks for them).

    Returns:
      A :class:`JointSpaceTask`.

    Raises:
      ConfigError: the robot has a floating base, or a target or the home pose is outside
        its joint limits.

    Examples:
      >>> from cfm_jax import config, robots
      >>> task = make(robots.load("two_link_arm"), config.TaskConfig(duration=0.5), 0.01)
      >>> task.targets, task.steps
      (5, 50)
    """
    require_fixed_base(robot, task.name)
    return JointSpaceTask(robot, reaching(robot, task, control_dt), task.kp, task.kd, control_dt)


def default_config() -> Config:
    """The task's defaults (what ``Config(task=TaskConfig(name="inverse_dynamics"))``, the
    CLI's ``--task inverse_dynamics`` and :func:`cfm_jax.config.for_task` give): the generic
    values of every field (:data:`cfm_jax.config.GENERIC` and the sections' dataclasses).

    The learner's options were chosen by the selection run (``experiments/select_defaults.py``,
    docs/results/selection/): every option compared with all four losses alike, 3 seeds, on
    motions other than the test ones, by a rule written before it ran (the lowest mean over
    the losses of log10 final tracking MSE, a fall or divergence scoring 1000 x PD-only), one
    factor at a time, on this task for the arms. They are: the paper's arm networks, 100 Hz
    control, ``kp = 100``, ``kd = 20`` in ``s*`` (set before any loss was run), and, chosen
    by the selection run, ``reaching`` initial data (the task's PD feedback tracking reaches
    to random poses inside the joint limits: it knows neither the test references nor the
    reference controller; ``home``, holding the start pose, was clearly worse) with the
    ``babbling`` normaliser (statistics of that data, fitted once) and the ``mlp`` forward
    model (``rigid_body`` was clearly worse on the arm), the controller loss in the ``norm``
    form (per-sample Euclidean norms, the authors' code; clearly better than the squares of
    the paper's text) and the goal ``desired`` (the paper's eq. 4; ``observed`` was clearly
    worse). Babbling size and noise, 2 rollouts per target at torque noise 0.1 of the torque
    scale, were set before any loss was run. Torques are scaled by the ``coupled`` scale,
    chosen on the development set of published arms by a rule written before its run (issue
    41, docs/how-to/own-robot.md).

    Returns:
      A :class:`cfm_jax.config.Config`.

    Examples:
      >>> config = default_config()
      >>> config.robot, config.loop.babbling, config.forward.kind, config.loop.torque_scale
      ('iiwa14', 'reaching', 'mlp', 'coupled')
    """
    return Config(task=TaskConfig(name="inverse_dynamics"))


def check_config(task: TaskConfig) -> None:
    """What the arm tasks (this one and ``opspace``) refuse of a :class:`TaskConfig`: the
    legged tasks' joint gains (the arms take ``kp`` and ``kd`` for their joints), their
    desired next velocity and their motions (the arms follow ``targets``).

    Args:
      task: a :class:`cfm_jax.config.TaskConfig` of an arm task (its fields' types checked).

    Raises:
      ConfigError: naming the field, its value and what the task takes.

    Examples:
      >>> TaskConfig(name="opspace", joint_kd=5.0)
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.joint_kd=5.0 is not allowed: None for task 'opspace' ...
    """
    for field in ("joint_kp", "joint_kd"):
        if getattr(task, field) is not None:
            fail(
                f"task.{field}",
                getattr(task, field),
                f"None for task {task.name!r} (joint gains of the legged tasks 'walk' and "
                "'jump'; the arm tasks use task.kp and task.kd for their joints)",
            )
    if task.desired != "pd":
        fail(
            "task.desired",
            task.desired,
            f"'pd' for task {task.name!r} (the desired next velocity is an s* of the legged "
            "tasks 'walk' and 'jump')",
        )
    if task.motions is not None:
        fail(
            "task.motions",
            task.motions,
            f"None for task {task.name!r} (the arm tasks follow task.targets)",
        )
