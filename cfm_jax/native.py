"""MuJoCo's C engine stepping a batch of states on the host (the ``native`` simulator).

:class:`Stepper` is what :func:`cfm_jax.rollout.native_physics` calls through
``jax.pure_callback`` once per control step: ``(qpos, qvel, ctrl) -> (qpos, qvel,
sensordata)`` after ``n_sub`` physics steps, for any leading batch shape. It has no JAX in
it, so it can be tested and benchmarked alone.

Example:
  >>> import numpy as np
  >>> from cfm_jax import robots
  >>> arm = robots.load("two_link_arm")
  >>> stepper = Stepper(arm.mj_model, n_sub=5)
  >>> q, qd, sensors = stepper(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)))
  >>> q.shape, sensors.shape
  ((3, 2), (3, 5, 0))
"""

from __future__ import annotations

import copy
import os

import numpy as np


class Stepper:
    """Steps a batch of states ``n_sub`` physics steps with MuJoCo's C engine.

    ``stepper(qpos (..., nq), qvel (..., nv), ctrl (..., nu))`` returns ``qpos (..., nq)``,
    ``qvel (..., nv)`` (float32) after ``n_sub`` steps with the control held, and the
    model's ``sensordata`` recorded at each of those steps, ``(..., n_sub, nsensordata)``
    (float32; MuJoCo computes sensors in the ``mj_forward`` at the start of each step, so
    entry ``k`` belongs to the state before step ``k``'s integration).

    Holds a copy of the robot's ``MjModel`` with automatic reset on numerical instability
    disabled (``mjDSBL_AUTORESET``), so a diverging state stays non-finite and is flagged
    like in MJX, instead of silently jumping back to ``qpos0``; a non-finite control makes
    the state non-finite too (MuJoCo would zero it and step on). Batches of at least
    :attr:`THREADED_BATCH` use a pool of two threads (``mujoco.rollout.Rollout``); results
    do not depend on the thread count (each rollout is computed by one thread).
    """

    THREADED_BATCH = 32

    def __init__(self, mj_model, n_sub: int):
        import mujoco
        from mujoco import rollout as mj_rollout

        self.model = copy.deepcopy(mj_model)
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self.n_sub = n_sub
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
        self.threads = max(1, min(2, os.cpu_count() or 1))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self.single = mj_rollout.Rollout(nthread=0)
        self.pool = mj_rollout.Rollout(nthread=self.threads) if self.threads > 1 else None

    def __call__(self, qpos, qvel, ctrl):
        nq, nv, nu = self.model.nq, self.model.nv, self.model.nu
        batch_shape = np.shape(qpos)[:-1]
        qpos = np.asarray(qpos, np.float64).reshape(-1, nq)
        batch = qpos.shape[0]
        state = np.tile(self.template, (batch, 1))
        state[:, self.qpos] = qpos
        state[:, self.qvel] = np.asarray(qvel, np.float64).reshape(-1, nv)
        control = np.repeat(np.asarray(ctrl, np.float64).reshape(-1, 1, nu), self.n_sub, axis=1)
        out = np.empty((batch, self.n_sub, self.nstate))
        sensors = np.empty((batch, self.n_sub, self.model.nsensordata))
        threaded = self.pool is not None and batch >= self.THREADED_BATCH
        runner, datas = (self.pool, self.datas) if threaded else (self.single, self.datas[:1])
        runner.rollout(
            [self.model] * batch,
            datas,
            state,
            np.ascontiguousarray(control),
            control_spec=self.ctrl_spec,
            skip_checks=True,
            nstep=self.n_sub,
            state=out,
            sensordata=sensors,
            chunk_size=max(1, batch // (2 * len(datas))),
        )
        last = out[:, -1]
        # MuJoCo zeroes a non-finite ctrl (with a warning) and steps on; mark such rollouts
        # non-finite instead, as MJX's NaN propagation does.
        bad = ~np.all(np.isfinite(control[:, 0]), axis=-1)
        last[bad] = np.nan
        sensors[bad] = np.nan
        return (
            last[:, self.qpos].astype(np.float32).reshape(*batch_shape, nq),
            last[:, self.qvel].astype(np.float32).reshape(*batch_shape, nv),
            sensors.astype(np.float32).reshape(*batch_shape, self.n_sub, -1),
        )
