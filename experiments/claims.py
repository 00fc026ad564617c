"""The paper's claims, one verdict each, from the committed records (nothing is trained here).

Reads:

* the comparison's cell records (``experiments/comparison.py``,
  ``docs/results/comparison/cells/<task>/<cell>/`` and a later block of seeds in
  ``<cell>/seeds-<first>-<last>/``): per task the four losses at the shared library defaults
  (``shared``) and each loss at its own search's choice (``own-<loss>``), every block of
  seeds that has run (20 seeds, 10-29, once both have): the headline. Until a task's shared
  cell has run, the robustness study's 5-seed default cell stands in for it (the page says
  so); until all four own cells of a task have run, "each at its best" is "not run yet";
* the robustness study's other cells (``docs/results/robustness/cells``; 3-5 seeds):
  exploratory, which loss is lowest in each (no interval, no verdict);
* the data-set swap, ``docs/results/swap/swap_metrics.csv`` (``swap_study.py``);
* the 1-D theory, recomputed (``theory_1d.run_sweeps``, seconds).

and writes ``docs/results/claims.md``, its figures (``claims_forest.png``: every comparison
of the primary family with its interval; ``claims_profiles.png``) and
``claims_comparisons.csv`` (each comparison's per-seed differences, p-value, Holm level and
decision: what a reader needs to check every verdict).

The rule (:data:`RULE`; written down with the primary family and the seed count in
``docs/results/claims_plan.md`` before the second block of seeds ran, issue 68): a comparison
A - B is the per-seed difference of log10 errors (each seed averaged over its motions); it is
*clear* when the exact sign-flip test (:func:`cfm_jax.analysis.stats.sign_flip_p`, every sign
assignment enumerated: no random number) is rejected by Holm's procedure over the primary
family, the paper's claims, each comparison counted once (the same runs in both
configurations: one comparison). A verdict follows from the clear comparisons by a fixed rule,
the same for every claim, loss and configuration. Effect sizes (they decide nothing): the mean
difference with the interval that inverts the exact test at its Holm level, the IQM with a
bootstrap interval, per loss the IQM score with its stratified bootstrap interval and the
probability of improvement (:mod:`cfm_jax.analysis.stats`, rliable's definitions). ``--seed``
changes the bootstrap's seed: the intervals of the effect sizes move, no verdict does (tested).

Usage:
  python experiments/claims.py
  python experiments/claims.py --comparison DIR --records DIR --swap FILE --out FILE --seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
import os

import comparison
import numpy as np
import pandas as pd
import robustness_study
import select_defaults
import walk_feedback

from cfm_jax.analysis import report, stats

PLAN = "docs/results/claims_plan.md"
"""Where the primary family, the rule and the seed count are written down (before the rerun)."""
ALPHA = 0.05
"""Holm's family-wise error over the primary family."""
MARGIN = 0.3
"""A claim of similar performance: the exact interval at its Holm level inside +-MARGIN (log10
error: a factor of 2)."""
RULE = (
    "A comparison A - B is the per-seed difference of log10 errors (each seed averaged over "
    "its test motions). It is *clear* when Holm's procedure over the primary family (the "
    "paper's claims below, each comparison counted once: runs that are the same in both "
    "configurations are one comparison), at a family-wise 5%, rejects 'no difference' by the "
    "two-sided exact sign-flip test of the mean difference (all 2^n assignments of signs "
    "to the n seeds' differences enumerated; no random number enters a verdict). A claim that "
    "loss A beats loss B *reproduces* when A - B is clearly below 0 for every B the claim "
    "names, *does not reproduce* when it is clearly above 0 for some B, and is *not resolved* "
    "otherwise; 'only the joint loss succeeds' is such a claim on each seed's fraction of "
    "failed runs. A claim that two perform similarly *reproduces* when the exact interval of "
    f"their difference lies inside +-{MARGIN:g} (a factor of {10**MARGIN:.0f} in the "
    "error), *does not reproduce* when the difference is clear and its interval is not "
    "inside, and is *not resolved* otherwise. A "
    "claim is judged on each configuration apart (the shared defaults; each loss at its own "
    "search's best)."
)
OTHERS = ("task", "distal", "supervised")
LOSSES = ("joint", *OTHERS)
ARMS = {"shared": "shared defaults", "own": "each at its best"}
STATISTIC = "iqm"
REPS = 4000
"""Bootstrap resamples per effect-size interval (effect sizes only; the page's default seed
is 0, so that it is regenerated bit for bit)."""
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

    def runs(self, loss: str):
        """The sweep cells that hold ``loss``'s runs (``cfm_jax.runs.sweeps.cell_id``s), or None
        where the records do not name them: two comparisons of the same runs are one."""
        if "cell" not in self.metrics:
            return None
        return frozenset(self.metrics[self.metrics.loss == loss].cell.unique())


def _read(folder: str) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    if not os.path.isfile(os.path.join(folder, "metrics.csv")):
        return None
    return (pd.read_csv(os.path.join(folder, "metrics.csv")),
            pd.read_csv(os.path.join(folder, "baselines.csv")))  # fmt: skip


def _same(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    key = ["baseline", "target"]
    a, b = (f.set_index(key).sort_index() for f in (a, b))
    return a.index.equals(b.index) and np.allclose(a.tracking_mse, b.tracking_mse, rtol=1e-6)


def complete_blocks(comparison_dir: str, cells) -> tuple[int, ...]:
    """The blocks of seeds (``comparison.BLOCKS``, their first seeds) that every one of
    ``cells`` has run: the blocks a comparison between them may use."""
    return tuple(first for first in comparison.BLOCKS
                 if all(_read(comparison.record_dir(comparison_dir, c.block(first))) is not None
                        for c in cells))  # fmt: skip


def read_blocks(comparison_dir: str, cell,
                blocks=comparison.BLOCKS) -> tuple[pd.DataFrame, pd.DataFrame] | None:  # fmt: skip
    """A comparison cell's records over the ``blocks`` of seeds (their first seeds, in
    order) that it has run (the first of them must have run): the metrics together, the
    baselines (of the test motions, the same in every block) once."""
    if not blocks:
        return None
    found = [_read(comparison.record_dir(comparison_dir, cell.block(first))) for first in blocks]
    if found[0] is None:
        return None
    found = [r for r in found if r is not None]
    for _, baselines in found[1:]:
        if not _same(baselines, found[0][1]):
            raise ValueError(f"{cell.task}/{cell.name}: a block of seeds has other baselines "
                             "than the first (other test motions or gains?)")  # fmt: skip
    return pd.concat([m for m, _ in found], ignore_index=True), found[0][1]


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
    if not _same(*(f[f.baseline == "pd_only"] for f in (own, shared))):
        raise ValueError(
            f"{task}: the own-{loss} cell's PD-only differs from the shared cell's (other "
            "test motions or gains?): the two cannot be compared"
        )


def _same_runs(own: pd.DataFrame, shared: pd.DataFrame) -> str:
    """A note naming the losses whose own cell is the shared cell's run (the same sweep cell,
    ``cfm_jax.runs.sweeps.cell_id``: the same config), or ``""``."""
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
        cells = [comparison.Cell(task, comparison.SHARED, LOSSES),
                 *(comparison.Cell(task, f"own-{n}", (n,)) for n in LOSSES)]  # fmt: skip
        # Once every cell of the task has run a block, only such blocks count: both
        # configurations then compare the same seeds, and a block still running (some of
        # its cells finished) changes nothing on the page, nor the family's count.
        blocks = complete_blocks(comparison_dir, cells) or comparison.BLOCKS
        shared = read_blocks(comparison_dir, cells[0], blocks)
        if shared is not None:
            shared = Arm(*shared, "the comparison's shared cell")
        else:
            default = [c for c in robustness if c.task == task and c.default]
            shared = Arm(*robustness[default[0]], "the robustness study's default cell (the "
                         "10-seed shared cell has not run yet)") if default else None  # fmt: skip
        own = [read_blocks(comparison_dir, cell, blocks) for cell in cells[1:]]
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
    plain, non-finite runs skipped; ``"failed"``: 1 for a failed run, 0 else, not logged),
    averaged over the seed's motions at the last iteration
    (``over="last"``) or over its motions and all iterations (``"all"``: the paper's "during
    learning")."""
    metrics = arm.metrics
    if column == "failed":
        frame = metrics.assign(score=report.failed_runs(metrics).astype(float))
    elif column == "tracking_mse" and arm.baselines is not None:
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
    magnitude below PD-only (:func:`cfm_jax.analysis.stats.score`), a failed run at most
    :data:`FAILED_SCORE`."""
    frame = select_defaults.scores(arm.metrics, arm.baselines)
    frame = frame[frame.iteration == frame.iteration.max()]
    pd_only = arm.baselines[arm.baselines.baseline == "pd_only"].set_index("target")
    frame = frame.assign(orders=np.log10(frame.target.map(pd_only.tracking_mse)) - frame.score)
    table = {loss: f.pivot(index="seed", columns="target", values="orders").to_numpy()
             for loss, f in frame.groupby("loss")}  # fmt: skip
    return {loss: table[loss] for loss in LOSSES if loss in table}


def _signed(value: float) -> str:
    """``value`` to two decimals with its sign (a value that rounds to 0 is +0.00)."""
    return f"{np.round(value, 2) + 0.0:+.2f}"


class Family:
    """The primary family: every comparison of the paper's claims, each counted once, decided
    together (exact sign-flip tests, Holm). A comparison is added under a display name; two
    names whose runs are the same (the same ``key``: the compared column and the sweep cells
    on both sides) are one comparison."""

    def __init__(self):
        self.differences: dict[str, pd.Series] = {}  # comparison id -> per-seed A - B
        self.ids: dict[str, str] = {}  # display name -> comparison id
        self._keys: dict = {}
        self.table = None

    def add(self, name: str, a: pd.Series, b: pd.Series, key=None) -> str:
        """Add ``a - b`` over the seeds both have as ``name`` (an existing comparison of the
        same ``key``, when given and known, is reused); returns ``name``."""
        if key is not None and key in self._keys:
            self.ids[name] = self._keys[key]
            return name
        common = a.index.intersection(b.index)
        self.differences[name] = a[common] - b[common]
        self.ids[name] = name
        if key is not None:
            self._keys[key] = name
        return name

    def solve(self, seed: int = 0) -> None:
        """Decide every comparison (``seed``: the bootstrap's, effect sizes only)."""
        values = {n: d.to_numpy() for n, d in self.differences.items()}
        table = stats.paired_comparisons(values, ALPHA, STATISTIC, REPS, seed)
        self.table = table.set_index("comparison")

    def row(self, name: str) -> pd.Series:
        return self.table.loc[self.ids[name]]

    def sign(self, name: str) -> int:
        """-1 or +1: clearly below or above 0; 0: not clear."""
        row = self.row(name)
        return int(np.sign(row["mean"])) if row.clear else 0

    def interval(self, name: str) -> str:
        row = self.row(name)
        if not np.isfinite(row.low):
            return f"{_signed(row['mean'])} [unbounded: {row.runs} seeds cannot reach its level]"
        return f"{_signed(row['mean'])} [{_signed(row.low)}, {_signed(row.high)}]"

    def text(self, name: str, label: str) -> str:
        row = self.row(name)
        clear = ", clear" if row.clear else ""
        return (f"{label} {self.interval(name)} (p = {row.p:.1e}, Holm level {row.level:.1e}"
                f"{clear})")  # fmt: skip


def beats_verdict(signs) -> str:
    """The rule's verdict on "the winner is lower than each loser" from the comparisons'
    signs (-1: clearly lower, +1: clearly higher, 0: not clear)."""
    if any(s > 0 for s in signs):
        return "does not reproduce"
    return "reproduces" if signs and all(s < 0 for s in signs) else "not resolved"


def similar_verdict(clear: bool, low: float, high: float, margin: float = MARGIN) -> str:
    """The rule's verdict on "A and B perform similarly" (amendment 1 of the plan): an exact
    interval (at its Holm level) inside ``+-margin`` shows it, even where a smaller
    difference is detectable; a clear difference whose interval is not inside refutes it;
    else not resolved."""
    if -margin < low and high < margin:
        return "reproduces"
    return "does not reproduce" if clear else "not resolved"


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


def failures_text(arm: Arm) -> str:
    """The failed runs per loss at the last iteration (:func:`cfm_jax.analysis.report.failed_runs`:
    fell, or the simulation diverged)."""
    final = arm.metrics[arm.metrics.iteration == arm.metrics.iteration.max()]
    failed = final.assign(f=report.failed_runs(final)).groupby("loss").f.agg(["sum", "size"])
    return ", ".join(f"{n} {int(failed.loc[n, 'sum'])}/{int(failed.loc[n, 'size'])}"
                     for n in LOSSES if n in failed.index)  # fmt: skip


def _combined(verdicts) -> str:
    """One verdict of a claim with several parts: theirs when they agree, else "mixed"
    (the numbers column gives each part's)."""
    return verdicts[0] if len(set(verdicts)) == 1 else "mixed: " + ", ".join(verdicts)


THEORY_RULE = (
    "The 1-D claim (no seeds: closed forms over a grid of model biases) *reproduces* when, "
    "over the model biases where the joint iteration converges and the task loss leaves an "
    "error (|task error| > 1e-4), the joint loss ends closer to s_d than the task loss in "
    "every one; *does not reproduce* when in none; is *mixed* when in some; and is *not "
    "resolved* when there is no such bias."
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


@dataclasses.dataclass
class Claim:
    """One claim of the paper: its label, what the paper says, how it is decided (``kind``:
    ``beats``, one comparison per loser; ``parts``, each comparison a claim of its own, the
    verdicts combined; ``similar``) and per configuration its comparisons as (name, label),
    or None where the configuration has not run (``"-"``: the claim has one configuration)."""

    label: str
    paper: str
    kind: str
    parts: dict
    note: str = ""
    seeds: str = ""


CLAIMS = (
    ("Fig. 3a", "iiwa inverse dynamics: the joint loss converges faster and more stably than "
     "the others and learns a very good tracking controller in < 10 iterations",
     "inverse_dynamics", "tracking_mse", "last"),
    ("Fig. 3a (during learning)", "the same, over the iterations", "inverse_dynamics",
     "tracking_mse", "all"),
    ("Fig. 3b", "iiwa op-space: the joint loss outperforms the others; supervised learning "
     "is unsatisfactory (redundancy)", "opspace", "tracking_mse", "last"),
)  # fmt: skip
LEGGED = ("walk", "jump")


def _seeds_text(arms) -> str:
    """The seeds per loss of each configuration that has run, ``shared / own`` (a range
    where the losses differ: a block of seeds not yet run for some)."""
    texts = []
    for arm in arms:
        if arm is None:
            continue
        counts = arm.metrics.groupby("loss").seed.nunique()
        low, high = int(counts.min()), int(counts.max())
        texts.append(str(low) if low == high else f"{low}-{high}")
    return " / ".join(texts)


def _ranking(family, tasks, claim, task, column, over, pairs) -> dict:
    """Per configuration the comparisons ``pairs`` (A, B) of ``column`` on ``task``."""
    parts = {}
    for key, arm in tasks[task].items():
        if arm is None:
            parts[key] = None
            continue
        values = per_seed(arm, column, over)
        names = []
        for a, b in pairs:
            runs = (arm.runs(a), arm.runs(b))
            same = None if None in runs else (task, column, over, *runs)
            name = family.add(f"{claim} | {ARMS[key]} | {a} - {b}", values[a], values[b], same)
            names.append((name, f"{a} - {b}"))
        parts[key] = names
    return parts


def _swap(family, path: str):
    """The data-set swap's comparisons (retrains of the inverse-dynamics defaults of their
    time): per retraining loss the joint-loss data minus the task-loss data; per data set the
    joint minus the task retrain."""
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
    return better, similar, str(int(metrics.seed.nunique()))


def _legged_claims(family: Family, tasks: dict, robustness: dict, task: str) -> list[Claim]:
    """The claims of the legged ``task`` (Fig. 5, its success, Table I, Fig. 4), their
    comparisons added to ``family``."""
    beats, claims = [("joint", n) for n in OTHERS], []
    seeds = _seeds_text(tasks[task].values())
    label = f"Fig. 5 ({task})"
    claims.append(Claim(label, f"Solo12 {task}: the joint loss tracks the base best", "beats",
                        _ranking(family, tasks, label, task, "tracking_mse", "last", beats),
                        exploratory(robustness, task, "tracking_mse", "last"), seeds))  # fmt: skip
    label = f"Fig. 5 ({task}, success)"
    parts = _ranking(family, tasks, label, task, "failed", "last", beats)
    falls = "; ".join(f"{ARMS[k]}: failed runs {failures_text(a)}"
                      for k, a in tasks[task].items() if a is not None)  # fmt: skip
    claims.append(Claim(label, f"Solo12 {task}: only the joint loss succeeds (fraction of "
                        "failed runs per seed)", "beats", parts, falls, seeds))  # fmt: skip
    label = f"Table I ({task})"
    claims.append(Claim(label, f"Solo12 {task}: the joint loss tracks the foot forces best",
                        "beats", _ranking(family, tasks, label, task, "force_mse", "last", beats),
                        exploratory(robustness, task, "force_mse", "last"), seeds))  # fmt: skip
    label = f"Fig. 4 ({task})"
    error = _ranking(family, tasks, f"{label} prediction error", task, "prediction_error",
                     "all", [("joint", "task")])  # fmt: skip
    predicted = _ranking(family, tasks, f"{label} predicted task error", task,
                         "predicted_task_error", "all", [("task", "joint")])  # fmt: skip
    parts = {k: None if error[k] is None else
             [(error[k][0][0], "prediction error joint - task"),
              (predicted[k][0][0], "predicted task error task - joint")]
             for k in error}  # fmt: skip
    claims.append(Claim(label, f"Solo12 {task}: during learning the joint loss's forward-model "
                        "prediction error is lower than the task loss's, whose predicted task "
                        "error is lower", "parts", parts, "", seeds))  # fmt: skip
    return claims


def plan_claims(family: Family, tasks: dict, robustness: dict, swap_path: str) -> list[Claim]:
    """The paper's claims in the page's order, their comparisons added to ``family`` (the
    primary family of ``claims_plan.md``)."""
    beats = [("joint", n) for n in OTHERS]
    out = []
    for label, paper, task, column, over in CLAIMS:
        out.append(Claim(label, paper, "beats",
                         _ranking(family, tasks, label, task, column, over, beats),
                         exploratory(robustness, task, column, over),
                         _seeds_text(tasks[task].values())))  # fmt: skip
    for task in LEGGED:
        out += _legged_claims(family, tasks, robustness, task)
    swap = _swap(family, swap_path)
    if swap is None:
        out.append(Claim("Fig. 3c", "data-set swap", "parts", {"shared": None, "own": "-"}))
    else:
        better, similar, seeds = swap
        note = "the data sets of the inverse-dynamics defaults of their time"
        out.append(Claim("Fig. 3c", "data-set swap: both losses do better on the data the "
                         "joint loss collected", "parts", {"shared": better, "own": "-"}, note,
                         seeds))  # fmt: skip
        out.append(Claim("Fig. 3c", "on the same data the task and joint losses perform "
                         "similarly", "similar", {"shared": similar, "own": "-"}, note,
                         seeds))  # fmt: skip
    return out


def verdict(family: Family, claim: Claim, key: str) -> str:
    """The rule's verdict of ``claim`` in configuration ``key`` (``family`` solved)."""
    names = claim.parts[key]
    if names is None:
        return "not run yet"
    if names == "-":
        return "-"
    if claim.kind == "beats":
        return beats_verdict([family.sign(n) for n, _ in names])
    if claim.kind == "parts":
        return _combined([beats_verdict([family.sign(n)]) for n, _ in names])
    rows = [family.row(n) for n, _ in names]
    return _combined([similar_verdict(r.clear, r.low, r.high) for r in rows])


def _measured(family: Family, claim: Claim) -> str:
    lines = []
    for key, names in claim.parts.items():
        if names is None or names == "-":
            continue
        prefix = f"{ARMS[key]}: " if claim.parts.get("own") != "-" else ""
        lines.append(prefix + "; ".join(family.text(n, label) for n, label in names))
    return "<br>".join(lines)


def _same_runs_note(family: Family, claim: Claim) -> str:
    """Whether both configurations' verdicts rest on the same comparisons (the same runs)."""
    shared, own = claim.parts.get("shared"), claim.parts.get("own")
    if not isinstance(shared, list) or not isinstance(own, list):
        return ""
    same = [family.ids[a] == family.ids[b] for (a, _), (b, _) in zip(shared, own, strict=True)]
    if all(same):
        return "both configurations: the same runs"
    if any(same):
        return "partly the same runs in both configurations"
    return ""


def claim_rows(family: Family, claims: list[Claim]) -> list[tuple]:
    """The detailed table's rows: claim, the paper, each configuration's verdict, what was
    measured, the notes."""
    rows = []
    for claim in claims:
        note = "; ".join(x for x in (_same_runs_note(family, claim), claim.note) if x)
        rows.append((claim.label, claim.paper, verdict(family, claim, "shared"),
                     verdict(family, claim, "own"), _measured(family, claim),
                     note))  # fmt: skip
    return rows


def summary_rows(family: Family, claims: list[Claim], theory: tuple | None) -> list[tuple]:
    """The page's first table: per claim its verdicts, its comparisons' effects (mean per-seed
    difference [exact interval at the Holm level]; in bold the clear ones) and seeds."""
    rows = []
    for claim in claims:
        effects = []
        for key, names in claim.parts.items():
            if names is None or names == "-":
                continue
            done = set()
            for name, label in names:
                if family.ids[name] in done and key == "own":
                    continue
                shown = f"{label} {family.interval(name)}"
                effects.append(f"**{shown}**" if family.row(name).clear else shown)
            done |= {family.ids[n] for n, _ in names}
            if key == "shared" and isinstance(claim.parts.get("own"), list):
                own = [n for n, _ in claim.parts["own"] if family.ids[n] not in done]
                if not own:
                    break  # the own configuration's are the same comparisons
                effects.append(f"*{ARMS['own']}:*")
        rows.append((claim.label, verdict(family, claim, "shared"), verdict(family, claim, "own"),
                     "<br>".join(effects), claim.seeds))  # fmt: skip
    if theory is not None:
        verdict_1d, _ = theory
        rows.append(("III-B (1-D)", verdict_1d, "-", "closed forms (no seeds)", "-"))
    return rows


def headline_table(task: str, pair: dict, seed: int = 0) -> list[str]:
    """Per loss and configuration the IQM score [95% CI], failed runs, the seeds whose
    controller ends below PD-only (the mean of its runs' scores over the test motions above
    0: a geometric-mean error below PD-only's) and P(joint > loss) (bootstrap seed
    ``seed``)."""
    lines = [f"### {task}", ""]
    for key, arm in pair.items():
        if arm is not None:
            lines.append(f"- {ARMS[key]}: {arm.source}, {arm.seeds} seeds x "
                         f"{arm.metrics.target.nunique()} test motions")  # fmt: skip
    lines += ["", "| loss | " + " | ".join(f"{ARMS[k]}: IQM [95% CI] | failed | "
                                         "seeds below PD-only | P(joint > loss)"
                                         for k in pair) + " |",
              "|---|" + "---|---|---|---|" * len(pair)]  # fmt: skip
    cells = {}
    for key, arm in pair.items():
        if arm is None:
            cells[key] = {n: ("not run yet", "", "", "") for n in LOSSES}
            continue
        scores = run_scores(arm)
        est = stats.interval_estimates(scores, statistic=STATISTIC, seed=seed)
        est = est.set_index("method")
        final = arm.metrics[arm.metrics.iteration == arm.metrics.iteration.max()]
        failed = final.assign(f=report.failed_runs(final)).groupby("loss").f.agg(["sum", "size"])
        cells[key] = {}
        for n in LOSSES:
            p = (
                ""
                if n == "joint" or scores[n].shape != scores["joint"].shape
                else "{:.2f} [{:.2f}, {:.2f}]".format(
                    *stats.probability_of_improvement(scores["joint"], scores[n], seed=seed)
                )
            )
            cells[key][n] = (
                f"{est.point[n]:.2f} [{est.low[n]:.2f}, {est.high[n]:.2f}]",
                f"{int(failed.loc[n, 'sum'])}/{int(failed.loc[n, 'size'])}",
                f"{int((scores[n].mean(axis=1) > 0).sum())}/{scores[n].shape[0]}",
                p,
            )
    for n in LOSSES:
        lines.append(f"| {n} | " + " | ".join(" | ".join(cells[k][n]) for k in pair) + " |")
    return lines + [""]


def profiles(tasks: dict, path: str, seed: int = 0) -> None:
    """The performance profiles (rliable): per task the fraction of runs above each score,
    solid the shared defaults, dashed each at its best; two by two."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = min(2, len(tasks))
    rows = -(-len(tasks) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5 * columns, 3.4 * rows), squeeze=False)
    taus = np.linspace(-3, 6, 91)
    for ax, (task, pair) in zip(axes.flat, tasks.items(), strict=False):
        for key, style in (("shared", "-"), ("own", "--")):
            if pair[key] is None:
                continue
            frame = stats.performance_profile(run_scores(pair[key]), taus, reps=500, seed=seed)
            for k, (loss, f) in enumerate(frame.groupby("method", sort=False)):
                ax.plot(f.threshold, f.fraction, style, color=f"C{k}",
                        label=f"{loss} ({ARMS[key]})")  # fmt: skip
                ax.fill_between(f.threshold, f.low, f.high, color=f"C{k}", alpha=0.1)
        ax.set(title=task, xlabel="score tau (orders of magnitude below PD-only)",
               ylabel="fraction of runs with score > tau")  # fmt: skip
        ax.axvline(0, color="grey", lw=0.5)
    for ax in list(axes.flat)[len(tasks) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)


def forest(family: Family, path: str) -> None:
    """Every comparison of the primary family: its mean per-seed difference with the exact
    interval at its Holm level (unbounded: an arrow to the edge), against 0; clear ones in
    colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = family.table
    finite = np.concatenate([table[["low", "high"]].to_numpy()[np.isfinite(table.low)].ravel(),
                             table["mean"].to_numpy()])  # fmt: skip
    edge = 1.1 * float(np.max(np.abs(finite))) if len(finite) else 1.0
    fig, ax = plt.subplots(figsize=(8, 0.22 * len(table) + 1.2))
    for y, (_, row) in enumerate(table.iloc[::-1].iterrows()):
        colour = ("C3" if row["mean"] > 0 else "C0") if row.clear else "0.55"
        low = row.low if np.isfinite(row.low) else -edge
        high = row.high if np.isfinite(row.high) else edge
        ax.plot([low, high], [y, y], color=colour, lw=1.5)
        ax.plot(row["mean"], y, "o", color=colour, ms=4)
        if not np.isfinite(row.low):
            ax.annotate("", (-edge, y), (-0.9 * edge, y), arrowprops={"arrowstyle": "->",
                                                                     "color": colour})  # fmt: skip
            ax.annotate("", (edge, y), (0.9 * edge, y), arrowprops={"arrowstyle": "->",
                                                                   "color": colour})  # fmt: skip
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(range(len(table)), [n.replace(" | ", ", ") for n in table.index[::-1]],
                  fontsize=6)  # fmt: skip
    ax.set_xlim(-edge, edge)
    ax.set_xlabel("A - B, mean per-seed difference of log10 errors (success: of failed "
                  "fractions; < 0: A lower), exact interval at its Holm level",
                  fontsize=7)  # fmt: skip
    ax.set_title("The primary family: blue A clearly lower, red A clearly higher, grey not "
                 "clear", fontsize=8)  # fmt: skip
    ax.tick_params(axis="x", labelsize=7)
    fig.savefig(path, dpi=110, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)


COMPARISON_COLUMNS = ["comparison", "names", "seeds", "differences", "runs", "mean", "low",
                      "high", "level", "p", "adjusted", "clear"]  # fmt: skip


def comparisons_frame(family: Family) -> pd.DataFrame:
    """The primary family as a table: per comparison the display names that share it, its
    seeds and per-seed differences (space-separated, full precision) and the decision."""
    names = {}
    for name, key in family.ids.items():
        names.setdefault(key, []).append(name)
    rows = []
    for key, d in family.differences.items():
        row = family.table.loc[key]
        rows.append({"comparison": key, "names": "; ".join(names[key]),
                     "seeds": " ".join(str(int(s)) for s in d.index),
                     "differences": " ".join(repr(float(v)) for v in d.to_numpy()),
                     **{c: row[c] for c in COMPARISON_COLUMNS[4:]}})  # fmt: skip
    return pd.DataFrame(rows, columns=COMPARISON_COLUMNS)


def _page(tasks: dict, summary: list[tuple], rows: list[tuple], family: Family, seed: int) -> str:
    """The page: the verdicts first, then the forest plot, the rule, the headline cells and
    the detailed table."""
    lines = [
        "# The paper's claims under the faithful protocol",
        "",
        "| claim | shared defaults | each at its best | effects: A - B, mean per-seed "
        "difference of log10 errors [exact interval at its Holm level] (bold: clear) | seeds "
        "(shared / own) |",
        "|---|---|---|---|---|",
        *(f"| {' | '.join(row)} |" for row in summary),
        "",
        f"Decided by an exact test over a primary family of {len(family.differences)} "
        "comparisons written down before the rerun ([the plan](claims_plan.md)); "
        f"clear: {int(family.table.clear.sum())} of them. Negative: the first loss's error is "
        "lower (-1: ten times lower). The plan's 20 seeds per headline cell run in two "
        "blocks (10-19, 20-29); a comparison uses the seeds both of its losses have (the "
        "seeds column; 10 seeds cannot reach Holm's first levels: 'unbounded').",
        "",
        "![every comparison of the primary family with its interval](claims_forest.png)",
        "",
        "## How it is decided",
        "",
        f"Rule: {RULE} {THEORY_RULE}",
        "",
        "Written by `experiments/claims.py` from the committed records: "
        "`experiments/comparison.py` (per task the four losses at the shared defaults and "
        "each loss at its own search's best, the test motions; a task's robustness default "
        "cell, 5 seeds, stands in until its shared cell has run), "
        "`experiments/swap_study.py`, the robustness study's other cells (exploratory) and "
        "the 1-D theory. Every comparison's per-seed differences, p-value and Holm level: "
        "[claims_comparisons.csv](claims_comparisons.csv). Effect sizes, which decide "
        "nothing (by `cfm_jax.analysis.stats`, rliable's definitions): scores are orders of "
        f"magnitude below PD-only (a failed run: at most {FAILED_SCORE:g}); IQM: the "
        "interquartile mean over seeds x motions; 95% stratified bootstrap intervals; seeds "
        "below PD-only: the "
        "seeds whose runs score above 0 on average over the test motions (a geometric-mean "
        "error below PD-only's: does the learned controller beat the feedback it is added "
        "to?); P(joint > loss): the "
        "probability that a joint-loss run scores above a run of that loss on the same "
        "motion.",
        "",
        "## The headline cells (exploratory: effect sizes)",
        "",
        "![performance profiles](claims_profiles.png)",
        "",
    ]
    for task, pair in tasks.items():
        if pair["shared"] is not None:
            lines += headline_table(task, pair, seed)
    lines += [
        "## The claims in detail",
        "",
        f"| claim | the paper says | {ARMS['shared']} | {ARMS['own']} | measured | notes |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {' | '.join(row)} |" for row in rows]
    return "\n".join(lines) + "\n"


FEEDBACK = walk_feedback.OUT
"""The walk's records under today's ``s*`` (``experiments/walk_feedback.py``): the second
family of ``claims_plan.md``'s amendment 2."""
FEEDBACK_CELL = walk_feedback.cell(comparison.BLOCKS[0])


def feedback_family(feedback_dir: str = FEEDBACK, seed: int = 0):
    """The walk's claims under today's ``s*`` on every block of seeds (amendment 2), decided
    as a family of their own: ``(claims, family)``, or None until every block is recorded."""
    if complete_blocks(feedback_dir, [FEEDBACK_CELL]) != comparison.BLOCKS:
        return None
    metrics, baselines = read_blocks(feedback_dir, FEEDBACK_CELL)
    source = "the comparison's shared walk cell with joint position feedback in s*"
    tasks = {"walk": {"shared": Arm(metrics, baselines, source), "own": None}}
    family = Family()
    found = _legged_claims(family, tasks, {}, "walk")
    family.solve(seed)
    return found, family


def feedback_section(found, feedback_dir: str = FEEDBACK) -> list[str]:
    """The page's section on the walk under today's ``s*`` (the plan's amendment 2):
    ``found``, :func:`feedback_family`'s answer for ``feedback_dir``."""
    lines = [
        "## The Solo12 walk under today's `s*` (the plan's amendment 2)",
        "",
        "The walk's claims again, on the comparison's shared walk cell with joint position "
        "feedback in `s*` (`experiments/walk_feedback.py`, seeds 10-29, nothing else "
        "changed; [its page](walk_feedback.md)), as a second family of their own: Holm over "
        "its comparisons only, the rule above. The verdicts above are the walk's under the "
        "earlier `s*`; no own cells were run for this one.",
        "",
    ]
    if found is None:
        blocks = complete_blocks(feedback_dir, [FEEDBACK_CELL])
        done = [f"{b}-{b + comparison.SEEDS - 1}" for b in blocks]
        return lines + [f"Not decided yet: decided once seeds 10-29 are all recorded "
                        f"(recorded: {', '.join(done) or 'none'}).", ""]  # fmt: skip
    found_claims, family = found
    lines += [
        "| claim | shared defaults | effects: A - B [exact interval at its Holm level] "
        "(bold: clear) | seeds |",
        "|---|---|---|---|",
        *(f"| {r[0]} | {r[1]} | {r[3]} | {r[4]} |"
          for r in summary_rows(family, found_claims, None)),
        "",
        f"{len(family.differences)} comparisons; clear: {int(family.table.clear.sum())}. "
        "Each comparison's per-seed differences, p-value and Holm level: "
        "[claims_feedback_comparisons.csv](claims_feedback_comparisons.csv).",
        "",
    ]  # fmt: skip
    return lines


def decide(comparison_dir: str, records_dir: str, swap_path: str, seed: int = 0):
    """The headline cells per task, the primary family decided (bootstrap ``seed``: effect
    sizes only) and the paper's claims: ``(tasks, family, claims)``; :func:`verdict` gives
    each claim's verdicts."""
    robustness = records(records_dir)
    tasks = arms(comparison_dir, robustness)
    family = Family()
    claims = plan_claims(family, tasks, robustness, swap_path)
    family.solve(seed)  # the whole primary family is added: Holm over all of it
    return tasks, family, claims


def write(
    comparison_dir: str,
    records_dir: str,
    swap_path: str,
    out: str,
    seed: int = 0,
    feedback_dir: str = FEEDBACK,
) -> str:
    """Write the claims page ``out``, its figures and ``claims_comparisons.csv`` beside it
    from the comparison records (``comparison_dir``), the robustness records
    (``records_dir``, the stand-ins and the exploratory notes) and the swap study's metrics
    (``swap_path``); ``seed``: the bootstrap's (effect sizes only). Returns the page's text."""
    tasks, family, claims = decide(comparison_dir, records_dir, swap_path, seed)
    theory = theory_claim()
    rows = claim_rows(family, claims)
    verdict_1d, theory_lines = theory
    rows.append(("III-B (1-D)", "the joint loss rests at s_p = (s_d + s_a)/2, which drives "
                 "s_a to s_d: it corrects a biased model where the task loss does not",
                 verdict_1d, "-", "<br>".join(theory_lines),
                 "closed forms in docs/theory.md"))  # fmt: skip
    folder = os.path.dirname(os.path.abspath(out))
    os.makedirs(folder, exist_ok=True)
    profiles({t: p for t, p in tasks.items() if p["shared"] is not None},
             os.path.join(folder, "claims_profiles.png"), seed)  # fmt: skip
    forest(family, os.path.join(folder, "claims_forest.png"))
    comparisons_frame(family).to_csv(os.path.join(folder, "claims_comparisons.csv"), index=False)
    text = _page(tasks, summary_rows(family, claims, theory), rows, family, seed)
    second = feedback_family(feedback_dir, seed)
    text += "\n" + "\n".join(feedback_section(second, feedback_dir))
    if second is not None:
        comparisons_frame(second[1]).to_csv(
            os.path.join(folder, "claims_feedback_comparisons.csv"), index=False
        )
    with open(out, "w") as f:
        f.write(text)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--comparison", default="docs/results/comparison")
    parser.add_argument("--records", default="docs/results/robustness")
    parser.add_argument("--swap", default="docs/results/swap/swap_metrics.csv")
    parser.add_argument("--out", default="docs/results/claims.md")
    parser.add_argument("--feedback", default=FEEDBACK, help="the walk under today's s*")
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="the bootstrap's seed (effect sizes only; no verdict moves)",
    )
    args = parser.parse_args()
    print(write(args.comparison, args.records, args.swap, args.out, args.seed, args.feedback))


if __name__ == "__main__":
    main()
