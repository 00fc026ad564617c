"""The initial data of Algorithm 1 ("motor babbling data"): what the babbling controller
follows and which controller it is (``Config.loop.babbling``, :data:`STRATEGIES`).

Every strategy rolls out ``loop.babbling_rollouts`` times per seed, each rollout as wide as
one rollout of the task (its ``targets x steps`` transitions), with Gaussian torque noise of
``loop.babbling_noise`` times each joint's torque scale (``loop.torque_scale``:
:meth:`cfm_jax.robots.Robot.torque_scale`, or the torque limit):

* ``home`` (the legged tasks' default): the task's PD feedback (its PD-only baseline
  controller) holding the start pose: the arm's start pose (``task.home``, else the MJCF
  keyframe ``home``), the legged robot's standing pose (its keyframe ``home``). The authors'
  Solo12 code collects its initial data this way. It knows neither the test references nor
  the reference controller.
* ``reaching`` (the arm tasks' default, chosen by the selection run): the same PD
  feedback tracking minimum-jerk reaches of the task's duration from the start pose to
  random poses of the actuated joints, drawn uniformly inside each joint's range shrunk
  by 10% at both ends (``start +- pi`` for an unlimited joint), fresh for every seed and
  rollout; for ``opspace`` the reaches are straight lines of the site to where those poses
  put it; for a legged robot the base is not commanded and a fall ends
  the rollout's data. Knows neither the test references nor the reference controller.
* ``reference_pd``: PD tracking of the test references themselves (the arms' babbling
  before the faithful protocol). For studies of its effect only.
* ``oracle``: the task's oracle on the test references (the legged tasks' babbling before
  the faithful protocol: feed-forward torque plus joint PD, which reproduces the
  reference). For studies of its effect only.

The desired quantity ``s*`` stored with the babbling data is the one of the motion that was
babbled (for ``home`` the held pose: zero desired acceleration and, for a legged robot, the
static standing forces ``m g / feet`` on each foot).

Examples:
  >>> policy_weights("home"), policy_weights("oracle")
  ({'feedback': 1.0}, {'oracle': 1.0})
  >>> uses_reference("reaching"), uses_reference("reference_pd")
  (False, True)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cfm_jax import config as config_lib

STRATEGIES = config_lib.BABBLING
"""The strategies, as :data:`cfm_jax.config.BABBLING`."""

# Fraction of each joint's range kept free at both ends when drawing reaching goals (the
# same margin as the default test targets, cfm_jax.references.RANGE_MARGIN).
RANGE_MARGIN = 0.1
# The key stream of the reaching goals, folded into each babbling rollout's key (the
# rollout's torque noise keeps the rollout's key itself).
GOAL_STREAM = 1
# Poses over which the babbling's feedback gains are sized (pose_sample): enough that the
# lightest inertia of a 7-joint arm is within about 10% of its minimum over the range (the
# published iiwa 14: 1024 against 4096 poses), at about 60 ms a task.
POSE_SAMPLE = 1024


def policy_weights(strategy: str) -> dict:
    """The :class:`cfm_jax.rollout.MixedPolicy` weights of a strategy's controller.

    Args:
      strategy: one of :data:`STRATEGIES`.

    Returns:
      ``{"oracle": 1.0}`` for ``oracle``, else ``{"feedback": 1.0}`` (the task's PD).

    Raises:
      ConfigError: an unknown strategy.

    Examples:
      >>> policy_weights("reaching")
      {'feedback': 1.0}
    """
    _check(strategy)
    return {"oracle": 1.0} if strategy == "oracle" else {"feedback": 1.0}


def uses_reference(strategy: str) -> bool:
    """Whether a strategy babbles on the task's own (test) references.

    Args:
      strategy: one of :data:`STRATEGIES`.

    Returns:
      True for ``reference_pd`` and ``oracle``.

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
    """The ``qpos`` index and the ``(low, high)`` range of each actuated joint.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.

    Returns:
      ``(qpos_index (action_dim,), joint_range (action_dim, 2))``.

    Examples:
      >>> from cfm_jax import robots
      >>> index, limits = actuated_joints(robots.load("two_link_arm"))
      >>> index.tolist(), limits.shape
      ([0, 1], (2, 2))
    """
    model = robot.mj_model
    joint = np.asarray(model.dof_jntid)[robot.actuated_dofs]
    return np.asarray(model.jnt_qposadr)[joint], np.asarray(robot.joint_range)[joint]


def _goal_ranges(robot):
    """``(qpos index, limited, low, high)`` of the actuated joints' goal ranges: each
    limited range shrunk by :data:`RANGE_MARGIN` at both ends, ``-pi, pi`` (about the
    start) for an unlimited joint."""
    index, limits = actuated_joints(robot)
    width = limits[:, 1] - limits[:, 0]
    limited = np.isfinite(width)
    low = np.where(limited, limits[:, 0] + RANGE_MARGIN * np.where(limited, width, 0), -np.pi)
    high = np.where(limited, limits[:, 1] - RANGE_MARGIN * np.where(limited, width, 0), np.pi)
    return index, limited, low, high


def random_poses(key, robot, start):
    """Random goal poses: every actuated joint uniform inside its range shrunk by
    :data:`RANGE_MARGIN` at both ends (``start +- pi`` when unlimited); other coordinates
    (a floating base) stay at ``start``.

    Args:
      key: PRNG key.
      robot: a :class:`cfm_jax.robots.Robot`.
      start: ``(..., nq)`` start poses (one goal is drawn for each).

    Returns:
      ``(..., nq)`` float32 goal poses.

    Examples:
      >>> from cfm_jax import robots
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
    """A fixed sample of the poses the ``reaching`` babbling may visit: ``start`` and
    ``count - 1`` poses with every actuated joint uniform in the ranges of
    :func:`random_poses` (NumPy's generator of seed 0, the same for every run and seed).
    The babbling's feedback gains are sized over it
    (:func:`cfm_jax.baselines.babbling_joint_gains`).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      start: ``(nq,)`` the start pose.
      count: poses in the sample, ``start`` included.

    Returns:
      ``(count, nq)`` float64 poses.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> poses = pose_sample(arm, arm.home, count=4)
      >>> poses.shape, bool(np.all(np.abs(poses) <= arm.joint_range[:, 1]))
      ((4, 2), True)
    """
    index, limited, low, high = _goal_ranges(robot)
    start = np.asarray(start, np.float64)
    offset = np.where(limited, 0.0, start[index])
    u = np.random.default_rng(0).uniform(size=(count - 1, index.shape[0]))
    poses = np.repeat(start[None], count, axis=0)
    poses[1:, index] = offset + low + u * (high - low)
    return poses


def standing_forces(robot, feet: int) -> np.ndarray:
    """Static standing forces: ``m g / feet`` upwards on each foot (world frame, N).

    Args:
      robot: a :class:`cfm_jax.robots.Robot` (its total mass and gravity).
      feet: the number of feet.

    Returns:
      ``(feet * 3,)`` float32, ``[0, 0, m g / feet]`` per foot.

    Examples:
      >>> from cfm_jax import robots
      >>> solo = robots.load("solo12")
      >>> np.round(standing_forces(solo, 4)[:3].astype(float), 2).tolist()  # 2.501 kg g / 4
      [0.0, 0.0, 6.13]
    """
    import mujoco

    weight = mujoco.mj_getTotalmass(robot.mj_model) * -float(robot.mj_model.opt.gravity[2])
    per_foot = np.array([0.0, 0.0, weight / feet])
    return np.tile(per_foot, feet).astype(np.float32)
