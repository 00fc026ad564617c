"""The Solo12 quadruped: model file, the floor's forces on the feet, leg kinematics, fall rule.

``qpos`` (19): base position, quaternion (w, x, y, z), 12 joints FL, FR, HL, HR x (HAA, HFE,
KFE); ``qvel`` (18): base linear (world) and angular (base frame) velocity, joints."""

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
    return str(Path(__file__).resolve().parents[2] / "robots" / "solo12.xml")


def load_model(path: str | None = None):
    """``mujoco.MjModel`` of Solo12 (the C model alone, no :class:`cfm_jax.sim.robots.Robot`).

    Args:
      path: an MJCF file, or None for :func:`model_path`.

    Examples:
      >>> model = load_model()
      >>> model.nq, model.nv, model.nu, model.nsensordata, model.opt.timestep
      (19, 18, 12, 40, 0.002)
    """
    import mujoco

    return mujoco.MjModel.from_xml_path(path or model_path())


KINEMATICS_TOLERANCE = 1e-6
"""Largest foot or knee gap (m) to the closed-form kinematics that :func:`check_model` accepts."""


def check_model(model, name: str = "solo12") -> None:
    """Check that ``model`` is built like the Solo12 (where the legged tasks use this module's
    closed forms, :func:`cfm_jax.tasks.locomotion.legs_of`; any other quadruped is read from its
    file): free base, :data:`JOINTS`, 12 actuators, feet and knees where :func:`leg_fk`,
    :func:`knee_positions` say.

    Args:
      model: a ``mujoco.MjModel``; masses, inertias, friction, gains and timestep may differ.
      name: the robot's name, for the message.

    Raises:
      ConfigError: saying what differs from the Solo12.

    Examples:
      >>> check_model(load_model())  # the model file of this package passes
    """
    import mujoco

    def fail(what: str) -> None:
        raise ConfigError(
            f"robot {name!r} is not built like the Solo12 (the closed-form kinematics of "
            f"cfm_jax.sim.solo12 do not apply to it): {what}"
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
    """The floor's force on each foot (N, world frame), ``(..., 4, 3)``, from the contact sensors.

    Args:
      sensordata: ``(..., nsensordata)``, first the four feet's sensors (10 each, FL, FR, HL, HR).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Examples:
      >>> import mujoco
      >>> data = mujoco.MjData(model := load_model())
      >>> mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
      >>> mujoco.mj_forward(model, data)
      >>> np.round(foot_forces(data.sensordata)[:, 2], 1).tolist()  # the floor pushes each foot up
      [6.6, 6.6, 6.6, 6.6]
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
    """Foot centre of leg ``leg``, base frame (m), ``(3,)``: the closed form of solo12.xml's chain.

    Args:
      q_leg: the leg's joint angles ``(HAA, HFE, KFE)`` (rad).
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR).

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
    """Knees ``(..., 3)`` of legs with joints ``q_legs (..., 3)`` and signs ``signs (..., 2)``."""
    sx, sy = signs[..., 0], signs[..., 1]
    q0, q1 = q_legs[..., 0], q_legs[..., 1]
    x = -sx * HFE_DX - L_UPPER * xp.sin(q1)
    y, z = sy * KNEE_Y, -L_UPPER * xp.cos(q1)
    c, s = xp.cos(q0), xp.sin(q0)
    return xp.stack([sx * HAA_X + x, sy * HAA_Y + c * y - s * z, s * y + c * z], axis=-1)


def knee_fk(q_leg, leg: int) -> np.ndarray:
    """Knee (KFE axis) of leg ``leg``, base frame (m), ``(3,)``.

    Args:
      q_leg: the leg's joint angles ``(HAA, HFE, KFE)`` (rad); KFE does not move the knee.
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR).

    Examples:
      >>> np.round(knee_fk([0.0, 0.8, -1.6], 0), 4).tolist()  # FL at home: knee behind the hip
      [0.0798, 0.139, -0.1115]
    """
    return _knees(np.asarray(q_leg, float), LEG_SIGNS[leg], np)


def knee_positions(joints, xp=np):
    """The four knees, base frame (m), ``(..., 4, 3)``: :func:`knee_fk` of every leg, traceable.

    Args:
      joints: ``(..., 12)`` joint angles (rad), legs FL, FR, HL, HR, each (HAA, HFE, KFE).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Examples:
      >>> np.round(knee_positions(HOME_JOINTS)[:, 2], 4).tolist()  # standing: all at -0.11 m
      [-0.1115, -0.1115, -0.1115, -0.1115]
    """
    q = xp.reshape(joints, joints.shape[:-1] + (4, 3))
    return _knees(q, xp.asarray(LEG_SIGNS, dtype=q.dtype), xp)


def leg_ik(foot, leg: int) -> np.ndarray:
    """Joints ``(HAA, HFE, KFE)`` (rad) that put leg ``leg``'s foot centre at ``foot``.

    Args:
      foot: ``(3,)`` target of the foot centre, base frame (m); unreachable ones are clipped.
      leg: 0, 1, 2 or 3 (FL, FR, HL, HR); the ODRI knee branch: front KFE < 0, hind KFE > 0.

    Examples:
      >>> np.round(leg_ik(leg_fk([0.0, 0.8, -1.6], 0), 0), 6).tolist()  # inverse of leg_fk
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
    """Foot centres at the home pose, base frame (m), ``(4, 3)``: :func:`leg_fk` of each leg.

    Examples:
      >>> np.round(hip_positions()[1], 4).tolist()  # FR
      [0.1946, -0.148, -0.2229]
    """
    return np.array([leg_fk(HOME_JOINTS[3 * i : 3 * i + 3], i) for i in range(4)])


def quat_to_mat(quat, xp=np):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``.

    Args:
      quat: unit quaternions ``(..., 4)``, scalar first (w, x, y, z; MuJoCo's convention).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Examples:
      >>> quat_to_mat(np.array([0.0, 0.0, 0.0, 1.0])).diagonal().tolist()  # half turn about z
      [-1.0, -1.0, 1.0]
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
    """Thresholds of :func:`fell`; the defaults are the library's one fall rule, :data:`FALL`.

    Attributes:
      min_base_height: lowest base origin height (m; standing 0.239, deepest jump crouch ~0.16).
      max_tilt: largest angle between the base's and the world's z axes (rad).
      body_clearance: least height (m) of the base-box corners (and knees) above the floor.
      knees: whether the knees (joint axes, inside the 8 mm leg shell) count as body points.
      max_pull: largest downward force (N) a foot may exert on the floor (beyond: non-physical).

    Examples:
      >>> bool(fell(load_model().key("home").qpos, limits=FallLimits(min_base_height=0.3)))
      True
    """

    min_base_height: float = 0.10
    max_tilt: float = 0.8
    body_clearance: float = 0.005
    knees: bool = True
    max_pull: float = 1e-6


FALL = FallLimits()
"""The library's fall rule: reference checks, legged tasks' ``fell`` metric and terminal steps."""


def fell(qpos, foot_force=None, limits: FallLimits = FALL, xp=np):
    """Where the robot has fallen, ``(...)`` bool: base too low or tilted, body near the floor, or
    (given ``foot_force``) a foot pulling the floor; thresholds in :class:`FallLimits`.

    Args:
      qpos: ``(..., 19)`` positions (base pose, 12 joints).
      foot_force: ``(..., 4, 3)`` floor forces on the feet (world frame), or None.
      limits: the :class:`FallLimits` (default: :data:`FALL`).
      xp: the array module, ``numpy`` or ``jax.numpy`` (traces under ``jit`` and ``vmap``).

    Examples:
      >>> kneel = load_model().key("home").qpos.copy()
      >>> kneel[2] = 0.11  # knees at the floor, base above 0.10 m
      >>> bool(fell(kneel)), bool(fell(kneel, limits=FallLimits(body_clearance=0.0, knees=False)))
      (True, False)
    """
    return body_fell(qpos, BASE_CORNERS, _knee_points(limits, xp), limits, foot_force, xp)


def fall_terms(qpos, foot_force=None, limits: FallLimits = FALL, xp=np) -> dict:
    """The clauses of :func:`fell` one by one (:func:`body_fall_terms`).

    Args:
      qpos: ``(..., 19)`` positions (base pose, 12 joints).
      foot_force: ``(..., 4, 3)`` floor forces on the feet (world frame), or None.
      limits: the :class:`FallLimits` (default: :data:`FALL`).
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Examples:
      >>> low = load_model().key("home").qpos.copy()
      >>> low[2] = 0.05
      >>> sorted(what for what, broken in fall_terms(low).items() if broken)[0]
      'a body point less than 0.005 m above the floor'
    """
    return body_fall_terms(qpos, BASE_CORNERS, _knee_points(limits, xp), limits, foot_force, xp)


def _knee_points(limits: FallLimits, xp):
    """The Solo12's knees as body points of :func:`body_fell`, or None."""
    if not limits.knees:
        return None
    return lambda qpos: knee_positions(qpos[..., 7:19], xp=xp)


def body_fell(qpos, corners, knees, limits: FallLimits, foot_force=None, xp=np):
    """:func:`fell` of a floating base whose body points are ``corners`` (base frame,
    ``(k, 3)``) and the points ``knees(qpos)`` returns (base frame, ``(..., m, 3)``; None:
    none), judged by ``limits`` (its ``knees`` field is not read): the rule of every
    quadruped (:func:`cfm_jax.sim.quadruped.fall_rule`).

    Args:
      qpos: ``(..., nq)`` positions (base pose first).
      corners: the base's points, base frame, ``(k, 3)``.
      knees: a function of ``qpos`` giving further body points, or None.
      limits: the :class:`FallLimits`.
      foot_force: ``(..., 4, 3)`` floor forces on the feet (world frame), or None.
      xp: the array module, ``numpy`` or ``jax.numpy``.

    Examples:
      >>> bool(body_fell(load_model().key("home").qpos, BASE_CORNERS, None, FALL))
      False
    """
    terms = list(body_fall_terms(qpos, corners, knees, limits, foot_force, xp).values())
    out = terms[0]
    for term in terms[1:]:
        out = out | term
    return xp.asarray(out)


def body_fall_terms(qpos, corners, knees, limits: FallLimits, foot_force=None, xp=np) -> dict:
    """The clauses of :func:`body_fell` one by one, ``{what breaks the rule, in words: bool}``.

    Args:
      qpos: positions, base pose first, ``(..., nq)``.
      corners: points of the base in its own frame, ``(k, 3)``.
      knees: ``knees(qpos)``, more body points in the base frame, or None.
      limits: the thresholds, a :class:`FallLimits`.
      foot_force: the floor's forces on the four feet in the world frame, ``(..., 4, 3)``;
        None: no foot clause.
      xp: ``numpy`` or ``jax.numpy``.

    Examples:
      >>> rolled = load_model().key("home").qpos.copy()
      >>> rolled[3:7] = (np.cos(0.45), np.sin(0.45), 0.0, 0.0)  # 0.9 rad about x
      >>> terms = body_fall_terms(rolled, BASE_CORNERS, None, FALL)
      >>> [what for what, broken in terms.items() if broken]
      ['the base tilted more than 46 deg']
    """
    qpos = np.asarray(qpos, float) if xp is np else xp.asarray(qpos)
    quat = qpos[..., 3:7] / xp.linalg.norm(qpos[..., 3:7], axis=-1, keepdims=True)
    rotation = quat_to_mat(quat, xp=xp)
    up = rotation[..., 2, :]  # world z components of the base axes
    height = qpos[..., 2]
    corners = xp.asarray(corners, dtype=qpos.dtype)
    lowest = xp.min(height[..., None] + xp.einsum("kj,...j->...k", corners, up), axis=-1)
    if knees is not None:
        points = knees(qpos)  # (..., m, 3), base frame
        knee_z = height[..., None] + xp.einsum("...j,...kj->...k", up, points)
        lowest = xp.minimum(lowest, xp.min(knee_z, axis=-1))
    tilt = float(np.degrees(limits.max_tilt))
    terms = {
        f"the base origin lower than {limits.min_base_height:.3g} m": (
            height < limits.min_base_height
        ),
        f"the base tilted more than {tilt:.0f} deg": (
            xp.arccos(xp.clip(up[..., 2], -1.0, 1.0)) > limits.max_tilt
        ),
        f"a body point less than {limits.body_clearance:.3g} m above the floor": (
            lowest < limits.body_clearance
        ),
    }
    if foot_force is not None:
        fz = xp.asarray(foot_force)[..., 2]
        terms[f"a foot pulling the floor (more than {limits.max_pull:.3g} N)"] = xp.any(
            fz < -limits.max_pull, axis=-1
        )
    return terms
