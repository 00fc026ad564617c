"""The inverse-dynamics task (``inverse_dynamics``, paper section IV-A-1): joint-space
reaching, the controller gets a desired joint acceleration. Its :class:`JointSpaceTask`
documents the interface every task has.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax.config import Config, ConfigError, TaskConfig, fail
from cfm_jax.sim import rollout
from cfm_jax.tasks import babbling, baselines
from cfm_jax.tasks.references import (
    Reference,
    as_jax,
    desired_acceleration,
    minimum_jerk,
    reaching,
    rms_reach,
)


class AccelerationOutput(NamedTuple):
    """How ``qacc`` enters a task's output ``y``: ``y[entries] = scale * (A(s) qacc + b(s))``.

    The ``rigid_body`` forward model puts its physics there.

    Attributes:
      entries: the ``k`` output indices of the map (others, like foot forces, are not in it).
      scale: a constant factor (1, or ``control_dt`` for outputs in velocity units).
      affine: None for ``A = I``, ``b = 0``, or ``affine(qpos, qvel) -> (A (k, nv), b (k,))``
        of one state, traceable by JAX (no host callback).

    Examples:
      >>> AccelerationOutput(entries=(0, 1), scale=0.5)
      AccelerationOutput(entries=(0, 1), scale=0.5, affine=None)
    """

    entries: tuple[int, ...]
    scale: float = 1.0
    affine: Callable | None = None


class JointSpaceTask:
    """The joint-space tracking task (``inverse_dynamics``), and the interface of every task.

    The interface that :func:`cfm_jax.sim.rollout.run` and :mod:`cfm_jax.runs.training` call (here):

    * ``state(qpos, qvel, features)``: the learning state ``s`` (``[q, qdot]``);
    * ``desired(ref_t, qpos, qvel, features)``: ``s*``, here
      ``qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``;
    * ``observed(step, qpos', qvel', features')``: what the forward model predicts, here
      ``(qdot' - qdot) / control_dt``; ``s*`` specifies its entries ``desired_index``;
    * ``features(qpos, qvel, sensordata)``: measurements carried in the state (none);
    * ``tracking_error(ref_next, qpos', qvel', features')`` (``q' - q_ref``, rad), ``record``,
      ``metrics``, ``start(reference)``, :meth:`entries`, :meth:`acceleration_output`;
    * :meth:`babbling_reference`, :meth:`with_reference`, :meth:`for_babbling`,
      ``feedback(step)`` (the PD baseline), ``oracle_policy(simulator)``;
    * ``value_names``, :meth:`values`, :meth:`with_values`: the config's values (reference,
      gains), passed to compiled code as arguments so that a sweep over them compiles once.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      reference: a :class:`Reference` (NumPy, ``(targets, steps + 1, nq)``).
      kp: proportional gain (1/s^2) of the PD correction in the desired acceleration.
      kd: derivative gain (1/s) of the same correction.
      control_dt: control period (a multiple of the robot's timestep).
      oracle: one of :data:`cfm_jax.config.ORACLES` (:meth:`oracle_policy`).

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> ref = cfm_jax.tasks.references.quintic(arm.home, arm.home + 0.1, 0.5, control_dt=0.01)
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

    def __init__(
        self,
        robot,
        reference: Reference,
        kp: float,
        kd: float,
        control_dt: float,
        oracle: str = "period",
    ):
        self.robot = robot
        self.oracle = oracle
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
        """RMS reaching distance (rad) of the actuated joints."""
        q = self._q(self.reference_np.q)
        return rms_reach(Reference(q, q, q))

    def _pd_gains(self, kp: float, kd: float):
        gain_p, gain_d = baselines.joint_pd_gains(self.robot, kp, kd, self.reference_np.q[0, 0])
        return self._v(gain_p), self._v(gain_d)

    def _babbling_gains(self, kp: float, kd: float):
        """Gains for the lightest inertia of the babbling's poses
        (:func:`cfm_jax.tasks.baselines.babbling_joint_gains`).
        """
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
        """``{name: value}`` of :attr:`value_names`; tasks of the same structure have the same keys
        and shapes.

        Examples:
          >>> arm = cfm_jax.sim.robots.load("two_link_arm")
          >>> task = make(arm, TaskConfig(duration=0.5), control_dt=0.01)
          >>> softer = make(arm, TaskConfig(duration=0.5, kp=25.0), control_dt=0.01)
          >>> float(task.with_values(softer.values()).kp), float(task.kp)
          (25.0, 100.0)
        """
        return {name: getattr(self, name) for name in self.value_names}

    def with_values(self, values: dict):
        """A shallow copy of this task that uses ``values`` (maybe traced).

        Raises:
          ValueError: keys or shapes other than those of this task's :meth:`values`.
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
        """A shallow copy that follows ``reference``; ``reference_np`` and ``tracking_scale`` still
        describe this task's own.
        """
        import copy

        task = copy.copy(self)
        task.reference = reference
        return task

    def for_babbling(self, reference):
        """:meth:`with_reference` with the babbling's feedback gains (stable wherever it goes)."""
        task = self.with_reference(reference)
        task.gain_p, task.gain_d = self.babbling_gain_p, self.babbling_gain_d
        return task

    def babbling_reference(self, strategy: str, key):
        """The babbling's reference: this task's for ``reference_pd`` and ``oracle``, else
        minimum-jerk paths from home, held (``home``) or to random poses (``reaching``).
        """
        if babbling.uses_reference(strategy):
            return self.reference
        start = self.reference.q[:, 0]  # (targets, nq): every reach starts at home
        goal = start if strategy == "home" else babbling.random_poses(key, self.robot, start)
        return Reference(*minimum_jerk(start, goal, self.steps * self.control_dt, self.control_dt))

    def entries(self) -> dict:
        """The state's and output's entries, ``(kind, index)`` of :mod:`cfm_jax.tasks.scales`.

        Examples:
          >>> task = make(cfm_jax.sim.robots.load("two_link_arm"), TaskConfig(duration=0.5), 0.01)
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
        """``(qpos, qvel)`` of states (for ``rigid_body``); held or passive joints at ``home``."""
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
        """The output's :class:`AccelerationOutput`, or None if not an affine image of ``qacc``.

        Examples:
          >>> arm = cfm_jax.sim.robots.load("two_link_arm")
          >>> make(arm, TaskConfig(duration=0.1), 0.01).acceleration_output()
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
        """``((weight, (output index, ...)), ...)``, the groups of the ``norm`` controller loss
        (:func:`cfm_jax.learning.losses.grouped`); the arms: one group, the plain Euclidean norm.
        """
        return ((1.0, tuple(range(self.output_dim))),)

    def feedback(self, step):
        """``K_p (q_ref - q) + K_d (qd_ref - qd)``
        (:func:`cfm_jax.tasks.baselines.joint_pd_gains`)."""
        ref = step.reference
        return self.gain_p * self._q(ref.q - step.qpos) + self.gain_d * self._v(ref.qd - step.qvel)

    def oracle_policy(self, simulator: str):
        """MuJoCo's inverse dynamics (:func:`cfm_jax.tasks.baselines.inverse_dynamics_oracle`;
        held joints at zero acceleration), exact over the period with ``oracle="period"``."""
        oracle = baselines.inverse_dynamics_oracle(self.robot, simulator)
        robot = self.robot
        if not robot.drives_every_dof:
            one_step = oracle

            def oracle(step, key):
                qacc = jnp.zeros(step.desired.shape[:-1] + (robot.nv,), step.desired.dtype)
                full = step._replace(desired=qacc.at[..., robot.actuated_dofs].set(step.desired))
                return self._v(one_step(full, key))

        if self.oracle == "step":
            return oracle
        n_sub = rollout.substeps(robot, self.control_dt)
        physics = (rollout.native_physics if simulator == "native" else rollout.mjx_physics)(
            robot, n_sub
        )

        def response(step, tau):
            qpos, qvel, sensors = physics(step.qpos, step.qvel, robot.torque_to_ctrl(tau))
            return self.observed(step, qpos, qvel, self.features(qpos, qvel, sensors))

        return baselines.over_the_period(oracle, response, robot.torque_limit)


def require_fixed_base(robot, name: str, every_joint: bool = False) -> None:
    """Refuse a robot an arm task cannot drive (a floating base, undriven joints).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      name: the task's name, for the message.
      every_joint: whether the task also needs every joint driven by the controller.

    Raises:
      ConfigError: a floating base, or with ``every_joint`` held or passive joints.

    Examples:
      >>> require_fixed_base(cfm_jax.sim.robots.load("two_link_arm"), "opspace")  # passes
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


def fits(robot) -> str:
    """Whether ``inverse_dynamics`` can run on ``robot`` (``cfm-jax robot check``).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Raises:
      ConfigError: it has a floating base.

    Examples:
      >>> fits(cfm_jax.sim.robots.load("two_link_arm"))
      ''
    """
    require_fixed_base(robot, "inverse_dynamics")
    return ""


def make(robot, task: TaskConfig, control_dt: float, simulator: str = "native") -> JointSpaceTask:
    """The ``inverse_dynamics`` task of a config (:func:`cfm_jax.tasks.references.reaching`).

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`.
      control_dt: control period (s).
      simulator: ``"native"`` or ``"mjx"`` (the same task for both).

    Raises:
      ConfigError: a floating base, or a target or the home pose outside the joint limits.

    Examples:
      >>> task = make(cfm_jax.sim.robots.load("two_link_arm"), TaskConfig(duration=0.5), 0.01)
      >>> task.targets, task.steps
      (5, 50)
    """
    require_fixed_base(robot, task.name)
    reference = reaching(robot, task, control_dt)
    return JointSpaceTask(robot, reference, task.kp, task.kd, control_dt, task.oracle)


def default_config() -> Config:
    """The task's defaults: the generic values (:data:`cfm_jax.config.GENERIC`), chosen by the
    selection run (docs/results.md, "How the defaults are chosen").

    Examples:
      >>> config = default_config()
      >>> config.robot, config.loop.babbling, config.forward.kind, config.loop.torque_scale
      ('iiwa14', 'reaching', 'mlp', 'auto')
    """
    return Config(task=TaskConfig(name="inverse_dynamics", oracle="period"))


def check_config(task: TaskConfig) -> None:
    """Refuse the legged tasks' fields (``joint_kp``, ``joint_kd``, ``desired``, ``motions``,
    ``motion_family``).

    Args:
      task: a :class:`cfm_jax.config.TaskConfig` of an arm task.

    Raises:
      ConfigError: naming the field, its value and what the task takes.

    Examples:
      >>> TaskConfig(name="opspace", joint_kd=5.0)
      Traceback (most recent call last):
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
    if task.motion_family != "test":
        fail(
            "task.motion_family",
            task.motion_family,
            f"'test' for task {task.name!r} (the arm tasks follow task.targets; the selection "
            "targets are references.default_targets(..., seed=references.SELECTION_SEED))",
        )
