# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Compare the four controller losses
#
# The same experiment, the iiwa learning inverse dynamics, trained with each of the four
# controller losses: the paper's **joint** loss, the **task** loss, the **distal teacher**
# and the **supervised** inverse loss ([the losses](../concepts/losses.md)). Every loss
# starts from the same babbling data and the same initial forward model, because they share
# one `Experiment`; each loss compiles its iteration once.
#
# About 6.5 minutes on two CPU cores at the default size (390 s measured while the pose scale's
# MJX inertia ran in every fit step, before its term was stored per data row on 2026-12-01; 51 s
# under the coupled torque scale, the default before it); `CFM_JAX_DOCS_QUICK=1` runs a
# reduced size (the tests do).
#
# Small runs are noisy: the full-size study (3 seeds x 10 iterations, paper-size
# networks) is on the [results page](../results.md).

# %%
import os

import matplotlib.pyplot as plt
import pandas as pd
from IPython.display import Markdown, display

import cfm_jax  # first: it sets the XLA flag before JAX starts
from cfm_jax import ControllerConfig, ForwardModelConfig, LoopConfig, TaskConfig
from cfm_jax.analysis import report
from cfm_jax.learning import losses

# %% tags=["remove-cell"]
# The tests run every notebook at a reduced size (CFM_JAX_DOCS_QUICK=1).
QUICK = os.environ.get("CFM_JAX_DOCS_QUICK") == "1"

# %%
base = cfm_jax.Config(
    robot="iiwa14",
    task=TaskConfig(duration=1.0),
    forward=ForwardModelConfig(
        hidden=(128, 128), ensemble_size=2, initial_steps=400, steps_per_iteration=100
    ),
    controller=ControllerConfig(hidden=(128, 64), initial_steps=400, steps_per_iteration=100),
    loop=LoopConfig(iterations=4, seeds=2, babbling_rollouts=2),
)

# %% tags=["remove-cell"]
if QUICK:  # the tests' reduced size
    base = cfm_jax.Config(
        robot="iiwa14",
        task=TaskConfig(duration=0.3),
        forward=ForwardModelConfig(
            hidden=(32,), ensemble_size=2, initial_steps=30, steps_per_iteration=10, batch_size=64
        ),
        controller=ControllerConfig(
            hidden=(32,), initial_steps=30, steps_per_iteration=10, batch_size=64
        ),
        # coupled: the default pose scale's MJX compile would be most of a run this short
        loop=LoopConfig(iterations=1, seeds=1, babbling_rollouts=1, torque_scale="coupled"),
    )

# %% [markdown]
# ## One run per loss, one shared experiment

# %%
experiment = cfm_jax.Experiment(base)
results = {}
for loss in losses.PAPER_LOSSES:
    results[loss] = cfm_jax.train(base.replace(loss=loss), progress=False, experiment=experiment)
    print(f"{loss:>10}: {results[loss].seconds:5.1f} s")
metrics = pd.concat([r.metrics for r in results.values()], ignore_index=True)
baselines = results["joint"].baselines

# %% [markdown]
# ## Final tracking error per loss
#
# Mean and standard deviation over seeds and targets at the last iteration, next to the
# oracle (MuJoCo's inverse dynamics) and PD-only; `rmse_over_reach` is the tracking RMSE
# as a fraction of the RMS reaching distance.

# %%
table = report.summary(metrics, baselines, results["joint"].rms_reach)
display(Markdown(report.markdown(table)))

# %% [markdown]
# ## Learning curves
#
# Tracking error, the forward model's prediction error on the new rollout, and its
# predicted task error (the paper's Fig. 3 and 4), per loss and iteration.

# %%
columns = ["tracking_mse", "prediction_error", "predicted_task_error"]
curves = metrics.groupby(["loss", "iteration"])[columns].mean()
fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
for ax, column in zip(axes, columns, strict=True):
    for loss in losses.PAPER_LOSSES:
        series = curves.loc[loss, column]
        ax.plot(series.index, series.to_numpy(), marker="o", label=loss)
    ax.set(yscale="log", xlabel="iteration", title=column)
for name, style in (("oracle", "--"), ("pd_only", ":")):
    level = baselines[baselines.baseline == name].tracking_mse.mean()
    axes[0].axhline(level, color="k", ls=style, lw=1, label=name)
axes[0].legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## Where the controllers differ
#
# The per-target final errors show whether a loss fails on some motions or on all:

# %%
final = metrics[metrics.iteration == metrics.iteration.max()]
final.pivot_table(index="target", columns="loss", values="tracking_mse", aggfunc="mean")
