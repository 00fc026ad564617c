"""MuJoCo's C engine stepping a batch of states on the host (the ``native`` simulator):
:class:`Stepper` and its JAX operation :func:`host_step` (docs/performance.md).
"""

from __future__ import annotations

import copy
import hashlib
import os
import threading

import numpy as np

from cfm_jax.sim import host as host_lib

MAXVAL = 1e10
"""MuJoCo's ``mjMAXVAL``: a state entry NaN, infinite or beyond it in magnitude is *bad*."""

WARNINGS: dict[str, int] = {}
"""MuJoCo warnings captured (not printed) while stepping, by message (:func:`take_warnings`)."""


def take_warnings() -> dict[str, int]:
    """The MuJoCo warnings captured since the last call, ``{message: count}``; clears them.

    Examples:
      >>> take_warnings()
      {}
    """
    out = dict(WARNINGS)
    WARNINGS.clear()
    return out


def _capture(message: str) -> None:
    key = message.split(" at DOF")[0].split(". ")[0]
    WARNINGS[key] = WARNINGS.get(key, 0) + 1


def bad_rows(x: np.ndarray) -> np.ndarray:
    """Whether each row (all axes but the last) of ``x`` has a bad entry (:data:`MAXVAL`).

    Args:
      x: an array ``(..., n)``.

    Examples:
      >>> bad_rows(np.array([[0.0, 1.0], [np.nan, 0.0], [2e10, 0.0]])).tolist()
      [False, True, True]
    """
    with np.errstate(invalid="ignore"):
        return ~np.all(np.abs(x) <= MAXVAL, axis=-1)


def model_digest(mj_model) -> str:
    """A digest of a model's bytes as MuJoCo saves them (the same in every process): the
    part of a host function's key (:func:`cfm_jax.sim.host.host_call`) that names its model.

    Args:
      mj_model: a ``mujoco.MjModel``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> a, b = robots.load("two_link_arm").mj_model, robots.load("two_link_arm").mj_model
      >>> model_digest(a) == model_digest(b), len(model_digest(a))
      (True, 32)
    """
    import mujoco

    saved = np.zeros(mujoco.mj_sizeModel(mj_model), np.uint8)
    mujoco.mj_saveModel(mj_model, None, saved)
    return hashlib.sha256(saved.tobytes()).hexdigest()[:32]


class _Buffers:
    """Preallocated arrays of one batch size (reused by every call of that size)."""

    def __init__(self, stepper: Stepper, batch: int):
        model = stepper.model
        self.models = [model] * batch
        self.state = np.tile(stepper.template, (batch, 1))
        self.control = np.empty((batch, stepper.n_sub, model.nu))
        self.out = np.empty((batch, stepper.n_sub, stepper.nstate))
        self.sensors = np.empty((batch, stepper.n_sub, model.nsensordata))


class Stepper:
    """Steps a batch of states ``n_sub`` physics steps with MuJoCo's C engine.

    ``stepper(qpos, qvel, ctrl)`` (any leading batch shape) returns float32 ``qpos``, ``qvel``
    after ``n_sub`` steps with ``ctrl`` held and ``sensordata (..., n_sub, nsensordata)``,
    from the model's defaults for all else (time, warm start, activations).
    Auto-reset is off: a row that went bad (:func:`bad_rows`) at any step, that
    ``mujoco.rollout`` stopped at a warning (:data:`WARNINGS`) or whose input was bad
    returns NaN, and changes no other row. Results do not depend on ``threads``.

    Args:
      mj_model: the ``mujoco.MjModel`` to step (copied).
      n_sub: physics steps per call (>= 2 to see a stop at a warning).
      threads: size of the thread pool; None: ``min(2, os.cpu_count())``.

    Examples:
      >>> from cfm_jax.sim import robots
      >>> stepper = Stepper(robots.load("two_link_arm").mj_model, n_sub=5, threads=1)
      >>> stepper(np.zeros(2), np.zeros(2), np.zeros(2))[2].shape  # no batch; no sensors
      (5, 0)
      >>> stepper(np.zeros(2), np.zeros(2), np.array([np.nan, 0.0]))[0].tolist()  # no reset
      [nan, nan]
    """

    threaded_batch = 8
    """Smallest batch stepped on the thread pool (below it the dispatch costs more)."""

    def __init__(self, mj_model, n_sub: int, threads: int | None = None):
        import mujoco
        from mujoco import rollout as mj_rollout

        self.model = copy.deepcopy(mj_model)
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self.n_sub = int(n_sub)
        self.spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self.ctrl_spec = int(mujoco.mjtState.mjSTATE_CTRL)
        data = mujoco.MjData(self.model)
        self.nstate = mujoco.mj_stateSize(self.model, self.spec)
        self.template = np.empty(self.nstate)
        mujoco.mj_getState(self.model, data, self.template, self.spec)
        self.template[0] = 0.0  # time
        nq, nv = self.model.nq, self.model.nv
        self.qpos = slice(1, 1 + nq)
        self.qvel = slice(1 + nq, 1 + nq + nv)
        # The time after n_sub steps (MuJoCo adds the timestep once per step): a row that
        # ends earlier was stopped by mujoco.rollout, which stops at MuJoCo's first warning.
        self.final_time = 0.0
        for _ in range(self.n_sub):
            self.final_time += self.model.opt.timestep
        if threads is None:
            threads = min(2, os.cpu_count() or 1)
        self.threads = max(1, int(threads))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        # MuJoCo's public ``Rollout.rollout`` with ``skip_checks``: the buffers are right by
        # construction, and the wrapper's argument checks cost more than stepping a small
        # batch. Where a MuJoCo does not take that call, the checked call (:meth:`_rollout`).
        self._single = mj_rollout.Rollout(nthread=0)
        self._pool = mj_rollout.Rollout(nthread=self.threads) if self.threads > 1 else None
        self.unchecked = True
        """Whether the next batch goes through ``skip_checks=True`` (False after a MuJoCo
        refused that call: every later batch takes the checked call)."""
        self._buffers: dict[int, _Buffers] = {}
        self._lock = threading.Lock()
        self.key = f"step-{model_digest(self.model)}-{self.n_sub}-{self.threads}"
        """What the compiled programs name this stepper by: the model's bytes, ``n_sub`` and
        ``threads`` (the same in every process, so JAX's cache serves the programs)."""

    def __call__(self, qpos, qvel, ctrl):
        import mujoco

        nq, nv, nu = self.model.nq, self.model.nv, self.model.nu
        batch_shape = np.shape(qpos)[:-1]
        qpos = np.reshape(qpos, (-1, nq))
        batch = qpos.shape[0]
        with self._lock:
            buffers = self._buffers.get(batch)
            if buffers is None:
                buffers = self._buffers[batch] = _Buffers(self, batch)
            state, control = buffers.state, buffers.control
            state[:, self.qpos] = qpos
            state[:, self.qvel] = np.reshape(qvel, (-1, nv))
            control[:] = np.reshape(ctrl, (-1, 1, nu))
            # Rows that are already bad are not stepped (no warnings, nothing to learn).
            skip = bad_rows(state[:, self.qpos]) | bad_rows(state[:, self.qvel])
            skip |= ~np.all(np.isfinite(control[:, 0]), axis=-1)
            if skip.any():
                state[skip] = self.template
                control[skip] = 0.0
            threaded = self._pool is not None and batch >= self.threaded_batch
            runner, datas = (self._pool, self.datas) if threaded else (self._single, self.datas[:1])
            previous = mujoco.get_mju_user_warning()
            mujoco.set_mju_user_warning(_capture)
            try:
                self._rollout(runner, buffers, datas, batch)
            finally:
                mujoco.set_mju_user_warning(previous)
            last = buffers.out[:, -1]
            q_next = last[:, self.qpos].astype(np.float32)
            qd_next = last[:, self.qvel].astype(np.float32)
            sensors = buffers.sensors.astype(np.float32)
            # A row diverged when its state was bad after any physics step (MuJoCo goes on
            # with huge values when auto-reset is off).
            out = buffers.out
            diverged = bad_rows(out[:, :, self.qpos]) | bad_rows(out[:, :, self.qvel])
            diverged = np.any(diverged, axis=1) | (out[:, -1, 0] != self.final_time)
            bad = skip | diverged
        if bad.any():
            q_next[bad] = np.nan
            qd_next[bad] = np.nan
            sensors[bad] = np.nan
        return (
            q_next.reshape(*batch_shape, nq),
            qd_next.reshape(*batch_shape, nv),
            sensors.reshape(*batch_shape, self.n_sub, self.model.nsensordata),
        )

    def _rollout(self, runner, buffers, datas, batch):
        """Steps ``buffers.state`` with ``buffers.control`` into ``buffers.out`` and
        ``buffers.sensors`` through MuJoCo's public ``Rollout.rollout``: unchecked while this
        MuJoCo takes ``skip_checks``, else checked (the same C++ call after the wrapper's
        shape checks; the results are copied into the buffers if it returns new arrays)."""
        arguments = dict(
            control_spec=self.ctrl_spec,
            nstep=self.n_sub,
            state=buffers.out,
            sensordata=buffers.sensors,
            chunk_size=-(-batch // len(datas)),  # one chunk per thread
        )
        if self.unchecked:
            try:
                runner.rollout(
                    buffers.models, datas, buffers.state, buffers.control, skip_checks=True,
                    **arguments,
                )  # fmt: skip
                return
            except TypeError:  # this MuJoCo's rollout has no skip_checks
                self.unchecked = False
        out, sensors = runner.rollout(
            buffers.models, datas, buffers.state, buffers.control, **arguments
        )
        if out is not buffers.out:
            buffers.out[:] = out
        if sensors is not buffers.sensors:
            buffers.sensors[:] = sensors


# ----- the JAX operation ------------------------------------------------------------------

FAST_CALLBACK: bool | None = None
"""Whether :func:`host_step` (``fast=True``) takes the FFI target (:func:`cfm_jax.sim.host.here`;
None: not called yet; False: ``jax.pure_callback``, whose programs JAX's cache does not keep)."""


def host_step(stepper: Stepper, qpos, qvel, ctrl, fast: bool = True):
    """:class:`Stepper` as a JAX operation (one host call per ``vmap`` batch; no gradient).

    Args:
      stepper: the :class:`Stepper` (static, not traced).
      qpos: positions ``(..., nq)``.
      qvel: velocities ``(..., nv)``.
      ctrl: controls ``(..., nu)``.
      fast: on CPU, step through :func:`cfm_jax.sim.host.host_call`'s FFI target, not
        ``jax.pure_callback`` (the same result; a program that calls the target is kept in
        JAX's persistent compilation cache, one with a Python callback is not).

    Examples:
      >>> import jax
      >>> from cfm_jax.sim import robots
      >>> stepper = Stepper(robots.load("two_link_arm").mj_model, n_sub=5, threads=1)
      >>> step = jax.jit(jax.vmap(lambda q, qd, u: host_step(stepper, q, qd, u)))
      >>> step(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)))[0].shape
      (3, 2)
    """
    import jax
    import jax.numpy as jnp

    qpos, qvel, ctrl = (jnp.asarray(x, jnp.float32) for x in (qpos, qvel, ctrl))
    global FAST_CALLBACK
    if fast:
        FAST_CALLBACK = host_lib.here()
    shapes = (
        jax.ShapeDtypeStruct(qpos.shape, jnp.float32),
        jax.ShapeDtypeStruct(qvel.shape, jnp.float32),
        jax.ShapeDtypeStruct(
            (*qpos.shape[:-1], stepper.n_sub, stepper.model.nsensordata), jnp.float32
        ),
    )
    return host_lib.host_call(stepper.key, stepper, shapes, qpos, qvel, ctrl, fast=fast)
