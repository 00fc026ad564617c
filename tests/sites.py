"""Oracles of the end-effector site shared by the op-space tests (test_opspace.py,
test_references.py, test_baselines.py): the two-link arm's closed-form planar kinematics,
the iiwa's home flange and reach worked by hand from the facts sheet, MuJoCo's own
acceleration recursion, and random states near home."""

from __future__ import annotations

import mujoco
import numpy as np

L1, L2, SHOULDER_Z = 0.5, 0.4, 1.0  # two-link arm geometry (robots/two_link_arm.xml)
# iiwa home flange, by hand: J2 at z = 0.36; link2..4 (0.42 m) tilted by q2 = pi/4 about +y,
# J4..flange (0.4 + 0.126 = 0.526 m) tilted by q2 - q4 = 3 pi/4: x = 0.946 s, z = 0.36 - 0.106 s
# with s = sin(pi/4).
S45 = np.sqrt(0.5)
IIWA_HOME_FLANGE = np.array([0.946 * S45, 0.0, 0.36 - 0.106 * S45])
IIWA_REACH = 0.2045 + 0.2155 + 0.1845 + 0.2155 + 0.081 + 0.045  # J2 -> flange, [1.2]


def site_kinematics_closed_form(q, qd):
    """Tip position, Jacobian and Jdot qd of the planar two-link arm (x-z plane)."""
    q1, q12 = q[0], q[0] + q[1]
    w1, w12 = qd[0], qd[0] + qd[1]
    x = np.array(
        [L1 * np.cos(q1) + L2 * np.cos(q12), 0.0, SHOULDER_Z + L1 * np.sin(q1) + L2 * np.sin(q12)]
    )
    jac = np.array(
        [
            [-L1 * np.sin(q1) - L2 * np.sin(q12), -L2 * np.sin(q12)],
            [0.0, 0.0],
            [L1 * np.cos(q1) + L2 * np.cos(q12), L2 * np.cos(q12)],
        ]
    )
    bias = np.array(
        [
            -L1 * np.cos(q1) * w1**2 - L2 * np.cos(q12) * w12**2,
            0.0,
            -L1 * np.sin(q1) * w1**2 - L2 * np.sin(q12) * w12**2,
        ]
    )
    return x, jac, bias


def mujoco_site_acceleration(model, site, qpos, qvel, qacc):
    """Classical linear site acceleration from MuJoCo's cacc recursion: mj_objectAcceleration
    (world orientation) plus gravity (the recursion starts from the world at -gravity)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(model, data)
    data.qacc[:] = qacc
    mujoco.mj_rnePostConstraint(model, data)
    res = np.zeros(6)
    mujoco.mj_objectAcceleration(model, data, mujoco.mjtObj.mjOBJ_SITE, site, res, 0)
    return res[3:] + model.opt.gravity


def random_states(robot, rng, count, spread=0.5):
    """States near home (inside the joint limits), moderate velocities."""
    low, high = robot.joint_range[:, 0], robot.joint_range[:, 1]
    q = np.clip(
        robot.home + rng.uniform(-spread, spread, (count, robot.nq)),
        low + 0.1 * (high - low),
        high - 0.1 * (high - low),
    )
    return q, rng.uniform(-1.0, 1.0, (count, robot.nv))
