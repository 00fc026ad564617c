"""experiments/peers_search.py (issue 68, item 3): the peers' tuning.

Oracles: SB3's own constructors (the defaults trial is SB3's defaults), scores by hand, the
per-loss search's constants (the same count, sampler and seeds), Optuna's record of told
trials, and a tiny run of the program itself on the two-link arm."""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("stable_baselines3")
optuna = pytest.importorskip("optuna")
import peers  # noqa: E402
import peers_search  # noqa: E402

from cfm_jax import config as config_lib  # noqa: E402
from cfm_jax import envs  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")
CONFIG = config_lib.Config(robot="two_link_arm", task=config_lib.TaskConfig(duration=0.2))


def test_the_defaults_trial_is_sb3s_defaults():
    import stable_baselines3

    env = envs.TrackingEnv(CONFIG, references="test", action="scale")
    for name, algorithm in (("sac", stable_baselines3.SAC), ("ppo", stable_baselines3.PPO)):
        arguments = peers._arguments(peers_search.hyper(name, peers_search.DEFAULTS[name]), env)
        ours = algorithm("MlpPolicy", env, device="cpu", **arguments)
        sb3 = algorithm("MlpPolicy", env, device="cpu")
        for field in ("gamma", "batch_size", "learning_rate"):
            assert getattr(ours, field) == pytest.approx(getattr(sb3, field)), (name, field)
        assert ours.policy.net_arch == sb3.policy.net_arch, name
        assert ours.policy.activation_fn is sb3.policy.activation_fn, name
        if name == "sac":
            for field in ("buffer_size", "learning_starts", "gradient_steps", "tau",
                          "target_entropy"):  # fmt: skip
                assert getattr(ours, field) == getattr(sb3, field), field
            assert ours.train_freq == sb3.train_freq
        else:
            for field in ("n_steps", "n_epochs", "gae_lambda", "max_grad_norm"):
                assert getattr(ours, field) == pytest.approx(getattr(sb3, field)), field
            assert ours.clip_range(1.0) == sb3.clip_range(1.0)
            assert ours.ent_coef == pytest.approx(sb3.ent_coef, abs=1e-8)  # the space's floor
    # Every peer's defaults point is a point of its space, and a residual peer's is the
    # environment before amendment 1 (residual scale 1).
    for peer in peers.PEERS:
        point = peers_search.defaults(peer)
        assert set(point) == set(peers_search.space(peer))
        for factor, (kind, *args) in peers_search.space(peer).items():
            value = point[factor]
            assert value in args[0] if kind == "categorical" else args[0] <= value <= args[1]
        assert point.get("residual_scale", 1.0) == 1.0
        assert ("residual_scale" in point) == (peers.ACTION[peer] == "residual")


def test_equal_footing_with_the_per_loss_search():
    import loss_search

    # The committed rule has the per-loss search's count, seeds and sampler, and is the
    # program's (which refuses to run otherwise).
    folder = os.path.join(ROOT, "docs", "results", "peers_search")
    with open(os.path.join(folder, "rule.json")) as f:
        rule = json.load(f)
    assert rule["trials"] == loss_search.TRIALS and rule["seeds"] == list(loss_search.SEEDS)
    assert (rule["sampler_seed"], rule["startup"]) == (loss_search.SAMPLER_SEED,
                                                       loss_search.STARTUP)  # fmt: skip
    peers_search.check_rule(folder)


def test_a_changed_rule_is_refused(tmp_path, monkeypatch):
    peers_search.check_rule(str(tmp_path), write=True)
    with pytest.raises(SystemExit, match="no rule"):
        peers_search.check_rule(str(tmp_path / "elsewhere"))
    monkeypatch.setitem(peers_search.BUDGET, "ppo", 1000.0)
    with pytest.raises(SystemExit, match=r"differs .* \['budget', 'rule'\]"):
        peers_search.check_rule(str(tmp_path))


def test_a_run_score_by_hand():
    # Two checkpoints x two motions; PD-only 1e-2, so the failure floor is log10(10) = 1.
    rows = [("ppo", 0, 100.0, 0, 1e-4, 0, 1.0), ("ppo", 0, 100.0, 1, 1e-2, 0, 1.0),
            ("ppo", 0, 200.0, 0, 1e-3, 0, 2.0), ("ppo", 0, 200.0, 1, np.nan, 1, 2.0)]  # fmt: skip
    records = pd.DataFrame(rows, columns=peers.COLUMNS)
    expected = (math.log10((1e-4 + 1e-2) / 2) + 1.0) / 2
    assert peers_search.run_score(records, 1e-2) == pytest.approx(expected)
    above = records.assign(tracking_mse=[50.0, 50.0, 1e-3, 1e-3], diverged=0)
    assert peers_search.run_score(above, 1e-2) == pytest.approx((1.0 - 3.0) / 2)


def test_round_robin_then_the_defaults_then_done(tmp_path):
    out = str(tmp_path)
    searches = {p: peers_search.study(out, p) for p in ("ppo", "sac_residual")}
    order = []
    for _ in range(6):  # 2 TPE trials each, then each its defaults trial
        peer = peers_search.next_peer(searches, trials=2)
        order.append(peer)
        search = searches[peer]
        trial = search.ask()
        values = peers_search.suggest(trial, peer)
        search.tell(trial, -float(len(order)))
        assert ("residual_scale" in values) == (peer == "sac_residual")
        if len(order) > 4:
            assert values == peers_search.defaults(peer)
    assert order == ["ppo", "sac_residual"] * 3
    assert peers_search.next_peer(searches, trials=2) is None
    chosen = peers_search.chosen(peers_search.records(out, peers.PEERS), trials=2)
    assert chosen["ppo"]["trial"] == 2 and chosen["ppo"]["complete"]  # the lowest: -5
    assert chosen["sac_residual"]["values"] == {**peers_search.DEFAULTS["sac"],
                                                "residual_scale": 1.0}  # fmt: skip
    assert chosen["sac_residual"]["hyper"]["gradient_steps"] == 1


def test_the_program_runs_a_tiny_search_and_records_it(tmp_path, monkeypatch):
    out, runs = str(tmp_path / "out"), str(tmp_path / "runs")
    quick = ["--quick", "--out", out, "--runs", runs, "--run-budget", "0.2", "--every", "0.1"]
    with pytest.raises(SystemExit, match="no rule"):
        peers_search.main([*quick, "--peers", "sac_residual", "--trials", "1"])
    peers_search.main([*quick, "--write-rule"])
    peers_search.main([*quick, "--peers", "sac_residual", "--trials", "1"])
    trials = pd.read_csv(os.path.join(out, "trials.csv"))
    assert len(trials) == 2  # one TPE trial and SB3's defaults
    with open(os.path.join(out, "chosen.json")) as f:
        chosen = json.load(f)["chosen"]["sac_residual"]
    assert chosen["complete"] and chosen["score"] == trials.score.min()
    # A trial's score is its run's, from the run's records (selection motions, seed 100).
    best = trials.sort_values("score").iloc[0]
    values = peers_search.typed("sac_residual", best)
    records = pd.read_csv(os.path.join(runs, "sac_residual", peers_search._hash(values),
                                       "seed100", "records.csv"))  # fmt: skip
    # One evaluation per checkpoint, at the step that reached it (SAC collects train_freq
    # steps at a time, so it may pass a checkpoint by up to train_freq - 1 steps).
    steps = np.round(records.robot_s.unique() / 0.01)
    assert (
        len(steps) == 2
        and ((steps >= [10, 20]) & (steps < np.add([10, 20], values["train_freq"]))).all()
    )
    with open(os.path.join(runs, "sac_residual", peers_search._hash(values), "seed100",
                           "state.json")) as f:  # fmt: skip
        assert json.load(f)["hyper"]["residual_scale"] == values["residual_scale"]
    pd_only = peers.pd_only_mse(peers_search.base_config(quick=True))
    assert chosen["score"] == pytest.approx(peers_search.run_score(records, pd_only))
    # Each finished seed's score is kept beside the journal; a trial run again (killed between
    # seeds, its runs lost) reads it back instead of running the seed again.
    kept = os.path.join(out, "sac_residual", "seeds", f"{peers_search._hash(values)}_seed100.json")
    with open(kept) as f:
        assert json.load(f)["score"] == chosen["score"]
    shutil.rmtree(runs)

    def must_not_run(*args, **kwargs):
        raise AssertionError("a kept seed ran again")

    monkeypatch.setattr(peers, "run_peer", must_not_run)
    again = argparse.Namespace(out=out, runs=runs)
    kept_score = peers_search.seed_score("sac_residual", values, 100, None, pd_only, [], again)
    assert kept_score == chosen["score"]
    # The study's command reads the choice.
    hypers, source = peers.tuned(os.path.join(out, "chosen.json"))
    assert hypers["sac_residual"] == chosen["hyper"] and hypers["ppo"] == {}
    assert "sac_residual" in source


def test_the_residual_studies_count_only_trials_under_amendment_1(tmp_path):
    # Amendment 1 (a searched residual scale) is in the committed rule, dated; every trial of
    # a residual study in the committed journals has a residual scale in its space, and the
    # one trial before the amendment is kept apart, with none.
    folder = os.path.join(ROOT, "docs", "results", "peers_search")
    with open(os.path.join(folder, "rule.json")) as f:
        rule = json.load(f)
    assert [a["number"] for a in rule["amendments"]] == [1]
    assert rule["residual_space"] == {"residual_scale": ["log", 0.01, 1.0]}
    for peer in ("ppo_residual", "sac_residual"):
        journal = os.path.join(folder, peer, "journal.log")
        if not os.path.exists(journal):
            continue
        os.makedirs(tmp_path / peer)
        shutil.copy(journal, tmp_path / peer / "journal.log")  # opening a study writes to it
        for trial in peers_search.study(str(tmp_path), peer).get_trials(deepcopy=False):
            if trial.params:
                assert 0.01 <= trial.params["residual_scale"] <= 1.0, (peer, trial.number)
    before = pd.read_csv(os.path.join(folder, "trials_before_amendment_1.csv"))
    assert list(before.peer) == ["ppo_residual"] and "residual_scale" not in before
    counted = pd.read_csv(os.path.join(folder, "trials.csv"))
    residual = counted[counted.peer.str.endswith("_residual")]
    assert residual.empty or residual.residual_scale.between(0.01, 1.0).all()
