"""The golden guard on a machine without a record (tests/golden.py): its tolerances are
the recorded machines' spread, recomputed here from the files with NumPy, and a run with
the forward model's learning rate 1 % higher fails them, also with this machine's record
hidden (what an unknown machine would see)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from golden import GOLDEN, MARGIN, SPREAD, _encode, _machine, tolerant_violations
from tiny import tiny_config

import cfm_jax
from cfm_jax import config as config_lib

NAMES = ("inverse_dynamics", "jump", "opspace", "walk")


def _floats(values):
    try:
        return np.array([float.fromhex(v) for v in values])
    except (TypeError, ValueError):
        return None  # labels


def _records(name):
    return json.loads((GOLDEN / f"{name}.json").read_text())["records"]


@pytest.mark.parametrize("name", NAMES)
def test_tolerances_are_the_recorded_machines_spread(name):
    records = _records(name)
    machines = [json.dumps(r["machine"], sort_keys=True) for r in records]
    assert len(set(machines)) == len(records) >= 2
    assert all(r["machine"]["cpu"]["model"] != "unknown (not recorded)" for r in records)
    for table in ("metrics", "baselines"):
        for column in records[0][table]:
            series = [_floats(r[table][column]) for r in records]
            if series[0] is None:
                continue
            spread = 0.0
            for i, a in enumerate(series):
                for b in series[i + 1 :]:
                    both = np.fmax(np.abs(a), np.abs(b))
                    rel = np.where(a == b, 0.0, np.abs(a - b) / np.where(both > 0, both, 1.0))
                    spread = max(spread, np.nanmax(rel, initial=0.0))
            stated = SPREAD[name][table].get(column)
            if stated is None:  # not compared: chaotic, 10x its spread is no check
                assert MARGIN * spread > 0.3, (table, column, spread)
            else:  # the measured spread rounded up to 3 digits
                assert spread <= stated <= 1.01 * spread, (table, column, spread, stated)


def test_the_recorded_machines_pass_each_other():
    """Positive control: each record, taken as a run, lies within the tolerances around
    the other (by construction for these two; a check of the comparison itself)."""
    for name in NAMES:
        first, second = _records(name)[:2]
        tables = {t: first[t] for t in ("metrics", "baselines")}
        assert tolerant_violations(name, tables, second) == []


@pytest.mark.parametrize(
    "name",
    # A full training run each: the arm's ~20 s (48 s on 2 busy cores), the iiwa's ~60 s;
    # a slow study (pytest -m slow). The moves they measure are in tests/golden.py.
    [pytest.param(name, marks=pytest.mark.slow) for name in ("inverse_dynamics", "opspace")],
)
def test_forward_learning_rate_one_percent_higher_fails_the_tolerances(name):
    config = tiny_config()
    if name == "opspace":
        config = tiny_config(iterations=1).replace(
            robot="iiwa14", task=config_lib.TaskConfig(name="opspace", duration=0.2)
        )
    forward = dataclasses.replace(config.forward, learning_rate=config.forward.learning_rate * 1.01)
    result = cfm_jax.train(config.replace(forward=forward), progress=False)
    got = {"metrics": _encode(result.metrics), "baselines": _encode(result.baselines)}
    records = _records(name)
    others = [r for r in records if r["machine"] != _machine()]  # this machine's hidden
    assert others, "no record of another machine"
    for record in records:  # this machine's included, where it has one
        problems = tolerant_violations(name, got, record)
        # The learned quantities move, the baselines (no forward model) do not.
        assert any(p.startswith("metrics.forward_loss") for p in problems), problems
        assert not any(p.startswith("baselines") for p in problems), problems
