"""Motor babbling, the initial data of Algorithm 1: the strategies of ``loop.babbling``.

:data:`STRATEGIES` are ``home`` (hold the start pose with the task's PD feedback),
``reaching`` (the same PD tracking minimum-jerk reaches to :func:`random_poses`), and, for
studies only, ``reference_pd`` and ``oracle`` on the test references; noise, widths and the
stored ``s*`` are in docs/concepts/method.md ("Initial data").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax import config as config_lib

STRATEGIES = config_lib.BABBLING
"""The strategies, as :data:`cfm_jax.config.BABBLING`."""

# Fraction of each joint's range kept free at both ends when drawing reaching goals (the
# same margin as the default test targets, cfm_jax.tasks.references.RANGE_MARGIN).
RANGE_MARGIN = 0.1
# The key stream of the reaching goals, folded into each babbling rollout's key (the
# rollout's torque noise keeps the rollout's key itself).
GOAL_STREAM = 1
# Poses over which the babbling's feedback gains are sized (pose_sample): enough that the
# lightest inertia of a 7-joint arm is within about 10% of its minimum over the range (the
# published iiwa 14: 1024 against 4096 poses), at about 60 ms a task.
POSE_SAMPLE = 1024


def policy_weights(strategy: str) -> dict:
    """The :class:`cfm_jax.sim.rollout.MixedPolicy` weights of a strategy's controller.

    Args:
      strategy: one of :data:`STRATEGIES`.

    Raises:
      ConfigError: an unknown strategy.

    Examples:
      >>> policy_weights("home"), policy_weights("oracle")
      ({'feedback': 1.0}, {'oracle': 1.0})
    """
    _check(strategy)
    return {"oracle": 1.0} if strategy == "oracle" else {"feedback": 1.0}


def uses_reference(strategy: str) -> bool:
    """Whether a strategy babbles on the task's own (test) references.

    Args:
      strategy: one of :data:`STRATEGIES`.

    Raises:
      ConfigError: an unknown strategy.

    Examples:
      >>> [uses_reference(name) for name in STRATEGIES]
      [False, False, True, True]
    """
    _check(strategy)
    return strategy in ("reference_pd", "oracle")


def _check(strategy: str) -> None:
    if strategy not in STRATEGIES:
        raise config_lib.ConfigError(
            f"loop.babbling={strategy!r} is not allowed: one of {STRATEGIES}"
        )


def actuated_joints(robot) -> tuple[np.ndarray, np.ndarray]:
    """``(qpos index (action_dim,), (low, high) range (action_dim, 2))`` of the actuated joints.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> index, limits = actuated_joints(robots.load("two_link_arm"))
      >>> index.tolist(), limits.shape
      ([0, 1], (2, 2))
    """
    model = robot.mj_model
    joint = np.asarray(model.dof_jntid)[robot.actuated_dofs]
    return np.asarray(model.jnt_qposadr)[joint], np.asarray(robot.joint_range)[joint]


def _goal_ranges(robot):
    """``(qpos index, limited, low, high)`` of the goal ranges (:func:`random_poses`)."""
    index, limits = actuated_joints(robot)
    width = limits[:, 1] - limits[:, 0]
    limited = np.isfinite(width)
    low = np.where(limited, limits[:, 0] + RANGE_MARGIN * np.where(limited, width, 0), -np.pi)
    high = np.where(limited, limits[:, 1] - RANGE_MARGIN * np.where(limited, width, 0), np.pi)
    return index, limited, low, high


def random_poses(key, robot, start):
    """Random float32 goal poses, one per start pose, for the ``reaching`` babbling.

    Each actuated joint is uniform in its range shrunk by :data:`RANGE_MARGIN` at both ends
    (``start +- pi`` if unlimited); other coordinates (a floating base) keep ``start``.

    Args:
      key: PRNG key.
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      start: ``(..., nq)`` start poses; the goals have the same shape.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> goals = random_poses(jax.random.key(0), arm, jnp.zeros((5, 2)))
      >>> goals.shape, bool(jnp.all(jnp.abs(goals) <= arm.joint_range[:, 1]))
      ((5, 2), True)
    """
    index, limited, low, high = _goal_ranges(robot)
    start = jnp.asarray(start, jnp.float32)
    offset = jnp.where(jnp.asarray(limited), 0.0, start[..., index])
    u = jax.random.uniform(key, start.shape[:-1] + (index.shape[0],), jnp.float32)
    goal = offset + jnp.asarray(low, jnp.float32) + u * jnp.asarray(high - low, jnp.float32)
    return start.at[..., index].set(goal)


def pose_sample(robot, start, count: int = POSE_SAMPLE) -> np.ndarray:
    """A fixed float64 ``(count, nq)`` sample of the poses the ``reaching`` babbling may visit.

    ``start`` and ``count - 1`` poses drawn as :func:`random_poses` does, with NumPy's seed 0
    (the same for every run); :func:`cfm_jax.tasks.baselines.babbling_joint_gains` uses it.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      start: ``(nq,)`` the start pose.
      count: poses in the sample, ``start`` included.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> poses = pose_sample(robots.load("two_link_arm"), np.zeros(2), count=4)
      >>> poses.shape, poses[0].tolist()  # start first
      ((4, 2), [0.0, 0.0])
    """
    index, limited, low, high = _goal_ranges(robot)
    start = np.asarray(start, np.float64)
    offset = np.where(limited, 0.0, start[index])
    u = np.random.default_rng(0).uniform(size=(count - 1, index.shape[0]))
    poses = np.repeat(start[None], count, axis=0)
    poses[1:, index] = offset + low + u * (high - low)
    return poses


def standing_forces(robot, feet: int) -> np.ndarray:
    """Static standing forces, ``[0, 0, m g / feet]`` per foot: ``(feet * 3,)`` float32 (N).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot` (its total mass and gravity).
      feet: the number of feet.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> np.round(standing_forces(robots.load("solo12"), 4)[:3].astype(float), 2).tolist()
      [0.0, 0.0, 6.13]
    """
    import mujoco

    weight = mujoco.mj_getTotalmass(robot.mj_model) * -float(robot.mj_model.opt.gravity[2])
    per_foot = np.array([0.0, 0.0, weight / feet])
    return np.tile(per_foot, feet).astype(np.float32)
