"""The peers at their own best (issue 68, item 3): a hyperparameter search per peer
(:data:`peers.PEERS`: SAC and PPO, each through cfm_jax's torque scale and as a residual on
the task's PD feedback) on an equal footing with the per-loss search of the library's own
losses (``experiments/loss_search.py``), by a rule written before its first trial.

The rule (:data:`RULE`, with the spaces and the defaults points in ``rule.json``, committed
before any trial ran; the program stops if the committed rule differs from this file's):

* One Optuna study per peer, the per-loss search's sampler and count: TPE
  (``loss_search.sampler``: seed ``loss_search.SAMPLER_SEED`` plus the finished trials, the
  first ``loss_search.STARTUP`` trials random), ``loss_search.TRIALS`` trials with distinct
  values, then one trial of SB3's defaults (:data:`DEFAULTS`, a point of the space; the
  per-loss search's Amendment 2 scores the library's defaults the same way), 13 in all.
* The space of each algorithm (:data:`SPACES`) is rl-zoo3's (``rl_zoo3/hyperparams_opt.py``,
  ``sample_ppo_params`` and ``sample_sac_params``), the sampler the RL community tunes SB3
  with, with the changes :data:`SPACE_CHANGES` says (and why); both variants of an algorithm
  search the same space.
* A trial runs the peer with the trial's values (``peers.run_peer``: the same environment,
  normalisation and reward as the study) on the selection motions
  (``peers.selection_config``: five reaches to other targets, never a test motion) with the
  selection seeds ``loss_search.SEEDS``, for :data:`BUDGET` robot-seconds, evaluated every
  ``peers.EVERY`` robot-seconds.
* Score of a run: the mean over its checkpoints of ``log10`` of its mean tracking MSE over the
  five selection motions, a checkpoint with a diverged motion or an MSE above 1000 x PD-only's
  scoring ``log10(1000 x PD-only)``: the area under the log learning curve, since the study
  asks how soon a peer gets to a level, not only where it ends. Score of a trial: the mean over
  the seeds. Lower is better.
* A peer's configuration for the study is its lowest-scoring trial of the 13 (ties: the
  earlier trial).
* Amendment 1 (:data:`AMENDMENTS`, 2026-11-29, before any further residual trial): the
  residual peers also search ``residual_scale`` (:data:`RESIDUAL_SPACE`, log-uniform on
  0.01-1; their defaults point has 1); the one residual trial before it stays on record,
  outside the count.

Resumable and in pieces (``--budget`` seconds: no trial starts after them): each study lives
in a journal file (``--out/<peer>/journal.log``, committed) and each trial's runs in
``--runs/<peer>/<values' hash>/seed<N>`` (not committed; a trial killed while running is
marked failed on the next start, its values tried again first, its finished seeds' scores read
back from ``--out/<peer>/seeds`` (committed) and its other runs resumed from their last
checkpoint where ``--runs`` still has it). After every trial ``--out`` gets ``trials.csv``
(one row per trial) and ``chosen.json`` (each peer's lowest-scoring trial, whether its study
is complete, and the SB3 arguments ``experiments/peers.py --hyper`` reads).

Usage:
  python experiments/peers_search.py --write-rule     # the rule, before the first trial
  taskset -c 1 python experiments/peers_search.py --peers ppo,ppo_residual --budget 7000
  python experiments/peers_search.py --quick --out /tmp/q --runs /tmp/q/runs   # smoke test
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time

import loss_search
import numpy as np
import pandas as pd
import peers

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRIALS = loss_search.TRIALS
SEEDS = loss_search.SEEDS
BUDGET = {"ppo": 2000.0, "sac": 500.0}
"""Robot-seconds of a trial's run, per algorithm (see ``SIZING`` in ``rule.json``)."""

SPACES = {
    "ppo": {
        "batch_size": ("categorical", [32, 64, 128, 256, 512]),
        "n_steps": ("categorical", [32, 64, 128, 256, 512, 1024, 2048]),
        "one_minus_gamma": ("log", 0.0001, 0.03),
        "one_minus_gae_lambda": ("log", 0.0001, 0.1),
        "learning_rate": ("log", 1e-5, 0.002),
        "ent_coef": ("log", 1e-8, 0.1),
        "clip_range": ("categorical", [0.1, 0.2, 0.3, 0.4]),
        "n_epochs": ("categorical", [1, 5, 10, 20]),
        "max_grad_norm": ("uniform", 0.3, 2.0),
        "net_arch": ("categorical", ["tiny", "small", "medium"]),
        "activation_fn": ("categorical", ["tanh", "relu"]),
    },
    "sac": {
        "gamma": ("categorical", [0.9, 0.95, 0.98, 0.99, 0.995, 0.999, 0.9999]),
        "learning_rate": ("log", 1e-5, 0.002),
        "batch_size": ("categorical", [16, 32, 64, 128, 256, 512]),
        "buffer_size": ("categorical", [10_000, 100_000, 1_000_000]),
        "learning_starts": ("categorical", [0, 100, 1000, 10_000, 20_000]),
        "train_freq": ("categorical", [1, 4, 8, 16, 32, 64, 128, 256, 512]),
        "tau": ("categorical", [0.001, 0.005, 0.01, 0.02, 0.05, 0.08]),
        "target_entropy_per_action": ("categorical", [-4.0, -2.0, -1.0, -0.5, 0.0]),
        "net_arch": ("categorical", ["small", "medium", "big"]),
    },
}
"""Each algorithm's space: ``(kind, values)`` or ``(kind, low, high)``; kinds ``categorical``,
``log`` (log-uniform) and ``uniform``. rl-zoo3's samplers with :data:`SPACE_CHANGES`."""
SPACE_CHANGES = (
    "PPO: rl-zoo3's sample_ppo_params as it is. SAC: rl-zoo3's sample_sac_params with the "
    "learning rate on PPO's range, 1e-5 to 2e-3 (the zoo's reaches 1, where SAC diverges, and "
    "12 trials are too few to spend there); batch sizes up to 512 (1024 and 2048 cost 4 to 8 "
    "times a step's time on one core); SB3's learning_starts, 100, added to the zoo's values so "
    "that SB3's defaults are a point of the space; log_std_init left out (it acts only with "
    "gSDE, which neither SB3's default nor the zoo's SAC sampler turns on); the entropy target "
    "searched (the zoo leaves it at 'auto', -1 per action dimension; the issue asks for it), "
    "per action dimension on -4, -2, -1, -0.5, 0. gradient_steps = train_freq, as in the zoo."
)
NET_ARCH = {
    "ppo": {
        "tiny": {"pi": [64], "vf": [64]},
        "small": {"pi": [64, 64], "vf": [64, 64]},
        "medium": {"pi": [256, 256], "vf": [256, 256]},
    },
    "sac": {"small": [64, 64], "medium": [256, 256], "big": [400, 300]},
}
"""rl-zoo3's network sizes (hidden layers of the policy and value / Q networks)."""
DEFAULTS = {
    "ppo": {
        "batch_size": 64,
        "n_steps": 2048,
        "one_minus_gamma": 0.01,
        "one_minus_gae_lambda": 0.05,
        "learning_rate": 3e-4,
        "ent_coef": 1e-8,
        "clip_range": 0.2,
        "n_epochs": 10,
        "max_grad_norm": 0.5,
        "net_arch": "small",
        "activation_fn": "tanh",
    },
    "sac": {
        "gamma": 0.99,
        "learning_rate": 3e-4,
        "batch_size": 256,
        "buffer_size": 1_000_000,
        "learning_starts": 100,
        "train_freq": 1,
        "tau": 0.005,
        "target_entropy_per_action": -1.0,
        "net_arch": "medium",
    },
}
"""SB3's defaults (2.9) as points of the spaces (PPO's entropy coefficient 0 as the space's
floor, 1e-8); ``tests/test_peers_search.py`` checks them against SB3's constructors."""
RESIDUAL_SPACE = {"residual_scale": ("log", 0.01, 1.0)}
"""Amendment 1: the residual peers' spaces add the factor of the policy's torque on top of the
PD feedback (:class:`cfm_jax.envs.TrackingEnv`'s ``residual_scale``); their defaults point
has 1, the environment without the factor."""
RESIDUAL_DEFAULTS = {"residual_scale": 1.0}
AMENDMENTS = (
    {
        "number": 1,
        "date": "2026-11-29",
        "text": (
            "Both residual peers (sac_residual, ppo_residual) search a residual scale as well: "
            "the policy's torque is residual_scale x the scale action's torque, added to the "
            "PD feedback; residual_scale log-uniform on 0.01-1 (1: the environment before the "
            "amendment, the defaults trial's value). Why: the first ppo_residual trial (the "
            "same draw as ppo's first) sat 10-100x above PD-only's error, its exploration "
            "(SB3's unit Gaussian on the action) adding torques as large as the PD "
            "feedback's; residual-RL practice keeps the residual small at the start (Silver "
            "et al. 2018 initialise its output layer at zero), and a scale on the residual "
            "is the knob that does so under that exploration. Decided from that one "
            "trial's learning curve, before any further residual trial and before any SAC "
            "trial. That trial stays on record (ppo_residual/journal_before_amendment_1.log, "
            "trials_before_amendment_1.csv) and is outside the count: the residual studies "
            "start again with the amended space. The plain peers' studies are unchanged."
        ),
    },
)
"""The rule's amendments, dated, each written before the trials it governs."""
RULE = (
    "One TPE study per peer (sac, sac_residual, ppo, ppo_residual), the per-loss search's "
    "sampler (seed {seed} plus the finished trials, {startup} random trials first) and count: "
    "{trials} trials with distinct values, then SB3's defaults as one more trial. The space: "
    "rl-zoo3's sampler of the algorithm with the stated changes; both variants of an algorithm "
    "search the same space. A trial runs the peer (experiments/peers.py's environment, "
    "VecNormalize and reward) with the trial's values on the selection motions (the "
    "SELECTION_SEED targets, never a test motion) with the selection seeds {seeds}, for "
    "{budget} robot-seconds (per algorithm), evaluated every {every:g} robot-seconds. Score of "
    "a run: the mean over its checkpoints of log10 of its mean tracking MSE over the five "
    "selection motions (a diverged motion or an MSE above 1000 x PD-only's: log10(1000 x "
    "PD-only)); score of a trial: the mean over seeds; lower is better. A peer's configuration "
    "is its lowest-scoring trial of the {total} (ties: the earlier). Written before the first "
    "trial."
)
SIZING = (
    "Measured before the first trial (2026-11-29), one run of SB3's defaults per algorithm on "
    "the iiwa14's selection motions, one seed, on one core shared with another single-core "
    "study (about half the core): PPO 0.44 s per robot-second of learning (102 robot-s in "
    "45 s; the residual variant 0.40) and about 5 s per evaluation of the five motions; SAC "
    "4.2 s per robot-second (40 robot-s in 167 s). A trial (3 seeds): PPO at 2000 robot-s "
    "about 3 x (880 + 20 x 5) = 2900 s, SAC at 500 robot-s about 3 x (2100 + 5 x 5) = 6400 s, "
    "at SB3's defaults; points of the space with more gradient steps per sample (PPO's 20 "
    "epochs of batches of 32, SAC's batches of 512 and 400-300 networks) cost up to 2 to 4 "
    "times that. 13 trials x 2 variants: PPO about 21 core-hours, SAC about 46, on a loaded "
    "core (about half that on a free one). SAC's trial budget is a quarter of its study "
    "budget for that reason; PPO's is the old study's 2000 robot-seconds."
)


def space(peer: str) -> dict:
    """``peer``'s space: its algorithm's (:data:`SPACES`), with :data:`RESIDUAL_SPACE` for a
    residual peer (amendment 1)."""
    extra = RESIDUAL_SPACE if peer.endswith("_residual") else {}
    return {**SPACES[peers.algorithm_of(peer)], **extra}


def defaults(peer: str) -> dict:
    """``peer``'s defaults point: SB3's defaults (:data:`DEFAULTS`), with
    :data:`RESIDUAL_DEFAULTS` for a residual peer."""
    extra = RESIDUAL_DEFAULTS if peer.endswith("_residual") else {}
    return {**DEFAULTS[peers.algorithm_of(peer)], **extra}


def rule(every: float = peers.EVERY) -> dict:
    """The rule's record (``rule.json``): the text, the spaces, their changes, the defaults
    points, the seeds, the budgets, the sizing and the amendments."""
    text = RULE.format(
        seed=loss_search.SAMPLER_SEED,
        startup=loss_search.STARTUP,
        trials=TRIALS,
        seeds=list(SEEDS),
        budget=BUDGET,
        every=every,
        total=TRIALS + 1,
    )
    return json.loads(json.dumps({
        "rule": text, "spaces": SPACES, "space_changes": SPACE_CHANGES, "net_arch": NET_ARCH,
        "defaults": DEFAULTS, "seeds": list(SEEDS), "budget": BUDGET, "every": every,
        "trials": TRIALS, "sampler_seed": loss_search.SAMPLER_SEED,
        "startup": loss_search.STARTUP, "sizing": SIZING, "residual_space": RESIDUAL_SPACE,
        "residual_defaults": RESIDUAL_DEFAULTS, "amendments": list(AMENDMENTS),
    }))  # fmt: skip


def check_rule(out: str, every: float = peers.EVERY, write: bool = False) -> dict:
    """The committed rule in ``out/rule.json``; written there with ``write`` when there is
    none. Raises SystemExit when it differs from this file's (a rule changes only as a
    written amendment, never silently), or when there is none and ``write`` is False."""
    path = os.path.join(out, "rule.json")
    wanted = rule(every)
    if not os.path.exists(path):
        if not write:
            raise SystemExit(f"peers_search: no rule in {path}: write and commit it first "
                             "(--write-rule), before the first trial")  # fmt: skip
        os.makedirs(out, exist_ok=True)
        with open(path, "w") as f:
            json.dump(wanted, f, indent=1)
        return wanted
    with open(path) as f:
        committed = json.load(f)
    if committed != wanted:
        changed = sorted(k for k in set(committed) | set(wanted)
                         if committed.get(k) != wanted.get(k))  # fmt: skip
        raise SystemExit(f"peers_search: {path} differs from experiments/peers_search.py in "
                         f"{changed}: the committed rule stands")  # fmt: skip
    return committed


def suggest(trial, peer: str) -> dict:
    """The trial's values (``{name: value}``) in ``peer``'s space (:func:`space`)."""
    values = {}
    for name, (kind, *args) in space(peer).items():
        if kind == "categorical":
            values[name] = trial.suggest_categorical(name, args[0])
        elif kind == "log":
            values[name] = trial.suggest_float(name, *args, log=True)
        elif kind == "uniform":
            values[name] = trial.suggest_float(name, *args)
        else:
            raise ValueError(f"space({peer!r})[{name!r}]: kind {kind!r} unknown")
    return values


def hyper(peer: str, values: dict) -> dict:
    """SB3's constructor arguments (JSON, as ``peers.run_peer`` takes them) of a point of
    ``peer``'s space, converted as rl-zoo3 converts its samples (a residual peer's
    ``residual_scale`` kept as it is: ``run_peer`` gives it to the environment).

    Examples:
      >>> sac = hyper("sac", DEFAULTS["sac"])
      >>> sac["policy_kwargs"], sac["gradient_steps"]
      ({'net_arch': [256, 256]}, 1)
    """
    values = dict(values)
    algorithm = peers.algorithm_of(peer)
    if algorithm == "ppo":
        arguments = {k: v for k, v in values.items() if k not in ("net_arch", "activation_fn")}
        arguments["gamma"] = 1 - arguments.pop("one_minus_gamma")
        arguments["gae_lambda"] = 1 - arguments.pop("one_minus_gae_lambda")
        arguments["policy_kwargs"] = {"net_arch": NET_ARCH["ppo"][values["net_arch"]],
                                      "activation_fn": values["activation_fn"]}  # fmt: skip
        return arguments
    if algorithm == "sac":
        arguments = {k: v for k, v in values.items() if k != "net_arch"}
        arguments["gradient_steps"] = arguments["train_freq"]
        arguments["policy_kwargs"] = {"net_arch": NET_ARCH["sac"][values["net_arch"]]}
        return arguments
    raise ValueError(f"peer={peer!r}: one of {list(peers.PEERS)}")


def run_score(records: pd.DataFrame, pd_only: float) -> float:
    """A run's score under :data:`RULE` from its records (``peers.COLUMNS``): the mean over its
    checkpoints of ``log10`` of the mean MSE over the motions, a checkpoint with a diverged
    motion, a non-finite MSE or one above 1000 x ``pd_only`` scoring ``log10(1000 x
    pd_only)``."""
    cap = math.log10(1000 * pd_only)
    points = []
    for _, at in records.groupby("robot_s"):
        mse = at.tracking_mse.mean()
        bad = bool(at.diverged.any()) or not np.isfinite(mse)
        points.append(cap if bad else min(math.log10(mse), cap))
    if not points:
        raise ValueError("run_score: the run has no checkpoint")
    return float(np.mean(points))


def _hash(values: dict) -> str:
    return hashlib.sha1(loss_search._key(values).encode()).hexdigest()[:12]


def study(out: str, peer: str):
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    folder = os.path.join(out, peer)
    os.makedirs(folder, exist_ok=True)
    backend = optuna.storages.journal.JournalFileBackend(os.path.join(folder, "journal.log"))
    return optuna.create_study(
        study_name=f"peers-{peer}",
        storage=optuna.storages.JournalStorage(backend),
        sampler=loss_search.sampler(0),
        direction="minimize",
        load_if_exists=True,
    )


def distinct(search, peer: str) -> int:
    """Finished trials with distinct values, SB3's defaults not counted."""
    import optuna

    done = search.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    keys = {loss_search._key(t.params) for t in done}
    keys.discard(loss_search._key(defaults(peer)))
    return len(keys)


def _has_defaults(search, peer: str, states) -> bool:
    values = loss_search._key(defaults(peer))
    return any(loss_search._key(loss_search._values(t)) == values
               for t in search.get_trials(deepcopy=False, states=states))  # fmt: skip


def next_peer(searches: dict, trials: int = TRIALS) -> str | None:
    """The peer whose study runs the next trial (round-robin: the fewest finished first), None
    when all are complete; a study with its ``trials`` TPE trials gets SB3's defaults queued."""
    import optuna

    complete = (optuna.trial.TrialState.COMPLETE,)
    alive = complete + (optuna.trial.TrialState.WAITING, optuna.trial.TrialState.RUNNING)
    done = {}
    for peer, search in searches.items():
        done[peer] = distinct(search, peer)
        if done[peer] >= trials and not _has_defaults(search, peer, complete):
            if not _has_defaults(search, peer, alive):
                search.enqueue_trial(defaults(peer))
            done[peer] = trials - 0.5
    todo = [peer for peer in searches if done[peer] < trials]
    return min(todo, key=lambda p: (done[p], list(searches).index(p)), default=None)


def _recover(search) -> None:
    """A trial left running by a killed piece: failed, and its values tried again first."""
    import optuna

    for trial in search.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        search.tell(trial.number, state=optuna.trial.TrialState.FAIL)
        search.enqueue_trial(trial.params)


def base_config(quick: bool = False):
    """The study's task on the selection motions: the quickstart (``cfm-jax train``'s
    defaults); ``quick``: the two-link arm's 0.2 s reaches."""
    import _study

    from cfm_jax import config as config_lib

    loop = config_lib.LoopConfig(torque_scale=_study.BEFORE_POSE["loop.torque_scale"])
    config = config_lib.Config(loop=loop)
    if quick:
        short = config_lib.TaskConfig(duration=0.2)
        config = config_lib.Config(robot="two_link_arm", task=short, loop=loop)
    return peers.selection_config(config)


def seed_score(peer: str, values: dict, seed: int, config, pd_only: float, checkpoints,
               args) -> float:  # fmt: skip
    """One selection seed's run score. A finished seed's score is kept in
    ``--out/<peer>/seeds/<values' hash>_seed<N>.json`` (committed, a few bytes), so a trial
    killed between seeds (a session's end, a machine whose scratch is wiped) reruns only the
    seeds it had not finished; the runs themselves live in ``--runs`` and may be lost."""
    key = f"{_hash(values)}_seed{seed}"
    kept = os.path.join(args.out, peer, "seeds", f"{key}.json")
    if os.path.exists(kept):
        with open(kept) as f:
            record = json.load(f)
        if record["values"] != loss_search._key(values):
            raise ValueError(f"{kept}: kept for other values than the trial's (hash clash)")
        return float(record["score"])
    out = os.path.join(args.runs, peer, _hash(values), f"seed{seed}")
    peers.run_peer(peer, seed, config, out, checkpoints, hyper(peer, values))
    score = run_score(pd.read_csv(os.path.join(out, "records.csv")), pd_only)
    os.makedirs(os.path.dirname(kept), exist_ok=True)
    part = f"{kept}.{os.getpid()}"
    with open(part, "w") as f:
        json.dump({"values": loss_search._key(values), "seed": seed, "score": score}, f)
    os.replace(part, kept)
    return score


def run_trial(search, peer: str, config, pd_only: float, args) -> dict:
    """Ask, run the peer on each selection seed (resumable), score, tell; the trial's record."""
    algorithm = peers.algorithm_of(peer)
    trial = loss_search.ask(search)
    values = suggest(trial, peer)
    budget = args.run_budget or BUDGET[algorithm]
    checkpoints = peers.default_checkpoints(budget, args.every)
    seeds = list(SEEDS[:1] if args.quick else SEEDS)
    start = time.perf_counter()
    scores = []
    for seed in seeds:
        scores.append(seed_score(peer, values, seed, config, pd_only, checkpoints, args))
    seconds = time.perf_counter() - start
    value = float(np.mean(scores))
    trial.set_user_attr("seconds", round(seconds, 1))
    trial.set_user_attr("seed_scores", scores)
    search.tell(trial, value)
    return {"peer": peer, "trial": trial.number, "score": value, "seconds": round(seconds, 1),
            **values}  # fmt: skip


def records(out: str, names) -> pd.DataFrame:
    """Every finished trial of the studies in ``out``."""
    import optuna

    rows = []
    for peer in names:
        if not os.path.exists(os.path.join(out, peer, "journal.log")):
            continue
        for t in study(out, peer).get_trials(
            deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)
        ):
            rows.append({"peer": peer, "trial": t.number, "score": t.value,
                         "seconds": t.user_attrs.get("seconds"), **t.params})  # fmt: skip
    return pd.DataFrame(rows)


def chosen(frame: pd.DataFrame, trials: int = TRIALS) -> dict:
    """Per peer: the lowest-scoring trial (ties: the earlier), its values, SB3's arguments
    (``hyper``) and whether its study is complete (``trials`` distinct TPE trials and SB3's
    defaults)."""
    out = {}
    for peer, mine in frame.groupby("peer", sort=False):
        best = mine.sort_values(["score", "trial"]).iloc[0]
        values = typed(peer, best)
        keys = {loss_search._key(typed(peer, r)) for _, r in mine.iterrows()}
        point = loss_search._key(defaults(peer))
        complete = point in keys and len(keys - {point}) >= trials
        out[peer] = {"trial": int(best["trial"]), "score": float(best["score"]),
                     "values": values, "hyper": hyper(peer, values),
                     "complete": bool(complete), "trials": len(mine)}  # fmt: skip
    return out


def typed(peer: str, row) -> dict:
    """The values of ``peer``'s space in a record's row, as the space has them (a table's
    column of integers with gaps reads back as floats).

    Examples:
      >>> typed("sac", {**DEFAULTS["sac"], "buffer_size": 1e6})["buffer_size"]
      1000000
    """
    values = {}
    for name, (kind, *args) in space(peer).items():
        value = row[name]
        if kind == "categorical":
            matches = [v for v in args[0] if v == value]
            if not matches:
                raise ValueError(f"{peer}: {name}={value!r} is not one of {args[0]}")
            value = matches[0]
        else:
            value = float(value)
        values[name] = value
    return values


def write_records(out: str, trials: int = TRIALS) -> pd.DataFrame:
    """``trials.csv`` and ``chosen.json`` in ``out`` from the studies there (written whole,
    then renamed)."""
    frame = records(out, peers.PEERS)
    if frame.empty:
        return frame
    for name, text in (
        ("trials.csv", frame.to_csv(index=False)),
        ("chosen.json", json.dumps({"chosen": chosen(frame, trials)}, indent=1)),
    ):
        part = os.path.join(out, f".{name}.{os.getpid()}")
        with open(part, "w") as f:
            f.write(text)
        os.replace(part, os.path.join(out, name))
    return frame


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peers", default=",".join(peers.PEERS))
    parser.add_argument("--trials", type=int, default=TRIALS, help="TPE trials per peer")
    parser.add_argument("--budget", type=float, default=math.inf,
                        help="seconds: start no trial after this (a piece)")  # fmt: skip
    parser.add_argument("--out", default=os.path.join(ROOT, "docs", "results", "peers_search"))
    parser.add_argument("--runs", default=os.path.join(ROOT, "results", "peers_search"))
    parser.add_argument("--every", type=float, default=peers.EVERY,
                        help="robot-seconds between a run's evaluations")  # fmt: skip
    parser.add_argument("--run-budget", type=float, default=None,
                        help="robot-seconds of a run (smoke tests; default BUDGET)")  # fmt: skip
    parser.add_argument("--write-rule", action="store_true",
                        help="write --out/rule.json (before the first trial)")  # fmt: skip
    parser.add_argument("--quick", action="store_true",
                        help="the two-link arm, one seed (a smoke test)")  # fmt: skip
    args = parser.parse_args(argv)
    names = [p for p in args.peers.split(",") if p]
    bad = sorted(set(names) - set(peers.PEERS))
    if bad:
        parser.error(f"--peers: {bad} not allowed; choose from {list(peers.PEERS)}")
    if args.trials < 1:
        parser.error(f"--trials={args.trials}: a positive number")
    if not args.quick and (args.run_budget is not None or args.every != peers.EVERY):
        parser.error("--run-budget and --every change the rule: only with --quick")
    if args.write_rule:
        check_rule(args.out, args.every, write=True)
        print(f"peers_search: the rule is in {os.path.join(args.out, 'rule.json')}")
        return
    check_rule(args.out, args.every)
    start = time.perf_counter()
    config = base_config(args.quick)
    pd_only = peers.pd_only_mse(config)
    searches = {peer: study(args.out, peer) for peer in names}
    for search in searches.values():
        _recover(search)
    while time.perf_counter() - start < args.budget:
        peer = next_peer(searches, args.trials)
        if peer is None:
            break
        row = run_trial(searches[peer], peer, config, pd_only, args)
        print(f"peers_search: {peer} trial {row['trial']}: score {row['score']:.3f} in "
              f"{row['seconds']:.0f} s", flush=True)  # fmt: skip
        write_records(args.out, args.trials)
    frame = write_records(args.out, args.trials)
    print(f"peers_search: {len(frame)} trials recorded in {args.out}")


if __name__ == "__main__":
    sys.exit(main())
