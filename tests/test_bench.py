"""The benchmark's rollout path, its CLI, and "no recompilation after the first iteration".

Oracles: a plain Python loop (the policy evaluated eagerly, MuJoCo's ``mj_step`` one
rollout at a time) for the compiled closed loop the bench times; XLA's backend-compile
events (``jax.monitoring``) for recompilation.
"""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from tiny import tiny_config

from cfm_jax.analysis import bench
from cfm_jax.runs import training


def test_bench_rollout_equals_python_loop_of_mj_step():
    b = bench.Bench.load("two_link_arm")
    _, controller = b.networks()
    params = controller.init(jax.random.key(0), b.state_dim)
    norm = b.normaliser()
    steps, phases = 4, jnp.asarray([0.0, 1.5], jnp.float32)
    transitions, ctrl, finite = jax.jit(b.rollout_fn(controller, steps))(params, norm, phases)
    assert bool(jnp.all(finite))
    model = b.mj_model
    for i, phase in enumerate(np.asarray(phases)):
        data = mujoco.MjData(model)
        q = np.asarray(b.q_home, np.float32)
        qd = np.zeros(model.nv, np.float32)
        for t in range(steps):
            np.testing.assert_allclose(
                np.asarray(transitions.state[i, t]), np.concatenate([q, qd]), atol=1e-5
            )
            # The policy evaluated eagerly, step by step (same formulas as the bench).
            time_s = t * bench.CONTROL_DT
            ref = b.q_home[b.act_qpos] + 0.3 * np.sin(2 * np.pi * 0.5 * time_s + phase)
            np.testing.assert_allclose(
                np.asarray(transitions.desired[i, t]),
                100.0 * (ref - q[b.act_qpos])
                + 20.0 * (0.3 * np.pi * np.cos(2 * np.pi * 0.5 * time_s + phase) - qd[b.act_dof]),
                rtol=1e-4,
                atol=1e-3,
            )
            u = np.asarray(ctrl[i, t], np.float64)
            assert np.all(u >= b.ctrl_low) and np.all(u <= b.ctrl_high)
            mujoco.mj_resetData(model, data)
            data.qpos[:], data.qvel[:], data.ctrl[:] = q, qd, u
            for _ in range(b.n_sub):
                mujoco.mj_step(model, data)
            qd_prev = qd
            q, qd = data.qpos.astype(np.float32), data.qvel.astype(np.float32)
            np.testing.assert_allclose(
                np.asarray(transitions.observed[i, t]),
                (qd[b.act_dof] - qd_prev[b.act_dof]) / bench.CONTROL_DT,
                rtol=1e-4,
                atol=1e-2,
            )


def test_bench_cli_json_line():
    out = subprocess.run(
        [sys.executable, "-m", "cfm_jax.analysis.bench", "--robot", "two_link_arm", "--batch", "3"]
        + ["--steps", "5", "--repeats", "1", "--no-train", "--json"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["batch"] == 3 and result["robot"] == "two_link_arm"
    assert result["rollout_steps_per_s"] > 0 and result["native_steps_per_s"] > 0
    ratio = result["rollout_steps_per_s"] / result["native_steps_per_s"]
    assert abs(result["ratio"] - ratio) < 1e-9 * ratio
    assert result["finite_fraction"] == 1.0 and result["peak_memory_mib"] > 0


def test_no_recompilation_after_first_iteration():
    """Iterations after the first compile nothing (no backend compile event at all)."""
    config = tiny_config(iterations=3)
    experiment = training.Experiment(config)
    keys = jax.vmap(jax.random.key)(jnp.arange(2, dtype=jnp.uint32))
    state = experiment.init("joint", keys)
    state, metrics = jax.block_until_ready(experiment.iteration("joint", state))
    compiles = []
    listening = [True]

    def listener(event, duration, **kwargs):
        if listening[0] and event == "/jax/core/compile/backend_compile_duration":
            compiles.append(kwargs)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        for _ in range(2):
            state, metrics = jax.block_until_ready(experiment.iteration("joint", state))
        assert compiles == []
        # Positive control: a new function does raise the event.
        jax.block_until_ready(jax.jit(lambda x: x * 3.0 + 1.0)(jnp.ones(5)))
        assert len(compiles) >= 1
    finally:
        listening[0] = False
    assert np.all(np.isfinite(np.asarray(metrics["forward_loss"])))


def test_processor_is_the_one_golden_records_name():
    """The benchmark pages and the peers' page name the processor as the golden records do:
    ``tests/golden._cpu`` reads ``/proc/cpuinfo`` on its own (there: its ``model name``)."""
    from golden import _cpu

    assert bench.processor() == _cpu()["model"]
    assert bench.machine().startswith(bench.processor() + ", ")
