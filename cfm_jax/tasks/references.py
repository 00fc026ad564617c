"""Reference trajectories of the tasks (docs/how-to/reference-trajectory.md): minimum-jerk
joint-space (:func:`reaching`, paper IV-A-1) and Cartesian (:func:`cartesian_reaching`,
IV-A-2) reaches with their :func:`desired_acceleration`, and the padded Solo12 recordings of
:mod:`cfm_jax.tasks.locomotion` (:func:`as_jax_legged`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax.config import ConfigError, TaskConfig, check_duration
from cfm_jax.sim import opspace

DEFAULT_TARGET_COUNT = 5
# Largest default reaching distance per joint (rad or m), and the fraction of each joint's
# range kept free at both ends when placing default targets.
DEFAULT_REACH = 0.6
RANGE_MARGIN = 0.1
# Seed of the selection run's arm targets (default_targets(..., seed=SELECTION_SEED)): five
# reaches of the same kind as the test targets (seed 0). 3 is the first seed whose targets
# are all at least 0.1 rad (max-norm) from every test target on both the iiwa14 (0.64 rad)
# and the two-link arm (0.16 rad); seeds 1 and 2 put one of the two-link arm's on a test
# target (its two joints clip to the same corner).
SELECTION_SEED = 3


# ---- joint-space reaching (inverse_dynamics) --------------------------------------------


class Reference(NamedTuple):
    """Joint reference trajectories, one per target, NumPy float64 (:func:`as_jax`: JAX).

    Attributes:
      q: ``(targets, steps + 1, nq)`` positions at the times ``0, dt, ..., duration``.
      qd: ``(targets, steps + 1, nq)`` velocities.
      qdd: ``(targets, steps + 1, nq)`` accelerations.

    Examples:
      >>> ref = quintic([0.0, 0.0], [1.0, 0.5], duration=1.0, control_dt=0.1)
      >>> ref.q.shape, ref.steps, ref.q[0, -1].tolist(), ref.qd[0, -1].tolist()
      ((1, 11, 2), 10, [1.0, 0.5], [0.0, 0.0])
    """

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    @property
    def steps(self) -> int:
        """Number of control steps per rollout."""
        return self.q.shape[1] - 1


def quintic(start, goal, duration: float, control_dt: float) -> Reference:
    """The :class:`Reference` ``(1, steps + 1, nq)`` of one :func:`minimum_jerk` path.

    Args:
      start: ``(nq,)`` positions at ``t = 0``.
      goal: ``(nq,)`` positions at ``t = duration``.
      duration: seconds (a whole number of control periods; not checked here).
      control_dt: sampling period (s).

    Examples:
      >>> quintic([0.0], [2.0], duration=1.0, control_dt=0.5).q[0, :, 0].tolist()
      [0.0, 1.0, 2.0]
    """
    start = np.asarray(start, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    q, qd, qdd = minimum_jerk(start, goal, duration, control_dt, xp=np)
    return Reference(q[None], qd[None], qdd[None])


def minimum_jerk(start, goal, duration: float, control_dt: float, xp=jnp):
    """Minimum-jerk paths ``(x, xd, xdd)``, each ``(..., steps + 1, n)``, in ``start``'s dtype.

    ``x(t) = start + (goal - start) (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration``: zero
    velocity and acceleration at both ends. Traceable with ``xp=jnp`` (the babbling's reaches).

    Args:
      start: ``(..., n)`` positions at ``t = 0``.
      goal: ``(..., n)`` positions at ``t = duration``.
      duration: seconds (a whole number of control periods).
      control_dt: sampling period (s).
      xp: ``numpy`` or ``jax.numpy``.

    Examples:
      >>> x, xd, _ = minimum_jerk(np.zeros(1), np.full(1, 2.0), 1.0, 0.5, xp=np)
      >>> x[:, 0].tolist(), xd[:, 0].tolist()  # half way at mid-time
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


def default_targets(joint_range: np.ndarray, home: np.ndarray, seed: int = 0) -> np.ndarray:
    """Five fixed reaching targets ``(5, nq)`` inside the joint limits.

    ``home + reach * d_i``, ``reach = min(0.6, range / 4)`` per joint, ``d_i`` in ``[-1, 1]``
    drawn with ``seed``, clipped to the range shrunk by :data:`RANGE_MARGIN` at each end.

    Args:
      joint_range: ``(nq, 2)`` joint limits, as :attr:`cfm_jax.sim.robots.Robot.joint_range`.
      home: ``(nq,)`` start pose the targets are placed around.
      seed: the directions' seed (0: the test targets; :data:`SELECTION_SEED`: selection's).

    Examples:
      >>> targets = default_targets(np.array([[-2.5, 2.5], [-2.5, 2.5]]), home=np.zeros(2))
      >>> targets.shape, bool(np.all(np.abs(targets) <= 0.6))
      ((5, 2), True)
    """
    nq = home.shape[0]
    directions = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(DEFAULT_TARGET_COUNT, nq))
    # Make every target move every joint by at least a third of the reach.
    directions = np.sign(directions) * np.maximum(np.abs(directions), 1 / 3)
    width = joint_range[:, 1] - joint_range[:, 0]
    reach = np.where(np.isfinite(width), np.minimum(DEFAULT_REACH, width / 4), DEFAULT_REACH)
    lower = joint_range[:, 0] + RANGE_MARGIN * np.where(np.isfinite(width), width, 0.0)
    upper = joint_range[:, 1] - RANGE_MARGIN * np.where(np.isfinite(width), width, 0.0)
    return np.clip(home + reach * directions, lower, upper)


def driven_targets(robot, home, seed: int = 0) -> np.ndarray:
    """:func:`default_targets` of a robot's driven joints; the others (held or passive,
    :func:`cfm_jax.sim.robots.held_joints`) stay at ``home``.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      home: ``(nq,)`` start pose.
      seed: as :func:`default_targets`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> driven_targets(robots.load("two_link_arm"), np.zeros(2)).shape
      (5, 2)
    """
    home = np.asarray(home, np.float64)
    targets = default_targets(robot.joint_range, home, seed)
    still = np.setdiff1d(np.arange(robot.nq), robot.actuated_qpos)
    targets[:, still] = home[still]
    return targets


def reaching(robot, task: TaskConfig, control_dt: float) -> Reference:
    """The :class:`Reference` of ``task``: a :func:`quintic` from ``task.home`` (None:
    ``robot.home``) to each of ``task.targets`` (None: :func:`driven_targets`).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      task: a :class:`cfm_jax.config.TaskConfig` (its ``targets`` are joint positions).
      control_dt: control period (s).

    Raises:
      ConfigError: targets or home not valid (:func:`check_positions`), or a bad duration.

    Examples:
      >>> from cfm_jax import config
      >>> from cfm_jax.sim import robots
      >>> reaching(robots.load("two_link_arm"), config.TaskConfig(duration=1.0), 0.01).q.shape
      (5, 101, 2)
    """
    check_duration(task.duration, control_dt)
    home = robot.home if task.home is None else np.asarray(task.home)
    check_positions("task.home", home[None], robot)
    if task.targets is None:
        targets = driven_targets(robot, home)
    else:
        targets = np.asarray(task.targets, dtype=np.float64)
    check_positions("task.targets", targets, robot)
    parts = [quintic(home, target, task.duration, control_dt) for target in targets]
    return Reference(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


def check_positions(field: str, positions: np.ndarray, robot) -> None:
    """Raise ConfigError if joint positions ``(k, nq)`` have the wrong size or break limits.

    Args:
      field: the configuration field, for the message (for example ``"task.targets"``).
      positions: ``(k, nq)`` joint positions.
      robot: the :class:`cfm_jax.sim.robots.Robot` whose joint count and limits apply.

    Raises:
      ConfigError: the wrong length, or the first position outside its joint's range.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> check_positions("task.targets", np.array([[0.0, 9.0]]), robots.load("two_link_arm"))
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
    """``qdd* = qdd_ref + kp (q_ref - q) + kd (qd_ref - qd)``, arrays ``(..., n)``.

    The desired acceleration of the joints (``n = nv``) or, with ``x_ref, xd_ref, xdd_ref,
    x, xd``, of the end-effector site (``n = 3``, world frame).

    Args:
      ref_q: reference positions.
      ref_qd: reference velocities.
      ref_qdd: reference accelerations.
      q: current positions.
      qd: current velocities.
      kp: proportional gain (1/s^2).
      kd: derivative gain (1/s).

    Examples:
      >>> desired_acceleration(np.array([1.0]), np.array([0.0]), np.array([0.5]),
      ...                      q=np.array([0.9]), qd=np.array([0.2]), kp=100.0, kd=20.0)
      array([6.5])
    """
    return ref_qdd + kp * (ref_q - q) + kd * (ref_qd - qd)


def rms_reach(reference: Reference) -> float:
    """RMS reaching distance, ``sqrt(mean over targets and joints of (q_goal - q_home)^2)``.

    Args:
      reference: a :class:`Reference`; its first and last positions are home and goal.

    Examples:
      >>> rms_reach(quintic([0.0, 0.0], [0.3, -0.4], duration=1.0, control_dt=0.5))
      0.3535533905932738
    """
    delta = reference.q[:, -1] - reference.q[:, 0]
    return float(np.sqrt(np.mean(np.square(delta))))


def as_jax(reference: Reference) -> Reference:
    """The same :class:`Reference` as float32 JAX arrays.

    Args:
      reference: a :class:`Reference` of NumPy arrays.

    Examples:
      >>> as_jax(quintic([0.0], [1.0], duration=1.0, control_dt=0.5)).q.dtype
      dtype('float32')
    """
    return Reference(*(jnp.asarray(x, jnp.float32) for x in reference))


# ---- Cartesian reaching (opspace) -------------------------------------------------------


class CartesianReference(NamedTuple):
    """End-effector reference trajectories, one per target, NumPy float64 (world frame).

    Attributes:
      x: ``(targets, steps + 1, 3)`` site positions at the times ``0, dt, ..., duration`` (m).
      xd: ``(targets, steps + 1, 3)`` site velocities (m/s).
      xdd: ``(targets, steps + 1, 3)`` site accelerations (m/s^2).

    Examples:
      >>> CartesianReference(*(np.zeros((1, 51, 3)),) * 3).steps
      50
    """

    x: np.ndarray
    xd: np.ndarray
    xdd: np.ndarray

    @property
    def steps(self) -> int:
        """Number of control steps per rollout."""
        return self.x.shape[1] - 1


def reach(robot, site: int | str | None = None) -> tuple[float, np.ndarray, str]:
    """An upper bound of the distance from the arm's base to the site: the arm's reach.

    The base is the last joint anchor of the site's chain that cannot move (on the axes of all
    hinges before it); the reach sums the anchor-to-anchor distances from there to the site
    at ``qpos0``, plus every slide joint's travel.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.

    Returns:
      ``(reach in m, base position (3,), base joint name)``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> length, base, joint = reach(robots.load("two_link_arm"), "tip")
      >>> round(length, 6), base.tolist(), joint
      (0.9, [0.0, 0.0, 1.0], 'shoulder')
    """
    model = robot.mj_model
    site = opspace.site_id(robot, site)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    chain = []
    body = int(model.site_bodyid[site])
    while body > 0:
        start, count = model.body_jntadr[body], model.body_jntnum[body]
        chain = list(range(start, start + count)) + chain
        body = int(model.body_parentid[body])
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    base = 0
    for k in range(1, len(chain)):
        anchor = data.xanchor[chain[k]]
        fixed = True
        for j in chain[:k]:
            if int(model.jnt_type[j]) == slide:
                fixed = False
                break
            offset = anchor - data.xanchor[j]
            if np.linalg.norm(np.cross(offset, data.xaxis[j])) > 1e-9:
                fixed = False
                break
        if not fixed:
            break
        base = k
    points = [data.xanchor[j] for j in chain[base:]] + [data.site_xpos[site]]
    length = float(np.sum(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1)))
    for j in chain:
        if int(model.jnt_type[j]) == slide:
            limited = bool(model.jnt_limited[j])
            length += float(np.ptp(model.jnt_range[j])) if limited else np.inf
        elif int(model.jnt_type[j]) != hinge:
            length = np.inf
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, chain[base]) or f"#{chain[base]}"
    return length, data.xanchor[chain[base]].copy(), name


def default_cartesian_targets(
    robot, site: int | str | None = None, home=None, seed: int = 0
) -> np.ndarray:
    """Five reachable end-effector targets ``(5, 3)`` (m): the site at :func:`default_targets`.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` pose the joint targets are placed around, or None for ``robot.home``.
      seed: as :func:`default_targets`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> targets = default_cartesian_targets(robots.load("two_link_arm"), "tip")
      >>> targets.shape, bool(np.all(targets[:, 1] == 0.0))  # the arm moves in the x-z plane
      ((5, 3), True)
    """
    home = robot.home if home is None else np.asarray(home, np.float64)
    joint_targets = default_targets(robot.joint_range, home, seed)
    return opspace.HostKinematics(robot, site)(joint_targets, np.zeros_like(joint_targets)).position


def check_targets(robot, targets, site: int | str | None = None) -> np.ndarray:
    """Validated end-effector targets as a ``(k, 3)`` float64 array.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      targets: end-effector positions (m, world frame), ``(k, 3)`` array-like.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.

    Raises:
      ConfigError: not a non-empty finite ``(k, 3)`` array, or a target beyond :func:`reach`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> check_targets(robots.load("two_link_arm"), [[2.0, 0.0, 0.0]], "tip")
      Traceback (most recent call last):
      ...
      cfm_jax.config.ConfigError: task.targets[0]=(2.0, 0.0, 0.0) is not allowed: it is ...
    """
    try:
        array = np.asarray(targets, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.ndim != 2 or array.shape[0] == 0 or array.shape[1] != 3:
        shape = None if array is None else array.shape
        raise ConfigError(
            f"task.targets={targets!r} is not allowed (shape {shape}): a non-empty sequence "
            "of end-effector positions (x, y, z) in metres, shape (k, 3)"
        )
    if not np.all(np.isfinite(array)):
        k = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise ConfigError(
            f"task.targets[{k}]={tuple(array[k].tolist())} is not allowed: finite positions"
        )
    length, base, joint = reach(robot, site)
    distance = np.linalg.norm(array - base, axis=1)
    far = np.flatnonzero(distance > length)
    if far.size:
        k = int(far[0])
        raise ConfigError(
            f"task.targets[{k}]={tuple(np.round(array[k], 4).tolist())} is not allowed: it is "
            f"{distance[k]:.3f} m from the base of robot {robot.name!r} (joint {joint!r} at "
            f"{tuple(np.round(base, 4).tolist())}), beyond the arm's reach of {length:.3f} m "
            f"to site {opspace.site_names(robot)[opspace.site_id(robot, site)]!r}"
        )
    return array


def cartesian_reaching(
    robot, site: int | str | None, targets, duration: float, control_dt: float, home=None
) -> CartesianReference:
    """The :class:`CartesianReference` ``(k, steps + 1, 3)`` of the site: a straight
    :func:`quintic` line from its position at ``home`` to each target.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      site: site name, id, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      targets: ``(k, 3)`` positions (m), or None for :func:`default_cartesian_targets`.
      duration: seconds per reach, a whole number (>= 1) of control periods.
      control_dt: control period (s).
      home: ``(nq,)`` start pose, or None for ``robot.home``.

    Raises:
      ConfigError: bad site, home, targets (:func:`check_targets`) or duration.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = cartesian_reaching(arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> ref.x.shape, np.round(ref.x[0, 0], 3).tolist(), ref.x[0, -1].tolist()  # home to goal
      ((1, 51, 3), [0.636, 0.0, 0.929], [0.5, 0.0, 1.4])
    """
    check_duration(duration, control_dt)
    home = robot.home if home is None else np.asarray(home, np.float64)
    check_positions("task.home", home[None], robot)
    if targets is None:
        targets = default_cartesian_targets(robot, site, home)
    targets = check_targets(robot, targets, site)
    start = opspace.HostKinematics(robot, site)(home, np.zeros(robot.nv)).position
    parts = [quintic(start, goal, duration, control_dt) for goal in targets]
    return CartesianReference(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


def as_jax_cartesian(reference: CartesianReference) -> CartesianReference:
    """The same :class:`CartesianReference` as float32 JAX arrays.

    Args:
      reference: a :class:`CartesianReference` of NumPy arrays.

    Examples:
      >>> ref = CartesianReference(*(np.zeros((1, 3, 3)) for _ in range(3)))
      >>> as_jax_cartesian(ref).xdd.dtype
      dtype('float32')
    """
    return CartesianReference(*(jnp.asarray(x, jnp.float32) for x in reference))


# ---- legged recordings padded (walk, jump) ----------------------------------------------


class LeggedReference(NamedTuple):
    """Locomotion references padded to one length (float32 JAX; :func:`as_jax_legged`).

    Attributes:
      qpos: ``(targets, steps + 1, nq)`` positions (base pose and joints).
      qvel: ``(targets, steps + 1, nv)`` velocities.
      qacc: ``(targets, steps + 1, nv)`` mean acceleration over control period ``t``.
      tau: ``(targets, steps + 1, action_dim)`` feed-forward joint torques.
      force: ``(targets, steps + 1, 4 * 3)`` mean floor force per foot, world frame (N).
      active: ``(targets, steps + 1)`` 1 inside the target's horizon, else 0.

    Examples:
      >>> LeggedReference._fields
      ('qpos', 'qvel', 'qacc', 'tau', 'force', 'active')
    """

    qpos: jax.Array
    qvel: jax.Array
    qacc: jax.Array
    tau: jax.Array
    force: jax.Array
    active: jax.Array


def as_jax_legged(references) -> LeggedReference:
    """Pad locomotion references to the longest horizon (holding the last state, torque and
    force, with zero acceleration) and stack them as a :class:`LeggedReference`.

    Args:
      references: :class:`cfm_jax.tasks.locomotion.LocomotionReference` s, one per target.

    Examples:
      >>> from cfm_jax.tasks import locomotion
      >>> walks = [locomotion.walk_reference(d, use_cache=False) for d in (0.1, 0.2)]
      >>> ref = as_jax_legged(walks)  # horizons of 25 and 50 steps
      >>> ref.qpos.shape, ref.active.sum(axis=1).tolist(), bool(jnp.all(ref.qacc[0, 25:] == 0))
      ((2, 51, 19), [25.0, 50.0], True)
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
