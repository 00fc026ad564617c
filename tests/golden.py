"""Bit-identity of the native simulator's numbers across restructurings of the library.

The oracle is the library itself before a restructuring: ``tests/golden/<name>.json`` holds
the metrics and baselines of a small run of each task (one test per task calls
:func:`assert_bit_identical`), every float as ``float.hex`` so that equality is exact,
recorded by the commit named in the file; ``losses.json`` holds every library loss trained
together (test_train's batched-losses test). A change that moves code without changing the
computation keeps them; a change that means to change the numbers (a new default, a fixed
bug) re-records them with

    CFM_JAX_WRITE_GOLDEN=1 pytest tests -k "bit_identical or trains_end_to_end or losses_batched"

and says so in its commit message.

The numbers hold for one build of JAX, XLA and MuJoCo on one kind of CPU: XLA compiles for
the host's instruction set (AVX2, AVX-512, FMA, ...), and another CPU may round the last
bits differently (seen: an AMD EPYC with AVX2 and the machine of the first record differ
in the 8th digit of the inverse-dynamics run, and the legged runs, chaotic, visibly). So a
file holds one record per machine (versions, CPU model and instruction-set flags), and a
test compares with the record of its machine, bit for bit. Add one for a new machine from
the commit *before* a restructuring (``git worktree add /tmp/before <commit>``, then the
command above there, with ``PYTHONPATH=/tmp/before``) and copy the files back, never from
the changed code.

Where no record matches (another CPU, or versions other than those of ``constraints.txt``,
which CI installs), the test is not skipped: it compares with every record at the
tolerances of :data:`SPREAD` and :data:`MARGIN`, derived from how far the recorded
machines' numbers lie apart (:func:`tolerant_violations`). ``CFM_JAX_GOLDEN_HIDE_MACHINE=1``
hides this machine's record, to see what an unknown machine would be told (a mutation
check: a forward-model learning rate 1 % higher fails the arm tasks that way too).
"""

from __future__ import annotations

import json
import math
import os
import platform
import re
import subprocess
from pathlib import Path

import jax
import jaxlib
import mujoco
import pandas as pd
import pytest

GOLDEN = Path(__file__).parent / "golden"
# Columns that measure time or the machine, not the computation.
NOT_COMPARED = ("seconds", "wall", "time")
# Columns added after the records, with the value every recorded run must have there (in
# none of them did a simulation diverge): they are checked for that value, not for bits.
ADDED_SINCE = {"diverged": 0.0, "diverged_step": -1.0}


# ---- tolerances for a machine without a record -------------------------------------------
#
# SPREAD[task][table][column]: the largest relative difference |a - b| / max(|a|, |b|) over
# the rows between the records of the two recorded machines (AMD EPYC with AVX2 only, at
# 4173512, and AMD EPYC with AVX-512, at df7f680; same jax/jaxlib 0.10.2 and MuJoCo 4.0.0),
# rounded up to 3 digits; tests/test_golden_guard.py recomputes it from the files. A
# machine without a record must lie within MARGIN times that of every record: 10x, since
# two machines sample the rounding differences of CPUs only thinly (another CPU may round
# differently again), and 10x still leaves the arm tasks' negative control (forward model
# learning rate 1 % higher, measured below) outside. A spread of 0 (every baseline: MuJoCo
# C in float64; the counts) is compared at FLOOR, 10 float32 eps, so that a count or a
# baseline that moves by one unit fails. Columns not in SPREAD are not compared in value.
#
# Negative control, measured on this machine (TINY, resp. the op-space test's config, with
# forward.learning_rate x 1.01), relative move against the records: inverse_dynamics
# tracking_mse 2.3e-2, prediction_error 0.145, predicted_task_error 5.7e-2, forward_loss
# 1.8e-2, controller_loss 1.6e-2 (9x to 230x the tolerance below); opspace tracking_mse
# 2.65e-2, prediction_error 4.0e-3, predicted_task_error 1.8e-2, forward_loss 5.5e-3,
# controller_loss 4.6e-3 (1500x to 4600x).
#
# The legged runs are chaotic: the baselines agree bit for bit between the two machines,
# but the learned controller's first rollout (iteration 0, after the fits on babbling
# data) already differs by 3 % (jump's transitions_added) to 95 % (jump's
# base_position_mse), and forward_loss (the refit after that rollout) by 12-27 %; 10x
# that is no check. So their metrics are compared only where they are not chaotic: fell
# and finite_fraction (same on both machines), the baselines (MuJoCo C, bit-identical),
# and the rows, columns and NaN pattern of the rest. The learning-rate control does not
# reach those: on the legged tasks it is caught only where a record matches, bit for bit.
# "losses" (one machine's record so far, no spread measured) is compared the same way; its
# joint loss is TINY's, held to the tolerances above as "inverse_dynamics".
MARGIN = 10.0
FLOOR = 10 * 1.1920929e-07
_ARM = ("finite_fraction", "transitions_added")
SPREAD = {
    "inverse_dynamics": {
        "metrics": {
            "tracking_mse": 1.44e-4,
            "prediction_error": 1.57e-3,
            "predicted_task_error": 1.88e-4,
            "forward_loss": 7.89e-6,
            "controller_loss": 3.70e-5,
            **dict.fromkeys(_ARM, 0.0),
        },
        "baselines": {"tracking_mse": 0.0},
    },
    "opspace": {
        "metrics": {
            "tracking_mse": 7.48e-7,
            "prediction_error": 2.64e-7,
            "predicted_task_error": 7.23e-7,
            "forward_loss": 1.04e-7,
            "controller_loss": 0.0,
            **dict.fromkeys(_ARM, 0.0),
        },
        "baselines": {"tracking_mse": 0.0},
    },
    **{
        legged: {
            "metrics": {"finite_fraction": 0.0, "fell": 0.0},
            "baselines": dict.fromkeys(
                ("tracking_mse", "force_mse", "fell", "base_position_mse", "base_orientation_mse"),
                0.0,
            ),
        }
        for legged in ("jump", "walk")
    },
}


def tolerance(name: str, table: str, column: str) -> float | None:
    """Relative tolerance of a column on a machine without a record; None: not compared."""
    spread = SPREAD.get(name, {}).get(table, {}).get(column)
    return None if spread is None else max(MARGIN * spread, FLOOR)


# /proc/cpuinfo flags that change what XLA's CPU compiler emits.
ISA = re.compile(r"^(sse4_[12]|avx.*|fma.*|f16c|amx.*)$")


def _cpu() -> dict:
    model, flags = platform.processor() or platform.machine(), []
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = sorted(f for f in value.split() if ISA.match(f))
                break
    except OSError:
        pass
    return {"model": model, "isa": flags}


def _machine() -> dict:
    return {
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "mujoco": mujoco.__version__,
        "platform": jax.default_backend(),
        "cpu": _cpu(),
    }


def _encode(frame: pd.DataFrame) -> dict:
    columns = [c for c in frame.columns if not any(word in c for word in NOT_COMPARED)]
    out = {}
    for column in columns:
        values = frame[column].tolist()
        if pd.api.types.is_float_dtype(frame[column]):
            values = [float(v).hex() for v in values]
        else:
            values = [v if isinstance(v, str) else int(v) for v in values]
        out[column] = values
    return out


def _commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).parent,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _dumps(records: list[dict]) -> str:
    """JSON with one line per column, so that a re-recording shows as a readable diff."""
    out = []
    for record in records:
        lines = []
        for i, (key, value) in enumerate(record.items()):
            comma = "," if i < len(record) - 1 else ""
            if key in ("metrics", "baselines"):
                cols = [f"    {json.dumps(c)}: {json.dumps(v)}" for c, v in value.items()]
                lines.append(f"   {json.dumps(key)}: {{\n" + ",\n".join(cols) + f"\n   }}{comma}")
            else:
                lines.append(f"   {json.dumps(key)}: {json.dumps(value)}{comma}")
        out.append("  {\n" + "\n".join(lines) + "\n  }")
    return '{\n "records": [\n' + ",\n".join(out) + "\n ]\n}\n"


def _records(path: Path) -> list[dict]:
    return json.loads(path.read_text())["records"] if path.is_file() else []


def _show(value) -> str:
    try:
        return f"{float.fromhex(value)!r} ({value})"
    except (TypeError, ValueError):
        return repr(value)


def _decode(values: list) -> list:
    out = []
    for v in values:
        try:
            out.append(float.fromhex(v))
        except (TypeError, ValueError):
            out.append(v)
    return out


def _without_added(name: str, table: str, expected: dict, actual: dict) -> dict:
    """``actual`` less the :data:`ADDED_SINCE` columns the record lacks (checked here)."""
    actual = dict(actual)
    for column, value in ADDED_SINCE.items():
        if column in actual and column not in expected:
            values = {float.fromhex(v) for v in actual.pop(column)}
            assert values <= {value}, f"{name} {table}.{column}: {values}, not {value}"
    return actual


def tolerant_violations(name: str, got: dict, record: dict) -> list[str]:
    """How ``got`` (``{"metrics": ..., "baselines": ...}`` as :func:`_encode` gives them)
    departs from ``record`` at the tolerances of :func:`tolerance`: other columns or rows,
    other labels (strings, integers), another NaN pattern, or a compared float column with
    ``|a - b| > tolerance * max(|a|, |b|)``; one line per column, empty if none."""
    problems = []
    for table in ("metrics", "baselines"):
        expected = record[table]
        actual = _without_added(name, table, expected, got[table])
        if sorted(actual) != sorted(expected):
            problems.append(f"{table}: columns {sorted(actual)}, recorded {sorted(expected)}")
            continue
        for column, values in expected.items():
            if len(actual[column]) != len(values):
                problems.append(f"{table}.{column}: {len(actual[column])} rows, not {len(values)}")
                continue
            want, have = _decode(values), _decode(actual[column])
            if not all(isinstance(v, float) for v in want + have):
                if want != have:
                    problems.append(f"{table}.{column}: other values")
                continue
            if [math.isnan(v) for v in want] != [math.isnan(v) for v in have]:
                problems.append(f"{table}.{column}: other NaN rows")
                continue
            rtol = tolerance(name, table, column)
            if rtol is None:
                continue
            worst, row = 0.0, 0
            for i, (a, b) in enumerate(zip(have, want, strict=True)):
                if a != b and not (math.isnan(a) and math.isnan(b)):
                    rel = abs(a - b) / max(abs(a), abs(b))
                    worst, row = (rel, i) if rel > worst else (worst, row)
            if worst > rtol:
                problems.append(
                    f"{table}.{column}: row {row}: {have[row]!r} instead of {want[row]!r}, "
                    f"relative {worst:.3g} > {rtol:.3g}"
                )
    return problems


def assert_bit_identical(name: str, result) -> None:
    """``result.metrics`` and ``result.baselines`` equal this machine's record bit for bit;
    without one (or with ``CFM_JAX_GOLDEN_HIDE_MACHINE=1``), every record within the
    tolerances of :func:`tolerance`."""
    path = GOLDEN / f"{name}.json"
    got = {"metrics": _encode(result.metrics), "baselines": _encode(result.baselines)}
    machine, records = _machine(), _records(path)
    if os.environ.get("CFM_JAX_WRITE_GOLDEN") == "1":
        GOLDEN.mkdir(exist_ok=True)
        others = [r for r in records if r["machine"] != machine]
        record = {"recorded_at_commit": _commit(), "machine": machine, **got}
        path.write_text(_dumps(others + [record]))
        return
    if not records:
        pytest.fail(f"{path} is missing; record it with CFM_JAX_WRITE_GOLDEN=1 (see {__file__})")
    if os.environ.get("CFM_JAX_GOLDEN_HIDE_MACHINE") == "1":
        records = [r for r in records if r["machine"] != machine]
    mine = [r for r in records if r["machine"] == machine]
    if not mine:
        problems = {
            f"{r['machine']['cpu']['model']} {r['machine']['cpu']['isa']} at commit "
            f"{r['recorded_at_commit'][:7]}": tolerant_violations(name, got, r)
            for r in records
        }
        problems = {k: v for k, v in problems.items() if v}
        assert not problems, (
            f"{name} lies outside the tolerances of {__file__} (SPREAD x MARGIN) around the "
            f"record(s) of other machines; this machine: {machine}. Where the versions "
            f"differ from constraints.txt that may be a new build, not a bug: add a record "
            f"from the commit before the change (see {__file__}). "
            + "; ".join(f"{k}: " + "; ".join(v) for k, v in problems.items())
        )
        return
    record = mine[0]
    for table in ("metrics", "baselines"):
        expected = record[table]
        actual = _without_added(name, table, expected, got[table])
        assert sorted(actual) == sorted(expected), f"{name} {table}: other columns"
        for column, values in expected.items():
            assert len(actual[column]) == len(values), f"{name} {table}: other row count"
            if values != actual[column]:
                pairs = zip(values, actual[column], strict=True)
                i = next(k for k, (a, b) in enumerate(pairs) if a != b)
                raise AssertionError(
                    f"{name} {table}.{column} differs from the numbers recorded at commit "
                    f"{record['recorded_at_commit'][:7]}: row {i}: {_show(actual[column][i])} "
                    f"instead of {_show(values[i])} ({len(values)} rows)"
                )
