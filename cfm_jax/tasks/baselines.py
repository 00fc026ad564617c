"""Baselines: the non-learned controllers the learned one is compared against.

Each task has a model-based *oracle* and a *PD-only* controller (``TrainResult.baselines``):
in joint space :func:`inverse_dynamics_oracle` and :func:`joint_pd_gains`; in operational
space the Khatib controller (:class:`HostOpspaceOracle`, :func:`opspace_oracle`,
:func:`mjx_opspace_oracle`; docs/opspace.md) and :func:`opspace_pd_policy`.
:func:`host_rollout` is the NumPy closed loop the compiled op-space rollout is tested against.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from cfm_jax._mjx import mjx
from cfm_jax.config import check_simulator
from cfm_jax.sim import native, opspace, rollout
from cfm_jax.sim.host import host_call
from cfm_jax.tasks import references

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
    """The joint-space oracle ``policy(step, key) -> tau (nv,)``: MuJoCo's inverse dynamics.

    ``tau = M qdd* + h D qdd* + bias - passive`` with ``qdd* = step.desired``; the
    :func:`implicit_damping` term ``h D qdd*`` makes one Euler step realise ``qdd*`` exactly.
    Where constraint forces act at every step (:func:`constraints_act`: dry friction,
    ``frictionloss``, or equality constraints), that closed form leaves them out and the
    oracle is no lower bound (issue 64: on arms with dry friction it tracked no better than
    PD-only); there it is MuJoCo's own ``mj_inverse`` in discrete time
    (``mjENBL_INVDISCRETE``): the force that makes one step of the model's integrator, its
    constraint forces included, realise ``qdd*``. (Elsewhere the two agree up to rounding,
    and the closed form keeps the recorded numbers bit for bit.)

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot` with a fixed base.
      simulator: ``"native"`` (MuJoCo C through :func:`cfm_jax.sim.host.host_call`) or ``"mjx"``.

    Examples:
      >>> from cfm_jax.tasks import references
      >>> from cfm_jax.sim import robots, rollout
      >>> from cfm_jax import tasks
      >>> arm = robots.load("two_link_arm")
      >>> ref = references.quintic(arm.home, arm.home + 0.1, duration=0.2, control_dt=0.01)
      >>> task = tasks.JointSpaceTask(arm, ref, kp=100.0, kd=20.0, control_dt=0.01)
      >>> out = rollout.run(task, inverse_dynamics_oracle(arm), jax.random.key(0))
      >>> float(rollout.tracking_mse(out)[0]) < 1e-5
      True
    """
    mj = robot.mj_model
    damping = implicit_damping(mj)
    if constraints_act(mj):
        return _constrained_oracle(mj, simulator)

    if simulator == "native":
        return _host_policy(_native_inverse(mj, damping), f"inverse-{native.model_digest(mj)}")

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


# Newton steps of :func:`over_the_period` and the size of its finite-difference probes (a
# fraction of each joint's torque limit: the response is close to affine in the torque, so
# a probe well above float32's rounding of the velocities costs nothing in accuracy).
PERIOD_NEWTON_STEPS = 2
PERIOD_PROBE = 1e-2


def over_the_period(policy, response, limit, steps: int = PERIOD_NEWTON_STEPS):
    """``policy`` made exact over the control period: Newton's method on the simulator.

    The torque is held for the period's physics steps, and inverting the first one misses the
    others (a damped joint's velocity relaxes within the period; issue 64). From ``policy``'s
    torque each step solves ``response(tau) = s*`` (Jacobian by finite differences, one probe
    per joint towards zero torque, one simulator call) and keeps the torque of the smallest
    residual, clipped to ``limit``. Rows whose ``s*`` is not finite (a rollout that weights
    the oracle 0, :func:`cfm_jax.sim.rollout.mixed_policy`) are not refined: no step runs.

    Args:
      policy: ``policy(step, key) -> tau (k,)``, the one-step oracle (the start).
      response: ``response(step, tau) -> (k,)``, what the task observes after the period
        with ``tau`` held (the simulator); ``s*`` is ``step.desired``.
      limit: ``(k,)`` torque limit.
      steps: Newton steps (``steps + 1`` simulator calls of ``k + 1`` rows each).

    Examples:
      >>> arm = jnp.array([[2.0, 0.0], [0.0, 0.5]])  # an affine response, A tau + b
      >>> def response(step, tau):
      ...     return arm @ tau + 1.0
      >>> start = lambda step, key: jnp.zeros(2)
      >>> class Step(NamedTuple):
      ...     desired: jax.Array
      >>> exact = over_the_period(start, response, jnp.array([10.0, 10.0]))
      >>> np.allclose(exact(Step(jnp.array([3.0, 2.0])), None), [1.0, 2.0])
      True
    """
    limit = jnp.asarray(limit, jnp.float32)
    probe = PERIOD_PROBE * limit

    def refined(step, key):
        tau = jnp.clip(policy(step, key), -limit, limit)
        active = jnp.all(jnp.isfinite(step.desired))

        def newton(carry):
            i, tau, best, best_error = carry
            # Probes towards zero torque stay within the limits.
            size = jnp.where(tau > 0, -probe, probe)
            rows = jnp.concatenate([tau[None], tau + jnp.diag(size)])
            residual = jax.vmap(lambda t: response(step, t) - step.desired)(rows)
            error = jnp.max(jnp.abs(residual[0]))
            better = error < best_error
            best = jnp.where(better, tau, best)
            jacobian = ((residual[1:] - residual[0]) / size[:, None]).T
            step_ = jnp.linalg.lstsq(jacobian, residual[0])[0]
            tau = jnp.clip(tau - step_, -limit, limit)
            return i + 1, tau, best, jnp.where(better, error, best_error)

        start = (jnp.int32(0), tau, tau, jnp.asarray(jnp.inf, tau.dtype))
        _, _, best, _ = jax.lax.while_loop(
            lambda carry: active & (carry[0] <= steps), newton, start
        )
        return best

    return refined


def constraints_act(mj_model) -> bool:
    """Whether constraint forces act on the model at every step, not only at a limit or a
    contact: dry friction of a joint or tendon (``frictionloss``) or an equality constraint.

    Args:
      mj_model: a ``mujoco.MjModel``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> constraints_act(robots.load("two_link_arm").mj_model)
      False
    """
    return bool(
        np.any(mj_model.dof_frictionloss > 0)
        or np.any(mj_model.tendon_frictionloss > 0)
        or mj_model.neq > 0
    )


def _discrete_inverse_model(mj_model, integrators=("EULER", "IMPLICITFAST", "IMPLICIT")):
    """A copy of ``mj_model`` whose ``mj_inverse`` inverts one step of its integrator, where
    the integrator is one of ``integrators`` (MuJoCo has no discrete inverse of RK4: there
    the continuous one)."""
    model = copy.copy(mj_model)
    kinds = [int(getattr(mujoco.mjtIntegrator, f"mjINT_{name}")) for name in integrators]
    if int(model.opt.integrator) in kinds:
        model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_INVDISCRETE)
    return model


def _constrained_oracle(mj_model, simulator: str):
    """:func:`inverse_dynamics_oracle` through ``mj_inverse`` (discrete time), its
    constraint forces included: MuJoCo C on the host, or ``mjx.inverse``."""
    if simulator == "native":
        model = _discrete_inverse_model(mj_model)
        data = mujoco.MjData(model)

        def row(qpos, qvel, qacc):
            data.qpos[:], data.qvel[:], data.qacc[:] = qpos, qvel, qacc
            mujoco.mj_inverse(model, data)
            return data.qfrc_inverse

        return _host_policy(
            _rows(row, model.nq, model.nv), f"mj_inverse-{native.model_digest(mj_model)}"
        )

    # MJX's discrete inverse of the Euler step tests the damping with a Python `if` on an
    # array (it fails under jit): that step's conversion is done here, as MuJoCo does it,
    # qacc = M^-1 (M + h D) qacc*, and MJX inverts the continuous dynamics at qacc.
    damping = np.asarray(implicit_damping(mj_model), np.float32)
    euler = bool(np.any(damping != 0))
    device_model = mjx.put_model(
        _discrete_inverse_model(mj_model, () if euler else ("IMPLICITFAST",))
    )
    blank = mjx.make_data(device_model)

    def policy(step, key):
        del key
        data = blank.replace(qpos=step.qpos, qvel=step.qvel)
        qacc = step.desired
        if euler:
            data = mjx.fwd_position(device_model, data)
            qfrc = mjx.mul_m(device_model, data, qacc) + damping * qacc
            qacc = jnp.linalg.solve(mjx.full_m(device_model, data), qfrc)
        return mjx.inverse(device_model, data.replace(qacc=qacc)).qfrc_inverse

    return policy


def implicit_damping(mj_model) -> np.ndarray:
    """``h D`` per dof (timestep times damping) if the Euler integrator treats damping
    implicitly, else zeros: the term one Euler step adds to ``M qdd``.

    Args:
      mj_model: a ``mujoco.MjModel``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> implicit_damping(robots.load("two_link_arm").mj_model).tolist()
      [0.0002, 0.0002]
    """
    eulerdamp = int(mj_model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_EULER) and not int(
        mj_model.opt.disableflags
    ) & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    return mj_model.dof_damping * mj_model.opt.timestep if eulerdamp else np.zeros(mj_model.nv)


def _native_inverse(mj_model, implicit_damping):
    """Host ``(qpos, qvel, qacc) -> M qacc + h D qacc + bias - passive``, float32, batched."""
    data = mujoco.MjData(mj_model)
    inertial = np.empty(mj_model.nv)

    def row(qpos, qvel, qacc):
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_fwdPosition(mj_model, data)
        mujoco.mj_fwdVelocity(mj_model, data)
        mujoco.mj_mulM(mj_model, data, inertial, qacc)
        return inertial + implicit_damping * qacc + data.qfrc_bias - data.qfrc_passive

    return _rows(row, mj_model.nq, mj_model.nv)


def _rows(row, nq: int, nv: int):
    """The batched host function ``(qpos, qvel, qacc) -> float32`` of ``row``, a float64
    function of one state and acceleration, applied to each row of any leading shape (NaN
    where an input is not finite: such a row is not asked of MuJoCo)."""

    def inverse(qpos, qvel, qacc):
        shape = np.shape(qacc)
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, nv)
        qacc = np.asarray(qacc, np.float64).reshape(-1, nv)
        out = np.full_like(qacc, np.nan)
        asked = np.isfinite(qpos).all(1) & np.isfinite(qvel).all(1) & np.isfinite(qacc).all(1)
        for i in np.flatnonzero(asked):
            out[i] = row(qpos[i], qvel[i], qacc[i])
        return out.astype(np.float32).reshape(shape)

    return inverse


def _host_policy(inverse, name: str):
    """``policy(step, key) -> tau``: the host function ``inverse(qpos, qvel, qdd*)`` through
    :func:`cfm_jax.sim.host.host_call` under ``name`` (batched over any vmapped axis)."""

    def policy(step, key):
        del key
        shape = jax.ShapeDtypeStruct(jnp.shape(step.desired), jnp.float32)
        args = (jnp.asarray(x, jnp.float32) for x in (step.qpos, step.qvel, step.desired))
        return host_call(name, inverse, shape, *args)

    return policy


def joint_pd_gains(robot, kp: float, kd: float, home) -> tuple[np.ndarray, np.ndarray]:
    """The joint PD-only baseline's torque gains ``(K_p, K_d) = (kp, kd) diag M(home)``.

    Each joint alone at ``home`` then has the gains ``kp, kd`` of ``s*``'s PD; the task applies
    them with no feed-forward (:meth:`cfm_jax.tasks.JointSpaceTask.feedback`).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      kp: acceleration stiffness (1/s^2).
      kd: acceleration damping (1/s).
      home: ``(nq,)`` the pose at which the mass matrix is taken.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> k_p, k_d = joint_pd_gains(arm, 100.0, 20.0, arm.home)
      >>> bool(np.allclose(k_p / k_d, 5.0))
      True
    """
    inertia = robot.mass_matrix_diagonal(home)
    return kp * inertia, kd * inertia


def babbling_joint_gains(robot, kp: float, kd: float, poses) -> tuple[np.ndarray, np.ndarray]:
    """The babbling's torque PD gains ``(max(kp I_j, w D_j), kd I_j)``: ``I_j`` each joint's
    lightest effective inertia over ``poses``, ``D_j`` its damping, ``w = sqrt(kp)``.

    :func:`joint_pd_gains` fit home only: unstable far from it on light arms. These damp no
    joint alone faster than ``kd`` anywhere; ``w D_j`` makes a joint whose damping outweighs
    its inertia follow its error at ``w`` (docs/how-to/own-robot.md).

    Args:
      robot: a :class:`cfm_jax.sim.robots.Robot`.
      kp: acceleration stiffness (1/s^2).
      kd: acceleration damping (1/s).
      poses: ``(n, nq)`` the poses the babbling may visit.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> k_p, k_d = babbling_joint_gains(arm, 100.0, 20.0, arm.home[None])
      >>> bool(np.all(k_d <= joint_pd_gains(arm, 100.0, 20.0, arm.home)[1]))
      True
    """
    inertia = robot.lightest_inertia(poses)
    damping = robot.mj_model.dof_damping[np.asarray(robot.actuated_dofs)]
    return np.maximum(kp * inertia, np.sqrt(kp) * damping), kd * inertia


def pd_loop_radius(robot, gain_p, gain_d, pose, control_dt: float) -> float:
    """Spectral radius of the joint PD loop ``tau = -K_p e - K_d ed``, linearised at ``pose``.

    The torque is held over the control period, whose physics steps are MuJoCo's Euler step
    (implicit in the joints' damping, as the ``Euler`` and ``implicitfast`` integrators take
    it): per step ``v' = v + h (M + h D)^-1 (tau - D v)``, ``q' = q + h v'``. ``M`` is the
    actuated joints' block of ``M(pose)`` (armature included; the other joints held), gravity's
    and velocity's derivatives are left out. Below 1 a small error decays; at 1 and above it
    does not. Unlike ``kd dt lambda_max(M^-1 K_d)`` it counts the damping and the sub-steps (a
    heavily damped wrist is stable where that number says it is not).

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      gain_p: ``(action_dim,)`` torque stiffness per joint (N m/rad).
      gain_d: ``(action_dim,)`` torque damping per joint (N m s/rad).
      pose: ``(nq,)`` the pose the loop is linearised at.
      control_dt: the control period (s), a multiple of ``robot.timestep``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> k_p, k_d = joint_pd_gains(arm, 100.0, 20.0, arm.home)
      >>> bool(pd_loop_radius(arm, k_p, k_d, arm.home, 0.01) < 1.0)
      True
    """
    h = robot.timestep
    dofs = np.asarray(robot.actuated_dofs)
    k = len(dofs)
    inertia = robot.mass_matrix(pose)[np.ix_(dofs, dofs)]
    damping = np.diag(robot.mj_model.dof_damping[dofs])
    solve = np.linalg.inv(inertia + h * damping)
    decay = np.eye(k) - h * solve @ damping
    step = np.block([[np.eye(k), h * decay], [np.zeros((k, k)), decay]])
    push = np.vstack([h * h * solve, h * solve])
    # One control period of n steps: x <- step^n x + (sum_i step^i push) tau.
    period, held = np.eye(2 * k), np.zeros((2 * k, k))
    for _ in range(max(1, round(control_dt / h))):
        period, held = step @ period, step @ held + push
    gains = np.hstack([np.diag(np.asarray(gain_p, np.float64)),
                       np.diag(np.asarray(gain_d, np.float64))])  # fmt: skip
    return float(np.abs(np.linalg.eigvals(period - held @ gains)).max())


# ---- operational space: the Khatib oracle -----------------------------------------------


class HostOpspaceOracle:
    """Analytic operational-space controller (Khatib 1987) with MuJoCo C, float64.

    ``oracle(qpos (..., nq), qvel (..., nv), xdd_desired (..., 3)) -> tau (..., nv)``:

        tau = J^T Lambda (xdd* - Jdot qd) + N^T tau_null + bias - passive
        Lambda = (J Mt^-1 J^T)^+,   Jbar = Mt^-1 J^T Lambda,   N^T = I - J^T Jbar^T
        tau_null = Mt (null_kp (q_home - q) - null_kd qd),     Mt = M + h D

    One Euler step realises ``xdd*`` exactly (derivation in docs/opspace.md); ``^+`` cuts
    singular values below :data:`RCOND`.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Examples:
      >>> from cfm_jax.sim import robots
      >>> iiwa = robots.load("iiwa14")
      >>> HostOpspaceOracle(iiwa)(iiwa.home, np.zeros(7), np.zeros(3)).shape
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
    """:class:`HostOpspaceOracle` as a float32 JAX function ``torque(qpos, qvel, xdd_desired)``.

    ``"native"``: one host call (:func:`cfm_jax.sim.host.host_call`) per batch into an oracle built
    once per (model, site, home, gains); ``"mjx"``: :func:`mjx_opspace_oracle`. Torques are
    not clipped.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).
      simulator: ``"native"`` or ``"mjx"``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> iiwa = robots.load("iiwa14")
      >>> jax.jit(opspace_oracle(iiwa))(iiwa.home, np.zeros(7), np.zeros(3)).shape
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
        return host_call(host.key, host, shape, *args, desired)

    return torque


def mjx_opspace_oracle(
    robot,
    site: int | str | None = None,
    home=None,
    null_kp: float = NULL_KP,
    null_kd: float = NULL_KD,
):
    """:class:`HostOpspaceOracle`'s controller computed by MJX in float32, as a jit/vmap-able
    ``torque(qpos, qvel, xdd_desired)``; its pseudo-inverse cuts at :data:`RCOND_FLOAT32`.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot` with hinge and slide joints.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` posture of the null-space term, or None for ``robot.home``.
      null_kp: null-space proportional gain (1/s^2).
      null_kd: null-space derivative gain (1/s).

    Examples:
      >>> from cfm_jax.sim import robots
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
    """The op-space PD-only baseline's gains ``(K_p, K_d) = (kp, kd) Lambda(home)``, ``(3, 3)``.

    ``Lambda`` is :meth:`HostOpspaceOracle.task_inertia`: at home the force ``K_p e + K_d ed``
    gives the site the acceleration ``kp e + kd ed`` (cf. :func:`joint_pd_gains`).

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      kp: proportional acceleration gain (1/s^2).
      kd: derivative acceleration gain (1/s).
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` pose where ``Lambda`` is taken, or None for ``robot.home``.

    Examples:
      >>> from cfm_jax.sim import robots
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
    """Task-space PD-only feedback ``torque(qpos, qvel, ref_x, ref_xd) -> tau`` (JAX, float32):
    ``tau = J^T (K_p (x_ref - x) + K_d (xd_ref - xd))``, no feed-forward or null-space term.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      gain_p: ``K_p``, ``(3, 3)`` (for example from :func:`opspace_pd_gains`).
      gain_d: ``K_d``, ``(3, 3)``.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      simulator: where the site kinematics come from, ``"native"`` or ``"mjx"``.

    Examples:
      >>> from cfm_jax.sim import robots
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
      positions: ``(targets, steps, 3)`` site positions ``x_{t+1}`` after each control step.
      reference_x: ``(targets, steps + 1, 3)`` (its first point dropped) or ``(targets, steps, 3)``.

    Examples:
      >>> site_tracking_mse(np.zeros((2, 3, 3)), np.ones((2, 4, 3))).tolist()
      [1.0, 1.0]
    """
    positions = jnp.asarray(positions)
    reference_x = jnp.asarray(reference_x)
    if reference_x.shape[-2] == positions.shape[-2] + 1:
        reference_x = reference_x[..., 1:, :]
    return jnp.mean(jnp.square(positions - reference_x), axis=(-2, -1))


class HostRollout(NamedTuple):
    """Result of :func:`host_rollout`, each ``(targets, steps, ...)`` after each control step.

    Attributes:
      qpos: joint positions ``(..., nq)``.
      qvel: joint velocities ``(..., nv)``.
      position: site positions ``(..., 3)``.
      desired: ``xdd*_t`` ``(..., 3)``.
      tau: applied (clipped) torques ``(..., nv)``.

    Examples:
      >>> HostRollout._fields
      ('qpos', 'qvel', 'position', 'desired', 'tau')
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
    """The :class:`HostRollout` of a host policy on every target, with MuJoCo C (NumPy): the
    reference for :func:`cfm_jax.sim.rollout.run` with the ``native`` simulator, same conventions.

    Start at rest at ``home``; at step ``t`` the policy's torque for ``xdd*_t``
    (:func:`cfm_jax.tasks.references.desired_acceleration`), clipped to the limits, is held for
    ``control_dt / timestep`` physics steps; the state is stored as float32.

    Args:
      robot: a fixed-base :class:`cfm_jax.sim.robots.Robot`.
      reference: a :class:`cfm_jax.tasks.references.CartesianReference` (NumPy).
      policy: NumPy ``policy(qpos, qvel, desired, ref_x, ref_xd) -> tau``, batched ``(B, ...)``.
      kp: proportional gain (1/s^2) of the desired acceleration.
      kd: derivative gain (1/s) of the desired acceleration.
      control_dt: control period (s), a multiple of the robot's timestep.
      site: the site's id or name, or None for :func:`cfm_jax.sim.opspace.ee_site`'s default.
      home: ``(nq,)`` start pose (at rest), or None for ``robot.home``.

    Examples:
      >>> from cfm_jax.tasks import references
      >>> from cfm_jax.sim import robots
      >>> arm = robots.load("two_link_arm")
      >>> ref = references.cartesian_reaching(
      ...     arm, "tip", [[0.5, 0.0, 1.4]], duration=0.5, control_dt=0.01)
      >>> oracle = HostOpspaceOracle(arm, "tip")
      >>> out = host_rollout(arm, ref, lambda q, qd, xdd, *_: oracle(q, qd, xdd),
      ...                    kp=100.0, kd=20.0, control_dt=0.01, site="tip")
      >>> out.tau.shape, bool(site_tracking_mse(out.position, ref.x)[0] < 1e-5)
      ((1, 50, 2), True)
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
