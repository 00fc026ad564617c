"""The paper's 1-D loss analysis (section III-B/C), computed: figures and a table.

Writes ``theory_landscape.png``, ``theory_iterated_map.png``, ``theory_error_curves.png``,
``theory_sweep.png``, ``theory_table.md`` and ``theory_sweep.csv`` to ``--out`` (default
``docs/figures``) and prints the markdown table. Runs in well under a minute on a CPU.

Usage:
  python experiments/theory_1d.py [--out results/theory]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax.numpy as jnp
import matplotlib
import numpy as np
import pandas as pd

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from cfm_jax.analysis import theory  # noqa: E402

DESIRED = 1.0
LINEAR = theory.TrueSystem(gain=1.0, offset=0.0, cubic=0.0)
CUBIC = theory.TrueSystem(gain=1.0, offset=0.0, cubic=0.5)
BABBLE = jnp.linspace(-1.0, 1.0, 5)
DISTAL_STEPS, LEARNING_RATE = 5, 0.05
COLORS = {"task": "tab:blue", "joint": "tab:red", "distal": "tab:green", "supervised": "tab:purple"}


def babble_fit(system):
    """Forward model and inverse controller fitted by least squares to the babbling data."""
    moments = theory.data_moments(BABBLE, theory.true_response(system, BABBLE))
    return (
        theory.fit_model(moments, theory.LinearModel()),
        theory.fit_inverse(moments, theory.AffineController()),
    )


def inner_steps_for(name):
    return DISTAL_STEPS if name == "distal" else None


def true_target_action(system):
    return float(theory.consistent_rest_action("distal", system, theory.LinearModel(), DESIRED))


# ----------------------------------------------------------------------------- figure 1


def plot_landscapes(out):
    cases = [
        ("exact model", theory.biased_model(LINEAR)),
        ("offset bias $\\hat b - b = 0.3$", theory.biased_model(LINEAR, 1.0, 0.3)),
        ("gain bias $\\hat a / a = 0.7$", theory.biased_model(LINEAR, 0.7, 0.0)),
    ]
    actions = jnp.linspace(-0.5, 2.5, 301)
    tau_run = 0.2  # the action of the last rollout; s_a = h(tau_run) is held fixed
    observed = float(theory.true_response(LINEAR, tau_run))
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), sharex=True)
    for col, (title, model) in enumerate(cases):
        for name in theory.MODEL_BASED_LOSSES:
            loss, grad = theory.loss_landscape(name, model, DESIRED, observed, actions)
            axes[0, col].plot(actions, loss, color=COLORS[name], label=name)
            axes[1, col].plot(actions, grad, color=COLORS[name], label=name)
            if name != "distal":
                rest = float(theory.rest_action(name, model, DESIRED, observed))
                for ax in axes[:, col]:
                    ax.axvline(rest, color=COLORS[name], ls=":", lw=1.5)
        for ax in axes[:, col]:
            ax.axvline(
                true_target_action(LINEAR), color="k", ls="--", lw=1, label="$h(\\tau) = s_d$"
            )
            ax.axvline(tau_run, color="gray", ls="-.", lw=1, label="$\\tau_{run}$")
        axes[1, col].axhline(0.0, color="k", lw=0.5)
        axes[0, col].set_title(title)
        axes[0, col].set_ylim(-4, 6)
        axes[1, col].set_xlabel("controller parameter $\\beta_0 = \\tau$")
    axes[0, 0].set_ylabel("loss (s_a held fixed)")
    axes[1, 0].set_ylabel("dL/d$\\tau$ (jax.grad)")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.suptitle(
        f"Loss landscapes, linear system $s_a = \\tau$, $s_d = {DESIRED}$, "
        f"$s_a = h(\\tau_{{run}}) = {observed}$ held; dotted = rest points"
    )
    fig.tight_layout()
    fig.savefig(out / "theory_landscape.png", dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- figure 2


def plot_iterated_maps(out):
    cases = [(1.5, 0.2), (0.7, 0.2), (0.45, 0.2)]
    actions = jnp.linspace(-1.0, 4.0, 201)
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    for ax, (ratio, offset) in zip(axes, cases, strict=True):
        model = theory.biased_model(LINEAR, ratio, offset)
        for name in ("task", "joint"):
            mapped = theory.iterated_action_map(name, LINEAR, model, DESIRED, actions)
            ax.plot(actions, mapped, color=COLORS[name], label=f"{name}: $T(\\tau_k)$")
        fp = theory.fixed_point("joint", LINEAR, model, DESIRED)
        trace = theory.iterate(
            "joint", LINEAR, model, theory.AffineController(-0.5, 0.0), DESIRED, num_iters=12
        )
        path = np.asarray(jnp.concatenate([trace.actions, trace.controller_offsets[-1:]]))
        xs = np.repeat(path[:-1], 2)  # cobweb: (t0, t0) -> (t0, t1) -> (t1, t1) -> ...
        ys = np.empty_like(xs)
        ys[0::2], ys[1::2] = path[:-1], path[1:]
        ax.plot(xs, ys, color="tab:red", lw=0.8, alpha=0.6)
        ax.plot(actions, actions, color="k", lw=0.7, label="$\\tau_{k+1} = \\tau_k$")
        ax.axvline(true_target_action(LINEAR), color="k", ls="--", lw=1, label="$h(\\tau) = s_d$")
        lam = float(fp.contraction)
        status = "converges" if abs(lam) < 1 else "diverges, fixed point repels"
        if abs(lam) < 1:
            ax.plot(fp.action, fp.action, "o", color="tab:red", label="joint fixed point")
        ax.set_title(
            f"$\\hat a/a = {ratio}$, $\\hat b - b = {offset}$: joint "
            f"$\\lambda = {lam:.2f}$ ({status})\n"
            f"$e^*_{{task}} = {float(theory.fixed_point('task', LINEAR, model, DESIRED).error):+.2f}$, "  # noqa: E501
            f"$e^*_{{joint}} = {float(fp.error):+.2f}$",
            fontsize=10,
        )
        ax.set_xlim(-1, 4)
        ax.set_ylim(-1, 4)
        ax.set_xlabel("$\\tau_k$ (executed in rollout k)")
    axes[0].set_ylabel("$\\tau_{k+1}$ (after training to rest, model fixed)")
    axes[0].legend(fontsize=8, loc="upper left")
    fig.suptitle(
        "Iterated map of Algorithm 1 with a fixed linear model (rollout reading), "
        "cobweb of the joint loss from $\\tau_0 = -0.5$"
    )
    fig.tight_layout()
    fig.savefig(out / "theory_iterated_map.png", dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- figure 3


def error_curve_cases():
    cubic_model, cubic_inverse = babble_fit(CUBIC)
    offset_model = theory.biased_model(LINEAR, 1.0, 0.3)
    gain_model = theory.biased_model(LINEAR, 0.6, 0.0)

    def inverse_of(model):
        return theory.AffineController(-model.offset / model.gain, 1.0 / model.gain)

    return [
        ("linear system, offset bias 0.3", LINEAR, offset_model, inverse_of(offset_model)),
        ("linear system, gain ratio 0.6", LINEAR, gain_model, inverse_of(gain_model)),
        ("cubic system $\\tau + 0.5\\tau^3$, linear fit", CUBIC, cubic_model, cubic_inverse),
    ]


def run_error_curves(num_iters=60):
    """Errors |s_a - s_d| per iteration for each case, refit mode and loss."""
    curves = {}
    for case, system, model, inverse in error_curve_cases():
        start = theory.AffineController(theory.controller_action(inverse, DESIRED), 0.0)
        for refit in theory.REFIT_MODES:
            for name in theory.THEORY_LOSSES:
                trace = theory.iterate(
                    name,
                    system,
                    model,
                    inverse if name == "supervised" else start,
                    DESIRED,
                    num_iters=num_iters,
                    refit=refit,
                    inner_steps=inner_steps_for(name),
                    learning_rate=LEARNING_RATE,
                    babble_actions=BABBLE if refit == "all" else None,
                )
                curves[case, refit, name] = np.asarray(trace.errors)
    return curves


def plot_error_curves(out, curves):
    cases = [c[0] for c in error_curve_cases()]
    fig, axes = plt.subplots(3, 3, figsize=(13, 10), sharex=True, sharey=True)
    for row, refit in enumerate(theory.REFIT_MODES):
        for col, case in enumerate(cases):
            ax = axes[row, col]
            for name in theory.THEORY_LOSSES:
                errors = np.abs(curves[case, refit, name])
                ax.semilogy(
                    np.maximum(errors, 1e-8),
                    color=COLORS[name],
                    label=name,
                    ls="--" if name == "supervised" else "-",
                )
            ax.set_ylim(1e-8, 1e2)
            if row == 0:
                ax.set_title(case, fontsize=10)
            if col == 0:
                ax.set_ylabel(f"refit = {refit!r}\n$|s_a - s_d|$ at rollout k")
            if row == 2:
                ax.set_xlabel("iteration k")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(
        "Actual error per iteration of Algorithm 1 ($s_d = 1$; distal: "
        f"{DISTAL_STEPS} steps of {LEARNING_RATE} per iteration; floor at 1e-8)"
    )
    fig.tight_layout()
    fig.savefig(out / "theory_error_curves.png", dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- sweep


def run_sweeps():
    gains = jnp.concatenate([jnp.array([-2.0, -1.0, -0.6]), jnp.linspace(0.3, 3.0, 55)])
    offsets = jnp.array([-0.3, 0.0, 0.2])
    tables = {}
    for system_name, system in (("linear", LINEAR), ("cubic", CUBIC)):
        for refit in ("none", "latest"):
            table = theory.sweep_model_bias(
                system,
                DESIRED,
                gains,
                offsets,
                refit=refit,
                num_iters=60,
                distal_steps=DISTAL_STEPS,
                learning_rate=LEARNING_RATE,
            )
            frame = pd.DataFrame({k: np.asarray(v) for k, v in table.items()})
            frame.insert(0, "refit", refit)
            frame.insert(0, "system", system_name)
            tables[system_name, refit] = frame
    return pd.concat(tables.values(), ignore_index=True)


def plot_sweep(out, sweep):
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    for ax, system_name in zip(axes[:2], ("linear", "cubic"), strict=True):
        rows = sweep[
            (sweep.system == system_name)
            & (sweep.refit == "none")
            & np.isclose(sweep.offset_error, 0.2)
            & (sweep.gain_ratio > 0)
        ]
        for name in theory.THEORY_LOSSES:
            converged = np.abs(rows[f"{name}_contraction"]) < 1
            err = np.where(converged, np.abs(rows[f"{name}_error"]), np.nan)
            ax.semilogy(
                rows.gain_ratio,
                np.maximum(err, 1e-7),
                color=COLORS[name],
                label=name,
                ls="--" if name == "supervised" else "-",
            )
        diverged = np.abs(rows.joint_contraction) >= 1
        ax.fill_between(
            rows.gain_ratio,
            1e-7,
            1e2,
            where=diverged,
            color="tab:red",
            alpha=0.1,
            label="joint diverges",
        )
        ax.set_ylim(1e-7, 1e2)
        ax.set_xlabel("model gain ratio $\\hat a / a$")
        ax.set_title(
            f"{system_name} system, fixed model, offset error 0.2:\n"
            "|fixed-point error| (blank: diverges; distal's 0 drawn at 1e-7)",
            fontsize=10,
        )
    axes[0].set_ylabel("$|h(\\tau^*) - s_d|$")
    axes[0].legend(fontsize=8)
    rows = sweep[
        (sweep.system == "linear") & np.isclose(sweep.offset_error, 0.0) & (sweep.gain_ratio > 0)
    ]
    for refit, ls in (("none", "-"), ("latest", ":")):
        part = rows[rows.refit == refit]
        for name in theory.THEORY_LOSSES:
            if refit == "none" and name == "supervised":
                continue
            axes[2].plot(
                part.gain_ratio,
                np.abs(part[f"{name}_contraction"]),
                color=COLORS[name],
                ls=ls,
                label=f"{name}, refit={refit}",
            )
    axes[2].axhline(1.0, color="k", lw=0.8)
    axes[2].set_ylim(0, 2)
    axes[2].set_xlabel("model gain ratio $\\hat a / a$")
    axes[2].set_ylabel("$|\\lambda|$ (converges iff < 1)")
    axes[2].set_title("contraction factor of the iteration, linear system", fontsize=10)
    axes[2].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out / "theory_sweep.png", dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- table


def fmt(value):
    return "diverges" if not np.isfinite(value) or abs(value) > 1e3 else f"{value:+.3f}"


def markdown_table(sweep, curves):
    lines = [
        "Fixed model (`refit='none'`), linear system `s_a = tau`, `s_d = 1`; "
        "`e*` = `h(tau*) - s_d` at the fixed point, `lam` = contraction factor "
        f"(distal: {DISTAL_STEPS} steps of {LEARNING_RATE}).",
        "",
        "| a_hat/a | b_hat-b | e*_task | e*_joint | lam_joint | e*_distal | lam_distal "
        "| e*_superv. | lam_task latest | lam_joint latest |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    lin = sweep[sweep.system == "linear"]
    for ratio in (-1.0, 0.3, 0.45, 0.6, 1.0, 1.5, 3.0):
        for offset in (0.0, 0.2):
            sel = np.isclose(lin.gain_ratio, ratio, atol=0.026) & np.isclose(
                lin.offset_error, offset
            )
            none = lin[sel & (lin.refit == "none")].iloc[0]
            latest = lin[sel & (lin.refit == "latest")].iloc[0]
            joint_err = none.joint_error if abs(none.joint_contraction) < 1 else np.nan
            distal_err = none.distal_error if abs(none.distal_contraction) < 1 else np.nan
            lines.append(
                f"| {none.gain_ratio:.2f} | {offset:+.1f} | {fmt(none.task_error)} | "
                f"{fmt(joint_err)} | {none.joint_contraction:+.3f} | {fmt(distal_err)} | "
                f"{none.distal_contraction:+.3f} | {fmt(none.supervised_error)} | "
                f"{latest.task_contraction:+.3f} | {latest.joint_contraction:+.3f} |"
            )
    lines += [
        "",
        "Iterated error `s_a - s_d` after k rollouts (cases of the error-curve figure):",
        "",
        "| case | refit | loss | k=1 | k=2 | k=5 | k=20 | k=60 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (case, refit, name), errors in curves.items():
        cells = " | ".join(
            fmt(errors[k - 1]) if abs(errors[k - 1]) >= 5e-4 else f"{errors[k - 1]:+.1e}"
            for k in (1, 2, 5, 20, 60)
        )
        lines.append(f"| {case.replace('$', '')} | {refit} | {name} | {cells} |")
    for system_name in ("linear", "cubic"):
        for sign, label in ((1, "right-sign"), (-1, "wrong-sign")):
            part = sweep[
                (sweep.system == system_name)
                & (sweep.refit == "none")
                & (np.sign(sweep.gain_ratio) == sign)
            ]
            both = (np.abs(part.joint_contraction) < 1) & (np.abs(part.task_error) > 1e-4)
            better = both & (np.abs(part.joint_error) < np.abs(part.task_error))
            lines.append("")
            lines.append(
                f"{system_name} system, fixed model, {len(part)} {label} biases (gain ratio "
                f"{part.gain_ratio.min():.1f}..{part.gain_ratio.max():.1f}, offset error "
                f"-0.3/0/+0.2): the joint iteration converges in {int(both.sum())} cases with "
                f"a nonzero task error; its error is smaller than the task loss's in "
                f"{int(better.sum())} of them."
            )
    return "\n".join(lines)


def refit_all_table():
    """Aggregated refit of a linear model of the cubic system: error after 100/400 rollouts."""
    model, inverse = babble_fit(CUBIC)
    lines = [
        "",
        "Linear model of the cubic system refitted on all data (`refit='all'`, babbling "
        "at 5 actions in [-1, 1]): `|s_a - s_d|` after k rollouts.",
        "",
        "| s_d | task k=100 | task k=400 | joint k=100 | joint k=400 | distal k=400 "
        "| superv. k=100 | superv. k=400 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for desired in (0.3, 0.6, 1.0, 1.5):
        cells = []
        for name in theory.THEORY_LOSSES:
            start = theory.AffineController(theory.controller_action(inverse, desired), 0.0)
            trace = theory.iterate(
                name,
                CUBIC,
                model,
                inverse if name == "supervised" else start,
                desired,
                num_iters=400,
                refit="all",
                inner_steps=inner_steps_for(name),
                learning_rate=LEARNING_RATE,
                babble_actions=BABBLE,
            )
            errors = np.abs(np.asarray(trace.errors))
            picks = (399,) if name == "distal" else (99, 399)
            cells += [f"{errors[k]:.1e}" if np.isfinite(errors[k]) else "diverges" for k in picks]
        lines.append(f"| {desired} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "figures"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    plot_landscapes(args.out)
    plot_iterated_maps(args.out)
    curves = run_error_curves()
    plot_error_curves(args.out, curves)
    sweep = run_sweeps()
    plot_sweep(args.out, sweep)
    sweep.to_csv(args.out / "theory_sweep.csv", index=False, float_format="%.6g")
    table = markdown_table(sweep, curves) + "\n" + refit_all_table()
    (args.out / "theory_table.md").write_text(table + "\n")
    print(table)
    print(f"\nwrote figures and table to {args.out} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
