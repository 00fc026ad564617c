"""TensorBoard event files of a training run (``cfm-jax train --tensorboard DIR``; extra
``cfm_jax[tensorboard]``): :class:`TensorBoardWriter`; see docs/how-to/metrics.md."""

from __future__ import annotations

import math
import os

import pandas as pd

__all__ = ["MISSING", "TensorBoardWriter", "available"]

MISSING = (
    "TensorBoard event files need tensorboardX, which is not installed: "
    "pip install 'cfm_jax[tensorboard]' (or pip install tensorboardX)"
)
_KEYS = ("loss", "seed", "iteration", "target")


def available() -> bool:
    """Whether tensorboardX can be imported (without importing it).

    Examples:
      >>> isinstance(available(), bool)
      True
    """
    import importlib.util

    return importlib.util.find_spec("tensorboardX") is not None


class TensorBoardWriter:
    """A ``progress_fn`` for :func:`cfm_jax.train` (ImportError without tensorboardX): per
    iteration (the step) it writes tag ``<loss>/<metric>`` = the mean over seeds and targets
    (non-finite: skipped) and flushes; ``written`` keeps ``{tag: [(step, value), ...]}``.

    Args:
      logdir: the folder of the event file (created; runs may share one).

    Examples:
      >>> import tempfile
      >>> rows = pd.DataFrame({"loss": "joint", "seed": [0, 1], "tracking_mse": [0.25, 0.75]})
      >>> with TensorBoardWriter(tempfile.mkdtemp()) as writer:
      ...     writer(0, rows)  # as cfm_jax.train(config, progress_fn=writer) calls it
      ...     writer.written
      {'joint/tracking_mse': [(0, 0.5)]}
    """

    def __init__(self, logdir: str | os.PathLike):
        try:
            from tensorboardX import SummaryWriter
        except ImportError as error:
            raise ImportError(MISSING) from error
        self.logdir = os.fspath(logdir)
        self.written: dict[str, list[tuple[int, float]]] = {}
        self._writer = SummaryWriter(logdir=self.logdir)

    def __call__(self, iteration: int, metrics: pd.DataFrame) -> None:
        """Write and flush one iteration's rows of ``TrainResult.metrics`` (no loss: ``run``)."""
        frame = metrics if "loss" in metrics.columns else metrics.assign(loss="run")
        columns = [
            c for c in frame.columns
            if c not in _KEYS and pd.api.types.is_numeric_dtype(frame[c])
        ]  # fmt: skip
        for loss, rows in frame.groupby("loss", sort=False):
            for column in columns:
                tag, value = f"{loss}/{column}", float(rows[column].astype(float).mean())
                if not math.isfinite(value):  # not measured here (all NaN), or infinite
                    continue
                self._writer.add_scalar(tag, value, global_step=int(iteration))
                self.written.setdefault(tag, []).append((int(iteration), value))
        self._writer.flush()

    def close(self) -> None:
        """Flush and close the event file."""
        self._writer.close()

    def __enter__(self) -> TensorBoardWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
