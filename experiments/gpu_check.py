"""The GPU check: what a developer runs on a machine with a GPU and whatever JAX it has.

Not a test of this repository's CI (CI has no GPU): a script for the next machine with a GPU.
Two steps, one on each machine:

* ``python experiments/gpu_check.py prepare`` (here, where pip reaches a package index): the
  wheels the GPU machine lacks, for its Python (``--python-version``, default 3.12) on
  x86_64 Linux, at the versions of ``constraints.txt`` (MuJoCo, MJX, tyro and what they
  need), plus this library's own wheel, into ``.whl/`` (ignored by git).
* ``bash experiments/gpu_check.sh`` (there): installs those wheels beside the machine's own
  JAX, flax, optax and orbax, then ``python experiments/gpu_check.py run``: the test files
  that matter for the device (imports and the XLA-flag logic on that jaxlib, the simulators'
  rollouts, one learning run per simulator), ``cfm-jax bench --robot iiwa14 --batch 16``,
  and the quickstart (``cfm-jax train``) on the native simulator and on MJX. Every step has
  a time cap inside ``--budget`` seconds (default 450: it fits in 8 minutes with the
  install); a step cut by its cap is reported as such, with what it had done.

It prints one table (wall times, the iteration's split, compile time, peak memory, final
errors) and writes it to ``OUT/gpu_check.md`` and every number to ``OUT/gpu_check.json``;
``publish`` puts the table into ``docs/benchmarks_gpu.md`` and its section of
``docs/benchmarks.md`` (which ``experiments/benchmark.py`` keeps when it rewrites the page).
``XLA_PYTHON_CLIENT_PREALLOCATE=false`` is set for every step, so that the test workers
share the GPU and the peaks are what a run used, not JAX's default 75% preallocation.

Compile time of a quickstart is the sum of JAX's own compile events
(``jax.monitoring``: tracing, lowering and XLA's backend compile) over the run: the part of
its wall time that is not training.

Usage:
  python experiments/gpu_check.py prepare [--python-version 3.12]
  python experiments/gpu_check.py run [--out DIR] [--budget 450] [--train-args "..."]
  python experiments/gpu_check.py publish OUT/gpu_check.md   # here, with the table back
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WHEELS = os.path.join(ROOT, ".whl")

# Packages the GPU image lacks (device README, KINDS.md's package list): MuJoCo, MJX, tyro
# and what they need beyond the image. Versions come from constraints.txt.
MISSING = (
    "mujoco",
    "mujoco-core",
    "mujoco-studio",
    "mujoco-mjx",
    "glfw",
    "PyOpenGL",
    "websockets",
    "trimesh",
    "tyro",
    "docstring_parser",
    "typeguard",
)
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64",
             "manylinux2014_x86_64", "manylinux1_x86_64", "any")  # fmt: skip

# The test files that matter for the device: the import and the XLA-flag logic on the
# machine's jaxlib, the native host callback and both simulators' rollouts against MuJoCo C.
QUICK_TESTS = ("tests/test_xla.py", "tests/test_jax_private.py", "tests/test_native.py",
               "tests/test_rollout.py", "tests/test_imports.py")  # fmt: skip
# One learning run per simulator (each file asserts that all four losses learn).
LEARNING_TESTS = ("tests/test_learning.py", "tests/test_learning_mjx.py")
# No cache folder in the tree; pytest-benchmark (in the GPU image) only warns under xdist.
PYTEST_FLAGS = ("-q", "-p", "no:cacheprovider", "-p", "no:benchmark")


def pins() -> dict[str, str]:
    """``{name (lower case, '-' for '_'): version}`` of constraints.txt."""
    out = {}
    with open(os.path.join(ROOT, "constraints.txt")) as f:
        for line in f:
            line = line.split("#")[0].strip()
            if "==" in line:
                name, version = line.split("==")
                out[name.strip().lower().replace("_", "-")] = version.strip()
    return out


def prepare(python_version: str) -> None:
    """Download the missing wheels and build this library's wheel into ``.whl/``."""
    os.makedirs(WHEELS, exist_ok=True)
    exclude = os.path.join(ROOT, ".git", "info", "exclude")
    if os.path.isdir(os.path.dirname(exclude)):
        text = open(exclude).read() if os.path.exists(exclude) else ""
        if "/.whl/" not in text.split():
            with open(exclude, "a") as f:
                f.write("\n/.whl/\n")
    versions = pins()
    specs = []
    for name in MISSING:
        key = name.lower().replace("_", "-")
        if key not in versions:
            raise SystemExit(f"gpu_check: {name} has no pin in constraints.txt")
        specs.append(f"{name}=={versions[key]}")
    platforms = [a for p in PLATFORMS for a in ("--platform", p)]
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
         "--python-version", python_version, "--implementation", "cp", *platforms,
         "-d", WHEELS, *specs],
        check=True,
    )  # fmt: skip
    for old in glob.glob(os.path.join(WHEELS, "cfm_jax-*.whl")):
        os.remove(old)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", WHEELS, ROOT], check=True
    )
    size = sum(os.path.getsize(p) for p in glob.glob(os.path.join(WHEELS, "*.whl")))
    print(f"gpu_check: {len(os.listdir(WHEELS))} wheels, {size / 2**20:.1f} MiB in {WHEELS}")
    if size > 60 * 2**20:
        print("gpu_check: warning: over 60 MiB; the device tool carries 64 MiB in all")


# ---- run (on the GPU machine) -----------------------------------------------------------


def _step(cmd: list[str], cap: float, log, cwd: str | None = None) -> dict:
    """Run ``cmd`` with a wall-clock cap; output to ``log``; wall time, return code, tail."""
    start = time.perf_counter()
    log.write(f"\n$ {shlex.join(cmd)}   (cap {cap:.0f} s)\n")
    log.flush()
    try:
        done = subprocess.run(
            cmd, cwd=cwd or ROOT, capture_output=True, text=True, timeout=max(cap, 1)
        )
        out, rc = done.stdout + done.stderr, done.returncode
    except subprocess.TimeoutExpired as e:
        out = (e.stdout or b"").decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        out += (e.stderr or b"").decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
        rc = "timeout"
    log.write(out)
    log.flush()
    step = dict(wall_s=time.perf_counter() - start, rc=rc, tail=out[-2000:])
    if summary := pytest_summary(out):
        step["summary"] = [summary]
    return step


def pytest_summary(out: str) -> str:
    """pytest's result line in ``out`` ('2 failed, 46 passed, ...'); for a run cut before
    it, the counts of its progress lines ('progress: 2 passed, 0 failed'); else ''."""
    lines = out.splitlines()
    for line in reversed(lines):
        if re.search(r"\d+ (passed|failed|error)", line) and " in " in line:
            return line.strip("= ").strip()
    marks = "".join(m.group(1) for line in lines if (m := re.match(r"^([.FEsxX]+)\s+\[", line)))
    if not marks:
        return ""
    return f"progress: {marks.count('.')} passed, {marks.count('F') + marks.count('E')} failed"


def _json_line(text: str, key: str) -> dict | None:
    """The last line of ``text`` that is a JSON object holding ``key``."""
    for line in reversed(text.splitlines()):
        line = line.strip()
        if line.startswith("{") and key in line:
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                continue
    return None


_VERSIONS = (
    "import json, platform, cfm_jax, jax, jaxlib, mujoco, flax, optax\n"
    "from mujoco import mjx\n"
    "from importlib.metadata import version\n"
    "d = jax.devices()[0]\n"
    "print(json.dumps(dict(python=platform.python_version(), jax=jax.__version__,\n"
    "  jaxlib=jaxlib.__version__, mujoco=mujoco.__version__, mjx=version('mujoco-mjx'),\n"
    "  flax=flax.__version__, optax=optax.__version__, platform=d.platform,\n"
    "  device=getattr(d, 'device_kind', str(d)), xla_flags=__import__('os').environ.get(\n"
    "  'XLA_FLAGS', ''), fast_xla=cfm_jax.FAST_XLA, versions=1)))\n"
)


def _final_errors(out_dir: str) -> dict:
    """Final tracking MSE per loss (mean over the runs that did not diverge, and how many
    diverged) and the baselines' means, from the run's CSV files (partial runs: the losses
    that finished)."""
    import pandas as pd

    paths = [os.path.join(out_dir, "metrics.csv")]
    if not os.path.exists(paths[0]):
        paths = sorted(glob.glob(os.path.join(out_dir, "*", "metrics.csv")))
    result: dict = {}
    if paths:
        m = pd.concat([pd.read_csv(p) for p in paths])
        for loss, rows in m.groupby("loss", sort=False):
            last = rows[rows.iteration == rows.iteration.max()]
            ok = last[last.diverged == 0]
            result[loss] = dict(
                mse=float(ok.tracking_mse.mean()) if len(ok) else float("nan"),
                diverged=int((last.diverged != 0).sum()),
                runs=len(last),
                iteration=int(rows.iteration.max()),
            )
    base = os.path.join(out_dir, "baselines.csv")
    if not os.path.exists(base):
        found = sorted(glob.glob(os.path.join(out_dir, "*", "baselines.csv")))
        base = found[0] if found else ""
    if base:
        b = pd.read_csv(base)
        for name, rows in b.groupby("baseline"):
            result[name] = dict(mse=float(rows.tracking_mse.mean()))
    return result


def run(out: str, budget: float, train_args: str, tests: bool) -> dict:
    """Every step within ``budget`` seconds; the table to stdout and OUT; returns the record."""
    os.makedirs(out, exist_ok=True)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    start = time.perf_counter()
    left = lambda: budget - (time.perf_counter() - start)  # noqa: E731
    record: dict = dict(date=time.strftime("%Y-%m-%d"), host=platform.node(), steps={})
    py = sys.executable
    with open(os.path.join(out, "gpu_check.log"), "w") as log:
        step = _step([py, "-c", _VERSIONS], min(60, left()), log)
        record["versions"] = _json_line(step["tail"], "versions") or {"error": step["tail"]}
        record["steps"]["versions"] = step
        if tests:
            for name, files, cap in (("tests (device)", QUICK_TESTS, 90),
                                     ("tests (learning)", LEARNING_TESTS, 150)):  # fmt: skip
                n = str(min(len(files), 4))
                step = _step(
                    [py, "-m", "pytest", *PYTEST_FLAGS, "-n", n, *files],
                    min(cap, left()),
                    log,
                )
                record["steps"][name] = step
        step = _step(
            [py, "-m", "cfm_jax.analysis.bench", "--robot", "iiwa14", "--batch", "16", "--no-torch",
             "--json"],
            min(90, left()),
            log,
            cwd=out,
        )  # fmt: skip
        step["bench"] = _json_line(step["tail"], "iteration_s")
        record["steps"]["bench"] = step
        extra = shlex.split(train_args)
        for simulator, share in (("native", 0.45), ("mjx", 1.0)):
            run_dir = os.path.join(out, f"quickstart_{simulator}")
            stats = os.path.join(out, f"quickstart_{simulator}.json")
            cap = max(30.0, share * left() if simulator == "native" else left())
            cap = min(cap, 180.0) if simulator == "native" else cap
            step = _step(
                [py, os.path.abspath(__file__), "_train", "--stats", stats, "--deadline",
                 str(cap - 5), "--", "--out", run_dir, "--quiet", "--simulator", simulator,
                 *extra],
                cap,
                log,
                cwd=out,
            )  # fmt: skip
            step["stats"] = json.load(open(stats)) if os.path.exists(stats) else None
            step["errors"] = _final_errors(run_dir)
            record["steps"][f"quickstart {simulator}"] = step
    record["total_s"] = time.perf_counter() - start
    text = table(record)
    print(text)
    with open(os.path.join(out, "gpu_check.md"), "w") as f:
        f.write(text + "\n")
    with open(os.path.join(out, "gpu_check.json"), "w") as f:
        json.dump(record, f, indent=1, default=str)
    return record


def _fmt(x, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        if x != x:
            return "nan"
        return f"{x:.{digits}g}" if abs(x) < 1e4 else f"{x:,.0f}"
    return str(x)


def table(record: dict) -> str:
    """The record as Markdown: versions, one row per step, the bench split, final errors.

    Examples:
      >>> r = dict(date="2026-11-26", host="h", versions=dict(jax="0.11.2"), total_s=1.0,
      ...          steps=dict(versions=dict(wall_s=1.0, rc=0, tail="")))
      >>> print(table(r).splitlines()[0])
      ## GPU check, 2026-11-26 (h)
    """
    v = record.get("versions", {})
    lines = [f"## GPU check, {record['date']} ({record['host']})", ""]
    lines.append(
        f"Device {v.get('device', '?')} ({v.get('platform', '?')}); Python {v.get('python')}, "
        f"jax {v.get('jax')}, jaxlib {v.get('jaxlib')}, mujoco {v.get('mujoco')}, "
        f"mujoco-mjx {v.get('mjx')}, flax {v.get('flax')}, optax {v.get('optax')}; "
        f"XLA_FLAGS={v.get('xla_flags')!r}, cfm_jax.FAST_XLA={v.get('fast_xla')}; "
        f"XLA_PYTHON_CLIENT_PREALLOCATE=false. Total {record['total_s']:.0f} s."
    )
    lines += ["", "| step | wall (s) | result | compile (s) | peak host / device (MiB) |",
              "|---|---:|---|---:|---|"]  # fmt: skip
    for name, s in record["steps"].items():
        status = "ok" if s["rc"] == 0 else ("cut by its cap" if s["rc"] == "timeout" else
                                           f"failed (rc {s['rc']})")  # fmt: skip
        if "summary" in s:
            status += f": {s['summary'][0][:80]}"
        compile_s, peak = "-", "-"
        st = s.get("stats")
        if st:
            compile_s = _fmt(sum(st["compile_s"].values()))
            peak = f"{_fmt(st['peak_host_mib'])} / {_fmt(st['peak_device_mib'])}"
            if not st["finished"]:
                status = f"cut by its cap after {', '.join(st['done']) or 'no loss'}"
        b = s.get("bench")
        if b:
            compile_s = f"{_fmt(b['iteration_compile_s'])} (iteration)"
            peak = f"{_fmt(b['peak_memory_mib'])} / -"
        lines.append(f"| {name} | {s['wall_s']:.1f} | {status} | {compile_s} | {peak} |")
    b = record["steps"].get("bench", {}).get("bench")
    if b:
        lines += ["", "`cfm-jax bench --robot iiwa14 --batch 16 --no-torch`: one training "
                  f"iteration {_fmt(b['iteration_s'])} s = rollout {_fmt(b['rollout_s'])} + "
                  f"forward update {_fmt(b['forward_update_s'])} + controller update "
                  f"{_fmt(b['controller_update_s'])} s; forward updates "
                  f"{_fmt(b['forward_updates_per_s'])}/s, controller updates "
                  f"{_fmt(b['controller_updates_per_s'])}/s; rollout "
                  f"{_fmt(b['rollout_steps_per_s'])} steps/s = {_fmt(b['ratio'])} of "
                  f"mujoco.rollout; rollout compile {_fmt(b['rollout_compile_s'])} s, "
                  f"iteration compile {_fmt(b['iteration_compile_s'])} s."]  # fmt: skip
    runs = {k: s for k, s in record["steps"].items() if k.startswith("quickstart")}
    if runs:
        names: list[str] = []
        for s in runs.values():
            names += [n for n in s["errors"] if n not in names]
        lines += ["", "Final tracking MSE (rad^2; mean over runs that did not diverge, "
                  "diverged count in brackets where any):", "",
                  "| run | " + " | ".join(names) + " |",
                  "|---|" + "---:|" * len(names)]  # fmt: skip
        for k, s in runs.items():
            cells = []
            for n in names:
                e = s["errors"].get(n)
                if e is None:
                    cells.append("-")
                else:
                    d = f" ({e['diverged']} div.)" if e.get("diverged") else ""
                    cells.append(_fmt(e["mse"], 2) + d)
            lines.append(f"| {k} | " + " | ".join(cells) + " |")
        for k, s in runs.items():
            st = s.get("stats")
            if st:
                parts = ", ".join(f"{n.rsplit('/', 1)[-1]} {t:.1f} s"
                                  for n, t in st["compile_s"].items())  # fmt: skip
                finished_at = st["loss_wall_s"]
                lines.append(f"\n{k}: compile events {parts or 'none'}; each loss "
                             f"finished at (s from the start) {finished_at}.")  # fmt: skip
    return "\n".join(lines)


def _train(argv: list[str], stats: str, deadline: float) -> None:
    """``cfm-jax train ARGV`` in this process, timing JAX's compile events; writes ``stats``
    (also when ``deadline`` seconds pass first: then the process ends there, code 124)."""
    import threading

    import jax

    import cfm_jax  # noqa: F401  (first: the XLA flag, where the jaxlib knows it)

    start = time.perf_counter()
    compile_s: dict[str, float] = collections.defaultdict(float)

    def listen(event: str, secs: float, **_) -> None:
        if event.startswith("/jax/core/compile/"):
            compile_s[event] += secs

    jax.monitoring.register_event_duration_secs_listener(listen)
    out_dir = argv[argv.index("--out") + 1]
    loss_wall: dict[str, float] = {}

    def done_losses() -> list[str]:
        # A loss is done when its folder has its metrics.csv (written when it finishes).
        found = sorted(glob.glob(os.path.join(out_dir, "*", "metrics.csv")),
                       key=os.path.getmtime)  # fmt: skip
        for p in found:
            loss_wall.setdefault(os.path.basename(os.path.dirname(p)),
                                 round(os.path.getmtime(p) - wall0, 1))  # fmt: skip
        return [os.path.basename(os.path.dirname(p)) for p in found]

    def dump(finished: bool) -> None:
        import resource

        try:
            mem = jax.devices()[0].memory_stats() or {}
        except Exception:  # noqa: BLE001  (a backend without memory stats)
            mem = {}
        peak_host = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        with open(stats, "w") as f:
            json.dump(dict(finished=finished, wall_s=time.perf_counter() - start,
                           compile_s=dict(compile_s), done=done_losses(),
                           loss_wall_s=dict(loss_wall), peak_host_mib=peak_host,
                           peak_device_mib=mem.get("peak_bytes_in_use", 0) / 2**20 or None),
                      f)  # fmt: skip

    def expire() -> None:
        dump(False)
        os._exit(124)

    wall0 = time.time()
    timer = threading.Timer(deadline, expire)
    timer.daemon = True
    timer.start()
    from cfm_jax import cli

    sys.argv = ["cfm-jax", "train", *argv]
    try:
        cli.main()
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    finally:
        timer.cancel()
    dump(True)


def publish(table_md: str) -> None:
    """``docs/benchmarks_gpu.md`` and the ``gpu-check`` section of docs/benchmarks.md from a
    table that ``run`` wrote on the GPU machine."""
    import _study

    with open(table_md) as f:
        section = f.read()
    _study.write_benchmark_section(
        os.path.join(ROOT, "docs", "benchmarks_gpu.md"), "gpu-check", section
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare", help="wheels for the GPU machine into .whl/")
    p.add_argument("--python-version", default="3.12")
    r = sub.add_parser("run", help="the check, on the GPU machine")
    r.add_argument("--out", default=os.environ.get("OUT") or "gpu_check_out")
    r.add_argument("--budget", type=float, default=450.0, help="seconds for all steps")
    r.add_argument("--train-args", default="", help="extra cfm-jax train flags (dry runs)")
    r.add_argument("--no-tests", action="store_true", help="skip the test files")
    w = sub.add_parser("publish", help="the table of a run into docs/benchmarks*.md")
    w.add_argument("table", help="OUT/gpu_check.md of a run")
    t = sub.add_parser("_train", help=argparse.SUPPRESS)
    t.add_argument("--stats", required=True)
    t.add_argument("--deadline", type=float, required=True)
    t.add_argument("argv", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    if args.cmd == "prepare":
        prepare(args.python_version)
    elif args.cmd == "publish":
        publish(args.table)
    elif args.cmd == "run":
        record = run(os.path.abspath(args.out), args.budget, args.train_args, not args.no_tests)
        # A step cut by its cap (timeout, or 124 from _train's own deadline) is reported, not
        # failed; any other non-zero code fails the check.
        failed = [k for k, s in record["steps"].items() if s["rc"] not in (0, 124, "timeout")]
        sys.exit(1 if failed else 0)
    else:
        argv = args.argv[1:] if args.argv[:1] == ["--"] else args.argv
        _train(argv, args.stats, args.deadline)


if __name__ == "__main__":
    main()
