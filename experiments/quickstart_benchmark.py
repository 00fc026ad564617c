"""Time the research loop (issue 46): the quickstart and a 1-iteration 2-link-arm run, whole
commands before and after, and where the quickstart's time goes.

Not a test: prints numbers and writes them to ``docs/benchmarks.md`` (the section between
``<!-- quickstart-benchmark -->`` markers). Three parts:

* **Whole commands**, timed from outside by ``farm-bench`` (median of ``--runs`` runs after
  one warm-up, A and B in turn, the ratio taken pair by pair): A is this checkout's
  ``cfm-jax train``, B the same command on the code of ``--before`` (a ``git worktree`` of
  the commit before the change, put first on ``PYTHONPATH``). The commands: the quickstart
  (``cfm-jax train --out DIR --quiet``: iiwa14, the four losses, 1 seed, 4 iterations) and
  ``cfm-jax train --robot two_link_arm --iterations 1``. A runs with its compilation cache
  (``CFM_JAX_COMPILATION_CACHE``) in a folder of its own, filled by the warm-up run; one
  more run of A with an empty cache folder gives the cold start.
* **Where the compilation went**, both commits: one quickstart each with an empty
  compilation cache and ``JAX_LOG_COMPILES=1``, JAX's log lines summed per jitted program.
* **The quickstart's split**, one run in this process with timers around the
  :class:`cfm_jax.learning.algorithm.Experiment` calls of :func:`cfm_jax.train` (each waits for its
  result) and JAX's compile-time events: building the experiment, babbling and the initial
  fit of f, the initial controller fits, the iterations (the first with its compilation),
  the final evaluation, the baselines, and writing (metrics, checkpoints, data set).

Usage (nothing else running on the machine):
  git worktree add /tmp/before <commit before the change>
  python experiments/quickstart_benchmark.py --before /tmp/before [--runs 3]
      [--before-name COMMIT] [--quickstart-only]
"""

from __future__ import annotations

import argparse
import collections
import datetime
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MARKER = "<!-- quickstart-benchmark -->"
COMMANDS = {
    "2-link arm, 4 losses, 1 iteration": ["--robot", "two_link_arm", "--iterations", "1"],
    "quickstart (iiwa14, 4 losses, 1 seed, 4 iterations)": [],
}


def train_command(python: str, out: str, flags: list[str], pythonpath: str | None) -> str:
    """One shell command: a fresh OUT, then ``cfm-jax train`` (``exec``: farm-bench times it)."""
    env = f"PYTHONPATH={pythonpath} " if pythonpath else ""
    args = " ".join(flags)
    run = f"{env}exec {python} -m cfm_jax.cli train {args} --out {out} --quiet"
    return f"sh -c 'rm -rf {out} && {run}'"


def farm_bench(a: str, b: str, runs: int, timeout: int, env: dict) -> dict:
    """farm-bench's medians of A and B (wall s, peak MiB) and the median ratio A/B."""
    command = ["farm-bench", "-n", str(runs), "--warmup", "1", "--timeout", str(timeout),
               "--vs", b, "--", *a.split(" ", 2)[:2], a.split(" ", 2)[2].strip("'")]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=timeout + 60)
    text = done.stdout + done.stderr
    print(text, flush=True)
    out = {"text": text}
    for key, pattern in {
        "a_wall": r"^A wall s\s+(\S+)\s+(\S+)\s+(\S+)",
        "b_wall": r"^B wall s\s+(\S+)\s+(\S+)\s+(\S+)",
        "a_peak": r"^A peak MiB\s+(\S+)\s+(\S+)\s+(\S+)",
        "b_peak": r"^B peak MiB\s+(\S+)\s+(\S+)\s+(\S+)",
        "ratio": r"^A/B wall\s+(\S+)\s+(\S+)\s+(\S+)",
    }.items():
        match = re.search(pattern, text, re.M)
        out[key] = tuple(float(x) for x in match.groups()) if match else None
    runs_line = re.search(r"n: A (\d+), B (\d+)", text)
    out["runs"] = runs_line.groups() if runs_line else ("?", "?")
    return out


def cold_run(python: str, flags: list[str], **env: str) -> tuple[float, str]:
    """One run of ``cfm-jax train FLAGS`` with an empty compilation cache and the variables
    ``env`` added: its wall seconds and what it wrote to stderr."""
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = {**os.environ, "CFM_JAX_COMPILATION_CACHE": cache, **env}
        start = time.perf_counter()
        done = subprocess.run([python, "-m", "cfm_jax.cli", "train", *flags, "--out",
                               os.path.join(out, "run"), "--quiet"], env=env, check=True,
                              capture_output=True, text=True)  # fmt: skip
        return time.perf_counter() - start, done.stderr


COMPILE_LINE = re.compile(
    r"Finished (XLA compilation of|tracing \+ transforming|jaxpr to MLIR module conversion) "
    r"(?:jit\()?([^ )]+)\)?(?: for (?:jit|pjit))? in ([0-9.]+) sec"
)
STAGES = {"XLA compilation of": "compile", "tracing + transforming": "trace",
          "jaxpr to MLIR module conversion": "lower"}  # fmt: skip


def programs(python: str, tree: str | None) -> tuple[float, dict]:
    """One quickstart of the code of ``tree`` (None: this checkout) with an empty compilation
    cache and ``JAX_LOG_COMPILES=1``: its wall seconds and ``{program: {stage: s}}`` summed
    from JAX's log lines (any JAX version that logs them; the same for both commits)."""
    extra = {"JAX_LOG_COMPILES": "1", **({"PYTHONPATH": tree} if tree else {})}
    wall, stderr = cold_run(python, [], **extra)
    found: dict = collections.defaultdict(lambda: collections.defaultdict(float))
    for stage, name, seconds in COMPILE_LINE.findall(stderr):
        found[name][STAGES[stage]] += float(seconds)
    return wall, {name: dict(stages) for name, stages in found.items()}


def programs_table(before: tuple[float, dict], after: tuple[float, dict]) -> list[str]:
    """Markdown lines: each program's trace + lower + compile seconds in both runs (the
    largest first, programs under 0.5 s in both summed in one row), the totals and the rest."""
    rows, small = [], [0.0, 0.0]
    names = set(before[1]) | set(after[1])
    total = [sum(sum(v.values()) for v in run[1].values()) for run in (before, after)]
    for name in names:
        pair = [sum(run[1].get(name, {}).values()) for run in (before, after)]
        if max(pair) < 0.5:
            small = [small[0] + pair[0], small[1] + pair[1]]
        else:
            rows.append((name, *pair))
    rows.sort(key=lambda row: -max(row[1:]))
    lines = ["| program (jit) | before: trace + lower + compile (s) | after (s) |", "|---|---|---|"]
    lines += [f"| `{name}` | {b:.1f} | {a:.1f} |" for name, b, a in rows]
    lines += [
        f"| the other programs (each under 0.5 s) | {small[0]:.1f} | {small[1]:.1f} |",
        f"| **all compilation** | **{total[0]:.1f}** | **{total[1]:.1f}** |",
        f"| the rest of the run (computing, writing) | {before[0] - total[0]:.1f} | "
        f"{after[0] - total[1]:.1f} |",
        f"| **wall, empty compilation cache** | **{before[0]:.1f}** | **{after[0]:.1f}** |",
    ]
    return lines


def split() -> tuple[dict, float, dict]:
    """The quickstart in this process with timers: ``({phase: s}, wall s, compile events)``."""
    import jax
    from jax._src import monitoring

    import cfm_jax
    from cfm_jax import cli
    from cfm_jax.learning import algorithm
    from cfm_jax.learning import losses as losses_lib
    from cfm_jax.runs import recorder

    compile_events: dict = collections.defaultdict(float)

    def listener(name, duration, **kwargs):
        if "compil" in name or "jaxpr" in name:
            compile_events[name.rsplit("/", 1)[-1]] += duration

    monitoring.register_event_duration_secs_listener(listener)
    phases: dict = collections.defaultdict(float)
    nested: list[float] = []  # time of the calls inside the running timed call

    def timed(owner, name, phase):
        original = getattr(owner, name)
        calls = [0]

        def wrapper(*args, **kwargs):
            nested.append(0.0)
            start = time.perf_counter()
            try:
                return jax.block_until_ready(original(*args, **kwargs))
            finally:
                elapsed = time.perf_counter() - start
                inner = nested.pop()
                label = phase(calls[0]) if callable(phase) else phase
                phases[label] += elapsed - inner  # its own time, nested calls apart
                calls[0] += 1
                if nested:
                    nested[-1] += elapsed

        setattr(owner, name, wrapper)

    exp_cls, rec_cls = algorithm.Experiment, recorder.Recorder
    timed(exp_cls, "__init__", "build the experiment (robot, task, models)")
    timed(exp_cls, "prepare", "babbling rollouts")
    timed(exp_cls, "_prepare_from_data", "initial fit of f (once per seed, every loss)")
    timed(exp_cls, "init_each", "initial controller fits (each loss)")
    timed(
        exp_cls,
        "iteration_losses",
        lambda call: (  # one call per loss and iteration, the losses in turn
            "first iteration, compilation included (every loss)"
            if call < len(losses_lib.PAPER_LOSSES)
            else "the other iterations (every loss)"
        ),
    )
    timed(exp_cls, "evaluate", "final evaluation")
    timed(exp_cls, "baselines", "baselines (oracle, PD-only)")
    for name in ("start", "iteration", "record", "finish", "flush", "open"):
        timed(rec_cls, name, "writing (metrics, checkpoints, data set)")
    out = tempfile.mkdtemp()
    start = time.perf_counter()
    try:
        cli._train_command(["--out", os.path.join(out, "run"), "--quiet"])
    finally:
        shutil.rmtree(out, ignore_errors=True)
    wall = time.perf_counter() - start
    phases["the rest (tables, plots, the run's combined files)"] = wall - sum(phases.values())
    del cfm_jax
    return dict(phases), wall, dict(compile_events)


def write(path: str, section: str) -> None:
    with open(path) as f:
        text = f.read()
    if MARKER in text:
        before, _, rest = text.partition(MARKER)
        _, _, after = rest.partition(MARKER)
        text = before + MARKER + "\n" + section + "\n\n" + MARKER + after
    else:
        text = text.rstrip("\n") + "\n\n" + MARKER + "\n" + section + "\n\n" + MARKER + "\n"
    with open(path, "w") as f:
        f.write(text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", required=True, help="checkout of the code before")
    parser.add_argument("--before-name", default="<checkout>",
                        help="how the page names --before (e.g. its commit)")  # fmt: skip
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--timeout", type=int, default=1800, help="per farm-bench call (s)")
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks.md"))
    parser.add_argument("--skip-whole", action="store_true", help="the split only")
    parser.add_argument("--quickstart-only", action="store_true",
                        help="time the quickstart alone, not the 2-link command")  # fmt: skip
    args = parser.parse_args()
    python = sys.executable
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    rows = []
    if not args.skip_whole:
        cache = tempfile.mkdtemp(prefix="cfm_jax_bench_cache_")
        env = {**os.environ, "CFM_JAX_COMPILATION_CACHE": cache}
        for label, flags in COMMANDS.items():
            if args.quickstart_only and flags:
                continue
            a = train_command(python, "/tmp/cfm_bench_a", flags, None)
            b = train_command(python, "/tmp/cfm_bench_b", flags, args.before)
            got = farm_bench(a, b, args.runs, args.timeout, env)
            cold, _ = cold_run(python, flags)
            rows.append((label, got, cold))
        shutil.rmtree(cache, ignore_errors=True)
    compiled = programs(python, args.before), programs(python, None)
    phases, wall, events = split()
    lines = [
        "## The research loop: "
        + ("the quickstart" if args.quickstart_only else "quickstart and a 1-iteration run")
        + f", {stamp}",
        "",
        f"`python experiments/quickstart_benchmark.py --before {args.before_name}`, nothing "
        f"else on the machine ({os.cpu_count()} cores). Whole commands timed from outside by "
        "`farm-bench` (median of the runs after one warm-up; A and B in turn, the ratio pair "
        "by pair): *after* is this checkout, *before* the code of `--before`, each with its "
        "compilation cache warmed by the warm-up run; *after, cold* is one run with an empty "
        "compilation cache.",
        "",
        "| command | before: wall (s) | after: wall (s) | after / before | after, cold (s) | peak MiB before / after | runs |",  # noqa: E501
        "|---|---|---|---|---|---|---|",
    ]

    def med(got, key):
        value = got.get(key)
        return f"{value[1]:.1f}" if value else "-"

    for label, got, cold in rows:
        ratio = got.get("ratio")
        lines.append(
            f"| {label} | {med(got, 'b_wall')} | {med(got, 'a_wall')} | "
            f"{ratio[1]:.2f} [{ratio[0]:.2f}, {ratio[2]:.2f}] | {cold:.1f} | "
            f"{med(got, 'b_peak')} / {med(got, 'a_peak')} | {got['runs'][0]} |"
            if ratio
            else f"| {label} | - | - | - | {cold:.1f} | - | - |"
        )
    lines += [
        "",
        f"Where the quickstart's {wall:.1f} s go (one run in one process, compilation cache "
        "as configured; each phase waits for its result):",
        "",
        "| phase | s |",
        "|---|---|",
    ]
    lines += [f"| {name} | {seconds:.1f} |" for name, seconds in phases.items()]
    lines += [
        "",
        "JAX's compile events in that run (s): "
        + ", ".join(f"{name} {seconds:.1f}" for name, seconds in sorted(events.items())),
    ]
    lines += [
        "",
        "Where the compilation went: one quickstart of each commit with an empty compilation "
        "cache and `JAX_LOG_COMPILES=1`, JAX's own log lines summed per program (the names "
        "of the jitted functions; a program renamed between the commits is two rows):",
        "",
        *programs_table(*compiled),
    ]
    section = "\n".join(lines)
    print(section)
    write(args.out, section)


if __name__ == "__main__":
    main()
