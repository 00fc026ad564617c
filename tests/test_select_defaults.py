"""experiments/select_defaults.py: its cells and its rule, on hand-made sweep outputs.

Oracles: the test motions of the library (``references.default_targets`` with seed 0,
``locomotion.WALK_DURATIONS`` / ``JUMP_HEIGHTS``), which no selection cell may use; and the
rule's scores computed by hand below (log10 errors, the failure floor of 1000 x PD-only).
No training runs here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil

import _study
import pandas as pd
import pytest
import select_defaults as select
from tiny import assert_targets_are_not_the_test_targets

from cfm_jax import config as config_lib
from cfm_jax.tasks import locomotion

LOSSES = ("joint", "task", "distal", "supervised")
RECORDS = os.path.join(os.path.dirname(__file__), "..", "docs", "results", "selection")


@pytest.mark.parametrize("task", ["inverse_dynamics", "opspace", "walk", "jump"])
def test_every_cell_runs_on_motions_other_than_the_test_ones(task):
    cells = select.cells_of(task)
    if task in select.SELECTED_ON.values():
        assert cells[0] == select.Cell(task)  # the base first
    elif task in select.TASK_CHECKS:
        assert cells[0] == select.defaults_cell(task)  # a check starts from the defaults
    else:
        assert cells == []  # takes its family's choices; its defaults on its motions:
        cells = [select.defaults_cell(task)]
    for cell in cells:
        config = cell.config()
        assert config.loop.iterations == select.ITERATIONS[task]
        if task == "walk":
            assert config.task.motions == select.SELECTION_WALKS
            assert not set(config.task.motions) & set(locomotion.WALK_DURATIONS)
        elif task == "jump":
            assert config.task.motions == select.SELECTION_JUMPS
            assert not set(config.task.motions) & set(locomotion.JUMP_HEIGHTS)
        else:
            assert_targets_are_not_the_test_targets(config)
    # One factor at a time: each cell differs from the base in its factor's fields only.
    base = config_lib.to_dict(cells[0].config())
    for cell in cells[1:]:
        tree = config_lib.to_dict(cell.config())
        changed = {
            f"{section}.{field}"
            for section, values in tree.items()
            if isinstance(values, dict)
            for field, value in values.items()
            if base[section][field] != value
        }
        base_values = cells[0].changes()
        expected = {p for p, v in cell.changes().items() if base_values.get(p) != v}
        if "forward.kind" in expected:  # a kind brings its own options, at its defaults
            kind = config_lib.ForwardModelConfig(kind=tree["forward"]["kind"])
            assert (
                tree["forward"]["options"]
                == config_lib.to_dict(config_lib.Config(forward=kind))["forward"]["options"]
            )
            changed.discard("forward.options")
        assert changed == expected and expected, cell.name


def _metrics(errors, fell=None):
    """A sweep's metrics.csv: ``errors[loss][seed][target]`` at the last iteration 3 (and
    ten times larger at iteration 0)."""
    rows = []
    for i, loss in enumerate(LOSSES):
        for seed, per_target in enumerate(errors[i]):
            for target, error in enumerate(per_target):
                for iteration, factor in ((0, 10.0), (3, 1.0)):
                    rows.append(dict(
                        loss=loss, seed=seed, iteration=iteration, target=target,
                        tracking_mse=error * factor,
                        fell=float(fell is not None and (i, seed, target) == fell),
                    ))  # fmt: skip
    return pd.DataFrame(rows)


BASELINES = pd.DataFrame(
    {
        "baseline": ["pd_only", "pd_only", "oracle"],
        "target": [0, 1, 0],
        "tracking_mse": [1e-3, 1e-2, 0],
    }
)


def test_the_rule_scores_by_hand():
    # Loss i, seed s, target k: error 10^-(i + s + k + 1).
    errors = [[[10.0 ** -(i + s + k + 1) for k in range(2)] for s in range(2)] for i in range(4)]
    frame = select.scores(_metrics(errors), BASELINES)
    # Seed score of loss i, seed s: mean over k of -(i + s + k + 1) = -(i + s + 1.5); the
    # mean over s: -(i + 2); over the four losses: -(0 + 1 + 2 + 3)/4 - 2 = -3.5.
    assert select.cell_score(frame) == pytest.approx(-3.5, abs=1e-12)
    # A fall (loss 0, seed 0, target 1: error 1e-2, log -2) scores the failure floor
    # log10(1000 x PD-only of target 1) = log10(10) = 1: the loss-0 mean moves by
    # (1 - (-2)) / 2 / 2 = 0.75, the cell's by 0.75 / 4.
    fallen = select.scores(_metrics(errors, fell=(0, 0, 1)), BASELINES)
    assert int(fallen[fallen.iteration == 3]["failed"].sum()) == 1
    assert select.cell_score(fallen) == pytest.approx(-3.5 + 0.75 / 4, abs=1e-12)
    # A diverged run (NaN error) scores the floor of its target: target 0, log10(1) = 0.
    nan = [[list(seed) for seed in loss] for loss in errors]
    nan[3][1][0] = math.nan
    diverged = select.scores(_metrics(nan), BASELINES)
    expected = -3.5 + (0 - (-(3 + 1 + 0 + 1))) / 2 / 2 / 4
    assert select.cell_score(diverged) == pytest.approx(expected, abs=1e-12)
    # A failure that is worse than the floor keeps its own score.
    huge = [[list(seed) for seed in loss] for loss in errors]
    huge[1][0][0] = 1e6
    worse = select.scores(_metrics(huge, fell=(1, 0, 0)), BASELINES)
    assert worse.loc[
        (worse.loss == "task") & (worse.seed == 0) & (worse.target == 0) & (worse.iteration == 3),
        "score",
    ].item() == pytest.approx(6.0)
    # The paired difference over seeds, mean over losses: the fall is on seed 0 only.
    stats = select.paired(fallen, frame)
    assert stats["mean"] == pytest.approx((0.75 * 2 / 4 + 0.0) / 2, abs=1e-12)


def test_factors_are_chosen_on_one_task_per_family_and_the_page_says_so(tmp_path):
    assert select.SELECTED_ON == {"arm": "inverse_dynamics", "legged": "walk"}
    assert {select.family(t) for t in select.SELECTED_ON.values()} == {"arm", "legged"}
    page = select.tables(str(tmp_path), ["inverse_dynamics", "opspace", "walk", "jump"])
    assert page.count("Not a task the factors are chosen on") == 2
    assert "takes the choice made on inverse_dynamics" in page.split("## opspace")[1]
    assert "takes the choice made on walk" in page.split("## jump")[1]
    assert "**Sizing.**" in page


def test_a_piece_of_one_task_keeps_the_other_task_s_tables(tmp_path):
    """Two pieces run side by side (--only inverse_dynamics, --only walk) each rewrite the
    page: the page holds every task with records, not only the piece's own."""
    for task in ("inverse_dynamics", "walk"):
        folder = tmp_path / "cells" / task / "base"
        folder.mkdir(parents=True)
        rows = [dict(loss=loss, seed=seed, iteration=0, target=0, tracking_mse=1e-3,
                     diverged=0.0, fell=0.0)
                for loss in LOSSES for seed in range(2)]  # fmt: skip
        pd.DataFrame(rows).to_csv(folder / "metrics.csv", index=False)
        pd.DataFrame([dict(baseline="pd_only", target=0, tracking_mse=1e-2)]).to_csv(
            folder / "baselines.csv", index=False
        )
    for only in (["walk"], ["inverse_dynamics"]):
        page = select.tables(str(tmp_path), only)
        assert "## inverse_dynamics" in page and "## walk" in page, only
        assert "| base | -3.000 |" in page
    assert set(pd.read_csv(tmp_path / "selection.csv").task) == {"inverse_dynamics", "walk"}


def test_finished_cells_keep_the_configs_of_their_records():
    """Oracle: each finished cell's config.json, written when it ran. A cell pins the options
    of the time (``_study.BEFORE_SELECTION``) beside its base and factor, so a change of the
    library's defaults leaves it what it was; keys added to the config since a record was
    written are not in it."""
    checked = 0
    for task in ("inverse_dynamics", "opspace", "walk"):
        for cell in select.cells_of(task):
            path = os.path.join(select.record_dir(RECORDS, cell), "config.json")
            if not _study.recorded(select.record_dir(RECORDS, cell)):
                continue
            with open(path) as f:
                recorded = json.load(f)
            recorded["forward"] = config_lib.upgrade_forward(recorded["forward"])
            got = json.loads(json.dumps(config_lib.to_dict(cell.config())))
            for section, value in recorded.items():
                if isinstance(value, dict):
                    assert {k: got[section][k] for k in value} == value, (cell.name, section)
                else:
                    assert got[section] == value, (cell.name, section)
            checked += 1
    assert checked >= 9


def test_the_chosen_values_are_the_rule_s_choices_and_the_library_s_defaults():
    """Oracle: the committed records, scored by the rule (``choices``), and
    ``config.for_task``: ``CHOSEN`` is what the rule picked where it left the base, the
    library's defaults are the base with it, and ``defaults_cell`` (a cell that ran on the
    selection task) is those defaults on the selection's motions."""
    for fam, task in select.SELECTED_ON.items():
        done = [c for c in select.cells_of(task) if _study.recorded(select.record_dir(RECORDS, c))]
        frames = {c: select.load(RECORDS, c) for c in done}
        chosen = select.final_choices(frames, task)
        expected = {**_study.BEFORE_SELECTION, **select.BASE[fam], **select.CHOSEN[fam]}
        for name, path, _ in select.FACTORS[fam]:
            for one in select.factor_paths(path):
                assert expected[one] == chosen[name], (task, name)
        round_one = {n: v for n, (v, _) in select.choices(frames, task).items()}
        first = {**_study.BEFORE_SELECTION, **select.BASE[fam], **select.ROUND_ONE_CHOSEN[fam]}
        for name, path, _ in select.FACTORS[fam]:
            assert all(first[one] == round_one[name] for one in select.factor_paths(path))
        if fam in select.SECOND_ROUND:
            second = select.choices(frames, task, round=2)
            if all(value is not None for value, _ in second.values()):
                moved = {n for n, _, values in select.SECOND_ROUND[fam]["factors"]
                         if second[n][0] != values[0]}  # fmt: skip
                assert set(select.ROUND_TWO_MOVED.get(fam, ())) == moved, task
        for member in (t for t in select.ARM + select.LEGGED if select.family(t) == fam):
            defaults = config_lib.for_task(member, robot=select.ROBOT[member])
            for path, value in {**expected, **select.TASK_CHOSEN.get(member, {})}.items():
                if path in _study.BEFORE_TORQUE_SCALING:  # issue 41's, not the selection's
                    continue
                section, field = path.split(".")
                assert getattr(getattr(defaults, section), field) == value, (member, path)
            # Issue 41 made the arms' torque scaling and babbling gains robot-aware after
            # the selection ran (inverse dynamics coupled, op-space per joint, each by its
            # own check; since issue 64's rule inverse dynamics 'auto', pose where MJX builds
            # the robot); the legged defaults keep the limits.
            want = {"inverse_dynamics": "auto", "opspace": "inertia"}.get(member, "limit")
            assert defaults.loop.torque_scale == want, member
            assert defaults.loop.babbling_gains == "lightest", member
            together = select.defaults_cell(member).config()
            motions = select.selection_motions(member, defaults)
            want = _study.with_changes(defaults, {
                "loop.iterations": select.ITERATIONS[member],
                **_study.BEFORE_TORQUE_SCALING,
                **(_study.BEFORE_PERIOD if defaults.task.oracle == "period" else {}),
                # the walk's defaults cell is the family's, before its own check's choice
                **(_study.BEFORE_WALK_FEEDBACK if member == "walk" else {}),
                **{f"task.{k}": v for k, v in motions.items()}})  # fmt: skip
            assert together == want, member


def test_a_task_s_own_check_chose_what_task_chosen_says():
    """Oracle: the committed records of each task's own check (``TASK_CHECKS``), scored by
    the rule (``check_choices``): ``TASK_CHOSEN`` holds exactly the values that left the
    family's defaults, and ``config.for_task`` has them."""
    checked = 0
    for task, factors in select.TASK_CHECKS.items():
        cells = [select.defaults_cell(task), *select.check_cells(task)]
        if not all(_study.recorded(select.record_dir(RECORDS, c)) for c in cells):
            # A check still running has chosen nothing, and the defaults do not move.
            assert task not in select.TASK_CHOSEN, task
            continue
        chosen = select.check_choices({c: select.load(RECORDS, c) for c in cells}, task)
        moved = {one: chosen[name][0] for name, path, values in factors
                 if chosen[name][0] != values[0] for one in select.factor_paths(path)}  # fmt: skip
        assert select.TASK_CHOSEN.get(task, {}) == moved, task
        defaults = config_lib.for_task(task, robot=select.ROBOT[task])
        for path, value in moved.items():
            section, field = path.split(".")
            assert getattr(getattr(defaults, section), field) == value, (task, path)
        checked += 1
    assert checked >= 1  # op-space's check has its records


def _frame(score_by_loss):
    """A scored cell frame whose loss ``i`` scores ``score_by_loss[i]`` on every seed and
    target (errors 10^score, nothing failed)."""
    errors = [[[10.0 ** score_by_loss[i]] * 2 for _ in range(2)] for i in range(4)]
    return select.scores(_metrics(errors), BASELINES)


def test_a_second_round_starts_from_its_base_and_replaces_its_factors_choices():
    """Hand-made cells: round 1 chooses per factor against the base; round 2, from
    ``round_two_base``, chooses its factors against that cell, and a finished round 2 replaces
    round 1's choices for them (an unfinished one leaves round 1's)."""
    task = "walk"
    second = select.round_two_base(task)
    assert second == select.Cell(task, *select.SECOND_ROUND["legged"]["from"])
    # Round-2 cells: the round-2 base's config with the factor's fields changed, nothing else.
    base2 = config_lib.to_dict(second.config())
    for cell in select.round_two_cells(task):
        if cell.together:
            continue
        tree = config_lib.to_dict(cell.config())
        changed = {f"{s}.{k}" for s, v in tree.items() if isinstance(v, dict)
                   for k, x in v.items() if base2[s][k] != x}  # fmt: skip
        path = dict((n, p) for n, p, _ in select.SECOND_ROUND["legged"]["factors"])[cell.factor]
        assert changed == set(select.factor_paths(path)), cell.name
    # Scores by hand: every round-1 cell -1 except rigid_body -3 and normaliser=robot -2.
    frames = {c: _frame([-1.0] * 4) for c in select.cells_of(task) if c.round == 1}
    frames[second] = _frame([-3.0] * 4)
    frames[select.Cell(task, "normaliser", "robot")] = _frame([-2.0] * 4)
    frames[select.Cell(task, "fit start", "warm_new_optimizer")] = _frame([-1.5] * 4)
    first = select.final_choices(frames, task)
    assert first["forward model"] == "rigid_body" and first["normaliser"] == "robot"
    assert first["fit start"] == "warm_new_optimizer"
    # Round 2 half finished: round 1's choices stand.
    frames[select.Cell(task, "fit start", "warm_new_optimizer", round=2)] = _frame([-2.5] * 4)
    assert select.final_choices(frames, task) == first
    # Finished: robot -3.5 beats the round-2 base (-3), warm_new_optimizer (-2.5) does not.
    frames[select.Cell(task, "normaliser", "robot", round=2)] = _frame([-3.5] * 4)
    frames[select.Cell(task, "normaliser", "babbling", round=2)] = _frame([-2.0] * 4)
    final = select.final_choices(frames, task)
    assert final == {**first, "normaliser": "robot", "fit start": "warm"}
    line = select.choices(frames, task, round=2)["normaliser"][1]
    assert line.startswith("normaliser: **robot** (-0.5") and "against data" in line


def test_the_pinned_first_round_legged_options_are_round_one_s_choices():
    """``_study.ROUND_ONE_LEGGED`` (what the robustness study's ``round1-*`` cells pin) is
    the options before the selection with the legged base and round 1's legged choices."""
    want = {**_study.BEFORE_SELECTION, **select.BASE["legged"], **select.ROUND_ONE_CHOSEN["legged"]}
    assert _study.ROUND_ONE_LEGGED == want
    # And it is round 1's chosen_together cell, whose config.json was written when it ran.
    assert select.Cell("walk", together=True).changes() == want


def test_a_task_s_own_check_starts_from_its_family_s_defaults_and_chooses_by_the_rule(tmp_path):
    """Op-space's check (``TASK_CHECKS``): its base is the family's defaults on op-space's
    selection targets (``for_task`` there), each check cell changes only its factor's fields,
    and the rule chooses by hand-made scores; the page shows the check's rule text."""
    task = "opspace"
    base = select.defaults_cell(task)
    defaults = config_lib.for_task(task, robot=select.ROBOT[task])
    motions = select.selection_motions(task, defaults)
    assert base.config() == _study.with_changes(defaults, {
        "loop.iterations": select.ITERATIONS[task],
        **_study.BEFORE_TORQUE_SCALING,
        **{f"task.{k}": v for k, v in motions.items()}})  # fmt: skip
    checks = select.check_cells(task)
    assert [c.name for c in checks] == ["check_babbling=home"]
    assert checks[0].config() == _study.with_changes(base.config(), {"loop.babbling": "home"})
    frames = {base: _frame([-1.0] * 4), checks[0]: _frame([-2.0, -1.0, -1.0, -1.0])}
    value, line = select.check_choices(frames, task)["babbling"]
    assert value == "home" and line.startswith("babbling: **home** (-0.25")
    frames[checks[0]] = _frame([-0.5] * 4)
    assert select.check_choices(frames, task)["babbling"][0] == "reaching"
    assert select.check_choices({base: frames[base]}, task)["babbling"][0] is None
    page = select.tables(str(tmp_path), ["opspace"])
    assert select.TASK_CHECK in page.split("\n## opspace")[1]


def test_the_walk_s_checks_differ_from_the_defaults_cell_in_their_option_alone(tmp_path):
    """The walk's own checks (``WALK_CHECK``, ``WALK_FEEDBACK_CHECK``, each written before it
    ran): each cell is the walk's defaults cell (round 2's, already recorded) with one option
    changed (``loop.restart_on_terminal=True``; ``task.joint_kp=1000``) and nothing else; the
    rule chooses by hand-made scores; the page of a piece with its records shows the checks'
    texts and tables after the rounds."""
    task = "walk"
    base = select.defaults_cell(task)
    checks = select.check_cells(task)
    names = ["check_restart_after_a_fall=True", "check_joint_position_feedback_in_sstar=1000.0"]
    assert [c.name for c in checks] == names
    assert select.cells_of(task)[-2:] == checks
    assert checks[0].config() == base.config().replace(
        loop=dataclasses.replace(base.config().loop, restart_on_terminal=True)
    )
    assert checks[1].config() == base.config().replace(
        task=dataclasses.replace(base.config().task, joint_kp=1000.0)
    )
    frames = {base: _frame([-1.0] * 4), checks[0]: _frame([-1.5, -1.0, -1.0, -1.0]),
              checks[1]: _frame([-0.5] * 4)}  # fmt: skip
    chosen = select.check_choices(frames, task)
    assert chosen["restart after a fall"][0] is True
    assert chosen["joint position feedback in s*"][0] is None  # the base's value
    frames[checks[0]], frames[checks[1]] = _frame([-0.5] * 4), _frame([-1.0, -1.0, -1.2, -1.0])
    chosen = select.check_choices(frames, task)
    assert chosen["restart after a fall"][0] is False
    assert chosen["joint position feedback in s*"][0] == 1000.0
    # The page: copy the walk's records and add a made-up record of the last check.
    for cell in select.cells_of(task)[:-1]:
        if _study.recorded(select.record_dir(RECORDS, cell)):
            shutil.copytree(
                select.record_dir(RECORDS, cell), select.record_dir(str(tmp_path), cell)
            )
    fake = select.record_dir(str(tmp_path), checks[1])
    if not os.path.isdir(fake):
        shutil.copytree(select.record_dir(RECORDS, base), fake)
    page = select.tables(str(tmp_path), ["walk"])
    walk = page.split("\n## walk")[1]
    assert select.WALK_CHECK in walk and "check_restart_after_a_fall=True |" in walk
    assert select.WALK_FEEDBACK_CHECK in walk
    assert "check_joint_position_feedback_in_sstar=1000.0 |" in walk
    round_one = walk.split("### walk, round 2")[0]
    assert "check_restart" not in round_one
