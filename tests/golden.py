"""Bit-identity of the native simulator's numbers across restructurings of the library.

The oracle is the library itself before a restructuring: ``tests/golden/<name>.json`` holds
the metrics and baselines of a small run of each task (one test per task calls
:func:`assert_bit_identical`), every float as ``float.hex`` so that equality is exact,
recorded by the commit named in the file. A change that moves code without changing the
computation keeps them; a change that means to change the numbers (a new default, a fixed
bug) re-records them with

    CFM_JAX_WRITE_GOLDEN=1 pytest tests -k bit_identical

and says so in its commit message. The numbers hold for this CPU build of JAX and XLA (the
versions in the file); on another platform or version they may differ in the last bits,
and the test is skipped there rather than loosened.
"""

from __future__ import annotations

import json
import os
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


def _versions() -> dict:
    return {
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "mujoco": mujoco.__version__,
        "platform": jax.default_backend(),
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


def _dumps(record: dict) -> str:
    """JSON with one line per column, so that a re-recording shows as a readable diff."""
    lines = ["{"]
    for i, (key, value) in enumerate(record.items()):
        comma = "," if i < len(record) - 1 else ""
        if key in ("metrics", "baselines"):
            columns = [f"  {json.dumps(c)}: {json.dumps(v)}" for c, v in value.items()]
            lines.append(f" {json.dumps(key)}: {{\n" + ",\n".join(columns) + f"\n }}{comma}")
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value)}{comma}")
    return "\n".join(lines) + "\n}\n"


def _show(value) -> str:
    try:
        return f"{float.fromhex(value)!r} ({value})"
    except (TypeError, ValueError):
        return repr(value)


def assert_bit_identical(name: str, result) -> None:
    """``result.metrics`` and ``result.baselines`` equal the recorded ones bit for bit."""
    path = GOLDEN / f"{name}.json"
    got = {"metrics": _encode(result.metrics), "baselines": _encode(result.baselines)}
    if os.environ.get("CFM_JAX_WRITE_GOLDEN") == "1":
        GOLDEN.mkdir(exist_ok=True)
        record = {"recorded_at_commit": _commit(), "versions": _versions(), **got}
        path.write_text(_dumps(record))
        return
    if not path.is_file():
        pytest.fail(f"{path} is missing; record it with CFM_JAX_WRITE_GOLDEN=1 (see {__file__})")
    record = json.loads(path.read_text())
    if record["versions"] != _versions():
        pytest.skip(f"golden numbers recorded with {record['versions']}, this is {_versions()}")
    for table in ("metrics", "baselines"):
        expected, actual = record[table], got[table]
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
