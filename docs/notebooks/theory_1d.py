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
# # The 1-D theory, by hand
#
# Section III-B of the paper argues with a one-dimensional example: the **task loss** comes
# to rest where the forward model *predicts* the goal, so a biased model gives a biased
# controller; the **joint loss** comes to rest half-way between the goal and what was
# observed, and iterating data collection pushes the observed state to the goal.
# `cfm_jax.analysis.theory` makes each step computable. The full study, with figures for many
# biases, is [The 1-D theory](../theory.md).
#
# Runs in well under a minute (6 s measured), so the tests run it at this size too
# (`CFM_JAX_DOCS_QUICK=1` changes nothing here).

# %%
import jax.numpy as jnp
import matplotlib.pyplot as plt
import pandas as pd

import cfm_jax  # noqa: F401  (first: it sets the XLA flag before JAX starts)
from cfm_jax.analysis import theory

# %% [markdown]
# ## A biased model of a linear system
#
# True system $s_a = h(\tau) = a\tau + b$ with $a = 1$, $b = 0$; the forward model
# $f(\tau) = \hat a \tau + \hat b$ has the right gain and an offset error of 0.3. The goal is
# $s_d = 1$, and the last rollout executed $\tau_{run} = 0.2$.

# %%
system = theory.TrueSystem(gain=1.0, offset=0.0)
model = theory.biased_model(system, gain_ratio=1.0, offset_error=0.3)
desired, tau_run = 1.0, 0.2
observed = float(theory.true_response(system, tau_run))
print(model, "observed s_a =", observed)

# %% [markdown]
# ## Where each loss comes to rest, with $s_a$ held fixed
#
# The losses are the library's own (`cfm_jax.learning.losses`), differentiated with `jax.grad`
# through $f \circ g$. Task: $f(\tau) = s_d$. Joint: $f(\tau) = (s_d + s_a)/2$. The distal
# teacher's loss is linear in $s_p$ and has no rest point.

# %%
actions = jnp.linspace(-0.5, 2.0, 301)
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharex=True)
for name in theory.MODEL_BASED_LOSSES:
    loss, grad = theory.loss_landscape(name, model, desired, observed, actions)
    axes[0].plot(actions, loss, label=name)
    axes[1].plot(actions, grad, label=name)
    if name != "distal":
        rest = float(theory.rest_action(name, model, desired, observed))
        print(f"{name:>6} rests at tau = {rest:.3f}, where the robot reaches "
              f"{float(theory.true_response(system, rest)):.3f} (goal {desired})")  # fmt: skip
        for ax in axes:
            ax.axvline(rest, ls=":", color=ax.lines[-1].get_color())
axes[0].set(xlabel=r"action $\tau$", ylabel="loss")
axes[1].set(xlabel=r"action $\tau$", ylabel=r"$\partial L / \partial \beta_0$")
axes[1].axhline(0, color="k", lw=0.5)
axes[0].legend()
fig.tight_layout()

# %% [markdown]
# ## Iterating Algorithm 1
#
# Roll out, observe, update the controller, repeat. With the model never refitted
# (`refit="none"`), the task loss stays exactly as wrong as the model, while the joint loss
# iterates to a fixed point with the error $e_{task} \cdot 2\hat a / (2\hat a - a)$: here
# *larger*. With the model's offset refitted on the latest observation (`refit="latest"`),
# both go to the goal, the joint loss more slowly (contraction $1 - a/(2\hat a)$).

# %%
iterations = 30
start = theory.AffineController(offset=float(theory.rest_action("task", model, desired, 0.0)))
rows = []
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
for ax, refit in zip(axes, ("none", "latest"), strict=True):
    for name in ("task", "joint"):
        trace = theory.iterate(name, system, model, start, desired, num_iters=iterations,
                               refit=refit)  # fmt: skip
        ax.plot(jnp.abs(trace.errors), marker=".", label=name)
        point = theory.fixed_point(name, system, model, desired, refit=refit)
        rows.append({"refit": refit, "loss": name, "last error": float(trace.errors[-1]),
                     "fixed-point error": float(point.error),
                     "contraction": float(point.contraction)})  # fmt: skip
    ax.set(yscale="log", xlabel="iteration", title=f'refit="{refit}"')
axes[0].set_ylabel(r"$|s_a - s_d|$")
axes[0].legend()
fig.tight_layout()
pd.DataFrame(rows)

# %% [markdown]
# The closed forms say the same: with a fixed model the task loss's error is the model's
# offset error mapped through the system, the joint loss's is twice that here
# ($2\hat a / (2\hat a - a) = 2$); with the offset refitted, the errors shrink by the
# contraction factor every iteration.

# %% [markdown]
# ## Many biases at once
#
# `theory.sweep_model_bias` computes fixed points and iterated errors for a grid of model
# biases in one `vmap`: where is the joint loss better than the task loss?

# %%
n = 21
sweep = theory.sweep_model_bias(
    system, desired, jnp.linspace(0.6, 1.6, n), jnp.linspace(-0.3, 0.3, n), refit="latest",
    num_iters=iterations,
)  # fmt: skip
table = pd.DataFrame({k: jnp.asarray(v) for k, v in sweep.items()})
table["joint better"] = table.joint_iterated_error.abs() < table.task_iterated_error.abs()
table.pivot_table(index="gain_ratio", columns="offset_error", values="joint better").round(2)
