"""Benchmark (``cfm-jax bench``): rollout steps/s next to ``mujoco.rollout``, a training
iteration's cost and compile time, PyTorch reference, memory (:func:`run`, docs/benchmarks.md)."""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import resource
import sys
import time
from importlib import metadata

import cfm_jax  # noqa: F401  (sets the XLA flag before JAX starts)

CONTROL_DT = 0.01
NATIVE_THREADS = 2


def _best(fn, repeats: int) -> float:
    import jax

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return min(times)


@dataclasses.dataclass
class Bench:
    """The robot, its stepping and a policy, from the MJCF alone (:meth:`load`; any base).

    Attributes:
      mj_model: the ``mujoco.MjModel``.
      n_sub: physics steps per control step of :data:`CONTROL_DT`.
      q_home: ``(nq,)`` the keyframe ``home``, else ``qpos0``.
      act_qpos: ``(nu,)`` qpos address of each actuator's joint.
      act_dof: ``(nu,)`` dof address of each actuator's joint.
      gear: ``(nu,)`` actuator gears (``tau = ctrl * gear``).
      ctrl_low: ``(nu,)`` lower control limits (``-inf``: not limited).
      ctrl_high: ``(nu,)`` upper control limits (``inf``: not limited).

    Examples:
      >>> Bench.load("solo12").act_dof[:3].tolist()  # floating base: 6 dofs before the joints
      [6, 7, 8]
    """

    mj_model: object
    n_sub: int
    q_home: object  # (nq,)
    act_qpos: object  # qpos address of each actuator's joint, (nu,)
    act_dof: object  # dof address of each actuator's joint, (nu,)
    gear: object  # (nu,)
    ctrl_low: object
    ctrl_high: object

    @classmethod
    def load(cls, robot: str) -> Bench:
        import mujoco
        import numpy as np

        from cfm_jax.sim import robots

        model = mujoco.MjModel.from_xml_path(robots.resolve(robot))
        n_sub = int(round(CONTROL_DT / model.opt.timestep))
        joints = model.actuator_trnid[:, 0]
        if np.any(model.actuator_trntype != int(mujoco.mjtTrn.mjTRN_JOINT)):
            raise ValueError(f"robot={robot!r}: the benchmark needs joint actuators")
        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
        q_home = model.key_qpos[key].copy() if key >= 0 else model.qpos0.copy()
        limited = model.actuator_ctrllimited.astype(bool)
        low = np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf)
        high = np.where(limited, model.actuator_ctrlrange[:, 1], np.inf)
        return cls(
            model,
            n_sub,
            q_home,
            model.jnt_qposadr[joints],
            model.jnt_dofadr[joints],
            model.actuator_gear[:, 0].copy(),
            low,
            high,
        )

    @property
    def mj_model_holder(self):
        """What :func:`cfm_jax.sim.rollout.native_physics` takes: an object with ``mj_model``."""
        return self

    @property
    def nu(self) -> int:
        return self.mj_model.nu

    @property
    def state_dim(self) -> int:
        return self.mj_model.nq + self.mj_model.nv

    @property
    def torque_limit(self):
        import numpy as np

        bound = np.maximum(np.abs(self.ctrl_low), np.abs(self.ctrl_high)) * np.abs(self.gear)
        return np.where(np.isfinite(bound), bound, 100.0).astype(np.float32)

    def networks(self):
        from cfm_jax.learning import networks

        forward = networks.forward_model((400, 400, 400), 3, self.nu)
        controller = networks.controller((300, 200, 100), self.nu)
        return forward, controller

    def normaliser(self):
        from cfm_jax.learning import networks

        return networks.Normaliser.identity(self.state_dim, self.nu, self.torque_limit)

    def rollout_fn(self, controller, steps: int):
        """``f(controller_params, normaliser, phases) -> (Transitions, ctrl, finite)``: the loop."""
        import jax
        import jax.numpy as jnp

        from cfm_jax.sim import dataset, rollout

        physics = rollout.native_physics(self.mj_model_holder, self.n_sub)
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        home, act_q, act_d = f32(self.q_home), self.act_qpos, self.act_dof
        gear, low, high = f32(self.gear), f32(self.ctrl_low), f32(self.ctrl_high)
        kp, kd = 100.0, 20.0
        # Torque PD gains of the actuated joints: kp, kd times the joint's diagonal inertia
        # at home, as the library's PD feedback.
        import mujoco
        import numpy as np

        data = mujoco.MjData(self.mj_model)
        data.qpos[:] = self.q_home
        mujoco.mj_forward(self.mj_model, data)
        full = np.zeros((self.mj_model.nv,) * 2)
        mujoco.mj_fullM(self.mj_model, data, full)
        diag = np.diag(full)[self.act_dof]
        gain_p, gain_d = f32(kp * diag), f32(kd * diag)

        def one(controller_params, normaliser, phase):
            def step(carry, t):
                q, qd = carry
                time_s = t * CONTROL_DT
                ref = home[act_q] + 0.3 * jnp.sin(2 * jnp.pi * 0.5 * time_s + phase)
                ref_qd = 0.3 * jnp.pi * jnp.cos(2 * jnp.pi * 0.5 * time_s + phase)
                desired = kp * (ref - q[act_q]) + kd * (ref_qd - qd[act_d])
                state = jnp.concatenate([q, qd])
                tau = controller.apply(controller_params, normaliser, state, desired)
                tau = tau + gain_p * (ref - q[act_q]) + gain_d * (ref_qd - qd[act_d])
                ctrl = jnp.clip(tau / gear, low, high)
                q_next, qd_next, _ = physics(q, qd, ctrl)
                observed = (qd_next[act_d] - qd[act_d]) / CONTROL_DT
                finite = jnp.all(jnp.isfinite(q_next)) & jnp.all(jnp.isfinite(qd_next))
                out = (dataset.Transitions(state, desired, ctrl * gear, observed), ctrl, finite)
                return (q_next, qd_next), out

            carry = (home, jnp.zeros(self.mj_model.nv, jnp.float32))
            return jax.lax.scan(step, carry, jnp.arange(steps))[1]

        return jax.vmap(one, in_axes=(None, None, 0))

    def native_rollout(self, ctrl, repeats: int, threads: int = NATIVE_THREADS) -> float:
        """Best seconds of ``mujoco.rollout`` replaying ``ctrl (batch, steps, nu)`` from home."""
        import mujoco
        import numpy as np
        from mujoco import rollout as mj_rollout

        control = np.repeat(np.asarray(ctrl, np.float64), self.n_sub, axis=1)
        spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
        data = mujoco.MjData(self.mj_model)
        data.qpos[:] = self.q_home
        state0 = np.empty(mujoco.mj_stateSize(self.mj_model, spec))
        mujoco.mj_getState(self.mj_model, data, state0, spec)
        initial = np.tile(state0, (control.shape[0], 1))
        datas = [mujoco.MjData(self.mj_model) for _ in range(threads)]
        with mj_rollout.Rollout(nthread=threads if threads > 1 else 0) as runner:
            return _best(lambda: runner.rollout(self.mj_model, datas, initial, control), repeats)


def measure_rollout(bench: Bench, batch: int, steps: int, repeats: int) -> dict:
    """Physics ``rollout_steps_per_s`` of our loop, ``native_steps_per_s`` of ``mujoco.rollout``
    replaying its controls (timed in turn), ``ratio``, ``rollout_compile_s``, ``finite_fraction``.

    Args:
      bench: the :class:`Bench`.
      batch: rollouts stepped together.
      steps: control steps per rollout.
      repeats: timed runs of each (the best counts).

    Examples:
      >>> measure_rollout(Bench.load("two_link_arm"), 2, 5, 1)  # tens of seconds  # doctest: +SKIP
    """
    import jax
    import jax.numpy as jnp
    import numpy as np

    _, controller = bench.networks()
    params = controller.init(jax.random.key(0), bench.state_dim)
    norm = bench.normaliser()
    fn = jax.jit(bench.rollout_fn(controller, steps))
    phases = jnp.linspace(0.0, 2 * np.pi, batch, endpoint=False)
    start = time.perf_counter()
    _, ctrl, finite = jax.block_until_ready(fn(params, norm, phases))
    first = time.perf_counter() - start
    ours, native_s = [], []
    for _ in range(repeats):
        ours.append(_best(lambda: fn(params, norm, phases), 1))
        native_s.append(bench.native_rollout(np.asarray(ctrl), 1))
    physics_steps = batch * steps * bench.n_sub
    rollout_rate = physics_steps / min(ours)
    native_rate = physics_steps / min(native_s)
    return dict(
        batch=batch,
        rollout_steps_per_s=rollout_rate,
        native_steps_per_s=native_rate,
        ratio=rollout_rate / native_rate,
        rollout_compile_s=first - min(ours),
        finite_fraction=float(np.mean(np.asarray(finite))),
    )


def measure_training(bench: Bench, targets: int, steps: int, fit_steps: int, repeats: int):
    """One iteration of Algorithm 1 (rollout, refit f, refit g with the joint loss) compiled whole
    and in parts: ``(times, (flat, normaliser))``, ``flat`` the first rollout; ``times`` has
    ``<part>_s`` (``rollout``, ``forward_update``, ``controller_update``, ``iteration``),
    ``iteration_compile_s``, ``recompiled_after_first`` and ``<model>_updates_per_s``.

    Args:
      bench: the :class:`Bench`.
      targets: rollouts per iteration.
      steps: control steps per rollout.
      fit_steps: Adam steps of each refit (batch 256).
      repeats: timed runs of each (the best counts; of the iteration at least 2).

    Examples:
      >>> measure_training(Bench.load("two_link_arm"), 2, 5, 2, 1)  # compiles  # doctest: +SKIP
    """
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from cfm_jax.learning import algorithm, networks
    from cfm_jax.sim import dataset

    forward, controller = bench.networks()
    roll = bench.rollout_fn(controller, steps)
    optimizer = optax.adam(1e-3)
    key = jax.random.key(0)
    fp = forward.init(jax.random.fold_in(key, 1), bench.state_dim)
    cp = controller.init(jax.random.fold_in(key, 2), bench.state_dim)
    fo, co = optimizer.init(fp), optimizer.init(cp)
    phases = jnp.linspace(0.0, 2 * np.pi, targets, endpoint=False)
    # A data set of 15 rollouts' capacity (5 babbling + 10 iterations), filled with the
    # first rollout's transitions (sampling cost does not depend on the content).
    transitions, _, finite = jax.jit(roll)(cp, bench.normaliser(), phases)
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), transitions)
    capacity = 15 * flat.state.shape[0]
    data = dataset.empty(capacity, bench.state_dim, bench.nu)
    for _ in range(15):
        data = dataset.add(data, flat, finite.reshape(-1))
    norm = networks.Normaliser.from_data(
        flat.state, flat.observed, bench.torque_limit, weights=finite.reshape(-1)
    )

    def rollout_part(cp, data):
        transitions, _, finite = roll(cp, norm, phases)
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), transitions)
        return dataset.add(data, flat, finite.reshape(-1))

    def forward_part(fp, fo, data, key):
        return algorithm.fit_forward(forward, optimizer, fp, fo, norm, data, key, fit_steps, 256)

    def controller_part(cp, co, fp, data, key):
        return algorithm.fit_controller(
            "joint", forward, controller, optimizer, cp, co, fp, norm, data, key, fit_steps, 256
        )

    def iteration(fp, fo, cp, co, data, key):
        key_f, key_c = jax.random.split(key)
        data = rollout_part(cp, data)
        fp, fo, _ = forward_part(fp, fo, data, key_f)
        cp, co, loss = controller_part(cp, co, fp, data, key_c)
        return fp, fo, cp, co, data, loss

    parts = {
        "rollout": (jax.jit(rollout_part), (cp, data)),
        "forward_update": (jax.jit(forward_part), (fp, fo, data, key)),
        "controller_update": (jax.jit(controller_part), (cp, co, fp, data, key)),
    }
    out = {}
    for name, (fn, args) in parts.items():
        jax.block_until_ready(fn(*args))
        out[f"{name}_s"] = _best(lambda fn=fn, args=args: fn(*args), repeats)
    step = jax.jit(iteration)
    start = time.perf_counter()
    state = jax.block_until_ready(step(fp, fo, cp, co, data, key))
    first = time.perf_counter() - start
    times = []
    for i in range(max(2, repeats)):
        start = time.perf_counter()
        state = jax.block_until_ready(step(*state[:5], jax.random.fold_in(key, i)))
        times.append(time.perf_counter() - start)
    out["iteration_s"] = min(times)
    out["iteration_compile_s"] = first - min(times)
    out["recompiled_after_first"] = step._cache_size() != 1
    out["forward_updates_per_s"] = fit_steps / out["forward_update_s"]
    out["controller_updates_per_s"] = fit_steps / out["controller_update_s"]
    return out, (flat, norm)


def measure_torch(bench: Bench, flat, repeats: int, updates: int = 50) -> dict:
    """PyTorch reference updates/s (ImportError without torch), ``torch_<model>_updates_per_s``
    (the better of 1 and 2 threads, also each as ``..._1t``, ``..._2t``), ``torch_version``.

    Args:
      bench: the :class:`Bench` (for the torque limits).
      flat: ``Transitions`` ``(n, ...)`` to train on (from :func:`measure_training`).
      repeats: timed runs per model and thread count (the best counts).
      updates: updates per timed run (after 5 warm-up updates).

    Examples:
      >>> _, (flat, _) = measure_training(Bench.load("two_link_arm"), 2, 5, 2, 1)  # doctest: +SKIP
      >>> measure_torch(Bench.load("two_link_arm"), flat, 1)  # needs torch  # doctest: +SKIP
    """
    import numpy as np

    from cfm_jax.analysis import torch_reference

    data = dict(
        state=np.asarray(flat.state),
        action=np.asarray(flat.action),
        observed=np.asarray(flat.observed),
        desired=np.asarray(flat.desired),
        torque_limit=bench.torque_limit,
    )
    out = {}
    for threads in (1, 2):
        fwd = torch_reference.ForwardUpdate(data, threads=threads)
        ctrl = torch_reference.ControllerUpdate(torch_reference.ForwardUpdate(data), data)
        for name, model in (("forward", fwd), ("controller", ctrl)):
            for _ in range(5):
                model.step()
            best = float("inf")
            for _ in range(repeats):
                start = time.perf_counter()
                for _ in range(updates):
                    model.step()
                best = min(best, (time.perf_counter() - start) / updates)
            out[f"torch_{name}_updates_per_s_{threads}t"] = 1.0 / best
    for name in ("forward", "controller"):
        out[f"torch_{name}_updates_per_s"] = max(
            out[f"torch_{name}_updates_per_s_{t}t"] for t in (1, 2)
        )
    import torch

    out["torch_version"] = torch.__version__
    return out


def peak_memory_mib() -> float:
    """Peak resident set size of this process in MiB.

    Examples:
      >>> peak_memory_mib() > 0
      True
    """
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024 if sys.platform != "darwin" else rss / 2**20


def versions() -> str:
    """The benchmark's package versions, for the record.

    Examples:
      >>> versions()  # doctest: +ELLIPSIS
      'jax ..., jaxlib ..., mujoco ..., mujoco-mjx ..., flax ..., optax ...'
    """
    names = ["jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax"]
    return ", ".join(f"{n} {metadata.version(n)}" for n in names)


def processor() -> str:
    """The processor's model (``/proc/cpuinfo``'s ``model name``, else ``platform``'s): XLA
    compiles for its instruction set, so the last bits of a run's numbers belong to it.

    Examples:
      >>> processor() != ""
      True
    """
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and value.strip():
                    return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> str:
    """Processor, cores, memory (``?`` without ``/proc/meminfo``), OS, Python and ``XLA_FLAGS``.

    Examples:
      >>> "cores" in machine() and "XLA_FLAGS=" in machine()
      True
    """
    try:
        with open("/proc/meminfo") as f:
            memory = f"{int(f.readline().split()[1]) / 2**20:.0f} GiB"
    except OSError:
        memory = "?"
    return (
        f"{processor()}, {os.cpu_count()} cores, {memory}, "
        f"{platform.system()} {platform.release()}, Python {platform.python_version()}, "
        f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}"
    )


def run(
    robot: str = "iiwa14",
    batch: int = 16,
    steps: int = 200,
    repeats: int = 5,
    train: bool = True,
    torch: bool = True,
    targets: int = 5,
    fit_steps: int = 200,
) -> dict:
    """Every measurement of one benchmark run as a flat dict (the ``measure_*`` results, the
    speed-ups over torch, ``robot``, ``n_sub``, ``peak_memory_mib``, ``machine``, ...).

    Args:
      robot: registered robot name or path to an MJCF file.
      batch: rollouts stepped together in the rollout measurement.
      steps: control steps per rollout.
      repeats: best of this many timed runs.
      train: also time a training iteration (:func:`measure_training`).
      torch: also time the PyTorch reference (without torch: ``torch_version`` None).
      targets: rollouts per training iteration.
      fit_steps: Adam steps per refit in the timed iteration.

    Examples:
      >>> run("two_link_arm", batch=2, steps=5, train=False)  # tens of seconds  # doctest: +SKIP
    """
    from cfm_jax.sim import native

    bench = Bench.load(robot)
    result = dict(robot=robot, n_sub=bench.n_sub, control_dt=CONTROL_DT, steps=steps)
    result.update(measure_rollout(bench, batch, steps, repeats))
    result["fast_callback"] = bool(native.FAST_CALLBACK)
    if train:
        training, (flat, _) = measure_training(bench, targets, steps, fit_steps, repeats)
        result.update(training)
        if torch:
            try:
                result.update(measure_torch(bench, flat, repeats))
            except ImportError:
                result["torch_version"] = None
            else:
                for name in ("forward", "controller"):
                    result[f"{name}_speedup_vs_torch"] = (
                        result[f"{name}_updates_per_s"] / result[f"torch_{name}_updates_per_s"]
                    )
    result["peak_memory_mib"] = peak_memory_mib()
    result["machine"] = machine()
    result["versions"] = versions()
    return result


def table(result: dict) -> str:
    """The result as an aligned two-column table (floats from 100 up with thousands separators).

    Args:
      result: a dict, as :func:`run` returns.

    Examples:
      >>> print(table({"rollout_steps_per_s": 123456.7, "ratio": 0.81234}))
      rollout_steps_per_s  123,457
      ratio                0.8123
    """
    rows = []
    for key, value in result.items():
        if isinstance(value, float):
            text = f"{value:,.0f}" if abs(value) >= 100 else f"{value:.4g}"
        else:
            text = str(value)
        rows.append((key, text))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k.ljust(width)}  {v}" for k, v in rows)


def main() -> None:
    """``python -m cfm_jax.analysis.bench``: :func:`bench` with its flags (tyro).

    Examples:
      >>> main()  # a benchmark with the flags in sys.argv (tens of seconds)  # doctest: +SKIP
    """
    import tyro

    tyro.cli(bench)


def bench(
    robot: str = "iiwa14",
    batch: int = 16,
    steps: int = 200,
    repeats: int = 5,
    train: bool = True,
    torch: bool = True,
    fit_steps: int = 200,
    json: bool = False,  # noqa: A002  (the flag's name)
) -> None:
    """Rollout steps/s next to mujoco.rollout, a training iteration's cost, compile time, memory.

    Args:
      robot: registered robot name or path to an MJCF file (fixed or floating base).
      batch: rollouts stepped together.
      steps: control steps per rollout (0.01 s each).
      repeats: best of this many timed runs.
      train: also time a training iteration (--no-train: rollouts only).
      torch: also time the PyTorch reference (needs the bench extra).
      fit_steps: Adam steps per refit in the timed iteration.
      json: print one JSON line instead of a table.

    Examples:
      >>> bench("two_link_arm", batch=2, steps=5, train=False)  # tens of seconds  # doctest: +SKIP
    """
    result = run(
        robot=robot,
        batch=batch,
        steps=steps,
        repeats=repeats,
        train=train,
        torch=torch,
        fit_steps=fit_steps,
    )
    if json:
        print(_json.dumps(result))
    else:
        print(table(result))


_json = json

if __name__ == "__main__":
    main()
