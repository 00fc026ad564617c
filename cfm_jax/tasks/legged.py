"""The legged tasks (``walk``, ``jump``; paper section IV-B): a floating-base robot tracks
recorded reference motions, with foot contact forces in its state."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from cfm_jax import babbling, locomotion, solo12
from cfm_jax.config import (
    Config,
    ConfigError,
    ControllerConfig,
    ForwardModelConfig,
    LoopConfig,
    TaskConfig,
)
from cfm_jax.references import LeggedReference, as_jax_legged, minimum_jerk
from cfm_jax.tasks.inverse_dynamics import AccelerationOutput, JointSpaceTask


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


# Why a robot whose servos were converted at load time cannot run a legged task.
CONVERTED_REFUSED = (
    "the legged tasks simulate their references from the MJCF file itself, so its servos "
    "must be motors in the file (robot_actuators='torque' converts only the loaded model)"
)


class LeggedTask(JointSpaceTask):
    """Legged locomotion (``walk``, ``jump``; paper section IV-B) for a floating-base robot
    with one MuJoCo contact sensor per foot (data ``found force normal tangent``, as in
    ``robots/solo12.xml``; :func:`cfm_jax.solo12.foot_forces`).

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
      fell within the horizon: :func:`cfm_jax.solo12.fell` with :attr:`FALL_LIMITS`, the
      library's rule :data:`cfm_jax.solo12.FALL`: base below 0.1 m, tilted more than
      0.8 rad, or a base-box corner or knee within 5 mm of the floor; the reference checks
      use the same rule),
      ``base_position_mse``, ``base_orientation_mse``.
    * Baselines: the reference's own controller (its feed-forward torque plus its joint
      PD) as ``oracle``, the joint PD alone as ``pd_only``.

    Args:
      robot: a floating-base :class:`cfm_jax.robots.Robot` with one contact sensor per foot
        and the Solo12's joints and leg geometry (:func:`cfm_jax.solo12.check_model`: the
        references are generated with its leg kinematics); masses, friction and gains may
        differ.
      task: the :class:`cfm_jax.config.TaskConfig`; ``name`` (``walk`` or ``jump``), ``kp``,
        ``kd``, ``joint_kp``, ``joint_kd`` and ``desired`` (``next_velocity``: the authors'
        ``s*``, ``kp = 0`` and ``kd = 1 / control_dt`` on every coordinate) are used. The
        targets and horizons are the references of :mod:`cfm_jax.locomotion` named by
        ``task.motions`` (None: the 5 test references): ``duration`` is not used, and
        ``targets`` and ``home`` must be None.
      control_dt: control period (s), at most :attr:`MAX_CONTROL_DT`.

    Raises:
      ConfigError: the robot has no floating base, no foot contact sensors or legs other
        than the Solo12's, ``control_dt`` is too long, or ``task.targets`` / ``task.home``
        is given.

    Examples:
      >>> from cfm_jax import config, robots
      >>> solo = robots.load("solo12")
      >>> walk = config.for_task("walk")  # control_dt 0.004
      >>> # not run: it builds the 5 references: about 6 s of simulation uncached
      >>> task = LeggedTask(solo, walk.task, walk.task.control_dt)  # doctest: +SKIP
      >>> task.targets, task.steps, task.state_dim, task.desired_dim  # doctest: +SKIP
      (5, 750, 49, 30)
    """

    tracking_name = "base pose tracking MSE"
    tracking_unit = "m | rad"
    output_unit = "(m/s, rad/s)$^2$ and N$^2$"
    metric_names = ("force_mse", "fell", "base_position_mse", "base_orientation_mse")
    MAX_CONTROL_DT = 0.004
    FALL_LIMITS = solo12.FALL  # the rule of the metric ``fell`` and of terminal steps

    def __init__(self, robot, task: TaskConfig, control_dt: float):
        import mujoco

        self.name = task.name
        if not robot.floating_base:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: it needs a "
                "legged robot with a floating base (for example robot='solo12')"
            )
        solo12.check_model(robot.mj_model, robot.name)
        others = getattr(robot, "held_joints", ()) + getattr(robot, "passive_joints", ())
        if others:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: its joints "
                f"{list(others)} have no torque motor of "
                "their own; the legged tasks need every joint below the base driven"
            )
        if getattr(robot, "converted", ()):
            raise ConfigError(f"robot {robot.name!r} is not allowed: {CONVERTED_REFUSED}")
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
        self.robot = robot
        self.sensor_rows = np.concatenate([np.arange(a, a + 10) for a in feet])
        self.feet = len(feet)
        kwargs = dict(control_dt=control_dt, model_file=robot.path)
        if task.name == "walk":
            durations = locomotion.WALK_DURATIONS if task.motions is None else task.motions
            refs = [locomotion.walk_reference(d, **kwargs) for d in durations]
        else:
            heights = locomotion.JUMP_HEIGHTS if task.motions is None else task.motions
            refs = [locomotion.jump_reference(h, **kwargs) for h in heights]
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

    def for_babbling(self, reference):
        """The babbling follows ``reference`` with the references' own joint gains
        (:meth:`with_reference`)."""
        return self.with_reference(reference)

    def _desired_gains(self, task: TaskConfig) -> dict:
        """The gains of the PD correction in ``s*``: ``desired_kp`` and ``desired_kd``,
        ``(6 + joints,)`` float32 (``task.kp``, ``task.kd`` on the 6 base coordinates, then
        ``task.joint_kp``, ``task.joint_kd`` on the actuated joints; None there: ``kp``,
        ``kd``). Not the references' joint PD torque gains ``gain_p``, ``gain_d``, which
        come with the recordings.

        With ``task.desired == "next_velocity"`` (the authors' Solo12 code) ``kp = 0`` and
        ``kd = 1 / control_dt`` on every coordinate: then ``s* = qacc* dt =
        qacc_ref dt + v_ref - v = v_ref(t+1) - v(t)``, the desired next velocity, because
        the recorded ``qacc_ref`` is ``(v_ref(t+1) - v_ref(t)) / dt`` (docs/locomotion.md)."""
        if task.desired == "next_velocity":
            n = 6 + self.robot.action_dim
            return {
                "desired_kp": jnp.zeros(n, jnp.float32),
                "desired_kd": jnp.full(n, 1.0 / self.control_dt, jnp.float32),
            }
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

    def entries(self) -> dict:
        """As :meth:`JointSpaceTask.entries`: the state ``[qpos, foot forces, qvel]``, the
        output ``[qacc dt, foot forces]`` (``velocity_change`` and ``force`` entries)."""
        nq, nv, forces = self.robot.nq, self.robot.nv, 3 * self.feet
        return {
            "state": tuple(("position", i) for i in range(nq))
            + tuple(("force", i) for i in range(forces))
            + tuple(("velocity", i) for i in range(nv)),
            "output": tuple(("velocity_change", i) for i in range(nv))
            + tuple(("force", i) for i in range(forces)),
        }

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
        forces = solo12.foot_forces(rows, xp=jnp)  # (n_sub, feet, 3)
        return jnp.mean(forces, axis=0).reshape(-1)

    def observed(self, step, qpos_next, qvel_next, features_next):
        return jnp.concatenate([qvel_next - step.qvel, features_next])

    def acceleration_output(self):
        """``y[:nv] = control_dt * qacc`` (the foot forces after it are the residual
        network's alone; see :meth:`JointSpaceTask.acceleration_output`)."""
        return AccelerationOutput(tuple(range(self.robot.nv)), self.control_dt)

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        error = self._pose_error(ref_next.qpos, qpos_next)[:6]
        return error * ref_next.active  # beyond the horizon: no error

    def record(self, step, tau, qpos_next, qvel_next, features_next):
        fell = solo12.fell(qpos_next, limits=self.FALL_LIMITS, xp=jnp)
        return {
            "active": step.reference.active > 0,
            "force_error": features_next - step.reference.force,
            "fell": fell,
            "terminal": fell,  # no data from a fallen robot (algorithm.data_mask)
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

    BASE_WEIGHT = 10.0
    """Weight of the base's vertical and angular velocity in the ``norm`` controller loss
    (the authors' public Solo12 code: ``10 mean |v_p[2:6] - v*[2:6]|``)."""

    def loss_weights(self) -> tuple:
        """The default coordinate groups of the ``norm`` controller loss, the authors'
        Solo12 task loss ``|v_p - v*| + |F_p - F*| + 10 |v_p[2:6] - v*[2:6]|``: the whole
        velocity change (``nv`` entries) with weight 1, the foot forces with weight 1 (a norm
        of their own, so newtons and velocities are not summed under one square root), and
        the base's vertical velocity and its three angular velocities (free-joint entries 2
        to 5) again with weight :attr:`BASE_WEIGHT`: those are the coordinates of balance
        (height, roll, pitch, yaw), a few of ``nv``, whose errors a controller would
        otherwise trade for the many joints' tracking.

        Examples:
          >>> # not run: it needs a LeggedTask (see the class's example)
          >>> task.loss_weights()[2]  # doctest: +SKIP
          (10.0, (2, 3, 4, 5))
        """
        nv = self.robot.nv
        return (
            (1.0, tuple(range(nv))),
            (1.0, tuple(range(nv, self.output_dim))),
            (self.BASE_WEIGHT, (2, 3, 4, 5)),
        )

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


def make(robot, task: TaskConfig, control_dt: float, simulator: str = "native") -> LeggedTask:
    """The ``walk`` or ``jump`` task of a config.

    Args:
      robot: a floating-base :class:`cfm_jax.robots.Robot` with the Solo12's feet.
      task: the :class:`cfm_jax.config.TaskConfig` (``name`` ``walk`` or ``jump``).
      control_dt: control period (s).
      simulator: ``"native"`` or ``"mjx"`` (the same task for both: its simulator-specific
        parts, the oracle, are chosen when a rollout asks for them).

    Returns:
      A :class:`LeggedTask`.

    Raises:
      ConfigError: the task does not fit the robot (the message says why).

    Examples:
      >>> from cfm_jax import config, robots
      >>> walk = config.for_task("walk")
      >>> # not run: it builds the 5 references: about 6 s of simulation uncached
      >>> task = make(robots.load("solo12"), walk.task, walk.task.control_dt)  # doctest: +SKIP
      >>> task.targets  # doctest: +SKIP
      5
    """
    return LeggedTask(robot, task, control_dt)


def default_config(name: str = "walk") -> Config:
    """The defaults of the legged task ``name`` (``walk`` or ``jump``; what
    ``Config(task=TaskConfig(name=name))``, the CLI's ``--task`` and
    :func:`cfm_jax.config.for_task` give).

    The paper's quadruped networks (forward model 1000-500-500, a single member; controller
    3 x 300), the Solo12, 250 Hz control (``task.control_dt = 0.004``) and ``home`` initial
    data (the task's PD feedback holding the standing pose plus torque noise, as the authors'
    Solo12 code collects it), and, chosen by the selection run (``experiments/select_defaults.py``,
    docs/results/selection/: all four losses alike, 3 seeds, motions other than the test
    ones, a rule written before it ran, on walking; jumping takes walking's choice): ``s*`` the
    desired next velocity (``task.desired = "next_velocity"``: ``kp = 0``, ``kd = 1 /
    control_dt`` on base and joints, the authors' Solo12 code; the PD form with no feedback,
    the paper's planned accelerations, was clearly worse), the ``rigid_body`` forward model
    (``M^-1 (S tau - h)`` of the robot's own MJCF plus a learned residual, as the authors'
    code; clearly better than the black box), the ``data`` normaliser (statistics of the
    whole data set, recomputed before every refit; in round 2 the ``robot`` and ``babbling``
    normalisers failed far more walks) and fits started ``warm_new_optimizer`` (both networks
    keep their parameters across iterations, Adam is re-created for each fit, as the authors'
    code; better than ``warm`` in both rounds, not clearly); the controller loss keeps the
    ``squared`` form (the ``norm`` form, chosen for the arms, failed more walks and scored
    worse, not clearly); torques scaled by their limits. The choices made one factor at a
    time did not work together on the walks, so a second round of the same rule, from the
    first round's best cell (the ``rigid_body`` forward model), chose the normaliser and the
    fit start again. The earlier legged choices, babbling 4 x 0.3 and the gains ``kp = 100``,
    ``kd = 20`` on the base, ``joint_kp = 2000``, ``joint_kd = 50``, were chosen on pilot
    runs of the joint loss alone; they remain cells of ``experiments/robustness_study.py``,
    not defaults.

    Args:
      name: ``walk`` or ``jump``.

    Returns:
      A :class:`cfm_jax.config.Config`.

    Examples:
      >>> jump = default_config("jump")
      >>> jump.robot, jump.task.control_dt, jump.forward.start, jump.controller.loss_form
      ('solo12', 0.004, 'warm_new_optimizer', 'squared')
    """
    return Config(
        robot="solo12",
        task=TaskConfig(name=name, control_dt=0.004, kp=0.0, kd=0.0, desired="next_velocity"),
        forward=ForwardModelConfig(
            hidden=(1000, 500, 500), ensemble_size=1, kind="rigid_body", start="warm_new_optimizer"
        ),
        controller=ControllerConfig(
            hidden=(300, 300, 300), loss_form="squared", start="warm_new_optimizer"
        ),
        loop=LoopConfig(babbling="home", normaliser="data", torque_scale="limit"),
    )
