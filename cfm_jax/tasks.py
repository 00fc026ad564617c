"""Reference trajectories and desired states for the joint-space tracking task.

The inverse-dynamics task (paper section IV-A-1): the robot reaches from its home pose to
each target along a quintic (minimum-jerk) joint-space path of ``duration`` seconds. At each
control step the desired next-step joint acceleration is

    qdd*_t = qdd_ref(t) + kp (q_ref(t) - q_t) + kd (qd_ref(t) - qd_t)

(``kp = kd = 0`` is pure feed-forward of the reference acceleration).

Examples:
  >>> import numpy as np
  >>> ref = quintic(np.zeros(1), np.ones(1), duration=1.0, control_dt=0.5)
  >>> ref.q[0, :, 0].tolist()
  [0.0, 0.5, 1.0]
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax import babbling
from cfm_jax.config import ConfigError, TaskConfig

DEFAULT_TARGET_COUNT = 5
# Largest default reaching distance per joint (rad or m), and the fraction of each joint's
# range kept free at both ends when placing default targets.
DEFAULT_REACH = 0.6
RANGE_MARGIN = 0.1


class Reference(NamedTuple):
    """Reference trajectories, one per target.

    Arrays are NumPy float64 (:func:`as_jax` makes float32 JAX copies).

    Attributes:
      q: ``(targets, steps + 1, nq)`` joint positions at the control times
        ``0, dt, ..., duration``.
      qd: ``(targets, steps + 1, nq)`` joint velocities at the same times.
      qdd: ``(targets, steps + 1, nq)`` joint accelerations at the same times.

    Examples:
      >>> ref = quintic([0.0, 0.0], [1.0, 0.5], duration=1.0, control_dt=0.1)
      >>> ref.q.shape, ref.steps
      ((1, 11, 2), 10)
      >>> ref.q[0, -1].tolist(), ref.qd[0, -1].tolist()  # at the goal, at rest
      ([1.0, 0.5], [0.0, 0.0])
    """

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    @property
    def steps(self) -> int:
        """Number of control steps per rollout."""
        return self.q.shape[1] - 1


def quintic(start, goal, duration: float, control_dt: float) -> Reference:
    """Minimum-jerk path ``start -> goal`` sampled every ``control_dt``: one target.

    ``q(t) = start + (goal - start) (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration``; zero
    velocity and acceleration at both ends.

    Args:
      start: ``(nq,)`` positions at ``t = 0``.
      goal: ``(nq,)`` positions at ``t = duration``.
      duration: seconds from start to goal (a whole number of control periods, see
        :func:`check_duration`; not checked here).
      control_dt: sampling period (s).

    Returns:
      A :class:`Reference` with a leading target axis of size 1,
      ``(1, round(duration / control_dt) + 1, nq)``.

    Examples:
      >>> ref = quintic([0.0], [2.0], duration=1.0, control_dt=0.5)
      >>> ref.q[0, :, 0].tolist(), ref.qd[0, :, 0].tolist()  # half way at mid-time
      ([0.0, 1.0, 2.0], [0.0, 3.75, 0.0])
    """
    start = np.asarray(start, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    q, qd, qdd = minimum_jerk(start, goal, duration, control_dt, xp=np)
    return Reference(q[None], qd[None], qdd[None])


def minimum_jerk(start, goal, duration: float, control_dt: float, xp=jnp):
    """Minimum-jerk paths ``start -> goal`` sampled every ``control_dt``, for any leading
    shape, in NumPy (``xp=np``, :func:`quintic`'s references) or JAX (traceable; the
    babbling references of :meth:`JointSpaceTask.babbling_reference`).

    ``x(t) = start + (goal - start) (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration``;
    with ``goal == start`` exactly ``start`` and zeros.

    Args:
      start: ``(..., n)`` positions at ``t = 0``.
      goal: ``(..., n)`` positions at ``t = duration``.
      duration: seconds (a whole number of control periods).
      control_dt: sampling period (s).
      xp: ``numpy`` or ``jax.numpy``.

    Returns:
      ``(x, xd, xdd)``, each ``(..., steps + 1, n)``, in the dtype of ``start``.

    Examples:
      >>> x, xd, _ = minimum_jerk(np.zeros(1), np.full(1, 2.0), 1.0, 0.5, xp=np)
      >>> x[:, 0].tolist(), xd[:, 0].tolist()
      ([0.0, 1.0, 2.0], [0.0, 3.75, 0.0])
    """
    start = xp.asarray(start)
    dtype = start.dtype
    start = start[..., None, :]
    delta = xp.asarray(goal, dtype)[..., None, :] - start
    steps = int(round(duration / control_dt))
    t = xp.arange(steps + 1, dtype=dtype) * control_dt
    u = xp.clip(t / duration, 0.0, 1.0)[:, None]
    x = start + delta * (10 * u**3 - 15 * u**4 + 6 * u**5)
    xd = delta * (30 * u**2 - 60 * u**3 + 30 * u**4) / duration
    xdd = delta * (60 * u - 180 * u**2 + 120 * u**3) / duration**2
    return x, xd, xdd


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


def default_targets(joint_range: np.ndarray, home: np.ndarray) -> np.ndarray:
    """Five reaching targets inside the joint limits, the same for every call.

    Target ``i`` is ``home + reach * d_i``, where ``d_i`` are fixed directions with entries in
    ``[-1, 1]`` (drawn once from a seeded generator), ``reach = min(0.6, range / 4)`` per
    joint, and the result is clipped to the joint range shrunk by 10% at each end. Works for
    any number of joints.

    Args:
      joint_range: ``(nq, 2)`` lower and upper joint limits (``-inf, inf`` for unlimited
        joints), as :attr:`cfm_jax.robots.Robot.joint_range`.
      home: ``(nq,)`` start pose the targets are placed around.

    Returns:
      ``(5, nq)`` target joint positions.

    Examples:
      >>> import numpy as np
      >>> joint_range = np.array([[-2.5, 2.5], [-2.5, 2.5]])
      >>> targets = default_targets(joint_range, home=np.zeros(2))
      >>> targets.shape, bool(np.all(np.abs(targets) <= 0.6))
      ((5, 2), True)
    """
    nq = home.shape[0]
    directions = np.random.default_rng(0).uniform(-1.0, 1.0, size=(DEFAULT_TARGET_COUNT, nq))
    # Make every target move every joint by at least a third of the reach.
    directions = np.sign(directions) * np.maximum(np.abs(directions), 1 / 3)
    width = joint_range[:, 1] - joint_range[:, 0]
    reach = np.where(np.isfinite(width), np.minimum(DEFAULT_REACH, width / 4), DEFAULT_REACH)
    lower = joint_range[:, 0] + RANGE_MARGIN * np.where(np.isfinite(width), width, 0.0)
    upper = joint_range[:, 1] - RANGE_MARGIN * np.where(np.isfinite(width), width, 0.0)
    return np.clip(home + reach * directions, lower, upper)


def reaching(robot, task: TaskConfig, control_dt: float) -> Reference:
    """Reference trajectories of the configured targets for a robot.

    One :func:`quintic` per target, from ``task.home`` (None: ``robot.home``) to each of
    ``task.targets`` (None: :func:`default_targets`) in ``task.duration`` seconds.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      task: a :class:`cfm_jax.config.TaskConfig` (its ``targets`` are joint positions).
      control_dt: control period (s).

    Returns:
      A :class:`Reference`, ``(targets, steps + 1, nq)``.

    Raises:
      ConfigError: targets or home of the wrong length or outside the joint limits, or a
        duration that is not a whole number of control periods.

    Examples:
      >>> from cfm_jax import config, robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = reaching(arm, config.TaskConfig(duration=1.0), control_dt=0.01)
      >>> ref.q.shape  # the 5 default targets, 100 control steps
      (5, 101, 2)
    """
    check_duration(task.duration, control_dt)
    home = robot.home if task.home is None else np.asarray(task.home)
    check_positions("task.home", home[None], robot)
    targets = (
        default_targets(robot.joint_range, home)
        if task.targets is None
        else np.asarray(task.targets, dtype=np.float64)
    )
    check_positions("task.targets", targets, robot)
    parts = [quintic(home, target, task.duration, control_dt) for target in targets]
    return Reference(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


def check_positions(field: str, positions: np.ndarray, robot) -> None:
    """Raise ConfigError if joint positions ``(k, nq)`` have the wrong size or break limits.

    Args:
      field: the configuration field the positions come from, for the message (for example
        ``"task.targets"``).
      positions: ``(k, nq)`` joint positions.
      robot: the :class:`cfm_jax.robots.Robot` whose joint count and limits apply.

    Raises:
      ConfigError: the last axis is not ``robot.nq`` long, or a position is outside its
        joint's range (the message names the first such entry and joint).

    Examples:
      >>> import numpy as np
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> check_positions("task.targets", np.array([[0.0, 1.0]]), arm)
      >>> check_positions("task.targets", np.array([[0.0, 9.0]]), arm)
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.targets[0][1]=9 (joint 'elbow') is outside the joint ...
    """
    if positions.shape[-1] != robot.nq:
        raise ConfigError(
            f"{field} has {positions.shape[-1]} joint positions per entry; robot "
            f"{robot.name!r} has nq={robot.nq} joints {robot.joint_names}"
        )
    low, high = robot.joint_range[:, 0], robot.joint_range[:, 1]
    bad = (positions < low) | (positions > high)
    if np.any(bad):
        k, j = np.argwhere(bad)[0]
        raise ConfigError(
            f"{field}[{k}][{j}]={positions[k, j]:.4g} (joint {robot.joint_names[j]!r}) is "
            f"outside the joint range [{low[j]:.4g}, {high[j]:.4g}]"
        )


def desired_acceleration(ref_q, ref_qd, ref_qdd, q, qd, kp: float, kd: float):
    """``qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``; all arrays ``(..., nv)``.

    Args:
      ref_q: reference positions ``q_ref``, ``(..., nv)``.
      ref_qd: reference velocities ``qd_ref``, ``(..., nv)``.
      ref_qdd: reference accelerations ``qdd_ref``, ``(..., nv)``.
      q: current positions, ``(..., nv)``.
      qd: current velocities, ``(..., nv)``.
      kp: proportional gain (1/s^2).
      kd: derivative gain (1/s).

    Returns:
      ``qdd*``, ``(..., nv)`` (NumPy or JAX, as the inputs).

    Examples:
      >>> import numpy as np
      >>> desired_acceleration(np.array([1.0]), np.array([0.0]), np.array([0.5]),
      ...                      q=np.array([0.9]), qd=np.array([0.2]), kp=100.0, kd=20.0)
      array([6.5])
    """
    return ref_qdd + kp * (ref_q - q) + kd * (ref_qd - qd)


def rms_reach(reference: Reference) -> float:
    """RMS reaching distance: ``sqrt(mean over targets and joints of (q_goal - q_home)^2)``.

    Args:
      reference: a :class:`Reference` ``(targets, steps + 1, nq)``; its first and last
        positions are taken as home and goal.

    Returns:
      The distance (rad, or m for slide joints), a float.

    Examples:
      >>> rms_reach(quintic([0.0, 0.0], [0.3, -0.4], duration=1.0, control_dt=0.5))
      0.3535533905932738
    """
    delta = reference.q[:, -1] - reference.q[:, 0]
    return float(np.sqrt(np.mean(np.square(delta))))


def as_jax(reference: Reference) -> Reference:
    """The same reference as float32 JAX arrays.

    Args:
      reference: a :class:`Reference` of NumPy arrays.

    Returns:
      A :class:`Reference` of ``jax.Array`` float32, same shapes.

    Examples:
      >>> ref = as_jax(quintic([0.0], [1.0], duration=1.0, control_dt=0.5))
      >>> ref.q.dtype, ref.q.shape
      (dtype('float32'), (1, 3, 1))
    """
    return Reference(*(jnp.asarray(x, jnp.float32) for x in reference))


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
    * ``babbling_reference(strategy, key)``: the reference the initial data's controller
      follows (:mod:`cfm_jax.babbling`), of the shapes of ``reference``, and
      ``with_reference(reference)``: a copy that follows another reference.
    * ``feedback(step) -> tau``: the PD-only baseline (and babbling) feedback;
      ``oracle_policy(simulator)``: the model-based oracle.
    * ``value_names``, ``values() -> dict`` and ``with_values(values)``: the attributes
      that hold values of the config rather than its structure (here the reference and the
      gains), and a copy of the task that uses other values of the same shapes (traced
      ones, inside compiled code). :class:`cfm_jax.training.Experiment` passes them as
      arguments of its compiled functions, so a sweep over the gains or over targets
      compiles once.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      reference: a :class:`Reference` (NumPy, ``(targets, steps + 1, nq)``).
      kp: proportional gain (1/s^2) of the PD correction in the desired acceleration.
      kd: derivative gain (1/s) of the same correction.
      control_dt: control period (a multiple of the robot's timestep).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = quintic(arm.home, arm.home + 0.1, duration=0.5, control_dt=0.01)
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
        nv = robot.nv
        self.targets, self.steps = reference.q.shape[0], reference.steps
        self.state_dim, self.desired_dim, self.output_dim = robot.nq + nv, nv, nv
        self.action_dim, self.feature_dim = nv, 0
        self.desired_index = tuple(range(nv))

    @property
    def tracking_scale(self) -> float:
        """RMS reaching distance (rad), the scale of the tracking error."""
        return rms_reach(self.reference_np)

    def _pd_gains(self, kp: float, kd: float):
        """The torque gains of :meth:`feedback` for the acceleration gains ``kp``, ``kd``."""
        from cfm_jax import rollout

        return rollout.pd_gains(self.robot, kp, kd, self.reference_np.q[0, 0])

    def _gains(self, kp: float, kd: float) -> dict:
        gain_p, gain_d = self._pd_gains(kp, kd)
        return {
            "kp": jnp.asarray(kp, jnp.float32),
            "kd": jnp.asarray(kd, jnp.float32),
            "gain_p": jnp.asarray(gain_p, jnp.float32),
            "gain_d": jnp.asarray(gain_d, jnp.float32),
        }

    # The attributes that hold values of the config (reference and gains), not structure.
    value_names: tuple[str, ...] = ("reference", "kp", "kd", "gain_p", "gain_d")

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

    def start(self, reference):
        return (
            reference.q[0],
            jnp.zeros(self.robot.nv, jnp.float32),
            jnp.zeros(0, jnp.float32),
        )

    def state(self, qpos, qvel, features):
        del features
        return jnp.concatenate([qpos, qvel])

    def desired(self, ref_t, qpos, qvel, features):
        del features
        return desired_acceleration(ref_t.q, ref_t.qd, ref_t.qdd, qpos, qvel, self.kp, self.kd)

    def features(self, qpos, qvel, sensors):
        del qpos, qvel, sensors
        return jnp.zeros(0, jnp.float32)

    def observed(self, step, qpos_next, qvel_next, features_next):
        del qpos_next, features_next
        return (qvel_next - step.qvel) / self.control_dt

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        del qvel_next, features_next
        return qpos_next - ref_next.q

    def record(self, step, tau, qpos_next, qvel_next, features_next):
        return {}

    def metrics(self, result) -> dict:
        return {}

    def feedback(self, step):
        """``K_p (q_ref - q) + K_d (qd_ref - qd)`` with :func:`cfm_jax.rollout.pd_gains`."""
        ref = step.reference
        return self.gain_p * (ref.q - step.qpos) + self.gain_d * (ref.qd - step.qvel)

    def oracle_policy(self, simulator: str):
        """MuJoCo's inverse dynamics of the desired acceleration
        (:func:`cfm_jax.rollout.oracle_policy`)."""
        from cfm_jax import rollout

        return rollout.oracle_policy(self.robot, simulator)


class OperationalSpaceTask(JointSpaceTask):
    """Operational-space control (``opspace``, paper section IV-A-2): the controller gets
    ``s = [q, qdot]`` and a desired end-effector acceleration
    ``xdd* = xdd_ref + kp (x_ref - x) + kd (xd_ref - xd)`` (3-D, world frame, of the
    configured site) and outputs joint torques; the forward model predicts the joint *and*
    end-effector accelerations ``y = [qdd, xdd]`` (observed over the control period as
    ``(qdot' - qdot) / dt`` and ``(xd' - xd) / dt``), of which the desired quantity specifies
    the last three (``desired_index``). Redundant arms make ``tau`` for a given ``xdd*``
    non-unique. The tracking error is the site position error ``x' - x_ref(t+1)`` (m).
    Site kinematics come from MuJoCo C (:mod:`cfm_jax.opspace`); the features carried in
    the rollout are ``[x, xd]`` of the site. Baselines: the analytic operational-space
    controller (Khatib) as oracle and task-space PD (``J^T (K_p e + K_d ed)``).

    Args:
      robot: a fixed-base arm with the end-effector site.
      task: the :class:`cfm_jax.config.TaskConfig` (``site``, ``targets`` as ``(k, 3)``
        positions or None for the defaults, ``home``, ``duration``, ``kp``, ``kd``).
      control_dt: control period.

    Examples:
      >>> from cfm_jax import config, robots
      >>> arm = robots.load("two_link_arm")
      >>> task = OperationalSpaceTask(
      ...     arm, config.TaskConfig(name="opspace", duration=1.0, site="tip"), 0.01)
      >>> task.reference.x.shape  # the 5 default targets, site positions
      (5, 101, 3)
      >>> task.desired_dim, task.output_dim, task.desired_index  # y = [qdd (2), xdd (3)]
      (3, 5, (2, 3, 4))
    """

    name = "opspace"
    tracking_name = "end-effector position tracking MSE"
    tracking_unit = "m"
    output_unit = "(rad/s$^2$)$^2$ and (m/s$^2$)$^2$"

    def __init__(self, robot, task: TaskConfig, control_dt: float):
        from cfm_jax import opspace

        check_duration(task.duration, control_dt)
        home = robot.home if task.home is None else np.asarray(task.home, np.float64)
        check_positions("task.home", home[None], robot)
        self.robot, self.opspace = robot, opspace
        self.site = opspace.ee_site(robot, task.site)
        targets = (
            opspace.default_cartesian_targets(robot, self.site, home)
            if task.targets is None
            else opspace.check_targets(robot, task.targets, self.site)
        )
        self.reference_np = opspace.cartesian_reaching(
            robot, self.site, targets, task.duration, control_dt, home
        )
        self.reference = opspace.as_jax(self.reference_np)
        self.home = jnp.asarray(home, jnp.float32)
        self.control_dt = float(control_dt)
        self._home_np = home
        self.__dict__.update(self._gains(float(task.kp), float(task.kd)))
        nv = robot.nv
        self.targets, self.steps = self.reference_np.x.shape[0], self.reference_np.steps
        self.state_dim, self.desired_dim, self.output_dim = robot.nq + nv, 3, nv + 3
        self.action_dim, self.feature_dim = nv, 6
        self.desired_index = (nv, nv + 1, nv + 2)

    @property
    def tracking_scale(self) -> float:
        """RMS end-effector reaching distance (m): ``sqrt(mean((x_goal - x_home)^2))``."""
        delta = self.reference_np.x[:, -1] - self.reference_np.x[:, 0]
        return float(np.sqrt(np.mean(np.square(delta))))

    def _pd_gains(self, kp: float, kd: float):
        """Task-space torque gains at home (:func:`cfm_jax.opspace.pd_gains`)."""
        return self.opspace.pd_gains(self.robot, kp, kd, self.site, self._home_np)

    def _site(self, qpos, qvel):
        kin = self.opspace.kinematics(self.robot, qpos, qvel, self.site)
        return jnp.concatenate([kin.position, kin.velocity], -1)

    def start(self, reference):
        del reference
        qvel = jnp.zeros(self.robot.nv, jnp.float32)
        return self.home, qvel, self._site(self.home, qvel)

    def babbling_reference(self, strategy: str, key):
        """As :meth:`JointSpaceTask.babbling_reference`, in Cartesian space: straight
        minimum-jerk paths of the site from its home position, held (``home``) or to where
        random joint poses put it (``reaching``)."""
        if babbling.uses_reference(strategy):
            return self.reference
        start = self.reference.x[:, 0]  # (targets, 3): the site at home
        if strategy == "home":
            goal = start
        else:
            poses = jnp.broadcast_to(self.home, (self.targets, self.robot.nq))
            poses = babbling.random_poses(key, self.robot, poses)
            goal = self.opspace.kinematics(self.robot, poses, jnp.zeros_like(poses), self.site)
            goal = goal.position
        x, xd, xdd = minimum_jerk(start, goal, self.steps * self.control_dt, self.control_dt)
        return type(self.reference)(x, xd, xdd)

    def desired(self, ref_t, qpos, qvel, features):
        return self.opspace.desired_acceleration(
            ref_t.x, ref_t.xd, ref_t.xdd, features[:3], features[3:], self.kp, self.kd
        )

    def features(self, qpos, qvel, sensors):
        del sensors
        return self._site(qpos, qvel)

    def observed(self, step, qpos_next, qvel_next, features_next):
        joint = (qvel_next - step.qvel) / self.control_dt
        site = (features_next[3:] - step.features[3:]) / self.control_dt
        return jnp.concatenate([joint, site])

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        return features_next[:3] - ref_next.x

    def feedback(self, step):
        """Task-space PD ``J^T (K_p (x_ref - x) + K_d (xd_ref - xd))``
        (:func:`cfm_jax.opspace.pd_policy`)."""
        torque = self.opspace.pd_policy(self.robot, self.gain_p, self.gain_d, self.site)
        return torque(step.qpos, step.qvel, step.reference.x, step.reference.xd)

    def oracle_policy(self, simulator: str):
        """The analytic operational-space controller (:func:`cfm_jax.opspace.oracle_policy`;
        MuJoCo C on the host for either simulator)."""
        del simulator
        torque = self.opspace.oracle_policy(self.robot, self.site, self._home_np)

        def policy(step, key):
            del key
            return torque(step.qpos, step.qvel, step.desired)

        return policy


def make(robot, task: TaskConfig, control_dt: float):
    """The task object of a :class:`cfm_jax.config.TaskConfig` for a robot.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`; its ``name`` chooses the class:
        :class:`JointSpaceTask` (``inverse_dynamics``), :class:`OperationalSpaceTask`
        (``opspace``) or :class:`LeggedTask` (``walk``, ``jump``).
      control_dt: control period (s), a multiple of the robot's timestep.

    Returns:
      The task object.

    Raises:
      ConfigError: the task does not fit the robot (the message says why).

    Examples:
      >>> from cfm_jax import config, robots
      >>> arm = robots.load("two_link_arm")
      >>> task = make(arm, config.TaskConfig(duration=1.0), control_dt=0.01)
      >>> type(task).__name__, task.targets, task.steps
      ('JointSpaceTask', 5, 100)
    """
    if task.name in ("inverse_dynamics", "opspace") and robot.floating_base:
        raise ConfigError(
            f"task.name={task.name!r} is not allowed for robot {robot.name!r}: it has a "
            "floating base (a free joint), and this task needs a fixed-base arm with every "
            "joint actuated"
        )
    if task.name == "inverse_dynamics":
        return JointSpaceTask(
            robot, reaching(robot, task, control_dt), task.kp, task.kd, control_dt
        )
    if task.name == "opspace":
        return OperationalSpaceTask(robot, task, control_dt)
    if task.name in ("walk", "jump"):
        return LeggedTask(robot, task, control_dt)
    raise ConfigError(f"task.name={task.name!r} is not allowed: no such task")


class LeggedReference(NamedTuple):
    """Locomotion references of several targets padded to one length (float32 JAX arrays,
    leading axes ``(targets, steps + 1)``; built by :func:`as_jax_legged`).

    Attributes:
      qpos: ``(targets, steps + 1, nq)`` positions (base pose and joints).
      qvel: ``(targets, steps + 1, nv)`` velocities.
      qacc: ``(targets, steps + 1, nv)`` mean acceleration over control period ``t`` (zero
        beyond the target's horizon).
      tau: ``(targets, steps + 1, action_dim)`` feed-forward joint torques.
      force: ``(targets, steps + 1, 4 * 3)`` the mean floor force on each foot over control
        period ``t``, flattened, world frame (N).
      active: ``(targets, steps + 1)`` 1 while ``t`` is inside the target's horizon, else 0.

    Examples:
      >>> from cfm_jax import locomotion
      >>> walks = [locomotion.walk_reference(d, use_cache=False) for d in (0.1, 0.2)]
      >>> ref = as_jax_legged(walks)
      >>> ref.qpos.shape, ref.force.shape, ref.active.sum(axis=1).tolist()
      ((2, 51, 19), (2, 51, 12), [25.0, 50.0])
    """

    qpos: jax.Array
    qvel: jax.Array
    qacc: jax.Array
    tau: jax.Array
    force: jax.Array
    active: jax.Array


def _quat_error(target, quat):
    """Rotation vector ``log(quat^-1 target)`` (MuJoCo's ``mju_subQuat(target, quat)``): the
    angular displacement from ``quat`` to ``target`` in ``quat``'s local frame, which is the
    frame of a free joint's angular velocity. Quaternions ``(w, x, y, z)``."""
    w1, v1 = quat[0], -quat[1:]  # conjugate of quat
    w2, v2 = target[0], target[1:]
    w = w1 * w2 - jnp.dot(v1, v2)
    v = w1 * v2 + w2 * v1 + jnp.cross(v1, v2)
    sign = jnp.where(w < 0, -1.0, 1.0)  # the shorter way round
    w, v = sign * w, sign * v
    norm = jnp.sqrt(jnp.sum(v * v) + 1e-24)
    return v * (2.0 * jnp.arctan2(norm, w) / norm)


class LeggedTask(JointSpaceTask):
    """Legged locomotion (``walk``, ``jump``; paper section IV-B) for a floating-base robot
    with one MuJoCo contact sensor per foot (data ``found force normal tangent``, as in
    ``robots/solo12.xml``; :func:`cfm_jax.locomotion.foot_forces`).

    * State ``s_t = [base pose and joint positions (qpos), foot forces f_t (world frame,
      mean over the previous control period), base and joint velocities (qvel)]``.
    * A step where the robot fell is terminal (``extras["terminal"]``): the rest of that
      rollout does not become data (the model has foot-floor contacts only, so a fallen
      body sinks through the floor).
    * The forward model predicts ``y = [qacc dt, f_{t+1}]``: the base and joint
      accelerations over the control period times ``dt`` (``qvel' - qvel``) and the mean
      foot forces over the period; the desired quantity is the same
      ``s* = [qacc* dt, f*]`` with ``qacc* = qacc_ref + kp e + kd (qvel_ref - qvel)`` (``e``:
      base position error, base orientation error as a rotation vector in the base frame,
      joint position errors; gains ``task.kp``, ``task.kd`` on the 6 base coordinates and
      ``task.joint_kp``, ``task.joint_kd`` on the joints) and ``f*`` the reference's foot
      forces.
    * References: :mod:`cfm_jax.locomotion` (a trot for 5 horizons, a vertical jump for 5
      heights), recorded from a whole-body controller on this model at ``control_dt``;
      padded to the longest horizon, steps beyond a target's horizon are masked out of the
      data and the metrics.
    * Tracking error: base position (m) and orientation (rad) error. Further metrics:
      ``force_mse`` (N^2, foot forces against the reference), ``fell`` (1 if the robot
      fell within the horizon: base below 0.1 m, tilted more than 0.8 rad, or a base-box
      corner at the floor), ``base_position_mse``, ``base_orientation_mse``.
    * Baselines: the reference's own controller (its feed-forward torque plus its joint
      PD) as ``oracle``, the joint PD alone as ``pd_only``.

    Args:
      robot: a floating-base :class:`cfm_jax.robots.Robot` with one contact sensor per foot
        (``solo12``).
      task: the :class:`cfm_jax.config.TaskConfig`; ``name`` (``walk`` or ``jump``), ``kp``,
        ``kd``, ``joint_kp`` and ``joint_kd`` are used. The targets and horizons are the 5
        references of :mod:`cfm_jax.locomotion`: ``duration`` is not used, and ``targets``
        and ``home`` must be None.
      control_dt: control period (s), at most :attr:`MAX_CONTROL_DT`.

    Raises:
      ConfigError: the robot has no floating base or no foot contact sensors,
        ``control_dt`` is too long, or ``task.targets`` / ``task.home`` is given.

    Examples:
      >>> from cfm_jax import config, robots
      >>> solo = robots.load("solo12")
      >>> walk = config.for_task("walk")  # control_dt 0.004
      >>> task = LeggedTask(solo, walk.task, walk.task.control_dt)  # doctest: +SKIP
      >>> task.targets, task.steps, task.state_dim, task.desired_dim  # doctest: +SKIP
      (5, 750, 49, 30)
    """

    tracking_name = "base pose tracking MSE"
    tracking_unit = "m | rad"
    output_unit = "(m/s, rad/s)$^2$ and N$^2$"
    metric_names = ("force_mse", "fell", "base_position_mse", "base_orientation_mse")
    MAX_CONTROL_DT = 0.004
    FALL_HEIGHT, FALL_TILT = 0.10, 0.8

    def __init__(self, robot, task: TaskConfig, control_dt: float):
        import mujoco

        from cfm_jax import locomotion

        self.name = task.name
        if not robot.floating_base:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: it needs a "
                "legged robot with a floating base (for example robot='solo12')"
            )
        if control_dt > self.MAX_CONTROL_DT + 1e-12:
            raise ConfigError(
                f"task.control_dt={control_dt!r} is not allowed for task {task.name!r}: the "
                f"legged references need {self.MAX_CONTROL_DT} s (250 Hz, the paper's rate) or "
                "a smaller multiple of the robot's timestep"
            )
        model = robot.mj_model
        contact = int(mujoco.mjtSensor.mjSENS_CONTACT)
        feet = [
            int(model.sensor_adr[i])
            for i in range(model.nsensor)
            if int(model.sensor_type[i]) == contact and int(model.sensor_dim[i]) == 10
        ]
        if len(feet) == 0:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: it needs one "
                '<contact> sensor per foot with data="found force normal tangent" (see '
                "robots/solo12.xml)"
            )
        for field in ("targets", "home"):
            if getattr(task, field) is not None:
                raise ConfigError(
                    f"task.{field}={getattr(task, field)!r} is not allowed for task "
                    f"{task.name!r}: None (the legged tasks start from and follow their 5 "
                    "recorded references, cfm_jax.locomotion.WALK_DURATIONS / JUMP_HEIGHTS)"
                )
        self.robot, self.locomotion = robot, locomotion
        self.sensor_rows = np.concatenate([np.arange(a, a + 10) for a in feet])
        self.feet = len(feet)
        kwargs = dict(control_dt=control_dt, model_file=robot.path)
        if task.name == "walk":
            refs = [locomotion.walk_reference(d, **kwargs) for d in locomotion.WALK_DURATIONS]
        else:
            refs = [locomotion.jump_reference(h, **kwargs) for h in locomotion.JUMP_HEIGHTS]
        self.references = refs  # the NumPy recordings (the other tasks' reference_np)
        self.reference = as_jax_legged(refs)
        self.control_dt = float(control_dt)
        self.__dict__.update(self._desired_gains(task))
        self.gain_p = jnp.float32(refs[0].kp)
        self.gain_d = jnp.float32(refs[0].kd)
        nq, nv, na = robot.nq, robot.nv, robot.action_dim
        self.targets, self.steps = len(refs), max(r.horizon for r in refs)
        forces = 3 * self.feet
        self.state_dim, self.desired_dim = nq + forces + nv, nv + forces
        self.output_dim, self.action_dim, self.feature_dim = nv + forces, na, forces
        self.desired_index = None
        self.joint_dofs = jnp.asarray(robot.actuated_dofs)
        self.joint_qpos = jnp.asarray(robot.actuated_dofs + (nq - nv))

    # The references are recordings of the model, structure; the values are the s* gains.
    value_names = ("desired_kp", "desired_kd")

    def _desired_gains(self, task: TaskConfig) -> dict:
        """The gains of the PD correction in ``s*``: ``desired_kp`` and ``desired_kd``,
        ``(6 + joints,)`` float32 (``task.kp``, ``task.kd`` on the 6 base coordinates, then
        ``task.joint_kp``, ``task.joint_kd`` on the actuated joints; None there: ``kp``,
        ``kd``). Not the references' joint PD torque gains ``gain_p``, ``gain_d``, which
        come with the recordings."""
        kp, kd = float(task.kp), float(task.kd)
        joint_kp = kp if task.joint_kp is None else float(task.joint_kp)
        joint_kd = kd if task.joint_kd is None else float(task.joint_kd)
        joints = self.robot.action_dim
        return {
            "desired_kp": jnp.asarray([kp] * 6 + [joint_kp] * joints, jnp.float32),
            "desired_kd": jnp.asarray([kd] * 6 + [joint_kd] * joints, jnp.float32),
        }

    @property
    def tracking_scale(self) -> float:
        """RMS base displacement of the references over their horizons (m)."""
        moves = [r.qpos[-1, :3] - r.qpos[0, :3] for r in self.references]
        peaks = [np.max(r.qpos[:, 2]) - r.qpos[0, 2] for r in self.references]
        return float(
            np.sqrt(np.mean([max(np.sum(m**2), p**2) for m, p in zip(moves, peaks, strict=True)]))
        )

    def start(self, reference):
        return reference.qpos[0], reference.qvel[0], reference.force[0]

    def babbling_reference(self, strategy: str, key):
        """As :meth:`JointSpaceTask.babbling_reference` from the robot's standing pose (its
        keyframe ``home``): the joints held (``home``) or moved to random poses
        (``reaching``), the base at rest, no feed-forward torque, the static standing
        forces (:func:`cfm_jax.babbling.standing_forces`) as desired forces, every step
        active. Neither depends on the recorded references."""
        if babbling.uses_reference(strategy):
            return self.reference
        robot, steps = self.robot, self.steps
        start = jnp.broadcast_to(jnp.asarray(robot.home, jnp.float32), (self.targets, robot.nq))
        goal = start if strategy == "home" else babbling.random_poses(key, robot, start)
        qpos, qd, qdd = minimum_jerk(start, goal, steps * self.control_dt, self.control_dt)
        shape = (self.targets, steps + 1)
        qvel = jnp.zeros(shape + (robot.nv,), jnp.float32).at[..., self.joint_dofs]
        qacc = jnp.zeros(shape + (robot.nv,), jnp.float32).at[..., self.joint_dofs]
        force = babbling.standing_forces(robot, self.feet)
        return LeggedReference(
            qpos=qpos,
            qvel=qvel.set(qd[..., self.joint_qpos]),
            qacc=qacc.set(qdd[..., self.joint_qpos]),
            tau=jnp.zeros(shape + (self.action_dim,), jnp.float32),
            force=jnp.broadcast_to(jnp.asarray(force), shape + force.shape),
            active=jnp.ones(shape, jnp.float32),
        )

    def state(self, qpos, qvel, features):
        return jnp.concatenate([qpos, features, qvel])

    def _pose_error(self, ref_qpos, qpos):
        return jnp.concatenate(
            [
                ref_qpos[:3] - qpos[:3],
                _quat_error(ref_qpos[3:7], qpos[3:7]),
                ref_qpos[self.joint_qpos] - qpos[self.joint_qpos],
            ]
        )

    def desired(self, ref_t, qpos, qvel, features):
        del features
        qacc = (
            ref_t.qacc
            + self.desired_kp * self._pose_error(ref_t.qpos, qpos)
            + self.desired_kd * (ref_t.qvel - qvel)
        )
        return jnp.concatenate([qacc * self.control_dt, ref_t.force])

    def features(self, qpos, qvel, sensors):
        del qpos, qvel
        rows = sensors[:, self.sensor_rows]
        forces = self.locomotion.foot_forces(rows, xp=jnp)  # (n_sub, feet, 3)
        return jnp.mean(forces, axis=0).reshape(-1)

    def observed(self, step, qpos_next, qvel_next, features_next):
        return jnp.concatenate([qvel_next - step.qvel, features_next])

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        error = self._pose_error(ref_next.qpos, qpos_next)[:6]
        return error * ref_next.active  # beyond the horizon: no error

    def record(self, step, tau, qpos_next, qvel_next, features_next):
        quat = qpos_next[3:7] / jnp.linalg.norm(qpos_next[3:7])
        rotation = self.locomotion.quat_to_mat(quat, xp=jnp)
        up = rotation[2, 2]  # world z component of the base z axis
        half = jnp.asarray(self.locomotion.BASE_HALF, jnp.float32)
        signs = jnp.asarray(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], jnp.float32
        )
        lowest = jnp.min(qpos_next[2] + (signs * half) @ rotation[2])
        fell = (
            (qpos_next[2] < self.FALL_HEIGHT)
            | (jnp.arccos(jnp.clip(up, -1.0, 1.0)) > self.FALL_TILT)
            | (lowest < 0.0)
        )
        return {
            "active": step.reference.active > 0,
            "force_error": features_next - step.reference.force,
            "fell": fell,
            "terminal": fell,  # no data from a fallen robot (see training._before_terminal)
        }

    def metrics(self, result) -> dict:
        extras = result.extras
        active = extras["active"].astype(jnp.float32)  # (targets, steps)
        count = jnp.maximum(jnp.sum(active, axis=-1), 1.0)

        def masked_mean(x):  # (targets, steps, k) -> (targets,)
            per_step = jnp.mean(jnp.square(x), axis=-1)
            return jnp.sum(per_step * active, axis=-1) / count

        return {
            "force_mse": masked_mean(extras["force_error"]),
            "fell": jnp.any(extras["fell"] & extras["active"], axis=-1).astype(jnp.float32),
            "base_position_mse": masked_mean(result.tracking_error[..., :3]),
            "base_orientation_mse": masked_mean(result.tracking_error[..., 3:6]),
        }

    def feedback(self, step):
        """The references' joint PD ``kp (q_ref - q) + kd (qd_ref - qd)`` on the actuated
        joints."""
        ref = step.reference
        joints = self.gain_p * (ref.qpos[self.joint_qpos] - step.qpos[self.joint_qpos])
        return joints + self.gain_d * (ref.qvel[self.joint_dofs] - step.qvel[self.joint_dofs])

    def oracle_policy(self, simulator: str):
        """The reference's own controller: its feed-forward torque plus its joint PD."""
        del simulator

        def policy(step, key):
            del key
            return step.reference.tau + self.feedback(step)

        return policy


def as_jax_legged(references) -> LeggedReference:
    """Pad :class:`cfm_jax.locomotion.LocomotionReference` s to the longest horizon
    (holding the last state, zero acceleration and the last torque and force) and stack
    them as float32 JAX arrays ``(targets, steps + 1, ...)``.

    Args:
      references: a sequence of :class:`cfm_jax.locomotion.LocomotionReference`, one per
        target (``steps`` is the longest horizon).

    Returns:
      A :class:`LeggedReference`; ``force`` is the references' ``foot_force_mean``.

    Examples:
      >>> from cfm_jax import locomotion
      >>> walks = [locomotion.walk_reference(d, use_cache=False) for d in (0.1, 0.2)]
      >>> ref = as_jax_legged(walks)
      >>> ref.tau.shape, ref.qacc[0, 25:].tolist() == [[0.0] * 18] * 26
      ((2, 51, 12), True)
    """
    steps = max(r.horizon for r in references)

    def pad(x, length):
        x = np.asarray(x, np.float64)
        extra = length - x.shape[0]
        return np.concatenate([x, np.repeat(x[-1:], extra, axis=0)]) if extra > 0 else x

    parts = []
    for r in references:
        force = r.foot_force_mean.reshape(r.horizon, -1)
        qacc = np.concatenate([r.qacc, np.zeros((steps + 1 - r.horizon, r.qacc.shape[1]))])
        active = (np.arange(steps + 1) < r.horizon).astype(np.float64)
        parts.append(
            (
                pad(r.qpos, steps + 1),
                pad(r.qvel, steps + 1),
                qacc,
                pad(r.tau, steps + 1),
                pad(force, steps + 1),
                active,
            )
        )
    return LeggedReference(
        *(jnp.asarray(np.stack(arrays), jnp.float32) for arrays in zip(*parts, strict=True))
    )
