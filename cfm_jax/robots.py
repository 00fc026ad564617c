"""Robots as data: MJCF file -> :class:`Robot` (MuJoCo model, MJX model, state map, limits).

A robot is loaded by registered name (``"iiwa14"``, ``"two_link_arm"``: files shipped in the
package, from the repository's ``robots/`` folder) or by a path to any MJCF whose every
hinge or slide joint is driven by exactly one torque motor; the robot may have a floating
base (one free joint at the root of the tree, not actuated), as legged robots do.

The action is the torque ``tau`` of the actuated joints (``action_dim`` of them, in dof
order), which becomes ``ctrl = tau / gear``. Fixed-base arms have ``nq == nv == action_dim``
and the arm tasks use the state ``s = [q, qdot]``; which tasks fit which robot is checked
by the task (:func:`cfm_jax.tasks.make`).

Examples:
  >>> robot = load("iiwa14")
  >>> robot.nv, robot.state_dim
  (7, 14)
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import os
import pathlib
from functools import cached_property

import mujoco
import numpy as np

_ROBOT_PACKAGE = "cfm_jax._robot_files"


class RobotError(ValueError):
    """An MJCF file that cannot be used as a cfm_jax robot (the message says why).

    Examples:
      >>> try:
      ...     load("no_such_robot")
      ... except RobotError as error:
      ...     print(str(error)[:45])
      robot='no_such_robot' is not a registered rob
    """


def robot_dir():
    """Folder of the shipped MJCF files: the installed package data ``cfm_jax._robot_files``
    (a wheel or an editable install), else ``robots/`` of the source checkout this module
    was imported from (for example Python started in a clone that shadows the install).

    Returns:
      A ``pathlib.Path`` or an ``importlib.resources`` traversable of the folder.

    Examples:
      >>> (robot_dir() / "iiwa14.xml").is_file()
      True
    """
    try:
        return importlib.resources.files(_ROBOT_PACKAGE)
    except ModuleNotFoundError:
        return pathlib.Path(__file__).resolve().parent.parent / "robots"


def registered() -> tuple[str, ...]:
    """Names of the robots shipped with the package (the ``robots/*.xml`` files).

    Returns:
      Sorted names, each usable as ``Config.robot``.

    Examples:
      >>> registered()
      ('iiwa14', 'solo12', 'two_link_arm')
    """
    files = robot_dir()
    return tuple(sorted(p.name[:-4] for p in files.iterdir() if p.name.endswith(".xml")))


def resolve(name_or_path: str) -> str:
    """Path of the MJCF file for a registered name or an existing path.

    Args:
      name_or_path: a registered name (see :func:`registered`) or a path to an ``.xml`` file
        (anything with a path separator or ending in ``.xml`` is taken as a path).

    Returns:
      The absolute path of the file.

    Raises:
      RobotError: neither a registered name nor an existing file (the message lists the
        registered names).

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


@dataclasses.dataclass(frozen=True, eq=False)
class Robot:
    """A torque-controlled robot: a fixed-base arm or a floating-base (legged) robot.

    Attributes:
      name: registered name or file stem.
      path: absolute path of the MJCF file.
      mj_model: the MuJoCo model (C engine); the oracle and native baselines use it.
      joint_names: names of all joints, in model order.
      joint_range: ``(njnt, 2)`` position limits (``-inf, inf`` for unlimited joints and
        the free joint).
      torque_limit: ``(action_dim,)`` symmetric torque limit per actuated joint (N·m or N).
      gear: ``(action_dim,)`` actuator gear per actuated joint; ``ctrl = tau / gear``.
      actuator_of_joint: ``(action_dim,)`` index of the actuator driving each actuated joint.
      home: ``(nq,)`` the keyframe ``home`` if present, else ``qpos0``.
      actuated_dofs: ``(action_dim,)`` dof (``qvel``) index of each actuated joint.
      floating_base: whether the root is a free joint (its 6 dofs are not actuated).

    Examples:
      >>> arm = load("two_link_arm")
      >>> arm.nq, arm.action_dim, arm.torque_limit.tolist(), arm.floating_base
      (2, 2, [20.0, 10.0], False)
      >>> arm.torque_to_ctrl(np.array([4.0, -2.0])).tolist()
      [4.0, -2.0]
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
    def timestep(self) -> float:
        return float(self.mj_model.opt.timestep)

    @cached_property
    def mjx_model(self):
        """The MJX model (``mujoco.mjx.put_model``); built by :func:`load`, outside any trace."""
        from cfm_jax._mjx import mjx

        return mjx.put_model(self.mj_model)

    def torque_to_ctrl(self, tau):
        """Map joint torques ``(..., action_dim)`` to the ``ctrl`` vector ``(..., nu)``."""
        import jax.numpy as jnp

        ctrl = jnp.zeros(tau.shape[:-1] + (self.mj_model.nu,), tau.dtype)
        return ctrl.at[..., self.actuator_of_joint].set(tau / self.gear)

    def mass_matrix_diagonal(self, qpos) -> np.ndarray:
        """Diagonal of the joint-space inertia ``M(q)`` (MuJoCo C), shape ``(nv,)``."""
        data = mujoco.MjData(self.mj_model)
        data.qpos[:] = qpos
        mujoco.mj_forward(self.mj_model, data)
        full = np.zeros((self.nv, self.nv))
        mujoco.mj_fullM(self.mj_model, data, full)
        return np.diag(full).copy()


def load(name_or_path: str, timestep: float | None = None) -> Robot:
    """Load and check a robot.

    Args:
      name_or_path: registered name (see :func:`registered`) or path to an MJCF file.
      timestep: override of the MJCF physics timestep in seconds (None: keep it).

    Raises:
      RobotError: the file does not exist, does not parse, has ball joints or a free joint
        other than a single floating base, no actuators, non-torque actuators, or hinge /
        slide joints without exactly one motor.

    Returns:
      The :class:`Robot` (its MJX model already built).

    Examples:
      >>> solo = load("solo12")
      >>> solo.floating_base, solo.nq, solo.nv, solo.action_dim
      (True, 19, 18, 12)
    """
    path = resolve(name_or_path)
    try:
        model = mujoco.MjModel.from_xml_path(path)
    except Exception as error:  # mujoco raises ValueError with the parser's message
        raise RobotError(
            f"robot={name_or_path!r}: MJCF file {path} does not parse: {error}"
        ) from error
    name = os.path.splitext(os.path.basename(path))[0]
    where = f"robot={name_or_path!r} ({path})"
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
    for a in range(model.nu):
        aname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}"
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
                "torques"
            )
        dof = model.jnt_dofadr[model.actuator_trnid[a, 0]]
        if actuator_of_joint[dof] >= 0:
            raise RobotError(f"{where}: joint dof {dof} is driven by more than one actuator")
        actuator_of_joint[dof] = a
        gear[dof] = model.actuator_gear[a, 0]
        limits = []
        if model.actuator_ctrllimited[a]:
            limits.append(np.max(np.abs(model.actuator_ctrlrange[a])) * abs(gear[dof]))
        if model.actuator_forcelimited[a]:
            limits.append(np.max(np.abs(model.actuator_forcerange[a])))
        if limits:
            torque_limit[dof] = min(limits)
    actuated = np.array([d for d in range(model.nv) if d not in unactuated], dtype=np.int32)
    if np.any(actuator_of_joint[sorted(unactuated)] >= 0):
        raise RobotError(f"{where}: the floating base (free joint) cannot be actuated")
    missing = actuated[actuator_of_joint[actuated] < 0]
    if missing.size:
        names = [
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.dof_jntid[d]) for d in missing
        ]
        raise RobotError(f"{where}: joints {names} have no motor; every joint needs one")
    if not np.all(np.isfinite(torque_limit[actuated])):
        unlimited = [
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.dof_jntid[d])
            for d in actuated[~np.isfinite(torque_limit[actuated])]
        ]
        raise RobotError(
            f"{where}: motors of joints {unlimited} have no torque limit; set ctrlrange "
            "(with ctrllimited) or forcerange, the controller's outputs are squashed into it"
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
    joint_names = tuple(
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        for j in range(model.njnt)
    )
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
    )
    robot.mjx_model  # noqa: B018 -- build the device copy now, never inside a jit trace
    return robot
