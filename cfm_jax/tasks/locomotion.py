"""Walk and jump references, recorded from a whole-body controller in MuJoCo (in place of the
paper's planner; docs/locomotion.md): :func:`walk_reference`, :func:`jump_reference`, their
on-disk cache, and the checks that replay them (:func:`replay`). The controller reads the
robot through :class:`Legs`: the Solo12's closed forms, or any motor-driven quadruped's
description (:mod:`cfm_jax.sim.quadruped`) with the Solo12's motions scaled to its size; a
quadruped driven by servos runs on the torque motors :func:`cfm_jax.sim.robots.load` converts
them to (``actuators="torque"``), the references simulated on that loaded model."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from cfm_jax._files import atomic_path
from cfm_jax.sim import solo12

CONTROL_DT = 0.004  # 250 Hz, the paper's authors' control rate

CACHE_ENV = "CFM_JAX_REFERENCE_CACHE"
_FORMAT_VERSION = 1

# ---- references ------------------------------------------------------------------------------


class LocomotionReference(NamedTuple):
    """A reference motion of ``T`` control steps; index ``t`` is time ``t * control_dt``.

    Attributes:
      control_dt: the control period (s).
      qpos: ``(T+1, 19)`` positions.
      qvel: ``(T+1, 18)`` velocities.
      qacc: ``(T, 18)`` mean acceleration of period ``t``, ``(qvel[t+1] - qvel[t]) / control_dt``.
      tau: ``(T, 12)`` joint torque held in period ``t``: the feed-forward.
      foot_force: ``(T+1, 4, 3)`` floor force on each foot (world, N), state ``t`` under ``tau[t]``.
      foot_force_mean: ``(T, 4, 3)`` that force's mean over the physics steps of period ``t``.
      contact: ``(T+1, 4)`` bool, the foot touches the floor.
      kp: joint gain (N m/rad) of the feedback ``tau[t] + kp (q_ref - q) + kd (qd_ref - qd)``:
        one for all joints (the Solo12's), or one per joint ``(12,)`` (:meth:`Legs.of`).
      kd: its derivative gain (N m s/rad), likewise.
      kind: ``"walk"`` or ``"jump"``.
      params: the :class:`WalkParams` or :class:`JumpParams` used, as JSON.

    Examples:
      >>> walk_reference(0.2, use_cache=False).foot_force_mean.shape  # 50 steps of 0.004 s
      (50, 4, 3)
    """

    control_dt: float
    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    tau: np.ndarray
    foot_force: np.ndarray
    foot_force_mean: np.ndarray
    contact: np.ndarray
    kp: float | np.ndarray
    kd: float | np.ndarray
    kind: str
    params: str

    @property
    def horizon(self) -> int:
        return len(self.tau)

    @property
    def duration(self) -> float:
        return self.horizon * self.control_dt

    @property
    def desired_next(self) -> np.ndarray:
        """The paper's ``s*_{t+1}``, ``[qacc[t] * control_dt, foot_force[t+1]]``, ``(T, 30)``."""
        return np.concatenate(
            [self.qacc * self.control_dt, self.foot_force[1:].reshape(self.horizon, 12)], axis=1
        )


class PhysicsRecording(NamedTuple):
    """Every physics step of a reference run, ``K`` steps; entry ``K`` is the final state.

    Attributes:
      qpos: ``(K+1, 19)`` positions before each step.
      qvel: ``(K+1, 18)`` velocities before each step.
      qacc: ``(K, 18)`` the acceleration MuJoCo integrated in step ``k``.
      tau: ``(K, 12)`` the joint torque held in step ``k``.
      sensordata: ``(K+1, nsensordata)`` sensors before step ``k``, ``tau[k]`` applied.

    Examples:
      >>> simulate_walk(WalkParams(duration=0.2))[1].sensordata.shape  # 2 physics steps a period
      (101, 40)
    """

    qpos: np.ndarray  # (K+1, 19)
    qvel: np.ndarray  # (K+1, 18)
    qacc: np.ndarray  # (K, 18)
    tau: np.ndarray  # (K, 12)
    sensordata: np.ndarray  # (K+1, nsensordata), like qpos


@dataclasses.dataclass(frozen=True)
class WalkParams:
    """Trot: diagonal pairs (FL+HR, FR+HL) alternate, feet placed by the legs' IK (:class:`Legs`).

    Attributes:
      duration: length of the reference (s), standing included.
      speed: cruise forward speed (m/s).
      period: gait cycle (s); each pair swings for half of it.
      swing_height: apex of a swinging foot above its stance height (m).
      height: commanded base height (m).
      ramp: time (s) over which the speed ramps linearly from 0 to ``speed``.
      stand: time (s) of standing before the first step.

    Examples:
      >>> round(commanded_distance(WalkParams(duration=1.0)), 3)
      0.18
    """

    duration: float = 2.0
    speed: float = 0.3
    period: float = 0.3
    swing_height: float = 0.05
    height: float = 0.24
    ramp: float = 0.6
    stand: float = 0.1  # s of standing before the first step


@dataclasses.dataclass(frozen=True)
class JumpParams:
    """Vertical jump: settle, crouch, push (``-J^T f`` per foot plus posture PD), fly, land, stand.

    Attributes:
      height: requested foot clearance (lowest foot bottom above the floor) at the apex (m).
      duration: length of the reference (s).
      settle: time (s) of standing before the crouch.
      crouch: time (s) of the crouch.
      crouch_height: base origin height at the bottom of the crouch (m).
      extension: foot-to-hip depth (m) at which the push ends.
      push_force: vertical ground force per foot in the push (N); None: bisected to ``height``.
      stand_depth: foot-to-hip depth (m) when standing (settle, flight, landing); None: the
        nominal stance of :func:`cfm_jax.sim.solo12.hip_positions` (0.223 m).

    Examples:
      >>> round(jump_clearance(simulate_jump(JumpParams(duration=0.8, push_force=30.0))[0]), 2)
      0.19
    """

    height: float = 0.1
    duration: float = 1.5
    settle: float = 0.1
    crouch: float = 0.3
    crouch_height: float = 0.17
    extension: float = 0.27
    push_force: float | None = None
    stand_depth: float | None = None


def _total_mass(model) -> float:
    return float(np.sum(model.body_mass))


def _joint_inertia(model, qpos) -> np.ndarray:
    """Each joint's effective inertia at ``qpos``: the diagonal of the joint-space mass
    matrix (armature included) over the joint vector ``qvel[6:]``, the other joints and
    the base held."""
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return np.diag(full)[6:].copy()


SOLO12_STANDING_HEIGHT = 0.2384
"""Base height (m) of the Solo12's keyframe ``home``: the length the references' parameters
(:class:`WalkParams`, :class:`JumpParams`) are given in, scaled for another quadruped."""


@dataclasses.dataclass(frozen=True)
class Legs:
    """What the reference controllers use of a quadruped: its legs' kinematics, gains and
    foot sensors. :meth:`solo12` gives the Solo12's closed forms (its facts sheet);
    :meth:`of` reads any motor-driven quadruped (:func:`cfm_jax.sim.quadruped.describe`) and
    gives each of its joints the Solo12's closed-loop dynamics at the robot's size.

    Attributes:
      model: the ``mujoco.MjModel``, with one contact sensor per foot
        (:func:`cfm_jax.sim.quadruped.with_foot_sensors`).
      nominal: the feet at the standing pose, base frame, ``(4, 3)``.
      foot_radius: each foot's radius ``(4,)`` (m).
      kp: the joints' PD gain (N m/rad): one for all joints, or one per joint ``(12,)``
        (joint vector order, ``qvel[6:]``).
      kd: its derivative gain (N m s/rad), likewise.
      scale: the robot's standing height over the Solo12's (:data:`SOLO12_STANDING_HEIGHT`).
      ik: ``ik(foot, leg)``: the leg's joints that put its foot centre at ``foot``.
      fk: ``fk(joints, leg)``: the leg's foot centre, base frame.
      sites: the Solo12's foot sites (Jacobians of the foot centre), or None: the foot geoms.
      foot_geoms: each foot's geom id.
      dofs: ``(4, 3)`` each leg's joints as indices into the joint vector (``qvel[6:]``).
      motors: the actuator of each joint, ``(nu,)``.
      sensor_rows: the four feet's contact sensor rows of ``sensordata``, ``(40,)``.
      key: the keyframe the references start from, or None (``standing``).
      standing: the standing pose, ``qpos (nq,)``.

    Examples:
      >>> legs = Legs.solo12()
      >>> legs.nominal.shape, legs.dofs[1].tolist()  # FR's joints: the 4th to 6th
      ((4, 3), [3, 4, 5])
    """

    model: object
    nominal: np.ndarray
    foot_radius: np.ndarray
    kp: float | np.ndarray
    kd: float | np.ndarray
    scale: float
    ik: object
    fk: object
    sites: list | None
    foot_geoms: list
    dofs: np.ndarray
    motors: np.ndarray
    sensor_rows: np.ndarray
    key: int | None
    standing: np.ndarray

    @classmethod
    def solo12(cls, model=None) -> Legs:
        """The Solo12's legs: its closed-form kinematics, gains and foot sites.

        Examples:
          >>> Legs.solo12().kp, Legs.solo12().scale
          (5.0, 1.0)
        """
        model = model if model is not None else solo12.load_model()
        key = model.key("home").id
        return cls(
            model=model,
            nominal=solo12.hip_positions(),
            foot_radius=np.full(4, solo12.FOOT_RADIUS),
            kp=solo12.KP,
            kd=solo12.KD,
            scale=1.0,
            ik=solo12.leg_ik,
            fk=solo12.leg_fk,
            sites=[model.site(f"{leg}_foot").id for leg in solo12.LEGS],
            foot_geoms=[model.geom(f"{leg}_foot").id for leg in solo12.LEGS],
            dofs=np.arange(12).reshape(4, 3),
            motors=np.arange(12),
            sensor_rows=np.arange(4 * solo12.SENSOR_SLOT),
            key=key,
            standing=np.array(model.key_qpos[key]),
        )

    @classmethod
    def of(cls, model) -> Legs:
        """Any motor-driven quadruped's legs: numeric kinematics on MuJoCo's Jacobians, and
        per joint the Solo12's gains at the same place in the leg (knee, hip, abduction).
        ``kp = max(KP M g L / (M g L)_solo, KP (I / I_solo) / scale)`` (load; natural
        frequency at the robot's time scale), ``I`` the joint-space mass matrix's diagonal
        at the standing pose; ``kd + b = KD sqrt(kp I / (KP I_solo))``, ``b`` the passive
        ``dof_damping``, ``kd >= 0``. On the Solo12 these are its ``KP`` and ``KD``.

        Args:
          model: a ``mujoco.MjModel`` with one contact sensor per foot on the ground
            (:func:`cfm_jax.sim.quadruped.with_foot_sensors`) and a torque motor on each joint
            (any gear; servos converted by :func:`cfm_jax.sim.robots.convert` are such motors).

        Raises:
          cfm_jax.sim.quadruped.QuadrupedError: not a quadruped, a joint without its own motor
            (a servo: load the robot with ``robot_actuators='torque'``), or a foot without
            a contact sensor.

        Examples:
          >>> from cfm_jax.sim import quadruped
          >>> legs = Legs.of(quadruped.with_foot_sensors(solo12.model_path())[0])
          >>> set(legs.kp.tolist()), set(legs.kd.tolist()), legs.scale  # the Solo12's own
          ({5.0}, {0.1}, 1.0)
        """
        import mujoco

        from cfm_jax.sim import quadruped

        found = quadruped.describe(model)
        solo = solo12.load_model()
        reference = quadruped.describe(solo)
        scale = found.standing_height / SOLO12_STANDING_HEIGHT
        g = float(-model.opt.gravity[2])

        def load(robot, mass):  # the body's load on a joint: M g L
            return mass * g * float(np.mean([leg.length for leg in robot.legs]))

        similar = load(found, _total_mass(model)) / load(reference, _total_mass(solo))
        # Each joint against the Solo12's joint at its place from the foot, of the same leg.
        inertia = _joint_inertia(model, found.standing)
        inertia0 = _joint_inertia(solo, reference.standing)
        solo_inertia = np.zeros(model.nv - 6)
        for leg, leg0 in zip(found.legs, reference.legs, strict=True):
            n0 = len(leg0.dofs)
            for j, dof in enumerate(leg.dofs):
                solo_inertia[dof - 6] = inertia0[leg0.dofs[max(n0 - len(leg.dofs) + j, 0)] - 6]
        kp = solo12.KP * np.maximum(similar, inertia / solo_inertia / scale)
        damping = solo12.KD * np.sqrt(kp * inertia / (solo12.KP * solo_inertia))
        kd = np.maximum(damping - model.dof_damping[6:], 0.0)
        motors, servos = np.full(model.nv - 6, -1), set()
        for a in range(model.nu):
            if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                continue
            dof = int(model.jnt_dofadr[model.actuator_trnid[a, 0]]) - 6
            if model.actuator_biastype[a] != 0 or model.actuator_gainprm[a, 0] != 1.0:
                servos.add(dof)  # a servo, not a torque motor
                continue
            motors[dof] = a
        if (motors < 0).any():
            missing = np.where(motors < 0)[0]
            names = [model.joint(int(model.dof_jntid[6 + i])).name for i in missing]
            hint = (
                " (servos: load it with robot_actuators='torque')"
                if servos & set(missing.tolist())
                else "; each leg joint needs one"
            )
            raise quadruped.QuadrupedError(
                f"its joints {names} have no torque motor of their own{hint}"
            )
        contact = int(mujoco.mjtSensor.mjSENS_CONTACT)
        rows = []
        for leg in found.legs:
            sensors = [
                i
                for i in range(model.nsensor)
                if int(model.sensor_type[i]) == contact
                and int(model.sensor_dim[i]) == 10
                and int(model.sensor_objid[i]) == leg.foot_id
            ]
            if not sensors:
                raise quadruped.QuadrupedError(
                    f"its {leg.name} foot has no contact sensor (quadruped.with_foot_sensors)"
                )
            rows.append(np.arange(model.sensor_adr[sensors[0]], model.sensor_adr[sensors[0]] + 10))

        names = [model.key(k).name for k in range(model.nkey)]
        key = names.index("home") if "home" in names else (0 if names else None)
        return cls(
            model=model,
            nominal=found.feet,
            foot_radius=np.array([leg.foot_radius for leg in found.legs]),
            kp=kp,
            kd=kd,
            scale=scale,
            ik=lambda foot, leg: found.leg_ik(leg, foot),
            fk=lambda joints, leg: found.foot_position(leg, joints),
            sites=None,
            foot_geoms=[leg.foot_id for leg in found.legs],
            dofs=np.array([[d - 6 for d in leg.dofs] for leg in found.legs]),
            motors=motors,
            sensor_rows=np.concatenate(rows),
            key=key,
            standing=found.standing,
        )

    def contact(self, sensordata, xp=np):
        """Whether each foot touches the ground, ``(..., 4)``."""
        return solo12.foot_contact(sensordata[..., self.sensor_rows], xp=xp)

    def forces(self, sensordata, xp=np):
        """The ground's force on each foot, world frame, ``(..., 4, 3)`` (N)."""
        return solo12.foot_forces(sensordata[..., self.sensor_rows], xp=xp)


def legs_of(model) -> Legs:
    """The :class:`Legs` of ``model``: the Solo12's closed forms where its kinematics are the
    Solo12's (:func:`cfm_jax.sim.solo12.check_model`), else :meth:`Legs.of`.

    Args:
      model: a ``mujoco.MjModel`` of a quadruped with its foot contact sensors.

    Examples:
      >>> legs_of(solo12.load_model()).sites is not None  # the Solo12's foot sites
      True
    """
    from cfm_jax.config import ConfigError

    try:
        solo12.check_model(model)
    except ConfigError:
        return Legs.of(model)
    return Legs.solo12(model)


def _torque_limits(model, motors) -> np.ndarray:
    """Each motor's joint torque limit (N m): the tightest of its ``ctrlrange`` and
    ``forcerange`` times its gear and its joint's ``actuatorfrcrange``
    (:func:`cfm_jax.sim.robots.actuator_torque_limit`), infinite where none is given."""
    from cfm_jax.sim import robots

    bounds = [robots.actuator_torque_limit(model, int(a)) for a in motors]
    return np.array([np.inf if bound is None else bound[0] for bound in bounds])


class _Sim:
    """MuJoCo simulation at the control rate with per-physics-step recording."""

    def __init__(self, legs: Legs, control_dt: float):
        import mujoco

        self.mj = mujoco
        self.legs = legs
        self.m = model = legs.model
        self.d = mujoco.MjData(model)
        n_sub = control_dt / model.opt.timestep
        if abs(n_sub - round(n_sub)) > 1e-9:
            raise ValueError(
                f"control_dt {control_dt} is not a whole number of physics steps "
                f"({model.opt.timestep})"
            )
        self.n_sub = int(round(n_sub))
        self.control_dt = control_dt
        if legs.key is not None:
            mujoco.mj_resetDataKeyframe(model, self.d, legs.key)
        else:
            self.d.qpos[:] = legs.standing
        mujoco.mj_forward(model, self.d)
        self.jac = np.zeros((3, model.nv))
        self.rec = {k: [] for k in ("qpos", "qvel", "qacc", "tau", "sensordata")}
        self.gear = model.actuator_gear[legs.motors, 0].copy()
        self.limit = _torque_limits(model, legs.motors)

    @property
    def q(self):
        return self.d.qpos[7:]

    @property
    def qd(self):
        return self.d.qvel[6:]

    def contact(self):
        return self.legs.contact(self.d.sensordata)

    def leg_jacobian(self, leg: int) -> np.ndarray:
        """3x3 world-frame Jacobian of the foot centre w.r.t. the leg's joints."""
        if self.legs.sites is not None:
            self.mj.mj_jacSite(self.m, self.d, self.jac, None, self.legs.sites[leg])
        else:
            self.mj.mj_jacGeom(self.m, self.d, self.jac, None, self.legs.foot_geoms[leg])
        return self.jac[:, 6 + self.legs.dofs[leg]].copy()

    def ff_force(self, forces) -> np.ndarray:
        """Joint torques ``-J^T f`` producing the ground forces ``forces (4, 3)`` (world)."""
        tau = np.zeros(12)
        for leg in range(4):
            if np.any(forces[leg]):
                tau[self.legs.dofs[leg]] = -self.leg_jacobian(leg).T @ forces[leg]
        return tau

    def step(self, tau):
        tau = np.clip(tau, -self.limit, self.limit)
        self.d.ctrl[self.legs.motors] = tau / self.gear
        for _ in range(self.n_sub):
            self.rec["qpos"].append(self.d.qpos.copy())
            self.rec["qvel"].append(self.d.qvel.copy())
            self.mj.mj_step(self.m, self.d)
            self.rec["qacc"].append(self.d.qacc.copy())
            self.rec["tau"].append(tau.copy())
            self.rec["sensordata"].append(self.d.sensordata.copy())
        self.mj.mj_forward(self.m, self.d)  # kinematics and sensors of the new state

    def recording(self) -> PhysicsRecording:
        return PhysicsRecording(
            qpos=np.array(self.rec["qpos"] + [self.d.qpos.copy()]),
            qvel=np.array(self.rec["qvel"] + [self.d.qvel.copy()]),
            qacc=np.array(self.rec["qacc"]),
            tau=np.array(self.rec["tau"]),
            sensordata=np.array(self.rec["sensordata"] + [self.d.sensordata.copy()]),
        )


def _to_reference(rec: PhysicsRecording, legs: Legs, n_sub, control_dt, kind, params):
    k = len(rec.tau)
    steps = k // n_sub
    idx = np.arange(steps + 1) * n_sub
    force = legs.forces(rec.sensordata)  # (K+1, 4, 3); entry K is the final state's
    qvel = rec.qvel[idx]
    return LocomotionReference(
        control_dt=control_dt,
        qpos=rec.qpos[idx],
        qvel=qvel,
        qacc=(qvel[1:] - qvel[:-1]) / control_dt,
        tau=rec.tau[idx[:-1]],
        foot_force=force[idx],
        foot_force_mean=force[:k].reshape(steps, n_sub, 4, 3).mean(axis=1),
        contact=legs.contact(rec.sensordata)[idx],
        kp=legs.kp,
        kd=legs.kd,
        kind=kind,
        params=json.dumps(params, sort_keys=True),
    )


def _stance_feedforward(sim: _Sim, stance: np.ndarray, weight: float) -> np.ndarray:
    n = int(stance.sum())
    forces = np.zeros((4, 3))
    if n:
        forces[stance, 2] = weight / n
    return sim.ff_force(forces)


def simulate_walk(params: WalkParams, model=None, control_dt: float = CONTROL_DT, legs=None):
    """Run the trot controller from the standing pose: ``(LocomotionReference, PhysicsRecording)``.
    Its feed-forward carries the stance feet's share of the weight and, on joints with
    passive damping or dry friction (none on the Solo12), their torque along the plan.

    Args:
      params: the :class:`WalkParams` (lengths and times of the Solo12; another robot's are
        scaled by :attr:`Legs.scale`, times by its square root).
      model: the ``mujoco.MjModel`` (None: :func:`cfm_jax.sim.solo12.load_model`).
      control_dt: control period (s), a whole number of physics steps.
      legs: the robot's :class:`Legs` (None: :func:`legs_of` ``model``).

    Raises:
      ValueError: ``control_dt`` is not a whole number of physics steps.

    Examples:
      >>> ref, rec = simulate_walk(WalkParams(duration=0.2))
      >>> ref.horizon, len(rec.tau)
      (50, 100)
    """
    if legs is None:
        legs = legs_of(model if model is not None else solo12.load_model())
    model = legs.model
    sim = _Sim(legs, control_dt)
    weight = _total_mass(model) * -model.opt.gravity[2]
    nominal = legs.nominal
    length, clock = legs.scale, np.sqrt(legs.scale)  # dynamic similarity to the Solo12
    half = params.period * clock / 2
    stand, ramp = params.stand * clock, params.ramp * clock
    height, swing = params.height * length, params.swing_height * length
    cruise = params.speed * length / clock
    steps = int(round(params.duration / control_dt))

    def plan(t):
        """The joint targets and the feet in stance at time ``t``."""
        tw = t - stand  # walking clock
        speed = cruise * np.clip(tw / ramp, 0.0, 1.0) if tw > 0 else 0.0
        targets = np.zeros(12)
        stance = np.ones(4, bool)
        for leg in range(4):
            foot = nominal[leg].copy()
            foot[2] = -height + legs.foot_radius[leg]  # depth of the foot centre below the base
            if tw > 0:
                pair = 0 if leg in (0, 3) else 1
                phase = ((tw / half) + pair) % 2.0  # [0, 1): swing, [1, 2): stance
                stride = speed * half  # base travel during one stance phase
                if phase < 1.0:
                    s = phase
                    foot[0] += stride * (s - 0.5)
                    foot[2] += swing * np.sin(np.pi * s)
                    stance[leg] = False
                else:
                    s = phase - 1.0
                    foot[0] += stride * (0.5 - s)
            targets[legs.dofs[leg]] = legs.ik(foot, leg)
        return targets, stance

    # The joints' passive torques along the planned motion (none on the Solo12): viscous
    # damping at the targets' velocity and dry friction against their direction.
    damping, friction = model.dof_damping[6:], model.dof_frictionloss[6:]
    passive = bool(damping.any() or friction.any())
    targets, stance = plan(0.0)
    for step in range(steps):
        # the first half-cycle: pair 1 (FR+HL) starts in stance, pair 0 swings
        tau = legs.kp * (targets - sim.q) - legs.kd * sim.qd
        tau += _stance_feedforward(sim, stance, weight)
        upcoming = plan((step + 1) * control_dt)
        if passive:
            velocity = (upcoming[0] - targets) / control_dt
            tau += damping * velocity + friction * np.sign(velocity)
        sim.step(tau)
        targets, stance = upcoming
    rec = sim.recording()
    ref = _to_reference(rec, legs, sim.n_sub, control_dt, "walk", dataclasses.asdict(params))
    return ref, rec


def _jump_run(params: JumpParams, push_force: float, legs: Legs, control_dt):
    sim = _Sim(legs, control_dt)
    model = legs.model
    weight = _total_mass(model) * -model.opt.gravity[2]
    nominal = legs.nominal
    length, clock = legs.scale, np.sqrt(legs.scale)  # dynamic similarity to the Solo12
    radius = float(np.max(legs.foot_radius))
    stand_depth = -nominal[0, 2] if params.stand_depth is None else params.stand_depth * length
    crouch_depth = params.crouch_height * length - radius
    settle, crouch = params.settle * clock, params.crouch * clock
    extension = params.extension * length
    steps = int(round(params.duration / control_dt))
    phase = "settle"
    t_phase = 0.0
    for step in range(steps):
        t = step * control_dt
        contact = sim.contact()
        if phase == "settle" and t >= settle:
            phase, t_phase = "crouch", t
        if phase == "crouch" and t - t_phase >= crouch:
            phase, t_phase = "push", t
        if phase == "push":
            depth = np.mean([-legs.fk(sim.q[legs.dofs[i]], i)[2] for i in range(4)])
            if depth >= extension or not contact.any():
                phase, t_phase = "flight", t
        if phase == "flight" and t - t_phase > 0.02 and contact.any():
            phase, t_phase = "land", t
        if phase in ("settle", "flight", "land"):
            depth = stand_depth
        elif phase == "crouch":
            s = 0.5 - 0.5 * np.cos(np.pi * min((t - t_phase) / crouch, 1.0))
            depth = stand_depth + s * (crouch_depth - stand_depth)
        else:  # push: hold the lateral posture, legs extend under the force
            depth = extension
        targets = np.zeros(12)
        for i in range(4):
            targets[legs.dofs[i]] = legs.ik(nominal[i] * [1, 1, 0] + [0, 0, -depth], i)
        tau = legs.kp * (targets - sim.q) - legs.kd * sim.qd
        if phase == "push":
            abduction = np.zeros(12)
            abduction[legs.dofs[:, 0]] = 1.0  # only the first joint of each leg holds
            tau = legs.kp * (targets - sim.q) * abduction - legs.kd * sim.qd
            forces = np.zeros((4, 3))
            forces[:, 2] = push_force
            tau = tau + sim.ff_force(forces)
        elif phase != "flight":
            tau += _stance_feedforward(sim, contact if contact.any() else np.ones(4, bool), weight)
        sim.step(tau)
    return sim


def jump_clearance(ref_or_rec, legs: Legs | None = None) -> float:
    """Largest foot clearance (m): max over time of the lowest foot bottom above the floor.

    Args:
      ref_or_rec: a :class:`LocomotionReference` or :class:`PhysicsRecording` (its ``qpos``).
      legs: the robot's :class:`Legs` (None: the Solo12's closed form).

    Examples:
      >>> round(jump_clearance(simulate_jump(JumpParams(duration=0.8, push_force=30.0))[1]), 2)
      0.19
    """
    qpos = ref_or_rec.qpos
    rot = solo12.quat_to_mat(qpos[:, 3:7])
    lowest = np.full(len(qpos), np.inf)
    fk = solo12.leg_fk if legs is None else legs.fk
    for leg in range(4):
        if legs is None:
            joints, radius = slice(7 + 3 * leg, 10 + 3 * leg), solo12.FOOT_RADIUS
        else:
            joints, radius = 7 + legs.dofs[leg], legs.foot_radius[leg]
        feet = np.array([fk(q[joints], leg) for q in qpos])
        z = qpos[:, 2] + np.einsum("tj,tj->t", rot[:, 2, :], feet) - radius
        lowest = np.minimum(lowest, z)
    return float(lowest.max())


# Push forces of the scan for the largest jump a robot lands (from a quarter of its weight to
# three times it, geometric): enough to place the landing limit within a step of 25 %.
LANDED_SCAN = 9
_LANDED: dict = {}


def largest_landed_jump(legs: Legs, control_dt: float = CONTROL_DT) -> float:
    """The largest foot clearance (m) of the reference controller's jumps that do not fall
    (:class:`JumpParams`, push forces of :data:`LANDED_SCAN`; fallen: the robot's
    :func:`cfm_jax.sim.quadruped.fall_rule` at any control step).

    Args:
      legs: the robot's :class:`Legs`.
      control_dt: control period (s).

    Examples:
      >>> round(largest_landed_jump(legs_of(solo12.load_model())), 3)  # no push falls
      0.255
    """
    from cfm_jax.sim import quadruped

    key = (model_bytes(legs.model), float(control_dt))
    if key not in _LANDED:
        rule = quadruped.fall_rule(quadruped.describe(legs.model), legs.scale)
        weight = _total_mass(legs.model) * -legs.model.opt.gravity[2]
        feet = None if legs.sites is not None else legs  # the Solo12's sites, else the legs
        landed = 0.0
        for force in np.geomspace(weight / 4, 3 * weight, LANDED_SCAN):
            sim = _jump_run(JumpParams(), float(force), legs, control_dt)
            rec = sim.recording()
            ref = _to_reference(rec, legs, sim.n_sub, control_dt, "jump", {})
            if not np.asarray(rule(ref.qpos, ref.foot_force)).any():
                landed = max(landed, jump_clearance(rec, feet))
        _LANDED[key] = landed
    return _LANDED[key]


def jump_height_scale(legs: Legs, control_dt: float = CONTROL_DT) -> float:
    """A robot's jump heights over the Solo12's: ``legs.scale``, or less where it lands less
    (:func:`largest_landed_jump` over the Solo12's). The Solo12: 1.

    Args:
      legs: the robot's :class:`Legs`.
      control_dt: control period (s).

    Examples:
      >>> jump_height_scale(legs_of(solo12.load_model()))
      1.0
    """
    solo = largest_landed_jump(legs_of(solo12.load_model()), control_dt)
    return min(legs.scale, largest_landed_jump(legs, control_dt) / solo)


def simulate_jump(params: JumpParams, model=None, control_dt: float = CONTROL_DT, legs=None):
    """Run the jump controller, as :func:`simulate_walk`; ``params.push_force`` None is
    bisected until :func:`jump_clearance` is ``params.height`` to 2 % (kept in ``ref.params``).

    Args:
      params: the :class:`JumpParams` (the Solo12's; another robot's scaled as the walk's,
        the requested clearance by :func:`jump_height_scale`).
      model: the ``mujoco.MjModel`` (None: :func:`cfm_jax.sim.solo12.load_model`).
      control_dt: control period (s), a whole number of physics steps.
      legs: the robot's :class:`Legs` (None: :func:`legs_of` ``model``).

    Examples:
      >>> ref, _ = simulate_jump(JumpParams(height=0.1, duration=0.8))  # bisection
      >>> abs(jump_clearance(ref) - 0.1) <= 0.002
      True
    """
    if legs is None:
        legs = legs_of(model if model is not None else solo12.load_model())
    model = legs.model
    solo = legs.sites is not None  # the Solo12's closed form measures its clearance
    weight = _total_mass(model) * -model.opt.gravity[2]
    if params.push_force is not None:
        force = params.push_force
    else:
        height = params.height * jump_height_scale(legs, control_dt)
        lo, hi = weight / 4, 3.0 * weight
        force = hi
        for _ in range(30):
            force = 0.5 * (lo + hi)
            rec = _jump_run(params, force, legs, control_dt).recording()
            got = jump_clearance(rec, None if solo else legs)
            if abs(got - height) <= 0.02 * height:
                break
            lo, hi = (force, hi) if got < height else (lo, force)
        params = dataclasses.replace(params, push_force=float(force))
    sim = _jump_run(params, force, legs, control_dt)
    rec = sim.recording()
    ref = _to_reference(rec, legs, sim.n_sub, control_dt, "jump", dataclasses.asdict(params))
    return ref, rec


# ---- checks -----------------------------------------------------------------------------------


def inverse_dynamics_residual(rec: PhysicsRecording, model=None) -> np.ndarray:
    """``mj_inverse(qpos, qvel, qacc)`` minus the applied force per physics step, ``(K, 18)``.

    Args:
      rec: a :class:`PhysicsRecording` of ``K`` physics steps.
      model: the ``mujoco.MjModel`` it was recorded on (None:
        :func:`cfm_jax.sim.solo12.load_model`).

    Examples:
      >>> _, rec = simulate_walk(WalkParams(duration=0.2))
      >>> bool(np.abs(inverse_dynamics_residual(rec)).max() < 1e-8)
      True
    """
    import mujoco

    model = model if model is not None else solo12.load_model()
    d = mujoco.MjData(model)
    out = np.empty((len(rec.tau), model.nv))
    for k in range(len(rec.tau)):
        d.qpos[:], d.qvel[:], d.qacc[:] = rec.qpos[k], rec.qvel[k], rec.qacc[k]
        mujoco.mj_inverse(model, d)
        out[k] = d.qfrc_inverse
        out[k, 6:] -= rec.tau[k]
    return out


class Replay(NamedTuple):
    """A closed-loop replay of a reference, ``T`` control steps.

    Attributes:
      qpos: ``(T+1, 19)`` positions at the control instants.
      qvel: ``(T+1, 18)`` velocities at the control instants.
      tau: ``(T, 12)`` applied (clipped) torques.
      foot_force: ``(T+1, 4, 3)`` as :attr:`LocomotionReference.foot_force`.
      fell: :func:`cfm_jax.sim.solo12.fell` (rule :data:`cfm_jax.sim.solo12.FALL`) at any instant.

    Examples:
      >>> replay(walk_reference(0.2, use_cache=False)).fell
      False
    """

    qpos: np.ndarray  # (T+1, 19)
    qvel: np.ndarray  # (T+1, 18)
    tau: np.ndarray  # (T, 12) applied (clipped) torques
    foot_force: np.ndarray  # (T+1, 4, 3)
    fell: bool


def replay(ref: LocomotionReference, model=None, qpos0=None, qvel0=None) -> Replay:
    """Simulate ``ref.tau`` plus the joint PD of ``ref.kp``, ``ref.kd`` (clipped), held per period.

    Args:
      ref: the :class:`LocomotionReference`.
      model: the ``mujoco.MjModel`` (None: :func:`cfm_jax.sim.solo12.load_model`).
      qpos0: ``(19,)`` initial positions, or None for ``ref.qpos[0]``.
      qvel0: ``(18,)`` initial velocities, or None for ``ref.qvel[0]``.

    Examples:
      >>> ref = walk_reference(0.2, use_cache=False)
      >>> float(np.abs(replay(ref).qpos - ref.qpos).max())  # from its own start: the recording
      0.0
    """
    import mujoco

    model = model if model is not None else solo12.load_model()
    d = mujoco.MjData(model)
    n_sub = int(round(ref.control_dt / model.opt.timestep))
    d.qpos[:] = ref.qpos[0] if qpos0 is None else qpos0
    d.qvel[:] = ref.qvel[0] if qvel0 is None else qvel0
    limit = model.actuator_ctrlrange[:, 1]
    qpos, qvel, taus, forces = [d.qpos.copy()], [d.qvel.copy()], [], []
    for t in range(ref.horizon):
        tau = ref.tau[t] + ref.kp * (ref.qpos[t, 7:] - d.qpos[7:])
        tau = np.clip(tau + ref.kd * (ref.qvel[t, 6:] - d.qvel[6:]), -limit, limit)
        d.ctrl[:] = tau
        for k in range(n_sub):
            mujoco.mj_step(model, d)
            if k == 0:  # sensors of the state at t under the torque applied at t
                forces.append(solo12.foot_forces(d.sensordata))
        qpos.append(d.qpos.copy())
        qvel.append(d.qvel.copy())
        taus.append(tau)
    mujoco.mj_forward(model, d)  # final state, last torque still applied
    forces.append(solo12.foot_forces(d.sensordata))
    qpos = np.array(qpos)
    forces = np.array(forces)
    return Replay(
        qpos,
        np.array(qvel),
        np.array(taus),
        forces,
        bool(solo12.fell(qpos, forces, solo12.FALL).any()),
    )


# ---- reference API with on-disk cache ----------------------------------------------------------

WALK_DURATIONS = (1.0, 1.5, 2.0, 2.5, 3.0)  # s, the 5 walking horizons
JUMP_HEIGHTS = (0.05, 0.08, 0.11, 0.14, 0.17)  # m of foot clearance, the 5 jump heights

SELECTION_MOTIONS = {
    "walk": {"speed": 0.2, "period": 0.4, "height": 0.22, "swing_height": 0.07},
    "jump": {"stand_depth": 0.2, "crouch_height": 0.19},
}
"""The motions a choice of hyperparameters is made on (``task.motion_family="selection"``):
the :class:`WalkParams` / :class:`JumpParams` fields that differ from the test references'.
A slower trot with a longer cycle, lower base and higher steps; jumps from a lower stance
through a shallower crouch. Not a window of any test motion: no 0.25 s window of a test
reference's joint positions is within :data:`DISJOINT_RMS` of any window of a selection
reference of the same kind (:func:`closest_window`; tests/test_locomotion.py), while the
walks and jumps of the test family are prefixes or shared phases of one another."""

DISJOINT_RMS = 0.03
"""rad: the RMS joint-position distance under which two 0.25 s windows count as the same
motion (the check of :data:`SELECTION_MOTIONS`)."""


def closest_window(a, b, window: int) -> float:
    """How close two trajectories come over any ``window`` steps, shifted in time: the
    minimum over start steps ``t`` of ``a`` and ``s`` of ``b`` of the RMS (over the window's
    steps and the columns) of ``a[t:t+window] - b[s:s+window]``. 0 when one trajectory holds
    a window of the other (a prefix, or the same phase at another time).

    Args:
      a: ``(Ta, n)`` array (for example a reference's joint positions ``qpos[:, 7:]``).
      b: ``(Tb, n)`` array.
      window: steps per window, at most ``min(Ta, Tb)``.

    Examples:
      >>> x = np.sin(np.linspace(0.0, 6.0, 50))[:, None]
      >>> closest_window(x, x[10:30], window=20)  # b is a window of a
      0.0
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"a and b: (T, n) arrays with the same n, got {a.shape} and {b.shape}")
    if not 1 <= window <= min(len(a), len(b)):
        raise ValueError(f"window={window}: between 1 and {min(len(a), len(b))} (the shorter one)")
    squared = ((a[:, None, :] - b[None, :, :]) ** 2).mean(-1)  # (Ta, Tb), step against step
    diagonal = np.zeros((len(a) + 1, len(b) + 1))  # sums along the diagonals t - s = const
    for t in range(len(a)):
        diagonal[t + 1, 1:] = diagonal[t, :-1] + squared[t]
    sums = diagonal[window:, window:] - diagonal[:-window, :-window]
    return float(np.sqrt(max(sums.min(), 0.0) / window))


def cache_dir(path: str | os.PathLike | None = None) -> Path:
    """Folder ``path``, else ``$CFM_JAX_REFERENCE_CACHE``, else ``~/.cache/cfm_jax/references``.

    Args:
      path: a folder, or None.

    Examples:
      >>> cache_dir("/tmp/references").as_posix()
      '/tmp/references'
    """
    if path is not None:
        return Path(path)
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    return Path.home() / ".cache" / "cfm_jax" / "references"


GENERATOR_FILES = (
    Path(__file__),
    Path(solo12.__file__),
    Path(solo12.__file__).with_name("quadruped.py"),
    Path(solo12.__file__).with_name("robots.py"),  # the motors' torque limits
)
"""The reference generator's sources: their bytes are part of the cache key."""


def model_bytes(model) -> bytes:
    """The compiled ``model`` as MuJoCo saves it (``mj_saveModel``): all of its numbers,
    so two models with the same bytes simulate alike. Part of the references' cache key.

    Args:
      model: a ``mujoco.MjModel``.

    Examples:
      >>> model_bytes(solo12.load_model()) == model_bytes(solo12.load_model())
      True
    """
    import mujoco

    buffer = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


def _cache_key(kind: str, params, control_dt: float, model) -> str:
    h = hashlib.sha256()
    meta = {"kind": kind, "params": dataclasses.asdict(params), "control_dt": control_dt}
    meta["format"] = _FORMAT_VERSION
    h.update(json.dumps(meta, sort_keys=True).encode())
    h.update(model_bytes(model))
    for source in GENERATOR_FILES:
        h.update(Path(source).read_bytes())
    return h.hexdigest()[:24]


def _save(ref: LocomotionReference, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **{k: np.asarray(v) for k, v in ref._asdict().items()})


def _load(path: Path) -> LocomotionReference:
    with np.load(path) as z:
        fields = {k: z[k] for k in LocomotionReference._fields}
    fields["control_dt"] = float(fields["control_dt"])
    for k in ("kp", "kd"):  # one gain, or one per joint
        fields[k] = float(fields[k]) if fields[k].ndim == 0 else np.array(fields[k])
    for k in ("kind", "params"):
        fields[k] = str(fields[k])
    return LocomotionReference(**fields)


def legs_of_file(path: str) -> Legs:
    """The :class:`Legs` of the quadruped in the MJCF file at ``path``: :func:`legs_of` its
    model, given the ground and foot sensors it lacks
    (:func:`cfm_jax.sim.quadruped.with_foot_sensors`).

    Args:
      path: an MJCF file of a motor-driven quadruped.

    Examples:
      >>> legs_of_file(solo12.model_path()).kp  # the Solo12's closed forms and gains
      5.0
    """
    from cfm_jax.sim import quadruped

    model = solo12.load_model(path)
    try:
        return legs_of(model)
    except quadruped.QuadrupedError:
        return legs_of(quadruped.with_foot_sensors(path)[0])


def _cached(kind, params, control_dt, model_file, model, cache, use_cache, simulate):
    if model is not None and model_file is not None:
        raise ValueError("give model or model_file, not both")
    legs = legs_of(model) if model is not None else legs_of_file(model_file or solo12.model_path())
    path = cache_dir(cache) / f"{kind}-{_cache_key(kind, params, control_dt, legs.model)}.npz"
    if use_cache and path.is_file():
        return _load(path)
    ref, _ = simulate(params, None, control_dt, legs=legs)
    if use_cache:
        _save(ref, path)
    return ref


def walk_reference(
    duration: float = 2.0,
    *,
    control_dt: float = CONTROL_DT,
    model_file: str | None = None,
    model=None,
    cache: str | os.PathLike | None = None,
    use_cache: bool = True,
    **params,
) -> LocomotionReference:
    """Trot reference of ``duration`` s, from the cache when there (key: docs/locomotion.md).

    Args:
      duration: length of the reference (s).
      control_dt: control period (s).
      model_file: the MJCF file (given the ground and foot sensors it lacks,
        :func:`legs_of_file`), or None for :func:`cfm_jax.sim.solo12.model_path`.
      model: or the compiled ``mujoco.MjModel`` itself, with its foot sensors (a
        :class:`cfm_jax.sim.robots.Robot`'s ``mj_model``: servos converted, sensors added, its
        timestep), the references then simulated on it (:func:`legs_of`).
      cache: the cache folder, or None for :func:`cache_dir`'s default.
      use_cache: read and write the cache; False simulates every time and writes nothing.
      params: further :class:`WalkParams` fields (``speed``, ``period``, ...).

    Raises:
      ValueError: both ``model_file`` and ``model`` given.
      cfm_jax.sim.quadruped.QuadrupedError: the model is not a quadruped with a torque motor
        per leg joint and a contact sensor per foot (:meth:`Legs.of`).

    Examples:
      >>> walk_reference(0.2, use_cache=False, speed=0.2).horizon  # 0.2 s at 250 Hz
      50
    """
    p = WalkParams(duration=duration, **params)
    return _cached("walk", p, control_dt, model_file, model, cache, use_cache, simulate_walk)


def jump_reference(
    height: float = 0.1,
    *,
    control_dt: float = CONTROL_DT,
    model_file: str | None = None,
    model=None,
    cache: str | os.PathLike | None = None,
    use_cache: bool = True,
    **params,
) -> LocomotionReference:
    """Vertical jump reference of ``height`` m foot clearance, cached as :func:`walk_reference`.

    Args:
      height: requested foot clearance (m).
      control_dt: control period (s).
      model_file: the MJCF file (given the ground and foot sensors it lacks,
        :func:`legs_of_file`), or None for :func:`cfm_jax.sim.solo12.model_path`.
      model: or the compiled ``mujoco.MjModel`` itself, with its foot sensors (a
        :class:`cfm_jax.sim.robots.Robot`'s ``mj_model``: servos converted, sensors added, its
        timestep), the references then simulated on it (:func:`legs_of`).
      cache: the cache folder, or None for :func:`cache_dir`'s default.
      use_cache: read and write the cache; False simulates every time and writes nothing.
      params: further :class:`JumpParams` fields (``duration``, ``push_force``, ...).

    Raises:
      ValueError, cfm_jax.sim.quadruped.QuadrupedError: as :func:`walk_reference`.

    Examples:
      >>> abs(jump_clearance(jump_reference(0.1, use_cache=False, duration=0.8)) - 0.1) <= 0.002
      True
    """
    p = JumpParams(height=height, **params)
    return _cached("jump", p, control_dt, model_file, model, cache, use_cache, simulate_jump)


def default_walks(**kwargs) -> list[LocomotionReference]:
    """The 5 walking horizons :data:`WALK_DURATIONS` (0.3 m/s trot).

    Args:
      kwargs: keyword arguments of :func:`walk_reference`.

    Examples:
      >>> [ref.horizon for ref in default_walks(use_cache=False)]  # 250 Hz
      [250, 375, 500, 625, 750]
    """
    return [walk_reference(t, **kwargs) for t in WALK_DURATIONS]


def default_jumps(**kwargs) -> list[LocomotionReference]:
    """The 5 jumps :data:`JUMP_HEIGHTS` (five bisections: about 6 s uncached).

    Args:
      kwargs: keyword arguments of :func:`jump_reference`.

    Examples:
      >>> [round(jump_clearance(ref), 2) for ref in default_jumps()]  # doctest: +SKIP
      [0.05, 0.08, 0.11, 0.14, 0.17]
    """
    return [jump_reference(h, **kwargs) for h in JUMP_HEIGHTS]


def commanded_distance(params: WalkParams) -> float:
    """Forward distance (m) of the commanded base motion: stand, linear speed ramp, cruise.

    Args:
      params: the :class:`WalkParams`.

    Examples:
      >>> round(commanded_distance(WalkParams(duration=2.0)), 3)  # 0.09 m ramp + 1.3 s cruise
      0.48
    """
    walk = max(params.duration - params.stand, 0.0)
    ramp = min(walk, params.ramp)
    return params.speed * (ramp * ramp / (2 * params.ramp) + (walk - ramp))


def summary(ref: LocomotionReference, model=None) -> dict:
    """Key numbers of a reference, a dict (``distance_m``, ``peak_torque_Nm``, ...).

    Args:
      ref: the :class:`LocomotionReference`.
      model: not used.

    Examples:
      >>> summary(walk_reference(0.2, use_cache=False))["duration_s"]
      0.2
    """
    out = {
        "kind": ref.kind,
        "duration_s": ref.duration,
        "distance_m": float(ref.qpos[-1, 0] - ref.qpos[0, 0]),
        "peak_torque_Nm": float(np.abs(ref.tau).max()),
        "peak_normal_force_N": float(ref.foot_force[..., 2].max()),
        "max_tilt_deg": float(
            np.degrees(np.arccos(solo12.quat_to_mat(ref.qpos[:, 3:7])[:, 2, 2])).max()
        ),
    }
    if ref.kind == "jump":
        out["clearance_m"] = jump_clearance(ref)
        out["base_apex_gain_m"] = float(ref.qpos[:, 2].max() - ref.qpos[0, 2])
        out["push_force_N"] = json.loads(ref.params)["push_force"]
    else:
        last = min(ref.horizon, int(round(1.0 / ref.control_dt)))
        out["speed_last_1s_mps"] = float(
            (ref.qpos[-1, 0] - ref.qpos[-1 - last, 0]) / (last * ref.control_dt)
        )
    return out
