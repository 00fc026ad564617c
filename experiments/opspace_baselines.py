"""Operational-space building blocks: kinematics timing (host callback vs MJX) and the
tracking quality of the oracle and PD-only baselines. Not a test: prints markdown tables
(the numbers of ``docs/opspace.md``).

* Kinematics: ``x, xd, J, Jdot qd`` of the end-effector site at every step of a scanned,
  vmapped loop of 200 steps (batch 5 and 15), (a) :func:`cfm_jax.sim.opspace.kinematics`
  (MuJoCo C through ``jax.pure_callback``) and (b) the same in JAX with MJX
  (``mjx.kinematics``; ``J`` by ``jax.jacfwd``, ``Jdot qd`` by nested ``jax.jvp``).
* Tracking: :func:`cfm_jax.tasks.baselines.host_rollout` of the oracle
  (:class:`cfm_jax.tasks.baselines.HostOpspaceOracle`) and of PD-only
  (:func:`cfm_jax.tasks.baselines.opspace_pd_gains`, ``tau = J^T (K_p e + K_d ed)``) on the 5
  default Cartesian references (2 s), kp = 100, kd = 20, control_dt 0.01 s (5 physics steps
  of 0.002 s, torque held) and 0.002 s.

Usage:
  python experiments/opspace_baselines.py            # ~2 min on 2 cores (MJX compiles)
  python experiments/opspace_baselines.py --no-mjx   # tracking and callback timing only
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import cfm_jax  # noqa: F401  (sets the XLA flag before JAX's backend starts)
from cfm_jax.sim import opspace, robots
from cfm_jax.tasks import baselines, references


def mjx_kinematics(robot, site):
    from mujoco import mjx

    model = robot.mjx_model
    blank = mjx.make_data(model)

    def position(q):
        return mjx.kinematics(model, blank.replace(qpos=q)).site_xpos[site]

    def kinematics(q, qd):
        x, xd = jax.jvp(position, (q,), (qd,))
        _, bias = jax.jvp(lambda q: jax.jvp(position, (q,), (qd,))[1], (q,), (qd,))
        return x, xd, jax.jacfwd(position)(q), bias

    return kinematics


def time_loop(kinematics, robot, batch, steps=200, repeats=3):
    def one(q0):
        def body(carry, _):
            q, qd = carry
            x, xd, jac, bias = kinematics(q, qd)
            qd = qd + 0.01 * (jac.T @ (jnp.ones(3) - bias - x - xd))
            return (q + 0.01 * qd, qd), x

        return jax.lax.scan(body, (q0, jnp.zeros_like(q0)), None, length=steps)[1]

    run = jax.jit(jax.vmap(one))
    q0 = jnp.asarray(np.tile(robot.home, (batch, 1)), jnp.float32)
    start = time.perf_counter()
    jax.block_until_ready(run(q0))
    first = time.perf_counter() - start
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run(q0))
        best = min(best, time.perf_counter() - start)
    return first - best, best / steps


def tracking(robot, site, control_dt, kp=100.0, kd=20.0):
    reference = references.cartesian_reaching(robot, site, None, 2.0, control_dt)
    oracle = baselines.HostOpspaceOracle(robot, site)
    gain_p, gain_d = baselines.opspace_pd_gains(robot, kp, kd, site)
    kinematics = opspace.HostKinematics(robot, site)

    def pd(q, qd, desired, ref_x, ref_xd):
        state = kinematics(q, qd)
        force = (ref_x - state.position) @ gain_p.T + (ref_xd - state.velocity) @ gain_d.T
        return np.einsum("bij,bi->bj", state.jacobian, force)

    rows = []
    for name, policy in (("oracle", lambda q, qd, xdd, *_: oracle(q, qd, xdd)), ("PD", pd)):
        out = baselines.host_rollout(robot, reference, policy, kp, kd, control_dt, site)
        rmse = np.sqrt(np.asarray(baselines.site_tracking_mse(out.position, reference.x)))
        saturated = np.mean(np.any(np.abs(out.tau) >= robot.torque_limit - 1e-9, axis=-1))
        rows.append((name, rmse, saturated))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--no-mjx", action="store_true", help="skip the MJX timing")
    args = parser.parse_args()

    iiwa = robots.load("iiwa14")
    site = opspace.ee_site(iiwa)
    print("| kinematics path | batch | compile (s) | per control step (us) |")
    print("|---|---:|---:|---:|")
    paths = [("host callback (MuJoCo C)", lambda q, qd: opspace.kinematics(iiwa, q, qd))]
    if not args.no_mjx:
        paths.append(("MJX in JAX", mjx_kinematics(iiwa, site)))
    for name, kinematics in paths:
        for batch in (5, 15):
            compile_s, per_step = time_loop(kinematics, iiwa, batch)
            print(f"| {name} | {batch} | {compile_s:.2f} | {per_step * 1e6:.0f} |")

    print()
    print("| robot | site | control_dt | policy | EE RMSE per target (mm) | mean (mm) | sat. |")
    print("|---|---|---:|---|---|---:|---:|")
    for robot_name, site_name in (("iiwa14", None), ("two_link_arm", "tip")):
        robot = robots.load(robot_name)
        label = opspace.site_names(robot)[opspace.ee_site(robot, site_name)]
        for control_dt in (0.01, 0.002):
            for name, rmse, saturated in tracking(robot, site_name, control_dt):
                per_target = ", ".join(f"{1e3 * r:.3g}" for r in rmse)
                print(
                    f"| {robot_name} | {label} | {control_dt} | {name} | {per_target} | "
                    f"{1e3 * np.sqrt(np.mean(rmse**2)):.3g} | {saturated:.1%} |"
                )


if __name__ == "__main__":
    main()
