"""Shared test helpers: tiny configs and CLI helpers for the end-to-end tests (fast, wiring
only), the oracle of the losses' batch axis, and the list of public modules."""

from __future__ import annotations

import json
import pkgutil
import re
import sys

import jax
import jax.numpy as jnp
import numpy as np

import cfm_jax
from cfm_jax import config as config_lib


def tiny_config(**loop) -> config_lib.Config:
    """The two-link arm, 0.3 s references, 16-unit networks and a few dozen fit steps.

    Its initial data is ``home`` babbling and its controller loss the ``squared`` form, the
    library's defaults before the selection run: the golden records (tests/golden/) were
    made with them, so that the tests built on this config keep checking those options bit
    for bit; tests/learning.py runs the defaults. Its torque scale is ``coupled``, the arms'
    default before issue 64 (the default ``auto``, pose here, is tests/test_pose_scale.py's);
    its oracle the one-step ``step`` (the default ``period`` is tests/test_baselines.py's)."""
    return config_lib.Config(
        robot="two_link_arm",
        task=config_lib.TaskConfig(duration=0.3, oracle="step"),
        forward=config_lib.ForwardModelConfig(
            hidden=(16,),
            ensemble_size=2,
            initial_steps=20,
            steps_per_iteration=10,
            batch_size=32,
        ),  # fmt: skip
        controller=config_lib.ControllerConfig(
            hidden=(16,),
            initial_steps=20,
            steps_per_iteration=10,
            batch_size=32,
            loss_form="squared",
        ),  # fmt: skip
        loop=config_lib.LoopConfig(
            **{"iterations": 2, "seeds": 2, "babbling_rollouts": 1, "babbling": "home"}
            | {"torque_scale": "coupled", **loop}
        ),
    )


def cli_command(config: config_lib.Config, tmp_path, out, losses: str, seeds: int,
                iterations: int) -> list[str]:  # fmt: skip
    """``python -m cfm_jax.cli train`` on ``config`` written to a JSON file in tmp_path."""
    config_file = tmp_path / "config.json"
    config_file.write_text(json.dumps(config_lib.to_dict(config)))
    return [
        sys.executable, "-m", "cfm_jax.cli", "train", "--robot", config.robot,
        "--loss", losses, "--seeds", str(seeds), "--iterations", str(iterations),
        "--config", str(config_file), "--out", str(out), "--quiet",
    ]  # fmt: skip


def public_modules() -> list[str]:
    """Public modules of cfm_jax, and those of public packages as ``tasks.legged``."""
    found = []
    for info in pkgutil.walk_packages(cfm_jax.__path__, prefix="cfm_jax."):
        name = info.name.removeprefix("cfm_jax.")
        if not any(part.startswith("_") for part in name.split(".")):
            found.append(name)
    return sorted(found)


# Lines that are not the library's own: MuJoCo MJX's Warp import messages, Python or
# MuJoCo warnings, tracebacks, absl/XLA log lines (issue 26 item 2).
FOREIGN = re.compile(r"warp|WARNING|Warning|Traceback|Failed to import|^[EWI]\d{4} ")


def assert_own_output(done) -> None:
    """A finished ``--quiet`` CLI subprocess exited 0, wrote nothing to stderr and no
    foreign line to stdout."""
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stderr == "", done.stderr  # --quiet: nothing at all on stderr
    foreign = [line for line in done.stdout.splitlines() if FOREIGN.search(line)]
    assert not foreign, foreign


def assert_each_loss_equals_it_alone(experiment, result, losses=None) -> None:
    """The batched run of several losses (issue 46) against each loss run alone.

    Oracle: the loss's own programs (``init`` and ``iteration`` of the Experiment, the path
    of train before the batching, the loop written out here). Every state (parameters, Adam,
    data set, keys) and every metric of the loss's slice of ``result`` is bit-identical to
    it. ``losses``: which slices to check (default: all of them)."""
    seeds = result.state.iteration.shape[-1]
    keys = jax.vmap(jax.random.key)(jnp.arange(seeds, dtype=jnp.uint32))
    for loss in losses or result.losses:
        state = experiment.init(loss, keys)
        rows = []
        for _ in range(experiment.config.loop.iterations):
            state, metrics = experiment.iteration(loss, state)
            rows.append(jax.device_get(metrics))
        rows.append(jax.device_get(experiment.evaluate(state)))
        leaves = zip(jax.tree.leaves(result.of(loss).state), jax.tree.leaves(state), strict=True)
        for batched, alone in leaves:
            if jnp.issubdtype(alone.dtype, jax.dtypes.prng_key):
                batched, alone = jax.random.key_data(batched), jax.random.key_data(alone)
            np.testing.assert_array_equal(np.asarray(batched), np.asarray(alone))
        frame = result.of(loss).metrics
        for iteration, metrics in enumerate(rows):
            got = frame[frame.iteration == iteration]
            targets = len(got) // seeds
            for name in experiment.metric_columns[4:]:
                want = np.asarray(metrics[name]).reshape(seeds, -1)
                want = np.broadcast_to(want, (seeds, targets)).ravel()
                np.testing.assert_array_equal(got[name], want, err_msg=f"{loss}: {name}")


def assert_targets_are_not_the_test_targets(config) -> None:
    """An iiwa14 arm config's ``task.targets`` are selection targets: as many as the test
    targets, none within 0.1 (rad, or m for op-space) per coordinate of a test target
    (``references.default_targets`` with seed 0; op-space: their end-effector positions)."""
    from cfm_jax.sim import robots
    from cfm_jax.tasks import references

    robot = robots.load("iiwa14")
    test = references.default_targets(robot.joint_range, robot.home)
    if config.task.name == "opspace":  # end-effector positions of the test poses, metres
        test = references.default_cartesian_targets(robot, config.task.site, robot.home)
    chosen = np.asarray(config.task.targets)
    assert chosen.shape == test.shape
    assert np.min(np.abs(test[:, None] - chosen[None]).max(axis=-1)) > 0.1
