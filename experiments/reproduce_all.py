"""Every result of the paper in one command: the results scripts one after another, each in
its own process, and an index ``OUT/README.md`` with each result's wall time, its tables and
its figures.

Parts (``--only`` takes a comma-separated list of these names):

  theory_1d              theory_1d.py: the 1-D loss analysis (section III-B/C)
  iiwa_inverse_dynamics  iiwa_inverse_dynamics.py: inverse dynamics (Fig. 3a) and the
                         prediction error / predicted task error during learning (Fig. 4)
  opspace                opspace_study.py: operational-space control (Fig. 3b; Fig. 4)
  swap                   swap_study.py: the data-set swap (Fig. 3c)
  solo_walk              solo_study.py --task walk: Solo12 walking (IV-B, Table I, Fig. 5, 6)
  solo_jump              solo_study.py --task jump: Solo12 jumping (IV-B, Table I)

Each part writes into ``OUT/<part>/`` (its log in ``log.txt``). Interrupted parts resume
when started again (finished sweep cells, swap runs and op-space checkpoints are reused;
the 1-D theory is recomputed, it takes seconds). A failing part does not stop the others;
the exit status is 1 if any failed. ``--quick`` runs every part small (the arm studies:
networks of 16 units, a few dozen fit steps, 0.3 s references, 2 seeds, 1 iteration, 2
losses; the Solo12 study: 1 seed and 1 iteration of the real networks): a test that the
whole pipeline runs, not a result.

Usage:
  python experiments/reproduce_all.py --out results                 # full size, hours
  python experiments/reproduce_all.py --quick --out /tmp/quick      # smoke test
  python experiments/reproduce_all.py --only iiwa_inverse_dynamics --backend ray
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))

# name: (script and its arguments, paper result, tables, figures), files inside OUT/<part>/
PARTS = {
    "theory_1d": (
        ["theory_1d.py"],
        "1-D loss analysis (section III-B/C)",
        ["theory_table.md"],
        [
            "theory_landscape.png",
            "theory_iterated_map.png",
            "theory_error_curves.png",
            "theory_sweep.png",
        ],
    ),
    "iiwa_inverse_dynamics": (
        ["iiwa_inverse_dynamics.py"],
        "iiwa inverse dynamics (Fig. 3a; Fig. 4: the middle and right panels)",
        ["table.md", "summary.md"],
        ["curves.png"],
    ),
    "opspace": (
        ["opspace_study.py", "--resume"],
        "iiwa operational-space control (Fig. 3b; Fig. 4: the middle and right panels)",
        ["summary.md"],
        ["learning_curves.png"],
    ),
    "swap": (
        ["swap_study.py"],
        "data-set swap (Fig. 3c)",
        ["swap_table.md"],
        ["swap_study.png"],
    ),
    "solo_walk": (
        ["solo_study.py", "--task", "walk", "--resume"],
        "Solo12 walking (section IV-B: Table I, Fig. 5 and 6)",
        ["table_1.md", "summary.md"],
        ["learning_curves.png", "falls.png", "frames_joint.png", "force_joint.png"],
    ),
    "solo_jump": (
        ["solo_study.py", "--task", "jump", "--resume"],
        "Solo12 jumping (section IV-B: Table I)",
        ["table_1.md", "summary.md"],
        ["learning_curves.png", "falls.png", "frames_joint.png", "force_joint.png"],
    ),
}
SWEEP_PARTS = ("iiwa_inverse_dynamics",)  # the parts that take --backend and --address


def command(name: str, out: str, args) -> list[str]:
    script, *extra = PARTS[name][0]
    cmd = [sys.executable, os.path.join(HERE, script), *extra, "--out", out]
    if name != "theory_1d":
        cmd += ["--quiet"] + (["--quick"] if args.quick else [])
    if name in SWEEP_PARTS:
        cmd += ["--backend", args.backend]
        if args.address:
            cmd += ["--address", args.address]
    return cmd


def index(out: str, runs: dict, quick: bool, total: float) -> str:
    mode = "--quick: small, a pipeline test, not a result" if quick else "full size"
    lines = [
        "# Results",
        "",
        f"`python experiments/reproduce_all.py` ({mode}); total wall time {total:.0f} s.",
        "",
        "| part | paper result | status | wall time |",
        "|---|---|---|---:|",
    ]
    for name, (status, seconds) in runs.items():
        lines.append(f"| [{name}]({name}/) | {PARTS[name][1]} | {status} | {seconds:.0f} s |")
    for name, (status, _) in runs.items():
        lines += ["", f"## {name}: {PARTS[name][1]}", ""]
        if status != "ok":
            lines.append(f"{status}; see [{name}/log.txt]({name}/log.txt).")
            continue
        for table in PARTS[name][2]:
            path = os.path.join(out, name, table)
            if os.path.isfile(path):
                with open(path) as f:
                    lines += [f"`{table}`:", "", f.read().strip(), ""]
        for figure in PARTS[name][3]:
            if os.path.isfile(os.path.join(out, name, figure)):
                lines.append(f"![{name} {figure}]({name}/{figure})")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results")
    parser.add_argument("--quick", action="store_true", help="every part tiny (smoke test)")
    parser.add_argument("--only", default=",".join(PARTS), help="comma-separated part names")
    parser.add_argument("--backend", default="local", choices=("local", "ray"))
    parser.add_argument("--address", default=None, help="ray: an existing cluster")
    args = parser.parse_args()
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in PARTS]
    if bad or not names:
        parser.error(f"--only={args.only!r} is not allowed: names from {', '.join(PARTS)}")
    os.makedirs(args.out, exist_ok=True)
    start = time.perf_counter()
    runs = {}
    for name in names:
        part_out = os.path.abspath(os.path.join(args.out, name))
        os.makedirs(part_out, exist_ok=True)
        cmd = command(name, part_out, args)
        print(f"reproduce_all: {name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        with open(os.path.join(part_out, "log.txt"), "w") as log:
            code = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
        seconds = time.perf_counter() - t0
        status = "ok" if code == 0 else f"failed (exit status {code})"
        runs[name] = (status, seconds)
        print(f"reproduce_all: {name}: {status} in {seconds:.0f} s", flush=True)
        with open(os.path.join(args.out, "README.md"), "w") as f:
            f.write(index(args.out, runs, args.quick, time.perf_counter() - start))
    total = time.perf_counter() - start
    print(f"reproduce_all: {len(names)} part(s) in {total:.0f} s; index in {args.out}/README.md")
    if any(status != "ok" for status, _ in runs.values()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
