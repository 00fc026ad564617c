"""Baselines: the non-learned controllers that the learned controller is compared against.

Each task has a model-based *oracle* (an analytic controller with the true model) and a
*PD-only* feedback controller; the training loop rolls both out next to the learned
controller (``TrainResult.baselines``).

* Joint space (the ``inverse_dynamics`` task): MuJoCo's inverse dynamics at the current
  state, ``tau = M qdd* + c - passive`` (:func:`inverse_dynamics_oracle`), and the PD gains
  ``kp diag M(q_home)``, ``kd diag M(q_home)`` (:func:`joint_pd_gains`; the task applies
  them).
* Operational space (the ``opspace`` task): the analytic operational-space controller of
  Khatib (1987) (:class:`HostOpspaceOracle` with MuJoCo C on the host, float64;
  :func:`opspace_oracle` as a JAX function through a host callback, or computed by MJX,
  :func:`mjx_opspace_oracle`), and task-space PD ``J^T (K_p e + K_d ed)``
  (:func:`opspace_pd_gains`, :func:`opspace_pd_policy`).
* :func:`host_rollout`: the plain NumPy closed loop of an op-space policy with MuJoCo C
  (the reference the compiled rollout is tested against), and :func:`site_tracking_mse`.

Both oracles account for MuJoCo's implicit joint damping (:func:`implicit_damping`), so
that one Euler step realises the desired acceleration exactly. The legged tasks' oracle
replays recorded torques (:meth:`cfm_jax.tasks.LeggedTask.oracle_policy`).

Examples:
  >>> import jax, numpy as np
  >>> from cfm_jax import references, robots, rollout, tasks
  >>> arm = robots.load("two_link_arm")
  >>> ref = references.quintic(arm.home, arm.home + 0.1, duration=0.2, control_dt=0.01)
  >>> task = tasks.JointSpaceTask(arm, ref, kp=100.0, kd=20.0, control_dt=0.01)
  >>> out = rollout.run(task, inverse_dynamics_oracle(arm), key=jax.random.key(0))
  >>> bool(rollout.tracking_mse(out)[0] < 1e-5)  # the oracle tracks the reference
  True
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax import native, opspace, references, rollout
from cfm_jax._mjx import mjx
from cfm_jax.config import check_simulator

# Gains of the null-space posture term of the oracle (1/s^2 and 1/s): a critically damped
# joint-space PD towards the home pose, 5 rad/s, acting only in the task's null space.
NULL_KP = 25.0
NULL_KD = 10.0
# Relative singular-value cut-off of the pseudo-inverse of J M^-1 J^T (the two-link arm
# moves in a plane, so its 3 x 3 J M^-1 J^T has rank 2; the iiwa's has rank 3 away from
# singularities).
RCOND = 1e-9
# The same cut-off for the float32 pseudo-inverse of the MJX oracle: 10 x 3 x float32's eps
# (3.6e-6, jnp.linalg.pinv's default for a 3 x 3). RCOND is below float32's rounding: the
# eigensolver returns the planar arm's zero eigenvalue as noise of ~1e-8 (seen: -1.3e-8
# against 2.92, 4.5e-9 relative, at XLA's optimisation level 0), which RCOND keeps and
# inverts (a 7.6e7 entry in Lambda). Poses whose J M^-1 J^T has a true eigenvalue ratio
# between RCOND and RCOND_FLOAT32 (condition number 3e5 to 1e9, next to a singularity) are
# cut by the MJX oracle and kept by the host one.
RCOND_FLOAT32 = 10 * 3 * float(np.finfo(np.float32).eps)


# ---- joint space: inverse dynamics and PD gains -----------------------------------------


def inverse_dynamics_oracle(robot, simulator="native"):
    """MuJoCo's inverse dynamics at the current state: ``tau = M qdd* + c - passive``,
    with ``qdd* = step.desired`` (the joint-space task's desired acceleration).

    ``c`` is MuJoCo's bias force (Coriolis, centrifugal, gravity), ``passive`` the joint
    damping and spring forces. With the Euler integrator and implicit damping, the
    integrator's extra ``h D qdd`` term (``h`` the timestep, ``D`` the joint damping) is
    added so that one physics step realises ``qdd*`` exactly (up to torque limits); with
    several physics steps per control step the torque is held and tracking is approximate.

    ``simulator="native"`` computes it with MuJoCo C (``mj_fwdPosition``,
    ``mj_fwdVelocity``, ``mj_mulM``) through ``jax.pure_callback``; ``"mjx"`` with the
    corresponding MJX functions.

    Args:
      robot: a :class:`cfm_jax.robots.Robot` with a fixed base.
      simulator: ``"native"`` or ``"mjx"``.

    Returns:
      ``policy(step, key) -> tau (nv,)``.

    Examples:
      >>> import jax, numpy as np
      >>> from cfm_jax import references, robots, rollout, tasks
      >>> robot = robots.load("two_link_arm")
      >>> ref = references.quintic(robot.home, robot.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(robot, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> out = rollout.run(task, inverse_dynamics_oracle(robot), jax.random.key(0))
      >>> float(rollout.tracking_mse(out)[0]) < 1e-5
      True
    """
    mj = robot.mj_model
    damping = implicit_damping(mj)

    if simulator == "native":
        inverse = _native_inverse(mj, damping)

        def policy(step, key):
            del key
            shape = jax.ShapeDtypeStruct(jnp.shape(step.desired), jnp.float32)
            return jax.pure_callback(
                inverse, shape, step.qpos, step.qvel, step.desired, vmap_method="broadcast_all"
            )

        return policy

    model = robot.mjx_model
    blank = mjx.make_data(model)
    damping = jnp.asarray(damping, jnp.float32)

    def policy(step, key):
        del key
        data = blank.replace(qpos=step.qpos, qvel=step.qvel)
        data = mjx.fwd_position(model, data)
        data = mjx.fwd_velocity(model, data)
        inertial = mjx.mul_m(model, data, step.desired) + damping * step.desired
        return inertial + data.qfrc_bias - data.qfrc_passive

    return policy


def implicit_damping(mj_model) -> np.ndarray:
    """``h D`` per dof when MuJoCo's Euler integrator treats joint damping implicitly
    (``h`` the timestep, ``D`` the damping), else zeros: the extra inertia-like term that
    one Euler step adds to ``M qdd``.

    Args:
      mj_model: a ``mujoco.MjModel``.

    Returns:
      ``(nv,)``: ``timestep * dof_damping`` with the Euler integrator and implicit damping
      enabled, else zeros.

    Examples:
      >>> from cfm_jax import robots
      >>> implicit_damping(robots.load("two_link_arm").mj_model).tolist()
      [0.0002, 0.0002]
    """
    eulerdamp = int(mj_model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_EULER) and not int(
        mj_model.opt.disableflags
    ) & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    return mj_model.dof_damping * mj_model.opt.timestep if eulerdamp else np.zeros(mj_model.nv)


def _native_inverse(mj_model, implicit_damping):
    """Host function ``(qpos, qvel, qacc) -> M qacc + h D qacc + bias - passive`` (float32),
    any leading batch shape."""
    data = mujoco.MjData(mj_model)
    nq, nv = mj_model.nq, mj_model.nv

    def inverse(qpos, qvel, qacc):
        shape = np.shape(qacc)
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, nv)
        qacc = np.asarray(qacc, np.float64).reshape(-1, nv)
        out = np.empty_like(qacc)
        inertial = np.empty(nv)
        for i in range(qacc.shape[0]):
            data.qpos[:], data.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_fwdPosition(mj_model, data)
            mujoco.mj_fwdVelocity(mj_model, data)
            mujoco.mj_mulM(mj_model, data, inertial, qacc[i])
            out[i] = inertial + implicit_damping * qacc[i] + data.qfrc_bias - data.qfrc_passive
        return out.astype(np.float32).reshape(shape)

    return inverse


def joint_pd_gains(robot, kp: float, kd: float, home) -> tuple[np.ndarray, np.ndarray]:
    """Torque PD gains equivalent to the acceleration gains ``kp, kd`` at the home pose.

    ``K_p = kp * diag(M(q_home))`` and ``K_d = kd * diag(M(q_home))``: the gains that give each
    joint, taken alone at the home pose, the same closed-loop stiffness and damping as the
    PD correction of the desired acceleration. No gravity compensation, no feed-forward.
    The joint-space PD baseline, ``K_p (q_ref - q) + K_d (qd_ref - qd)``, is the task's
    feedback (:meth:`cfm_jax.tasks.JointSpaceTask.feedback`).

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      kp: acceleration stiffness (1/s^2).
      kd: acceleration damping (1/s).
      home: ``(nq,)`` the pose at which the mass matrix is taken.

    Returns:
      ``(K_p, K_d)``, each ``(nv,)``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> k_p, k_d = joint_pd_gains(arm, 100.0, 20.0, arm.home)
      >>> bool(np.allclose(k_p / k_d, 5.0))
      True
    """
    inertia = robot.mass_matrix_diagonal(home)
    return kp * inertia, kd * inertia


def babbling_joint_gains(robot, kp: float, kd: float, poses) -> tuple[np.ndarray, np.ndarray]:
    """Torque PD gains of the babbling's joint feedback: ``K = (kp, kd) * I_j``, with
    ``I_j`` the joint's smallest effective inertia over ``poses``
    (:meth:`cfm_jax.robots.Robot.lightest_inertia`),
    for example every pose the babbling may visit.

    The PD-only baseline's gains, ``diag M(q_home)`` (:func:`joint_pd_gains`), fit the home
    pose; the babbling reaches far from it, and on an arm with light links and no armature
    the coupled inertia there makes those gains unstable at the control period (the
    published KUKA iiwa 14: ``kd dt lambda_max(M(q)^-1 K_d)`` up to 20 over its range, 2
    being the limit of a held torque), so that the babbling data is a noise-driven
    oscillation of tens of rad/s. With ``K_d = kd I``, ``I_jj <= 1 / (M(q)^-1)_jj`` at
    every pose of the sample, so the matrix ``K_d^(1/2) M(q)^-1 K_d^(1/2) / kd`` has a
    diagonal of at most 1 wherever the babbling goes: each joint alone is damped at the
    rate ``kd`` or less, and the loop's number ``kd dt lambda_max(M^-1 K_d)`` is at most
    ``kd dt nv`` (on the development set of published arms at most ``2.6 kd dt``). On an
    arm whose inertia changes little with the pose (armature) the gains are close to the
    baseline's.

    Args:
      robot: a :class:`cfm_jax.robots.Robot`.
      kp: acceleration stiffness (1/s^2).
      kd: acceleration damping (1/s).
      poses: ``(n, nq)`` the poses the babbling may visit.

    Returns:
      ``(K_p, K_d)``, each ``(action_dim,)``.

    Examples:
      >>> from cfm_jax import robots
      >>> arm = robots.load("two_link_arm")
      >>> k_p, k_d = babbling_joint_gains(arm, 100.0, 20.0, arm.home[None])
      >>> bool(np.all(k_d <= joint_pd_gains(arm, 100.0, 20.0, arm.home)[1]))
      True
    """
    inertia = robot.lightest_inertia(poses)
    return kp * inertia, kd * inertia


# ---- operational space: the Khatib oracle -----------------------------------------------


class HostOpspaceOracle:
    """Analytic operational-space controller (Khatib 1987) with MuJoCo C, float64.

    ``HostOpspaceOracle(robot, site, home, null_kp, null_kd)(qpos (..., nq), qvel (..., nv),
    xdd_desired (..., 3)) -> tau (..., nv)``:

        tau = J^T Lambda (xdd* - Jdot qd) + N^T tau_null + bias - passive
        Lambda = (J Mt^-1 J^T)^+,   Jbar = Mt^-1 J^T Lambda,   N^T = I - J^T Jbar^T
        tau_null = Mt (null_kp (q_home - q) - null_kd qd),     Mt = M + h D

    ``bias`` is MuJoCo's ``qfrc_bias`` (Coriolis, centrifugal, gravity), ``passive``
    ``qfrc_passive`` (joint damping and springs), ``M`` the joint-space inertia (with
    armature), ``h D`` :func:`implicit_damping`. ``^+`` is the pseudo-inverse (relative
    cut-off :data:`RCOND`), which is the inverse when ``J`` has full row rank.

    Derivation: one Euler step realises ``qdd = Mt^-1 (tau + passive - bias)``
    (:func:`implicit_damping`), so ``J qdd = J Mt^-1 J^T Lambda (xdd* - Jdot qd) +
    J Mt^-1 N^T tau_null``. The first term is ``xdd* - Jdot qd`` (``J Mt^-1 J^T Lambda = I``
    on the range of ``J``); the second is zero because ``J Mt^-1 N^T = J Mt^-1 -
    (J Mt^-1 J^T) Lambda J Mt^-1 = 0`` (dynamically consistent projector). Hence the site's
    acceleration ``J qdd + Jdot qd = xdd*`` exactly over one physics step from any state
    (up to torque and joint limits), whatever ``tau_null``. With the torque held over
    several physics steps, tracking is approximate. Using ``M`` instead of ``Mt`` leaves an
    error of order ``h D / M`` (~1e-3 on the iiwa).

    The null-space term pulls the redundant joints towards ``home`` (default
    ``robot.home``) with the joint-space acceleration gains ``null_kp`` (1/s^2, default
    25) and ``null_kd`` (1/s, default 10, critical damping at 5 rad/s), scaled by ``Mt``.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> tau = HostOpspaceOracle(iiwa)(iiwa.home, np.zeros(7), np.zeros(3))  # holds the pose
      >>> tau.shape
      (7,)
    """

    def __init__(
        self,
        robot,
        site: int | str | None = None,
        home=None,
        null_kp: float = NULL_KP,
        null_kd: float = NULL_KD,
    ):
        self.kinematics = opspace.HostKinematics(robot, site)
        self.model = robot.mj_model
        self.data = self.kinematics.data
        self.home = np.asarray(robot.home if home is None else home, np.float64)
        self.null_kp, self.null_kd = float(null_kp), float(null_kd)
        self.implicit_damping = implicit_damping(self.model)

    def task_inertia(self, qpos) -> np.ndarray:
        """``Lambda(q) = (J Mt^-1 J^T)^+``, ``(3, 3)``, at one pose (kg)."""
        self.data.qpos[:], self.data.qvel[:] = qpos, 0.0
        mujoco.mj_fwdPosition(self.model, self.data)
        _, jac, _ = self.kinematics._jacobians()
        return self._task_inertia(jac, self._inertia())[0]

    def _inertia(self) -> np.ndarray:
        nv = self.model.nv
        full = np.zeros((nv, nv))
        mujoco.mj_fullM(self.model, self.data, full)
        return full + np.diag(self.implicit_damping)

    @staticmethod
    def _task_inertia(jac, inertia):
        inverse_jt = np.linalg.solve(inertia, jac.T)  # Mt^-1 J^T, (nv, 3)
        return np.linalg.pinv(jac @ inverse_jt, rcond=RCOND, hermitian=True), inverse_jt

    def __call__(self, qpos, qvel, xdd_desired):
        nq, nv = self.model.nq, self.model.nv
        batch_shape = np.shape(xdd_desired)[:-1]
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, nv)
        desired = np.asarray(xdd_desired, np.float64).reshape(-1, 3)
        tau = np.empty((desired.shape[0], nv))
        for i in range(desired.shape[0]):
            self.data.qpos[:], self.data.qvel[:] = qpos[i], qvel[i]
            mujoco.mj_fwdPosition(self.model, self.data)  # kinematics, com, M
            mujoco.mj_fwdVelocity(self.model, self.data)  # cvel, Jdot terms, bias, passive
            _, jac, jac_dot = self.kinematics._jacobians()
            inertia = self._inertia()
            task_inertia, inverse_jt = self._task_inertia(jac, inertia)
            force = task_inertia @ (desired[i] - jac_dot @ qvel[i])
            null_accel = self.null_kp * (self.home - qpos[i]) - self.null_kd * qvel[i]
            tau_null = inertia @ null_accel
            # N^T tau_null = tau_null - J^T Jbar^T tau_null, Jbar^T = Lambda J Mt^-1.
            projected = tau_null - jac.T @ (task_inertia @ (inverse_jt.T @ tau_null))
            tau[i] = jac.T @ force + projected + self.data.qfrc_bias - self.data.qfrc_passive
        return tau.reshape(batch_shape + (nv,))


def opspace_oracle(
    robot,
    site: int | str | None = None,
    home=None,
    null_kp: float = NULL_KP,
    null_kd: float = NULL_KD,
    simulator: str = "native",
):
    """The operational-space oracle as a JAX function
    ``torque(qpos (..., nq), qvel (..., nv), xdd_desired (..., 3)) -> tau (..., nv)``
    (float32). ``simulator="native"``: one ``jax.pure_callback`` into
    :class:`HostOpspaceOracle` (one host call per batch under ``vmap``); ``"mjx"``: the same
    controller computed by MJX in JAX (:func:`mjx_opspace_oracle`). Torques are not
    clipped.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).
      simulator: ``"native"`` or ``"mjx"``.

    Returns:
      The function ``torque``; one :class:`HostOpspaceOracle` per (model, site, home,
      gains) is built and reused.

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = opspace_oracle(iiwa)
      >>> jax.jit(torque)(iiwa.home, np.zeros(7), np.zeros(3)).shape
      (7,)
    """
    if simulator == "mjx":
        return mjx_opspace_oracle(robot, site, home, null_kp, null_kd)
    check_simulator(simulator)
    home = tuple(np.asarray(robot.home if home is None else home, np.float64).tolist())
    host = opspace.host_function(
        HostOpspaceOracle,
        robot,
        opspace.site_id(robot, site),
        home,
        float(null_kp),
        float(null_kd),
    )

    def torque(qpos, qvel, xdd_desired):
        args = [jax.lax.stop_gradient(jnp.asarray(a, jnp.float32)) for a in (qpos, qvel)]
        desired = jax.lax.stop_gradient(jnp.asarray(xdd_desired, jnp.float32))
        shape = jax.ShapeDtypeStruct(desired.shape[:-1] + (robot.nv,), jnp.float32)
        return jax.pure_callback(host, shape, *args, desired, vmap_method="broadcast_all")

    return torque


def mjx_opspace_oracle(
    robot,
    site: int | str | None = None,
    home=None,
    null_kp: float = NULL_KP,
    null_kd: float = NULL_KD,
):
    """:class:`HostOpspaceOracle`'s controller computed by MJX, in JAX (no host callback), as
    ``torque(qpos (..., nq), qvel (..., nv), xdd_desired (..., 3)) -> tau (..., nv)``.

    The same formula: ``J``, ``Jdot qd`` from :func:`cfm_jax.opspace.mjx_kinematics`, ``M``
    from ``mjx.full_m``, ``qfrc_bias`` and ``qfrc_passive`` from ``mjx.fwd_position`` and
    ``mjx.fwd_velocity``, ``Lambda`` with ``jnp.linalg.pinv`` at the relative cut-off
    :data:`RCOND_FLOAT32` (float32's rounding; :data:`RCOND` for the float64 host); float32
    instead of float64.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot` with hinge and slide joints.
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Returns:
      The function ``torque`` (float32, jit/vmap-able).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = mjx_opspace_oracle(iiwa)
      >>> # not run: compiling MJX's op-space oracle of the iiwa takes 25-40 s on a CPU
      >>> tau = jax.jit(torque)(iiwa.home, np.zeros(7), np.zeros(3))  # doctest: +SKIP
      >>> tau.shape  # doctest: +SKIP
      (7,)
    """
    model, sid, bid, blank = opspace.mjx_site(robot, site)
    del sid, bid
    home = jnp.asarray(robot.home if home is None else home, jnp.float32)
    damping = jnp.asarray(implicit_damping(robot.mj_model), jnp.float32)
    null_kp, null_kd = float(null_kp), float(null_kd)

    def one(q, qd, desired):
        kin = opspace.mjx_kinematics(robot, q, qd, site)
        data = mjx.fwd_velocity(model, mjx.fwd_position(model, blank.replace(qpos=q, qvel=qd)))
        inertia = mjx.full_m(model, data) + jnp.diag(damping)
        jac = kin.jacobian
        inverse_jt = jnp.linalg.solve(inertia, jac.T)  # Mt^-1 J^T, (nv, 3)
        task_inertia = jnp.linalg.pinv(jac @ inverse_jt, rtol=RCOND_FLOAT32, hermitian=True)
        force = task_inertia @ (desired - kin.bias_acceleration)
        tau_null = inertia @ (null_kp * (home - q) - null_kd * qd)
        projected = tau_null - jac.T @ (task_inertia @ (inverse_jt.T @ tau_null))
        return jac.T @ force + projected + data.qfrc_bias - data.qfrc_passive

    def torque(qpos, qvel, xdd_desired):
        args = [jax.lax.stop_gradient(jnp.asarray(a, jnp.float32)) for a in (qpos, qvel)]
        desired = jax.lax.stop_gradient(jnp.asarray(xdd_desired, jnp.float32))
        return opspace.over_batch(one, *args, desired)

    return torque


# ---- operational space: PD-only ---------------------------------------------------------


def opspace_pd_gains(
    robot, kp: float, kd: float, site: int | str | None = None, home=None
) -> tuple[np.ndarray, np.ndarray]:
    """Task-space torque PD gains equivalent to the acceleration gains ``kp, kd`` at home.

    ``K_p = kp * Lambda(q_home)``, ``K_d = kd * Lambda(q_home)``, ``(3, 3)`` each, with the
    task-space inertia ``Lambda = (J Mt^-1 J^T)^+`` of :class:`HostOpspaceOracle`: a force
    ``F = K_p e + K_d ed`` on the end effector alone at the home pose gives it the
    acceleration ``kp e + kd ed`` (the PD correction of the desired acceleration). The
    analogue of :func:`joint_pd_gains` (which uses ``diag M(q_home)``).

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      kp: proportional acceleration gain (1/s^2).
      kd: derivative acceleration gain (1/s).
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      home: ``(nq,)`` pose where ``Lambda`` is taken, or None for ``robot.home``.

    Returns:
      ``(K_p, K_d)``, ``(3, 3)`` NumPy arrays each (N/m and N s/m).

    Examples:
      >>> from cfm_jax import robots
      >>> gain_p, gain_d = opspace_pd_gains(robots.load("two_link_arm"), 100.0, 20.0, "tip")
      >>> gain_p.shape, bool(np.allclose(gain_p / 100.0, gain_d / 20.0))
      ((3, 3), True)
    """
    home = robot.home if home is None else np.asarray(home, np.float64)
    task_inertia = HostOpspaceOracle(robot, site).task_inertia(home)
    return kp * task_inertia, kd * task_inertia


def opspace_pd_policy(
    robot, gain_p, gain_d, site: int | str | None = None, simulator: str = "native"
):
    """PD-only feedback in task space as a JAX function
    ``torque(qpos, qvel, ref_x (..., 3), ref_xd (..., 3)) -> tau (..., nv)``:

        tau = J(q)^T (K_p (x_ref - x) + K_d (xd_ref - xd))

    with ``x, xd, J`` from :func:`cfm_jax.opspace.kinematics` (of ``simulator``). No gravity
    compensation, no feed-forward, no null-space term (the joint damping of the model is the
    only null-space damping).

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      gain_p: ``K_p``, ``(3, 3)`` (for example from :func:`opspace_pd_gains`).
      gain_d: ``K_d``, ``(3, 3)``.
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      simulator: ``"native"`` (site kinematics from MuJoCo C on the host) or ``"mjx"``.

    Returns:
      The function ``torque`` (float32, jit/vmap-able).

    Examples:
      >>> from cfm_jax import robots
      >>> iiwa = robots.load("iiwa14")
      >>> torque = opspace_pd_policy(iiwa, *opspace_pd_gains(iiwa, 100.0, 20.0))
      >>> x = opspace.ee_position(iiwa, iiwa.home)
      >>> bool(np.abs(np.asarray(torque(iiwa.home, np.zeros(7), x, np.zeros(3)))).max() < 1e-3)
      True
    """
    gain_p = jnp.asarray(gain_p, jnp.float32)
    gain_d = jnp.asarray(gain_d, jnp.float32)

    def torque(qpos, qvel, ref_x, ref_xd):
        kin = opspace.kinematics(robot, qpos, qvel, site, simulator)
        force = jnp.einsum("ij,...j->...i", gain_p, ref_x - kin.position) + jnp.einsum(
            "ij,...j->...i", gain_d, ref_xd - kin.velocity
        )
        return jnp.einsum("...ij,...i->...j", kin.jacobian, force)

    return torque


# ---- operational space: metrics and the NumPy closed loop -------------------------------


def site_tracking_mse(positions, reference_x):
    """End-effector position tracking MSE per target, ``(targets,)`` (m^2).

    Args:
      positions: ``(targets, steps, 3)`` site positions after each control step,
        ``x_{t+1}``.
      reference_x: ``(targets, steps + 1, 3)`` (``CartesianReference.x``) or already
        aligned ``(targets, steps, 3)``.

    Returns:
      ``mean over t and axes of (x_{t+1} - x_ref(t+1))^2``, ``(targets,)``.

    Examples:
      >>> positions = np.zeros((2, 3, 3))  # 2 targets, 3 steps
      >>> reference_x = np.ones((2, 4, 3))  # the first reference point is dropped
      >>> site_tracking_mse(positions, reference_x).tolist()
      [1.0, 1.0]
    """
    positions = jnp.asarray(positions)
    reference_x = jnp.asarray(reference_x)
    if reference_x.shape[-2] == positions.shape[-2] + 1:
        reference_x = reference_x[..., 1:, :]
    return jnp.mean(jnp.square(positions - reference_x), axis=(-2, -1))


class HostRollout(NamedTuple):
    """Result of :func:`host_rollout`, leading axes ``(targets, steps)``.

    Attributes:
      qpos: joint positions after each control step, ``(targets, steps, nq)``.
      qvel: joint velocities after each control step, ``(targets, steps, nv)``.
      position: site position after each control step, ``(targets, steps, 3)``.
      desired: ``xdd*_t`` at each control step, ``(targets, steps, 3)``.
      tau: applied (clipped) torque, ``(targets, steps, nv)``.

    Examples:
      >>> from cfm_jax import references, robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = references.cartesian_reaching(
      ...     arm, "tip", [[0.5, 0.0, 1.4]], duration=0.1, control_dt=0.01)
      >>> oracle = HostOpspaceOracle(arm, "tip")
      >>> out = host_rollout(arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd),
      ...                    kp=100.0, kd=20.0, control_dt=0.01, site="tip")
      >>> out.qpos.shape, out.position.shape, out.tau.shape
      ((1, 10, 2), (1, 10, 3), (1, 10, 2))
    """

    qpos: np.ndarray
    qvel: np.ndarray
    position: np.ndarray
    desired: np.ndarray
    tau: np.ndarray


def host_rollout(
    robot,
    reference: references.CartesianReference,
    policy,
    kp: float,
    kd: float,
    control_dt: float,
    site: int | str | None = None,
    home=None,
) -> HostRollout:
    """Closed loop of a host policy on every target, MuJoCo C on the host (NumPy).

    The reference implementation of the operational-space rollout, with the conventions of
    :func:`cfm_jax.rollout.run` and its ``native`` simulator (:class:`cfm_jax.native.Stepper`,
    state stored as float32 between control steps): start at rest at ``home``; at step ``t``
    ``xdd*_t`` from :func:`cfm_jax.references.desired_acceleration`, ``tau = clip(policy(qpos,
    qvel, xdd*_t, x_ref(t), xd_ref(t)), limits)`` held for ``control_dt / timestep`` physics
    steps.

    Args:
      robot: a fixed-base :class:`cfm_jax.robots.Robot`.
      reference: a :class:`cfm_jax.references.CartesianReference` (NumPy),
        ``(targets, steps + 1, 3)``.
      policy: ``policy(qpos (B, nq), qvel (B, nv), desired (B, 3), ref_x (B, 3),
        ref_xd (B, 3)) -> tau (B, nv)``, NumPy; e.g. ``lambda q, qd, xdd, *_:
        HostOpspaceOracle(robot)(q, qd, xdd)``.
      kp: proportional gain (1/s^2) of the desired acceleration.
      kd: derivative gain (1/s) of the desired acceleration.
      control_dt: control period (s), a multiple of the robot's timestep.
      site: the site's id or name, or None for :func:`cfm_jax.opspace.ee_site`'s default.
      home: ``(nq,)`` start pose (at rest), or None for ``robot.home``.

    Returns:
      A :class:`HostRollout`, ``(targets, steps, ...)``.

    Examples:
      >>> from cfm_jax import references, robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = references.cartesian_reaching(
      ...     arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> oracle = HostOpspaceOracle(arm, "tip")
      >>> out = host_rollout(arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd),
      ...                    kp=100.0, kd=20.0, control_dt=0.01, site="tip")
      >>> bool(site_tracking_mse(out.position, ref.x)[0] < 1e-5)  # the oracle tracks the line
      True
    """
    n_sub = rollout.substeps(robot, control_dt)
    stepper = native.Stepper(robot.mj_model, n_sub)
    kin = opspace.HostKinematics(robot, site)
    home = robot.home if home is None else np.asarray(home, np.float64)
    k, steps = reference.x.shape[0], reference.steps
    qpos = np.tile(np.asarray(home, np.float32), (k, 1))
    qvel = np.zeros((k, robot.nv), np.float32)
    out = {name: [] for name in HostRollout._fields}
    ctrl = np.zeros((k, robot.mj_model.nu))
    for t in range(steps):
        state = kin(qpos, qvel)
        desired = references.desired_acceleration(
            reference.x[:, t],
            reference.xd[:, t],
            reference.xdd[:, t],
            state.position,
            state.velocity,
            kp,
            kd,
        )
        desired = np.asarray(desired)
        tau = policy(qpos, qvel, desired, reference.x[:, t], reference.xd[:, t])
        tau = np.clip(tau, -robot.torque_limit, robot.torque_limit)
        ctrl[:, robot.actuator_of_joint] = tau / robot.gear
        qpos, qvel, _ = stepper(qpos, qvel, ctrl)
        for name, value in zip(
            HostRollout._fields,
            (qpos, qvel, kin(qpos, qvel).position, desired, tau),
            strict=True,
        ):
            out[name].append(np.asarray(value))
    return HostRollout(*(np.stack(out[name], axis=1) for name in HostRollout._fields))
