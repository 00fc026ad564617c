"""The native stepper and its JAX operation against MuJoCo's ``mj_step``, one state at a time.

Oracle: a fresh ``MjData`` per state, ``qpos, qvel, ctrl`` set, ``mj_step`` called ``n_sub``
times, ``sensordata`` read after each step (MuJoCo's own loop, no batching, no threads).
"""

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from cfm_jax.sim import host, native, robots

SENSOR_ARM = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" type="hinge" axis="0 1 0" damping="0.1" range="-1 1" limited="true"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05" mass="1"/>
      <body name="lower" pos="0 0 -0.5">
        <joint name="elbow" type="hinge" axis="0 1 0" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.05" mass="1"/>
        <site name="tip" pos="0 0 -0.5"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" ctrlrange="-5 5" ctrllimited="true"/>
    <motor joint="elbow" ctrlrange="-5 5" ctrllimited="true"/>
  </actuator>
  <sensor>
    <jointpos joint="elbow"/>
    <framepos objtype="site" objname="tip"/>
    <actuatorfrc actuator="shoulder"/>
  </sensor>
</mujoco>
"""


def oracle(model, qpos, qvel, ctrl, n_sub):
    """``mj_step`` one state at a time (float64), inputs as the stepper sees them."""
    qpos, qvel, ctrl = (np.asarray(x, np.float32).astype(np.float64) for x in (qpos, qvel, ctrl))
    batch = qpos.shape[0]
    out_q = np.empty((batch, model.nq))
    out_qd = np.empty((batch, model.nv))
    sensors = np.empty((batch, n_sub, model.nsensordata))
    for i in range(batch):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos[i], qvel[i], ctrl[i]
        for k in range(n_sub):
            mujoco.mj_step(model, data)
            sensors[i, k] = data.sensordata
        out_q[i], out_qd[i] = data.qpos, data.qvel
    return out_q, out_qd, sensors


def random_inputs(model, batch, seed):
    rng = np.random.default_rng(seed)
    qpos = model.qpos0 + 0.3 * rng.standard_normal((batch, model.nq))
    qvel = rng.standard_normal((batch, model.nv))
    ctrl = rng.uniform(-3, 3, (batch, model.nu))
    return qpos.astype(np.float32), qvel.astype(np.float32), ctrl.astype(np.float32)


@pytest.fixture(scope="module")
def sensor_arm():
    return mujoco.MjModel.from_xml_string(SENSOR_ARM)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("batch", [1, 3, 17])
def test_stepper_matches_mj_step(sensor_arm, threads, batch):
    stepper = native.Stepper(sensor_arm, n_sub=4, threads=threads)
    qpos, qvel, ctrl = random_inputs(sensor_arm, batch, seed=batch)
    q, qd, sensors = stepper(qpos, qvel, ctrl)
    want_q, want_qd, want_sensors = oracle(sensor_arm, qpos, qvel, ctrl, 4)
    assert q.dtype == qd.dtype == sensors.dtype == np.float32
    assert sensors.shape == (batch, 4, sensor_arm.nsensordata)
    np.testing.assert_allclose(q, want_q, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(qd, want_qd, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(sensors, want_sensors, rtol=1e-6, atol=1e-6)


def test_stepper_reuses_buffers_without_carrying_state(sensor_arm):
    # Calls of different batch sizes interleaved give what a fresh stepper gives: the
    # preallocated buffers of one call never leak into the next.
    stepper = native.Stepper(sensor_arm, n_sub=3, threads=2)
    for batch, seed in [(5, 0), (2, 1), (5, 2), (16, 3), (5, 4)]:
        inputs = random_inputs(sensor_arm, batch, seed)
        got = stepper(*inputs)
        want = native.Stepper(sensor_arm, n_sub=3, threads=1)(*inputs)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)


def test_stepper_leading_batch_shape_and_nan_control(sensor_arm):
    stepper = native.Stepper(sensor_arm, n_sub=2)
    qpos, qvel, ctrl = random_inputs(sensor_arm, 6, seed=7)
    ctrl[4, 1] = np.nan
    q, qd, sensors = stepper(qpos.reshape(2, 3, -1), qvel.reshape(2, 3, -1), ctrl.reshape(2, 3, -1))
    assert q.shape == (2, 3, sensor_arm.nq) and sensors.shape == (2, 3, 2, 5)
    q, qd, sensors = q.reshape(6, -1), qd.reshape(6, -1), sensors.reshape(6, 2, -1)
    assert np.all(np.isnan(q[4])) and np.all(np.isnan(qd[4])) and np.all(np.isnan(sensors[4]))
    keep = [0, 1, 2, 3, 5]
    want_q, want_qd, _ = oracle(sensor_arm, qpos[keep], qvel[keep], ctrl[keep], 2)
    np.testing.assert_allclose(q[keep], want_q, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(qd[keep], want_qd, rtol=1e-6, atol=1e-6)


class NoSkipChecks:
    """A ``mujoco.rollout.Rollout`` as a MuJoCo without ``skip_checks`` would have it: the
    unchecked call is refused with the TypeError Python gives an unknown keyword."""

    def __init__(self, runner):
        self.runner, self.checked_calls = runner, 0

    def rollout(self, *args, skip_checks=None, **kwargs):
        if skip_checks is not None:
            raise TypeError("rollout() got an unexpected keyword argument 'skip_checks'")
        self.checked_calls += 1
        return self.runner.rollout(*args, **kwargs)


@pytest.mark.parametrize("threads, batch", [(1, 3), (2, 17)])
def test_stepper_falls_back_to_the_checked_rollout(sensor_arm, threads, batch):
    # The public fallback path: MuJoCo's checked Rollout.rollout gives the same numbers,
    # bit for bit, as the unchecked call and matches mj_step; once refused, the unchecked
    # call is not tried again.
    qpos, qvel, ctrl = random_inputs(sensor_arm, batch, seed=11)
    want = native.Stepper(sensor_arm, n_sub=4, threads=threads)(qpos, qvel, ctrl)
    stepper = native.Stepper(sensor_arm, n_sub=4, threads=threads)
    stepper._single = NoSkipChecks(stepper._single)
    if stepper._pool is not None:
        stepper._pool = NoSkipChecks(stepper._pool)
    runner = stepper._pool if batch >= stepper.threaded_batch and threads > 1 else stepper._single
    for call in range(2):
        got = stepper(qpos, qvel, ctrl)
        assert not stepper.unchecked and runner.checked_calls == call + 1
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
    want_q, want_qd, want_sensors = oracle(sensor_arm, qpos, qvel, ctrl, 4)
    np.testing.assert_allclose(got[0], want_q, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got[2], want_sensors, rtol=1e-6, atol=1e-6)


def test_stepper_checked_rollout_without_sensors():
    # A model without sensors (sensordata of width 0) through the checked call.
    robot = robots.load("iiwa14")
    qpos, qvel, ctrl = random_inputs(robot.mj_model, 4, seed=5)
    stepper = native.Stepper(robot.mj_model, n_sub=5, threads=1)
    stepper._single = NoSkipChecks(stepper._single)
    got = stepper(qpos, qvel, ctrl)
    assert stepper._single.checked_calls == 1
    want = native.Stepper(robot.mj_model, n_sub=5, threads=1)(qpos, qvel, ctrl)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)


def test_stepper_iiwa_matches_mj_step():
    robot = robots.load("iiwa14")
    stepper = native.Stepper(robot.mj_model, n_sub=5)
    qpos, qvel, ctrl = random_inputs(robot.mj_model, 16, seed=3)
    got = stepper(qpos, qvel, ctrl)
    want = oracle(robot.mj_model, qpos, qvel, ctrl, 5)
    for a, b in zip(got[:2], want[:2], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def closed_loop(stepper, fast, steps=6):
    """A compiled vmap(scan) of PD feedback through :func:`native.host_step`, with a
    nested vmap (seeds x targets) and a control shared by the batch on the first step."""

    def one(q0):
        def step(carry, t):
            q, qd = carry
            ctrl = jnp.where(t == 0, jnp.ones(2), -5.0 * q - qd)
            q, qd, sensors = native.host_step(stepper, q, qd, ctrl, fast=fast)
            return (q, qd), (q, sensors)

        return jax.lax.scan(step, (q0, jnp.zeros_like(q0)), jnp.arange(steps))[1]

    return jax.jit(jax.vmap(jax.vmap(one)))


def test_host_step_fast_equals_pure_callback_and_python_loop(sensor_arm):
    stepper = native.Stepper(sensor_arm, n_sub=3)
    q0 = jnp.asarray(np.random.default_rng(0).uniform(-0.5, 0.5, (2, 3, 2)), jnp.float32)
    fast_q, fast_s = closed_loop(stepper, fast=True)(q0)
    slow_q, slow_s = closed_loop(stepper, fast=False)(q0)
    # On a CPU backend the direct host callback is in use; on a GPU, jax.pure_callback.
    assert native.FAST_CALLBACK is (jax.default_backend() == "cpu")
    np.testing.assert_array_equal(np.asarray(fast_q), np.asarray(slow_q))
    np.testing.assert_array_equal(np.asarray(fast_s), np.asarray(slow_s))
    # Oracle: the same loop in plain Python, one state at a time with mj_step.
    flat = np.asarray(q0).reshape(6, 2)
    for i in range(6):
        q, qd = flat[i : i + 1], np.zeros((1, 2), np.float32)
        for t in range(6):
            ctrl = np.ones((1, 2), np.float32) if t == 0 else -5.0 * q - qd
            ctrl = ctrl.astype(np.float32)
            q, qd, sensors = oracle(sensor_arm, q, qd, ctrl, 3)
            q, qd = q.astype(np.float32), qd.astype(np.float32)
            np.testing.assert_allclose(
                np.asarray(fast_q).reshape(6, 6, 2)[i, t], q[0], rtol=1e-5, atol=1e-5
            )
            np.testing.assert_allclose(
                np.asarray(fast_s).reshape(6, 6, 3, 5)[i, t], sensors[0], rtol=1e-5, atol=1e-5
            )


def test_host_step_eager_and_unbatched(sensor_arm):
    stepper = native.Stepper(sensor_arm, n_sub=2)
    qpos, qvel, ctrl = random_inputs(sensor_arm, 1, seed=11)
    eager = native.host_step(stepper, qpos[0], qvel[0], ctrl[0])
    jitted = jax.jit(lambda a, b, c: native.host_step(stepper, a, b, c))(qpos[0], qvel[0], ctrl[0])
    want = oracle(sensor_arm, qpos, qvel, ctrl, 2)
    for a, b, w in zip(eager, jitted, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_allclose(np.asarray(a), w[0], rtol=1e-6, atol=1e-6)


def _step_twice(stepper, q, qd, u):
    step = jax.jit(jax.vmap(lambda a, b, c: native.host_step(stepper, a, b, c)))
    return [np.asarray(x) for x in step(q, qd, u)]


def test_host_step_without_the_ffi_target_falls_back_with_the_same_results(monkeypatch):
    # Where JAX cannot register the FFI target (no jax.ffi, another ABI), registered() says
    # so and host_step takes jax.pure_callback: the same numbers as the FFI target's.
    arm = robots.load("two_link_arm")
    stepper = native.Stepper(arm.mj_model, n_sub=3, threads=1)
    rng = np.random.default_rng(3)
    q, qd, u = (jnp.asarray(rng.uniform(-1, 1, (4, 2)), jnp.float32) for _ in range(3))
    ffi = _step_twice(stepper, q, qd, u)
    # The FFI target is registered for XLA:CPU only; on a GPU both runs fall back.
    on_cpu = jax.default_backend() == "cpu"
    assert native.FAST_CALLBACK is on_cpu and (host.registered() or not on_cpu)

    def no_ffi(*args, **kwargs):
        raise AttributeError("this JAX has no jax.ffi.register_ffi_target")

    monkeypatch.setattr(host, "_REGISTERED", None)  # as in a new process
    monkeypatch.setattr(jax.ffi, "register_ffi_target", no_ffi)
    public = _step_twice(stepper, q, qd, u)
    assert native.FAST_CALLBACK is False and host.registered() is False
    for a, b in zip(public, ffi, strict=True):
        np.testing.assert_array_equal(a, b)
    # Oracle: MuJoCo C stepped directly by the Stepper, no JAX.
    want = stepper(np.asarray(q), np.asarray(qd), np.asarray(u))
    for a, w in zip(public, want, strict=True):
        np.testing.assert_array_equal(a, np.asarray(w, np.float32))


def test_host_step_on_another_backend_uses_pure_callback(monkeypatch):
    # On a GPU the FFI target (registered for XLA:CPU only) is not used: the step goes
    # through jax.pure_callback and FAST_CALLBACK says False. The backend's name is what
    # host_step decides on.
    arm = robots.load("two_link_arm")
    stepper = native.Stepper(arm.mj_model, n_sub=2, threads=1)
    rng = np.random.default_rng(5)
    q, qd, u = (jnp.asarray(rng.uniform(-1, 1, (3, 2)), jnp.float32) for _ in range(3))
    monkeypatch.setattr(native, "FAST_CALLBACK", None)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    step = jax.jit(jax.vmap(lambda a, b, c: native.host_step(stepper, a, b, c)))
    traced = str(step.trace(q, qd, u).jaxpr)
    assert "pure_callback" in traced and host.TARGET not in traced
    got = step(q, qd, u)
    assert native.FAST_CALLBACK is False
    want = stepper(np.asarray(q), np.asarray(qd), np.asarray(u))  # MuJoCo C, no JAX
    for a, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(w, np.float32))


def test_an_error_in_the_host_function_is_raised_by_the_program(monkeypatch):
    # Through the FFI target an exception in Python cannot cross XLA: the handler turns it
    # into XLA's error, which the compiled call raises, with the exception's message.
    if jax.default_backend() != "cpu":
        pytest.skip("the FFI target is XLA:CPU's")
    arm = robots.load("two_link_arm")
    stepper = native.Stepper(arm.mj_model, n_sub=2, threads=1)
    q = jnp.zeros((2, 2), jnp.float32)
    _step_twice(stepper, q, q, q)  # registered, and compiled

    def broken(*args):
        raise RuntimeError("the stepper broke")

    monkeypatch.setitem(host._FUNCTIONS, stepper.key, broken)
    with pytest.raises(Exception, match="RuntimeError: the stepper broke"):
        _step_twice(stepper, q, q + 1.0, q)


def test_the_stepper_key_is_the_model_and_the_step(tmp_path):
    # Programs name a stepper by its key, so JAX's cache serves them in a new process: the
    # same file loaded twice gives the same key; another model, n_sub or pool does not.
    arm, again = robots.load("two_link_arm"), robots.load("two_link_arm")
    assert arm.mj_model is not again.mj_model
    one = native.Stepper(arm.mj_model, n_sub=3, threads=1)
    assert native.Stepper(again.mj_model, n_sub=3, threads=1).key == one.key
    assert native.Stepper(arm.mj_model, n_sub=4, threads=1).key != one.key
    assert native.Stepper(arm.mj_model, n_sub=3, threads=2).key != one.key
    heavier = robots.load("two_link_arm").mj_model
    heavier.body_mass[-1] += 0.1
    assert native.Stepper(heavier, n_sub=3, threads=1).key != one.key


CACHED = """
import sys, jax, numpy as np
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
import cfm_jax
from jax import monitoring
from cfm_jax.sim import native, robots
events = []
monitoring.register_event_listener(lambda event, **_: events.append(event))
stepper = native.Stepper(robots.load("two_link_arm").mj_model, n_sub=3, threads=1)
roll = jax.jit(lambda q: jax.lax.scan(
    lambda q, _: (native.host_step(stepper, q, q, -q)[0], q), q, None, length=4)[1])
out = np.asarray(roll(np.full((2, 2), 0.3, np.float32)))
print(events.count("/jax/compilation_cache/cache_hits"),
      events.count("/jax/compilation_cache/cache_misses"), out.tobytes().hex())
"""


def test_a_native_program_is_read_from_the_persistent_cache_in_a_new_process(tmp_path):
    # Two processes, one empty cache folder: the first compiles the rollout (a miss) and
    # writes it; the second reads it (a hit, no miss) and gives the same bits. With a
    # jax.pure_callback the second would compile again (JAX writes no such program).
    import subprocess
    import sys

    if jax.default_backend() != "cpu":
        pytest.skip("the FFI target is XLA:CPU's")
    cache = tmp_path / "cache"
    runs = [
        subprocess.run([sys.executable, "-c", CACHED, str(cache)], capture_output=True,
                       text=True, timeout=300, env={**os.environ, "JAX_COMPILATION_CACHE_DIR": ""})
        for _ in range(2)
    ]  # fmt: skip
    (hits0, misses0, out0), (hits1, misses1, out1) = (r.stdout.split() for r in runs)
    assert int(misses0) >= 1 and (int(hits1), int(misses1)) == (int(misses0), 0)
    assert out1 == out0
