"""Checkpoints of the whole :class:`cfm_jax.learning.algorithm.TrainState` with Orbax, verified by a
content manifest (docs/how-to/resume.md).

``DIR/<step>/`` (``step``: completed iterations) holds the state of every seed (the PRNG
key as raw key data) and a JSON ``meta`` part. Orbax writes a step atomically; then
:class:`Checkpointer` writes ``cfm_manifest.json``, the size and SHA-256 of every file, so
a truncated or altered file is found on restore and a step without one (killed between
the two writes) counts as incomplete.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os

import jax
import numpy as np

from cfm_jax._files import write_text

MANIFEST = "cfm_manifest.json"

_ORBAX_TIMING = "Waiting for previous save to complete"


def has_steps(run_dir: str) -> bool:
    """Whether ``run_dir/checkpoints`` holds a checkpoint step (a run killed before its first
    leaves it empty: none).

    Args:
      run_dir: a run's output folder (``out_dir``, or ``OUT/<loss>`` of the CLI).

    Examples:
      >>> import tempfile
      >>> run = tempfile.mkdtemp()
      >>> has_steps(run)
      False
      >>> os.makedirs(os.path.join(run, "checkpoints", "2"))
      >>> has_steps(run)
      True
    """
    folder = os.path.join(run_dir, "checkpoints")
    return os.path.isdir(folder) and any(
        name.isdigit() and os.path.isdir(os.path.join(folder, name)) for name in os.listdir(folder)
    )


class _DropOrbaxTiming(logging.Filter):
    """Drops Orbax's absl WARNING "Waiting for previous save to complete took N seconds" (a
    note on disk speed, not the run's: a run prints nothing else); other records pass."""

    def filter(self, record: logging.LogRecord) -> bool:
        return _ORBAX_TIMING not in record.getMessage()


def _quiet_orbax_timing() -> None:
    absl = logging.getLogger("absl")
    if not any(isinstance(f, _DropOrbaxTiming) for f in absl.filters):
        absl.addFilter(_DropOrbaxTiming())


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used (the message names it and what to do).

    Examples:
      >>> cfm_jax.train(config, resume="results/run")  # doctest: +SKIP
      Traceback (most recent call last):
      cfm_jax.runs.checkpoint.CheckpointError: checkpoint step 4 is not usable: ...
    """


def _files(step_dir: str) -> list[str]:
    out = []
    for root, _, names in os.walk(step_dir):
        for name in names:
            path = os.path.join(root, name)
            if os.path.relpath(path, step_dir) != MANIFEST:
                out.append(path)
    return sorted(out)


def _digest(path: str) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def _to_storable(state):
    return state.replace(key=jax.random.key_data(state.key))


def _from_storable(state):
    return state.replace(key=jax.random.wrap_key_data(np.asarray(state.key)))


class Checkpointer:
    """Save and restore training states under ``directory`` (created).

    Args:
      directory: the checkpoint folder (``OUT/checkpoints`` of a run), one sub-folder a step.
      keep: number of most recent steps kept on disk (Orbax deletes older ones).

    Examples:
      >>> ckpt = Checkpointer("/tmp/run/checkpoints", keep=3)  # doctest: +SKIP
      >>> ckpt.save(2, result.state, {"rows": []})  # doctest: +SKIP
      >>> state, meta = ckpt.restore(2, template=result.state)  # doctest: +SKIP
    """

    def __init__(self, directory: str, keep: int = 3):
        import orbax.checkpoint as ocp

        _quiet_orbax_timing()
        self.directory = os.path.abspath(directory)
        self._ocp = ocp
        self._manager = ocp.CheckpointManager(
            self.directory,
            options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True),
        )
        self._pending: int | None = None  # the step being written in the background

    def steps(self) -> list[int]:
        """Steps present on disk (complete or not), ascending."""
        self.wait()
        self._manager.reload()
        return sorted(self._manager.all_steps())

    def save(self, step: int, state, meta: dict) -> None:
        """Write ``state`` and JSON ``meta`` as ``step`` in the background (Orbax's async
        save). The manifest that makes the step complete is written at the next :meth:`save`,
        :meth:`wait` or :meth:`close`; a step a kill interrupts has none and is skipped."""
        self.wait()
        ocp = self._ocp
        self._manager.save(
            step,
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(_to_storable(state)),
                meta=ocp.args.JsonSave(meta),
            ),
            force=True,
        )
        self._pending = step

    def wait(self) -> None:
        """Wait for the step being written and write its manifest (nothing if none is)."""
        if self._pending is None:
            return
        step, self._pending = self._pending, None
        self._manager.wait_until_finished()
        step_dir = os.path.join(self.directory, str(step))
        manifest = {
            os.path.relpath(p, step_dir): [os.path.getsize(p), _digest(p)] for p in _files(step_dir)
        }
        write_text(os.path.join(step_dir, MANIFEST), json.dumps(manifest), durable=True)

    def problem(self, step: int) -> str | None:
        """Why ``step`` cannot be restored (no manifest, a missing, truncated or changed file), or
        None when it verifies."""
        self.wait()
        step_dir = os.path.join(self.directory, str(step))
        try:
            with open(os.path.join(step_dir, MANIFEST)) as f:
                manifest = json.load(f)
        except FileNotFoundError:
            return f"{step_dir} is incomplete (no {MANIFEST}: the run stopped while writing it)"
        except (OSError, ValueError) as error:
            return f"{os.path.join(step_dir, MANIFEST)} is unreadable ({error})"
        for name, (size, digest) in sorted(manifest.items()):
            path = os.path.join(step_dir, name)
            if not os.path.isfile(path):
                return f"{path} is missing"
            actual = os.path.getsize(path)
            if actual != size:
                return f"{path} is truncated or changed ({actual} bytes, expected {size})"
            if _digest(path) != digest:
                return f"{path} is corrupt (its SHA-256 differs from the manifest)"
        return None

    def restore(self, step: int, template):
        """``(state, meta)`` of ``step``; ``template`` is a state of the same structure.

        Raises:
          CheckpointError: the step does not verify (the newest earlier one that does is offered).
        """
        self.wait()
        problem = self.problem(step)
        if problem is not None:
            earlier = [s for s in self.steps() if s < step and self.problem(s) is None]
            offer = (
                f"the previous valid checkpoint is step {earlier[-1]}: delete "
                f"{os.path.join(self.directory, str(step))} to resume from it"
                if earlier
                else "no earlier valid checkpoint exists: start the run again (cfm-jax "
                "train --restart moves the old run aside first)"
            )
            raise CheckpointError(f"checkpoint step {step} is not usable: {problem}; {offer}")
        ocp = self._ocp
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _to_storable(template))
        restored = self._manager.restore(
            step,
            args=ocp.args.Composite(
                state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()
            ),
        )
        return _from_storable(restored.state), restored.meta

    def delete(self, step: int) -> None:
        """Remove ``step`` from disk (for example one left incomplete by a kill)."""
        self.wait()
        self._manager.delete(step)

    def close(self) -> None:
        """Finish the step being written (:meth:`wait`) and close the manager."""
        self.wait()
        self._manager.close()
