"""Robots as data: MJCF file -> :class:`Robot` (MuJoCo model, MJX model, state map, limits);
:func:`load` checks the file against the rules of docs/how-to/own-robot.md.
"""

from __future__ import annotations

import dataclasses
import os
from functools import cached_property

import mujoco
import numpy as np

from cfm_jax import _shipped
from cfm_jax.config import ROBOT_ACTUATORS

ACTUATORS = ROBOT_ACTUATORS
"""How :func:`load` takes actuators: ``strict`` (motors only) or ``torque`` (:func:`convert`)."""

_OPTION = (
    "robot_actuators='torque' (CLI: --robot-actuators torque) replaces each joint servo by a "
    "torque motor on its joint"
)


class RobotError(ValueError):
    """An MJCF file that cannot be used as a cfm_jax robot (the message says why).

    Examples:
      >>> load("no_such_robot")
      Traceback (most recent call last):
      cfm_jax.sim.robots.RobotError: robot='no_such_robot' is not a registered robot; ...
    """


def robot_dir():
    """Folder of the shipped MJCF files (package data, else the source checkout's ``robots/``).

    Examples:
      >>> (robot_dir() / "iiwa14.xml").is_file()
      True
    """
    return _shipped.robot_dir()


def registered() -> tuple[str, ...]:
    """Sorted names of the shipped robots, each usable as ``Config.robot``.

    Examples:
      >>> registered()
      ('iiwa14', 'solo12', 'two_link_arm')
    """
    return _shipped.registered()


def resolve(name_or_path: str) -> str:
    """Absolute path of the MJCF file of a registered name or an existing path.

    Args:
      name_or_path: a registered name, or a path (with a path separator or ending ``.xml``).

    Raises:
      RobotError: neither a registered name nor an existing file.

    Examples:
      >>> resolve("two_link_arm").endswith("two_link_arm.xml")
      True
    """
    if os.path.sep in name_or_path or name_or_path.endswith(".xml"):
        if not os.path.isfile(name_or_path):
            raise RobotError(
                f"robot={name_or_path!r}: no such MJCF file; give a path to an existing .xml "
                f"file or a registered robot name {registered()}"
            )
        return os.path.abspath(name_or_path)
    path = robot_dir() / f"{name_or_path}.xml"
    if not path.is_file():
        raise RobotError(
            f"robot={name_or_path!r} is not a registered robot; allowed: {registered()} or a "
            "path to an MJCF file"
        )
    return str(path)


_MJX_STEP_ERRORS: dict[str, str | None] = {}
""":func:`_mjx_step_error` per model digest (one trace per model and process)."""


def _mjx_step_error(mj_model, model) -> str | None:
    """What MJX raises when it traces one ``mjx.step`` of ``model`` (the MJX model of
    ``mj_model``; shapes only, ``jax.eval_shape``: nothing is compiled or run), as
    ``"<exception type>: <first line>"``, or None. Some models MJX refuses only there, not
    in ``put_model`` (a ``condim=1`` geom under an elliptic cone: NotImplementedError)."""
    import jax

    from cfm_jax._mjx import mjx
    from cfm_jax.sim import native

    key = native.model_digest(mj_model)
    if key not in _MJX_STEP_ERRORS:
        try:
            jax.eval_shape(mjx.step, model, mjx.make_data(model))
            _MJX_STEP_ERRORS[key] = None
        except Exception as error:  # noqa: BLE001  MJX's own failure, whatever its type
            _MJX_STEP_ERRORS[key] = f"{type(error).__name__}: {error}".split("\n")[0]
    return _MJX_STEP_ERRORS[key]


@dataclasses.dataclass(frozen=True, eq=False)
class Robot:
    """A torque-controlled robot: a fixed-base arm or a floating-base (legged) robot.

    Attributes:
      name: registered name or file stem.
      path: absolute path of the MJCF file.
      mj_model: the MuJoCo model (C engine).
      joint_names: names of all joints, in model order.
      joint_range: ``(njnt, 2)`` position limits (``-inf, inf`` where unlimited).
      torque_limit: ``(action_dim,)`` symmetric torque limit per actuated joint (N m or N).
      gear: ``(action_dim,)`` actuator gear per actuated joint; ``ctrl = tau / gear``.
      actuator_of_joint: ``(action_dim,)`` index of the actuator of each actuated joint.
      home: ``(nq,)`` the keyframe ``home`` if present, else (a quadruped) its standing
        pose (:func:`cfm_jax.sim.quadruped.describe`), else ``qpos0``.
      actuated_dofs: ``(action_dim,)`` dof (``qvel``) index of each actuated joint.
      floating_base: whether the root is a free joint (not actuated).
      actuators: how the file's actuators were taken, one of :data:`ACTUATORS`.
      limit_source: where each torque limit comes from (``ctrlrange``, ``forcerange``, ...).
      converted: ``(name, kind)`` of each servo replaced by a torque motor.
      held_joints: joints coupled by an equality constraint, not driven (:func:`held_joints`).
      passive_joints: hinge/slide joints with no actuator and no coupling.
      hold_ctrl: ``(nu,)`` set points of the held joints' actuators; None if nothing is held.
      added: what loading added to the file, in words: a quadruped's ground plane and foot
        contact sensors where it lacks them (:func:`cfm_jax.sim.quadruped.with_foot_sensors`).

    Examples:
      >>> load("two_link_arm").torque_limit.tolist()
      [20.0, 10.0]
    """

    name: str
    path: str
    mj_model: mujoco.MjModel
    joint_names: tuple[str, ...]
    joint_range: np.ndarray
    torque_limit: np.ndarray
    gear: np.ndarray
    actuator_of_joint: np.ndarray
    home: np.ndarray
    actuated_dofs: np.ndarray
    floating_base: bool = False
    actuators: str = "strict"
    limit_source: tuple[str, ...] = ()
    converted: tuple[tuple[str, str], ...] = ()
    held_joints: tuple[str, ...] = ()
    passive_joints: tuple[str, ...] = ()
    hold_ctrl: np.ndarray | None = None
    added: tuple[str, ...] = ()

    @property
    def nq(self) -> int:
        return int(self.mj_model.nq)

    @property
    def nv(self) -> int:
        return int(self.mj_model.nv)

    @property
    def state_dim(self) -> int:
        """Size of ``s = [q, qdot]``."""
        return self.nq + self.nv

    @property
    def action_dim(self) -> int:
        """Number of actuated joints (torques)."""
        return int(self.actuated_dofs.shape[0])

    @property
    def actuated_qpos(self) -> np.ndarray:
        """``(action_dim,)`` ``qpos`` index of each actuated joint."""
        joints = np.asarray(self.mj_model.dof_jntid)[np.asarray(self.actuated_dofs)]
        return np.asarray(self.mj_model.jnt_qposadr)[joints].astype(np.int32)

    @property
    def drives_every_dof(self) -> bool:
        """Whether the controller drives every dof (``nq == nv == action_dim``)."""
        return self.nq == self.nv == self.action_dim

    @property
    def timestep(self) -> float:
        return float(self.mj_model.opt.timestep)

    @cached_property
    def mjx_model(self):
        """The MJX model, built by :func:`load` outside any trace; :class:`RobotError` where
        MJX cannot build it (e.g. a cylinder-box collision; the native simulator can) or
        cannot trace its step (e.g. a ``condim=1`` geom under an elliptic cone: MJX builds
        that model and refuses it only when a step is traced, :func:`_mjx_step_error`)."""
        from cfm_jax._mjx import mjx

        try:
            model = mjx.put_model(self.mj_model)
        except NotImplementedError as error:
            problem = str(error)
        else:
            step_error = _mjx_step_error(self.mj_model, model)
            problem = None if step_error is None else f"mjx.step: {step_error}"
        if problem is not None:
            raise RobotError(
                f"robot={self.name!r}: MJX cannot build this model ({problem}). The native "
                "simulator (simulator='native', the default) runs it; simulator='mjx' and "
                "forward.kind='rigid_body' need MJX (change what MJX names: a collision pair "
                "it has no function for, exclude those geoms with <contact><exclude>; an "
                "integrator it lacks, as 'implicit', <option integrator=\"implicitfast\"/>; "
                "or use the native simulator)"
            )
        return model

    @property
    def mjx_error(self) -> str | None:
        """Why MJX cannot build this model (the :class:`RobotError` text), or None if it can."""
        try:
            self.mjx_model  # noqa: B018
        except RobotError as error:
            return str(error)
        return None

    def torque_to_ctrl(self, tau):
        """Map joint torques ``(..., action_dim)`` to the ``ctrl`` vector ``(..., nu)``."""
        import jax.numpy as jnp

        shape = tau.shape[:-1] + (self.mj_model.nu,)
        if self.hold_ctrl is None:
            ctrl = jnp.zeros(shape, tau.dtype)
        else:  # the held joints' actuators keep their set points
            ctrl = jnp.broadcast_to(jnp.asarray(self.hold_ctrl, jnp.float32), shape).astype(
                tau.dtype
            )
        return ctrl.at[..., self.actuator_of_joint].set(tau / self.gear)

    def mass_matrix(self, qpos) -> np.ndarray:
        """The joint-space inertia ``M(q)`` (MuJoCo C, armature included), ``(nv, nv)``."""
        return self.mass_matrices(np.asarray(qpos)[None])[0]

    def mass_matrix_diagonal(self, qpos) -> np.ndarray:
        return np.diag(self.mass_matrix(qpos)).copy()

    def lightest_inertia(self, poses) -> np.ndarray:
        """Each actuated joint's least ``1 / (M(q)^-1)_jj`` (others free) over ``poses (n, nq)``."""
        return _lightest(np.linalg.inv(self.mass_matrices(poses)), self.actuated_dofs)

    def mass_matrices(self, poses) -> np.ndarray:
        """``M(q)`` at each of ``poses (n, nq)`` (MuJoCo C, armature included), ``(n, nv, nv)``."""
        model = self.mj_model
        data = mujoco.MjData(model)
        full = np.zeros((len(poses), model.nv, model.nv))
        for i, q in enumerate(np.asarray(poses)):
            data.qpos[:] = q
            mujoco.mj_fwdPosition(model, data)
            mujoco.mj_fullM(model, data, full[i])
        return full

    def torque_scale(self, frequency: float = np.inf) -> np.ndarray:
        """Torque scale of each actuated joint (``loop.torque_scale="inertia"``): ``S_j = F_j +
        I_j min_k (tau_max_k - F_k) / I_k``, ``I_j = hypot(M_jj, D_j / w)``, ``M`` at home.

        Args:
          frequency: ``w`` (rad/s), the task's feedback frequency; ``inf`` leaves damping out.

        Raises:
          ValueError: ``frequency`` is not > 0.

        Examples:
          >>> arm = load("iiwa14")
          >>> bool(np.any(arm.torque_scale(10.0) == arm.torque_limit))  # the weakest joint's
          True
        """
        return self._torque_scale(frequency)[0]

    def scale_acceleration(self, frequency: float = np.inf) -> float:
        """The acceleration ``a`` :meth:`torque_scale` gives every joint (rad/s^2).

        Args:
          frequency: as :meth:`torque_scale`.

        Examples:
          >>> round(load("two_link_arm").scale_acceleration(10.0), 1)
          58.5
        """
        return self._torque_scale(frequency)[1]

    def _torque_scale(self, frequency: float) -> tuple[np.ndarray, float]:
        """:meth:`torque_scale` and the acceleration ``a`` it gives every joint."""
        if not frequency > 0:  # also NaN
            raise ValueError(
                f"frequency={frequency!r}: must be a number > 0 (rad/s; inf: no damping)"
            )
        dofs = np.asarray(self.actuated_dofs)
        model = self.mj_model
        friction = model.dof_frictionloss[dofs].astype(np.float64)
        inertia = np.hypot(self.mass_matrix_diagonal(self.home)[dofs],
                           model.dof_damping[dofs] / frequency)  # fmt: skip
        limit = np.asarray(self.torque_limit, np.float64)
        # A joint whose friction its limit cannot overcome gets its limit: it cannot move.
        moving = np.maximum(limit - friction, 0.0)
        weakest = int(np.argmin(moving / inertia))
        acceleration = moving[weakest] / inertia[weakest]
        scale = friction + inertia * acceleration
        # Exact where the formula gives the limit up to rounding: the weakest joint is
        # scaled by its limit, and a joint that ties with it never by more than its own.
        scale[weakest] = limit[weakest]
        return np.minimum(scale, limit), float(acceleration)

    def coupled_torque_scale(self, frequency: float = np.inf) -> np.ndarray:
        """Torque scale with the joints' coupling (``loop.torque_scale="coupled"``): ``T = diag(S)
        + a (M - diag(M_jj))``, ``a`` the acceleration :meth:`torque_scale` gives every joint.

        Args:
          frequency: as :meth:`torque_scale`.

        Examples:
          >>> arm = load("two_link_arm")
          >>> np.allclose(np.diag(arm.coupled_torque_scale(10.0)), arm.torque_scale(10.0))
          True
        """
        scale, acceleration = self._torque_scale(frequency)
        dofs = np.asarray(self.actuated_dofs)
        inertia = self.mass_matrix(self.home)[np.ix_(dofs, dofs)]
        coupled = acceleration * (inertia - np.diag(np.diag(inertia)))
        return coupled + np.diag(scale)


def _lightest(inverses: np.ndarray, dofs) -> np.ndarray:
    return (1.0 / np.diagonal(inverses, axis1=1, axis2=2)[:, np.asarray(dofs)]).min(axis=0)


def servo_kind(model, a) -> str | None:
    """What actuator ``a`` is: None (a motor), a servo kind :func:`convert` replaces, or ``other``.

    Args:
      model: a ``mujoco.MjModel``.
      a: the actuator's index.

    Examples:
      >>> servo_kind(compile_file("docs/how-to/servo_arm.xml"), 0)
      'position'
    """
    dyn = int(model.actuator_dyntype[a])
    gain = int(model.actuator_gaintype[a])
    bias = int(model.actuator_biastype[a])
    if (
        dyn == int(mujoco.mjtDyn.mjDYN_NONE)
        and gain == int(mujoco.mjtGain.mjGAIN_FIXED)
        and bias == int(mujoco.mjtBias.mjBIAS_NONE)
        and model.actuator_gainprm[a, 0] == 1.0
    ):
        return None
    fixed_or_affine = (int(mujoco.mjtGain.mjGAIN_FIXED), int(mujoco.mjtGain.mjGAIN_AFFINE))
    if gain not in fixed_or_affine or bias not in (
        int(mujoco.mjtBias.mjBIAS_NONE),
        int(mujoco.mjtBias.mjBIAS_AFFINE),
    ):
        return "other"
    if dyn == int(mujoco.mjtDyn.mjDYN_INTEGRATOR):
        return "intvelocity"
    affine = bias == int(mujoco.mjtBias.mjBIAS_AFFINE)
    gainprm, biasprm = model.actuator_gainprm[a], model.actuator_biasprm[a]
    if affine and biasprm[1] == -gainprm[0] and biasprm[0] == 0 and gainprm[0] != 0:
        return "position"
    if affine and biasprm[2] == -gainprm[0] and biasprm[:2].tolist() == [0, 0]:
        return "velocity"
    return "general"


def joint_name(model, j) -> str:
    """Name of joint ``j`` (``joint<j>`` if unnamed).

    Args:
      model: a ``mujoco.MjModel``.
      j: the joint's index.

    Examples:
      >>> joint_name(load("two_link_arm").mj_model, 1)
      'elbow'
    """
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"


def held_joints(model) -> tuple[set[int], set[int]]:
    """Ids of the *held* joints (coupled by an ``<equality>``) and of actuators moving only them.

    Args:
      model: a ``mujoco.MjModel``.

    Examples:
      >>> held_joints(compile_file("tests/gripper_arm.xml"))  # the fingers and their servo
      ({3, 4}, {2})
    """
    tendon_joints = []
    for t in range(model.ntendon):
        adr, num = int(model.tendon_adr[t]), int(model.tendon_num[t])
        types = model.wrap_type[adr : adr + num]
        ids = model.wrap_objid[adr : adr + num]
        joint_wrap = int(mujoco.mjtWrap.mjWRAP_JOINT)
        tendon_joints.append({int(i) for w, i in zip(types, ids, strict=True) if w == joint_wrap})
    joints: set[int] = set()
    for e in range(model.neq):
        if not model.eq_active0[e]:
            continue
        objects = [int(model.eq_obj1id[e]), int(model.eq_obj2id[e])]
        if int(model.eq_type[e]) == int(mujoco.mjtEq.mjEQ_JOINT):
            joints.update(o for o in objects if o >= 0)
        elif int(model.eq_type[e]) == int(mujoco.mjtEq.mjEQ_TENDON):
            for o in objects:
                if o >= 0:
                    joints.update(tendon_joints[o])
    actuators = set()
    for a in range(model.nu):
        trn, target = int(model.actuator_trntype[a]), int(model.actuator_trnid[a, 0])
        if trn == int(mujoco.mjtTrn.mjTRN_JOINT) and target in joints:
            actuators.add(a)
        elif trn == int(mujoco.mjtTrn.mjTRN_TENDON) and tendon_joints[target]:
            if tendon_joints[target] <= joints:
                actuators.add(a)
    return joints, actuators


def actuator_torque_limit(model, a: int, control_is_force: bool = True):
    """The most joint torque (N m; N on a slide) actuator ``a`` exerts, as MuJoCo clamps it:
    the least of its ``ctrlrange`` (a motor's control is its force) and ``forcerange``, both
    times ``|gear|`` (the gear applies after the clamp), and its joint's ``actuatorfrcrange``
    (in joint units), each where it is limited.

    Args:
      model: a ``mujoco.MjModel``.
      a: the actuator's index (joint transmission).
      control_is_force: whether ``ctrlrange`` bounds the force (a motor) or not (a servo's
        control is a position or velocity).

    Returns:
      ``(limit, source)``, ``source`` one of ``ctrlrange``, ``forcerange``,
      ``actuatorfrcrange``; None where nothing bounds it.

    Examples:
      >>> xml = ('<mujoco><worldbody><body><joint name="j" axis="0 1 0"/><geom size=".1"/>'
      ...        '</body></worldbody><actuator><motor joint="j" gear="2" forcerange="-5 5"/>'
      ...        '</actuator></mujoco>')
      >>> actuator_torque_limit(mujoco.MjModel.from_xml_string(xml), 0)
      (10.0, 'forcerange')
    """
    gear = abs(float(model.actuator_gear[a, 0]))
    bounds = []
    if control_is_force and model.actuator_ctrllimited[a]:
        bounds.append((float(np.max(np.abs(model.actuator_ctrlrange[a]))) * gear, "ctrlrange"))
    if model.actuator_forcelimited[a]:
        bounds.append((float(np.max(np.abs(model.actuator_forcerange[a]))) * gear, "forcerange"))
    joint = int(model.actuator_trnid[a, 0])
    if model.jnt_actfrclimited[joint]:
        frc = float(np.max(np.abs(model.jnt_actfrcrange[joint])))
        bounds.append((frc, "actuatorfrcrange"))
    return min(bounds, key=lambda bound: bound[0]) if bounds else None


def servo_limits(model, torque_limit=None, where: str = "robot", keep=()):
    """``{actuator: (kind, torque limit, source)}`` of each servo on a joint: the bound of
    :func:`actuator_torque_limit` (its ``forcerange`` and its joint's ``actuatorfrcrange``),
    else ``torque_limit``.

    Args:
      model: a ``mujoco.MjModel`` as the file gives it.
      torque_limit: None, or limits (N m or N): one for all, or one per hinge/slide joint.
      where: the robot, for the messages.
      keep: actuators left as published (:func:`held_joints`).

    Raises:
      RobotError: a servo without a limit, a muscle/user actuator, a bad ``torque_limit``.

    Examples:
      >>> servo_limits(compile_file("docs/how-to/servo_arm.xml"))
      {0: ('position', 40.0, 'forcerange'), 1: ('position', 15.0, 'forcerange')}
    """
    hinge_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    joints = [j for j in range(model.njnt) if int(model.jnt_type[j]) in hinge_slide]
    position = {j: k for k, j in enumerate(joints)}
    if torque_limit is not None and len(torque_limit) not in (1, len(joints)):
        raise RobotError(
            f"{where}: robot_torque_limit={tuple(torque_limit)!r} has {len(torque_limit)} "
            f"values; give one for all joints or one per joint ({len(joints)}: "
            f"{[joint_name(model, j) for j in joints]})"
        )
    found, missing = {}, []
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT) or a in keep:
            continue  # reported by load(), or held as published
        kind = servo_kind(model, a)
        if kind is None:
            continue
        j = int(model.actuator_trnid[a, 0])
        if kind == "other":
            aname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}"
            raise RobotError(
                f"{where}: actuator {aname!r} on joint {joint_name(model, j)!r} is a muscle or "
                "user actuator (gain or bias type other than fixed/affine); only motors and "
                "servos can be taken as torque motors"
            )
        bound = actuator_torque_limit(model, a, control_is_force=False)
        if bound is not None:
            found[a] = (kind, *bound)
        elif torque_limit is not None and j in position:
            value = torque_limit[0] if len(torque_limit) == 1 else torque_limit[position[j]]
            found[a] = (kind, float(value), "robot_torque_limit")
        else:
            missing.append(joint_name(model, j))
    if missing:
        raise RobotError(
            f"{where}: the servos of joints {missing} have no torque limit; give one as the "
            "actuator's forcerange (with forcelimited or autolimits), the joint's "
            "actuatorfrcrange, or robot_torque_limit (CLI: --robot-torque-limit, one number "
            "for all joints or one per joint)"
        )
    return found


def convert(path: str, model, torque_limit=None, where: str = "robot", keep=(), spec=None):
    """``(model, servos)``: ``path``'s model with each servo on a joint replaced by a torque
    motor of the same joint, gear and limit (:func:`servo_limits`), keyframe ``ctrl`` 0.

    Args:
      path: the MJCF file (edited through ``mujoco.MjSpec``, not written).
      model: its ``mujoco.MjModel`` as compiled from the file (or from ``spec``).
      torque_limit: the user's limits (see :func:`servo_limits`), or None.
      where: the robot, for the messages.
      keep: actuators left as published, their keyframe ``ctrl`` kept.
      spec: the file's ``mujoco.MjSpec`` with other edits that leave its actuators as they
        are (a quadruped's foot sensors, :func:`cfm_jax.sim.quadruped.add_foot_sensors`), to
        edit further; None: read from ``path``.

    Raises:
      RobotError: as :func:`servo_limits`, or the converted model does not compile.

    Examples:
      >>> path = "docs/how-to/servo_arm.xml"
      >>> convert(path, compile_file(path))[0].actuator_ctrlrange.tolist()
      [[-40.0, 40.0], [-15.0, 15.0]]
    """
    servos = servo_limits(model, torque_limit, where, keep)
    if not servos:
        return model, servos
    spec = mujoco.MjSpec.from_file(path) if spec is None else spec
    for a, (_, limit, _) in servos.items():
        act = spec.actuators[a]
        gear = abs(float(model.actuator_gear[a, 0]))
        act.dyntype = mujoco.mjtDyn.mjDYN_NONE
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_NONE
        act.dynprm = [1.0] + [0.0] * 9
        act.gainprm = [1.0] + [0.0] * 9
        act.biasprm = [0.0] * 10
        act.actlimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.actdim = -1
        act.actearly = False
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-limit / gear, limit / gear]
    for key in spec.keys:
        if len(key.ctrl) == model.nu:
            ctrl = np.array(key.ctrl, dtype=float)
            ctrl[list(servos)] = 0.0
            key.ctrl = ctrl.tolist()
        else:  # written for actuators the file no longer has (dropped by _compile)
            key.ctrl = []
        key.act = []
    try:
        return spec.compile(), servos
    except Exception as error:  # mujoco raises ValueError with the compiler's message
        raise RobotError(f"{where}: the converted model does not compile: {error}") from error


def _as_quadruped(path: str, model):
    """``(model, added, standing, spec)``: a quadruped with ground and foot sensors
    (:func:`cfm_jax.sim.quadruped.add_foot_sensors`), what was added, its standing pose and
    the edited spec (None: nothing added); any other model as it is, ``()``, None, None."""
    from cfm_jax.sim import quadruped

    try:
        found = quadruped.describe(model)
        spec = mujoco.MjSpec.from_file(path)
        added = quadruped.add_foot_sensors(spec)
        if not added:
            return model, (), found.standing, None
        sensed = spec.compile()
    except (quadruped.QuadrupedError, ValueError):
        return model, (), None, None  # not a quadruped (or its keyframes do not compile alone)
    return sensed, tuple(added), quadruped.describe(sensed).standing, spec


def compile_file(path: str):
    """``mujoco.MjModel`` of an MJCF file, without keyframe ``ctrl``/``act`` that do not fit.

    Args:
      path: an MJCF file.

    Raises:
      ValueError: MuJoCo's, when the file does not compile for another reason.

    Examples:
      >>> compile_file(resolve("two_link_arm")).nq
      2
    """
    try:
        return mujoco.MjModel.from_xml_path(path)
    except ValueError as error:
        if "invalid ctrl size" not in str(error) and "invalid act size" not in str(error):
            raise
        spec = mujoco.MjSpec.from_file(path)
        for key in spec.keys:
            key.ctrl = []
            key.act = []
        return spec.compile()


def conversion(name_or_path: str, torque_limit=None) -> list[dict]:
    """What ``robot_actuators='torque'`` does to a file: a dict per servo (none for motors).

    Args:
      name_or_path: registered name or MJCF path.
      torque_limit: ``Config.robot_torque_limit``.

    Raises:
      RobotError: as :func:`servo_limits`.

    Examples:
      >>> conversion("docs/how-to/servo_arm.xml")[1]
      {'joint': 'elbow', 'servo': 'position', 'torque_limit': 15.0, 'source': 'forcerange'}
    """
    path = resolve(name_or_path)
    model = compile_file(path)
    where = f"robot={name_or_path!r} ({path})"
    servos = servo_limits(model, torque_limit, where, keep=held_joints(model)[1])  # as load()
    return [
        {"joint": joint_name(model, int(model.actuator_trnid[a, 0])), "servo": kind,
         "torque_limit": float(limit), "source": source}
        for a, (kind, limit, source) in servos.items()
    ]  # fmt: skip


def conversion_note(name_or_path: str, torque_limit=None) -> str:
    """:func:`conversion` as one line of Markdown (the summary's protocol line).

    Args:
      name_or_path: registered name or MJCF path.
      torque_limit: ``Config.robot_torque_limit``.

    Examples:
      >>> conversion_note("two_link_arm")
      "`robot_actuators='torque'`: no servos (all torque motors)"
    """
    servos = conversion(name_or_path, torque_limit)
    if not servos:
        return "`robot_actuators='torque'`: no servos (all torque motors)"
    parts = [f"{s['joint']} {s['torque_limit']:g} ({s['servo']}, {s['source']})" for s in servos]
    return (
        f"`robot_actuators='torque'`: {len(servos)} servo{'s' if len(servos) != 1 else ''} "
        f"as torque motors, limits {', '.join(parts)}"
    )


def fresh_model(robot: Robot) -> mujoco.MjModel:
    """A new ``mujoco.MjModel`` of ``robot``'s file, given what :func:`load` added and
    converted as it did, to edit.

    Args:
      robot: a :class:`Robot`.

    Examples:
      >>> fresh_model(load("two_link_arm")).nu
      2
    """
    model, spec = compile_file(robot.path), None
    if robot.added:  # a quadruped's ground and foot sensors, in the spec convert edits
        model, _, _, spec = _as_quadruped(robot.path, model)
    if robot.actuators == "torque":
        limits = tuple(robot.torque_limit.tolist())
        model, _ = convert(robot.path, model, limits, robot.name, spec=spec)
    return model


def nonfinite_fields(mj_model) -> list[str]:
    """The names of the compiled model's floating-point arrays and options that hold a NaN or
    an infinity (a model with ``mass="nan"`` compiles), sorted; empty for a sound model.

    Args:
      mj_model: a ``mujoco.MjModel``.

    Examples:
      >>> model = mujoco.MjModel.from_xml_string(
      ...     '<mujoco><worldbody><body><joint/><geom size="0.1"/></body></worldbody></mujoco>')
      >>> nonfinite_fields(model)
      []
      >>> model.dof_damping[0] = float("inf"); nonfinite_fields(model)
      ['dof_damping']
    """
    bad = []
    for owner, prefix in ((mj_model, ""), (mj_model.opt, "opt.")):
        for field in dir(owner):
            if field.startswith("_"):
                continue
            try:
                value = getattr(owner, field)
            except Exception:  # a property MuJoCo does not serve for this model
                continue
            if isinstance(value, float):
                value = np.asarray(value)
            if (
                isinstance(value, np.ndarray)
                and value.dtype.kind == "f"
                and not np.all(np.isfinite(value))
            ):
                bad.append(prefix + field)
    return sorted(bad)


def of_config(config) -> Robot:
    """The robot of ``config`` as training loads it: :func:`load` of its ``robot``,
    ``robot_actuators`` and ``robot_torque_limit``.

    Args:
      config: a :class:`cfm_jax.config.Config`.

    Raises:
      RobotError: as :func:`load`.

    Examples:
      >>> import cfm_jax
      >>> of_config(cfm_jax.Config(robot="two_link_arm")).nq
      2
    """
    return load(
        config.robot, actuators=config.robot_actuators, torque_limit=config.robot_torque_limit
    )


def load(
    name_or_path: str,
    timestep: float | None = None,
    actuators: str = "strict",
    torque_limit=None,
) -> Robot:
    """Load and check a robot (what a file needs: docs/how-to/own-robot.md).

    Args:
      name_or_path: registered name (:func:`registered`) or path to an MJCF file.
      timestep: override of the MJCF physics timestep (s); None keeps it.
      actuators: one of :data:`ACTUATORS`.
      torque_limit: with ``actuators="torque"``, limits for servos whose file gives none.

    Raises:
      RobotError: the file is missing, does not parse or breaks one of that page's rules.

    Examples:
      >>> solo = load("solo12")
      >>> solo.floating_base, solo.nq, solo.nv, solo.action_dim
      (True, 19, 18, 12)
    """
    if actuators not in ACTUATORS:
        raise RobotError(f"actuators={actuators!r} is not allowed: one of {ACTUATORS}")
    path = resolve(name_or_path)
    warned = []  # MuJoCo's parser warns of a 'nan' it then ignores (mass="nan": density)
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warned.append)
    try:
        model = compile_file(path)
    except Exception as error:  # mujoco raises ValueError with the parser's message
        raise RobotError(
            f"robot={name_or_path!r}: MJCF file {path} does not parse: {error}"
        ) from error
    finally:
        mujoco.set_mju_user_warning(previous)
    name = os.path.splitext(os.path.basename(path))[0]
    where = f"robot={name_or_path!r} ({path})"
    bad = nonfinite_fields(model)
    if bad or any("NaN" in message for message in warned):
        found = f"in {bad}" if bad else "in the file (MuJoCo: 'XML contains a NaN')"
        raise RobotError(
            f"{where}: NaN or infinite values {found}; a model needs finite numbers "
            "(MuJoCo compiles them, and the simulation would not be what the file says)"
        )
    for message in warned:  # any other parser warning goes where MuJoCo would send it
        if previous is not None:
            previous(message)
        else:
            print(f"WARNING: {message}\n")
    # A quadruped gets its ground and foot sensors (converted or not: one MjSpec takes both
    # edits) and, without a keyframe 'home', its standing pose as home.
    model, added, standing, spec = _as_quadruped(path, model)
    servos = {}
    held, keep = held_joints(model)
    if actuators == "torque":
        model, servos = convert(path, model, torque_limit, where, keep, spec=spec)
    floating_base = False
    unactuated = set()
    for j in range(model.njnt):
        jtype = int(model.jnt_type[j])
        jname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        is_root_free = (
            jtype == int(mujoco.mjtJoint.mjJNT_FREE)
            and j == 0
            and model.body_parentid[model.jnt_bodyid[j]] == 0
        )
        if is_root_free:
            floating_base = True
            unactuated.update(range(int(model.jnt_dofadr[j]), int(model.jnt_dofadr[j]) + 6))
            continue
        if jtype not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            kind = mujoco.mjtJoint(jtype).name
            raise RobotError(
                f"{where}: joint {jname!r} is {kind}; supported are hinge and slide joints, "
                "on a fixed base or below one free joint at the root (a floating base)"
            )
    if model.nu == 0:  # after the joint types: a ball joint is the first problem to report
        raise RobotError(f"{where} has no actuators; add one <motor> per joint")
    actuator_of_joint = -np.ones(model.nv, dtype=np.int32)
    gear = np.ones(model.nv)
    torque_limit = np.full(model.nv, np.inf)
    limit_source = [""] * model.nv
    for a in range(model.nu):
        if a in keep:
            continue  # moves only held joints: kept as published
        aname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}"
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            trn = mujoco.mjtTrn(int(model.actuator_trntype[a])).name[len("mjTRN_") :].lower()
            raise RobotError(
                f"{where}: actuator {aname!r} has a {trn} transmission; every actuator must "
                "drive one hinge or slide joint directly (joint transmission), because the "
                "controller outputs one torque per joint"
            )
        is_motor = (
            int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            and int(model.actuator_dyntype[a]) == int(mujoco.mjtDyn.mjDYN_NONE)
            and int(model.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_FIXED)
            and int(model.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_NONE)
            and model.actuator_gainprm[a, 0] == 1.0
        )
        if not is_motor:
            raise RobotError(
                f"{where}: actuator {aname!r} is not a torque motor (need <motor joint=...>: "
                "joint transmission, no activation dynamics, unit fixed gain, no bias); "
                "position/velocity servos are not allowed because the controller outputs "
                f"torques; {_OPTION} (see docs/how-to/own-robot.md)"
            )
        dof = model.jnt_dofadr[model.actuator_trnid[a, 0]]
        if actuator_of_joint[dof] >= 0:
            raise RobotError(f"{where}: joint dof {dof} is driven by more than one actuator")
        actuator_of_joint[dof] = a
        gear[dof] = model.actuator_gear[a, 0]
        if a in servos:
            torque_limit[dof], limit_source[dof] = servos[a][1:]
            continue
        bound = actuator_torque_limit(model, a)
        if bound is not None:
            torque_limit[dof], limit_source[dof] = bound
    if np.any(actuator_of_joint[sorted(unactuated)] >= 0):
        raise RobotError(f"{where}: the floating base (free joint) cannot be actuated")
    not_driven = unactuated | {int(model.jnt_dofadr[j]) for j in held}  # base, held joints
    others = [d for d in range(model.nv) if d not in not_driven]
    actuated = np.array([d for d in others if actuator_of_joint[d] >= 0], dtype=np.int32)
    passive = [d for d in others if actuator_of_joint[d] < 0]
    if actuated.size == 0:
        raise RobotError(
            f"{where}: no joint is driven by a torque motor of its own; the controller needs "
            "at least one (joints coupled by an equality constraint are held, not driven)"
        )
    if not np.all(np.isfinite(torque_limit[actuated])):
        unlimited = [
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.dof_jntid[d])
            for d in actuated[~np.isfinite(torque_limit[actuated])]
        ]
        raise RobotError(
            f"{where}: motors of joints {unlimited} have no torque limit; set ctrlrange "
            "(with ctrllimited), forcerange or the joint's actuatorfrcrange, the controller's "
            "outputs are squashed into it"
        )
    if timestep is not None:
        model.opt.timestep = timestep
    joint_range = np.where(
        model.jnt_limited[:, None].astype(bool),
        model.jnt_range,
        np.array([-np.inf, np.inf]),
    )
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    home = model.key_qpos[key].copy() if key >= 0 else model.qpos0.copy()
    if key < 0 and standing is not None:
        home = standing.copy()
    joint_names = tuple(
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        for j in range(model.njnt)
    )
    hold_ctrl = None
    if keep:
        hold_ctrl = np.zeros(model.nu)
        if key >= 0:
            hold_ctrl[sorted(keep)] = model.key_ctrl[key][sorted(keep)]
    robot = Robot(
        name=name,
        path=path,
        mj_model=model,
        joint_names=joint_names,
        joint_range=joint_range,
        torque_limit=torque_limit[actuated],
        gear=gear[actuated],
        actuator_of_joint=actuator_of_joint[actuated],
        home=home,
        actuated_dofs=actuated,
        floating_base=floating_base,
        actuators=actuators,
        limit_source=tuple(limit_source[d] for d in actuated),
        converted=tuple(
            (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}", kind)
            for a, (kind, _, _) in servos.items()
        ),
        held_joints=tuple(joint_names[j] for j in sorted(held)),
        passive_joints=tuple(joint_names[int(model.dof_jntid[d])] for d in passive),
        hold_ctrl=hold_ctrl,
        added=tuple(added),
    )
    # Build the device copy now, never inside a jit trace. A model MJX cannot build still
    # loads: the native simulator runs it, and whatever needs MJX raises the RobotError.
    robot.mjx_error  # noqa: B018
    return robot
