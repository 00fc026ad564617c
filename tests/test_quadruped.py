"""A quadruped read from its MJCF alone (issue 65, item 1): legs, feet, hips and standing pose.

Oracles: the Solo12's closed-form leg kinematics (cfm_jax.sim.solo12, from the robot's facts
sheet); the published quadrupeds' own joint names, whose leg prefixes are written out here by
hand; MuJoCo's forward kinematics for the computed standing pose; hand-written MJCF files for
the models that are not quadrupeds."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from cfm_jax.analysis import robot_check
from cfm_jax.sim import quadruped, solo12
from cfm_jax.tasks import locomotion

QUADRUPEDS = Path(__file__).parent / "robots" / "quadrupeds"

# Each published file's names for the legs FL, FR, HL, HR (as its authors spell them).
PUBLISHED = {
    "go2": ("FL_", "FR_", "RL_", "RR_"),
    "anymal_c": ("LF_", "RF_", "LH_", "RH_"),
    "barkour_vb_mjx": ("_front_left", "_front_right", "_hind_left", "_hind_right"),
}


def test_the_solo12_read_from_its_file_is_its_closed_form():
    found = quadruped.describe(solo12.load_model())
    assert [leg.name for leg in found.legs] == list(solo12.LEGS)
    assert sum((leg.joints for leg in found.legs), ()) == solo12.JOINTS
    assert [leg.foot_geom for leg in found.legs] == [f"{leg}_foot" for leg in solo12.LEGS]
    # Feet at the home pose: the facts sheet's closed form (leg_fk at HOME_JOINTS).
    np.testing.assert_allclose(found.feet, solo12.hip_positions(), rtol=0, atol=1e-12)
    hips = [[sx * solo12.HAA_X, sy * solo12.HAA_Y, 0.0] for sx, sy in solo12.LEG_SIGNS]
    np.testing.assert_allclose([leg.hip for leg in found.legs], hips, rtol=0, atol=1e-12)
    assert all(leg.foot_radius == solo12.FOOT_RADIUS for leg in found.legs)
    np.testing.assert_array_equal(found.standing[7:], solo12.HOME_JOINTS)
    assert found.standing_from == "keyframe 'home'"
    # qpos / qvel addresses: the free joint's 7 / 6, then the legs in order.
    assert sum((leg.qpos for leg in found.legs), ()) == tuple(range(7, 19))
    assert sum((leg.dofs for leg in found.legs), ()) == tuple(range(6, 18))
    # The chain's length: HAA -> HFE (19.5 mm inboard, 14 mm out) -> KFE -> foot (16 cm each).
    first = float(np.hypot(solo12.HFE_DX, 0.014))
    lower = float(np.hypot(solo12.L_LOWER, 0.009))  # the foot sits 9 mm out from the knee
    want = first + float(np.hypot(solo12.L_UPPER, 0.03745)) + lower
    assert all(abs(leg.length - want) < 1e-9 for leg in found.legs)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_published_quadrupeds_are_read_without_names_of_their_own(name):
    model = mujoco.MjModel.from_xml_path(str(QUADRUPEDS / f"{name}.xml"))
    found = quadruped.describe(model)
    for leg, label in zip(found.legs, PUBLISHED[name], strict=True):
        assert len(leg.joints) == 3 and all(label in joint for joint in leg.joints), leg.joints
    # Left and right mirror each other across the base's x-z plane (all three published
    # files are built symmetric; front and hind differ).
    feet = found.feet
    for left, right in ((0, 1), (2, 3)):
        np.testing.assert_allclose(feet[left] * [1, -1, 1], feet[right], atol=2e-3)
    # The standing pose: a keyframe where the file has one, else computed so that the lowest
    # foot sphere touches z = 0 (MuJoCo's forward kinematics at that pose).
    data = mujoco.MjData(model)
    data.qpos[:] = found.standing
    mujoco.mj_kinematics(model, data)
    bottoms = [data.geom_xpos[leg.foot_id][2] - leg.foot_radius for leg in found.legs]
    if model.nkey:
        assert found.standing_from == "keyframe 'home'"
        np.testing.assert_array_equal(found.standing, model.key("home").qpos)
    else:
        assert found.standing_from.startswith("computed")
        assert abs(min(bottoms)) < 1e-12
    assert all(leg.foot_radius > 0 for leg in found.legs)  # each foot is a sphere


TRIPOD = """
<mujoco>
  <worldbody>
    <body name="base" pos="0 0 0.3">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.02"/>
      {legs}
    </body>
  </worldbody>
</mujoco>
"""
LEG = """
      <body pos="{x} {y} 0">
        <joint name="hip{k}" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02"/>
        <body pos="0 0 -0.2">
          <joint name="knee{k}" axis="0 1 0"/>
          <geom type="sphere" pos="0 0 -0.1" size="0.02"/>
        </body>
      </body>"""


def _legged(corners) -> mujoco.MjModel:
    legs = "".join(LEG.format(x=x, y=y, k=k) for k, (x, y) in enumerate(corners))
    return mujoco.MjModel.from_xml_string(TRIPOD.format(legs=legs))


def test_a_hand_written_quadruped_is_read_and_not_quadrupeds_are_refused_saying_why():
    found = quadruped.describe(_legged([(0.1, 0.1), (-0.1, -0.1), (0.1, -0.1), (-0.1, 0.1)]))
    # Named by where the feet stand, whatever the file's order: FL, FR, HL, HR.
    assert [leg.joints[0] for leg in found.legs] == ["hip0", "hip2", "hip3", "hip1"]
    # No keyframe: each foot under its hip (the first joint of these two-joint legs), the
    # Solo12's fraction of the leg's 0.3 m reach below it, radius 0.02 on the ground.
    depth = quadruped.standing_depth() * 0.3
    np.testing.assert_allclose(found.legs[0].foot, [0.1, 0.1, -depth], atol=1e-9)
    np.testing.assert_allclose(found.legs[0].hip, [0.1, 0.1, 0.0], atol=1e-12)
    assert abs(found.standing_height - (depth + 0.02)) < 1e-9
    assert abs(found.legs[0].length - 0.3) < 1e-12
    refusals = [
        (_legged([(0.1, 0.1), (-0.1, -0.1), (0.1, -0.1)]), "carries 3 jointed limbs"),
        (_legged([(0.1, 0.1), (0.1, 0.2), (-0.1, -0.1), (-0.1, -0.2)]), "one in each quadrant"),
        (mujoco.MjModel.from_xml_path(str(Path(solo12.model_path()).parent / "iiwa14.xml")),
         "it has 0 free joints"),
    ]  # fmt: skip
    for model, reason in refusals:
        with pytest.raises(quadruped.QuadrupedError, match=reason):
            quadruped.describe(model)


def test_the_standing_depth_is_the_solo12s_from_its_facts_sheet():
    # The closed form's feet stand 0.2229 m below the HFE axis (z 0 in the base frame); the
    # reach from the HFE is the upper and lower legs with their lateral offsets.
    reach = float(np.hypot(solo12.L_UPPER, 0.03745) + np.hypot(solo12.L_LOWER, 0.009))
    depth = -float(solo12.hip_positions()[0, 2])
    assert quadruped.standing_depth() == pytest.approx(depth / reach, rel=0, abs=1e-12)


def test_the_solo12_without_its_keyframe_stands_as_its_keyframe(tmp_path):
    """The computed standing pose of the Solo12's file with its keyframe removed is the pose
    its authors chose (each foot under its HFE, knees toward the body's middle), base on
    rigid contact: the foot centres 0.2229 m below it plus the feet's 17 mm radius (the
    keyframe's 0.2384 m sinks 1.5 mm into the floor)."""
    text = Path(solo12.model_path()).read_text()
    start, end = text.index("<keyframe>"), text.index("</keyframe>") + len("</keyframe>")
    (tmp_path / "solo12.xml").write_text(text[:start] + text[end:])
    found = quadruped.describe(mujoco.MjModel.from_xml_path(str(tmp_path / "solo12.xml")))
    assert found.standing_from.startswith("computed: each foot under its hip")
    np.testing.assert_allclose(found.standing[7:], solo12.HOME_JOINTS, rtol=0, atol=1e-9)
    height = -float(solo12.hip_positions()[0, 2]) + solo12.FOOT_RADIUS
    assert found.standing_height == pytest.approx(height, rel=0, abs=1e-9)


@pytest.mark.parametrize("name", ["anymal_c", "barkour_vb_mjx"])
def test_a_quadruped_without_keyframe_stands_on_bent_legs_under_its_hips(name):
    """ANYmal C's qpos0 has straight legs and Barkour vB's folded ones; their computed
    standing pose, checked with MuJoCo's forward kinematics: the base level, each foot on
    the floor, under its hip (the anchor of the leg's second-to-last joint) and at its
    qpos0 lateral place, standing_depth of the leg's reach below the hip (the four legs'
    depths averaged: Barkour's differ by 0.2 mm), the joints within their ranges and the
    knees bent toward the body's middle where the ranges allow (ANYmal's knees bend either
    way; Barkour's bend one way only, its hind knees behind their feet)."""
    model = mujoco.MjModel.from_xml_path(str(QUADRUPEDS / f"{name}.xml"))
    assert model.nkey == 0
    found = quadruped.describe(model)
    assert found.standing_from.startswith("computed: each foot under its hip,")
    np.testing.assert_array_equal(found.standing[3:7], [1.0, 0.0, 0.0, 0.0])
    data = mujoco.MjData(model)
    data.qpos[:] = found.standing
    mujoco.mj_kinematics(model, data)
    level = mujoco.MjData(model)  # qpos0, the base level
    level.qpos[:] = model.qpos0
    level.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
    mujoco.mj_kinematics(model, level)
    for leg in found.legs:
        ids = [model.joint(joint).id for joint in leg.joints]
        hip, knee = data.xanchor[ids[-2]], data.xanchor[ids[-1]]
        foot = data.geom_xpos[leg.foot_id]
        assert abs(foot[2] - leg.foot_radius) < 1e-9  # on the floor
        assert abs(foot[0] - hip[0]) < 1e-9  # under the hip
        assert abs(foot[1] - level.geom_xpos[leg.foot_id][1]) < 1e-9
        reach = np.linalg.norm(knee - hip) + np.linalg.norm(foot - knee)
        assert abs(hip[2] - foot[2] - quadruped.standing_depth() * reach) < 5e-4
        q = found.standing[list(leg.qpos)]
        low, high = model.jnt_range[ids].T
        assert np.all((low <= q) & (q <= high))
        thigh, shank = knee - hip, foot - knee
        bend = np.arccos(thigh @ shank / np.linalg.norm(thigh) / np.linalg.norm(shank))
        assert bend > 0.5  # not straight
        inward = (knee[0] - foot[0]) * np.sign(foot[0] - found.standing[0]) < 0
        assert inward or (name == "barkour_vb_mjx" and leg.name[0] == "H"), leg.name


def test_robot_check_reports_the_legs_it_read():
    text = robot_check.check(str(QUADRUPEDS / "go2.xml")).text
    assert "quadruped: yes, read from the file" in text
    assert "FL: joints FL_hip_joint, FL_thigh_joint, FL_calf_joint; foot FL" in text
    assert "HL: joints RL_hip_joint" in text and "standing pose: keyframe 'home'" in text
    assert "added at load time: a ground plane 'floor' at z = 0" in text  # Menagerie's has none
    legs = locomotion.legs_of_file(str(QUADRUPEDS / "go2.xml"))
    scale = locomotion.jump_height_scale(legs)  # 0.635: what it lands, below its length scale
    assert f"jump heights: the Solo12's times {scale:.3f} (length scale {legs.scale:.3f};" in text


def test_the_numeric_leg_ik_is_the_solo12_closed_form():
    # 200 targets that the legs reach (the closed-form leg_fk of joints near home): MuJoCo-
    # Jacobian Newton steps give the facts sheet's closed-form leg_ik, knee branch included.
    found = quadruped.describe(solo12.load_model())
    rng = np.random.default_rng(0)
    for k in range(200):
        leg = k % 4
        joints = solo12.HOME_JOINTS[3 * leg : 3 * leg + 3] + rng.uniform(-0.4, 0.4, 3)
        foot = solo12.leg_fk(joints, leg)
        got = found.leg_ik(leg, foot)
        np.testing.assert_allclose(got, solo12.leg_ik(foot, leg), rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_the_numeric_leg_ik_inverts_mujocos_kinematics(name):
    model = mujoco.MjModel.from_xml_path(str(QUADRUPEDS / f"{name}.xml"))
    found = quadruped.describe(model)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    for k in range(40):
        leg = found.legs[k % 4]
        ids = [model.joint(name).id for name in leg.joints]
        limited = model.jnt_limited[ids].astype(bool)  # targets reached within the ranges
        low = np.where(limited, model.jnt_range[ids, 0], -np.inf)
        high = np.where(limited, model.jnt_range[ids, 1], np.inf)
        joints = np.clip(found.standing[list(leg.qpos)] + rng.uniform(-0.25, 0.25, 3), low, high)
        data.qpos[:] = found.standing
        data.qpos[:3], data.qpos[3:7] = 0.0, (1.0, 0.0, 0.0, 0.0)  # base frame = world
        data.qpos[list(leg.qpos)] = joints
        mujoco.mj_kinematics(model, data)
        target = data.geom_xpos[leg.foot_id].copy()
        data.qpos[list(leg.qpos)] = found.leg_ik(k % 4, target)
        mujoco.mj_kinematics(model, data)
        assert np.linalg.norm(data.geom_xpos[leg.foot_id] - target) < 1e-9


def test_the_numeric_leg_ik_of_a_target_out_of_reach_is_the_closest_foot():
    # The hand-written legs hang straight (0.3 m, hip to foot centre) at qpos0: from there,
    # a target 1 m below the hip gives the straight leg, its foot 0.3 m below.
    found = quadruped.describe(_legged([(0.1, 0.1), (-0.1, -0.1), (0.1, -0.1), (-0.1, 0.1)]))
    joints = found.leg_ik(0, [0.1, 0.1, -1.0], start=[0.0, 0.0])
    np.testing.assert_allclose(joints, [0.0, 0.0], atol=1e-12)


def _foot_rows(model, found) -> np.ndarray:
    """The 40 sensordata rows of the four feet's contact sensors, FL, FR, HL, HR."""
    adr = [int(model.sensor_adr[model.sensor(f"{leg.name}_contact").id]) for leg in found.legs]
    return np.concatenate([np.arange(a, a + 10) for a in adr])


def test_a_published_quadruped_gets_a_ground_and_foot_sensors_that_read_the_contact_forces():
    model, added = quadruped.with_foot_sensors(str(QUADRUPEDS / "go2.xml"))
    assert added[0] == "a ground plane 'floor' at z = 0" and "HL: RL" in added[1]
    found = quadruped.describe(model)
    # Stand on the ground under joint PD for 2 s, from 2 cm above the standing pose.
    data = mujoco.MjData(model)
    data.qpos[:] = found.standing
    data.qpos[2] += 0.02
    qpos = [a for leg in found.legs for a in leg.qpos]
    dofs = [a for leg in found.legs for a in leg.dofs]
    motor = {int(model.jnt_qposadr[model.actuator_trnid[a, 0]]): a for a in range(model.nu)}
    for _ in range(int(2.0 / model.opt.timestep)):
        tau = 100.0 * (found.standing[qpos] - data.qpos[qpos]) - 4.0 * data.qvel[dofs]
        data.ctrl[[motor[a] for a in qpos]] = tau
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)
    forces = solo12.foot_forces(data.sensordata[_foot_rows(model, found)])
    # Oracle 1: MuJoCo's own contact force of each foot's contact with the floor, in the world.
    for leg, force in zip(found.legs, forces, strict=True):
        (c,) = [
            c
            for c in range(data.ncon)
            if leg.foot_id in (data.contact[c].geom1, data.contact[c].geom2)
        ]
        local = np.zeros(6)
        mujoco.mj_contactForce(model, data, c, local)
        world = data.contact[c].frame.reshape(3, 3).T @ local[:3]
        np.testing.assert_allclose(force, world, rtol=1e-12, atol=1e-9)
    # Oracle 2: standing still, the floor carries the robot's weight.
    weight = float(np.sum(model.body_mass)) * -model.opt.gravity[2]
    assert abs(forces[:, 2].sum() - weight) < 1e-3 * weight
    # A file that declares its own sensors (the Solo12) is compiled as it is.
    solo, nothing = quadruped.with_foot_sensors(solo12.model_path())
    assert nothing == [] and solo.nsensor == solo12.load_model().nsensor


def _barkour_with_bits(default: tuple[int, int], feet: tuple[int, int], plane=None):
    """The Barkour vB's spec (its 4 foot spheres are its only geoms) with the file's
    top-level contact bits ``default`` and the feet's ``feet`` (contype, conaffinity), and
    a ground plane of ``plane`` bits declared in the file where given."""
    spec = mujoco.MjSpec.from_file(str(QUADRUPEDS / "barkour_vb_mjx.xml"))
    spec.default.geom.contype, spec.default.geom.conaffinity = default
    for geom in spec.geoms:
        geom.contype, geom.conaffinity = feet
    if plane is not None:
        floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
        floor.contype, floor.conaffinity = plane
    return spec


def test_the_added_floor_meets_feet_whose_file_makes_geoms_collide_with_nothing():
    # As Menagerie's Barkour v0 MJX file: every geom defaults to contype 0 conaffinity 0
    # and the feet are contype 1 conaffinity 0. Oracle: MuJoCo's collision detection.
    spec = _barkour_with_bits(default=(0, 0), feet=(1, 0))
    assert quadruped.add_foot_sensors(spec)[0] == "a ground plane 'floor' at z = 0"
    model = spec.compile()
    found = quadruped.describe(model)
    data = mujoco.MjData(model)
    data.qpos[:] = found.standing
    data.qpos[2] -= 0.01  # every foot 1 cm into the ground
    mujoco.mj_forward(model, data)
    floor = model.geom("floor").id
    touching = {int(g) for c in data.contact[: data.ncon] for g in (c.geom1, c.geom2)}
    assert floor in touching and {leg.foot_id for leg in found.legs} <= touching


def test_a_foot_that_cannot_touch_the_ground_is_refused_naming_it():
    # The file's own plane on bit 1 and feet on bit 2 only: nothing collides.
    spec = _barkour_with_bits(default=(1, 1), feet=(2, 2), plane=(1, 1))
    with pytest.raises(quadruped.QuadrupedError, match=r"its F[LR] foot \(geom '.*'\) cannot "
                       r"touch the ground plane 'floor': contype 2 conaffinity 2 against the "
                       r"floor's 1 and 1, and no <contact><pair> of the two"):  # fmt: skip
        quadruped.add_foot_sensors(spec)
    # A <pair> of each foot and the plane is enough (as robots/solo12.xml declares them).
    spec = _barkour_with_bits(default=(1, 1), feet=(2, 2), plane=(1, 1))
    model = spec.compile()
    plane = [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_PLANE][0]
    plane.name = "ground"
    for leg in quadruped.describe(model).legs:
        foot = spec.geoms[leg.foot_id]
        foot.name = f"{leg.name}_sphere"
        spec.add_pair(geomname1=foot.name, geomname2="ground")
    assert "on 'ground'" in quadruped.add_foot_sensors(spec)[-1]


# ---- references from the description (cfm_jax.tasks.locomotion.Legs.of) ------------------------


def test_the_general_legs_on_the_solo12_give_its_closed_form_references():
    # The Solo12 read as any quadruped (numeric IK, foot geoms, per-joint gains from its
    # own joints' inertias and load, no passive joint torques) against its facts sheet's
    # closed forms: the same gains and, through the contacts of a walk and a jump, the same
    # motion to 1e-9.
    model, _ = quadruped.with_foot_sensors(solo12.model_path())
    legs = locomotion.Legs.of(model)
    assert (legs.kp, legs.kd, legs.scale) == pytest.approx((solo12.KP, solo12.KD, 1.0), abs=1e-12)
    for simulate, params in (
        (locomotion.simulate_walk, locomotion.WalkParams(duration=0.6)),
        (locomotion.simulate_jump, locomotion.JumpParams(duration=0.8, push_force=30.0)),
    ):
        general, _ = simulate(params, legs=legs)
        closed, _ = simulate(params)
        np.testing.assert_allclose(general.qpos, closed.qpos, rtol=0, atol=1e-9)
        np.testing.assert_allclose(general.tau, closed.tau, rtol=0, atol=1e-8)


def test_a_published_quadrupeds_jump_from_its_file():
    legs = locomotion.legs_of_file(str(QUADRUPEDS / "go2.xml"))
    standing = quadruped.describe(legs.model).standing_height
    # A jump at a push force the bisection found for the default jump (0.1 m on the
    # Solo12, scaled by the Go2's size): its feet clear the floor by that much, it stays
    # upright by the library's fall rule (tilt under solo12.FALL.max_tilt, 0.8 rad; it
    # reaches 0.31) and lands on its four feet.
    jump, _ = locomotion.simulate_jump(
        locomotion.JumpParams(duration=1.5, push_force=197.54014992468757), legs=legs
    )
    assert abs(locomotion.jump_clearance(jump, legs) - 0.1 * legs.scale) < 0.02 * 0.1 * legs.scale
    tilt = np.arccos(solo12.quat_to_mat(jump.qpos[:, 3:7])[:, 2, 2])
    assert tilt.max() < solo12.FALL.max_tilt and jump.contact[-1].all()
    assert abs(jump.qpos[-1, 2] - standing) < 0.03


def test_a_published_quadruped_trots_forward_from_its_file():
    # The Go2 (joint damping 2 N m s/rad, friction 0.2 N m, armature 0.01 kg m^2) trots the
    # Solo12's 2 s walk at its size. Before the per-joint gains and the passive torques'
    # feed-forward it moved 1.5 cm of the 0.54 m commanded (issue 65).
    legs = locomotion.legs_of_file(str(QUADRUPEDS / "go2.xml"))
    standing = quadruped.describe(legs.model).standing_height
    params = locomotion.WalkParams(duration=2.0)
    walk, rec = locomotion.simulate_walk(params, legs=legs)
    # Forward: the base's travel in the physics recording against the commanded base
    # motion at the Go2's size; at least three quarters of it (the Solo12's own trot, on
    # which the motion was made, covers 77 %), without drifting sideways.
    commanded = locomotion.commanded_distance(params) * legs.scale
    assert rec.qpos[-1, 0] - rec.qpos[0, 0] >= 0.75 * commanded
    assert abs(rec.qpos[-1, 1] - rec.qpos[0, 1]) < 0.05 * commanded
    # Upright and not fallen: tilt under the fall rule's, the base above 80 % of its
    # standing height, and nothing but the four feet touches the floor at any instant
    # (MuJoCo's collision of each recorded pose).
    tilt = np.arccos(solo12.quat_to_mat(rec.qpos[:, 3:7])[:, 2, 2])
    assert tilt.max() < solo12.FALL.max_tilt and rec.qpos[:, 2].min() > 0.8 * standing
    floor, feet = legs.model.geom("floor").id, set(legs.foot_geoms)
    data = mujoco.MjData(legs.model)
    for qpos in walk.qpos:
        data.qpos[:] = qpos
        mujoco.mj_forward(legs.model, data)
        touches = {(int(c.geom1), int(c.geom2)) for c in data.contact[: data.ncon]}
        assert {a + b - floor for a, b in touches if floor in (a, b)} <= feet
    # The diagonal pairs alternate (FL+HR, then FR+HL).
    pairs = {(1, 0, 0, 1), (0, 1, 1, 0)}
    assert pairs <= {tuple(c) for c in walk.contact.astype(int)}


def test_the_fall_rule_of_any_quadruped_finds_its_knees_as_mujoco_does():
    """quadruped.fall_rule reads a quadruped's knees (each leg's last joint anchor) from its
    kinematic tree: on the Solo12 they are the closed form's (solo12.knee_positions), on the
    Go2 MuJoCo's own joint anchors (mj_kinematics), at random joint angles. The rule's
    verdicts follow it: standing is no fall; the Go2 lowered until a knee is at the floor, or
    tipped past max_tilt, has fallen, as has a foot pulling the floor."""
    rng = np.random.default_rng(0)
    solo = solo12.load_model()
    rule = quadruped.fall_rule(quadruped.describe(solo), scale=1.0)
    qpos = np.tile(solo.key("home").qpos, (20, 1))
    qpos[:, 7:] += rng.normal(0.0, 0.5, (20, 12))
    np.testing.assert_allclose(
        rule.knee_positions(qpos), solo12.knee_positions(qpos[:, 7:]), rtol=0, atol=1e-12
    )
    model, _ = quadruped.with_foot_sensors(str(QUADRUPEDS / "go2.xml"))
    go2 = quadruped.describe(model)
    scale = go2.standing_height / locomotion.SOLO12_STANDING_HEIGHT
    rule = quadruped.fall_rule(go2, scale=scale)
    data = mujoco.MjData(model)
    for _ in range(10):
        data.qpos[:] = go2.standing
        data.qpos[:3], data.qpos[3:7] = 0.0, (1.0, 0.0, 0.0, 0.0)  # base frame = world
        data.qpos[7:] += rng.normal(0.0, 0.5, 12)
        mujoco.mj_kinematics(model, data)
        anchors = [data.xanchor[model.joint(leg.joints[-1]).id] for leg in go2.legs]
        np.testing.assert_allclose(rule.knee_positions(data.qpos.copy()), anchors, atol=1e-12)
    standing = go2.standing.copy()
    assert not rule(standing)
    knees = rule.knee_positions(standing)
    low = standing.copy()
    low[2] = -knees[:, 2].min() + 0.5 * rule.body_clearance  # the lowest knee at the floor
    assert rule(low) and low[2] > rule.min_base_height  # the knees decide, not the height
    tipped = standing.copy()
    tipped[3:7] = (np.cos(0.45), np.sin(0.45), 0.0, 0.0)  # rolled 0.9 rad > max_tilt 0.8
    assert rule(tipped)
    pulling = np.zeros((4, 3))
    pulling[2, 2] = -1.0
    assert rule(standing, foot_force=pulling) and not rule(standing, foot_force=-pulling)
    assert rule.min_base_height == pytest.approx(0.10 * scale)


def test_the_fall_rules_clauses_are_the_rule_one_by_one():
    """The clauses named in a refusal (solo12.fall_terms, FallRule.terms) make up the rule:
    any of them is the verdict, on the Solo12's closed form and on the Go2's rule read from
    its file, at random poses and foot forces; the height and tilt clauses are the base
    height and MuJoCo's rotation of the base quaternion against the limits."""
    rng = np.random.default_rng(1)
    model, _ = quadruped.with_foot_sensors(str(QUADRUPEDS / "go2.xml"))
    go2 = quadruped.describe(model)
    go2_rule = quadruped.fall_rule(go2, scale=go2.standing_height / 0.2384)
    solo = solo12.load_model().key("home").qpos
    cases = [
        (solo12.fell, solo12.fall_terms, solo, solo12.FALL.min_base_height),
        (go2_rule, go2_rule.terms, go2.standing, go2_rule.min_base_height),
    ]
    for rule, terms_of, standing, lowest in cases:
        qpos = np.tile(standing, (200, 1))
        qpos[:, 2] *= rng.uniform(0.3, 1.3, 200)
        quat = np.concatenate([np.ones((200, 1)), rng.normal(0.0, 0.4, (200, 3))], axis=1)
        qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        qpos[:, 7:] += rng.normal(0.0, 0.1, (200, 12))
        force = rng.normal(0.0, 1.0, (200, 4, 3))
        force[..., 2] = np.abs(force[..., 2]) * np.where(rng.random((200, 4)) < 0.05, -1, 1)
        terms = terms_of(qpos, force)
        assert len(terms) == 4
        either = np.any(np.stack(list(terms.values())), axis=0)
        np.testing.assert_array_equal(either, rule(qpos, force))
        assert all(0 < where.sum() < 200 for where in terms.values()), terms_of
        rotation = np.zeros((200, 9))
        for row, q in zip(rotation, qpos[:, 3:7], strict=True):
            mujoco.mju_quat2Mat(row, q)
        tilt = np.arccos(np.clip(rotation[:, 8], -1.0, 1.0))
        height, tilted = list(terms.values())[:2]
        np.testing.assert_array_equal(height, qpos[:, 2] < lowest)
        np.testing.assert_array_equal(tilted, tilt > solo12.FALL.max_tilt)
        assert list(terms)[1] == "the base tilted more than 46 deg"


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_the_highest_jump_is_sized_to_what_the_robot_lands(name):
    # Oracle: the robot's own fall rule on the states of the jump, simulated in MuJoCo C.
    # Scaled by length alone (0.17 m x the standing-height ratio), the highest jump fell on
    # the Go2 (tilt 33 deg on landing) and the Barkour vB, and asked the ANYmal C for more
    # than it reaches (0.296 of 0.330 m). Sized by what each lands (jump_height_scale), its
    # clearance is 0.17 m times that factor and it lands.
    from cfm_jax.sim import robots

    flags = json.loads((QUADRUPEDS / "robots.json").read_text())[f"{name}.xml"]
    robot = robots.load(str(QUADRUPEDS / f"{name}.xml"), actuators=flags[1])
    legs = locomotion.legs_of(robot.mj_model)
    rule = quadruped.fall_rule(quadruped.describe(legs.model), legs.scale)
    scale = locomotion.jump_height_scale(legs)
    landed = locomotion.largest_landed_jump(legs)
    solo = locomotion.largest_landed_jump(locomotion.legs_of(solo12.load_model()))
    assert scale == min(legs.scale, landed / solo) < legs.scale
    highest = max(locomotion.JUMP_HEIGHTS)
    jump = locomotion.jump_reference(highest, model=robot.mj_model, use_cache=False)
    target = highest * scale
    assert abs(locomotion.jump_clearance(jump, legs) - target) <= 0.02 * target
    assert target < landed
    assert not np.asarray(rule(jump.qpos, jump.foot_force)).any()
    if name == "go2":  # the rule bites: a harder push (0.215 m of clearance) falls
        harder, _ = locomotion.simulate_jump(locomotion.JumpParams(push_force=296.0), legs=legs)
        assert locomotion.jump_clearance(harder, legs) > landed
        assert np.asarray(rule(harder.qpos, harder.foot_force)).any()
