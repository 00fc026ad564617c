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
# # Bring your own robot: a two-link arm
#
# Any MJCF model with one torque motor per joint can be a cfm_jax robot
# ([the requirements](../how-to/own-robot.md)). This notebook writes a planar two-link arm
# from scratch, checks it, looks at it, and learns a tracking controller for it with the
# joint loss. Under a minute on two CPU cores (39 s measured; `CFM_JAX_DOCS_QUICK=1`: less).

# %%
import base64
import os
import pathlib
import tempfile

import numpy as np
from IPython.display import HTML, Image, Markdown, display

import cfm_jax  # first: it sets the XLA flag before JAX starts
from cfm_jax import ControllerConfig, ForwardModelConfig, LoopConfig, TaskConfig
from cfm_jax.analysis import report
from cfm_jax.runs import training
from cfm_jax.sim import render, robots
from cfm_jax.tasks import references

# %% tags=["remove-cell"]
# The tests run every notebook at a reduced size (CFM_JAX_DOCS_QUICK=1).
QUICK = os.environ.get("CFM_JAX_DOCS_QUICK") == "1"

# %%
OUT = pathlib.Path(tempfile.mkdtemp(prefix="cfm_jax_own_robot_"))

# %% [markdown]
# ## The model
#
# Two hinges about the vertical axis (the arm moves in a horizontal plane), capsule links
# whose inertia MuJoCo computes from their mass, one `<motor>` per joint with a
# `ctrlrange` (the torque limit), and a `home` keyframe (the start of every motion).

# %%
MJCF = """
<mujoco model="my_arm">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <default>
    <joint type="hinge" axis="0 0 1" range="-2.5 2.5" damping="0.05" armature="0.01"/>
    <geom type="capsule" size="0.03" contype="0" conaffinity="0"/>
  </default>
  <worldbody>
    <light pos="0 0 3"/>
    <geom type="plane" size="1 1 0.01" rgba="0.8 0.8 0.8 1"/>
    <body name="upper" pos="0 0 0.1">
      <joint name="shoulder"/>
      <geom fromto="0 0 0 0.4 0 0" mass="1.0" rgba="0.2 0.45 0.8 1"/>
      <body name="fore" pos="0.4 0 0">
        <joint name="elbow"/>
        <geom fromto="0 0 0 0.3 0 0" mass="0.5" rgba="0.9 0.5 0.15 1"/>
        <site name="ee" pos="0.3 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" ctrlrange="-5 5"/>
    <motor joint="elbow" ctrlrange="-3 3"/>
  </actuator>
  <keyframe>
    <key name="home" qpos="0.3 0.6"/>
  </keyframe>
</mujoco>
"""
path = OUT / "my_arm.xml"
path.write_text(MJCF)

robot = robots.load(str(path))
print("joints", robot.joint_names, "nq", robot.nq, "action_dim", robot.action_dim)
print("torque limits", robot.torque_limit, "home", robot.home, "timestep", robot.timestep)

# %% [markdown]
# `robots.load` refuses models the controller cannot drive, and says why. A position
# servo instead of a motor, for example:

# %%
bad = OUT / "servo_arm.xml"
bad.write_text(MJCF.replace('<motor joint="elbow"', '<position kp="50" joint="elbow"'))
try:
    robots.load(str(bad))
except robots.RobotError as error:
    print("RobotError:", error)

# %% [markdown]
# ## The reaching motions
#
# Without `task.targets`, five targets are placed inside the joint ranges around home; the
# references are quintic paths to them. A picture of the first motion, five frames from
# above:

# %%
task = TaskConfig(duration=1.5)

# %% tags=["remove-cell"]
if QUICK:  # the tests' reduced size
    task = TaskConfig(duration=0.5)

# %%
reference = references.reaching(robot, task, control_dt=task.control_dt)
print("reference q:", reference.q.shape, "(targets, steps + 1, nq)")
top_view = {"distance": 1.6, "azimuth": 90.0, "elevation": -89.0, "lookat": [0.2, 0.0, 0.1]}
available, why = render.render_available()
if available:
    strip = OUT / "reference_strip.png"
    render.frame_strip(
        robot.mj_model, reference.q[0], strip, n_frames=5, width=200, height=160,
        camera=top_view, track=False,
    )  # fmt: skip
    display(Image(filename=str(strip)))
else:
    print("no offscreen rendering here:", why)

# %% [markdown]
# ## Learn a controller for it

# %%
forward = ForwardModelConfig(
    hidden=(128, 128), ensemble_size=3, initial_steps=500, steps_per_iteration=150
)
controller = ControllerConfig(hidden=(128, 64), initial_steps=500, steps_per_iteration=150)
loop = LoopConfig(iterations=5, seeds=2, babbling_rollouts=2)

# %% tags=["remove-cell"]
if QUICK:  # the tests' reduced size
    forward = ForwardModelConfig(
        hidden=(32, 32), ensemble_size=2, initial_steps=50, steps_per_iteration=20, batch_size=64
    )
    controller = ControllerConfig(
        hidden=(32, 32), initial_steps=50, steps_per_iteration=20, batch_size=64
    )
    loop = LoopConfig(iterations=1, seeds=1, babbling_rollouts=1)

# %%
config = cfm_jax.Config(
    robot=str(path), loss="joint", task=task, forward=forward, controller=controller, loop=loop
)
experiment = cfm_jax.Experiment(config)
result = cfm_jax.train(config, progress=False, experiment=experiment)
display(Markdown(report.markdown(result.summary())))

# %%
result.metrics.groupby("iteration").tracking_mse.agg(["mean", "std"])

# %% [markdown]
# ## The learned controller, in motion
#
# Reference (left) and the learned controller (right) on the first target, from above.

# %%
if available:
    qpos = training.rollout_qpos(result, seed=0, experiment=experiment)[0]
    steps = len(qpos)
    frames = np.concatenate(
        [
            render.render_frames(robot.mj_model, reference.q[0, :steps], width=240, height=180,
                                 camera=top_view, track=False),
            render.render_frames(robot.mj_model, qpos, width=240, height=180,
                                 camera=top_view, track=False),
        ],
        axis=2,
    )  # fmt: skip
    every = 3
    gif = render.write_video(frames[::every], OUT / "my_arm.gif", fps=1 / (every * task.control_dt))
    with open(str(gif), "rb") as f:  # inline, as HTML: the site's pages show GIFs that way
        display(HTML(f'<img src="data:image/gif;base64,{base64.b64encode(f.read()).decode()}">'))
