"""What one native step costs beside the physics: ``cfm_jax.sim.native.host_step`` with a
stepper that does no physics, inside a compiled ``vmap(scan)`` (batch 16, 7 joints, 2000
steps), through the FFI target (``fast=True``, the default on CPU) and through
``jax.pure_callback`` (``fast=False``). Not a test: prints microseconds per call (the best of
``--runs`` timed runs after one warm-up).

Usage (nothing else running on the machine; ``PYTHONPATH=<worktree>`` times another commit):
  python experiments/host_call_benchmark.py [--runs 5]
"""

from __future__ import annotations

import argparse
import time
import types

import numpy as np

STEPS, BATCH, JOINTS = 2000, 16, 7


class _NoPhysics:
    """A stepper's interface, no physics: returns its inputs (no sensors)."""

    n_sub = 5
    model = types.SimpleNamespace(nsensordata=0)
    key = "host-call-benchmark"

    def __call__(self, qpos, qvel, ctrl):
        return qpos, qvel, np.zeros((*np.shape(qpos)[:-1], self.n_sub, 0), np.float32)


def per_call(fast: bool, runs: int) -> float:
    """Microseconds per host call, the best of ``runs``."""
    import jax
    import jax.numpy as jnp

    from cfm_jax.sim import native

    stepper = _NoPhysics()

    def one(q):
        def step(carry, _):
            return native.host_step(stepper, carry, carry, carry, fast=fast)[0] + 1.0, None

        return jax.lax.scan(step, q, None, length=STEPS)[0]

    rollout = jax.jit(jax.vmap(one))
    q = jnp.zeros((BATCH, JOINTS), jnp.float32)
    rollout(q).block_until_ready()
    best = float("inf")
    for _ in range(runs):
        start = time.perf_counter()
        rollout(q).block_until_ready()
        best = min(best, time.perf_counter() - start)
    return best / STEPS * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    import cfm_jax  # noqa: F401 (its XLA flags first)
    from cfm_jax.sim import native

    fast = per_call(True, args.runs)
    slow = per_call(False, args.runs)
    print(f"host_step: {fast:.1f} us per call (FAST_CALLBACK={native.FAST_CALLBACK}), "
          f"jax.pure_callback {slow:.1f} us per call")  # fmt: skip


if __name__ == "__main__":
    main()
