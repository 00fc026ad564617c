"""Checks of the hand-written Solo12 model (robots/solo12.xml) against independent oracles.

Oracles: the facts sheet (shared reference robot_facts.md, section 2; "[2.x]" below), whose
numbers are typed in here rather than read from the XML; closed-form statics; MuJoCo C's own
contact forces (``mj_contactForce``) for the contact sensors; MuJoCo C for MJX; and for
the fall rule, the former plain-loop check (copied here) and hand-made poses.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from cfm_jax.sim import solo12
from cfm_jax.tasks import locomotion

SOLO = Path(__file__).resolve().parents[1] / "robots" / "solo12.xml"
G = 9.81

# ---- Solo12 facts, typed from the sheet --------------------------------------------------
LEGS = ["FL", "FR", "HL", "HR"]
SIGNS = {"FL": (1, 1), "FR": (1, -1), "HL": (-1, 1), "HR": (-1, -1)}  # (front, left) [2.1]
MASS = {"base": 1.25123725, "shoulder": 0.14196048, "upper_leg": 0.14737324}
MASS["lower_leg"] = 0.02318294
TOTAL_MASS = 2.5013  # [2.3] (computed in the sheet)
BASE_COM = [-0.00082966, 0.00000105, -0.00060210]
# Full inertia tensors [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]] about the COM [2.3].
BASE_I = [[0.00266220, -0.00003684, -0.00001716], [-0.00003684, 0.01388510, -0.00000009]]
BASE_I.append([-0.00001716, -0.00000009, 0.01605370])
SHOULDER_COM = {
    "FL": ([-0.09407251, -0.00438935, +0.00001384], +3.687e-5, -9e-8),
    "FR": ([-0.09407251, +0.00438935, -0.00001384], -3.687e-5, +9e-8),
    "HL": ([+0.09407251, -0.00438935, -0.00001384], -3.687e-5, -9e-8),
    "HR": ([+0.09407251, +0.00438935, +0.00001384], +3.687e-5, +9e-8),
}
# Joint and foot positions in the base frame at q = 0 [2.2] (FL; mirror the signs).
HAA_Q0 = (0.2141, 0.0875, 0.0)
HFE_Q0 = (0.1946, 0.1015, 0.0)
KFE_Q0 = (0.1946, 0.1389, -0.16)
FOOT_Q0 = (0.1946, 0.1479, -0.32)
FOOT_STAND = (0.1946, 0.1479, -0.2229)  # [2.6] straight standing
ARMATURE = 3.645e-4  # [2.5]
TORQUE_LIMIT = 2.7  # [2.5]
RANGES = {"HAA": 1.2, "HFE": 2.0, "KFE": 3.1}  # [2.5] suggested MJCF ranges
FOOT_RADIUS = 0.017  # [2.4]
HOME = [0, 0.8, -1.6, 0, 0.8, -1.6, 0, -0.8, 1.6, 0, -0.8, 1.6]  # [2.6]


def _full_inertia(m, body: int) -> np.ndarray:
    """Inertia tensor of a body about its COM, in the body frame, from MuJoCo's principal
    moments and inertial-frame quaternion."""
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[body])
    rot = rot.reshape(3, 3)
    return rot @ np.diag(m.body_inertia[body]) @ rot.T


def _mirror(v, leg):
    sx, sy = SIGNS[leg]
    return np.array([sx * v[0], sy * v[1], v[2]])


@pytest.fixture(scope="module")
def solo():
    m = mujoco.MjModel.from_xml_path(str(SOLO))
    return m, mujoco.MjData(m)


def _pose(m, d, joints, base_z=0.0):
    d.qpos[:] = 0
    d.qpos[2] = base_z
    d.qpos[3] = 1.0
    d.qpos[7:] = joints
    d.qvel[:] = 0
    mujoco.mj_forward(m, d)
    return d


# ---- structure -----------------------------------------------------------------------------
def test_sizes_names_and_order(solo):
    m, _ = solo
    assert (m.nq, m.nv, m.nu) == (19, 18, 12)
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    names = [m.joint(i).name for i in range(1, m.njnt)]
    assert names == [f"{leg}_{j}" for leg in LEGS for j in ("HAA", "HFE", "KFE")]
    assert list(solo12.JOINTS) == names
    # actuator i drives joint i+1 (qpos 7 + i), gear 1
    np.testing.assert_array_equal(m.actuator_trnid[:, 0], np.arange(1, 13))
    np.testing.assert_array_equal(m.actuator_gear[:, 0], 1.0)


def test_primitive_geoms_and_only_foot_floor_contacts(solo):
    m, _ = solo
    prims = {
        mujoco.mjtGeom.mjGEOM_PLANE,
        mujoco.mjtGeom.mjGEOM_SPHERE,
        mujoco.mjtGeom.mjGEOM_CAPSULE,
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        mujoco.mjtGeom.mjGEOM_BOX,
    }
    assert {mujoco.mjtGeom(int(t)) for t in m.geom_type} <= prims
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    # MuJoCo may store a pair in either order; compare unordered name pairs
    pairs = {
        frozenset((m.geom(int(a)).name, m.geom(int(b)).name))
        for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)
    }
    assert pairs == {frozenset((f"{leg}_foot", "floor")) for leg in LEGS}
    for leg in LEGS:
        g = m.geom(f"{leg}_foot")
        assert g.type == mujoco.mjtGeom.mjGEOM_SPHERE and g.size[0] == FOOT_RADIUS
        assert g.friction[0] == 1.0
    assert m.geom("floor").friction[0] == 1.0
    np.testing.assert_array_equal(m.pair_friction[:, 0], 1.0)
    # foot sphere sits at the FOOT frame (0, +-0.009, -0.16) of the lower leg [2.4]
    for leg in LEGS:
        np.testing.assert_allclose(m.geom(f"{leg}_foot").pos, _mirror((0, 0.009, -0.16), leg))


def test_limits_armature_timestep(solo):
    m, _ = solo
    np.testing.assert_allclose(m.actuator_ctrlrange, [[-TORQUE_LIMIT, TORQUE_LIMIT]] * 12)
    assert np.all(m.actuator_ctrllimited)
    for i in range(1, 13):
        kind = m.joint(i).name.split("_")[1]
        np.testing.assert_allclose(m.jnt_range[i], [-RANGES[kind], RANGES[kind]])
        assert m.jnt_limited[i]
    np.testing.assert_allclose(m.dof_armature[6:], ARMATURE)
    np.testing.assert_allclose(m.dof_damping, 0.0)
    # 250 Hz control (0.004 s) is a whole number of physics steps
    assert m.opt.timestep == 0.002 and round(0.004 / m.opt.timestep) * m.opt.timestep == 0.004


# ---- inertials [2.3] --------------------------------------------------------------------
def test_masses(solo):
    m, _ = solo
    assert m.body("base").mass[0] == pytest.approx(MASS["base"], abs=1e-9)
    for leg in LEGS:
        for part in ("shoulder", "upper_leg", "lower_leg"):
            assert m.body(f"{leg}_{part}").mass[0] == pytest.approx(MASS[part], abs=1e-9)
    assert m.body_mass.sum() == pytest.approx(TOTAL_MASS, abs=1e-4)


def test_inertia_tensors_and_coms(solo):
    m, _ = solo
    b = m.body("base").id
    np.testing.assert_allclose(m.body_ipos[b], BASE_COM, atol=1e-9)
    np.testing.assert_allclose(_full_inertia(m, b), BASE_I, atol=1e-9)
    for leg in LEGS:
        sy = SIGNS[leg][1]
        com, ixy, ixz = SHOULDER_COM[leg]
        s = m.body(f"{leg}_shoulder").id
        np.testing.assert_allclose(m.body_ipos[s], com, atol=1e-9)
        ishoulder = [[0.00002802, ixy, ixz], [ixy, 0.00038264, 0], [ixz, 0, 0.00038050]]
        np.testing.assert_allclose(_full_inertia(m, s), ishoulder, atol=1e-9)
        u = m.body(f"{leg}_upper_leg").id
        np.testing.assert_allclose(m.body_ipos[u], [sy * 1.53e-5, sy * 0.0176764, -0.0783823])
        iyz, ixz = -sy * 4.589e-5, sy * 1e-7
        iupper = [[0.00041540, 0, ixz], [0, 0.00041637, iyz], [ixz, iyz, 0.00002982]]
        np.testing.assert_allclose(_full_inertia(m, u), iupper, atol=1e-9)
        k = m.body(f"{leg}_lower_leg").id
        np.testing.assert_allclose(m.body_ipos[k], [0, sy * 0.00776716, -0.07003876])
        iyz = -sy * 2.0e-6
        ilower = [[0.00008508, 0, 0], [0, 0.00008580, iyz], [0, iyz, 0.00000139]]
        np.testing.assert_allclose(_full_inertia(m, k), ilower, atol=1e-9)


def test_whole_robot_com(solo):
    """[2.3]: COM (-0.0004, 0, -0.027) at q = 0 and (-0.0004, 0, -0.019) standing."""
    m, d = solo
    _pose(m, d, np.zeros(12))
    np.testing.assert_allclose(d.subtree_com[1], [-0.0004, 0, -0.027], atol=5e-4)
    _pose(m, d, HOME)
    np.testing.assert_allclose(d.subtree_com[1], [-0.0004, 0, -0.019], atol=5e-4)


# ---- kinematics [2.1], [2.2], [2.6] ---------------------------------------------------------
def test_joint_and_foot_positions_at_zero(solo):
    m, d = solo
    _pose(m, d, np.zeros(12))
    for leg in LEGS:
        np.testing.assert_allclose(d.xpos[m.body(f"{leg}_shoulder").id], _mirror(HAA_Q0, leg))
        hfe = d.xpos[m.body(f"{leg}_upper_leg").id]
        np.testing.assert_allclose(hfe, _mirror(HFE_Q0, leg), atol=5e-5)  # sheet rounds to 0.1 mm
        kfe = d.xpos[m.body(f"{leg}_lower_leg").id]
        np.testing.assert_allclose(kfe, _mirror(KFE_Q0, leg), atol=5e-5)
        np.testing.assert_allclose(d.site(f"{leg}_foot").xpos, _mirror(FOOT_Q0, leg), atol=5e-5)


def test_joint_axes_and_sign_conventions(solo):
    """[2.1]: HAA +x, HFE +y, KFE +y on every leg; +HAA moves the foot to +y, +HFE swings the
    knee backward."""
    m, d = solo
    _pose(m, d, np.zeros(12))
    for i in range(1, 13):
        kind = m.joint(i).name.split("_")[1]
        np.testing.assert_allclose(d.xaxis[i], [1, 0, 0] if kind == "HAA" else [0, 1, 0])
    for leg in range(4):
        z = np.zeros(12)
        z[3 * leg] = 0.1
        y0 = _pose(m, d, np.zeros(12)).site(f"{LEGS[leg]}_foot").xpos[1]
        assert _pose(m, d, z).site(f"{LEGS[leg]}_foot").xpos[1] > y0
        z[3 * leg], z[3 * leg + 1] = 0.0, 0.3
        assert (
            _pose(m, d, z).xpos[m.body(f"{LEGS[leg]}_lower_leg").id][0]
            < _mirror(KFE_Q0, LEGS[leg])[0]
        )


def test_home_keyframe_standing_geometry(solo):
    m, d = solo
    key = m.key("home")
    np.testing.assert_allclose(key.qpos[7:], HOME)
    np.testing.assert_allclose(key.qpos[3:7], [1, 0, 0, 0])
    _pose(m, d, HOME)
    for leg in LEGS:
        np.testing.assert_allclose(d.site(f"{leg}_foot").xpos, _mirror(FOOT_STAND, leg), atol=1e-4)
    # [2.6]: base height = foot depth + radius = 0.240, less a small static contact deflection
    assert 0.2379 < key.qpos[2] < 0.2399


def test_leg_fk_ik_match_mujoco(solo):
    """Closed-form foot and knee positions (one leg, and all knees at once with NumPy and
    jax.numpy) against MuJoCo's site and body positions; the IK inverts the FK."""
    import jax.numpy as jnp

    m, _ = solo
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = solo12.HOME_JOINTS + rng.uniform(-0.4, 0.4, 12)
        d.qpos[:7] = [0, 0, 0, 1, 0, 0, 0]
        d.qpos[7:] = q
        mujoco.mj_kinematics(m, d)
        knees = [d.xpos[m.body(f"{leg}_lower_leg").id].copy() for leg in LEGS]
        for leg in range(4):
            ql = q[3 * leg : 3 * leg + 3]
            foot = d.site(f"{solo12.LEGS[leg]}_foot").xpos
            np.testing.assert_allclose(solo12.leg_fk(ql, leg), foot, atol=1e-12)
            np.testing.assert_allclose(solo12.knee_fk(ql, leg), knees[leg], atol=1e-12)
            np.testing.assert_allclose(solo12.leg_ik(foot, leg), ql, atol=1e-9)
        np.testing.assert_allclose(solo12.knee_positions(q), knees, atol=1e-12)
        got = np.asarray(solo12.knee_positions(jnp.asarray(q, jnp.float32), xp=jnp))
        np.testing.assert_allclose(got, knees, atol=1e-6)


# ---- fall detection ------------------------------------------------------------------------
def _fell_loop(qpos, foot_force=None, height=0.10, tilt=0.8, clearance=0.005, knees=True):
    """The former NumPy fall check, copied as the oracle: a plain loop over states and legs,
    knees from :func:`cfm_jax.sim.solo12.knee_fk` (itself checked against MuJoCo above); a
    ``knees`` switch added so that it also states the legged tasks' former rule."""
    qpos = np.asarray(qpos, float)
    batch = qpos.shape[:-1]
    flat = qpos.reshape(-1, qpos.shape[-1])
    rot = solo12.quat_to_mat(flat[:, 3:7] / np.linalg.norm(flat[:, 3:7], axis=-1, keepdims=True))
    pos = flat[:, :3]
    angle = np.arccos(np.clip(rot[:, 2, 2], -1.0, 1.0))
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners = corners * solo12.BASE_HALF
    lowest = (pos[:, None, :] + np.einsum("bij,kj->bki", rot, corners))[..., 2].min(axis=1)
    for i in range(len(flat) if knees else 0):
        for leg in range(4):
            knee = pos[i] + rot[i] @ solo12.knee_fk(flat[i, 7 + 3 * leg : 10 + 3 * leg], leg)
            lowest[i] = min(lowest[i], knee[2])
    out = (pos[:, 2] < height) | (angle > tilt) | (lowest < clearance)
    if foot_force is not None:
        fz = np.asarray(foot_force, float).reshape(-1, 4, 3)[..., 2]
        out |= np.any(fz < -1e-6, axis=-1)
    return out.reshape(batch)


def _training_fell_before(qpos_next):
    """The legged tasks' former fall rule (no knees) as LeggedTask.record computed it before
    it called solo12.fell (float32, one state), copied as the oracle of bit-identity."""
    import jax.numpy as jnp

    quat = qpos_next[3:7] / jnp.linalg.norm(qpos_next[3:7])
    rotation = solo12.quat_to_mat(quat, xp=jnp)
    up = rotation[2, 2]
    half = jnp.asarray(solo12.BASE_HALF, jnp.float32)
    signs = jnp.asarray(
        [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], jnp.float32
    )
    lowest = jnp.min(qpos_next[2] + (signs * half) @ rotation[2])
    return (qpos_next[2] < 0.10) | (jnp.arccos(jnp.clip(up, -1.0, 1.0)) > 0.8) | (lowest < 0.0)


def _random_states(n, seed=0):
    """States around every threshold: base 0-0.35 m, tilts 0-1.3 rad about random axes
    (quaternions not normalised), joints far from standing (knees down to the floor)."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, 1.3, n)
    quat = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)
    qpos = np.zeros((n, 19))
    qpos[:, :2] = rng.normal(size=(n, 2))
    qpos[:, 2] = rng.uniform(0.0, 0.35, n)
    qpos[:, 3:7] = quat * rng.uniform(0.5, 2.0, (n, 1))
    qpos[:, 7:] = solo12.HOME_JOINTS + rng.uniform(-1.5, 1.5, (n, 12))
    return qpos


RULES = {  # name: (FallLimits, oracle keywords)
    "fall": (solo12.FALL, {}),  # the library's rule: replay and training
    "no_knees": (
        solo12.FallLimits(body_clearance=0.0, knees=False),  # the training's before
        {"clearance": 0.0, "knees": False},
    ),  # fmt: skip
    "knees_at_floor": (solo12.FallLimits(body_clearance=0.0), {"clearance": 0.0}),
}


@pytest.mark.parametrize("rule", sorted(RULES))
def test_fell_matches_the_plain_loop_on_random_states(rule):
    """NumPy (float64) exactly, jax.numpy (float32, under jit and vmap, and batched) on the
    same float32 states exactly; every reason occurs in the sample and each rule's answer
    differs from the others somewhere."""
    import jax
    import jax.numpy as jnp

    limits, keywords = RULES[rule]
    qpos = _random_states(3000)
    expected = _fell_loop(qpos, **keywords)
    assert 0.2 < expected.mean() < 0.95
    np.testing.assert_array_equal(solo12.fell(qpos, limits=limits), expected)
    np.testing.assert_array_equal(solo12.fell(qpos.reshape(3, 1000, 19), limits=limits),
                                  expected.reshape(3, 1000))  # fmt: skip
    q32 = qpos.astype(np.float32)
    expected32 = _fell_loop(q32.astype(np.float64), **keywords)
    one = jax.jit(jax.vmap(lambda q: solo12.fell(q, limits=limits, xp=jnp)))
    np.testing.assert_array_equal(np.asarray(one(jnp.asarray(q32))), expected32)
    batched = jax.jit(lambda q: solo12.fell(q, limits=limits, xp=jnp))
    np.testing.assert_array_equal(np.asarray(batched(jnp.asarray(q32))), expected32)
    others = [_fell_loop(qpos, **k) for name, (_, k) in RULES.items() if name != rule]
    assert all(np.any(other != expected) for other in others)


def test_no_knees_limits_are_bit_identical_to_the_tasks_former_check():
    """The legged tasks' rule before it counted the knees, stated as FallLimits, gives the
    former inline check's answers bit for bit (so the limits are the only difference)."""
    import jax
    import jax.numpy as jnp

    q32 = jnp.asarray(_random_states(3000, seed=1), jnp.float32)
    limits = RULES["no_knees"][0]
    new = jax.jit(jax.vmap(lambda q: solo12.fell(q, limits=limits, xp=jnp)))
    before = jax.jit(jax.vmap(_training_fell_before))
    np.testing.assert_array_equal(np.asarray(new(q32)), np.asarray(before(q32)))
    assert solo12.FALL == solo12.FallLimits(0.10, 0.8, 0.005, knees=True)


def test_fell_on_hand_made_states(solo):
    """Each reason alone, and poses where only a knee is at the floor: the rules differ
    exactly by their knee and clearance limits, with NumPy and jax.numpy alike."""
    import jax.numpy as jnp

    m, d = solo
    home = m.key("home").qpos.copy()
    low = home.copy()
    low[2] = 0.08
    tilted = home.copy()
    tilted[3:7] = [np.cos(0.5), np.sin(0.5), 0, 0]  # 1.0 rad roll
    slight = home.copy()
    slight[3:7] = [np.cos(0.1), np.sin(0.1), 0, 0]  # 0.2 rad roll: fine
    nose = home.copy()  # pitched 0.7 rad (below the tilt limit), base 0.13 m: nose corner under
    nose[2], nose[3:7] = 0.13, [np.cos(0.35), 0, np.sin(0.35), 0]
    kneel = home.copy()  # base sunk to 0.11 m (above the 0.10 m limit): knees under the floor
    kneel[2] = 0.11
    touch = home.copy()  # knees 3.5 mm above the floor: within the 5 mm clearance only
    touch[2] = 0.115
    for state, knee_below in ((kneel, 0.0), (touch, 0.005)):
        d.qpos[:] = state
        mujoco.mj_kinematics(m, d)
        knee_z = min(d.xpos[m.body(f"{leg}_lower_leg").id][2] for leg in LEGS)
        assert knee_below - 0.005 < knee_z < knee_below  # and the base box is 8 cm up:
        assert state[2] - solo12.BASE_HALF[2] > 0.08
    states = np.stack([home, low, tilted, slight, nose, kneel, touch])
    expected = {
        "fall": [False, True, True, False, True, True, True],
        "knees_at_floor": [False, True, True, False, True, True, False],
        "no_knees": [False, True, True, False, True, False, False],
    }
    for rule, (limits, keywords) in RULES.items():
        np.testing.assert_array_equal(_fell_loop(states, **keywords), expected[rule])
        np.testing.assert_array_equal(solo12.fell(states, limits=limits), expected[rule])
        got = solo12.fell(jnp.asarray(states, jnp.float32), limits=limits, xp=jnp)
        np.testing.assert_array_equal(np.asarray(got), expected[rule])
    assert not solo12.fell(home) and solo12.fell(home, limits=solo12.FallLimits(0.3))
    pulling = np.zeros((4, 3))
    pulling[0, 2] = -1.0
    assert solo12.fell(home, pulling) and not solo12.fell(home, 0.0 * pulling)
    assert not solo12.fell(home, pulling, solo12.FallLimits(max_pull=2.0))
    assert solo12.fell(jnp.asarray(home), jnp.asarray(pulling), xp=jnp)


# ---- statics and contact forces --------------------------------------------------------------
@pytest.fixture(scope="module")
def standing(solo):
    """Stand 2 s with the library's standing controller (joint PD + -J^T m g / 4)."""
    m, _ = solo
    ref, rec = locomotion.simulate_walk(
        locomotion.WalkParams(duration=2.0, speed=0.0, stand=10.0), m
    )
    return ref, rec


def test_standing_statics(solo, standing):
    """At rest the four normal forces carry m g (closed form), split evenly by symmetry, and
    the knee holds about 2.5 * 9.81 / 4 * 0.115 = 0.70 N m ([2.6])."""
    m, _ = solo
    ref, _ = standing
    assert np.abs(ref.qvel[-1]).max() < 0.01
    f = ref.foot_force[-1]
    weight = TOTAL_MASS * G
    assert f[:, 2].sum() == pytest.approx(weight, rel=2e-3)
    np.testing.assert_allclose(f[:, 2], weight / 4, rtol=0.01)
    assert np.abs(f[:, :2]).max() < 0.1  # small lateral forces only
    knees = np.abs(ref.tau[-1, 2::3])
    np.testing.assert_allclose(knees, 0.70, atol=0.02)
    np.testing.assert_allclose(np.abs(m.key("home").ctrl[2::3]), 0.70, atol=0.01)
    assert ref.qpos[-1, 2] == pytest.approx(m.key("home").qpos[2], abs=1e-3)


def _contact_force_oracle(m, d) -> np.ndarray:
    """Floor force on each foot (world), from mj_contactForce rotated by the contact frame."""
    out = np.zeros((4, 3))
    floor = m.geom("floor").id
    for i in range(d.ncon):
        c = d.contact[i]
        f6 = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, f6)
        world = c.frame.reshape(3, 3).T @ f6[:3]  # force of geom1 on geom2
        foot = c.geom1 if c.geom2 == floor else c.geom2
        sign = -1.0 if c.geom1 == foot else 1.0
        out[LEGS.index(m.geom(foot).name.split("_")[0])] += sign * world
    return out


def test_contact_sensor_matches_mj_contact_force(solo, standing):
    m, d = solo
    walk, rec = locomotion.simulate_walk(locomotion.WalkParams(duration=1.5), m)
    states = [
        (r.qpos[k], r.qvel[k], r.tau[k]) for r in (rec, standing[1]) for k in range(0, 700, 7)
    ]
    n_touch = n_air = 0
    for qpos, qvel, tau in states:
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos, qvel, tau
        mujoco.mj_forward(m, d)
        got = solo12.foot_forces(d.sensordata)
        np.testing.assert_allclose(got, _contact_force_oracle(m, d), atol=1e-9, rtol=0)
        touching = solo12.foot_contact(d.sensordata)
        n_touch += touching.sum()
        n_air += (~touching).sum()
        assert np.all(got[~touching] == 0)
        assert np.all(got[touching, 2] >= 0)  # touching, never pulling (0 just at touchdown)
    assert n_touch > 100 and n_air > 50  # both standing/stance and swing feet were checked


def test_foot_forces_jax_matches_numpy(standing):
    import jax.numpy as jnp

    ref, rec = standing
    s = rec.sensordata[::50]
    want = solo12.foot_forces(s)  # float64 NumPy
    # float32 JAX: a rotation of float32-rounded inputs, so within a few float32 ulps of the
    # largest force (|f| <= 6.6 N). Measured: 2.3e-7 N (0.3 ulp of 6.6 N); tolerance 4 ulps
    # (3e-6 N). A wrong axis or sign would be off by up to 6.6 N (normal) or 0.37 N
    # (tangential, the smallest components checked here).
    atol = 4 * np.finfo(np.float32).eps * np.abs(want).max()
    np.testing.assert_allclose(
        np.asarray(solo12.foot_forces(jnp.asarray(s, jnp.float32), xp=jnp)),
        want,
        atol=atol,
        rtol=0,
    )


# ---- MJX ---------------------------------------------------------------------------------
def test_mjx_matches_mujoco_with_contacts(solo):
    """30 MJX steps (float32) vs MuJoCo C from a standing state and across a trot touchdown,
    with the recorded torques. Measured differences: qpos < 3e-7 m, qvel < 5e-6, contact
    sensors < 3e-6 N; tolerances 1e-5 / 1e-4 / 1e-3 leave float32 headroom and are still
    far below any modelling error (a 0.1 mm contact offset changes forces by ~0.4 N)."""
    import jax
    from mujoco import mjx

    m, _ = solo
    mx = mjx.put_model(m)
    step = jax.jit(mjx.step)
    _, rec = locomotion.simulate_walk(locomotion.WalkParams(duration=0.8), m)
    contact = solo12.foot_contact(rec.sensordata)
    touchdown = int(np.nonzero(~contact[:-1, 0] & contact[1:, 0])[0][0]) - 10
    for start in (0, touchdown):
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = rec.qpos[start], rec.qvel[start]
        mujoco.mj_forward(m, d)
        dx = mjx.put_data(m, d)
        touched = False
        for k in range(start, start + 30):
            d.ctrl[:] = rec.tau[k]
            dx = step(mx, dx.replace(ctrl=jax.numpy.asarray(rec.tau[k], jax.numpy.float32)))
            mujoco.mj_step(m, d)
            np.testing.assert_allclose(np.asarray(dx.qpos), d.qpos, atol=1e-5, rtol=0)
            np.testing.assert_allclose(np.asarray(dx.qvel), d.qvel, atol=1e-4, rtol=0)
            # sensors of the state before this step, computed by MJX's JAX contact sensor
            np.testing.assert_allclose(np.asarray(dx.sensordata), d.sensordata, atol=1e-3, rtol=0)
            touched |= start > 0 and bool(solo12.foot_contact(d.sensordata)[0])
        assert start == 0 or touched  # the touchdown really happened in the window
    assert np.abs(rec.qvel[: 30 * 1]).max() > 1e-3
