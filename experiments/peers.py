"""Robot-seconds to a working controller: cfm_jax's four losses against SAC and PPO on the
same tracking task, one command (issues 42 and 68).

Not a test: a study. It runs

* **cfm_jax**: ``cfm-jax train --loss LOSS --seeds N`` for each of the four losses, as a user
  would (the quickstart: the iiwa14's inverse-dynamics task, 4 iterations; ``--train-flags``
  passes other flags), each loss in its own process and folder (``OUT/cfm_LOSS``). Its
  controller of iteration ``i`` was fitted on the babbling and ``i`` iterations' rollouts:
  ``babbling_rollouts x targets x duration + i x targets x duration`` robot-seconds
  (20 + 10 i s on the quickstart);
* **the peers**, SAC and PPO of Stable-Baselines3 (PyTorch, CPU), each in two variants
  (:data:`PEERS`, :data:`ACTION`): acting through the torque scale cfm_jax's controller acts
  through (``sac``, ``ppo``), and as a residual on the task's PD feedback (``sac_residual``,
  ``ppo_residual``: zero action is PD-only, what a roboticist would run on a real arm); on
  :class:`cfm_jax.envs.TrackingEnv` of the very config the cfm_jax run recorded: the same
  robot, control period, torque limits, start state and references. Observations and
  rewards are normalised by SB3's ``VecNormalize`` (saved with the model; frozen when
  evaluating), the reward scaled to order 1 first (:func:`reward_scale`: 1 / PD-only's MSE on
  the selection motions). Their episodes follow the task's references in turn, the references
  every iteration of Algorithm 1 rolls out on (the babbling knows none of them; neither
  method sees the reference controller). Every peer is evaluated every ``--every``
  robot-seconds (100 by default; robot-seconds = environment steps x control period), and
  every ``--early-every`` (10, cfm_jax's resolution) before that, with its deterministic
  policy on each test reference; evaluation episodes are not learning data. The tracking
  MSE is the library's metric (``tests/test_envs.py``);

then writes ``--page`` (``docs/results/peers.md``): a log-log figure of test tracking MSE
against robot-seconds (mean over seeds and its 95% bootstrap band; PD-only and oracle as
lines) and a table per method: robot-seconds to PD-only's MSE (the median of the seeds' first
crossings, and each seed's) and to 10x below it, the MSE at cfm_jax's budget and at the
peers' largest, how much the curve still falls over the last fifth of its budget (is it
flat?), and the wall-clock time. A seed's MSE at a checkpoint is its mean over the
test references; a rollout that diverged makes that checkpoint a failure for the seed.

Resumable: a finished cfm_jax loss or peer seed is read, not run again; an interrupted
cfm_jax loss resumes from its checkpoints; an interrupted peer resumes from its last
robot-second checkpoint (its model, normalisation, optimiser and replay buffer as SB3 saves
them; a resumed peer is not bit-identical to an uninterrupted one: SB3 does not save its
random state). A peer begun on a coarser grid gets the checkpoints it passed from a replay
of its seed from the start, checked bit for bit against it (:func:`_replay`). ``--records``
(the page's data, committed) is rewritten after every piece.

The peers' hyperparameters: each peer's choice of its search (``experiments/peers_search.py``,
on the selection motions, by a rule committed before its first trial; ``--hyper``), SB3's
defaults for a peer whose search is not complete. ``--peer-budgets`` gives a peer its own
budget (PPO is cheap: run it until its curve is flat).

Usage:
  python experiments/peers.py [--seeds 5] [--methods joint,...,sac,sac_residual,ppo,...]
      [--budget 2000] [--peer-budgets ppo=20000,ppo_residual=20000] [--every 100]
      [--early-every 10]
      [--out results/peers] [--page docs/results/peers.md] [--hyper FILE]
      [--records docs/results/peers_records.csv] [--train-flags "..."] [--jobs 2]
      [--page-only]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from typing import NamedTuple

import numpy as np
import pandas as pd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOSSES = ("joint", "task", "distal", "supervised")
PEERS = ("sac", "sac_residual", "ppo", "ppo_residual")
"""The peers: SB3's SAC and PPO, each in two variants (:data:`ACTION`)."""
METHODS = LOSSES + PEERS
ACTION = {"sac": "scale", "sac_residual": "residual", "ppo": "scale", "ppo_residual": "residual"}
"""Each peer's action (:data:`cfm_jax.envs.ACTIONS`): ``scale``, the torque through the torque
scale cfm_jax's controller acts through; ``residual``, that torque added to the task's PD
feedback (the PD-only baseline at zero action)."""
HYPERPARAMETERS = {peer: {} for peer in PEERS}
"""Arguments given to SB3's ``SAC`` / ``PPO`` beyond ``"MlpPolicy"``, the environment and
the seed where no tuning record is given: none, SB3's own defaults for continuous control
(SAC: learning rate 3e-4, batch 256, buffer 1e6, automatic entropy with target
``-action_dim``; PPO: learning rate 3e-4, 2048 steps per update, 10 epochs of batches of 64).
The tuned ones: ``experiments/peers_search.py``."""
COLUMNS = ["method", "seed", "robot_s", "target", "tracking_mse", "diverged", "wall_s"]
"""The records: one row per method, seed, robot-second checkpoint and test reference;
``wall_s`` the method's wall-clock seconds (this seed) up to that checkpoint (cfm_jax: the
whole run of the loss, all seeds, on every row)."""
EVERY = 100.0
"""Robot-seconds between the peers' evaluations (``--every``)."""
EARLY = 10.0
"""Robot-seconds between the study's evaluations before the first ``EVERY`` (``--early-every``):
cfm_jax's resolution (one iteration's rollouts of the five 2-s motions), so that a peer that
gets to a level within its first ``EVERY`` s is not charged the whole of it."""


def algorithm_of(method: str) -> str:
    """``sac`` or ``ppo``: the SB3 algorithm of a peer (:data:`PEERS`).

    Examples:
      >>> algorithm_of("ppo_residual")
      'ppo'
    """
    if method not in PEERS:
        raise ValueError(f"method={method!r}: not a peer; one of {PEERS}")
    return method.split("_")[0]


def default_checkpoints(budget: float, every: float = EVERY, early: float | None = None):
    """Robot-second checkpoints on a linear grid: every ``every`` s up to ``budget`` (and
    ``budget`` itself where the grid misses it), and every ``early`` s before the first
    ``every`` where given, fine enough that robot-seconds to a level are not set by the grid.

    Examples:
      >>> default_checkpoints(450)
      [100.0, 200.0, 300.0, 400.0, 450.0]
      >>> default_checkpoints(250, early=25)
      [25.0, 50.0, 75.0, 100.0, 200.0, 250.0]
    """
    if not (every > 0 and budget > 0 and (early is None or early > 0)):
        raise ValueError(
            f"every={every!r}, budget={budget!r}, early={early!r}: each must be > 0 (robot-s)"
        )
    points = [every * k for k in range(1, int(np.floor(budget / every + 1e-9)) + 1)]
    if not points or points[-1] < budget - 1e-9:
        points.append(float(budget))
    if early is not None:
        first = min(every, budget)
        points = [early * k for k in range(1, int(np.ceil(first / early - 1e-9)))] + points
    return [float(p) for p in points]


# ----- cfm_jax --------------------------------------------------------------------------


def _cfm_finished(out: str) -> bool:
    return os.path.exists(os.path.join(out, "peers_wall_s.txt"))


def run_cfm(loss: str, seeds: int, out: str, flags: list[str]) -> None:
    """``cfm-jax train --loss LOSS --seeds N --out OUT`` (resumed where ``out`` holds a run),
    its wall-clock seconds written to ``OUT/peers_wall_s.txt`` when it finishes."""
    if _cfm_finished(out):
        return
    resume = ["--resume"] if os.path.exists(os.path.join(out, "config.json")) else []
    command = [sys.executable, "-m", "cfm_jax.cli", "train", "--loss", loss, "--seeds",
               str(seeds), "--out", out, "--quiet", *flags, *resume]  # fmt: skip
    start = time.perf_counter()
    subprocess.run(command, check=True, cwd=ROOT)
    with open(os.path.join(out, "peers_wall_s.txt"), "w") as f:
        f.write(f"{time.perf_counter() - start:.1f}\n")


def cfm_seconds(config) -> tuple[float, float]:
    """``(babbling, per iteration)`` robot-seconds of a cfm_jax run of ``config``: the
    babbling's ``loop.babbling_rollouts`` rollouts and each iteration's rollout, each
    ``targets x steps x control_dt``."""
    from cfm_jax.learning.algorithm import Experiment

    task = Experiment(config).task
    rollout = task.targets * task.steps * task.control_dt
    return config.loop.babbling_rollouts * rollout, rollout


def cfm_records(loss: str, out: str) -> pd.DataFrame:
    """The records of a finished cfm_jax loss: iteration ``i`` at ``babbling + i x
    per-iteration`` robot-seconds."""
    from cfm_jax import config as config_lib

    with open(os.path.join(out, loss, "config.json")) as f:
        config = config_lib.from_dict(json.load(f))
    babbling, per_iteration = cfm_seconds(config)
    metrics = pd.read_csv(os.path.join(out, "metrics.csv"))
    with open(os.path.join(out, "peers_wall_s.txt")) as f:
        wall = float(f.read())
    return pd.DataFrame({
        "method": loss,
        "seed": metrics.seed,
        "robot_s": babbling + metrics.iteration * per_iteration,
        "target": metrics.target,
        "tracking_mse": metrics.tracking_mse,
        "diverged": (metrics.diverged != 0).astype(int),
        "wall_s": wall,
    })[COLUMNS]  # fmt: skip


# ----- the peers ------------------------------------------------------------------------


def evaluate(model, env, normalise=None) -> list[tuple[int, float, int]]:
    """``(target, tracking MSE, diverged)`` of the deterministic policy on each test
    reference of ``env`` (a ``references="test"`` :class:`cfm_jax.envs.TrackingEnv`): the
    mean over the episode's steps of the squared tracking error (the library's metric);
    NaN for an episode that diverged. ``normalise``: the observation normalisation the
    policy learned with, frozen (SB3's ``VecNormalize.normalize_obs``, which updates no
    statistic), or None."""
    rows = []
    for k in range(env.task.targets):
        obs, _ = env.reset(options={"target": k})
        errors, diverged = [], False
        while True:
            shown = obs if normalise is None else normalise(obs)
            action, _ = model.predict(shown, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            errors.append(np.mean(np.square(info["tracking_error"], dtype=np.float64)))
            if terminated or truncated:
                diverged = bool(info["diverged"])
                break
        rows.append((k, float("nan") if diverged else float(np.mean(errors)), int(diverged)))
    return rows


def pd_only_mse(config, experiment=None) -> float:
    """PD-only's tracking MSE on ``config``'s references (the mean over them): the ``residual``
    environment at zero action, which is the task's PD feedback alone."""
    from cfm_jax import envs

    env = envs.TrackingEnv(config, references="test", experiment=experiment, action="residual")
    zero = np.zeros(env.action_space.shape, np.float32)
    return float(np.nanmean([mse for _, mse, _ in evaluate(_Constant(zero), env)]))


class _Constant:
    """A policy of one action (SB3's ``predict`` interface)."""

    def __init__(self, action):
        self.action = action

    def predict(self, obs, deterministic=True):
        return self.action, None


def reward_scale(config) -> float:
    """The peers' reward factor: ``1 / PD-only's tracking MSE on the selection motions``
    (:func:`selection_config`), so that PD-only's reward is -1 a step on average on motions
    that are not the test ones, whatever the robot and its units; the same factor in the
    tuning and the study."""
    return 1.0 / pd_only_mse(selection_config(config))


def run_peer(
    method: str, seed: int, config, out: str, checkpoints: list[float], hyper: dict | None = None
) -> None:
    """Train ``method`` (:data:`PEERS`) with ``seed`` up to the last checkpoint, evaluating at
    each; ``OUT/records.csv`` gains the rows of each checkpoint as it is reached, and the
    model, its observation and reward normalisation (SB3's ``VecNormalize``) and SAC's replay
    buffer are saved there, so an interruption loses at most the piece since the last
    checkpoint. The environment: :class:`cfm_jax.envs.TrackingEnv` with the peer's
    :data:`ACTION` and the reward scaled by :func:`reward_scale`; evaluation with the
    normalisation's statistics frozen. ``hyper``: arguments for SB3's constructor (None:
    :data:`HYPERPARAMETERS`) and, for a residual peer, the environment's ``residual_scale``
    (default 1); a resumed run must have the ones it began with."""
    import stable_baselines3
    import torch
    from stable_baselines3.common import vec_env

    from cfm_jax import envs
    from cfm_jax.learning.algorithm import Experiment

    torch.set_num_threads(1)
    hyper = dict(HYPERPARAMETERS[method] if hyper is None else hyper)
    os.makedirs(out, exist_ok=True)
    experiment = Experiment(config)
    records = os.path.join(out, "records.csv")
    state_path = os.path.join(out, "state.json")
    model_path = os.path.join(out, "model.zip")
    buffer_path = os.path.join(out, "buffer.pkl")
    normaliser_path = os.path.join(out, "vecnormalize.pkl")
    algorithm = {"sac": stable_baselines3.SAC, "ppo": stable_baselines3.PPO}[algorithm_of(method)]
    if os.path.exists(state_path):
        with open(state_path) as f:
            state = json.load(f)
        if state.get("hyper", {}) != hyper:
            raise SystemExit(
                f"peers: {out} began with hyperparameters {state.get('hyper', {})}, not "
                f"{hyper}: give another --out, or remove the folder to start again"
            )
        scale = state["reward_scale"]
    else:
        scale = reward_scale(config)
        state = {"wall_s": 0.0, "done": [], "hyper": hyper, "reward_scale": scale}
    residual = float(hyper.get("residual_scale", 1.0))
    env = envs.TrackingEnv(config, references="test", experiment=experiment,
                           action=ACTION[method], reward_scale=scale,
                           residual_scale=residual)  # fmt: skip
    probe = envs.TrackingEnv(config, references="test", experiment=experiment,
                             action=ACTION[method], residual_scale=residual)  # fmt: skip
    arguments = _arguments(hyper, env)
    if os.path.exists(model_path):
        venv = vec_env.VecNormalize.load(normaliser_path, vec_env.DummyVecEnv([lambda: env]))
        model = algorithm.load(model_path, env=venv, device="cpu")
        if algorithm_of(method) == "sac":
            model.load_replay_buffer(buffer_path)
    else:
        venv = vec_env.VecNormalize(vec_env.DummyVecEnv([lambda: env]),
                                    gamma=arguments.get("gamma", 0.99))  # fmt: skip
        model = algorithm("MlpPolicy", venv, seed=seed, device="cpu", verbose=0, **arguments)
        pd.DataFrame(columns=COLUMNS).to_csv(records, index=False)
    dt = env.control_dt
    passed = [p for p in checkpoints
              if p not in state["done"] and int(round(p / dt)) <= model.num_timesteps]  # fmt: skip
    if passed:
        _replay(method, seed, config, out, state, passed, hyper)
    for point in checkpoints:
        if point in state["done"]:
            continue
        start = time.perf_counter()
        remaining = int(round(point / dt)) - model.num_timesteps
        if remaining > 0:
            model.learn(remaining, reset_num_timesteps=False)
        state["wall_s"] += time.perf_counter() - start
        if model.num_timesteps == state.get("evaluated"):
            # PPO learns in whole rollouts (n_steps): it may pass several checkpoints in
            # one; a model is evaluated once.
            state["done"].append(point)
            continue
        state["evaluated"] = model.num_timesteps
        rows = [
            (method, seed, model.num_timesteps * dt, k, mse, diverged, state["wall_s"])
            for k, mse, diverged in evaluate(model, probe, venv.normalize_obs)
        ]
        pd.DataFrame(rows, columns=COLUMNS).to_csv(records, mode="a", header=False, index=False)
        model.save(model_path)
        venv.save(normaliser_path)
        if algorithm_of(method) == "sac":
            model.save_replay_buffer(buffer_path)
        state["done"].append(point)
        with open(state_path, "w") as f:
            json.dump(state, f)
    with open(state_path, "w") as f:
        json.dump(state, f)


def _replay(method, seed, config, out: str, state: dict, passed: list, hyper: dict) -> None:
    """Checkpoints a run has passed without evaluating them (it began on a coarser grid): the
    same seed run again from the start in ``OUT/replay`` through them and on to the run's next
    evaluated checkpoint, whose rows must equal the run's bit for bit (the same run: the seed,
    the code and the machine's arithmetic) before the replay's rows of ``passed`` join the
    run's records; otherwise the program stops and says so. A replay cut short starts again
    (a resumed SB3 run draws anew from its seed, so it is not the same run)."""
    import shutil

    records_path = os.path.join(out, "records.csv")
    records = pd.read_csv(records_path)
    later = sorted(p for p in state["done"] if p > max(passed))
    if not later:
        raise SystemExit(f"peers: {out}: nothing evaluated after {max(passed)} s to check a replay")
    points = sorted(passed) + [later[0]]
    folder = os.path.join(out, "replay")
    if not _peer_finished(folder, points):
        shutil.rmtree(folder, ignore_errors=True)
        print(f"peers: {method} seed {seed}: replaying to {points[-1]} s for {passed}", flush=True)
        run_peer(method, seed, config, folder, points, hyper)
    replay = pd.read_csv(os.path.join(folder, "records.csv"))
    check = replay.robot_s.max()
    keys = ["robot_s", "target", "tracking_mse", "diverged"]
    mine = replay[replay.robot_s == check][keys].reset_index(drop=True)
    theirs = records[records.robot_s == check][keys].reset_index(drop=True)
    if theirs.empty or not mine.equals(theirs):
        raise SystemExit(
            f"peers: {out}: the replay's rows at {check} s differ from the run's "
            f"({mine.tracking_mse.tolist()} against {theirs.tracking_mse.tolist()}): not the "
            "same run (another machine's arithmetic?); rerun the seed from the start"
        )
    early = replay[(replay.robot_s < check) & ~replay.robot_s.isin(records.robot_s)]
    merged = pd.concat([records, early]).sort_values(["robot_s", "target"], kind="stable")
    merged.to_csv(records_path, index=False)
    state["done"] = sorted(set(state["done"]) | set(passed))
    with open(os.path.join(out, "state.json"), "w") as f:
        json.dump(state, f)


def _peer_finished(out: str, checkpoints: list[float]) -> bool:
    try:
        with open(os.path.join(out, "state.json")) as f:
            return set(checkpoints) <= set(json.load(f)["done"])
    except FileNotFoundError:
        return False


ACTIVATIONS = ("tanh", "relu")


def _arguments(hyper: dict, env) -> dict:
    """SB3's constructor arguments of ``hyper`` (JSON: the records keep it): SAC's
    ``target_entropy_per_action`` (a multiple of the action dimension) becomes its
    ``target_entropy``, ``policy_kwargs.activation_fn`` (one of :data:`ACTIVATIONS`) the
    PyTorch module; ``residual_scale`` (the environment's) is left out."""
    import torch

    arguments = json.loads(json.dumps(hyper))
    arguments.pop("residual_scale", None)  # the environment's, not SB3's
    per_action = arguments.pop("target_entropy_per_action", None)
    if per_action is not None:
        arguments["target_entropy"] = float(per_action * env.action_space.shape[0])
    policy = arguments.get("policy_kwargs", {})
    if "activation_fn" in policy:
        name = policy["activation_fn"]
        if name not in ACTIVATIONS:
            raise ValueError(f"policy_kwargs.activation_fn={name!r}: one of {ACTIVATIONS}")
        policy["activation_fn"] = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[name]
    return arguments


class Piece(NamedTuple):
    """One peer run of the study or the selection (the arguments of :func:`run_peer`)."""

    method: str
    seed: int
    config: object
    out: str
    checkpoints: tuple
    hyper: dict


def _run_piece(piece: Piece) -> Piece:
    run_peer(piece.method, piece.seed, piece.config, piece.out, list(piece.checkpoints),
             piece.hyper)  # fmt: skip
    return piece


def run_pieces(pieces: list[Piece], jobs: int):
    """Run the unfinished ``pieces``, ``jobs`` at once (each its own spawned process,
    PyTorch on one thread); yields each piece as it finishes, finished ones first."""
    todo = []
    for piece in pieces:
        if _peer_finished(piece.out, list(piece.checkpoints)):
            yield piece
        else:
            todo.append(piece)
    if jobs <= 1:
        for piece in todo:
            print(f"peers: {piece.method} {_name(piece.hyper)} seed {piece.seed} ...", flush=True)
            yield _run_piece(piece)
        return
    import concurrent.futures
    import multiprocessing

    context = multiprocessing.get_context("spawn")  # no fork of a process that ran JAX
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
        futures = [pool.submit(_run_piece, piece) for piece in todo]
        for piece in todo:
            print(
                f"peers: {piece.method} {_name(piece.hyper)} seed {piece.seed} queued", flush=True
            )
        for future in concurrent.futures.as_completed(futures):
            yield future.result()


# ----- the selection motions ---------------------------------------------------------


def selection_config(config):
    """``config`` on the selection motions: the targets of
    :func:`cfm_jax.tasks.references.driven_targets` with ``SELECTION_SEED``."""
    import dataclasses

    from cfm_jax.sim import robots
    from cfm_jax.tasks import references

    robot = robots.load(config.robot, actuators=config.robot_actuators,
                        torque_limit=config.robot_torque_limit)  # fmt: skip
    home = robot.home if config.task.home is None else np.asarray(config.task.home)
    targets = references.driven_targets(robot, home, references.SELECTION_SEED)
    task = dataclasses.replace(
        config.task, targets=tuple(tuple(float(x) for x in t) for t in targets)
    )
    return dataclasses.replace(config, task=task)


def _name(hyper: dict) -> str:
    return "defaults" if not hyper else json.dumps(hyper, sort_keys=True)


# ----- the page -------------------------------------------------------------------------


def seed_curves(records: pd.DataFrame) -> pd.DataFrame:
    """Per method, seed and checkpoint: the mean tracking MSE over the test references
    (inf where one diverged) and the wall-clock seconds."""
    grouped = records.groupby(["method", "seed", "robot_s"])
    curves = grouped.agg(tracking_mse=("tracking_mse", "mean"), diverged=("diverged", "max"),
                         wall_s=("wall_s", "max")).reset_index()  # fmt: skip
    curves.loc[curves.diverged > 0, "tracking_mse"] = np.inf
    return curves


def first_crossings(curves: pd.DataFrame, level: float, before: bool = False) -> dict:
    """Per seed, the first checkpoint (robot-seconds) whose MSE is at or below ``level``, or
    None where none is; with ``before``, the checkpoint before that one (0 where it is the
    first): the crossing lies between the two."""
    firsts = {}
    for seed, mine in curves.groupby("seed"):
        reached = mine[mine.tracking_mse <= level].robot_s
        first = float(reached.min()) if len(reached) else None
        if before and first is not None:
            earlier = mine[mine.robot_s < first].robot_s
            first = float(earlier.max()) if len(earlier) else 0.0
        firsts[int(seed)] = first
    return firsts


def late_change(curves: pd.DataFrame, fraction: float = 0.2) -> float | None:
    """Whether a curve is flat: the mean over seeds of ``log10`` MSE at the last checkpoint
    minus at the last checkpoint at or before ``(1 - fraction)`` of it (seeds that diverged
    at either left out); None where no seed has both. Near 0: flat; below: still improving."""
    changes = []
    for _, mine in curves.groupby("seed"):
        last = mine.robot_s.max()
        before = mine[mine.robot_s <= (1 - fraction) * last + 1e-9]
        if before.empty:
            continue
        end = mine[mine.robot_s == last].tracking_mse.iloc[0]
        start = before[before.robot_s == before.robot_s.max()].tracking_mse.iloc[0]
        if np.isfinite(end) and np.isfinite(start) and end > 0 and start > 0:
            changes.append(np.log10(end) - np.log10(start))
    return float(np.mean(changes)) if changes else None


def time_to(curves: pd.DataFrame, level: float) -> tuple[float | None, int, int]:
    """``(median robot-seconds, seeds that reach it, seeds)``: per seed the first checkpoint
    whose MSE is at or below ``level`` (:func:`first_crossings`); the median over the seeds
    that reach it (None if none does)."""
    firsts = [x for x in first_crossings(curves, level).values() if x is not None]
    seeds = curves.seed.nunique()
    return (float(np.median(firsts)) if firsts else None), len(firsts), seeds


def _mse_at(curves: pd.DataFrame, budget: float):
    """Mean and CI over seeds of the MSE at the last checkpoint at or below ``budget``
    (diverged seeds left out and counted), and that checkpoint."""
    from cfm_jax.analysis import report

    before = curves[curves.robot_s <= budget + 1e-9]
    if before.empty:
        return None, None, 0
    point = before.robot_s.max()
    at = before[before.robot_s == point].tracking_mse.to_numpy()
    finite = at[np.isfinite(at)]
    stats = dict(report.mean_ci(finite), n=len(finite)) if len(finite) else None
    return stats, point, int((~np.isfinite(at)).sum())


def summary_rows(records: pd.DataFrame, pd_only: float) -> list[dict]:
    """One row per method (in :data:`METHODS` order) of the page's table."""
    curves = seed_curves(records)
    cfm_budget = curves[curves.method.isin(LOSSES)].robot_s.max()
    peer_budget = curves[curves.method.isin(PEERS)].robot_s.max()
    rows = []
    for method in METHODS:
        mine = curves[curves.method == method]
        if mine.empty:
            continue
        wall = mine.groupby("seed").wall_s.max()
        rows.append(dict(
            method=method,
            to_pd=time_to(mine, pd_only),
            crossings=first_crossings(mine, pd_only),
            to_tenth=time_to(mine, pd_only / 10),
            tenth_crossings=first_crossings(mine, pd_only / 10),
            tenth_before=first_crossings(mine, pd_only / 10, before=True),
            at_cfm=_mse_at(mine, cfm_budget) if np.isfinite(cfm_budget) else (None, None, 0),
            at_peer=(
                _mse_at(mine, peer_budget)
                if method in PEERS and np.isfinite(peer_budget)
                else (None, None, 0)
            ),
            last=float(mine.robot_s.max()),
            late=late_change(mine),
            wall=float(wall.iloc[0]) if method in LOSSES else float(wall.mean()),
        ))  # fmt: skip
    return rows


def _time_text(result, last: float) -> str:
    median, reached, seeds = result
    if median is None:
        return f"not reached within {last:.3g} s (0/{seeds})"
    return f"{median:.3g} s ({reached}/{seeds})"


def _crossings_text(crossings: dict) -> str:
    return ", ".join("-" if x is None else f"{x:.4g}" for _, x in sorted(crossings.items()))


def _change_text(change) -> str:
    return "-" if change is None else f"{change:+.2f}"


def _mse_text(result) -> str:
    from cfm_jax.analysis import report

    stats, point, diverged = result
    if point is None:
        return "-"
    text = (report.ci_text(stats) if stats["n"] > 1 else f"{stats['mean']:.3g}") if stats else "-"
    text += f" at {point:.3g} s"
    return text + (f"; {diverged} diverged" if diverged else "")


def _rank_gap(x, y) -> float:
    """The mean rank of the seeds ``x`` minus that of ``y``, both pooled (None: inf)."""
    from scipy import stats as scipy_stats

    ranks = scipy_stats.rankdata([np.inf if v is None else v for v in [*x, *y]])
    return ranks[: len(x)].mean() - ranks[len(x) :].mean()


def rank_test(later, earlier) -> float:
    """Two-sided p-value of an exact two-sample permutation test of the seeds' robot-seconds
    to a level (a seed that never reaches it, None: inf): the difference of mean ranks, every split
    of the pooled seeds enumerated (scipy; two-sided: twice the smaller tail), no random number.

    Examples:
      >>> round(rank_test([500, 600, 700, 800, 900], [20, 20, 30, 30, 30]), 4)  # 2 of 252 splits
      0.0079
    """
    from scipy import stats as scipy_stats

    samples = tuple(
        np.array([np.inf if x is None else x for x in s], float) for s in (later, earlier)
    )
    result = scipy_stats.permutation_test(
        samples, _rank_gap, permutation_type="independent", n_resamples=np.inf
    )
    return float(result.pvalue)


def headline(records: pd.DataFrame) -> str:
    """The README's sentence on the peers, from the records alone (``tests/test_peers.py``
    checks that the README says it): each method's robot-seconds to PD-only's MSE and to 10x
    below it (the median of the seeds' first crossings; how many seeds, where not all), and
    how many times the robot-seconds of cfm_jax's slowest loss the fastest peer needs to get
    10x below PD-only (a range: from its checkpoints before its crossings to the crossings),
    with :func:`rank_test` of the two's seeds at both ends."""
    pd_only, _ = levels(records)
    rows = summary_rows(records, pd_only)

    def reach(row, key):
        median, reached, seeds = row[key]
        if median is None:
            return f"none in {row['last']:.0f}"
        return f"{median:.0f}" + ("" if reached == seeds else f" ({reached}/{seeds})")

    seeds = " or ".join(str(n) for n in sorted({row["to_pd"][2] for row in rows}))
    text = (
        f"robot-seconds to PD-only's error / to 10x below it (median of {seeds} seeds' first "
        "crossings): "
        + ", ".join(
            f"{row['method']} {reach(row, 'to_pd')} / {reach(row, 'to_tenth')}" for row in rows
        )
        + f" (PD-only {pd_only:.2g} rad^2)."
    )
    every = [
        r for r in rows if r["to_tenth"][0] is not None and r["to_tenth"][1] == r["to_tenth"][2]
    ]
    losses = [r for r in every if r["method"] in LOSSES]
    peers = [r for r in every if r["method"] in PEERS]
    if len(losses) < len({r["method"] for r in rows} & set(LOSSES)):
        return text + " Not every cfm_jax loss gets 10x below PD-only on every seed: no ratio."
    if not peers:
        return text + " No peer gets 10x below PD-only on every seed within its budget."
    slowest = max(losses, key=lambda r: r["to_tenth"][0])
    fastest = min(peers, key=lambda r: r["to_tenth"][0])
    later, before, earlier = (
        list(r[key].values())
        for r, key in ((fastest, "tenth_crossings"), (fastest, "tenth_before"),
                       (slowest, "tenth_crossings"))
    )  # fmt: skip
    if min(len(later), len(earlier)) < 2:
        verdict = "too few seeds for a test"
    elif not _rank_gap(before, earlier) > 0:
        verdict = "not resolved: at the checkpoints before its crossings the peer ranks first"
    else:  # the crossing lies between two checkpoints: the test at either end, the larger p
        p = max(rank_test(later, earlier), rank_test(before, earlier))
        verdict = f"p = {p:.2g}" + ("" if p < 0.05 else ", not resolved")
    slow = slowest["to_tenth"][0]
    low, high = float(np.median(before)) / slow, fastest["to_tenth"][0] / slow
    times = f"{low:.2g}x to {high:.2g}x" if low > 0 else f"at most {high:.2g}x"
    return text + (
        f" To 10x below PD-only the fastest peer, {fastest['method']}, needs {times} the "
        f"robot-seconds of cfm_jax's slowest loss, {slowest['method']} (from the peer's "
        "checkpoint before its crossing to the crossing; exact two-sample permutation test of "
        f"their seeds' crossings at either end, the larger p: {verdict})."
    )


def table(records: pd.DataFrame, pd_only: float, oracle: float) -> str:
    """The page's table (Markdown) from the records: the same records give the same text."""
    lines = [
        "| method | robot-s to PD-only | first checkpoint at or below PD-only, per seed (s; "
        "-: none) | robot-s to 10x below PD-only | MSE at cfm_jax's budget | MSE at the peers' "
        "budget | log10 MSE change over the last fifth (near 0: flat) | wall-clock (s; "
        "cfm_jax: all seeds in one run, a peer: per seed) |",
        "|---|---|---|---|---|---|---|---:|",
    ]
    for row in summary_rows(records, pd_only):
        lines.append(
            f"| {row['method']} | {_time_text(row['to_pd'], row['last'])} | "
            f"{_crossings_text(row['crossings'])} | "
            f"{_time_text(row['to_tenth'], row['last'])} | {_mse_text(row['at_cfm'])} | "
            f"{_mse_text(row['at_peer'])} | {_change_text(row['late'])} | {row['wall']:.0f} |"
        )
    lines += ["", f"PD-only: {pd_only:.3g} rad^2; oracle: {oracle:.3g} rad^2."]
    return "\n".join(lines) + "\n"


def figure(records: pd.DataFrame, pd_only: float, oracle: float, path: str) -> None:
    """Log-log test tracking MSE against robot-seconds: per method the mean over the seeds
    that did not diverge and its 95% bootstrap band; PD-only and oracle as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cfm_jax.analysis import report

    curves = seed_curves(records)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for method in METHODS:
        mine = curves[(curves.method == method) & np.isfinite(curves.tracking_mse)]
        if mine.empty:
            continue
        points = sorted(mine.robot_s.unique())
        stats = [report.mean_ci(mine[mine.robot_s == p].tracking_mse.to_numpy()) for p in points]
        mean = [s["mean"] for s in stats]
        line = ax.plot(points, mean, marker="o", ms=3, label=method)[0]
        low = [s["low"] if np.isfinite(s["low"]) else s["mean"] for s in stats]
        high = [s["high"] if np.isfinite(s["high"]) else s["mean"] for s in stats]
        ax.fill_between(points, low, high, color=line.get_color(), alpha=0.2)
    ax.axhline(pd_only, color="k", ls="--", lw=1, label="PD-only")
    ax.axhline(oracle, color="k", ls=":", lw=1, label="oracle")
    ax.set(xscale="log", yscale="log", xlabel="robot-seconds of learning data",
           ylabel="test tracking MSE (rad$^2$)")  # fmt: skip
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def describe(config, command: str, checkpoints: dict, hypers: dict, source: str) -> dict:
    """What the page says of a run, kept beside the records (``RECORDS`` with ``.json``):
    the command, date, machine, the task and the peers' versions and settings.
    ``checkpoints``: each peer's robot-second checkpoints; ``source``: where ``hypers`` come
    from."""
    import stable_baselines3
    import torch

    from cfm_jax.analysis import bench
    from cfm_jax.learning.algorithm import Experiment

    task = Experiment(config).task
    grids = sorted({_grid_text(points) for points in checkpoints.values()})
    scaled = ", ".join(p for p in PEERS if ACTION[p] == "scale")
    residual = ", ".join(p for p in PEERS if ACTION[p] == "residual")
    return {
        "command": command,
        "date": datetime.date.today().isoformat(),
        "machine": f"{bench.processor()}, {platform.machine()}, {os.cpu_count()} cores",
        "task": (
            f"{os.path.splitext(os.path.basename(config.robot))[0]}, {config.task.name}, "
            f"{task.targets} test motions of {task.steps * task.control_dt:g} s at "
            f"{1 / task.control_dt:g} Hz; cfm_jax {config.loop.iterations} iterations"
        ),
        "control_dt": task.control_dt,
        "peers": (
            f"stable-baselines3 {stable_baselines3.__version__}, torch {torch.__version__} "
            f"(CPU, 1 thread); observations and rewards normalised by SB3's VecNormalize "
            f"(its statistics frozen when evaluating); the reward is minus the squared "
            f"tracking error over PD-only's MSE on the selection motions "
            f"({1 / reward_scale(config):.3g} rad^2); actions through cfm_jax's "
            f"`{config.loop.torque_scale}` torque scale ({scaled}) "
            f"and the same added to the task's PD feedback "
            f"({residual}); hyperparameters "
            f"({source}): {hypers}; evaluated {' / '.join(grids)}"
        ),
        "checkpoints": checkpoints,
    }


def _grid_text(points) -> str:
    """``every D s from A to B s`` for an evenly spaced grid (and ``, then every E s to C s``
    for each further evenly spaced stretch), else the points.

    Examples:
      >>> _grid_text([100.0, 200.0, 300.0]), _grid_text([10.0, 20.0, 50.0])
      ('every 100 s from 100 to 300 s', 'at 10, 20, 50 s')
      >>> _grid_text([25.0, 50.0, 75.0, 100.0, 200.0, 300.0])
      'every 25 s from 25 to 100 s, then every 100 s to 300 s'
    """
    points = [float(p) for p in points]
    stretches, i = [], 0  # (first, last, step) of each evenly spaced stretch
    while i < len(points) - 1:
        step, j = points[i + 1] - points[i], i + 1
        while j < len(points) - 1 and np.isclose(points[j + 1] - points[j], step):
            j += 1
        stretches.append((points[i], points[j], step, j - i))
        i = j
    if not stretches or stretches[0][3] < 2 or len(stretches) > 3:
        return "at " + ", ".join(f"{p:g}" for p in points) + " s"
    first, last, step, _ = stretches[0]
    text = f"every {step:g} s from {first:g} to {last:g} s"
    return text + "".join(f", then every {e:g} s to {b:g} s" for _, b, e, _ in stretches[1:])


PLACES = ("--out", "--page", "--records")
"""Flags that only say where files go: an absolute value outside the repository (one
machine's folder, which changes no number) is left out of the command a page names."""


def shown_command(command: str, root: str = ROOT) -> str:
    """``command`` as a committed page names it: an absolute path inside ``root`` (the
    repository) relative to it; an absolute :data:`PLACES` value elsewhere left out (with
    its flag); everything else as it is.

    Examples:
      >>> shown_command("python experiments/peers.py --jobs 1 --out /work/results_peers", "/r")
      'python experiments/peers.py --jobs 1'
      >>> shown_command("python experiments/peers.py --page=/r/docs/p.md --out=results/p", "/r")
      'python experiments/peers.py --page=docs/p.md --out=results/p'
    """
    words, shown = shlex.split(command), []
    i = 0
    while i < len(words):
        flag, joined, value = words[i].partition("=")
        if not joined:
            flag, value = words[i], words[i + 1] if i + 1 < len(words) else ""
        taken = 1 if joined else 2
        if flag.startswith("--") and os.path.isabs(value):
            inside = os.path.commonpath([os.path.abspath(value), os.path.abspath(root)])
            if inside == os.path.abspath(root):
                relative = os.path.relpath(value, root)
                shown += [f"{flag}={relative}"] if joined else [flag, relative]
            elif flag not in PLACES:
                shown += words[i : i + taken]
            i += taken
            continue
        shown.append(words[i])
        i += 1
    return " ".join(shlex.quote(w) for w in shown)


def page(records: pd.DataFrame, meta: dict, figure_name: str) -> str:
    """The results page (Markdown) from the records and their description: the same
    records give the same page."""
    pd_only, oracle = levels(records)
    seeds = records[records.method.isin(METHODS)].seed.nunique()
    return "\n".join([
        "# Robot-seconds to a working controller: cfm_jax against SAC and PPO",
        "",
        f"Written by `{shown_command(meta['command'])}`, {meta['date']} ({meta['machine']}), "
        f"from its records (`{RECORDS}`). The task: {meta['task']}. Peers: {meta['peers']}. "
        "Robot-seconds: "
        "simulated time of all data a method learned from (cfm_jax: babbling and every "
        "iteration's rollouts; a peer: its environment steps x "
        f"{meta['control_dt']:g} s); the peers' evaluation rollouts on the test references "
        f"are not counted. Seeds per method: {seeds}. A seed's MSE at a checkpoint is its "
        "mean over the test motions (a diverged motion fails the checkpoint); `robot-s to "
        "...`: the median, over the seeds that reach the level, of their first checkpoint "
        "at or below it (and how many seeds do); MSE cells: the mean over seeds with its "
        "95% bootstrap interval, at the last checkpoint within the budget. How to read it: "
        "[the comparison](../peers.md).",
        "",
        f"![test tracking MSE against robot-seconds]({figure_name})",
        "",
        table(records, pd_only, oracle),
    ])  # fmt: skip


RECORDS = "docs/results/peers_records.csv"


def baseline_records(out: str) -> pd.DataFrame:
    """PD-only's and the oracle's rows (``method`` ``pd_only`` / ``oracle``, no
    robot-seconds) from a cfm_jax run's ``baselines.csv``: they learn nothing."""
    base = pd.read_csv(os.path.join(out, "baselines.csv"))
    return pd.DataFrame({
        "method": base.baseline, "seed": 0, "robot_s": np.nan, "target": base.target,
        "tracking_mse": base.tracking_mse, "diverged": 0, "wall_s": np.nan,
    })[COLUMNS]  # fmt: skip


def levels(records: pd.DataFrame) -> tuple[float, float]:
    """PD-only's and the oracle's mean tracking MSE in the records."""
    means = records.groupby("method").tracking_mse.mean()
    return float(means["pd_only"]), float(means["oracle"])


def meta_path(records_path: str) -> str:
    """The description's file beside the records: ``.csv`` replaced by ``.json``."""
    return os.path.splitext(records_path)[0] + ".json"


def write_page(records_path: str, page_path: str) -> None:
    """The page and its figure (beside it, same name, ``.png``) from the records and their
    description."""
    records = pd.read_csv(records_path)
    with open(meta_path(records_path)) as f:
        meta = json.load(f)
    pd_only, oracle = levels(records)
    folder = os.path.dirname(os.path.abspath(page_path))
    name = os.path.splitext(os.path.basename(page_path))[0] + ".png"
    figure(records, pd_only, oracle, os.path.join(folder, name))
    with open(page_path, "w") as f:
        f.write(page(records, meta, name))


def _budgets(text: str, default: float) -> dict:
    """Each peer's robot-second budget: ``default``, or ``PEER=SECONDS`` of ``text``
    (comma-separated).

    Examples:
      >>> _budgets("ppo=20000", 2000.0)["ppo"], _budgets("", 2000.0)["sac"]
      (20000.0, 2000.0)
    """
    budgets = dict.fromkeys(PEERS, float(default))
    for item in [x for x in text.split(",") if x]:
        name, _, value = item.partition("=")
        if name not in PEERS:
            raise ValueError(f"--peer-budgets: {name!r} is not a peer; one of {list(PEERS)}")
        try:
            budgets[name] = float(value)
        except ValueError:
            raise ValueError(f"--peer-budgets: {item!r}: want PEER=SECONDS") from None
        if not budgets[name] > 0:
            raise ValueError(f"--peer-budgets: {item!r}: the seconds must be > 0")
    return budgets


def tuned(path: str) -> tuple[dict, str]:
    """The peers' hyperparameters: each finished study's choice in the tuning record ``path``
    (``experiments/peers_search.py``), SB3's defaults (:data:`HYPERPARAMETERS`) for a peer
    without one; and a sentence saying which is which."""
    hypers = dict(HYPERPARAMETERS)
    chosen = {}
    if os.path.exists(path):
        with open(path) as f:
            chosen = {k: v for k, v in json.load(f)["chosen"].items() if v.get("complete")}
    for peer, record in chosen.items():
        hypers[peer] = record["hyper"]
    names = ", ".join(sorted(chosen)) or "none"
    source = f"tuned by `experiments/peers_search.py` ({path}): {names}; SB3's defaults otherwise"
    return hypers, source


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument(
        "--budget",
        type=float,
        default=2000.0,
        help="each peer's robot-seconds (default 2000: 2e5 steps)",
    )
    parser.add_argument(
        "--peer-budgets",
        default="",
        help="PEER=SECONDS,... : a peer's own budget (PPO run until its curve is flat)",
    )
    parser.add_argument(
        "--early-every",
        type=float,
        default=EARLY,
        help="robot-seconds between evaluations before the first --every",
    )
    parser.add_argument(
        "--every", type=float, default=EVERY, help="robot-seconds between evaluations"
    )
    parser.add_argument(
        "--checkpoints",
        default=None,
        help="comma-separated robot-seconds for every peer (default: every --every s)",
    )
    parser.add_argument("--out", default="results/peers")
    parser.add_argument("--page", default="docs/results/peers.md")
    parser.add_argument("--records", default=RECORDS)
    parser.add_argument(
        "--hyper",
        default="docs/results/peers_search/chosen.json",
        help="the tuning's record (experiments/peers_search.py); SB3's defaults without one",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="peer runs at once, each its own process (one core each)",
    )
    parser.add_argument("--train-flags", default="", help="more flags for cfm-jax train")
    parser.add_argument(
        "--page-only",
        action="store_true",
        help="write the page from --records alone (nothing is run)",
    )
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        parser.error(f"--methods: {unknown} not allowed; choose from {list(METHODS)}")
    if args.seeds < 1:
        parser.error(f"--seeds={args.seeds}: a positive number")
    if args.jobs < 1:
        parser.error(f"--jobs={args.jobs}: a positive number")
    if not args.every > 0:
        parser.error(f"--every={args.every}: a positive number of robot-seconds")
    if not args.early_every > 0:
        parser.error(f"--early-every={args.early_every}: a positive number of robot-seconds")
    try:
        budgets = _budgets(args.peer_budgets, args.budget)
    except ValueError as error:
        parser.error(str(error))
    checkpoints = {
        peer: [float(x) for x in args.checkpoints.split(",")] if args.checkpoints
        else default_checkpoints(budgets[peer], args.every, args.early_every)
        for peer in PEERS
    }  # fmt: skip
    command = " ".join(["python experiments/peers.py", *(shlex.quote(a) for a in argv)])
    if not args.page_only:
        import _study

        from cfm_jax import config as config_lib

        # The torque scale the study's records were made on unless the flags name one.
        flags = shlex.split(args.train_flags)
        if "--loop.torque-scale" not in flags:
            flags = ["--loop.torque-scale", _study.BEFORE_POSE["loop.torque_scale"], *flags]
        # Every method's config and the baselines: the cfm_jax runs' (without a loss among
        # the methods, the joint loss's run still gives them).
        runs = [m for m in methods if m in LOSSES] or ["joint"]
        for loss in runs:
            run_cfm(loss, args.seeds, os.path.join(args.out, f"cfm_{loss}"), flags)
        first = os.path.join(args.out, f"cfm_{runs[0]}")
        with open(os.path.join(first, runs[0], "config.json")) as f:
            config = config_lib.from_dict(json.load(f))
        peers = [m for m in methods if m in PEERS]
        hypers, source = tuned(args.hyper)
        meta = describe(config, command, {p: checkpoints[p] for p in peers}, hypers, source)
        pieces = [
            Piece(
                method,
                seed,
                config,
                os.path.join(args.out, method, f"seed{seed}"),
                tuple(checkpoints[method]),
                hypers[method],
            )  # fmt: skip
            for seed in range(args.seeds)
            for method in peers
        ]
        for _ in run_pieces(pieces, args.jobs):
            # The page after every piece: a study cut short still shows what it has.
            collect(args.out, first, methods, args.seeds, args.records, meta)
            write_page(args.records, args.page)
        collect(args.out, first, methods, args.seeds, args.records, meta)
    write_page(args.records, args.page)
    print(f"peers: wrote {args.page} and {args.records}")


def collect(out: str, first: str, methods, seeds: int, records_path: str, meta: dict) -> None:
    """The records of every finished cfm_jax loss and every peer seed begun, with the
    baselines of ``first`` (a cfm_jax run), into ``records_path``; ``meta`` beside them."""
    parts = [baseline_records(first)]
    parts += [cfm_records(loss, os.path.join(out, f"cfm_{loss}"))
              for loss in methods if loss in LOSSES]  # fmt: skip
    for method in [m for m in methods if m in PEERS]:
        for seed in range(seeds):
            path = os.path.join(out, method, f"seed{seed}", "records.csv")
            if os.path.exists(path):
                parts.append(pd.read_csv(path))
    records = pd.concat(parts, ignore_index=True)[COLUMNS]
    os.makedirs(os.path.dirname(os.path.abspath(records_path)), exist_ok=True)
    records.to_csv(records_path, index=False, float_format="%.9g")
    with open(meta_path(records_path), "w") as f:
        json.dump(meta, f, indent=1)


if __name__ == "__main__":
    main()
