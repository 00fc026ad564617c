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
# # Train the iiwa from a notebook
#
# The KUKA iiwa 14 learns an inverse-dynamics tracking controller for five reaching
# motions with the paper's **joint loss**: motor babbling, initial fits of the forward
# model and the controller, then iterations of rollout, data, refit (Algorithm 1).
# We plot the learning curves against the oracle and PD-only baselines and render a video
# of the learned controller.
#
# At its default size this notebook runs in about 3.5 minutes on two CPU cores (214 s measured
# while the pose scale's MJX inertia ran in every fit step, before its term was stored per data
# row on 2026-12-01; 51 s under the coupled torque scale, the default before it).
# `CFM_JAX_DOCS_QUICK=1` (what the tests set) runs it at a reduced size in well under a
# minute; the code path is the same.

# %%
import base64
import os
import tempfile

import matplotlib.pyplot as plt
from IPython.display import HTML, Markdown, display

import cfm_jax  # first: it sets the XLA flag before JAX starts
from cfm_jax import ControllerConfig, ForwardModelConfig, LoopConfig, TaskConfig
from cfm_jax.analysis import plots, report
from cfm_jax.runs import training
from cfm_jax.sim import render, robots

# %% tags=["remove-cell"]
# The tests run every notebook at a reduced size (CFM_JAX_DOCS_QUICK=1).
QUICK = os.environ.get("CFM_JAX_DOCS_QUICK") == "1"

# %%
OUT = tempfile.mkdtemp(prefix="cfm_jax_iiwa_")

# %% [markdown]
# ## The configuration
#
# The paper's networks (forward ensemble 3 x 400, controller 300-200-100) and 10
# iterations take about 20 minutes per loss on two cores (`cfm-jax train`). Here the
# networks and fits are smaller and the motions shorter; everything else is as in the
# paper's setup: 100 Hz control, desired joint accelerations with a PD correction
# (`kp = 100`, `kd = 20`), babbling with 10 % torque noise.

# %%
forward = ForwardModelConfig(
    hidden=(200, 200), ensemble_size=3, initial_steps=500, steps_per_iteration=150
)
controller = ControllerConfig(hidden=(200, 100), initial_steps=500, steps_per_iteration=150)
loop = LoopConfig(iterations=5, seeds=2, babbling_rollouts=2)
task = TaskConfig(duration=1.0)

# %% tags=["remove-cell"]
if QUICK:  # the tests' reduced size
    forward = ForwardModelConfig(
        hidden=(32, 32), ensemble_size=2, initial_steps=50, steps_per_iteration=20, batch_size=64
    )
    controller = ControllerConfig(
        hidden=(32, 32), initial_steps=50, steps_per_iteration=20, batch_size=64
    )
    # coupled: the default pose scale's MJX compile would be most of a run this short
    loop = LoopConfig(iterations=1, seeds=1, babbling_rollouts=1, torque_scale="coupled")
    task = TaskConfig(duration=0.3)

# %%
config = cfm_jax.Config(
    robot="iiwa14", loss="joint", task=task, forward=forward, controller=controller, loop=loop
)
config

# %% [markdown]
# ## Training
#
# `cfm_jax.train` runs every seed at once (a `vmap` axis) and returns a `TrainResult`.
# With `out_dir` it also writes `metrics.csv`, `baselines.csv`, `config.json`, the data set
# and checkpoints there.

# %%
experiment = cfm_jax.Experiment(config)  # the compiled pieces, reused for the video below
result = cfm_jax.train(config, out_dir=OUT, progress=False, experiment=experiment)
print(
    f"{result.seconds:.0f} s, of which the first iteration's compile {result.compile_seconds:.0f} s"
)
result.metrics.head()

# %% [markdown]
# ## Learning curves
#
# One row of `result.metrics` per (seed, iteration, target). Iteration 0 is the controller
# after babbling and the initial fits; iteration `i` is measured on the rollout *before* the
# models are refitted on it.

# %%
curve = result.metrics.groupby("iteration")[
    ["tracking_mse", "prediction_error", "predicted_task_error"]
].agg(["mean", "std"])
curve

# %%
baselines = result.baselines.groupby("baseline").tracking_mse.mean()
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
mean, std = curve["tracking_mse"]["mean"], curve["tracking_mse"]["std"].fillna(0)
axes[0].errorbar(mean.index, mean, yerr=std, marker="o", capsize=3, label="joint loss")
axes[0].axhline(baselines["oracle"], color="k", ls="--", label="oracle")
axes[0].axhline(baselines["pd_only"], color="gray", ls=":", label="PD-only")
axes[0].set(yscale="log", xlabel="iteration", ylabel="joint tracking MSE (rad$^2$)")
axes[0].legend()
for column in ("prediction_error", "predicted_task_error"):
    axes[1].plot(curve.index, curve[column]["mean"], marker="o", label=column)
axes[1].set(yscale="log", xlabel="iteration", ylabel="(rad/s$^2$)$^2$")
axes[1].legend()
fig.tight_layout()

# %% [markdown]
# The same table the command line prints, with the baselines and the tracking RMSE as a
# fraction of the reaching distance:

# %%
table = result.summary()  # = report.summary(result.metrics, result.baselines, result.rms_reach)
display(Markdown(report.markdown(table)))

# %% [markdown]
# `plots.plot_learning_curves` draws the library's standard figure (tracking error,
# prediction error and predicted task error per loss) and returns it (given a path, it
# also writes the image there):

# %%
plots.plot_learning_curves(
    result.metrics, os.path.join(OUT, "learning_curves.png"), baselines=result.baselines
)

# %% [markdown]
# ## A video of the learned controller
#
# `training.rollout_qpos` rolls the final controller of one seed out again (the rollout of
# the final evaluation) and returns the joint positions, `(targets, steps, nq)`;
# `render.video` renders them offscreen (EGL on a headless machine) into a GIF or an MP4.

# %%
available, why = render.render_available()
if available:
    qpos = training.rollout_qpos(result, seed=0, experiment=experiment)
    gif = os.path.join(OUT, "iiwa_target0.gif")
    every = 2
    render.video(
        robots.load("iiwa14"),
        qpos[0],
        gif,
        fps=1 / (every * config.task.control_dt),
        every=every,
        width=320,
        height=240,
        camera={"distance": 2.2, "azimuth": 120, "elevation": -20, "lookat": [0, 0, 0.6]},
        track=False,
    )
    with open(gif, "rb") as f:  # inline, as HTML: the site's pages show GIFs that way
        display(HTML(f'<img src="data:image/gif;base64,{base64.b64encode(f.read()).decode()}">'))
else:
    print("no offscreen rendering here:", why)
