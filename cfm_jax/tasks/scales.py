"""Fixed physical scales of a task's state and output from the robot's MJCF and the task, never
from data: the ``robot`` normaliser (``loop.normaliser = "robot"``; the rule of each entry kind
is in docs/concepts/method.md). Entry point: :func:`robot_scales`."""

from __future__ import annotations

import mujoco
import numpy as np

VELOCITY_SCALE = 8.0
"""Scale of every velocity (rad/s, m/s), the authors' Solo12 code's (an MJCF has no velocity
limits); within a factor of about 3 of the Solo12's and the iiwa14's speeds."""

UNLIMITED_POSITION_SCALE = 1.0
"""Scale of unlimited joints and free-joint coordinates (1 m, 1 rad), as the authors' code."""

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
"""Kinds of a ``task.entries()`` entry; its index is a ``qpos`` index (``position``), a dof, a site
id (``site_acceleration``) or a force component (``force``)."""


def gravity(robot) -> float:
    """``|g|`` of the robot's MJCF (m/s^2); :data:`STANDARD_GRAVITY` where it is zero.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> gravity(robots.load("iiwa14"))
      9.81
    """
    g = float(np.linalg.norm(robot.mj_model.opt.gravity))
    return g if g > 0 else STANDARD_GRAVITY


def acceleration_scales(robot) -> np.ndarray:
    """Acceleration scale of every dof, ``(nv,)``: what its full torque gives it alone at home,
    ``torque_limit / M_ii(home)`` (armature included); ``|g|`` for the unactuated ones.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> acceleration_scales(robots.load("solo12"))[:6].tolist() == [9.81] * 6  # floating base
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
    """``(centre, scale)`` of each ``(kind, index)`` entry for ``robot``, ``(len(entries),)`` each.

    ``site_acceleration`` is scaled by the RMS over x, y, z of ``J(home) A``, with ``J`` the site's
    Jacobian and ``A`` the :func:`acceleration_scales`; other kinds: docs/concepts/method.md.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      entries: a sequence of ``(kind, index)``, kinds of :data:`KINDS`.
      control_dt: the control period (s), for ``velocity_change``.

    Raises:
      ValueError: an unknown kind.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> [a.tolist() for a in scales_of(robots.load("two_link_arm"), [("velocity", 0)], 0.01)]
      [[0.0], [8.0]]
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
    """The ``robot`` normaliser: ``state_mean``, ``state_std``, ``output_mean``, ``output_std``.

    Args:
      task: a task with ``robot``, ``control_dt`` and ``entries()``, as all of :mod:`cfm_jax.tasks`.

    Raises:
      ConfigError: the task has no ``entries()``.

    Examples:
      >>> from cfm_jax import config, tasks
      >>> from cfm_jax.sim import robots
      >>> task = tasks.make(robots.load("two_link_arm"), config.TaskConfig(duration=0.5), 0.01)
      >>> robot_scales(task)["state_std"][2:].tolist()  # joint velocities
      [8.0, 8.0]
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
