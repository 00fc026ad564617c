"""Bit-identity of the native simulator's numbers across restructurings of the library.

The oracle is the library itself before a restructuring: ``tests/golden/<name>.json`` holds
the metrics and baselines of a small run of each task (one test per task calls
:func:`assert_bit_identical`), every float as ``float.hex`` so that equality is exact,
recorded by the commit named in the file. A change that moves code without changing the
computation keeps them; a change that means to change the numbers (a new default, a fixed
bug) re-records them with

    CFM_JAX_WRITE_GOLDEN=1 pytest tests -k bit_identical

and says so in its commit message.

The numbers hold for one build of JAX, XLA and MuJoCo on one kind of CPU: XLA compiles for
the host's instruction set (AVX2, AVX-512, FMA, ...), and another CPU may round the last
bits differently (seen: an AMD EPYC with AVX2 and the machine of the first record differ
in the 8th digit of the inverse-dynamics run, and the legged runs, chaotic, visibly). So a
file holds one record per machine (versions, CPU model and instruction-set flags), and a
test compares with the record of its machine. Where none exists it is skipped with a
message saying how to add one: record it from the commit *before* the restructuring
(``git worktree add /tmp/before <commit>``, then the command above there, with
``PYTHONPATH=/tmp/before``) and copy the files back, never from the changed code.
"""

from __future__ import annotations

import json
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


def assert_bit_identical(name: str, result) -> None:
    """``result.metrics`` and ``result.baselines`` equal the recorded ones bit for bit."""
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
    mine = [r for r in records if r["machine"] == machine]
    if not mine:
        pytest.skip(
            f"no golden numbers of {name} for this machine ({machine}); {len(records)} "
            f"record(s) for others. Add one from the commit before a restructuring: see {__file__}"
        )
    record = mine[0]
    for table in ("metrics", "baselines"):
        expected, actual = record[table], dict(got[table])
        for column, value in ADDED_SINCE.items():
            if column in actual and column not in expected:
                values = {float.fromhex(v) for v in actual.pop(column)}
                assert values <= {value}, f"{name} {table}.{column}: {values}, not {value}"
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
