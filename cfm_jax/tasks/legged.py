"""The legged tasks (``walk``, ``jump``; paper section IV-B): a floating-base robot tracks
recorded reference motions, with foot contact forces in its state."""

from __future__ import annotations

import functools
import json

import jax.numpy as jnp
import numpy as np

from cfm_jax.config import (
    Config,
    ConfigError,
    ControllerConfig,
    ForwardModelConfig,
    LoopConfig,
    TaskConfig,
)
from cfm_jax.sim import quadruped, solo12
from cfm_jax.tasks import babbling, locomotion
from cfm_jax.tasks.inverse_dynamics import AccelerationOutput, JointSpaceTask
from cfm_jax.tasks.references import LeggedReference, as_jax_legged, minimum_jerk


def _quat_error(target, quat):
    """Rotation vector ``log(quat^-1 target)`` (``mju_subQuat``), in ``quat``'s local frame."""
    w1, v1 = quat[0], -quat[1:]  # conjugate of quat
    w2, v2 = target[0], target[1:]
    w = w1 * w2 - jnp.dot(v1, v2)
    v = w1 * v2 + w2 * v1 + jnp.cross(v1, v2)
    sign = jnp.where(w < 0, -1.0, 1.0)  # the shorter way round
    w, v = sign * w, sign * v
    norm = jnp.sqrt(jnp.sum(v * v) + 1e-24)
    return v * (2.0 * jnp.arctan2(norm, w) / norm)


class LeggedTask(JointSpaceTask):
    """Legged locomotion (``walk``, ``jump``; paper section IV-B; docs/locomotion.md) for a
    quadruped with one contact sensor per foot (:func:`cfm_jax.sim.solo12.foot_forces`; a file
    without them is given them when loaded, :func:`cfm_jax.sim.quadruped.with_foot_sensors`).

    State ``[qpos, f, qvel]`` (``f``: mean foot forces of the last period), output ``[qacc dt, f]``,
    ``qacc* = qacc_ref + kp e + kd (qvel_ref - qvel)``; a fall (:attr:`fall`) is terminal. The
    robot is read through :func:`cfm_jax.tasks.locomotion.legs_of`: the Solo12's closed forms, or
    any quadruped's description, whose references are the Solo12's motions scaled to it and
    simulated on the robot's own model (``robot.mj_model``: a servo-driven quadruped loaded
    with ``robot_actuators='torque'`` runs on its converted motors).

    Args:
      robot: a quadruped :class:`cfm_jax.sim.robots.Robot` (:func:`cfm_jax.sim.quadruped.describe`)
        with a torque motor on each leg joint (servos converted at load time count).
      task: the :class:`cfm_jax.config.TaskConfig`; ``motions`` None: the 5 test references;
        ``duration`` is not used, ``targets`` and ``home`` must be None.
      control_dt: control period (s), at most :attr:`MAX_CONTROL_DT`.

    Raises:
      ConfigError: the robot or ``control_dt`` does not fit, or ``targets``/``home`` is given.

    Examples:
      >>> from cfm_jax import config
      >>> from cfm_jax.sim import robots
      >>> walk = config.for_task("walk").task  # not run below: 5 references, ~6 s uncached
      >>> task = LeggedTask(robots.load("solo12"), walk, walk.control_dt)  # doctest: +SKIP
      >>> task.targets, task.steps, task.state_dim, task.desired_dim  # doctest: +SKIP
      (5, 750, 49, 30)
    """

    tracking_name = "base pose tracking MSE"
    tracking_unit = "m | rad"
    output_unit = "(m/s, rad/s)$^2$ and N$^2$"
    metric_names = ("force_mse", "fell", "base_position_mse", "base_orientation_mse")
    MAX_CONTROL_DT = 0.004

    def __init__(self, robot, task: TaskConfig, control_dt: float):
        self.name = task.name
        if not robot.floating_base:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: it needs a "
                "legged robot with a floating base (for example robot='solo12')"
            )
        others = getattr(robot, "held_joints", ()) + getattr(robot, "passive_joints", ())
        if others:
            raise ConfigError(
                f"task.name={task.name!r} is not allowed for robot {robot.name!r}: its joints "
                f"{list(others)} have no torque motor of "
                "their own; the legged tasks need every joint below the base driven"
            )
        if control_dt > self.MAX_CONTROL_DT + 1e-12:
            raise ConfigError(
                f"task.control_dt={control_dt!r} is not allowed for task {task.name!r}: the "
                f"legged references need {self.MAX_CONTROL_DT} s (250 Hz, the paper's rate) or "
                "a smaller multiple of the robot's timestep"
            )
        self.legs = legs_of(robot, f"task.name={task.name!r} is not allowed for robot")
        for field in ("targets", "home"):
            if getattr(task, field) is not None:
                raise ConfigError(
                    f"task.{field}={getattr(task, field)!r} is not allowed for task "
                    f"{task.name!r}: None (the legged tasks start from and follow their 5 "
                    "recorded references, cfm_jax.tasks.locomotion.WALK_DURATIONS / JUMP_HEIGHTS)"
                )
        self.robot = robot
        self.sensor_rows = np.asarray(self.legs.sensor_rows)  # FL, FR, HL, HR
        self.feet = len(self.legs.foot_geoms)
        self.fall = fall_rule(robot, self.legs)  # the metric ``fell``, and terminal steps
        refs = references(robot, task, control_dt)
        refused = f"task.name={task.name!r} is not allowed for robot {robot.name!r}: "
        check_references(refs, robot, self.legs, refused)
        self.references = refs  # the NumPy recordings (the other tasks' reference_np)
        self.reference = as_jax_legged(refs)
        self.control_dt = float(control_dt)
        self.__dict__.update(self._desired_gains(task))
        # the references' joint PD: one gain (the Solo12's), or one per joint (Legs.of)
        self.gain_p = jnp.asarray(refs[0].kp, jnp.float32)
        self.gain_d = jnp.asarray(refs[0].kd, jnp.float32)
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
        """Follow ``reference`` with the references' own joint gains (:meth:`with_reference`)."""
        return self.with_reference(reference)

    def _desired_gains(self, task: TaskConfig) -> dict:
        """``desired_kp``, ``desired_kd`` ``(6 + joints,)``, the PD gains in ``s*``: ``task.kp``,
        ``task.kd`` on the base, ``task.joint_kp``, ``task.joint_kd`` (None: the base's) on joints;
        with ``next_velocity`` ``kp`` 0 (``task.joint_kp`` on the joints, None: 0) and ``kd``
        ``1 / control_dt``, so ``s* = v_ref(t+1) - v(t) + control_dt joint_kp (q_ref - q)``."""
        if task.desired == "next_velocity":
            joints = self.robot.action_dim
            joint_kp = 0.0 if task.joint_kp is None else float(task.joint_kp)
            return {
                "desired_kp": jnp.asarray([0.0] * 6 + [joint_kp] * joints, jnp.float32),
                "desired_kd": jnp.full(6 + joints, 1.0 / self.control_dt, jnp.float32),
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
        """As :meth:`JointSpaceTask.babbling_reference` from keyframe ``home``, base at rest, no
        feed-forward, the standing forces (:func:`cfm_jax.tasks.babbling.standing_forces`) as
        ``f*``."""
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
        """State ``[position, force, velocity]``, output ``[velocity_change, force]``."""
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

    def configuration(self, state):
        """``(qpos, qvel)`` of states ``[qpos, foot forces, qvel]`` (for ``rigid_body``): the
        whole floating-base configuration, not the arms' driven-joint entries."""
        nq, nv = self.robot.nq, self.robot.nv
        return state[..., :nq], state[..., state.shape[-1] - nv :]

    def acceleration_output(self):
        """``y[:nv] = control_dt * qacc``; the foot forces are the residual network's alone."""
        return AccelerationOutput(tuple(range(self.robot.nv)), self.control_dt)

    def tracking_error(self, ref_next, qpos_next, qvel_next, features_next):
        error = self._pose_error(ref_next.qpos, qpos_next)[:6]
        return error * ref_next.active  # beyond the horizon: no error

    def record(self, step, tau, qpos_next, qvel_next, features_next):
        fell = self.fall(qpos_next, xp=jnp)
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
    """Weight of the base's vertical and angular velocity in the ``norm`` controller loss."""

    def loss_weights(self) -> tuple:
        """The authors' Solo12 ``norm`` loss ``|v_p - v*| + |F_p - F*| + 10 |v_p[2:6] - v*[2:6]|``
        (the forces a norm of their own; height, roll, pitch, yaw again: :attr:`BASE_WEIGHT`)."""
        nv = self.robot.nv
        return (
            (1.0, tuple(range(nv))),
            (1.0, tuple(range(nv, self.output_dim))),
            (self.BASE_WEIGHT, (2, 3, 4, 5)),
        )

    def feedback(self, step):
        """The references' joint PD ``kp (q_ref - q) + kd (qd_ref - qd)``."""
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


def legs_of(robot, refused: str = "the legged tasks cannot use robot") -> locomotion.Legs:
    """The :class:`cfm_jax.tasks.locomotion.Legs` the references of ``robot`` are made with.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      refused: the start of the error's message.

    Raises:
      ConfigError: ``robot`` is not a quadruped with a torque motor per joint and a contact
        sensor per foot; the message says what was found.

    Examples:
      >>> legs_of(cfm_jax.sim.robots.load("solo12")).kp  # the Solo12's closed forms
      5.0
    """
    try:
        return locomotion.legs_of(robot.mj_model)
    except quadruped.QuadrupedError as error:
        raise ConfigError(f"{refused} {robot.name!r}: {error}") from None


def references(robot, task: TaskConfig, control_dt: float) -> list:
    """The reference recordings ``task`` follows on ``robot``, simulated on the task's model
    (servos converted, ground and foot sensors added), cached.

    Args:
      robot: a quadruped :class:`cfm_jax.sim.robots.Robot`.
      task: the :class:`cfm_jax.config.TaskConfig` (``walk`` or ``jump``; its motions).
      control_dt: control period (s).

    Examples:
      >>> solo = cfm_jax.sim.robots.load("solo12")
      >>> walk = TaskConfig(name="walk", motions=(0.5,))
      >>> [ref.horizon for ref in references(solo, walk, 0.004)]
      [125]
    """
    kwargs = dict(control_dt=control_dt, model=robot.mj_model)
    if task.motion_family == "selection":
        kwargs.update(locomotion.SELECTION_MOTIONS[task.name])
    if task.name == "walk":
        durations = locomotion.WALK_DURATIONS if task.motions is None else task.motions
        return [locomotion.walk_reference(d, **kwargs) for d in durations]
    heights = locomotion.JUMP_HEIGHTS if task.motions is None else task.motions
    return [locomotion.jump_reference(h, **kwargs) for h in heights]


def check_references(refs, robot, legs: locomotion.Legs, refused: str = "") -> None:
    """Refuse references that fall by the robot's own :func:`fall_rule` (judged on their
    recorded poses and foot forces): tracking one perfectly would count as a fall.

    Args:
      refs: the :class:`cfm_jax.tasks.locomotion.LocomotionReference` recordings.
      robot: the quadruped :class:`cfm_jax.sim.robots.Robot` they were made on.
      legs: its :class:`cfm_jax.tasks.locomotion.Legs`.
      refused: the start of the error's message (before "its ... reference falls").

    Raises:
      ConfigError: the first reference that falls: which, at which control step, and
        which of the rule's clauses it breaks.

    Examples:
      >>> solo = cfm_jax.sim.robots.load("solo12")
      >>> walks = [locomotion.walk_reference(1.0)]
      >>> check_references(walks, solo, legs_of(solo))  # no fall: nothing raised
    """
    terms_of = fall_terms(robot, legs)
    for ref in refs:
        terms = terms_of(ref.qpos, ref.foot_force)
        fallen = np.any(np.stack(list(terms.values())), axis=0)
        if not fallen.any():
            continue
        step = int(np.argmax(fallen))
        broken = [what for what, where in terms.items() if where[step]]
        params = json.loads(ref.params)
        motion = (
            f"{params['duration']:g}-s walk" if ref.kind == "walk" else
            f"{params['height']:g}-m jump"
        )  # fmt: skip
        raise ConfigError(
            f"{refused}its {motion} reference falls by the robot's own "
            f"fall rule at control step {step} of {ref.horizon} ({'; '.join(broken)}): the "
            f"reference generator's {ref.kind} (joint PD along planned foot paths, no balance "
            "feedback) does not keep this robot up, and a controller tracking it would be "
            "counted as fallen"
        )


def _solo12_kinematics(robot) -> bool:
    """Whether ``robot``'s model has the Solo12's kinematics (:func:`solo12.check_model`)."""
    try:
        solo12.check_model(robot.mj_model, robot.name)
    except ConfigError:
        return False
    return True


def fall_terms(robot, legs: locomotion.Legs):
    """``terms(qpos, foot_force=None, xp=np)``: :func:`fall_rule`'s clauses one by one.

    Args:
      robot: a quadruped :class:`cfm_jax.sim.robots.Robot`.
      legs: its :class:`cfm_jax.tasks.locomotion.Legs` (:func:`legs_of`).

    Examples:
      >>> solo = cfm_jax.sim.robots.load("solo12")
      >>> terms = fall_terms(solo, legs_of(solo))(solo.home)
      >>> len(terms), any(terms.values())
      (3, False)
    """
    if _solo12_kinematics(robot):
        return functools.partial(solo12.fall_terms, limits=solo12.FALL)
    return quadruped.fall_rule(quadruped.describe(robot.mj_model), legs.scale).terms


def fall_rule(robot, legs: locomotion.Legs):
    """``fell(qpos, foot_force=None, xp=np)`` of ``robot``: the Solo12's
    :func:`cfm_jax.sim.solo12.fell` (:data:`cfm_jax.sim.solo12.FALL`) where its kinematics are the
    Solo12's, else the same rule read from the robot's model
    (:func:`cfm_jax.sim.quadruped.fall_rule`, lengths scaled by ``legs.scale``).

    Args:
      robot: a quadruped :class:`cfm_jax.sim.robots.Robot`.
      legs: its :class:`cfm_jax.tasks.locomotion.Legs` (:func:`legs_of`).

    Examples:
      >>> solo = cfm_jax.sim.robots.load("solo12")
      >>> bool(fall_rule(solo, legs_of(solo))(solo.home))
      False
    """
    if _solo12_kinematics(robot):
        return functools.partial(solo12.fell, limits=solo12.FALL)
    return quadruped.fall_rule(quadruped.describe(robot.mj_model), legs.scale)


def fits(robot, name: str = "walk") -> str:
    """Whether the legged task ``name`` runs on ``robot``: a quadruped whose default walks do
    not fall (:func:`check_references`), or some of whose jumps land.

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      name: ``walk`` or ``jump``.

    Returns:
      ``""``, or a note where the task runs but not with its defaults.

    Raises:
      ConfigError: no floating base, or not a quadruped with a torque motor per joint (servos
        converted at load time count) and a contact sensor per foot, or a default reference
        that falls.

    Examples:
      >>> fits(cfm_jax.sim.robots.load("solo12"))
      ''
    """
    if not robot.floating_base:
        raise ConfigError("the legged tasks need a floating base (a free joint at the root)")
    legs = legs_of(robot)
    task = default_config(name).task
    if name == "walk":  # the five walks: seconds to generate (cached for training)
        check_references(references(robot, task, task.control_dt), robot, legs)
    elif locomotion.largest_landed_jump(legs, task.control_dt) <= 0.0:
        # The jumps are sized to what lands (jump_height_scale); building them takes a
        # minute, so they are judged one by one where the task builds them (LeggedTask).
        raise ConfigError(
            "no jump of the reference controller lands by the robot's own fall rule (push "
            f"forces from a quarter of its weight to three times it, {locomotion.LANDED_SCAN} "
            "tried), so there is no jump reference to learn"
        )
    if robot.mjx_error is not None:  # the defaults' rigid-body forward model runs on MJX
        return (
            "not with its defaults: forward.kind='rigid_body' needs MJX, which cannot build "
            "this model (see above); forward.kind='mlp' runs on the native simulator"
        )
    return ""


def make(robot, task: TaskConfig, control_dt: float, simulator: str = "native") -> LeggedTask:
    """The ``walk`` or ``jump`` task of a config.

    Args:
      robot: a floating-base :class:`cfm_jax.sim.robots.Robot` with the Solo12's feet.
      task: the :class:`cfm_jax.config.TaskConfig` (``name`` ``walk`` or ``jump``).
      control_dt: control period (s).
      simulator: ``"native"`` or ``"mjx"``: the same task serves both.

    Raises:
      ConfigError: the task does not fit the robot (the message says why).

    Examples:
      >>> from cfm_jax import config
      >>> from cfm_jax.sim import robots
      >>> walk = config.for_task("walk").task  # not run below: 5 references, ~6 s uncached
      >>> make(robots.load("solo12"), walk, walk.control_dt).targets  # doctest: +SKIP
      5
    """
    return LeggedTask(robot, task, control_dt)


WALK_JOINT_KP = 1000.0
"""The walk's joint position feedback in ``s*`` (1/s^2, ``task.joint_kp``): chosen by the
selection run's second walk check (docs/results/selection/); the jump has none."""


def default_config(name: str = "walk") -> Config:
    """The defaults of the legged task ``name`` (what :func:`cfm_jax.config.for_task` gives).

    The paper's networks, 250 Hz, ``home`` babbling, and what the selection run chose (``s*``,
    the walk's joint position feedback in it, forward model, normaliser, fit start, loss form;
    docs/results/selection/).

    Args:
      name: ``walk`` or ``jump``.

    Examples:
      >>> jump = default_config("jump")
      >>> jump.robot, jump.task.control_dt, jump.forward.start, jump.controller.loss_form
      ('solo12', 0.004, 'warm_new_optimizer', 'squared')
    """
    joint_kp = WALK_JOINT_KP if name == "walk" else None
    return Config(
        robot="solo12",
        task=TaskConfig(
            name=name, control_dt=0.004, kp=0.0, kd=0.0, joint_kp=joint_kp, desired="next_velocity"
        ),
        forward=ForwardModelConfig(
            hidden=(1000, 500, 500), ensemble_size=1, kind="rigid_body", start="warm_new_optimizer"
        ),
        controller=ControllerConfig(
            hidden=(300, 300, 300), loss_form="squared", start="warm_new_optimizer"
        ),
        loop=LoopConfig(babbling="home", normaliser="data", torque_scale="limit"),
    )
