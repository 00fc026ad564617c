"""experiments/loss_search.py (issue 43, item 1): its trials' configs, score, resumption and
choice, without training.

Oracles: the test motions and seeds of the library, which no trial may use; scores computed
by hand (log10 errors, the failure floor of 1000 x PD-only); Optuna's own record of a trial.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pandas as pd
import pytest

from cfm_jax.tasks import locomotion

optuna = pytest.importorskip("optuna")
import loss_search  # noqa: E402
from tiny import assert_targets_are_not_the_test_targets  # noqa: E402


@pytest.mark.parametrize("task", ["inverse_dynamics", "opspace", "walk", "jump"])
def test_a_trial_runs_on_selection_motions_and_seeds_with_its_values(task):
    trial = optuna.trial.FixedTrial({
        **{name: values[-1] for name, (_, values) in loss_search.CATEGORICAL.items()},
        **{name: values[-1] for name, (_, values)
           in loss_search.FAMILY_CATEGORICAL[loss_search.select_defaults.family(task)].items()},
        "forward learning rate": 2e-4, "controller learning rate": 3e-4,
    })  # fmt: skip
    changes = loss_search.suggest(trial, task)
    config = loss_search.trial_config(task, changes)
    assert config.forward.learning_rate == 2e-4 and config.controller.learning_rate == 3e-4
    assert config.forward.start == config.controller.start == "fresh"  # one factor, two fields
    assert config.loop.normaliser == "robot" and config.controller.loss_form == "norm"
    assert config.loop.iterations == loss_search.ITERATIONS[task]
    if task == "walk":
        assert config.task.motion_family == "selection"
        assert not set(config.task.motions) & set(locomotion.WALK_DURATIONS)
    elif task == "jump":
        assert config.task.motion_family == "selection"
        assert not set(config.task.motions) & set(locomotion.JUMP_HEIGHTS)
    else:  # the arm: no target within 0.1 (rad or m, per coordinate) of a test target
        assert_targets_are_not_the_test_targets(config)
    assert not set(loss_search.SEEDS) & set(range(10, 20))  # no test cell's seed


def test_the_score_is_the_selection_rule_for_one_loss_by_hand():
    # Two seeds x two targets of one loss at the last iteration; PD-only 1e-2 on both
    # targets: the failure floor is log10(1000 x 1e-2) = 1.
    metrics = pd.DataFrame({
        "loss": "task", "seed": [100, 100, 101, 101], "iteration": 3, "target": [0, 1, 0, 1],
        "tracking_mse": [1e-4, 1e-6, 1e-5, np.nan], "diverged": [0, 0, 0, 1],
    })  # fmt: skip
    earlier = metrics.assign(iteration=2, tracking_mse=1.0, diverged=0)
    baselines = pd.DataFrame({"baseline": "pd_only", "target": [0, 1], "tracking_mse": 1e-2})
    got = loss_search.score(pd.concat([earlier, metrics], ignore_index=True), baselines)
    # seed 100: (-4 - 6) / 2 = -5; seed 101: (-5 + 1) / 2 = -2; mean -3.5.
    assert got == pytest.approx(-3.5)


def test_a_trial_cut_by_a_killed_piece_is_tried_again_first(tmp_path):
    search = loss_search.study(str(tmp_path), "inverse_dynamics", "joint")
    first = search.ask()
    loss_search.suggest(first, "inverse_dynamics")
    cut = dict(first.params)  # the piece is killed here: the trial stays RUNNING
    again = loss_search.study(str(tmp_path), "inverse_dynamics", "joint")  # the next piece
    loss_search._recover(again)
    states = [t.state for t in again.get_trials(deepcopy=False)]
    assert states == [optuna.trial.TrialState.FAIL, optuna.trial.TrialState.WAITING]
    retried = again.ask()
    loss_search.suggest(retried, "inverse_dynamics")
    assert retried.params == cut


def test_every_loss_draws_the_same_startup_trials_and_the_lowest_score_is_chosen(tmp_path):
    # The same sampler seed: the random startup trials are the same values for every loss
    # (paired), so no loss starts from luckier draws.
    drawn = {}
    for loss in ("joint", "supervised"):
        search = loss_search.study(str(tmp_path), "walk", loss)
        trials = [search.ask() for _ in range(loss_search.STARTUP)]
        for t in trials:
            loss_search.suggest(t, "walk")
        drawn[loss] = [t.params for t in trials]
    assert drawn["joint"] == drawn["supervised"]
    trials = pd.DataFrame({
        "task": "walk", "loss": ["joint"] * 3 + ["task"] * 2, "trial": [0, 1, 2, 0, 1],
        "score": [-1.0, -2.0, -2.0, 0.5, math.inf], "seconds": 1.0,
        "normaliser": ["data", "robot", "babbling", "data", "robot"],
    })  # fmt: skip
    chosen = loss_search.chosen(trials)
    assert chosen["walk"]["joint"] == {"trial": 1, "score": -2.0, "normaliser": "robot"}
    assert chosen["walk"]["task"]["trial"] == 0
    with pytest.raises(SystemExit):
        loss_search.main(["--losses", "joint,jont", "--out", str(tmp_path)])


def _draw(folder, pieces, loss="joint"):
    """Trials drawn and told in ``pieces`` (each a new study object, as a new process)."""
    for size in pieces:
        search = loss_search.study(str(folder), "walk", loss)
        for _ in range(size):
            trial = loss_search.ask(search)
            loss_search.suggest(trial, "walk")
            search.tell(trial, float((trial.number * 7) % 5))  # any made-up score
    search = loss_search.study(str(folder), "walk", loss)
    return [t.params for t in search.get_trials(states=(optuna.trial.TrialState.COMPLETE,))]


def test_a_trials_values_do_not_depend_on_the_pieces_it_ran_in(tmp_path):
    # 7 trials: 4 random startup draws, then TPE. In one piece, in pieces of 3 + 4, and one
    # trial per piece: the same values trial by trial.
    whole = _draw(tmp_path / "a", [7])
    assert _draw(tmp_path / "b", [3, 4]) == whole
    assert _draw(tmp_path / "c", [1] * 7) == whole
    assert len({str(p) for p in whole}) == 7
    # A piece killed during trial 5 (a TPE draw): the next piece tries its values again first,
    # and the trials after it draw what they would have drawn without the kill.
    _draw(tmp_path / "d", [5])
    search = loss_search.study(str(tmp_path / "d"), "walk", "joint")
    loss_search.suggest(loss_search.ask(search), "walk")  # killed: left RUNNING
    loss_search._recover(search)
    done = _draw(tmp_path / "d", [2])
    assert done == whole  # the killed trial's values retried, then the same draws


def test_a_loss_missing_a_startup_draw_gets_it_queued_and_repeats_do_not_count(tmp_path):
    startup = _draw(tmp_path, [loss_search.STARTUP], "joint")
    # The supervised study as the first pieces left it: its 4th trial repeated its 1st.
    search = loss_search.study(str(tmp_path), "walk", "supervised")
    for params in [*startup[:-1], startup[0]]:
        search.enqueue_trial(params)
        trial = search.ask()
        loss_search.suggest(trial, "walk")
        search.tell(trial, 1.0)
    assert loss_search.distinct(search) == loss_search.STARTUP - 1
    loss_search._fill_startup({"supervised": search}, str(tmp_path), "walk")
    # A queued draw counts as had: a piece that starts before it was tried queues it once.
    loss_search._fill_startup({"supervised": search}, str(tmp_path), "walk")
    assert len(search.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 1
    trial = loss_search.ask(search)
    loss_search.suggest(trial, "walk")
    assert trial.params == startup[-1]  # the missing draw first
    search.tell(trial, 2.0)
    assert loss_search.distinct(search) == loss_search.STARTUP
    loss_search._fill_startup({"supervised": search}, str(tmp_path), "walk")
    assert not search.get_trials(states=(optuna.trial.TrialState.WAITING,))  # nothing more


def test_the_records_page_names_each_losss_lowest_trial(tmp_path):
    rows = [{"task": "walk", "loss": loss, "trial": k, "score": score, "seconds": 1.0,
             **{name: values[0] for name, (_, values) in loss_search.space("walk").items()
                if name not in loss_search.LOG_UNIFORM},
             "forward learning rate": 1e-4 * (k + 1), "controller learning rate": 2e-4}
            for loss, scores in (("joint", (-1.0, -3.0)), ("task", (-2.0, -2.0)))
            for k, score in enumerate(scores)]  # fmt: skip
    pd.DataFrame(rows).to_csv(tmp_path / "trials_walk.csv", index=False)
    page = loss_search.write_page(str(tmp_path))
    assert "| joint | 2 (2) | -3.000 | 1 |" in page  # its lowest: trial 1
    assert "| task | 2 (2) | -2.000 | 0 |" in page  # a tie: the earlier trial
    assert (tmp_path / "search_walk.png").stat().st_size > 5_000


def test_a_walk_piece_refuses_to_run_on_more_than_one_core(tmp_path, monkeypatch, capsys):
    """The walk's trials run pinned to one core (``loss_search.CORES``: jaxlib 0.10's LAPACK
    stall, and the thread count changes a trial's numbers): a process that may use two is a
    usage error naming the task, the cores and the command, before any study is opened."""
    monkeypatch.setattr(loss_search.os, "sched_getaffinity", lambda pid: {0, 1})
    with pytest.raises(SystemExit):
        loss_search.main(["--task", "walk", "--out", str(tmp_path)])
    assert "--task=walk: its trials run on 1 core(s) (CORES) and this process may run on 2" in (
        capsys.readouterr().err
    )
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("task", ["inverse_dynamics", "walk"])
def test_the_shared_defaults_trial_trains_exactly_the_library_defaults(task):
    # Oracle: the trial config with no changes at all (the task's library defaults on the
    # selection motions); the defaults as a point of the space must give the same config.
    values = loss_search.defaults_values(task)
    assert set(values) == set(loss_search.space(task))
    changes = loss_search.suggest(optuna.trial.FixedTrial(values), task)
    assert loss_search.trial_config(task, changes) == loss_search.trial_config(task, {})


def test_every_study_scores_the_shared_defaults_after_its_tpe_trials_only(tmp_path):
    # Amendment 2: after its TPE trials (here 5), a study runs the shared defaults once more;
    # the TPE trials' values are those drawn without the amendment.
    whole = _draw(tmp_path / "plain", [5])
    searches = {"joint": loss_search.study(str(tmp_path / "a"), "walk", "joint")}
    drawn = []
    while (loss := loss_search.next_loss(searches, "walk", trials=5)) is not None:
        trial = loss_search.ask(searches[loss])
        loss_search.suggest(trial, "walk")
        made_up = (trial.number * 7) % 5 if trial.number < 5 else -5  # _draw's, then -5
        searches[loss].tell(trial, float(made_up))
        drawn.append(trial.params)
        assert len(drawn) <= 6
    assert drawn[:5] == whole
    assert drawn[5] == loss_search.defaults_values("walk")
    assert loss_search.distinct(searches["joint"], "walk") == 5
    frame = loss_search.records(str(tmp_path / "a"), ["walk"], ["joint"])
    assert loss_search.is_defaults(frame, "walk").tolist() == [False] * 5 + [True]
    assert loss_search.complete(frame, "walk", "joint", trials=5)
    assert not loss_search.complete(frame.iloc[:5], "walk", "joint", trials=5)  # no defaults
    assert not loss_search.complete(frame.iloc[1:], "walk", "joint", trials=5)  # 4 TPE trials
    # The defaults trial scored lowest (-5): it is the loss's choice, marked on the page.
    assert loss_search.chosen(frame)["walk"]["joint"]["trial"] == 5
    frame.to_csv(tmp_path / "trials_walk.csv", index=False)
    assert "| joint | 5 (shared defaults) | -5.000 |" in loss_search.write_page(str(tmp_path))
