"""The Solo12 quadruped itself: its model file, the floor's forces on its feet (from the
contact sensors), its leg kinematics, and when it has fallen.

The reference motions recorded on this robot are :mod:`cfm_jax.locomotion`'s; the legged
tasks (:mod:`cfm_jax.tasks.legged`) read the foot forces and falls from here.

Conventions (see docs/locomotion.md):

* ``qpos`` (19) = base position (3), base quaternion w x y z (4), 12 joints in the order
  FL, FR, HL, HR, each (HAA, HFE, KFE); ``qvel`` (18) = base linear velocity (world frame),
  base angular velocity (base frame, MuJoCo's free-joint convention), 12 joint velocities.
* ``foot_force (..., 4, 3)``: force the floor exerts on each foot, world frame, in newtons
  (z > 0 when standing).
* Leg kinematics are in the base frame, closed form of the chain in ``robots/solo12.xml``.

Examples:
  >>> from cfm_jax import solo12
  >>> standing = solo12.load_model().key("home").qpos
  >>> bool(solo12.fell(standing)), np.round(solo12.hip_positions()[0], 4).tolist()
  (False, [0.1946, 0.148, -0.2229])
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from cfm_jax.config import ConfigError

LEGS = ("FL", "FR", "HL", "HR")
JOINTS = tuple(f"{leg}_{j}" for leg in LEGS for j in ("HAA", "HFE", "KFE"))
# (front +1 / hind -1, left +1 / right -1) for each leg, [2.1] of the facts sheet.
LEG_SIGNS = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float)

# Kinematic constants of robots/solo12.xml (facts sheet [2.2], [2.4]).
HAA_X, HAA_Y = 0.2141, 0.0875
HFE_DX = 0.0195  # HFE sits 19.5 mm inboard of HAA
KNEE_Y = 0.014 + 0.03745  # lateral offset of the knee from the HAA axis (shoulder frame)
LEG_Y = KNEE_Y + 0.009  # lateral offset of the foot from the HAA axis (shoulder frame)
L_UPPER = L_LOWER = 0.16
FOOT_RADIUS = 0.017
BASE_HALF = np.array([0.196, 0.05, 0.025])  # visual base box half-extents
# The 8 corners of the base box in the base frame, (8, 3).
BASE_CORNERS = (
    np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    * BASE_HALF
)

SENSOR_SLOT = 10  # per foot: found (1), force in contact frame (3), normal (3), tangent (3)
HOME_JOINTS = np.array([0, 0.8, -1.6, 0, 0.8, -1.6, 0, -0.8, 1.6, 0, -0.8, 1.6])
KP, KD = 5.0, 0.1  # robot_properties_solo default joint PD [2.5]


def model_path() -> str:
    """Path of the shipped ``solo12.xml`` (package data, or ``robots/`` of a checkout).

    Returns:
      The file's path (str).

    Examples:
      >>> model_path().endswith("solo12.xml")
      True
    """
    try:
        import importlib.resources

        path = importlib.resources.files("cfm_jax._robot_files") / "solo12.xml"
        if path.is_file():
            return str(path)
    except ModuleNotFoundError:
        pass
    return str(Path(__file__).resolve().parent.parent / "robots" / "solo12.xml")


def load_model(path: str | None = None):
    """``mujoco.MjModel`` of Solo12 (the C model alone, no :class:`cfm_jax.robots.Robot`).

    Args:
      path: an MJCF file, or None for :func:`model_path`.

    Returns:
      The ``mujoco.MjModel``.

    Examples:
      >>> model = load_model()
      >>> model.nq, model.nv, model.nu, model.nsensordata, model.opt.timestep
      (19, 18, 12, 40, 0.002)
    """
    import mujoco

    return mujoco.MjModel.from_xml_path(path or model_path())


KINEMATICS_TOLERANCE = 1e-6
"""Largest foot or knee position difference (m) between MuJoCo and the closed-form leg
kinematics that :func:`check_model` accepts."""


def check_model(model, name: str = "solo12") -> None:
    """Check that ``model`` has the Solo12's structure and leg geometry, which the legged
    tasks' references and fall rule assume (:func:`leg_fk`, :func:`leg_ik`,
    :func:`knee_positions`): a free base then the 12 joints :data:`JOINTS` in that order, 12
    actuators, the sites ``<leg>_foot`` and bodies ``<leg>_lower_leg``, and foot and knee
    positions that the closed form reproduces within :data:`KINEMATICS_TOLERANCE` at three
    poses. Masses, inertias, friction, gains and the timestep may differ.

    Args:
      model: a ``mujoco.MjModel``.
      name: the robot's name, for the message.

    Raises:
      ConfigError: saying what differs from the Solo12.

    Examples:
      >>> check_model(load_model())  # the model file of this package passes
    """
    import mujoco

    def fail(what: str) -> None:
        raise ConfigError(
            f"robot {name!r} is not allowed for the legged tasks: they generate their "
            f"references with the Solo12's leg kinematics (cfm_jax.solo12), and {what}"
        )

    if model.nq != 19 or model.nv != 18 or model.nu != 12:
        fail(f"it has nq={model.nq}, nv={model.nv}, nu={model.nu} instead of 19, 18, 12")
    if int(model.jnt_type[0]) != int(mujoco.mjtJoint.mjJNT_FREE):
        fail("its first joint is not a free joint (the floating base)")
    joints = tuple(model.joint(i).name for i in range(1, model.njnt))
    if joints != JOINTS:
        fail(f"its joints are {joints} instead of {JOINTS}")
    objects = (
        (mujoco.mjtObj.mjOBJ_SITE, "site", "_foot"),
        (mujoco.mjtObj.mjOBJ_BODY, "body", "_lower_leg"),
    )
    for kind, word, suffix in objects:
        for leg in LEGS:
            if mujoco.mj_name2id(model, kind, leg + suffix) < 0:
                fail(f"it has no {word} {leg + suffix!r}")
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    for pose in (HOME_JOINTS, *(HOME_JOINTS + rng.uniform(-0.5, 0.5, (2, 12)))):
        data.qpos[:7] = [0, 0, 0, 1, 0, 0, 0]  # base at the origin: world frame = base frame
        data.qpos[7:] = pose
        mujoco.mj_kinematics(model, data)
        knees = knee_positions(pose)
        for i, leg in enumerate(LEGS):
            q = pose[3 * i : 3 * i + 3]
            for point, mine, theirs in (
                ("foot", leg_fk(q, i), data.site(f"{leg}_foot").xpos),
                ("knee", knees[i], data.body(f"{leg}_lower_leg").xpos),
            ):
                gap = float(np.max(np.abs(mine - theirs)))
                if gap > KINEMATICS_TOLERANCE:
                    fail(
                        f"its {leg} {point} lies {gap:.3g} m from where the Solo12's leg "
                        f"kinematics put it (joints {np.round(q, 3).tolist()})"
                    )


# ---- contact forces --------------------------------------------------------------------------


def foot_forces(sensordata, xp=np):
    """World-frame force of the floor on each foot, ``(..., 4, 3)``, from ``sensordata``.

    Works on ``(..., 40)`` arrays (the four contact sensors of ``solo12.xml``), with NumPy or
    ``jax.numpy`` (pass ``xp=jnp``). The contact sensors report the force in the contact frame
    (normal, tangent, bitangent = normal x tangent, the force that geom1 = foot exerts on
    geom2 = floor) together with the frame's normal and tangent in the world frame; this
    rotates it to the world frame and flips the sign so it is the floor's force on the foot.
    Slots with no contact are all zero, giving zero force.

    Args:
      sensordata: ``(..., nsensordata)`` whose first 40 entries are the four feet's contact
        sensors (10 each: found, force, normal, tangent), as in ``solo12.xml``.
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Returns:
      ``(..., 4, 3)`` forces (N), feet in the order FL, FR, HL, HR.

    Examples:
      >>> import mujoco
      >>> model = load_model()
      >>> data = mujoco.MjData(model)
      >>> mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
      >>> mujoco.mj_forward(model, data)
      >>> force = foot_forces(data.sensordata)
      >>> force.shape, np.round(force[:, 2], 1).tolist()  # the floor pushes each foot up
      ((4, 3), [6.6, 6.6, 6.6, 6.6])
    """
    s = xp.reshape(sensordata[..., : 4 * SENSOR_SLOT], sensordata.shape[:-1] + (4, SENSOR_SLOT))
    f, n, t = s[..., 1:4], s[..., 4:7], s[..., 7:10]
    b = xp.cross(n, t)
    world = f[..., 0:1] * n + f[..., 1:2] * t + f[..., 2:3] * b
    return -world


def foot_contact(sensordata, xp=np):
    """Whether each foot touches the floor, ``(..., 4)`` bool, from the sensors' found count.

    Args:
      sensordata: ``(..., nsensordata)`` as for :func:`foot_forces`.
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Returns:
      ``(..., 4)`` bool, feet in the order FL, FR, HL, HR.

    Examples:
      >>> foot_contact(np.zeros(40)).tolist()  # no sensor found a contact
      [False, False, False, False]
    """
    s = xp.reshape(sensordata[..., : 4 * SENSOR_SLOT], sensordata.shape[:-1] + (4, SENSOR_SLOT))
    return s[..., 0] > 0.5


# ---- leg kinematics (base frame) ------------------------------------------------------------


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def leg_fk(q_leg, leg: int) -> np.ndarray:
    """Foot centre of leg ``leg`` (0..3 = FL, FR, HL, HR) in the base frame for joints
    ``(HAA, HFE, KFE)``; closed form of the chain in solo12.xml ([2.2]).

    Args:
      q_leg: the leg's joint angles ``(HAA, HFE, KFE)``, ``(3,)`` (rad).
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR).

    Returns:
      ``(3,)`` foot centre position (m).

    Examples:
      >>> np.round(leg_fk([0.0, 0.8, -1.6], 0), 4).tolist()  # FL at the home pose
      [0.1946, 0.148, -0.2229]
    """
    sx, sy = LEG_SIGNS[leg]
    q0, q1, q2 = q_leg
    x = -sx * HFE_DX - L_UPPER * np.sin(q1) - L_LOWER * np.sin(q1 + q2)
    z = -L_UPPER * np.cos(q1) - L_LOWER * np.cos(q1 + q2)
    return np.array([sx * HAA_X, sy * HAA_Y, 0.0]) + _rot_x(q0) @ np.array([x, sy * LEG_Y, z])


def _knees(q_legs, signs, xp):
    """Knees of legs with joints ``q_legs (..., 3)`` and signs ``signs (..., 2)`` (broadcast
    together), base frame ``(..., 3)``: the HFE chain rotated about x by HAA."""
    sx, sy = signs[..., 0], signs[..., 1]
    q0, q1 = q_legs[..., 0], q_legs[..., 1]
    x = -sx * HFE_DX - L_UPPER * xp.sin(q1)
    y, z = sy * KNEE_Y, -L_UPPER * xp.cos(q1)
    c, s = xp.cos(q0), xp.sin(q0)
    return xp.stack([sx * HAA_X + x, sy * HAA_Y + c * y - s * z, s * y + c * z], axis=-1)


def knee_fk(q_leg, leg: int) -> np.ndarray:
    """Knee (KFE axis) of leg ``leg`` in the base frame.

    Args:
      q_leg: the leg's joint angles ``(HAA, HFE, KFE)``, ``(3,)`` (rad); KFE does not move
        the knee.
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR).

    Returns:
      ``(3,)`` knee position (m).

    Examples:
      >>> np.round(knee_fk([0.0, 0.8, -1.6], 0), 4).tolist()  # FL at home: knee behind the hip
      [0.0798, 0.139, -0.1115]
    """
    return _knees(np.asarray(q_leg, float), LEG_SIGNS[leg], np)


def knee_positions(joints, xp=np):
    """The four knees in the base frame, ``(..., 4, 3)``, from the 12 joint angles
    ``(..., 12)``: :func:`knee_fk` of every leg at once, with NumPy or ``jax.numpy``
    (traceable: no Python loop over the batch).

    Args:
      joints: ``(..., 12)`` joint angles, legs FL, FR, HL, HR, each (HAA, HFE, KFE) (rad).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Returns:
      ``(..., 4, 3)`` knee positions (m), legs FL, FR, HL, HR.

    Examples:
      >>> np.round(knee_positions(HOME_JOINTS)[:, 2], 4).tolist()  # standing: all at -0.11 m
      [-0.1115, -0.1115, -0.1115, -0.1115]
    """
    q = xp.reshape(joints, joints.shape[:-1] + (4, 3))
    return _knees(q, xp.asarray(LEG_SIGNS, dtype=q.dtype), xp)


def leg_ik(foot, leg: int) -> np.ndarray:
    """Joints ``(HAA, HFE, KFE)`` that put the foot centre of leg ``leg`` at ``foot`` (base
    frame). Knee branch of the ODRI demos: front legs KFE < 0, hind legs KFE > 0 (knees point
    to the body centre). Unreachable targets are clipped to the workspace boundary.

    Args:
      foot: ``(3,)`` target of the foot centre in the base frame (m).
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR).

    Returns:
      ``(3,)`` joint angles ``(HAA, HFE, KFE)`` (rad).

    Examples:
      >>> q = leg_ik(leg_fk([0.0, 0.8, -1.6], 0), 0)  # inverse of leg_fk on this branch
      >>> np.round(q, 6).tolist()
      [0.0, 0.8, -1.6]
    """
    sx, sy = LEG_SIGNS[leg]
    r = np.asarray(foot, float) - [sx * HAA_X, sy * HAA_Y, 0.0]
    ys = sy * LEG_Y
    zs = -np.sqrt(max(r[1] ** 2 + r[2] ** 2 - ys**2, 1e-12))
    q0 = np.arctan2(r[2], r[1]) - np.arctan2(zs, ys)
    q0 = (q0 + np.pi) % (2 * np.pi) - np.pi
    x, z = r[0] + sx * HFE_DX, zs
    d2 = x * x + z * z
    c2 = np.clip((d2 - L_UPPER**2 - L_LOWER**2) / (2 * L_UPPER * L_LOWER), -1.0, 1.0)
    q2 = -sx * np.arccos(c2)
    phi = np.arctan2(-x, -z)  # angle of the hip->foot line from straight down, + backward
    q1 = phi - q2 / 2  # equal link lengths
    return np.array([q0, q1, q2])


def hip_positions() -> np.ndarray:
    """Nominal foot positions under the hips at the home pose, base frame ``(4, 3)``.

    Returns:
      ``(4, 3)`` foot centres (m), legs FL, FR, HL, HR (:func:`leg_fk` of the home joints).

    Examples:
      >>> np.round(hip_positions(), 4)
      array([[ 0.1946,  0.148 , -0.2229],
             [ 0.1946, -0.148 , -0.2229],
             [-0.1946,  0.148 , -0.2229],
             [-0.1946, -0.148 , -0.2229]])
    """
    return np.array([leg_fk(HOME_JOINTS[3 * i : 3 * i + 3], i) for i in range(4)])


def quat_to_mat(quat, xp=np):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)`` (w, x, y, z).

    Args:
      quat: unit quaternions ``(..., 4)``, scalar first (MuJoCo's convention).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Returns:
      ``(..., 3, 3)`` rotation matrices.

    Examples:
      >>> quarter_turn = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # about z
      >>> np.round(quat_to_mat(quarter_turn), 6) + 0.0  # + 0.0: no negative zeros
      array([[ 0., -1.,  0.],
             [ 1.,  0.,  0.],
             [ 0.,  0.,  1.]])
    """
    w, x, y, z = (quat[..., i] for i in range(4))
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


# ---- fall detection -------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FallLimits:
    """Thresholds of :func:`fell`. The defaults are the library's one fall rule,
    :data:`FALL`, used by the reference checks and by the legged tasks' training alike.

    Attributes:
      min_base_height: lowest allowed base origin height (m; standing is 0.239 m, the
        deepest crouch of the jumps ~0.16 m).
      max_tilt: largest allowed angle between the base z axis and the world z axis (rad).
      body_clearance: the lowest base-box corner (and knee, with ``knees``) must stay this
        far above the floor (m; the model has no body-floor contacts, so touching the floor
        is detected geometrically; the knee point is the knee joint's axis, inside the lower
        leg's 8 mm capsule, so at 5 mm the leg's shell is already in the floor).
      knees: whether the four knees count as body points for ``body_clearance``.
      max_pull: largest downward normal force (N) a foot may exert on the floor when
        :func:`fell` is given the foot forces (beyond it the state is non-physical).

    Examples:
      >>> qpos = load_model().key("home").qpos  # standing
      >>> bool(fell(qpos)), bool(fell(qpos, limits=FallLimits(min_base_height=0.3)))
      (False, True)
    """

    min_base_height: float = 0.10
    max_tilt: float = 0.8
    body_clearance: float = 0.005
    knees: bool = True
    max_pull: float = 1e-6


FALL = FallLimits()
"""The fall rule of the library: base below 0.10 m, tilt above 0.8 rad, or a base-box corner
or knee within 5 mm of the floor. The reference checks (:func:`cfm_jax.locomotion.replay`)
and the legged tasks' ``fell`` metric and terminal steps
(:meth:`cfm_jax.tasks.legged.LeggedTask.record`) both use it."""


def fell(qpos, foot_force=None, limits: FallLimits = FALL, xp=np):
    """True where the robot has fallen: base too low, body (base-box corner, or knee when
    ``limits.knees``) closer to the floor than ``limits.body_clearance``, or base tilted more
    than ``limits.max_tilt``. ``qpos (..., 19)``; returns ``(...)`` bool. ``foot_force
    (..., 4, 3)`` is optional: a foot pulling the floor (normal force below
    ``-limits.max_pull``) also counts, which only happens for non-physical states.

    Knees are computed in closed form (:func:`knee_positions`), the base corners from the
    base pose. With ``xp=jax.numpy`` it traces under ``jit`` and ``vmap`` (no Python loop
    over the batch), in the precision of ``qpos``.

    Args:
      qpos: ``(..., 19)`` positions (base pose, 12 joints).
      foot_force: ``(..., 4, 3)`` floor forces on the feet (world frame), or None.
      limits: the :class:`FallLimits` (default: :data:`FALL`, the library's rule).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Returns:
      ``(...)`` bool array.

    Examples:
      >>> standing = load_model().key("home").qpos
      >>> low = standing.copy()
      >>> low[2] = 0.05  # base origin 5 cm above the floor
      >>> fell(np.stack([standing, low])).tolist()
      [False, True]
      >>> kneel = standing.copy()
      >>> kneel[2] = 0.11  # knees at the floor, base above 0.10 m
      >>> no_knees = FallLimits(body_clearance=0.0, knees=False)
      >>> bool(fell(kneel)), bool(fell(kneel, limits=no_knees))
      (True, False)
    """
    qpos = np.asarray(qpos, float) if xp is np else xp.asarray(qpos)
    quat = qpos[..., 3:7] / xp.linalg.norm(qpos[..., 3:7], axis=-1, keepdims=True)
    rotation = quat_to_mat(quat, xp=xp)
    up = rotation[..., 2, :]  # world z components of the base axes
    height = qpos[..., 2]
    corners = xp.asarray(BASE_CORNERS, dtype=qpos.dtype)
    lowest = xp.min(height[..., None] + xp.einsum("kj,...j->...k", corners, up), axis=-1)
    if limits.knees:
        knees = knee_positions(qpos[..., 7:19], xp=xp)  # (..., 4, 3), base frame
        knee_z = height[..., None] + xp.einsum("...j,...kj->...k", up, knees)
        lowest = xp.minimum(lowest, xp.min(knee_z, axis=-1))
    out = (
        (height < limits.min_base_height)
        | (xp.arccos(xp.clip(up[..., 2], -1.0, 1.0)) > limits.max_tilt)
        | (lowest < limits.body_clearance)
    )
    if foot_force is not None:
        fz = xp.asarray(foot_force)[..., 2]
        out = out | xp.any(fz < -limits.max_pull, axis=-1)
    return xp.asarray(out)
