"""The operational-space task (``opspace``, paper section IV-A-2): Cartesian reaching of an
end-effector site, the controller gets a desired site acceleration (docs/opspace.md).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from cfm_jax.config import Config, LoopConfig, TaskConfig, check_duration
from cfm_jax.sim import opspace
from cfm_jax.tasks import babbling, baselines
from cfm_jax.tasks.inverse_dynamics import AccelerationOutput, JointSpaceTask, require_fixed_base
from cfm_jax.tasks.references import (
    as_jax_cartesian,
    cartesian_reaching,
    check_positions,
    check_targets,
    default_cartesian_targets,
    desired_acceleration,
    minimum_jerk,
)


class OperationalSpaceTask(JointSpaceTask):
    """Operational-space control (``opspace``), the interface of :class:`JointSpaceTask`.

    The controller gets ``s = [q, qdot]`` and the site's desired acceleration
    ``xdd* = xdd_ref + kp (x_ref - x) + kd (xd_ref - xd)``; the forward model predicts
    ``y = [qdd, xdd]`` (finite differences over the control period), of which
    ``desired_index`` is the site part. Tracking error: the site position error (m).

    Args:
      robot: a fixed-base arm with the end-effector site.
      task: the :class:`cfm_jax.config.TaskConfig` (``targets`` as ``(k, 3)`` positions).
      control_dt: control period.
      simulator: ``"native"`` or ``"mjx"`` (where the site kinematics come from).

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> config = TaskConfig(name="opspace", duration=1.0, site="tip")
      >>> task = OperationalSpaceTask(arm, config, control_dt=0.01)
      >>> task.reference.x.shape, task.output_dim, task.desired_index  # y = [qdd (2), xdd (3)]
      ((5, 101, 3), 5, (2, 3, 4))
    """

    name = "opspace"
    tracking_name = "end-effector position tracking MSE"
    tracking_unit = "m"
    output_unit = "(rad/s$^2$)$^2$ and (m/s$^2$)$^2$"

    def __init__(self, robot, task: TaskConfig, control_dt: float, simulator: str = "native"):
        check_duration(task.duration, control_dt)
        home = robot.home if task.home is None else np.asarray(task.home, np.float64)
        check_positions("task.home", home[None], robot)
        self.robot, self.simulator = robot, simulator
        self.site = opspace.ee_site(robot, task.site)
        targets = (
            default_cartesian_targets(robot, self.site, home)
            if task.targets is None
            else check_targets(robot, task.targets, self.site)
        )
        self.reference_np = cartesian_reaching(
            robot, self.site, targets, task.duration, control_dt, home
        )
        self.reference = as_jax_cartesian(self.reference_np)
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
        """RMS end-effector reaching distance (m)."""
        delta = self.reference_np.x[:, -1] - self.reference_np.x[:, 0]
        return float(np.sqrt(np.mean(np.square(delta))))

    def _pd_gains(self, kp: float, kd: float):
        return baselines.opspace_pd_gains(self.robot, kp, kd, self.site, self._home_np)

    def _babbling_gains(self, kp: float, kd: float):
        """The babbling's feedback keeps the task-space PD gains."""
        return self._pd_gains(kp, kd)

    def _site(self, qpos, qvel):
        kin = opspace.kinematics(self.robot, qpos, qvel, self.site, self.simulator)
        return jnp.concatenate([kin.position, kin.velocity], -1)

    def entries(self) -> dict:
        """As :meth:`JointSpaceTask.entries`, the output ending with the site's ``xdd``."""
        joint = super().entries()
        site = tuple(("site_acceleration", int(self.site)) for _ in range(3))
        return {"state": joint["state"], "output": joint["output"] + site}

    def start(self, reference):
        del reference
        qvel = jnp.zeros(self.robot.nv, jnp.float32)
        return self.home, qvel, self._site(self.home, qvel)

    def babbling_reference(self, strategy: str, key):
        """As :meth:`JointSpaceTask.babbling_reference`, in straight lines of the site."""
        if babbling.uses_reference(strategy):
            return self.reference
        start = self.reference.x[:, 0]  # (targets, 3): the site at home
        if strategy == "home":
            goal = start
        else:
            poses = jnp.broadcast_to(self.home, (self.targets, self.robot.nq))
            poses = babbling.random_poses(key, self.robot, poses)
            goal = opspace.kinematics(
                self.robot, poses, jnp.zeros_like(poses), self.site, self.simulator
            )
            goal = goal.position
        x, xd, xdd = minimum_jerk(start, goal, self.steps * self.control_dt, self.control_dt)
        return type(self.reference)(x, xd, xdd)

    def desired(self, ref_t, qpos, qvel, features):
        return desired_acceleration(
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

    def acceleration_output(self):
        """``y = [qdd, xdd]`` is ``A qacc + b`` with ``A = [I; J(q)]``, ``b = [0; Jdot qd]`` by MJX.

        The observed ``y`` is the average over the control period, ``A qacc + b`` the value at
        its start (docs/opspace.md).
        """
        robot, site, nv = self.robot, self.site, self.robot.nv

        def affine(qpos, qvel):
            kin = opspace.mjx_kinematics(robot, qpos, qvel, site)
            a = jnp.concatenate([jnp.eye(nv, dtype=jnp.float32), kin.jacobian])
            b = jnp.concatenate([jnp.zeros(nv, jnp.float32), kin.bias_acceleration])
            return a, b

        return AccelerationOutput(tuple(range(nv + 3)), 1.0, affine)

    def feedback(self, step):
        """Task-space PD (:func:`cfm_jax.tasks.baselines.opspace_pd_policy`)."""
        torque = baselines.opspace_pd_policy(
            self.robot, self.gain_p, self.gain_d, self.site, self.simulator
        )
        return torque(step.qpos, step.qvel, step.reference.x, step.reference.xd)

    def oracle_policy(self, simulator: str):
        """The analytic operational-space controller
        (:func:`cfm_jax.tasks.baselines.opspace_oracle`)."""
        torque = baselines.opspace_oracle(self.robot, self.site, self._home_np, simulator=simulator)

        def policy(step, key):
            del key
            return torque(step.qpos, step.qvel, step.desired)

        return policy


def fits(robot) -> str:
    """Whether ``opspace`` can run on ``robot`` (``cfm-jax robot check``), and its site.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.

    Raises:
      ConfigError: a floating base, held or passive joints, or no end-effector site.

    Examples:
      >>> fits(cfm_jax.sim.robots.load("iiwa14"))
      "site 'flange'"
    """
    require_fixed_base(robot, "opspace", every_joint=True)
    return f"site {opspace.site_names(robot)[opspace.ee_site(robot)]!r}"


def make(
    robot, task: TaskConfig, control_dt: float, simulator: str = "native"
) -> OperationalSpaceTask:
    """The ``opspace`` task of a config.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig`.
      control_dt: control period (s).
      simulator: ``"native"`` (site kinematics by a host callback) or ``"mjx"`` (in JAX).

    Raises:
      ConfigError: the robot has a floating base, or the site or a target does not fit it.

    Examples:
      >>> arm = cfm_jax.sim.robots.load("two_link_arm")
      >>> make(arm, TaskConfig(name="opspace", duration=0.5, site="tip"), 0.01).steps
      50
    """
    require_fixed_base(robot, task.name, every_joint=True)
    return OperationalSpaceTask(robot, task, control_dt, simulator)


def default_config() -> Config:
    """The task's defaults: the inverse-dynamics task's, but the ``inertia`` torque scale
    (``coupled`` lost on the iiwa14's op-space task, docs/how-to/own-robot.md).

    Examples:
      >>> default_config().loop.torque_scale
      'inertia'
    """
    return Config(task=TaskConfig(name="opspace"), loop=LoopConfig(torque_scale="inertia"))
