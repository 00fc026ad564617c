"""The paper's claims, one verdict each, from the committed records (nothing is trained here).

Reads:

* the comparison's cell records (``experiments/comparison.py``,
  ``docs/results/comparison/cells/<task>/<cell>/``): per task the four losses at the shared
  library defaults (``shared``) and each loss at its own search's choice (``own-<loss>``),
  10 seeds x the task's test motions: the headline. Until a task's 10-seed shared cell has
  run, the robustness study's 5-seed default cell stands in for it (the page says so);
  until all four own cells of a task have run, "each at its best" is "not run yet";
* the robustness study's other cells (``docs/results/robustness/cells``; 3-5 seeds):
  exploratory, which loss is lowest in each (no interval, no verdict);
* the data-set swap, ``docs/results/swap/swap_metrics.csv`` (``swap_study.py``);
* the 1-D theory, recomputed (``theory_1d.run_sweeps``, seconds).

and writes ``docs/results/claims.md`` (and ``claims_profiles.png``). Statistics
(:mod:`cfm_jax.stats`, rliable's definitions): per loss the interquartile mean (IQM) of its
runs' scores, orders of magnitude below PD-only (a failed run at most -3), with a 95%
stratified bootstrap interval (runs: seeds, strata: test motions) and the probability that
a joint-loss run beats a run of each other loss; per claim the paired comparisons over the
same seeds (IQM of the per-seed differences of log10 errors, each seed averaged over its
motions), all the page's comparisons corrected together (Holm, family-wise 5%), each
interval at the level Holm tests it at. A verdict follows a fixed rule (:data:`RULE`), the
same for every claim, loss and configuration, so no verdict is a judgement call.

Usage:
  python experiments/claims.py
  python experiments/claims.py --comparison DIR --records DIR --swap FILE --out FILE
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import numpy as np
import pandas as pd

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import comparison  # noqa: E402
import robustness_study  # noqa: E402
import select_defaults  # noqa: E402

from cfm_jax import report, stats  # noqa: E402

RULE = (
    "A claim that loss A beats loss B *reproduces* when the comparison A - B (the IQM over "
    "seeds of the per-seed difference of log10 errors) is clearly below 0 for every B the "
    "claim names, *does not reproduce* when it is clearly above 0 for some B (B clearly "
    "better), and is *not resolved* otherwise. Clearly: Holm's correction over all the "
    "comparisons on this page rejects 'no difference' at a family-wise 5% (the interval "
    "shown, at the level Holm tests that comparison at, excludes 0). A claim of no "
    "difference reproduces when the difference is not clear. A claim is judged on each "
    "configuration apart (the shared defaults; each loss at its own search's best)."
)
OTHERS = ("task", "distal", "supervised")
LOSSES = ("joint", *OTHERS)
ARMS = {"shared": "shared defaults", "own": "each at its best"}
STATISTIC = "iqm"
ALPHA = 0.05
REPS = 4000
"""Bootstrap resamples per comparison and interval (fixed seed 0: the page is regenerated
bit for bit)."""
FAILED_SCORE = -float(np.log10(select_defaults.FAILURE_FACTOR))
"""A failed run's highest score (fell or diverged): the selection rule's floor, 3 orders of
magnitude above PD-only."""


@dataclasses.dataclass
class Arm:
    """One configuration of a task's headline: its metrics (every loss), the PD-only and
    oracle baselines of the task's test motions and where the records came from."""

    metrics: pd.DataFrame
    baselines: pd.DataFrame
    source: str

    @property
    def seeds(self) -> int:
        return int(self.metrics.seed.nunique())


def _read(folder: str) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    if not os.path.isfile(os.path.join(folder, "metrics.csv")):
        return None
    return (pd.read_csv(os.path.join(folder, "metrics.csv")),
            pd.read_csv(os.path.join(folder, "baselines.csv")))  # fmt: skip


def records(out: str):
    """The finished cells of the robustness study: {cell: (metrics, baselines)}."""
    found = {}
    for cell in robustness_study.CELLS:
        record = _read(robustness_study.record_dir(out, cell))
        if record is not None:
            found[cell] = record
    return found


def _same_baselines(task: str, loss: str, own: pd.DataFrame, shared: pd.DataFrame) -> None:
    """Both configurations are scored against one PD-only: an own cell's (of the same test
    motions) must be the shared cell's. (The oracle's may differ with ``s*``.)"""
    key = ["baseline", "target"]
    a, b = (f[f.baseline == "pd_only"].set_index(key).sort_index() for f in (own, shared))
    if not (a.index.equals(b.index) and np.allclose(a.tracking_mse, b.tracking_mse, rtol=1e-6)):
        raise ValueError(
            f"{task}: the own-{loss} cell's PD-only differs from the shared cell's (other "
            "test motions or gains?): the two cannot be compared"
        )


def _same_runs(own: pd.DataFrame, shared: pd.DataFrame) -> str:
    """A note naming the losses whose own cell is the shared cell's run (the same sweep cell,
    ``cfm_jax.sweeps.cell_id``: the same config), or ``""``."""
    if "cell" not in own or "cell" not in shared:
        return ""
    same = [n for n in LOSSES
            if set(own[own.loss == n].cell) == set(shared[shared.loss == n].cell)]  # fmt: skip
    if not same:
        return ""
    return (f" ({', '.join(same)}: their search chose the shared defaults, so these are the "
            "shared cell's runs)")  # fmt: skip


def arms(comparison_dir: str, robustness: dict) -> dict:
    """``{task: {"shared": Arm | None, "own": Arm | None}}`` from the comparison's records
    (the robustness study's default cell standing in for a shared cell not run yet)."""
    out = {}
    for task in comparison.TASKS:
        cell = comparison.Cell(task, comparison.SHARED, LOSSES)
        shared = _read(comparison.record_dir(comparison_dir, cell))
        if shared is not None:
            shared = Arm(*shared, "the comparison's shared cell")
        else:
            default = [c for c in robustness if c.task == task and c.default]
            shared = Arm(*robustness[default[0]], "the robustness study's default cell (the "
                         "10-seed shared cell has not run yet)") if default else None  # fmt: skip
        own = [_read(comparison.record_dir(comparison_dir, comparison.Cell(task, f"own-{n}", (n,))))
               for n in LOSSES]  # fmt: skip
        if shared is not None and all(r is not None for r in own):
            for loss, (_, baselines) in zip(LOSSES, own, strict=True):
                _same_baselines(task, loss, baselines, shared.baselines)
            metrics = pd.concat([m for m, _ in own], ignore_index=True)
            own_arm = Arm(metrics, shared.baselines, "the comparison's own cells" +
                          _same_runs(metrics, shared.metrics))  # fmt: skip
        else:
            own_arm = None
        out[task] = {"shared": shared, "own": own_arm}
    return out


def per_seed(arm: Arm, column: str, over: str = "last") -> dict[str, pd.Series]:
    """Each loss's log10 error per seed: ``column`` per run (the tracking MSE with a failed
    run's floor, :func:`select_defaults.scores`; other columns, and runs without baselines,
    plain, non-finite runs skipped), averaged over the seed's motions at the last iteration
    (``over="last"``) or over its motions and all iterations (``"all"``: the paper's "during
    learning")."""
    metrics = arm.metrics
    if column == "tracking_mse" and arm.baselines is not None:
        frame = select_defaults.scores(metrics, arm.baselines)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.log10(metrics[column].astype(float))
        frame = metrics.assign(score=values.where(np.isfinite(values)))
    if over == "last":
        frame = frame[frame.iteration == frame.iteration.max()]
    means = frame.groupby(["loss", "seed"])["score"].mean()
    return {loss: means[loss].dropna() for loss in LOSSES if loss in means.index.levels[0]}


def run_scores(arm: Arm) -> dict[str, np.ndarray]:
    """Per loss its runs' scores at the last iteration, ``(seeds, motions)``: orders of
    magnitude below PD-only (:func:`cfm_jax.stats.score`), a failed run at most
    :data:`FAILED_SCORE`."""
    frame = select_defaults.scores(arm.metrics, arm.baselines)
    frame = frame[frame.iteration == frame.iteration.max()]
    pd_only = arm.baselines[arm.baselines.baseline == "pd_only"].set_index("target")
    frame = frame.assign(orders=np.log10(frame.target.map(pd_only.tracking_mse)) - frame.score)
    table = {loss: f.pivot(index="seed", columns="target", values="orders").to_numpy()
             for loss, f in frame.groupby("loss")}  # fmt: skip
    return {loss: table[loss] for loss in LOSSES if loss in table}


class Family:
    """All the paired comparisons of the page, corrected together (Holm)."""

    def __init__(self):
        self.differences: dict[str, np.ndarray] = {}
        self.table = None

    def add(self, name: str, a: pd.Series, b: pd.Series) -> str:
        common = a.index.intersection(b.index)
        self.differences[name] = (a[common] - b[common]).to_numpy()
        return name

    def solve(self) -> None:
        table = stats.paired_comparisons(self.differences, STATISTIC, ALPHA, REPS)
        self.table = table.set_index("comparison")

    def sign(self, name: str) -> int:
        """-1 or +1: clearly below or above 0; 0: not clear."""
        row = self.table.loc[name]
        return int(np.sign(row.point)) if row.clear else 0

    def text(self, name: str, label: str) -> str:
        row = self.table.loc[name]
        clear = " clear" if row.clear else ""
        return (f"{label} {row.point:+.2f} [{row.low:+.2f}, {row.high:+.2f}] "
                f"({100 * row.confidence:.2f}%{clear})")  # fmt: skip


def beats_verdict(signs) -> str:
    """The rule's verdict on "the winner is lower than each loser" from the comparisons'
    signs (-1: clearly lower, +1: clearly higher, 0: not clear)."""
    if any(s > 0 for s in signs):
        return "does not reproduce"
    return "reproduces" if signs and all(s < 0 for s in signs) else "not resolved"


def success_verdict(arm: Arm) -> tuple[str, str]:
    """Fig. 5's "only the joint loss succeeds": at the last iteration the joint loss has no
    fallen run and every other loss has some (counts over seeds x motions, no interval)."""
    final = arm.metrics[arm.metrics.iteration == arm.metrics.iteration.max()]
    falls = final.assign(failed=report.failed_runs(final)).groupby("loss").failed.sum()
    runs = final.groupby("loss").size()
    ok = falls.get("joint", 1) == 0 and all(falls.get(n, 0) > 0 for n in OTHERS)
    text = ", ".join(f"{n} {int(falls.get(n, 0))}/{int(runs.get(n, 0))}" for n in LOSSES)
    return ("reproduces" if ok else "does not reproduce"), text


def exploratory(robustness: dict, task: str, column: str, over: str) -> str:
    """Which loss has the lowest mean log10 error in each of the robustness study's other
    cells of ``task`` (3-5 seeds; no interval, no verdict)."""
    lowest = {}
    for cell, (metrics, baselines) in robustness.items():
        if cell.task != task or cell.default:
            continue
        values = per_seed(Arm(metrics, baselines, ""), column, over)
        if not values:
            continue
        best = min(values.items(), key=lambda kv: kv[1].mean())[0]
        name = f"before the selection run, {cell.name}" if cell.before_selection else cell.name
        lowest.setdefault(best, []).append(name)
    if not lowest:
        return ""
    return "robustness cells, lowest: " + "; ".join(
        f"{loss} in {', '.join(names)}" for loss, names in sorted(lowest.items())
    )


def failures_text(metrics) -> str:
    """The failed runs per loss at the last iteration under the library's one rule
    (:func:`cfm_jax.report.failed_runs`: fell, or the simulation diverged), beside every
    claim's means; the diverged ones are named apart when there are any."""
    final = metrics[metrics.iteration == metrics.iteration.max()]
    final = final.assign(failed=report.failed_runs(final), div=report.diverged_runs(final))
    parts = []
    for loss, f in final.groupby("loss", sort=False):
        part = f"{loss} {int(f.failed.sum())}/{len(f)}"
        if f["div"].any():
            part += f" ({int(f['div'].sum())} diverged)"
        parts.append(part)
    what = "fell or diverged" if "fell" in final.columns else "diverged"
    return f"failed at the last iteration ({what}): " + ", ".join(parts)


def _combined(verdicts) -> str:
    """One verdict of a claim with several parts: theirs when they agree, else "mixed"
    (the numbers column gives each part's)."""
    return verdicts[0] if len(set(verdicts)) == 1 else "mixed: " + ", ".join(verdicts)


THEORY_RULE = (
    "The 1-D claim *reproduces* when, over the model biases where the joint iteration "
    "converges and the task loss leaves an error (|task error| > 1e-4), the joint loss ends "
    "closer to s_d than the task loss in every one; *does not reproduce* when in none; is "
    "*mixed* when in some; and is *not resolved* when there is no such bias."
)


def theory_verdict(cases: int, closer: int) -> str:
    """The verdict of the 1-D claim by :data:`THEORY_RULE`: ``cases`` biases where the joint
    iteration converges and the task loss leaves an error, in ``closer`` of which the joint
    loss ends closer to s_d."""
    if not 0 <= closer <= cases:
        raise ValueError(f"closer={closer}: between 0 and cases={cases}")
    if cases == 0:
        return "not resolved"
    if closer == cases:
        return "reproduces"
    return "does not reproduce" if closer == 0 else "mixed"


def theory_claim():
    import theory_1d

    sweep = theory_1d.run_sweeps()
    lines, cases, closer = [], 0, 0
    for system in ("linear", "cubic"):
        part = sweep[(sweep.system == system) & (sweep.refit == "none") & (sweep.gain_ratio > 0)]
        both = (np.abs(part.joint_contraction) < 1) & (np.abs(part.task_error) > 1e-4)
        better = both & (np.abs(part.joint_error) < np.abs(part.task_error))
        cases, closer = cases + int(both.sum()), closer + int(better.sum())
        lines.append(
            f"{system} system, fixed right-sign model: the joint iteration converges in "
            f"{int(both.sum())} biases with a nonzero task error and ends closer to s_d "
            f"than the task loss in {int(better.sum())}"
        )
    return theory_verdict(cases, closer), lines


RANKING = (
    ("Fig. 3a", "iiwa inverse dynamics: the joint loss converges faster and more stably than "
     "the others and learns a very good tracking controller in < 10 iterations",
     "inverse_dynamics", "tracking_mse", "last"),
    ("Fig. 3a (during learning)", "the same, over the iterations", "inverse_dynamics",
     "tracking_mse", "all"),
    ("Fig. 3b", "iiwa op-space: the joint loss outperforms the others; supervised learning "
     "is unsatisfactory (redundancy)", "opspace", "tracking_mse", "last"),
)  # fmt: skip
LEGGED = ("walk", "jump")


def _ranking(family, tasks, claim, task, column, over) -> dict:
    parts = {}
    for key, arm in tasks[task].items():
        if arm is None:
            parts[key] = None
            continue
        values = per_seed(arm, column, over)
        parts[key] = [
            (
                family.add(f"{claim} | {key} | joint - {n}", values["joint"], values[n]),
                f"joint - {n}",
            )
            for n in OTHERS
        ]
    return parts


def _fig4(family, tasks, task) -> dict:
    parts = {}
    for key, arm in tasks[task].items():
        if arm is None:
            parts[key] = None
            continue
        error = per_seed(arm, "prediction_error", "all")
        predicted = per_seed(arm, "predicted_task_error", "all")
        claim = f"Fig. 4 ({task}) | {key}"
        parts[key] = [
            (family.add(f"{claim} | prediction", error["joint"], error["task"]),
             "prediction error joint - task"),
            (family.add(f"{claim} | predicted", predicted["task"], predicted["joint"]),
             "predicted task error task - joint"),
        ]  # fmt: skip
    return parts


def _swap(family, path: str):
    """The data-set swap's comparisons (5 seeds, on the defaults of its time): per retraining
    loss the joint-loss data minus the task-loss data; per data set the joint minus the task
    retrain."""
    if not os.path.isfile(path):
        return None
    metrics = pd.read_csv(path)
    values = {d: per_seed(Arm(f, None, "swap"), "tracking_mse")
              for d, f in metrics.groupby("data")}  # fmt: skip
    better = [(family.add(f"Fig. 3c | retrained with {loss}", values["joint"][loss],
                          values["task"][loss]),
               f"retrained with {loss}: joint-loss data - task-loss data")
              for loss in ("task", "joint")]  # fmt: skip
    similar = [(family.add(f"Fig. 3c | on the {d}-loss data", values[d]["joint"],
                           values[d]["task"]), f"on the {d}-loss data: joint - task retrain")
               for d in ("task", "joint")]  # fmt: skip
    return better, similar, int(metrics.seed.nunique())


def _measured(family, parts) -> tuple[dict, str]:
    """Per configuration the rule's verdict, and the comparisons' text."""
    verdicts, lines = {}, []
    for key, names in parts.items():
        if names is None:
            verdicts[key] = "not run yet"
            continue
        verdicts[key] = beats_verdict([family.sign(n) for n, _ in names])
        lines.append(f"{ARMS[key]}: " + "; ".join(family.text(n, label) for n, label in names))
    return verdicts, "<br>".join(lines)


def _agreement(verdicts: dict) -> str:
    if "not run yet" in verdicts.values():
        return ""
    return "agree" if len(set(verdicts.values())) == 1 else "**disagree**"


def headline_table(task: str, pair: dict) -> list[str]:
    """Per loss and configuration the IQM score [95% CI], failed runs and P(joint > loss)."""
    lines = [f"### {task}", ""]
    for key, arm in pair.items():
        if arm is not None:
            lines.append(f"- {ARMS[key]}: {arm.source}, {arm.seeds} seeds x "
                         f"{arm.metrics.target.nunique()} test motions")  # fmt: skip
    lines += ["", "| loss | " + " | ".join(f"{ARMS[k]}: IQM [95% CI] | failed | P(joint > loss)"
                                         for k in pair) + " |",
              "|---|" + "---|---|---|" * len(pair)]  # fmt: skip
    cells = {}
    for key, arm in pair.items():
        if arm is None:
            cells[key] = {n: ("not run yet", "", "") for n in LOSSES}
            continue
        scores = run_scores(arm)
        est = stats.interval_estimates(scores, statistic=STATISTIC).set_index("method")
        final = arm.metrics[arm.metrics.iteration == arm.metrics.iteration.max()]
        failed = final.assign(f=report.failed_runs(final)).groupby("loss").f.agg(["sum", "size"])
        cells[key] = {}
        for n in LOSSES:
            p = (
                ""
                if n == "joint"
                else "{:.2f} [{:.2f}, {:.2f}]".format(
                    *stats.probability_of_improvement(scores["joint"], scores[n])
                )
            )
            cells[key][n] = (
                f"{est.point[n]:.2f} [{est.low[n]:.2f}, {est.high[n]:.2f}]",
                f"{int(failed.loc[n, 'sum'])}/{int(failed.loc[n, 'size'])}",
                p,
            )
    for n in LOSSES:
        lines.append(f"| {n} | " + " | ".join(" | ".join(cells[k][n]) for k in pair) + " |")
    return lines + [""]


def profiles(tasks: dict, path: str) -> None:
    """The performance profiles (rliable): per task the fraction of runs above each score,
    solid the shared defaults, dashed each at its best."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(tasks), figsize=(4 * len(tasks), 3.2), sharey=True)
    taus = np.linspace(-3, 6, 91)
    for ax, (task, pair) in zip(np.atleast_1d(axes), tasks.items(), strict=True):
        for key, style in (("shared", "-"), ("own", "--")):
            if pair[key] is None:
                continue
            frame = stats.performance_profile(run_scores(pair[key]), taus, reps=500)
            for k, (loss, f) in enumerate(frame.groupby("method", sort=False)):
                ax.plot(f.threshold, f.fraction, style, color=f"C{k}",
                        label=f"{loss} ({ARMS[key]})")  # fmt: skip
                ax.fill_between(f.threshold, f.low, f.high, color=f"C{k}", alpha=0.1)
        ax.set(title=task, xlabel="score tau (orders of magnitude below PD-only)")
        ax.axvline(0, color="grey", lw=0.5)
    np.atleast_1d(axes)[0].set_ylabel("fraction of runs with score > tau")
    np.atleast_1d(axes)[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)


def _plans(family: Family, tasks: dict, robustness: dict) -> list[tuple]:
    """The claims on the headline cells, in the page's order, as (claim, what the paper
    says, its parts, the exploratory note); their comparisons are added to ``family``."""
    plans = []
    for claim, paper, task, column, over in RANKING:
        plans.append((claim, paper, _ranking(family, tasks, claim, task, column, over),
                      exploratory(robustness, task, column, over)))  # fmt: skip
    for task in LEGGED:
        plans.append((f"Fig. 5 ({task})", f"Solo12 {task}: the joint loss tracks the base best",
                      _ranking(family, tasks, f"Fig. 5 ({task})", task, "tracking_mse", "last"),
                      exploratory(robustness, task, "tracking_mse", "last")))  # fmt: skip
        plans.append((f"Fig. 5 ({task}, success)", f"Solo12 {task}: only the joint loss "
                      "succeeds", "success", ""))  # fmt: skip
        plans.append((f"Table I ({task})", f"Solo12 {task}: the joint loss tracks the foot "
                      "forces best", _ranking(family, tasks, f"Table I ({task})", task,
                                              "force_mse", "last"),
                      exploratory(robustness, task, "force_mse", "last")))  # fmt: skip
        plans.append((f"Fig. 4 ({task})", f"Solo12 {task}: during learning the joint loss's "
                      "forward-model prediction error is lower than the task loss's, whose "
                      "predicted task error is lower", _fig4(family, tasks, task), ""))  # fmt: skip
    return plans


def _claim_row(family: Family, tasks: dict, claim, paper, parts, where) -> tuple:
    """One claim's row of the table (``family`` solved): its verdict in each configuration,
    what was measured and the notes."""
    if parts == "success":
        task = claim.split("(")[1].split(",")[0]
        verdicts, lines = {}, []
        for key, arm in tasks[task].items():
            if arm is None:
                verdicts[key] = "not run yet"
                continue
            verdicts[key], text = success_verdict(arm)
            lines.append(f"{ARMS[key]}: failed runs at the last iteration: {text}")
        measured = "<br>".join(lines)
    elif claim.startswith("Fig. 4"):
        verdicts, lines = {}, []
        for key, names in parts.items():
            if names is None:
                verdicts[key] = "not run yet"
                continue
            both = [beats_verdict([family.sign(n)]) for n, _ in names]
            verdicts[key] = _combined(both)
            lines.append(f"{ARMS[key]}: " + "; ".join(family.text(n, label)
                                                      for n, label in names))  # fmt: skip
        measured = "<br>".join(lines)
    else:
        verdicts, measured = _measured(family, parts)
    note = "; ".join(x for x in (_agreement(verdicts), where) if x)
    return (claim, paper, verdicts["shared"], verdicts["own"], measured, note)


def _swap_rows(family: Family, swap) -> list[tuple]:
    """The data-set swap's two rows (Fig. 3c), ``family`` solved."""
    if swap is None:
        return [("Fig. 3c", "", "not run yet", "", "", "")]
    better, similar, seeds = swap
    v = _combined([beats_verdict([family.sign(n)]) for n, _ in better])
    rows = [("Fig. 3c", "data-set swap: both losses do better on the data the joint loss "
             "collected", v, "-", "<br>".join(family.text(n, label) for n, label in better),
             f"{seeds} seeds, the default cell's data sets")]  # fmt: skip
    v = _combined(["does not reproduce" if family.sign(n) else "reproduces"
                   for n, _ in similar])  # fmt: skip
    rows.append(("Fig. 3c", "on the same data the task and joint losses perform similarly",
                 v, "-", "<br>".join(family.text(n, label) for n, label in similar),
                 f"{seeds} seeds, the default cell's data sets"))  # fmt: skip
    return rows


def _theory_row() -> tuple:
    """The 1-D theory's row (section III-B)."""
    verdict, theory = theory_claim()
    return ("III-B (1-D)", "the joint loss rests at s_p = (s_d + s_a)/2, which drives "
            "s_a to s_d: it corrects a biased model where the task loss does not",
            verdict, "-", "<br>".join(theory), "closed forms in docs/theory.md")  # fmt: skip


def _page(tasks: dict, rows: list[tuple], comparisons: int) -> str:
    """The page's text: how it is made, the headline tables, the claims table."""
    lines = [
        "# The paper's claims under the faithful protocol",
        "",
        "Written by `experiments/claims.py` from the committed records: "
        "`experiments/comparison.py` (per task the four losses at the shared defaults and "
        "each loss at its own search's best, 10 seeds x the test motions; a task's "
        "robustness default cell, 5 seeds, stands in until its shared cell has run), "
        "`experiments/swap_study.py`, the robustness study's other cells (exploratory) and "
        "the 1-D theory. Statistics by `cfm_jax.stats` (rliable's definitions): scores are "
        "orders of magnitude below PD-only (a failed run: at most "
        f"{FAILED_SCORE:g}); IQM: the interquartile mean over seeds x motions; 95% stratified "
        "bootstrap intervals; P(joint > loss): the probability that a joint-loss run scores "
        "above a run of that loss on the same motion. The claims' comparisons: the IQM over "
        "seeds of the per-seed difference of log10 errors (-1: ten times lower), "
        f"{comparisons} comparisons Holm-corrected together, each interval at "
        "the level Holm tests it at (in brackets after it).",
        "",
        f"Rule: {RULE} {THEORY_RULE}",
        "",
        "## The headline cells",
        "",
        "![performance profiles](claims_profiles.png)",
        "",
    ]
    for task, pair in tasks.items():
        if pair["shared"] is not None:
            lines += headline_table(task, pair)
    lines += [
        "## The claims",
        "",
        f"| claim | the paper says | {ARMS['shared']} | {ARMS['own']} | measured | notes |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {' | '.join(row)} |" for row in rows]
    return "\n".join(lines) + "\n"


def write(comparison_dir: str, records_dir: str, swap_path: str, out: str) -> str:
    """Write the claims page ``out`` and its profiles figure beside it from the comparison
    records (``comparison_dir``), the robustness records (``records_dir``, the stand-ins
    and the exploratory notes) and the swap study's metrics (``swap_path``); returns the
    page's text."""
    robustness = records(records_dir)
    tasks = arms(comparison_dir, robustness)
    family = Family()
    plans = _plans(family, tasks, robustness)
    swap = _swap(family, swap_path)
    family.solve()  # every comparison on the page is added: Holm over all of them
    rows = [_claim_row(family, tasks, *plan) for plan in plans]
    rows += _swap_rows(family, swap) + [_theory_row()]
    figure = os.path.join(os.path.dirname(os.path.abspath(out)), "claims_profiles.png")
    os.makedirs(os.path.dirname(figure), exist_ok=True)
    profiles({t: p for t, p in tasks.items() if p["shared"] is not None}, figure)
    text = _page(tasks, rows, len(family.differences))
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(out, "w") as f:
        f.write(text)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--comparison", default="docs/results/comparison")
    parser.add_argument("--records", default="docs/results/robustness")
    parser.add_argument("--swap", default="docs/results/swap/swap_metrics.csv")
    parser.add_argument("--out", default="docs/results/claims.md")
    args = parser.parse_args()
    print(write(args.comparison, args.records, args.swap, args.out))


if __name__ == "__main__":
    main()
