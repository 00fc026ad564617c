"""Checks of the hand-written robot models in robots/ against independent oracles.

The oracle for the iiwa is the facts sheet (shared reference robot_facts.md, section 1); the
section numbers [1.x] below refer to it. Numbers are typed in here from the sheet, not read
from the XML, and several are re-derived in closed form (gravity torques, forward
kinematics) or from a second model built in the Drake link-frame convention (tables 1.2 and
1.4), so a wrong frame, axis sign or COM in robots/iiwa14.xml cannot pass by construction.
The two-link arm is checked against textbook planar-arm formulas.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

# MJX on the 8-deep iiwa chain needs an XLA:CPU flag where the running jaxlib knows it; it
# is read when JAX's backend starts. `import cfm_jax` sets it (cfm_jax/_xla.py decides from
# jaxlib's version); tests/conftest.py imports cfm_jax before any test runs.
import cfm_jax  # noqa: E402, F401

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
IIWA = ROBOTS / "iiwa14.xml"
ARM2 = ROBOTS / "two_link_arm.xml"

PRIMITIVES = {
    mujoco.mjtGeom.mjGEOM_PLANE,
    mujoco.mjtGeom.mjGEOM_SPHERE,
    mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_CYLINDER,
    mujoco.mjtGeom.mjGEOM_BOX,
}

# ---- iiwa facts, typed from the sheet -------------------------------------------------------
LINKS = [f"link{i}" for i in range(1, 8)]
JOINTS = [f"joint{i}" for i in range(1, 8)]
# [1.3]
POS_LIMIT = np.array([2.96706, 2.09440, 2.96706, 2.09440, 2.96706, 2.09440, 3.05433])
TORQUE_LIMIT = np.array([320, 320, 176, 176, 110, 40, 40], dtype=float)
# [1.5] world-parallel frames
BODY_POS_Z = np.array([0.1575, 0.2025, 0.2045, 0.2155, 0.1845, 0.2155, 0.081])
AXES_WORLD = np.array(
    [[0, 0, 1], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]], dtype=float
)  # also [1.1]: J1 +z, J2 +y, J3 +z, J4 -y, J5 +z, J6 +y, J7 +z
MASS = np.array([5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2])
COM = np.array(
    [
        [0, -0.03, 0.12],
        [-0.0003, 0.042, 0.059],
        [0, 0.03, 0.13],
        [0, -0.034, 0.067],
        [-0.0001, -0.021, 0.076],
        [0, 0.0004, 0.0006],
        [0, 0, 0.02],
    ]
)
INERTIA = np.array(
    [
        [0.033, 0.0333, 0.0123],
        [0.0305, 0.0304, 0.011],
        [0.025, 0.0238, 0.0076],
        [0.017, 0.0164, 0.006],
        [0.01, 0.0087, 0.00449],
        [0.0049, 0.0036, 0.0047],
        [0.001, 0.001, 0.001],
    ]
)
COM_HEIGHT_Q0 = np.array([0.277, 0.419, 0.695, 0.847, 1.040, 1.181, 1.281])  # [1.5]
JOINT_Z_Q0 = np.array([0.1575, 0.360, 0.5645, 0.780, 0.9645, 1.180, 1.261])  # [1.2]
# [1.6]
DAMPING = 0.5
ARMATURE = np.array([3.382, 3.382, 3.382, 3.382, 1.321, 1.162, 1.162])
# [1.7]
HOME = np.array([0, 0.785398, 0, -1.5708, 0, 0, 0])
TOOL_DOWN = np.array([0, np.pi / 4, 0, -np.pi / 2, 0, np.pi / 4, 0])
G = 9.81  # MuJoCo's default |gravity|

# Second, independent iiwa model in the Drake / Menagerie link-frame convention: body
# positions and rotations from table [1.2], inertials in link axes from table [1.4] (Drake's
# link-6 tensor). Every joint turns about its local +z.
_DRAKE_CHAIN = """
<mujoco><compiler angle="radian"/><worldbody>
<body name="link1" pos="0 0 0.1575"><joint axis="0 0 1"/>
 <inertial mass="5.76" pos="0 -0.03 0.12" diaginertia="0.033 0.0333 0.0123"/>
<body name="link2" pos="0 0 0.2025" quat="0 0 1 1"><joint axis="0 0 1"/>
 <inertial mass="6.35" pos="0.0003 0.059 0.042" diaginertia="0.0305 0.011 0.0304"/>
<body name="link3" pos="0 0.2045 0" quat="0 0 1 1"><joint axis="0 0 1"/>
 <inertial mass="3.5" pos="0 0.03 0.13" diaginertia="0.025 0.0238 0.0076"/>
<body name="link4" pos="0 0 0.2155" quat="1 1 0 0"><joint axis="0 0 1"/>
 <inertial mass="3.5" pos="0 0.067 0.034" diaginertia="0.017 0.006 0.0164"/>
<body name="link5" pos="0 0.1845 0" quat="0 0 1 1"><joint axis="0 0 1"/>
 <inertial mass="3.5" pos="0.0001 0.021 0.076" diaginertia="0.01 0.0087 0.00449"/>
<body name="link6" pos="0 0 0.2155" quat="1 1 0 0"><joint axis="0 0 1"/>
 <inertial mass="1.8" pos="0 0.0006 0.0004" diaginertia="0.0049 0.0047 0.0036"/>
<body name="link7" pos="0 0.081 0" quat="0 0 1 1"><joint axis="0 0 1"/>
 <inertial mass="1.2" pos="0 0 0.02" diaginertia="0.001 0.001 0.001"/>
 <site name="flange" pos="0 0 0.045"/>
</body></body></body></body></body></body></body>
</worldbody></mujoco>
"""


def _load(path: Path) -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = mujoco.MjModel.from_xml_path(str(path))
    return m, mujoco.MjData(m)


def _forward(m: mujoco.MjModel, d: mujoco.MjData, q, v=None) -> mujoco.MjData:
    d.qpos[:] = q
    d.qvel[:] = 0.0 if v is None else v
    d.qacc[:] = 0.0
    d.ctrl[:] = 0.0
    mujoco.mj_forward(m, d)
    return d


def _gravity_holding_torque(m: mujoco.MjModel, d: mujoco.MjData, q) -> np.ndarray:
    """Joint torque that holds q still: qfrc_bias at v = 0 (pure gravity; damping needs v)."""
    return _forward(m, d, q).qfrc_bias.copy()


@pytest.fixture(scope="module")
def iiwa():
    return _load(IIWA)


@pytest.fixture(scope="module")
def arm2():
    return _load(ARM2)


# ---- both models ----------------------------------------------------------------------------
@pytest.mark.parametrize("path, n", [(IIWA, 7), (ARM2, 2)])
def test_loads_with_expected_sizes(path, n):
    m, _ = _load(path)
    assert (m.nq, m.nv, m.nu) == (n, n, n)
    assert m.opt.timestep == pytest.approx(0.002)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -G])
    assert m.nkey >= 1 and m.key(0).name == "home"
    assert np.all(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert np.all(m.jnt_limited == 1)


@pytest.mark.parametrize("path", [IIWA, ARM2])
def test_primitive_geoms_only_and_no_collisions(path):
    m, d = _load(path)
    assert m.nmesh == 0 and m.nhfield == 0
    assert {int(t) for t in m.geom_type} <= {int(t) for t in PRIMITIVES}
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    # Nothing can collide even in a folded-up pose.
    _forward(m, d, np.clip(np.full(m.nq, 2.0), *m.jnt_range.T))
    assert d.ncon == 0


@pytest.mark.parametrize("path", [IIWA, ARM2])
def test_actuators_are_unit_gear_torque_motors(path):
    m, _ = _load(path)
    assert np.all(m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT)
    np.testing.assert_array_equal(m.actuator_trnid[:, 0], np.arange(m.nu))  # actuator i -> joint i
    np.testing.assert_allclose(m.actuator_gear[:, 0], 1.0)
    assert np.all(m.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], 1.0)
    assert np.all(m.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE)
    assert np.all(m.actuator_ctrllimited == 1)
    np.testing.assert_allclose(m.actuator_ctrlrange[:, 0], -m.actuator_ctrlrange[:, 1])


# ---- iiwa: structure and parameters ---------------------------------------------------------
def test_iiwa_names_and_frames(iiwa):
    m, _ = iiwa
    assert [m.joint(i).name for i in range(m.njnt)] == JOINTS
    assert [m.body(m.jnt_bodyid[i]).name for i in range(m.njnt)] == LINKS
    np.testing.assert_allclose(m.body_pos[[m.body(b).id for b in LINKS]][:, 2], BODY_POS_Z)
    np.testing.assert_allclose(m.body_pos[[m.body(b).id for b in LINKS]][:, :2], 0.0)
    np.testing.assert_allclose(m.body_quat[[m.body(b).id for b in LINKS]], [[1, 0, 0, 0]] * 7)
    np.testing.assert_allclose(m.jnt_axis, AXES_WORLD)
    site = m.site("flange")
    assert m.body(site.bodyid[0]).name == "link7"
    np.testing.assert_allclose(site.pos, [0, 0, 0.045])  # [1.8]
    np.testing.assert_allclose(site.quat, [1, 0, 0, 0])
    np.testing.assert_allclose(m.key("home").qpos, HOME)


def test_iiwa_masses_and_inertials(iiwa):
    m, _ = iiwa
    ids = [m.body(b).id for b in LINKS]
    np.testing.assert_allclose(m.body_mass[ids], MASS)
    assert m.body_mass[ids].sum() == pytest.approx(25.61)  # [1.4] total moving mass
    np.testing.assert_allclose(m.body_ipos[ids], COM, atol=1e-12)
    np.testing.assert_allclose(m.body_inertia[ids], INERTIA)
    np.testing.assert_allclose(m.body_iquat[ids], [[1, 0, 0, 0]] * 7)  # no products of inertia


def test_iiwa_limits_damping_armature(iiwa):
    m, _ = iiwa
    np.testing.assert_allclose(m.jnt_range, np.c_[-POS_LIMIT, POS_LIMIT])
    assert [m.actuator(i).name for i in range(m.nu)] == JOINTS
    np.testing.assert_allclose(m.actuator_ctrlrange, np.c_[-TORQUE_LIMIT, TORQUE_LIMIT])
    np.testing.assert_allclose(m.dof_damping, DAMPING)
    np.testing.assert_allclose(m.dof_armature, ARMATURE)
    # [1.6] armature is the reflected rotor inertia N^2 J (sheet rounds to 4 figures).
    reflected = np.array([160, 160, 160, 160, 100, 160, 160]) ** 2 * np.array(
        [1.321e-4] * 5 + [4.54e-5] * 2
    )
    np.testing.assert_allclose(m.dof_armature, reflected, rtol=2e-3)
    assert np.all(m.dof_frictionloss == 0)


# ---- iiwa: kinematics -----------------------------------------------------------------------
def test_iiwa_forward_kinematics_q0(iiwa):
    m, d = iiwa
    _forward(m, d, np.zeros(7))
    np.testing.assert_allclose(d.site("flange").xpos, [0, 0, 1.306], atol=1e-9)
    np.testing.assert_allclose(d.site("flange").xmat.reshape(3, 3)[:, 2], [0, 0, 1], atol=1e-9)
    ids = [m.body(b).id for b in LINKS]
    np.testing.assert_allclose(d.xipos[ids, 2], COM_HEIGHT_Q0, atol=2e-3)
    np.testing.assert_allclose(d.xanchor[:, 2], JOINT_Z_Q0, atol=1e-9)
    np.testing.assert_allclose(d.xaxis, AXES_WORLD, atol=1e-12)  # [1.1] axes seen from world


@pytest.mark.parametrize(
    "q, flange, tool_axis",
    [
        (HOME, [0.669, 0, 0.285], [np.sqrt(0.5), 0, -np.sqrt(0.5)]),  # 45 deg down-forward
        (TOOL_DOWN, [0.580, 0, 0.248], [0, 0, -1]),
    ],
)
def test_iiwa_forward_kinematics_keyframes(iiwa, q, flange, tool_axis):
    m, d = iiwa
    _forward(m, d, q)
    np.testing.assert_allclose(d.site("flange").xpos, flange, atol=2e-3)  # [1.7]
    np.testing.assert_allclose(d.site("flange").xmat.reshape(3, 3)[:, 2], tool_axis, atol=1e-4)


def test_iiwa_home_keyframe_matches_planar_closed_form(iiwa):
    """Closed form: J2 tilts the 0.42 m upper arm by q2, J4 adds the 0.526 m forearm+wrist."""
    m, d = iiwa
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_forward(m, d)
    q2, q4 = HOME[1], HOME[3]
    a = q2 - q4  # J4 turns about -y, so a negative q4 bends further forward
    x = 0.42 * np.sin(q2) + (0.400 + 0.126) * np.sin(a)
    z = 0.360 + 0.42 * np.cos(q2) + 0.526 * np.cos(a)
    np.testing.assert_allclose(d.site("flange").xpos, [x, 0, z], atol=1e-5)


def test_iiwa_equals_drake_link_frame_model(iiwa):
    """The world-parallel model is the same multibody system as tables [1.2] + [1.4]."""
    m, d = iiwa
    m2 = mujoco.MjModel.from_xml_string(_DRAKE_CHAIN)
    d2 = mujoco.MjData(m2)
    rng = np.random.default_rng(0)
    ids = [m.body(b).id for b in LINKS]
    ids2 = [m2.body(b).id for b in LINKS]
    for q in [np.zeros(7), HOME, *rng.uniform(-2.0, 2.0, (10, 7))]:
        v = rng.normal(size=7)
        _forward(m, d, q, v)
        _forward(m2, d2, q, v)
        np.testing.assert_allclose(d.site("flange").xpos, d2.site("flange").xpos, atol=1e-12)
        np.testing.assert_allclose(d.site("flange").xmat, d2.site("flange").xmat, atol=1e-12)
        np.testing.assert_allclose(d.xipos[ids], d2.xipos[ids2], atol=1e-12)
        M, M2 = np.zeros((7, 7)), np.zeros((7, 7))
        mujoco.mj_fullM(m, d, M)
        mujoco.mj_fullM(m2, d2, M2)
        np.testing.assert_allclose(M - np.diag(m.dof_armature), M2, atol=1e-12)
        # Coriolis + gravity; m also has damping, which lives in qfrc_passive, not qfrc_bias.
        np.testing.assert_allclose(d.qfrc_bias, d2.qfrc_bias, atol=1e-10)


# ---- iiwa: gravity --------------------------------------------------------------------------
def test_iiwa_gravity_torques_at_home(iiwa):
    """[1.6]: (0, 57.0, 0.6, -17.1, 0.5, 0.85, 0) N m at the home pose.

    The sheet lists the generalized gravity force (Drake's tau_g, the torque gravity applies);
    the torque a controller must apply to hold the pose is its negative, MuJoCo's qfrc_bias.
    Signs checked by hand: at home the arm leans towards +x, so gravity turns it further
    about +y (J2 positive) and the holding torque on J2 is negative.
    """
    m, d = iiwa
    hold = _gravity_holding_torque(m, d, HOME)
    np.testing.assert_allclose(-hold, [0, 57.0, 0.6, -17.1, 0.5, 0.85, 0], atol=0.05)
    assert np.all(np.abs(hold) < TORQUE_LIMIT)


def test_iiwa_gravity_torques_arm_horizontal(iiwa):
    """[1.6]: with q2 = pi/2 (rest 0) J2 needs about 80.6 N m and J4 about 24.2 N m.

    Closed form from table [1.5]: the arm beyond J2 is rotated flat onto +x, so each COM's
    lever arm about J2 (J4) is its height above that joint at q = 0.
    """
    m, d = iiwa
    hold = _gravity_holding_torque(m, d, [0, np.pi / 2, 0, 0, 0, 0, 0])
    com_z = BODY_POS_Z.cumsum() + COM[:, 2]
    tau2 = G * np.sum(MASS[1:] * (com_z[1:] - JOINT_Z_Q0[1]))
    tau4 = G * np.sum(MASS[3:] * (com_z[3:] - JOINT_Z_Q0[3]))
    assert tau2 == pytest.approx(80.6, abs=0.05)
    assert tau4 == pytest.approx(24.2, abs=0.05)
    # J2 turns about +y: hold with negative torque. J4 turns about -y: positive.
    assert hold[1] == pytest.approx(-tau2, abs=1e-9)
    assert hold[3] == pytest.approx(+tau4, abs=1e-9)


# ---- two-link arm ---------------------------------------------------------------------------
L1, L2, M1, M2 = 0.5, 0.4, 1.0, 0.8
SHOULDER = np.array([0.0, 0.0, 1.0])


def _tip(q):
    q1, q2 = q
    x = L1 * np.cos(q1) + L2 * np.cos(q1 + q2)
    z = L1 * np.sin(q1) + L2 * np.sin(q1 + q2)
    return SHOULDER + [x, 0.0, z]


def test_two_link_parameters(arm2):
    m, _ = arm2
    assert [m.joint(i).name for i in range(2)] == ["shoulder", "elbow"]
    np.testing.assert_allclose(m.body_mass[1:], [M1, M2])
    np.testing.assert_allclose(m.body_ipos[1:], [[L1 / 2, 0, 0], [L2 / 2, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(m.jnt_range, [[-2.5, 2.5]] * 2)
    np.testing.assert_allclose(m.dof_damping, 0.1)
    np.testing.assert_allclose(m.dof_armature, 0.01)
    np.testing.assert_allclose(m.actuator_ctrlrange, [[-20, 20], [-10, 10]])
    # Rotational inertia about the long axis is tiny, about the other two a bit above m l^2/12.
    for b, (mass, length) in zip((1, 2), ((M1, L1), (M2, L2)), strict=True):
        big = np.sort(m.body_inertia[b])[1:]
        assert np.all(big > mass * length**2 / 12) and np.all(big < 1.2 * mass * length**2 / 12)


@pytest.mark.parametrize("q", [(0.0, 0.0), (-np.pi / 2, 0.0), (-0.785398, 1.570796), (1.0, -2.0)])
def test_two_link_forward_kinematics(arm2, q):
    m, d = arm2
    _forward(m, d, q)
    np.testing.assert_allclose(d.site("tip").xpos, _tip(q), atol=1e-12)


def test_two_link_gravity_and_torque_margin(arm2):
    m, d = arm2
    hold = _gravity_holding_torque(m, d, [0.0, 0.0])  # horizontal: worst static load
    expect = G * np.array([M1 * L1 / 2 + M2 * (L1 + L2 / 2), M2 * L2 / 2])
    # Hinge axes are -y, positive angles lift the arm: holding torque is positive.
    np.testing.assert_allclose(hold, expect, atol=1e-9)
    assert np.all(2 * expect < m.actuator_ctrlrange[:, 1])
    np.testing.assert_allclose(_gravity_holding_torque(m, d, [-np.pi / 2, 0.0]), 0, atol=1e-9)
    np.testing.assert_allclose(m.key("home").qpos, [-0.785398, 1.570796])


# ---- MJX ------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", [IIWA, ARM2])
def test_mjx_step_matches_mujoco(path):
    import jax
    from mujoco import mjx

    m, d = _load(path)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.ctrl[:] = 0.0
    mx = mjx.put_model(m)
    dx = mjx.put_data(m, d)
    dx = jax.jit(mjx.step)(mx, dx)
    mujoco.mj_step(m, d)
    assert np.abs(d.qvel).max() > 1e-3  # gravity really moved it, so the check is not vacuous
    np.testing.assert_allclose(np.asarray(dx.qpos), d.qpos, atol=1e-5, rtol=0)
    np.testing.assert_allclose(np.asarray(dx.qvel), d.qvel, atol=1e-5, rtol=0)
