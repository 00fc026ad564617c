"""Fixed physical scales of a task's state and output, from the robot's MJCF and the task
(the ``robot`` normaliser, ``Config.loop.normaliser = "robot"``), never from data.

Every task says what each entry of its state and of its forward model's output is
(``task.entries()``: a kind and an index per entry, see :data:`KINDS`); this module turns
that into a centre and a scale per entry for any robot:

* ``position`` (an entry of ``qpos``): a limited hinge or slide joint is centred at the
  middle of its range and scaled by half the range; an unlimited joint and the
  coordinates of a free joint (base position in m, orientation quaternion) are centred at
  the robot's home pose (its keyframe ``home``, else ``qpos0``) and scaled by
  :data:`UNLIMITED_POSITION_SCALE`.
* ``velocity`` (an entry of ``qvel``): centred at 0, scaled by :data:`VELOCITY_SCALE`.
* ``acceleration`` (an entry of ``qacc``): centred at 0, scaled by the acceleration the
  joint's full torque gives it alone at the home pose, ``torque_limit / M_ii(home)``
  (``M`` the MJCF's joint-space inertia, armature included): the output's counterpart
  of scaling torques by their limits (iiwa14: 34 to 83 rad/s^2, a few times its rated
  acceleration limits of 9 to 16 rad/s^2; Solo12: 1100 to 4800 rad/s^2, the light knee
  the largest). The unactuated coordinates of a floating base are scaled by gravity,
  ``|g|`` (m/s^2 for the linear ones, rad/s^2 for the angular ones: ``|g|`` per metre of
  lever).
* ``velocity_change`` (``qacc dt`` over one control period, the legged tasks' output):
  the acceleration scale times ``control_dt``.
* ``site_acceleration`` (an end-effector site's Cartesian acceleration, the ``opspace``
  output; the index is the site id): the same for x, y, z, the RMS over the three axes of
  the site's acceleration when every joint accelerates at its acceleration scale,
  ``sqrt(sum_kj (J_kj(home) A_j)^2 / 3)`` (``J`` the site's translational Jacobian).
* ``force`` (a component of a contact force, the legged tasks' foot forces): centred at
  0, scaled by the robot's weight ``m g`` (total mass of the MJCF times ``|g|``).
* torques (not an entry: :attr:`cfm_jax.networks.Normaliser.torque_limit` and
  ``torque_scale``): by ``Config.loop.torque_scale``, :meth:`cfm_jax.robots.Robot.torque_scale` or
  the torque limits, for every normaliser.

``|g|`` is the MJCF's gravity, or :data:`STANDARD_GRAVITY` where the MJCF has none.

Examples:
  >>> from cfm_jax import config, robots, tasks
  >>> arm = robots.load("two_link_arm")
  >>> task = tasks.make(arm, config.TaskConfig(duration=0.5), 0.01)
  >>> scales = robot_scales(task)
  >>> scales["state_std"][2:].tolist()  # joint velocities
  [8.0, 8.0]
"""

from __future__ import annotations

import mujoco
import numpy as np

VELOCITY_SCALE = 8.0
"""Scale of every velocity (rad/s, m/s): the authors' Solo12 code divides velocities by 8
(``norm_in`` in its ``model_module.py``), the only scale of the method's authors, so it
is kept rather than a number of our own. An MJCF has no velocity limits to read one from.
It fits both robots within a factor of about 3: the Solo12's recorded walks and jumps
reach 20 and 22 rad/s at the joints and 0.6 and 3.5 m/s at the base, the iiwa14's rated
joint speeds are 1.3 to 2.4 rad/s."""

UNLIMITED_POSITION_SCALE = 1.0
"""Scale of the position of an unlimited joint and of a free joint's coordinates
(1 m, 1 rad, a unit quaternion's components): the authors' code scales every position by
1."""

STANDARD_GRAVITY = 9.81
"""``|g|`` (m/s^2) where the MJCF's gravity is zero."""

KINDS = (
    "position",
    "velocity",
    "acceleration",
    "velocity_change",
    "site_acceleration",
    "force",
)
"""What an entry of a task's state or output can be (``task.entries()``): the kind, and
its index (``qpos`` index for ``position``; dof index for ``velocity``, ``acceleration``
and ``velocity_change``; the site id for ``site_acceleration``; the component for
``force``)."""


def gravity(robot) -> float:
    """``|g|`` of the robot's MJCF (m/s^2); :data:`STANDARD_GRAVITY` where it is zero.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.

    Returns:
      A float.

    Examples:
      >>> from cfm_jax import robots
      >>> gravity(robots.load("iiwa14"))
      9.81
    """
    g = float(np.linalg.norm(robot.mj_model.opt.gravity))
    return g if g > 0 else STANDARD_GRAVITY


def acceleration_scales(robot) -> np.ndarray:
    """Acceleration scale of every dof, ``(nv,)``: ``torque_limit / M_ii(home)`` for the
    actuated dofs, ``|g|`` for the unactuated ones (a floating base).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.

    Returns:
      ``(nv,)`` float64.

    Examples:
      >>> from cfm_jax import robots
      >>> solo = robots.load("solo12")
      >>> acceleration_scales(solo)[:6].tolist() == [9.81] * 6
      True
    """
    scales = np.full(robot.nv, gravity(robot))
    diagonal = robot.mass_matrix_diagonal(robot.home)
    dofs = np.asarray(robot.actuated_dofs)
    scales[dofs] = np.asarray(robot.torque_limit, np.float64) / diagonal[dofs]
    return scales


def _positions(robot) -> tuple[np.ndarray, np.ndarray]:
    """Centre and scale of every ``qpos`` entry, ``(nq,)`` each."""
    model = robot.mj_model
    centre = np.asarray(robot.home, np.float64).copy()
    scale = np.full(robot.nq, UNLIMITED_POSITION_SCALE)
    free = int(mujoco.mjtJoint.mjJNT_FREE)
    for j in range(model.njnt):
        if int(model.jnt_type[j]) == free or not model.jnt_limited[j]:
            continue
        low, high = (float(x) for x in model.jnt_range[j])
        adr = int(model.jnt_qposadr[j])
        centre[adr] = 0.5 * (low + high)
        scale[adr] = 0.5 * (high - low)
    return centre, scale


def _site_acceleration_scale(robot, site: int, accelerations: np.ndarray) -> float:
    """RMS over x, y, z of ``J(home) diag(accelerations)`` of a site."""
    model = robot.mj_model
    data = mujoco.MjData(model)
    data.qpos[:] = robot.home
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, robot.nv))
    mujoco.mj_jacSite(model, data, jac, None, int(site))
    return float(np.sqrt(np.sum(np.square(jac * accelerations[None, :])) / 3.0))


def scales_of(robot, entries, control_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre and scale of each entry of ``entries`` (``(kind, index)`` pairs, see
    :data:`KINDS`) for ``robot``.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      entries: a sequence of ``(kind, index)``.
      control_dt: the control period (s), for ``velocity_change``.

    Returns:
      ``(centre, scale)``, each ``(len(entries),)`` float64.

    Raises:
      ValueError: an unknown kind (the kind and :data:`KINDS` are named).

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> centre, scale = scales_of(arm, [("velocity", 0), ("force", 2)], 0.01)
      >>> centre.tolist(), float(scale[0])
      ([0.0, 0.0], 8.0)
    """
    positions = _positions(robot)
    accelerations = acceleration_scales(robot)
    weight = float(mujoco.mj_getTotalmass(robot.mj_model)) * gravity(robot)
    centre, scale = [], []
    for kind, index in entries:
        if kind == "position":
            centre.append(positions[0][index])
            scale.append(positions[1][index])
            continue
        centre.append(0.0)
        if kind == "velocity":
            scale.append(VELOCITY_SCALE)
        elif kind == "acceleration":
            scale.append(accelerations[index])
        elif kind == "velocity_change":
            scale.append(accelerations[index] * control_dt)
        elif kind == "site_acceleration":
            scale.append(_site_acceleration_scale(robot, index, accelerations))
        elif kind == "force":
            scale.append(weight)
        else:
            raise ValueError(f"entry kind {kind!r} is not allowed: one of {KINDS}")
    return np.asarray(centre, np.float64), np.asarray(scale, np.float64)


def robot_scales(task) -> dict:
    """The ``robot`` normaliser's centres and scales of a task's state and output.

    Args:
      task: a task object with ``robot``, ``control_dt`` and ``entries()`` (every task of
        :mod:`cfm_jax.tasks` has them).

    Returns:
      ``{"state_mean", "state_std", "output_mean", "output_std"}``, float64 NumPy arrays of
      the sizes ``task.state_dim`` and ``task.output_dim``.

    Raises:
      ConfigError: the task has no ``entries()`` (a task of one's own needs it for
        ``loop.normaliser = "robot"``).

    Examples:
      >>> from cfm_jax import config, robots, tasks
      >>> arm = robots.load("two_link_arm")
      >>> task = tasks.make(arm, config.TaskConfig(duration=0.5), 0.01)
      >>> {k: v.shape for k, v in robot_scales(task).items()}["output_std"]
      (2,)
    """
    from cfm_jax.config import ConfigError

    if not hasattr(task, "entries"):
        raise ConfigError(
            f"loop.normaliser='robot' is not allowed for task {type(task).__name__}: it has "
            "no entries() saying what its state and output entries are (see "
            "cfm_jax.tasks.scales); one of ('babbling', 'data')"
        )
    entries = task.entries()
    state_mean, state_std = scales_of(task.robot, entries["state"], task.control_dt)
    output_mean, output_std = scales_of(task.robot, entries["output"], task.control_dt)
    return {
        "state_mean": state_mean,
        "state_std": state_std,
        "output_mean": output_mean,
        "output_std": output_std,
    }
