"""TensorBoard event files of a training run (the optional ``tensorboard`` extra:
``pip install 'cfm_jax[tensorboard]'``, which installs tensorboardX; no TensorFlow).

:class:`TensorBoardWriter` is a ``progress_fn`` for :func:`cfm_jax.train` (and what
``cfm-jax train --tensorboard DIR`` uses): after every iteration it writes one scalar per
metric and loss, tag ``<loss>/<metric>`` (``joint/tracking_mse``), step = the iteration
(``0 .. loop.iterations``, the last one the final evaluation), value = the metric's mean
over the iteration's rows, i.e. over seeds and targets, as the command line's table
averages (:func:`cfm_jax.report.summary`). Every numeric column of
:attr:`cfm_jax.TrainResult.metrics` but ``seed``, ``iteration`` and ``target`` is a
metric: ``tracking_mse``, ``prediction_error``, ``predicted_task_error``,
``forward_loss``, ``controller_loss``, ``diverged`` (the fraction of rollouts that
diverged) and the task's own. A metric whose mean is not finite at an iteration is not
written there: the mean skips NaN rows, so that is a metric nobody measured at that step
(``forward_loss`` and ``controller_loss`` at the final evaluation, which fits nothing), or
an infinite one; TensorBoard would only draw a gap, and tensorboardX would print a warning
for each. The file is flushed after every iteration, so TensorBoard
shows a run while it trains (``tensorboard --logdir DIR``).

Examples:
  >>> import tempfile
  >>> import pandas as pd
  >>> rows = pd.DataFrame({"loss": ["joint"] * 2, "seed": [0, 1], "iteration": [0, 0],
  ...                      "target": [0, 0], "tracking_mse": [0.25, 0.75]})
  >>> with TensorBoardWriter(tempfile.mkdtemp()) as writer:
  ...     writer(0, rows)  # as cfm_jax.train(config, progress_fn=writer) calls it
  ...     writer.written
  {'joint/tracking_mse': [(0, 0.5)]}
"""

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
    """A ``progress_fn`` that writes each iteration's metrics to a TensorBoard event file
    in ``logdir`` (see the module's text for the tags and values).

    Args:
      logdir: the folder of the event file (created); several runs may share one folder
        (TensorBoard shows each event file) or use one folder each.

    Attributes:
      logdir: the folder.
      written: every scalar written, ``{tag: [(step, value), ...]}`` in order.

    Raises:
      ImportError: tensorboardX is not installed (the message says how to install it).

    Examples:
      >>> import cfm_jax
      >>> # not run here: it trains the default config (minutes)
      >>> with TensorBoardWriter("runs/iiwa") as writer:  # doctest: +SKIP
      ...     result = cfm_jax.train(cfm_jax.Config(), progress_fn=writer)
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
        """Write the scalars of one iteration's rows (``train``'s ``progress_fn``
        signature) and flush them to the file.

        Args:
          iteration: the step.
          metrics: that iteration's rows of :attr:`cfm_jax.TrainResult.metrics` (one per
            seed and target; a ``loss`` column, else the loss is ``run``).
        """
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
