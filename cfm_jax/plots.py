"""Every figure of the library (matplotlib, imported when a figure is drawn): learning curves
of training results and the foot forces of a legged reference. The numbers they draw come
from :mod:`cfm_jax.report` (tables, statistics) and :mod:`cfm_jax.locomotion`.

Examples:
  >>> from cfm_jax import plots
  >>> plots.plot_foot_force.__name__
  'plot_foot_force'
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cfm_jax import solo12

if TYPE_CHECKING:
    from cfm_jax.locomotion import LocomotionReference


def _pyplot():
    """matplotlib's pyplot on the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ---- legged references -----------------------------------------------------------------------


def plot_foot_force(
    ref: LocomotionReference,
    path: str | os.PathLike,
    *,
    observed: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    foot: str = "FR",
    title: str | None = None,
):
    """Plot desired (``ref.foot_force``) vs observed (and optionally predicted) force of one
    foot over time, one panel per world axis, like the paper's Fig. 6; saves a PNG. The
    force arrays are ``(T+1, 4, 3)`` (or ``(T, 4, 3)`` for the states after each step).

    Args:
      ref: the :class:`cfm_jax.locomotion.LocomotionReference` (its ``foot_force`` is the
        desired force).
      path: the image file to write (its folder is created).
      observed: ``(T+1, 4, 3)`` or ``(T, 4, 3)`` observed forces, or None.
      predicted: forces of the same shape predicted by a model, or None.
      foot: ``"FL"``, ``"FR"``, ``"HL"`` or ``"HR"``.
      title: the figure's title (None: the kind and foot).

    Examples:
      >>> import os, tempfile
      >>> from cfm_jax import locomotion
      >>> ref = locomotion.walk_reference(0.2, use_cache=False)
      >>> with tempfile.TemporaryDirectory() as folder:
      ...     path = os.path.join(folder, "force.png")
      ...     plot_foot_force(ref, path, observed=locomotion.replay(ref).foot_force)
      ...     os.path.getsize(path) > 0
      True
    """
    plt = _pyplot()
    leg = solo12.LEGS.index(foot)
    t = np.arange(len(ref.foot_force)) * ref.control_dt
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    curves = [("desired", ref.foot_force, dict(color="k", lw=2.0, alpha=0.6))]
    if observed is not None:
        curves.append(("observed", np.asarray(observed), dict(color="C0", lw=1.2)))
    if predicted is not None:
        curves.append(("predicted", np.asarray(predicted), dict(color="C3", lw=1.0, ls="--")))
    for axis, ax in enumerate(axes):
        for label, force, style in curves:
            ax.plot(t[-len(force) :], force[:, leg, axis], label=label, **style)
        ax.set_ylabel(f"f{'xyz'[axis]} [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or f"{ref.kind}: contact force of the {foot} foot (world frame)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
