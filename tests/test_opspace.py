"""Operational-space kinematics (cfm_jax/sim/opspace.py): site lookup, host and JAX kinematics.

Oracles: closed-form planar kinematics of the two-link arm and the iiwa's home pose worked
by hand from the facts sheet; central finite differences of MuJoCo's site positions and of
the site velocity along an RK4 trajectory; MuJoCo's own velocity / acceleration recursions
(``mj_objectVelocity``, ``mj_rnePostConstraint`` + ``mj_objectAcceleration``, whose linear
part is the classical acceleration minus gravity).
"""

from __future__ import annotations

import copy
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from sites import (
    IIWA_HOME_FLANGE,
    mujoco_site_acceleration,
    random_states,
    site_kinematics_closed_form,
)

from cfm_jax.config import ConfigError
from cfm_jax.sim import opspace

# ---- site -------------------------------------------------------------------------------

TOY_XML = """
<mujoco>
  <worldbody>
    <site name="fixed"/>
    <body name="link">
      <joint name="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 1 0 0" size="0.05"/>
      <site name="flange" pos="1 0 0"/>
      <site name="ee" pos="1.2 0 0"/>
    </body>
  </worldbody>
  <actuator><motor joint="hinge" ctrlrange="-1 1"/></actuator>
</mujoco>
"""


def toy_robot():
    return types.SimpleNamespace(name="toy", mj_model=mujoco.MjModel.from_xml_string(TOY_XML))


def test_ee_site_default_is_the_iiwa_flange(iiwa):
    site = opspace.ee_site(iiwa)
    assert site == opspace.ee_site(iiwa, "flange")
    assert opspace.site_names(iiwa)[site] == "flange"


def test_ee_site_prefers_ee_over_flange_and_rejects_fixed_site():
    toy = toy_robot()
    assert opspace.site_names(toy)[opspace.ee_site(toy)] == "ee"
    with pytest.raises(ConfigError) as info:
        opspace.ee_site(toy, "fixed")
    message = str(info.value)
    assert message.startswith("task.site='fixed' is not allowed: it is fixed to the world")
    assert "('fixed', 'flange', 'ee')" in message


def test_ee_site_unknown_name_lists_sites(iiwa):
    with pytest.raises(ConfigError) as info:
        opspace.ee_site(iiwa, "hand")
    message = str(info.value)
    assert message.startswith("task.site='hand' is not allowed: robot 'iiwa14' has no such site")
    assert "('flange',)" in message


def test_ee_site_no_default_names_the_sites(arm):
    with pytest.raises(ConfigError) as info:
        opspace.ee_site(arm)
    message = str(info.value)
    assert message.startswith("task.site=None is not allowed for robot 'two_link_arm'"), message
    assert "'ee' or 'flange'" in message and "('tip',)" in message
    assert opspace.ee_site(arm, "tip") == 0


# ---- kinematics -------------------------------------------------------------------------


def test_host_kinematics_two_link_closed_form(arm):
    rng = np.random.default_rng(1)
    q, qd = random_states(arm, rng, 6, spread=1.5)
    kin = opspace.HostKinematics(arm, "tip")(q, qd)
    assert kin.position.shape == (6, 3) and kin.jacobian.shape == (6, 3, 2)
    for i in range(6):
        x, jac, bias = site_kinematics_closed_form(q[i], qd[i])
        # float64 trigonometry and MuJoCo's quaternion chain agree to a few ulps of 1 m.
        np.testing.assert_allclose(kin.position[i], x, atol=1e-13)
        np.testing.assert_allclose(kin.jacobian[i], jac, atol=1e-13)
        np.testing.assert_allclose(kin.velocity[i], jac @ qd[i], atol=1e-13)
        np.testing.assert_allclose(kin.bias_acceleration[i], bias, atol=1e-12)


def test_host_kinematics_iiwa_poses_by_hand(iiwa):
    kin = opspace.HostKinematics(iiwa)(np.stack([np.zeros(7), iiwa.home]), np.zeros((2, 7)))
    np.testing.assert_allclose(kin.position[0], [0.0, 0.0, 1.306], atol=1e-12)  # [1.2]
    # keyframe home is (0, 0.785398, 0, -1.5708, 0, 0, 0): pi/4 and -pi/2 to 6-7 digits,
    # so 1e-6 rad of angle error times < 1 m of lever.
    np.testing.assert_allclose(kin.position[1], IIWA_HOME_FLANGE, atol=2e-6)
    np.testing.assert_array_equal(kin.velocity, 0.0)
    np.testing.assert_array_equal(kin.bias_acceleration, 0.0)


def test_iiwa_jacobian_by_finite_differences_and_velocity_by_mujoco(iiwa):
    model, site = iiwa.mj_model, opspace.ee_site(iiwa)
    rng = np.random.default_rng(2)
    q, qd = random_states(iiwa, rng, 4)
    kin = opspace.HostKinematics(iiwa)(q, qd)
    data = mujoco.MjData(model)

    def position(qpos):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        return data.site_xpos[site].copy()

    h = 1e-6
    for i in range(4):
        fd = np.stack(
            [(position(q[i] + h * e) - position(q[i] - h * e)) / (2 * h) for e in np.eye(7)],
            axis=1,
        )
        # truncation h^2/6 |x'''| < 1e-12 (|x'''| ~ 1 m), rounding eps |x| / h ~ 2e-10
        np.testing.assert_allclose(kin.jacobian[i], fd, atol=2e-9)
        # MuJoCo's velocity recursion (cvel), linear part in world orientation
        data.qpos[:], data.qvel[:] = q[i], qd[i]
        mujoco.mj_forward(model, data)
        res = np.zeros(6)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, site, res, 0)
        np.testing.assert_allclose(kin.velocity[i], res[3:], atol=1e-13)


def test_iiwa_acceleration_by_finite_differences_along_a_trajectory(iiwa):
    # RK4 at h = 1 ms, constant torque (half the gravity compensation at home, so the arm
    # sags while moving): data.qacc at each state is the exact ODE acceleration, and the
    # central difference of the site velocity differs from xdd only by truncation.
    model = copy.deepcopy(iiwa.mj_model)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    h = model.opt.timestep = 1e-3
    site = opspace.ee_site(iiwa)
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = iiwa.home, np.linspace(-1.0, 1.0, 7)
    mujoco.mj_forward(model, data)
    data.ctrl[:] = 0.5 * data.qfrc_bias[iiwa.actuator_of_joint]
    states, velocities = [], []
    for _ in range(51):
        mujoco.mj_forward(model, data)
        states.append((data.qpos.copy(), data.qvel.copy(), data.qacc.copy()))
        velocity = np.zeros(6)  # MuJoCo's recursion, independent of our J
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
        velocities.append(velocity[3:])
        mujoco.mj_step(model, data)
    q, qd, qdd = (np.array(x) for x in zip(*states, strict=True))
    kin = opspace.HostKinematics(iiwa)(q, qd)
    xdd = opspace.task_acceleration(kin, qdd)
    assert xdd.dtype == np.float64
    velocities = np.array(velocities)
    fd = (velocities[2:] - velocities[:-2]) / (2 * h)
    # Truncation of the central difference: h^2/6 max|v'''|, v''' from third differences.
    jerk_rate = np.max(np.abs(np.diff(velocities, 3, axis=0))) / h**3
    bound = h**2 / 6 * jerk_rate
    assert 1e-6 < bound < 1e-5  # ~4.4e-6 for |v'''| ~ 27 m/s^4
    assert np.max(np.abs(xdd)) > 3.0  # a real acceleration, gravity sag included
    np.testing.assert_allclose(xdd[1:-1], fd, atol=1.2 * bound)
    # MuJoCo's acceleration recursion, with the spatial -> classical and gravity conversion
    for i in (0, 25, 50):
        oracle = mujoco_site_acceleration(model, site, q[i], qd[i], qdd[i])
        np.testing.assert_allclose(xdd[i], oracle, atol=1e-12)
        # without adding gravity back, mj_objectAcceleration is off by 9.81 m/s^2 in z
        assert abs((oracle - model.opt.gravity)[2] - xdd[i, 2]) > 9.8


def test_jax_kinematics_match_host_under_jit_and_vmap(iiwa):
    rng = np.random.default_rng(3)
    q, qd = random_states(iiwa, rng, 6)
    qdd = rng.uniform(-2.0, 2.0, (6, 7))
    q32, qd32, qdd32 = (np.asarray(a, np.float32) for a in (q, qd, qdd))
    host = opspace.HostKinematics(iiwa)(q32, qd32)

    @jax.jit
    def functions(q, qd, qdd):
        return (
            opspace.ee_position(iiwa, q),
            opspace.ee_velocity(iiwa, q, qd),
            opspace.ee_jacobian(iiwa, q),
            opspace.ee_acceleration(iiwa, q, qd, qdd),
        )

    x, xd, jac, xdd = jax.vmap(functions)(q32, qd32, qdd32)
    assert x.dtype == jnp.float32 and jac.shape == (6, 3, 7)
    # float32 rounding of outputs of size ~1 (values computed in float64 from the same
    # float32 inputs); the acceleration adds 7 float32 products of size ~2.
    np.testing.assert_allclose(x, host.position, atol=1e-7)
    np.testing.assert_allclose(xd, host.velocity, atol=1e-6)
    np.testing.assert_allclose(jac, host.jacobian, atol=1e-7)
    expected = np.einsum("nij,nj->ni", host.jacobian, qdd32) + host.bias_acceleration
    np.testing.assert_allclose(xdd, expected, atol=2e-6)


def test_ee_acceleration_differentiable_in_qacc_constant_in_state(iiwa):
    q = jnp.asarray(iiwa.home, jnp.float32)
    qd = jnp.linspace(-1.0, 1.0, 7, dtype=jnp.float32)
    qdd = jnp.ones(7, jnp.float32)
    loss = lambda q, qd, qdd: jnp.sum(opspace.ee_acceleration(iiwa, q, qd, qdd))  # noqa: E731
    grad_q, grad_qd, grad_qdd = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(q, qd, qdd)
    jac = opspace.HostKinematics(iiwa)(np.asarray(q), np.asarray(qd)).jacobian
    np.testing.assert_allclose(grad_qdd, jac.sum(axis=0), atol=1e-6)  # d(1^T J qdd)/dqdd
    np.testing.assert_array_equal(grad_q, 0.0)  # kinematics are constants of the state
    np.testing.assert_array_equal(grad_qd, 0.0)
