"""A quadruped as data: its legs, feet, hips and standing pose, derived from the MJCF alone.

:func:`describe` reads any floating-base model with four legs (MuJoCo Menagerie's Unitree,
ANYbotics and Google quadrupeds as published, the Solo12) without names or constants of its
own: the base is the body of the free joint; a leg is the chain of hinge joints below one of
the base's children; its foot is the lowest sphere among the collision geoms (those with a
contype or conaffinity, or in a ``<contact><pair>``) of the chain's last body and below (else
its lowest collision geom) at the standing pose; legs are named by where their
feet stand, front/hind (``F``/``H``) along the base's x axis and left/right (``L``/``R``)
along its y axis (read at ``qpos0``, base level, where the file has no keyframe). The standing
pose is the keyframe ``home`` (else the file's first keyframe), or, in a file without one,
computed from the model alone: each foot under its hip, the Solo12's fraction of the leg's
reach below it (:func:`standing_depth`), the knee bent toward the body's middle where its
range allows, the base level and raised until the feet touch the ground plane z = 0.

What :func:`describe` finds is what ``cfm-jax robot check`` reports for a floating-base robot;
:meth:`Quadruped.leg_ik` is any such leg's inverse kinematics (on the Solo12 it gives the
closed form of :func:`cfm_jax.sim.solo12.leg_ik`), and :func:`with_foot_sensors` /
:func:`add_foot_sensors` give a file without them the ground and the foot contact sensors
whose forces the legged tasks put in the state (:func:`cfm_jax.sim.robots.load` adds them to a
quadruped's file that lacks them, its servos converted or not); :func:`fall_rule` is the
Solo12's fall rule read from any quadruped's model. The legged tasks use the Solo12's closed
forms (:mod:`cfm_jax.sim.solo12`) on the Solo12 and this module's description on any other
quadruped with a torque motor per joint (:func:`cfm_jax.tasks.locomotion.legs_of`).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

LEG_NAMES = ("FL", "FR", "HL", "HR")
"""The legs' order: front left, front right, hind left, hind right (the Solo12's)."""


class QuadrupedError(ValueError):
    """A model that :func:`describe` cannot read as a quadruped; the message says why.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> describe(robots.load("iiwa14").mj_model)
      Traceback (most recent call last):
      cfm_jax.sim.quadruped.QuadrupedError: it has 0 free joints; a quadruped has one, its base's
    """


@dataclasses.dataclass(frozen=True)
class Leg:
    """One leg of a :class:`Quadruped`; positions in the base frame at the standing pose (m).

    Attributes:
      name: ``FL``, ``FR``, ``HL`` or ``HR`` (:data:`LEG_NAMES`).
      joints: the leg's hinge joints, from the base to the foot.
      qpos: their addresses in ``qpos``.
      dofs: their addresses in ``qvel``.
      foot_geom: the foot's geom (its name, else ``"geom <id>"``).
      foot_id: its id in the model.
      foot_radius: the foot sphere's radius (0 for a foot that is not a sphere).
      hip: the anchor of the leg's first joint.
      foot: the foot's centre.
      length: the chain's length, joint anchor to joint anchor to the foot's centre.

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> leg = describe(solo12.load_model()).legs[1]
      >>> leg.name, leg.foot_geom, leg.qpos, round(leg.foot_radius, 3)
      ('FR', 'FR_foot', (10, 11, 12), 0.017)
    """

    name: str
    joints: tuple[str, ...]
    qpos: tuple[int, ...]
    dofs: tuple[int, ...]
    foot_geom: str
    foot_id: int
    foot_radius: float
    hip: np.ndarray
    foot: np.ndarray
    length: float


@dataclasses.dataclass(frozen=True)
class Quadruped:
    """A quadruped's legs and standing pose, from :func:`describe`.

    Attributes:
      base: the floating base's body.
      legs: the four :class:`Leg` in :data:`LEG_NAMES` order.
      standing: the standing pose, ``qpos (nq,)``.
      standing_from: where it comes from (a keyframe, or how it was computed).
      model: the ``mujoco.MjModel`` it was read from (for :meth:`leg_ik`).

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> robot = describe(solo12.load_model())
      >>> robot.standing_from, round(robot.standing_height, 4), robot.feet.shape
      ("keyframe 'home'", 0.2384, (4, 3))
    """

    base: str
    legs: tuple[Leg, ...]
    standing: np.ndarray
    standing_from: str
    model: object = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def standing_height(self) -> float:
        """Height (m) of the base's origin at the standing pose."""
        return float(self.standing[2])

    @property
    def feet(self) -> np.ndarray:
        """The four feet's centres at the standing pose, base frame, ``(4, 3)``."""
        return np.stack([leg.foot for leg in self.legs])

    def leg_ik(self, leg: int, foot, start=None, tolerance: float = 1e-12) -> np.ndarray:
        """Joints of leg ``leg`` that put its foot's centre at ``foot`` (base frame, m):
        Newton's method on MuJoCo's Jacobian of the foot geom (damped where the leg is near
        straight), from ``start`` (None: the standing pose's joints, whose knee branch it
        keeps), within the joints' ranges where they have them.

        Args:
          leg: 0, 1, 2 or 3 (FL, FR, HL, HR).
          foot: ``(3,)`` target of the foot centre in the base frame (m).
          start: the leg's joints to start from, or None.
          tolerance: the largest foot error (m) at which it stops (else after 100 steps).

        Returns:
          the leg's joint angles ``(len(joints),)``; for a target out of reach, those of the
          closest foot position it found.

        Examples:
          >>> from cfm_jax.sim import solo12
          >>> robot = describe(solo12.load_model())
          >>> np.round(robot.leg_ik(0, solo12.leg_fk([0.1, 0.7, -1.4], 0)), 9).tolist()
          [0.1, 0.7, -1.4]
        """
        import mujoco

        model, spec = self.model, self.legs[leg]
        q = np.array(self.standing[list(spec.qpos)] if start is None else start, dtype=float)
        joints = [model.joint(name).id for name in spec.joints]
        low = np.where(model.jnt_limited[joints], model.jnt_range[joints, 0], -np.inf)
        high = np.where(model.jnt_limited[joints], model.jnt_range[joints, 1], np.inf)
        target = np.asarray(foot, dtype=float)
        jacobian = np.zeros((3, model.nv))
        best, best_error = q.copy(), np.inf
        for _ in range(100):
            data = self._posed(leg, q)
            mujoco.mj_comPos(model, data)
            error = target - data.geom_xpos[spec.foot_id]
            size = float(np.linalg.norm(error))
            if size < best_error:
                best, best_error = q.copy(), size
            if size <= tolerance:
                break
            mujoco.mj_jacGeom(model, data, jacobian, None, spec.foot_id)
            j = jacobian[:, list(spec.dofs)]
            damping = 1e-12 + 1e-6 * size  # vanishes at the solution: Newton's steps there
            step = j.T @ np.linalg.solve(j @ j.T + damping * np.eye(3), error)
            q = np.clip(q + step, low, high)
        return best

    def foot_position(self, leg: int, joints) -> np.ndarray:
        """Leg ``leg``'s foot centre (base frame, m) with its joints at ``joints``, the others
        standing: MuJoCo's forward kinematics.

        Examples:
          >>> from cfm_jax.sim import solo12
          >>> robot = describe(solo12.load_model())
          >>> np.round(robot.foot_position(0, [0.0, 0.8, -1.6]), 4).tolist()
          [0.1946, 0.148, -0.2229]
        """
        return self._posed(leg, joints).geom_xpos[self.legs[leg].foot_id].copy()

    def _posed(self, leg: int, joints):
        """The kinematics (one ``MjData``, reused) of the standing pose with the base at the
        origin (base frame = world frame) and leg ``leg``'s joints at ``joints``."""
        import mujoco

        data = self.__dict__.get("_data")
        if data is None:
            data = mujoco.MjData(self.model)
            object.__setattr__(self, "_data", data)
        data.qpos[:] = self.standing
        data.qpos[:3], data.qpos[3:7] = 0.0, (1.0, 0.0, 0.0, 0.0)
        data.qpos[list(self.legs[leg].qpos)] = joints
        mujoco.mj_kinematics(self.model, data)
        return data

    def summary(self) -> str:
        """One line per leg and one for the stance, as ``cfm-jax robot check`` prints them."""
        lines = [
            f"standing pose: {self.standing_from}; base {self.base!r} at "
            f"{self.standing_height:.3g} m"
        ]
        for leg in self.legs:
            foot = ", ".join(f"{x:+.3f}" for x in leg.foot)
            lines.append(
                f"{leg.name}: joints {', '.join(leg.joints)}; foot {leg.foot_geom} (radius "
                f"{leg.foot_radius:.3g} m) at ({foot}) m from the base, leg length "
                f"{leg.length:.3g} m"
            )
        return "\n".join(lines)


def _body_name(model, body: int) -> str:
    name = model.body(body).name
    return name if name else f"body {body}"


def _geom_name(model, geom: int) -> str:
    name = model.geom(geom).name
    return name if name else f"geom {geom}"


def _standing(model) -> tuple[np.ndarray, str | None]:
    """The keyframe ``home`` (else the first keyframe) and its name, else ``qpos0`` and None."""
    if model.nkey:
        names = [model.key(k).name for k in range(model.nkey)]
        k = names.index("home") if "home" in names else 0
        label = names[k] or f"keyframe {k}"
        return np.array(model.key_qpos[k], dtype=float), label
    return np.array(model.qpos0, dtype=float), None


def _in_base(data, base: int, points: np.ndarray) -> np.ndarray:
    """World ``points (..., 3)`` in the frame of body ``base``."""
    rotation = data.xmat[base].reshape(3, 3)
    return (np.asarray(points) - data.xpos[base]) @ rotation


def describe(model) -> Quadruped:
    """Read ``model`` as a quadruped (the rules: this module's docstring).

    Args:
      model: a ``mujoco.MjModel``.

    Raises:
      QuadrupedError: the model has no floating base, not four legs of hinge joints, a leg
        without a collision geom at its end, or feet that do not stand one in each quadrant
        around the base; the message names what was found.

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> robot = describe(solo12.load_model())
      >>> [leg.name for leg in robot.legs], robot.legs[0].joints
      (['FL', 'FR', 'HL', 'HR'], ('FL_HAA', 'FL_HFE', 'FL_KFE'))
    """
    import mujoco

    free, hinge = int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_HINGE)
    frees = [j for j in range(model.njnt) if int(model.jnt_type[j]) == free]
    if len(frees) != 1:
        raise QuadrupedError(f"it has {len(frees)} free joints; a quadruped has one, its base's")
    base = int(model.jnt_bodyid[frees[0]])
    if int(model.body_parentid[base]) != 0:
        raise QuadrupedError(
            f"its free joint's body {_body_name(model, base)!r} is not a child of the world"
        )
    others = [j for j in range(model.njnt) if j != frees[0]]
    wrong = [model.joint(j).name or f"joint {j}" for j in others if model.jnt_type[j] != hinge]
    if wrong:
        raise QuadrupedError(f"its joints {wrong} are not hinges; a leg here is a chain of hinges")

    def top(body: int) -> int:
        """The child of the base whose subtree holds ``body`` (-1: not below the base)."""
        while body > 0 and int(model.body_parentid[body]) != base:
            body = int(model.body_parentid[body])
        return body if body > 0 else -1

    chains: dict[int, list[int]] = {}
    for j in others:
        root = top(int(model.jnt_bodyid[j]))
        if root < 0:
            raise QuadrupedError(f"its joint {model.joint(j).name!r} is not below the base")
        chains.setdefault(root, []).append(j)
    if len(chains) != 4:
        found = {_body_name(model, r): len(js) for r, js in chains.items()}
        raise QuadrupedError(
            f"the base {_body_name(model, base)!r} carries {len(chains)} jointed limbs "
            f"(bodies and their joints: {found}); a quadruped has four legs"
        )
    qpos, label = _standing(model)
    if label is not None:
        return _read(model, base, chains, qpos, f"keyframe {label!r}")
    # No keyframe: the legs read at qpos0 (base level, lowest foot on the ground), then
    # each foot placed under its hip at the Solo12's depth and read again there.
    qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
    rough = _read(model, base, chains, qpos, "qpos0")
    return _read(model, base, chains, *_computed_standing(rough))


def _read(model, base: int, chains: dict, qpos: np.ndarray, standing_from: str) -> Quadruped:
    """The :class:`Quadruped` of ``model``'s legs ``chains`` at pose ``qpos``; a pose not
    from a keyframe (``standing_from`` not ``keyframe ...``) has its base raised or lowered
    until its lowest foot touches the ground z = 0."""
    import mujoco

    qpos = np.array(qpos, dtype=float)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)

    sphere = int(mujoco.mjtGeom.mjGEOM_SPHERE)
    # Geoms that can touch anything: by contype/conaffinity, or named in a <contact><pair>.
    touching = {g for g in range(model.ngeom) if model.geom_contype[g] or model.geom_conaffinity[g]}
    touching |= {int(g) for g in (*model.pair_geom1, *model.pair_geom2)}
    legs = []
    for root, joints in chains.items():
        bodies = [int(model.jnt_bodyid[j]) for j in joints]
        for a, b in zip(bodies, bodies[1:], strict=False):  # each joint below the one before
            up = b
            while up not in (a, base, 0):
                up = int(model.body_parentid[up])
            if up != a:
                raise QuadrupedError(
                    f"the limb of body {_body_name(model, root)!r} branches (joints "
                    f"{[model.joint(j).name for j in joints]}); a leg here is one chain"
                )
        last = bodies[-1]
        below = [b for b in range(model.nbody) if b == last or _descends(model, b, last)]
        geoms = [
            g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in below and g in touching
        ]
        if not geoms:
            raise QuadrupedError(
                f"the leg of joints {[model.joint(j).name for j in joints]} has no collision "
                "geom at its end (its foot)"
            )
        spheres = [g for g in geoms if int(model.geom_type[g]) == sphere]
        pool = spheres or geoms
        foot = min(pool, key=lambda g: (data.geom_xpos[g][2], g))
        anchors = [np.array(data.xanchor[j]) for j in joints]
        points = [*anchors, np.array(data.geom_xpos[foot])]
        length = float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False)))
        legs.append(
            dict(
                joints=tuple(model.joint(j).name for j in joints),
                qpos=tuple(int(model.jnt_qposadr[j]) for j in joints),
                dofs=tuple(int(model.jnt_dofadr[j]) for j in joints),
                foot_geom=_geom_name(model, foot),
                foot_id=foot,
                foot_radius=float(model.geom_size[foot][0]) if foot in spheres else 0.0,
                hip=_in_base(data, base, anchors[0]),
                foot=_in_base(data, base, data.geom_xpos[foot]),
                length=length,
            )
        )
    if not standing_from.startswith("keyframe"):  # the lowest foot on the ground z = 0
        lowest = min(float(data.geom_xpos[leg["foot_id"]][2]) - leg["foot_radius"] for leg in legs)
        qpos[2] -= lowest
    named = {}
    for leg in legs:
        x, y = leg["foot"][0], leg["foot"][1]
        name = ("F" if x > 0 else "H") + ("L" if y > 0 else "R")
        if name in named or x == 0 or y == 0:
            feet = {tuple(np.round(leg["foot"], 3)): leg["joints"][0] for leg in legs}
            raise QuadrupedError(
                "its feet do not stand one in each quadrant around the base (front/hind along "
                f"its x axis, left/right along y) at the standing pose: feet {feet}"
            )
        named[name] = leg
    ordered = []
    for name in LEG_NAMES:
        ordered.append(Leg(name=name, **named[name]))
    return Quadruped(
        base=_body_name(model, base),
        legs=tuple(ordered),
        standing=qpos,
        standing_from=standing_from,
        model=model,
    )


@functools.cache
def standing_depth() -> float:
    """The Solo12's foot depth below the hip at ``home`` over its leg's reach (hip, the
    second-to-last joint, to foot centre: 0.2229 m of 0.3246 m); keyframe-less quadrupeds
    stand at this depth (:func:`describe`).

    Examples:
      >>> round(standing_depth(), 4)
      0.6869
    """
    from cfm_jax.sim import solo12

    solo = describe(solo12.load_model())
    return float(np.mean([depth / reach for depth, reach in _hip_depths(solo)]))


def _hip_depths(robot: Quadruped) -> list[tuple[float, float]]:
    """Per leg ``(depth, reach)`` at the standing pose: its foot centre's depth below its
    hip (the anchor of its second-to-last joint; its only joint's for a one-joint leg) and
    the chain's length from the hip to the foot centre."""
    out = []
    for leg in range(4):
        points = _hip_to_foot(robot, leg, robot.standing[list(robot.legs[leg].qpos)])
        reach = sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False))
        out.append((float(points[0][2] - points[-1][2]), float(reach)))
    return out


def _hip_to_foot(robot: Quadruped, leg: int, joints) -> list[np.ndarray]:
    """The anchors of leg ``leg``'s joints from its hip down, then its foot centre, base
    frame, with its joints at ``joints`` (MuJoCo's kinematics)."""
    spec, model = robot.legs[leg], robot.model
    data = robot._posed(leg, joints)
    hip = max(len(spec.joints) - 2, 0)
    anchors = [data.xanchor[model.joint(name).id].copy() for name in spec.joints[hip:]]
    return [*anchors, data.geom_xpos[spec.foot_id].copy()]


def _computed_standing(rough: Quadruped) -> tuple[np.ndarray, str]:
    # ``(qpos, standing_from)``: the standing pose of a quadruped without keyframe, from
    # its legs ``rough`` read at ``qpos0`` with the base level. Each foot centre is placed
    # under its hip (the anchor of the leg's second-to-last joint) in x, at its ``qpos0``
    # lateral place in y, and :func:`standing_depth` of the leg's reach below the hip (the
    # depths of the four legs averaged, so all four feet touch the ground when the legs
    # differ slightly); :meth:`Quadruped.leg_ik` solves each leg from both knee bends
    # (the last joint at +1 and -1 rad, where its range allows) and keeps, of the solutions
    # that reach the foot, the one whose knee (the last joint's anchor) points toward the
    # middle of the body along x, as the Solo12's do (front knees behind their feet, hind
    # knees ahead of theirs), else the other, else the closest. The base is then lowered
    # until the feet touch z = 0 (:func:`_read`).
    model = rough.model
    ratio = standing_depth()
    qpos = rough.standing.copy()
    targets, solved = [], []
    for leg, spec in enumerate(rough.legs):
        points = _hip_to_foot(rough, leg, qpos[list(spec.qpos)])
        reach = sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False))
        hip, foot = points[0], points[-1]
        targets.append([hip[0], foot[1], hip[2] - ratio * reach])
    # One body height for all four feet: each foot bottom on the same plane.
    bottom = np.mean([t[2] - spec.foot_radius for t, spec in zip(targets, rough.legs, strict=True)])
    for leg, spec in enumerate(rough.legs):
        target = np.array(targets[leg])
        target[2] = bottom + spec.foot_radius
        joints = [model.joint(name).id for name in spec.joints]
        low, high = model.jnt_range[joints[-1]]
        limited = bool(model.jnt_limited[joints[-1]])
        found = []
        for bend in (1.0, -1.0):
            if limited and not low <= bend <= high:
                continue
            start = np.array(qpos[list(spec.qpos)], dtype=float)
            start[-1] = bend
            if len(start) > 1:
                start[-2] = -bend / 2
            q = rough.leg_ik(leg, target, start=start)
            error = float(np.linalg.norm(rough.foot_position(leg, q) - target))
            knee = _hip_to_foot(rough, leg, q)[-2]
            inward = (knee[0] - target[0]) * np.sign(target[0]) < 0
            found.append((error > 1e-9, not inward, error, q))
        if not found:  # a knee whose range holds neither bend: leave it at qpos0
            found.append((True, True, np.inf, qpos[list(spec.qpos)]))
        best = min(found, key=lambda f: f[:3])
        qpos[list(spec.qpos)] = best[3]
        solved.append(not best[0])
    where = "under its hip" if all(solved) else "under its hip where it reaches"
    return qpos, (
        f"computed: each foot {where}, {ratio:.3f} of the leg's reach below it (the "
        "Solo12's), knees toward the body's middle where their ranges allow, on the ground "
        "z = 0"
    )


def _descends(model, body: int, ancestor: int) -> bool:
    """Whether ``body`` lies below ``ancestor`` in the kinematic tree."""
    while body > 0:
        body = int(model.body_parentid[body])
        if body == ancestor:
            return True
    return False


FOOT_SENSOR_DATA = 99
"""The contact sensor's ``data="found force normal tangent"`` (MuJoCo's bit set, 10 numbers)."""


def with_foot_sensors(path: str):
    """The model of the MJCF at ``path`` with what the legged tasks read of the ground
    (:func:`add_foot_sensors`). A file whose feet each have such a sensor already is
    compiled as it is.

    Args:
      path: an MJCF file of a quadruped (:func:`describe`).

    Returns:
      ``(model, added)``: the compiled ``mujoco.MjModel`` and what was added, in words (an
      empty list: nothing).

    Raises:
      QuadrupedError: as :func:`describe`.

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> with_foot_sensors(solo12.model_path())[1]  # it declares its own
      []
    """
    import mujoco

    spec = mujoco.MjSpec.from_file(path)
    added = add_foot_sensors(spec)
    return spec.compile(), added


def add_foot_sensors(spec) -> list[str]:
    """Give the quadruped of ``spec`` (edited in place) what the legged tasks read of the
    ground: a plane ``floor`` at z = 0 (where the world body has none; MuJoCo's contact
    defaults) and a contact sensor ``<leg>_contact`` per foot, FL, FR, HL, HR, declared as
    ``robots/solo12.xml`` declares them (unnamed foot geoms become ``<leg>_foot``). Nothing
    is added where each foot has one already; composes with :func:`cfm_jax.sim.robots.convert`.

    Args:
      spec: a ``mujoco.MjSpec`` of a quadruped (:func:`describe` of its compiled model).

    Returns:
      what was added, in words (an empty list: nothing).

    Raises:
      QuadrupedError: as :func:`describe`; or a foot that cannot touch the ground plane (no
        shared contact bit, no ``<contact><pair>``), named.

    Examples:
      >>> import mujoco
      >>> from cfm_jax.sim import solo12
      >>> add_foot_sensors(mujoco.MjSpec.from_file(solo12.model_path()))  # it has its own
      []
    """
    import mujoco

    model = spec.compile()
    found = describe(model)
    plane = int(mujoco.mjtGeom.mjGEOM_PLANE)
    contact = int(mujoco.mjtSensor.mjSENS_CONTACT)
    planes = [
        g for g in range(model.ngeom) if model.geom_type[g] == plane and model.geom_bodyid[g] == 0
    ]
    feet = [leg.foot_id for leg in found.legs]
    sensed = set()
    for i in range(model.nsensor):
        if int(model.sensor_type[i]) == contact and int(model.sensor_dim[i]) == 10:
            pair = {int(model.sensor_objid[i]), int(model.sensor_refid[i])}
            sensed |= {f for f in feet if f in pair and pair - {f} <= set(planes)}
    if planes and set(feet) <= sensed:
        _feet_touch(model, found, planes[0])
        return []
    added = []
    geoms = list(spec.geoms)
    if planes:
        floor = geoms[planes[0]]
        if not floor.name:
            floor.name = "floor"
    else:
        # The floor's contact bits are set, not inherited from the file's top-level default
        # (an MJX variant's may be contype 0 conaffinity 0, which collides with nothing): bit
        # 1 both ways, as a scene's floor has, and whatever bits the feet carry, so that each
        # foot meets it (MuJoCo: contype of one & conaffinity of the other, either way round).
        floor = spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                        size=[0.0, 0.0, 0.05])  # fmt: skip
        floor.contype = 1 | int(np.bitwise_or.reduce(model.geom_conaffinity[feet]))
        floor.conaffinity = 1 | int(np.bitwise_or.reduce(model.geom_contype[feet]))
        added.append("a ground plane 'floor' at z = 0")
    for leg in found.legs:
        geom = geoms[leg.foot_id]
        if not geom.name:
            geom.name = f"{leg.name}_foot"
        spec.add_sensor(
            name=f"{leg.name}_contact",
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_GEOM,
            objname=geom.name,
            reftype=mujoco.mjtObj.mjOBJ_GEOM,
            refname=floor.name,
            intprm=[FOOT_SENSOR_DATA, 1, 1],
        )
    added.append(
        "a contact sensor per foot ("
        + ", ".join(f"{leg.name}: {geoms[leg.foot_id].name}" for leg in found.legs)
        + f" on {floor.name!r})"
    )
    names = [geoms[leg.foot_id].name for leg in found.legs]  # the spec's geoms are the
    model = spec.compile()  # model's, in order: checked on the model compiled again
    again = [model.geom(g).name for g in (leg.foot_id for leg in describe(model).legs)]
    if again != names:
        raise QuadrupedError(f"its feet {names} were not found again after adding the sensors")
    _feet_touch(model, describe(model), model.geom(floor.name).id)
    return added


def _feet_touch(model, robot: Quadruped, floor: int) -> None:
    """Raise :class:`QuadrupedError` unless every foot of ``robot`` can touch the ground
    plane ``floor`` (a geom id): a ``<contact><pair>`` of the two, or their contact bits
    (contype of one and conaffinity of the other share a bit), and no ``<exclude>`` of
    their bodies."""
    pairs = {frozenset(map(int, ab)) for ab in zip(model.pair_geom1, model.pair_geom2, strict=True)}
    excluded = {frozenset((int(b) >> 16, int(b) & 0xFFFF)) for b in model.exclude_signature}
    for leg in robot.legs:
        foot = leg.foot_id
        if frozenset((foot, floor)) in pairs:
            continue
        bits = (model.geom_contype[foot] & model.geom_conaffinity[floor]) or (
            model.geom_contype[floor] & model.geom_conaffinity[foot]
        )
        bodies = frozenset((int(model.geom_bodyid[foot]), int(model.geom_bodyid[floor])))
        if bits and bodies not in excluded:
            continue
        why = "an <exclude> of their bodies" if bits else (
            f"contype {model.geom_contype[foot]} conaffinity {model.geom_conaffinity[foot]} "
            f"against the floor's {model.geom_contype[floor]} and "
            f"{model.geom_conaffinity[floor]}, and no <contact><pair> of the two"
        )  # fmt: skip
        raise QuadrupedError(
            f"its {leg.name} foot (geom {_geom_name(model, foot)!r}) cannot touch the ground "
            f"plane {_geom_name(model, floor)!r}: {why}; give the foot a contype or "
            "conaffinity bit the floor shares, or a <pair> with it"
        )


@dataclasses.dataclass(frozen=True)
class FallRule:
    """:func:`cfm_jax.sim.solo12.fell` for any quadruped (traceable), its lengths scaled by
    the standing height over the Solo12's; its body points are the corners of the base's
    collision boxes and the knees (each leg's last joint anchor).

    Attributes:
      corners: the base's points, base frame, ``(k, 3)``: the 8 corners of each collision
        geom's bounding box (MuJoCo's ``geom_aabb``) of the base body.
      knees: per leg, what :meth:`knees` composes: ``(qpos address or -1, body position,
        body rotation, joint anchor, joint axis)`` per step from the base to the knee.
      min_base_height: lowest base origin height (m).
      max_tilt: largest angle between the base's and the world's z axes (rad).
      body_clearance: least height (m) of the base corners and knees above the floor.
      max_pull: largest downward force (N) a foot may exert on the floor.

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> rule = fall_rule(describe(solo12.load_model()), scale=1.0)
      >>> bool(rule(solo12.load_model().key("home").qpos)), rule.min_base_height
      (False, 0.1)
    """

    corners: np.ndarray
    knees: tuple
    min_base_height: float
    max_tilt: float
    body_clearance: float
    max_pull: float

    def knee_positions(self, qpos, xp=np):
        """The four knees (each leg's last joint anchor), base frame, ``(..., 4, 3)``.

        Args:
          qpos: ``(..., nq)`` positions.
          xp: the array module, ``numpy`` or ``jax.numpy``.

        Examples:
          >>> from cfm_jax.sim import solo12
          >>> rule = fall_rule(describe(solo12.load_model()), scale=1.0)
          >>> np.round(rule.knee_positions(solo12.load_model().key("home").qpos)[:, 2], 4)
          array([-0.1115, -0.1115, -0.1115, -0.1115])
        """
        out = []
        for steps in self.knees:
            position = xp.zeros(qpos.shape[:-1] + (3,), dtype=qpos.dtype)
            rotation = xp.broadcast_to(xp.eye(3, dtype=qpos.dtype), qpos.shape[:-1] + (3, 3))
            anchor = None
            for address, body_pos, body_rot, anchor, axis in steps:
                if address < 0:  # a body: its pose in its parent's frame
                    position = position + xp.einsum("...ij,j->...i", rotation, body_pos)
                    rotation = xp.einsum("...ij,jk->...ik", rotation, body_rot)
                    continue
                # a hinge about ``axis`` through ``anchor`` (the body's frame)
                turn = _rotation(axis, qpos[..., address], xp)
                shift = anchor - xp.einsum("...ij,j->...i", turn, anchor)
                position = position + xp.einsum("...ij,...j->...i", rotation, shift)
                rotation = xp.einsum("...ij,...jk->...ik", rotation, turn)
            out.append(position + xp.einsum("...ij,j->...i", rotation, anchor))
        return xp.stack(out, axis=-2)

    def __call__(self, qpos, foot_force=None, xp=np):
        """Where the robot has fallen, ``(...)`` bool (the rule: the class docstring).

        Args:
          qpos: ``(..., nq)`` positions (base pose first).
          foot_force: ``(..., 4, 3)`` floor forces on the feet (world frame), or None.
          xp: the array module, ``numpy`` or ``jax.numpy``.
        """
        from cfm_jax.sim import solo12

        knees = lambda q: self.knee_positions(q, xp)  # noqa: E731
        return solo12.body_fell(qpos, self.corners, knees, self._limits(), foot_force, xp)

    def terms(self, qpos, foot_force=None, xp=np) -> dict:
        """The clauses one by one (:func:`cfm_jax.sim.solo12.body_fall_terms`)."""
        from cfm_jax.sim import solo12

        knees = lambda q: self.knee_positions(q, xp)  # noqa: E731
        return solo12.body_fall_terms(qpos, self.corners, knees, self._limits(), foot_force, xp)

    def _limits(self):
        from cfm_jax.sim import solo12

        return solo12.FallLimits(
            min_base_height=self.min_base_height,
            max_tilt=self.max_tilt,
            body_clearance=self.body_clearance,
            max_pull=self.max_pull,
        )


def _rotation(axis, angle, xp):
    """Rotation matrices about the unit ``axis`` by ``angle`` ``(...)``: ``(..., 3, 3)``."""
    x, y, z = (float(a) for a in axis)
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = xp.sin(angle)[..., None, None], xp.cos(angle)[..., None, None]
    return np.eye(3) + s * cross + (1.0 - c) * (cross @ cross)


def fall_rule(robot: Quadruped, scale: float, limits=None) -> FallRule:
    """The :class:`FallRule` of ``robot``: the Solo12's limits (``limits``, None:
    :data:`cfm_jax.sim.solo12.FALL`) with the base height and the body clearance times
    ``scale`` (the robot's standing height over the Solo12's), the base corners from its
    collision geoms and the knees from its kinematic tree.

    Args:
      robot: a :class:`Quadruped` (:func:`describe`).
      scale: the length scale to the Solo12.
      limits: a :class:`cfm_jax.sim.solo12.FallLimits` to scale.

    Examples:
      >>> from cfm_jax.sim import solo12
      >>> fall_rule(describe(solo12.load_model()), scale=2.0).min_base_height
      0.2
    """
    import mujoco

    from cfm_jax.sim import solo12

    limits = solo12.FALL if limits is None else limits
    model = robot.model
    base = model.body(robot.base).id
    touching = [
        g
        for g in range(model.ngeom)
        if int(model.geom_bodyid[g]) == base
        and (model.geom_contype[g] or model.geom_conaffinity[g])
    ]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = [np.zeros((1, 3))]  # the base origin where the base has no collision geom
    for g in touching:
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        local = model.geom_aabb[g, :3] + signs * model.geom_aabb[g, 3:]
        corners.append(model.geom_pos[g] + local @ rot.reshape(3, 3).T)
    corners = np.concatenate(corners[1:] or corners)
    knees = []
    for leg in robot.legs:
        last = model.joint(leg.joints[-1]).id
        chain, body = [], int(model.jnt_bodyid[last])
        while body != base:
            chain.append(body)
            body = int(model.body_parentid[body])
        steps = []
        for body in reversed(chain):
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.body_quat[body])
            steps.append((-1, np.array(model.body_pos[body]), rot.reshape(3, 3), None, None))
            first, count = int(model.body_jntadr[body]), int(model.body_jntnum[body])
            for j in range(first, first + count):
                steps.append((int(model.jnt_qposadr[j]), None, None,
                              np.array(model.jnt_pos[j]), np.array(model.jnt_axis[j])))  # fmt: skip
                if j == last:
                    break
        knees.append(tuple(steps))
    return FallRule(
        corners=corners,
        knees=tuple(knees),
        min_base_height=limits.min_base_height * scale,
        max_tilt=limits.max_tilt,
        body_clearance=limits.body_clearance * scale,
        max_pull=limits.max_pull,
    )
