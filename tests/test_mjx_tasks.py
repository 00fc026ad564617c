"""MJX as an on-device simulator: with ``simulator="mjx"`` a task's rollout is a JAX
program with no host callback, the MJX site kinematics and operational-space oracle equal
MuJoCo C's, and every task's rollout of a fixed policy on MJX follows the native one.

Oracles: the traced program itself (its primitives; the native simulator's rollout is the
positive control, it must show its host callback), MuJoCo C in float64
(:class:`cfm_jax.sim.opspace.HostKinematics`, :class:`cfm_jax.tasks.baselines.HostOpspaceOracle`) at
random states, and the native simulator's rollout of the same policy (the task's oracle or
its PD feedback; a 1 % gain change is the negative control)."""

from __future__ import annotations

import copy
import functools
import re
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cfm_jax import config as config_lib
from cfm_jax import tasks
from cfm_jax.runs import training
from cfm_jax.sim import host, opspace, robots, rollout
from cfm_jax.tasks import baselines

CALLBACK = re.compile(rf"callback|{host.TARGET}")  # a host call: Python or the FFI target

COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}
"""XLA's CPU back end without LLVM optimisation: these rollouts are tiny, and optimising
them takes longer than it saves (the MJX compile of the two-link arm's rollout drops from
7.6 to 3.0 s, the Solo12's from 9.3 to 2.9 s); results move in float32's last digits."""


def fast_jit(fn, *args):
    """``fn`` compiled for ``args`` with :data:`COMPILER_OPTIONS` (called like ``fn``)."""
    return jax.jit(fn).lower(*args).compile(COMPILER_OPTIONS)


def small(name: str, simulator: str) -> config_lib.Config:
    """The task's defaults at a small size (the traced program has the same structure)."""
    base = tasks.load(name).default_config()
    changes = {"simulator": simulator}
    if name in ("inverse_dynamics", "opspace"):
        site = "tip" if name == "opspace" else None
        # The one-step oracle, whose comparison the tolerances below were measured on: the
        # default period oracle solves each simulator's own period by Newton steps on
        # float32 finite differences, which differ between the simulators at 1e-4 rad/s
        # (its MJX path against MuJoCo C: tests/test_baselines.py).
        task = config_lib.TaskConfig(name=name, duration=0.1, site=site, oracle="step")
        changes.update(robot="two_link_arm", task=task)
    return base.replace(
        **changes,
        forward=config_lib.ForwardModelConfig(hidden=(8,), ensemble_size=1),
        controller=config_lib.ControllerConfig(hidden=(8,)),
        loop=config_lib.LoopConfig(iterations=1, seeds=1, babbling_rollouts=1),
    )


class Program:
    """A task's experiment (:func:`small`) on one simulator, its babbling policy, which
    mixes every branch (controller, feedback, oracle, noise) with runtime weights, so that
    all of them are in the program and any weights run on it, and (on first use) its
    rollout traced with that policy."""

    def __init__(self, name: str, simulator: str):
        self.experiment = training.Experiment(small(name, simulator))
        self.policy = self.experiment.babbling_policy()

    @functools.cached_property
    def traced(self):
        return jax.jit(self.experiment.rollout_one).trace(self.policy, jax.random.key(0))


@pytest.fixture(scope="module")
def programs():
    """``programs(name, simulator)`` -> :class:`Program`, built once per module: the
    callback check and the comparison with the native simulator share the experiment and
    the trace (most of the op-space task's cost: tracing MJX's site kinematics)."""
    cache = {}

    def get(name: str, simulator: str) -> Program:
        if (name, simulator) not in cache:
            cache[name, simulator] = Program(name, simulator)
        return cache[name, simulator]

    return get


@pytest.mark.parametrize("name", sorted(tasks.REGISTRY))
def test_mjx_rollout_has_no_host_callback(programs, name):
    assert not CALLBACK.findall(str(programs(name, "mjx").traced.jaxpr))


def test_the_callback_check_sees_the_native_simulator(programs):
    """Positive control: the native rollout steps MuJoCo C through a host callback."""
    assert CALLBACK.findall(str(programs("inverse_dynamics", "native").traced.jaxpr))


@pytest.fixture(scope="module")
def arms(iiwa, arm):
    return {"iiwa14": iiwa, "two_link_arm": arm}  # the shared fixtures of conftest.py


def random_states(robot, n: int, seed: int):
    rng = np.random.default_rng(seed)
    low, high = robot.joint_range[:, 0], robot.joint_range[:, 1]
    qpos = rng.uniform(low + 0.1 * (high - low), high - 0.1 * (high - low), (n, robot.nq))
    qvel = rng.normal(0.0, 1.0, (n, robot.nv))
    return qpos.astype(np.float32), qvel.astype(np.float32)


# The iiwa (the arm of the paper's op-space figure) is in the default run: each of the two
# tests below compiles one program for it (MJX's kinematics of a depth-8 chain: about 1 MB
# of StableHLO; measured 12-20 s of compile and 5-7 s of trace on 2 shared cores), so the
# site kinematics are compiled once, through the task's entry point on a batch of two axes,
# which calls mjx_kinematics on the flattened batch.
@pytest.mark.parametrize("name,site", [("iiwa14", None), ("two_link_arm", "tip")])
def test_mjx_site_kinematics_equal_mujoco_c(arms, name, site):
    robot = arms[name]
    qpos, qvel = random_states(robot, 6, seed=1)
    q2, qd2 = qpos.reshape(2, 3, -1), qvel.reshape(2, 3, -1)
    got = fast_jit(lambda q, qd: opspace.kinematics(robot, q, qd, site, "mjx"), q2, qd2)(q2, qd2)
    want = opspace.HostKinematics(robot, site)(qpos, qvel)
    for field, a, b in zip(want._fields, got, want, strict=True):
        # float32 against float64: positions to ~1e-6 m, derivatives to a few 1e-5.
        a = np.asarray(a)
        assert a.shape == (2, 3) + b.shape[1:], field  # both batch axes kept
        np.testing.assert_allclose(a.reshape(b.shape), b, rtol=1e-4, atol=1e-4, err_msg=field)


@pytest.mark.parametrize("name,site", [("iiwa14", None), ("two_link_arm", "tip")])
def test_mjx_oracle_equals_the_host_oracle(arms, name, site):
    robot = arms[name]
    qpos, qvel = random_states(robot, 6, seed=2)
    desired = np.random.default_rng(3).normal(0.0, 2.0, (6, 3)).astype(np.float32)
    # At XLA's optimisation level 0 the first of these 6 states once came out wrong (-9.87
    # instead of 5.18 N m). Cause, in our code: the two-link arm moves in a plane, so its
    # 3 x 3 J Mt^-1 J^T has rank 2 (J's y row is exactly 0); float32's eigensolver returns
    # the zero eigenvalue as rounding noise, and the float64 cut-off RCOND = 1e-9 kept it.
    # Measured at level 0 (eigenvalues of J Mt^-1 J^T): state 0 [-1.3e-8, 0.48, 2.92],
    # state 2 [-8.1e-9, 0.56, 2.92] (2.8e-9 and 4.5e-9 relative, above 1e-9), so pinv put
    # 7.6e7 and 1.2e8 into Lambda (state 2 agreed by luck: the noise's eigenvector was y,
    # which J^T drops); the other 4 states, and all 6 at the default level, gave exactly 0;
    # float64 MuJoCo C gives |0| <= 7e-17. The MJX oracle now cuts at float32's rounding,
    # RCOND_FLOAT32 = 3.6e-6 (800x the noise, 3e4x below this arm's smallest true ratio
    # here, 0.12); compiled at level 0 on purpose, where the noise shows.
    got = fast_jit(baselines.opspace_oracle(robot, site, simulator="mjx"), qpos, qvel, desired)(
        qpos, qvel, desired
    )
    want = baselines.HostOpspaceOracle(robot, site)(qpos, qvel, desired)
    scale = np.abs(want).max()
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-3, atol=1e-4 * scale)


# ---- MJX against native, task by task ----------------------------------------------------
#
# A fixed, non-learned policy, the task's oracle or its PD feedback alone (the baselines'
# policies: rollout.MixedPolicy weights, as Experiment.baselines sets them), rolled out with
# simulator="native" and "mjx" from the same start; the trajectories (tracking error and
# state at every step) and the per-target metrics must agree. The arm tasks run the
# experiment's own rollout (all 5 targets x 10 steps of the two-link arm). The legged ones
# run the first target for LEGGED_STEPS steps, through the same rollout.run and
# mixed_policy, with the reference an argument, so that walk and jump compile the same
# program (under -m slow JAX's persistent cache, on in conftest.py, serves the second):
# contacts make the two simulators' float32 and float64 paths drift apart, and a short
# horizon keeps the comparison about the simulator, not about chaos.

LEGGED_STEPS = 250
"""1 s at 250 Hz: the whole 1.0 s walk (standing, then 4 trot steps with touchdowns), and
the 0.05 m jump from standing through crouch, push, flight (steps 163-240) and landing."""

GAIN_CHANGE = 1.01
"""The negative control: the PD feedback 1 % stiffer on the native side only."""


class Tolerance(NamedTuple):
    """Largest allowed |native - mjx| (absolute, per element), and for the per-target
    metrics ``|a - b| <= atol + rtol |a|``."""

    error: float  # the task's tracking error at each step (m or rad)
    qpos: float  # joint positions (rad); legged: also base position (m) and quaternion
    qvel: float  # velocities (rad/s, m/s)
    forces: float  # legged: the foot forces in the state (N); the arm tasks have none
    rtol: float  # tracking MSE and (legged) force MSE per target
    mse_atol: float  # tracking MSE (m^2, rad^2): the oracle's is ~0 on the legged tasks
    force_atol: float  # force MSE (N^2)


# The two-link arm, 10 control steps of 5 physics steps, no contact or active limit: one
# smooth ODE integrated in float32 (MJX) and float64 (MuJoCo C; the native state is rounded
# to float32 between control steps). Measured on this machine: tracking error and qpos
# <= 6e-7, qvel <= 5e-6, metrics relative <= 5e-6 (float32 eps 1.2e-7 times |q| ~ 2 over
# 50 steps); the tolerances leave 16x or more for other CPUs' rounding. The negative
# control moves them by 8e-4 (op-space error) to 5e-2 (qvel) and the MSE by 1 %: 77-500x
# over.
ARM = Tolerance(
    error=1e-5, qpos=1e-5, qvel=1e-4, forces=0.0, rtol=1e-4, mse_atol=1e-10, force_atol=0.0
)
# The Solo12, 250 control steps of 2 physics steps with foot contacts: one MJX step's
# foot forces differ from MuJoCo C's by ~1e-6 N (tests/test_solo12.py), but every
# touchdown and take-off passes the differences on and amplifies them. Measured on this
# machine: tracking error <= 8e-6, qpos <= 4e-5, qvel <= 4e-3, foot forces <= 4e-3 N,
# tracking MSE relative <= 3e-5 (force MSE 2e-6); the oracle's tracking MSE is 3e-15
# native and <= 7e-12 on MJX (float32 states against a recording made in float64), its
# force MSE <= 1.2e-7 N^2. The tolerances leave 8x or more; the 1 % gain change exceeds
# each by 5x (walk's qvel) to 70x.
LEGGED = Tolerance(
    error=1e-4, qpos=3e-4, qvel=3e-2, forces=3e-2, rtol=1e-3, mse_atol=1e-9, force_atol=1e-5
)
TOLERANCE = {"inverse_dynamics": ARM, "opspace": ARM, "walk": LEGGED, "jump": LEGGED}


class Run(NamedTuple):
    result: rollout.Rollout
    tracking_mse: np.ndarray  # (targets,)
    metrics: dict  # the task's own, (targets,) each


def shortened(task, steps: int):
    """The task on its first target only, for its first ``steps`` control steps."""
    short = copy.copy(task)
    short.reference = jax.tree.map(lambda x: x[:1, : steps + 1], task.reference)
    short.targets, short.steps = 1, steps
    return short


@pytest.fixture(scope="module")
def runs(programs):
    """``runs(name, simulator, policy)`` -> :class:`Run`, each rolled out once; ``policy``:
    ``oracle``, ``pd`` or ``pd_stiffer`` (the PD with :data:`GAIN_CHANGE`)."""
    compiled, cache = {}, {}
    weights = {"oracle": (1.0, 0.0), "pd": (0.0, 1.0), "pd_stiffer": (0.0, GAIN_CHANGE)}

    def compile_rollout(name: str, simulator: str):
        """``(task, run(policy) -> Rollout)`` on the task's targets and horizon that are
        compared."""
        program = programs(name, simulator)
        if name not in ("walk", "jump"):
            fn = program.traced.lower().compile(COMPILER_OPTIONS)
            return program.experiment.task, lambda policy: fn(policy, jax.random.key(0))
        experiment = program.experiment
        task = shortened(experiment.task, LEGGED_STEPS)

        def run(policy, reference):
            here = task.with_reference(reference)
            mixed = rollout.mixed_policy(here, experiment.controller, policy, simulator)
            return rollout.run(here, mixed, jax.random.key(0), simulator)

        fn = jax.jit(run).trace(program.policy, task.reference).lower().compile(COMPILER_OPTIONS)
        return task, lambda policy: fn(policy, task.reference)

    def get(name: str, simulator: str, policy: str) -> Run:
        if (name, simulator, policy) not in cache:
            if (name, simulator) not in compiled:
                compiled[name, simulator] = compile_rollout(name, simulator)
            task, run = compiled[name, simulator]
            oracle, feedback = weights[policy]
            mixed = programs(name, simulator).policy._replace(
                controller_weight=jnp.float32(0.0),
                oracle_weight=jnp.float32(oracle),
                feedback_weight=jnp.float32(feedback),
                # The placeholder's own shape: (nv,) per joint, (nv, nv) for the coupled scale.
                noise_std=jnp.zeros_like(programs(name, simulator).policy.noise_std),
            )
            result = jax.device_get(run(mixed))
            cache[name, simulator, policy] = Run(
                result,
                np.asarray(rollout.tracking_mse(result)),
                {k: np.asarray(v) for k, v in jax.device_get(task.metrics(result)).items()},
            )
        return cache[name, simulator, policy]

    return get


def discrepancies(name: str, native: Run, mjx: Run) -> dict[str, float]:
    """Each check's largest difference over its tolerance (> 1: the check fails)."""
    tol, robot = TOLERANCE[name], robots.load(small(name, "native").robot)
    a, b = native.result, mjx.result
    state_a, state_b = np.asarray(a.transitions.state), np.asarray(b.transitions.state)
    nq, nv = robot.nq, robot.nv
    parts = {
        "tracking error": (a.tracking_error, b.tracking_error, tol.error),
        "qpos": (state_a[..., :nq], state_b[..., :nq], tol.qpos),
        "qvel": (state_a[..., -nv:], state_b[..., -nv:], tol.qvel),
    }
    if state_a.shape[-1] > nq + nv:  # the legged state carries the foot forces
        parts["foot forces"] = (state_a[..., nq:-nv], state_b[..., nq:-nv], tol.forces)
    out = {k: float(np.max(np.abs(np.subtract(x, y))) / t) for k, (x, y, t) in parts.items()}

    def metric(x, y, atol):
        return float(np.max(np.abs(x - y) / (atol + tol.rtol * np.abs(x))))

    out["tracking MSE"] = metric(native.tracking_mse, mjx.tracking_mse, tol.mse_atol)
    if "force_mse" in native.metrics:
        forces = native.metrics["force_mse"], mjx.metrics["force_mse"]
        out["force MSE"] = metric(*forces, tol.force_atol)
    return out


# Every task in the default run (the acceptance: MJX against native per task in
# CI). Walk and jump compile the same program, so JAX's persistent cache (on in
# conftest.py) serves the second; the op-space rollout's MJX site kinematics add ~10 s.
COMPARED = ["inverse_dynamics", "opspace", "jump", "walk"]


@pytest.mark.parametrize("policy", ["oracle", "pd"])
@pytest.mark.parametrize("name", COMPARED)
def test_mjx_rollout_follows_the_native_one(runs, name, policy):
    native, mjx = runs(name, "native", policy), runs(name, "mjx", policy)
    ratios = discrepancies(name, native, mjx)
    assert max(ratios.values()) <= 1.0, ratios
    assert np.all(native.result.finite) and np.all(mjx.result.finite)
    for metric, value in native.metrics.items():  # e.g. the legged tasks' falls: none
        if metric not in ("force_mse",):
            np.testing.assert_allclose(mjx.metrics[metric], value, rtol=1e-3, atol=1e-9)
    if name in ("walk", "jump"):
        assert not np.any(native.metrics["fell"])  # a fall would make the horizon moot


@pytest.mark.parametrize("name", COMPARED)
def test_the_comparison_sees_a_one_percent_gain_change(runs, name):
    """Negative control: the native PD 1 % stiffer against MJX's unchanged PD; every check
    of :func:`discrepancies` must fail on its own."""
    ratios = discrepancies(name, runs(name, "native", "pd_stiffer"), runs(name, "mjx", "pd"))
    assert min(ratios.values()) > 1.0, ratios


def test_every_task_is_compared():
    assert set(COMPARED) == set(tasks.REGISTRY)
