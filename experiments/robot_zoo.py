"""The quickstart protocol on every robot of a folder: one table of final tracking error per
loss against PD-only and the oracle, diverged counts and wall times.

Not a test: a study. For each ``*.xml`` of ``--robots`` (default ``tests/robots/``, the
development set of published arms) it runs ``cfm-jax train`` as a user would with the
library's defaults (inverse dynamics, the four losses, ``--seeds`` seeds, 4 iterations,
5 reaching targets), each robot in its own process and output folder
(``--out/ROBOT``). Servos are converted to torque motors (``--robot-actuators torque``:
motors stay as they are); a ``robots.json`` beside the files may give per file the CLI
flags of its own (``{"arm.xml": ["--robot-torque-limit", "40", "20"]}``), e.g. torque
limits for a file that has none. A robot the library refuses, or a run that fails, is a row
that says why.

Other tasks: ``--tasks walk,jump`` runs the legged tasks instead (e.g. on
``--robots tests/robots/quadrupeds``), each with its own defaults
(``cfm_jax.config.for_task(task)`` with the robot replaced) and the CLI's iterations; a
flag ``--robot-actuators`` in ``robots.json`` replaces the zoo's ``torque``. Where a default
cannot run on a robot, one general rule replaces it, for every loss of that robot alike
(:func:`fallback`): a default that needs MJX (``forward.kind='rigid_body'``,
``simulator='mjx'``) becomes its native counterpart (``mlp``, ``native``) on a robot MJX
cannot build (the Go2's and ANYmal's cylinder-box collisions); the row says so. A legged
task's table adds the runs that fell (its ``fell`` metric) beside each tracking MSE.

Resumable: a robot whose folder already holds a finished run (every loss at its last
iteration) is read, not run again; an interrupted one resumes from its checkpoints
(``--resume``). One folder per robot and task: ``--out/seeds3/ROBOT`` for the inverse
dynamics, ``--out/TASK_seeds3/ROBOT`` for the others. Writes ``--table`` (default
``docs/results/robots.md``) after every robot, one table per task.

Usage:
  python experiments/robot_zoo.py [--robots tests/robots] [--seeds 3]
      [--out results/robot_zoo] [--table docs/results/robots.md] [--only NAME,...]
  python experiments/robot_zoo.py --robots tests/robots/quadrupeds --tasks walk,jump \
      --seeds 3 --table docs/results/quadrupeds.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np
import pandas as pd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOSSES = ("joint", "task", "distal", "supervised")
REFUSED = "zoo_refused.txt"  # in a robot's output folder: why its last run failed
CODE = "zoo_code.txt"  # in a robot's output folder: the commit of the code that ran it
# (``START..END`` where the code changed while it ran: the last piece's start and end)
MACHINE = "zoo_machine.txt"  # and the machine that ran it: JAX's device, cores, JAX version
ARMS = "inverse_dynamics"  # the default task (the arms' table)
ARMS_FOLDER = os.path.join(ROOT, "tests", "robots")  # the arms' development set
ARMS_PAGE = os.path.join("docs", "results", "robots.md")  # its page, the --table default
# The defaults that need MJX, and what replaces them on a robot MJX cannot build.
NEEDS_MJX = {"forward.kind": ("rigid_body", "mlp"), "simulator": ("mjx", "native")}


def defaults_of(task: str) -> dict[str, str]:
    """The MJX-sensitive defaults of ``task`` (``cfm_jax.config.for_task``), by flag path."""
    from cfm_jax import config

    base = config.for_task(task)
    return {"forward.kind": base.forward.kind, "simulator": base.simulator}


def fallback(defaults: dict[str, str], mjx_builds: bool) -> list[str]:
    """The CLI flags of the one fallback rule: on a robot MJX cannot build, each default
    that needs MJX becomes its native counterpart (:data:`NEEDS_MJX`), for every loss; else
    none. Never a choice per robot: only whether MJX builds it decides."""
    if mjx_builds:
        return []
    flags: list[str] = []
    for path, (needs, instead) in NEEDS_MJX.items():
        if defaults.get(path) == needs:
            flags += [f"--{path}", instead]
    return flags


def mjx_error(path: str, flags: list[str]) -> str | None:
    """Why MJX cannot build the robot file ``path`` loaded as its flags say
    (``--robot-actuators``, default ``torque``; ``--robot-torque-limit``), or None."""
    from cfm_jax.sim import robots

    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--robot-actuators", default="torque")
    parser.add_argument("--robot-torque-limit", nargs="+", type=float)
    known, _ = parser.parse_known_args(flags)
    limit = known.robot_torque_limit
    if limit is not None and len(limit) == 1:
        limit = limit[0]
    robot = robots.load(path, actuators=known.robot_actuators, torque_limit=limit)
    return robot.mjx_error


def mjx_builds(path: str, flags: list[str]) -> bool:
    """:func:`mjx_error` is None, asked of a child process (this one keeps off the GPU);
    a robot that does not load counts as built (the run itself then says why)."""
    probe = (
        "import json, sys; import robot_zoo; "
        "print(json.dumps(robot_zoo.mjx_error(sys.argv[1], sys.argv[2:]) is None))"
    )
    here = os.path.dirname(os.path.abspath(__file__))
    path_env = os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH")) if p)
    done = subprocess.run(
        [sys.executable, "-c", probe, path, *flags],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": path_env},
    )
    lines = done.stdout.strip().splitlines()
    return done.returncode != 0 or not lines or json.loads(lines[-1])


def run_folder(out: str, task: str, seeds: int, tag: str = "") -> str:
    """The folder of one task's runs (one subfolder per robot)."""
    name = f"seeds{seeds}{tag and '_' + tag}"
    return os.path.join(out, name if task == ARMS else f"{task}_{name}")


def code_version(root: str = ROOT) -> str:
    """The commit of the code in ``root`` (short hash; ``+changes`` where tracked files
    differ from it), or ``unknown`` outside a git checkout."""

    def git(*args: str) -> str:
        done = subprocess.run(["git", "-C", root, *args], capture_output=True, text=True)
        if done.returncode != 0:
            raise OSError(done.stderr)
        return done.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except OSError:
        return "unknown"
    return head + ("+changes" if dirty else "")


def flags_of(folder: str) -> dict[str, list[str]]:
    """``robots.json`` of ``folder``: ``{file name: [extra CLI flags]}`` (none: ``{}``)."""
    path = os.path.join(folder, "robots.json")
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        table = json.load(f)
    for name, flags in table.items():
        if not isinstance(flags, list) or not all(isinstance(x, str) for x in flags):
            raise SystemExit(
                f"robot_zoo: {path}: the value of {name!r} must be a list of strings "
                f"(CLI flags), got {flags!r}"
            )
    return table


def finished(out: str, extra: list[str] = ()) -> bool:
    """Whether ``out`` holds a finished run: every loss has the metrics of its last
    iteration (``summary.md`` alone is written after each loss). A run that ``extra``
    asks to take further (``--loop.iterations N`` above the run's) is not finished:
    it resumes and continues."""
    try:
        with open(os.path.join(out, "config.json")) as f:
            iterations = json.load(f)["loop"]["iterations"]
        metrics = pd.read_csv(os.path.join(out, "metrics.csv"))
    except (OSError, KeyError, ValueError):
        return False
    flags = list(extra)
    for i, flag in enumerate(flags[:-1]):
        if flag == "--loop.iterations":
            iterations = max(iterations, int(flags[i + 1]))
    last = metrics.groupby("loss").iteration.max()
    return all(last.get(loss, -1) >= iterations for loss in LOSSES)


def _vectors() -> str:
    """The processor's widest vector instructions as the probe's f-string part: ``" AVX-512"``,
    ``" AVX2"`` or nothing (one model name, e.g. "AMD EPYC", covers CPUs with and without
    AVX-512, which round differently)."""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line.split(":", 1)[1].split() for line in f
                          if line.split(":")[0].strip() == "flags"), [])  # fmt: skip
    except OSError:
        return ""
    return " AVX-512" if "avx512f" in flags else " AVX2" if "avx2" in flags else ""


def machine() -> str:
    """JAX's first device, the processor's model and architecture (XLA compiles for its
    instruction set: a seed's numbers reproduce on the same kind of CPU only), its cores and
    JAX's version, as ``cfm-jax train`` sees them (asked of a child process, so that this one
    never takes the GPU's memory)."""
    from cfm_jax.analysis import bench

    probe = "import jax; print(jax.devices()[0].device_kind); print(jax.__version__)"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    if done.returncode != 0:
        return "unknown"
    kind, version = done.stdout.strip().rsplit("\n", 1)  # a device kind may hold spaces
    return (f"{kind} ({bench.processor()}{_vectors()}, {platform.machine()}, "
            f"{os.cpu_count()} cores), jax {version}")  # fmt: skip


def run_robot(
    path: str, out: str, seeds: int, extra: list[str], task: str = ARMS, defaults=None
) -> dict:
    """``cfm-jax train`` on one robot (or read its finished run); a summary dict.
    ``defaults``: the task's MJX-sensitive defaults (:func:`defaults_of`), for the
    fallback rule and the row's record of it."""
    done = finished(out, extra)
    start = time.perf_counter()
    error = None
    defaults = defaults if defaults is not None else {}
    if not done:
        load = [] if "--robot-actuators" in extra else ["--robot-actuators", "torque"]
        if any(defaults.get(k) == needs for k, (needs, _) in NEEDS_MJX.items()):
            extra = [*extra, *fallback(defaults, mjx_builds(path, extra))]
        if task != ARMS:
            extra = ["--task", task, *extra]
        cmd = [sys.executable, "-m", "cfm_jax.cli", "train", "--robot", path, *load,
               "--seeds", str(seeds), "--out", out, "--quiet", *extra]  # fmt: skip
        # Resume what a run left; a folder holding only an earlier refusal has no run.
        if os.path.isdir(out) and set(os.listdir(out)) - {REFUSED}:
            cmd.append("--resume")
        started = code_version()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            lines = (proc.stderr or proc.stdout).strip().splitlines()
            error = lines[-1] if lines else f"exit status {proc.returncode}"
            # The CLI names the file by its absolute path: keep the reason, not the machine.
            error = "refused: " + error.removeprefix("cfm-jax: error: ").split("): ", 1)[-1]
            # Kept beside the runs, so that a later --only run of other robots still shows it.
            os.makedirs(out, exist_ok=True)
            with open(os.path.join(out, REFUSED), "w") as f:
                f.write(error + "\n")
        elif os.path.exists(os.path.join(out, REFUSED)):
            os.remove(os.path.join(out, REFUSED))
    wall = time.perf_counter() - start
    row = dict(robot=os.path.splitext(os.path.basename(path))[0], error=error)
    timing = os.path.join(out, "zoo_wall_s.txt")
    code = os.path.join(out, CODE)
    if not done and error is None:
        with open(timing, "w") as f:
            f.write(f"{wall:.0f}\n")
        ended = code_version()  # a run the code changed under names both commits
        with open(code, "w") as f:
            f.write((started if ended == started else f"{started}..{ended}") + "\n")
        with open(os.path.join(out, MACHINE), "w") as f:
            f.write(machine() + "\n")
    row["wall_s"] = float(open(timing).read()) if os.path.exists(timing) else float("nan")
    row["code"] = open(code).read().strip() if os.path.exists(code) else "not recorded"
    where = os.path.join(out, MACHINE)
    row["machine"] = open(where).read().strip() if os.path.exists(where) else "not recorded"
    if error is None:
        row.update(summarise(out))
        row["changed"] = changed_defaults(out, defaults)
    return row


def changed_defaults(out: str, defaults: dict[str, str]) -> str:
    """The defaults the run in ``out`` replaced (its ``config.json`` against ``defaults``),
    e.g. ``forward.kind=mlp``; ``""`` where none."""
    try:
        with open(os.path.join(out, "config.json")) as f:
            config = json.load(f)
    except (OSError, ValueError):
        return ""
    ran = {
        "forward.kind": config.get("forward", {}).get("kind"),
        "simulator": config.get("simulator"),
    }
    return ", ".join(f"{k}={ran[k]}" for k, v in defaults.items() if ran.get(k) not in (None, v))


def summarise(out: str) -> dict:
    """Per loss: seed means of the final tracking MSE (runs that diverged left out), their
    mean and bootstrap CI, diverged runs, seeds below PD-only; PD-only's and the oracle's
    means."""
    from cfm_jax.analysis import report

    metrics = pd.read_csv(os.path.join(out, "metrics.csv"))
    base = pd.read_csv(os.path.join(out, "baselines.csv"))
    pd_only = float(base[base.baseline == "pd_only"].tracking_mse.mean())
    oracle = float(base[base.baseline == "oracle"].tracking_mse.mean())
    result: dict = dict(pd_only=pd_only, oracle=oracle)
    if "fell" in base.columns:  # the legged tasks: baseline runs that fell, of how many
        for name in ("pd_only", "oracle"):
            rows = base[base.baseline == name]
            result[f"{name}_fell"] = (int((rows.fell.fillna(0) == 1).sum()), len(rows))
    means = report.seed_means(metrics)
    for loss in LOSSES:
        rows = metrics[metrics.loss == loss]
        if rows.empty:
            continue
        last = rows[rows.iteration == rows.iteration.max()]
        per_seed = means[means.loss == loss].tracking_mse.to_numpy()
        result[loss] = dict(
            stats=report.mean_ci(per_seed[np.isfinite(per_seed)]),
            diverged=int((last.diverged != 0).sum()),
            runs=len(last),
            below_pd=int((per_seed < pd_only).sum()),
            seeds=len(per_seed),
        )
        if "fell" in last.columns:
            result[loss]["fell"] = int((last.fell.fillna(0) == 1).sum())
    return result


def table(rows: list[dict], seeds: int, folder: str, note: str = "") -> str:
    """The results page (Markdown); ``note``: a paragraph on a variant run's flags."""
    lines = [
        "# The defaults on published robots",
        "",
        f"Written by `python experiments/robot_zoo.py --robots {folder} --seeds {seeds}`, "
        f"{datetime.date.today().isoformat()}. "
        "Each robot: `cfm-jax train --robot FILE --robot-actuators torque` with the library's "
        "defaults (inverse dynamics, 5 reaching targets, 4 iterations). Cells: final tracking "
        "MSE (rad^2), mean over seeds of each seed's mean over its targets, with its 95% "
        "bootstrap interval; runs whose simulation diverged are left out of the mean and "
        "counted (`div.`); `below PD` is the number of seeds whose mean is below PD-only's; "
        "`code`: the commit that ran the robot (a resumed run: the commit that finished it); "
        "`machine`: JAX's device, the processor and JAX's version where it ran (wall times "
        "compare only on the same machine).",
        *(["", note] if note else []),
        "",
        *_arm_rows(rows, seeds),
    ]
    return "\n".join(lines) + "\n"


def _loss_cells(row: dict, seeds: int) -> list[str]:
    """Each loss's cell of a robot's row: its final tracking MSE (mean over seeds; with
    several, its 95% interval), the runs that fell (the legged tasks), the seeds below
    PD-only and the diverged runs; ``-`` for a loss not run."""
    from cfm_jax.analysis import report

    cells = []
    for loss in LOSSES:
        r = row.get(loss)
        if r is None:
            cells.append("-")
            continue
        text = report.ci_text(r["stats"]) if seeds > 1 else f"{r['stats']['mean']:.3g}"
        if "fell" in r:
            text += f"; {_fell((r['fell'], r['runs']))}"
        text += f"; below PD {r['below_pd']}/{r['seeds']}"
        if r["diverged"]:
            text += f"; div. {r['diverged']}/{r['runs']}"
        cells.append(text)
    return cells


def _arm_rows(rows: list[dict], seeds: int) -> list[str]:
    """The inverse dynamics' table: header and one line per robot."""

    lines = [
        "| robot | " + " | ".join(LOSSES) + " | PD-only | oracle | wall (s) | code | machine |",
        "|---|" + "---|" * len(LOSSES) + "---:|---:|---:|---|---|",
    ]
    for row in rows:
        if row.get("error"):
            lines.append(f"| {row['robot']} | {row['error']} " + "| " * (len(LOSSES) + 4) + "|")
            continue
        cells = _loss_cells(row, seeds)
        lines.append(
            f"| {row['robot']} | " + " | ".join(cells) + f" | {row['pd_only']:.3g} | "
            f"{row['oracle']:.3g} | {row['wall_s']:.0f} | {row.get('code', 'not recorded')} | "
            f"{row.get('machine', 'not recorded')} |"
        )
    return lines


def _fell(counts) -> str:
    return f"fell {counts[0]}/{counts[1]}"


def legged_rows(rows: list[dict], seeds: int) -> list[str]:
    """A legged task's table: header and one line per robot. Each loss: final tracking MSE
    (mean over seeds, 95% interval), runs that fell at the last iteration, seeds below
    PD-only, diverged runs; PD-only's and the oracle's MSE and falls; the defaults the
    fallback rule replaced."""

    lines = [
        "| robot | " + " | ".join(LOSSES) + " | PD-only | oracle | defaults replaced | "
        "wall (s) | code | machine |",
        "|---|" + "---|" * len(LOSSES) + "---:|---:|---|---:|---|---|",
    ]
    for row in rows:
        if row.get("error"):
            lines.append(f"| {row['robot']} | {row['error']} " + "| " * (len(LOSSES) + 5) + "|")
            continue
        cells = _loss_cells(row, seeds)
        base = [
            f"{row[name]:.3g}"
            + (f"; {_fell(row[name + '_fell'])}" if name + "_fell" in row else "")
            for name in ("pd_only", "oracle")
        ]
        changed = row.get("changed") or "none"
        if row.get("changed"):
            changed += " (MJX cannot build it)"
        lines.append(
            f"| {row['robot']} | " + " | ".join(cells + base) + f" | {changed} | "
            f"{row['wall_s']:.0f} | {row.get('code', 'not recorded')} | "
            f"{row.get('machine', 'not recorded')} |"
        )
    return lines


def page(
    results: dict[str, list[dict]], seeds: int, folder: str, note: str = "", defaults=None
) -> str:
    """The results page: the arms' :func:`table` where only the inverse dynamics ran, else
    one section per task (``defaults``: each task's MJX-sensitive defaults)."""
    if list(results) == [ARMS]:
        return table(results[ARMS], seeds, folder, note)
    defaults = defaults or {}
    tasks = ",".join(results)
    lines = [
        f"# The defaults on published robots: {', '.join(results)}",
        "",
        f"Written by `python experiments/robot_zoo.py --robots {folder} --tasks {tasks} "
        f"--seeds {seeds}`, {datetime.date.today().isoformat()}. "
        "Each robot and task: `cfm-jax train --robot FILE --task TASK` with the flags of the "
        "folder's `robots.json` (else `--robot-actuators torque`) and the task's defaults "
        "(`cfm_jax.config.for_task(TASK)`: the four losses, its iterations and references). "
        "Where a default needs MJX and MJX cannot build the robot, one rule for every robot "
        "and every loss alike replaces it by its native counterpart ("
        + ", ".join(f"`{k}='{a}'` by `'{b}'`" for k, (a, b) in NEEDS_MJX.items())
        + "): the column `defaults replaced` says where. Cells: final tracking MSE (the "
        "task's `tracking_mse`), "
        "mean over seeds of each seed's mean over its references (95% bootstrap interval "
        "with several seeds); `fell`: runs (seeds x references) whose robot fell at the last "
        "iteration (the task's `fell` metric; a run that fell still counts in the mean); "
        "`below PD`: seeds whose mean is below PD-only's; `div.`: runs whose simulation "
        "diverged, left out of the mean; `code`, `machine`: the commit and machine that "
        "ran the robot (wall times compare only on the same machine).",
        *(["", note] if note else []),
    ]
    for task, rows in results.items():
        said = ", ".join(f"{k}='{v}'" for k, v in (defaults.get(task) or {}).items())
        lines += ["", f"## {task}", ""]
        if said:
            lines += [f"Defaults: {said}.", ""]
        lines += _arm_rows(rows, seeds) if task == ARMS else legged_rows(rows, seeds)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", default=ARMS_FOLDER)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", default=os.path.join(ROOT, "results", "robot_zoo"))
    parser.add_argument("--table", help=f"the page to write; default {ARMS_PAGE} (the arms' set "
                        "only: another folder or a --tag must name its own)")  # fmt: skip
    parser.add_argument("--only", default="", help="comma-separated file stems")
    parser.add_argument(
        "--tasks",
        default=ARMS,
        help="comma-separated tasks, each with its own defaults (e.g. walk,jump on "
        "tests/robots/quadrupeds); default: inverse_dynamics",
    )
    parser.add_argument(
        "--tag",
        default="",
        help="a name for a variant run (its own output folder): with --flags-file, e.g. a "
        "diagnosis with other babbling noise; the defaults' run has none",
    )
    parser.add_argument(
        "--flags-file",
        default="",
        help="a JSON file like robots.json whose flags are added for this run (per file)",
    )
    args = parser.parse_args(argv)
    if not os.path.isdir(args.robots):
        raise SystemExit(f"robot_zoo: --robots {args.robots!r} is not a folder")
    if args.table is None:  # the arms' page is written over only by the arms' own run
        if os.path.realpath(args.robots) != os.path.realpath(ARMS_FOLDER) or args.tag:
            parser.error(
                f"--table is required with --robots {args.robots!r}"
                + (f" --tag {args.tag!r}" if args.tag else "")
                + f": the default page, {ARMS_PAGE}, is the arms' development set"
            )
        args.table = os.path.join(ROOT, ARMS_PAGE)
    files = sorted(f for f in os.listdir(args.robots) if f.endswith(".xml"))
    stems = [os.path.splitext(f)[0] for f in files]
    wanted = set(args.only.split(",")) if args.only else set(stems)
    unknown = wanted - set(stems)
    if unknown:
        raise SystemExit(f"robot_zoo: --only {sorted(unknown)} not in {args.robots}")
    extra = flags_of(args.robots)
    if args.flags_file:
        with open(args.flags_file) as f:
            for name, flags in json.load(f).items():
                extra[name] = extra.get(name, []) + list(flags)
    tasks = [t for t in args.tasks.split(",") if t]
    # Each task's defaults that need MJX (the fallback rule); the arms' run as before.
    defaults = {task: {} if task == ARMS else defaults_of(task) for task in tasks}
    results: dict[str, list[dict]] = {task: [] for task in tasks}
    folder = os.path.relpath(args.robots, ROOT)

    def write() -> None:
        note = ""
        if args.tag:
            ran = {f"{row['robot']}.xml" for rows in results.values() for row in rows}
            flags_file = os.path.relpath(args.flags_file, ROOT) if args.flags_file else ""
            given = f" --flags-file {flags_file}" if flags_file else ""
            note = (
                f"Variant `{args.tag}` (`--tag {args.tag}{given}`): added flags per file "
                + ", ".join(f"{k}: `{' '.join(v)}`" for k, v in sorted(extra.items()) if k in ran)
            )
        os.makedirs(os.path.dirname(os.path.abspath(args.table)), exist_ok=True)
        with open(args.table, "w") as f:
            f.write(page(results, args.seeds, folder, note, defaults))

    for task in tasks:
        rows = results[task]
        for name, stem in zip(files, stems, strict=True):
            out = os.path.join(run_folder(args.out, task, args.seeds, args.tag), stem)
            path = os.path.join(args.robots, name)
            if stem not in wanted:
                # Not asked for this time: its finished run or its refusal still goes into
                # the table, and a robot not yet run says so.
                if finished(out):
                    rows.append(run_robot(path, out, args.seeds, [], task, defaults[task]))
                elif os.path.exists(os.path.join(out, REFUSED)):
                    with open(os.path.join(out, REFUSED)) as f:
                        rows.append(dict(robot=stem, error=f.read().strip(), wall_s=float("nan")))
                else:
                    rows.append(dict(robot=stem, error="not run yet", wall_s=float("nan")))
                write()
                continue
            print(f"robot_zoo: {name} {task} ...", flush=True)
            row = run_robot(path, out, args.seeds, extra.get(name, []), task, defaults[task])
            print(f"robot_zoo: {name} {task}: {row.get('error') or 'done'} ({row['wall_s']:.0f} s)")
            rows.append(row)
            write()
    print(f"robot_zoo: wrote {args.table}")


if __name__ == "__main__":
    main()
