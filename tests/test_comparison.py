"""experiments/comparison.py (issue 43): the cells the claims page rests on, each loss at its
own search's choice and all four at the shared defaults, on the test motions and seeds 10-19.

Oracles: the library's defaults (``for_task``), a search record written by hand (its lowest
trial known), and tiny own cells and a shared cell run end to end.
"""

from __future__ import annotations

import json
import os

import comparison
import loss_search
import pandas as pd
import pytest

from cfm_jax import config as config_lib


def _search(folder, task: str, trials: dict) -> None:
    """A search record: ``trials`` per loss, a list of (score, values), as loss_search
    writes it (trials csv and the chosen json made from it)."""
    rows = [{"task": task, "loss": loss, "trial": i, "score": score, "seconds": 1.0, **values}
            for loss, runs in trials.items() for i, (score, values) in enumerate(runs)]  # fmt: skip
    frame = pd.DataFrame(rows)
    frame.to_csv(os.path.join(folder, f"trials_{task}.csv"), index=False)
    with open(os.path.join(folder, f"chosen_{task}.json"), "w") as f:
        json.dump({"rule": "", "chosen": loss_search.chosen(frame)}, f)


def _runs(best: dict, other: dict, n: int, task: str = "inverse_dynamics") -> list:
    """n trials with distinct values, ``best`` the lowest-scoring one (the second), then the
    shared-defaults trial (scoring higher)."""
    rest = [(-1.0, {**other, "controller learning rate": 2e-3 + 1e-5 * k}) for k in range(n - 2)]
    return [(-2.0, other), (-5.0, best), *rest, (-3.0, loss_search.defaults_values(task))]


ARM = {"normaliser": "data", "forward model": "mlp", "controller goal": "observed",
       "loss form": "squared", "fit start": "fresh", "babbling": "home",
       "forward learning rate": 2e-4, "controller learning rate": 5e-4}  # fmt: skip
OTHER = {**ARM, "normaliser": "robot", "forward learning rate": 1e-3}


@pytest.mark.parametrize("task", ["inverse_dynamics", "opspace"])
def test_an_own_cell_is_the_defaults_with_its_lowest_trial_on_the_test_motions(tmp_path, task):
    n = loss_search.TRIALS
    # joint: the lowest trial is the second; distal: n trials but only two distinct values
    # (a repeated trial does not count).
    _search(tmp_path, "inverse_dynamics", {
        "joint": _runs(ARM, OTHER, n),
        "distal": [(-9.0, ARM), (-8.0, OTHER)] + [(-7.0, ARM)] * (n - 2),  # two distinct
        "task": _runs(ARM, OTHER, n)[:-1],  # its TPE trials, not yet the shared defaults
    })  # fmt: skip
    cells = {c.name: c for c in comparison.cells([task], str(tmp_path), blocks=(10,))}
    assert set(cells) == {"shared", "own-joint"}  # distal and task wait for their search
    assert comparison.pending([task], str(tmp_path)) == [
        f"{task}/own-{loss}" for loss in ("task", "distal", "supervised")]  # fmt: skip
    import _study

    defaults = _study.for_task(task, robot="iiwa14")  # the records' oracle and torque scale
    own, shared = cells["own-joint"].config(), cells["shared"].config()
    assert cells["own-joint"].losses == ("joint",)
    assert shared.replace(seed=0, loop=defaults.loop) == defaults  # the shared cell: defaults
    assert (own.loop.normaliser, own.forward.kind, own.controller.goal) == ("data", "mlp",
                                                                            "observed")  # fmt: skip
    assert own.controller.loss_form == "squared" and own.loop.babbling == "home"
    assert own.forward.start == own.controller.start == "fresh"
    assert (own.forward.learning_rate, own.controller.learning_rate) == (2e-4, 5e-4)
    for config in (own, shared):  # the test motions, seeds 10-19, the search's iterations
        assert config.task == defaults.task
        assert config_lib.seeds_of(config) == tuple(range(10, 20))
        assert config.loop.iterations == loss_search.ITERATIONS[task]
    # No seed of a selection: the first selection run's (0-2) and the search's (100-102).
    selection = {*range(loss_search.select_defaults.SEEDS), *loss_search.SEEDS}
    assert not set(config_lib.seeds_of(own)) & selection


def test_the_legged_cells_take_the_walks_search_and_a_stale_choice_is_refused(tmp_path):
    n = loss_search.TRIALS
    values = {"normaliser": "data", "forward model": "rigid_body", "controller goal": "desired",
              "loss form": "norm", "fit start": "warm", "s*": "pd",
              "forward learning rate": 3e-4, "controller learning rate": 1e-3}  # fmt: skip
    _search(tmp_path, "walk", {"task": _runs(values, {**values, "s*": "next_velocity"}, n, "walk")})
    for task in ("walk", "jump"):
        cell = [c for c in comparison.cells([task], str(tmp_path)) if c.own][0]
        config = cell.config()
        assert config.task.name == task and config.task.desired == "pd"
        assert config.task.motion_family == "test"
        assert config.loop.iterations == 30 and config.forward.learning_rate == 3e-4
    with open(tmp_path / "chosen_walk.json") as f:
        record = json.load(f)
    record["chosen"]["walk"]["task"]["normaliser"] = "robot"  # no longer the trials' lowest
    with open(tmp_path / "chosen_walk.json", "w") as f:
        json.dump(record, f)
    with pytest.raises(RuntimeError, match="chosen_walk.json disagrees"):
        comparison.cells(["jump"], str(tmp_path))


def test_tiny_own_cells_keep_their_records_and_the_shared_cell_reuses_a_run_of_its_config(
    tmp_path,
):
    # The joint loss's search chose other values than the defaults; the task loss's chose
    # the shared defaults (its defaults trial scores lowest), as joint, task and distal did
    # on the walk. Oracles: the search record written here, and the own cells' records. The
    # shared cell takes the own task run as it is (not trained again: no run folder in its
    # sweep) and trains the joint loss, whose config differs.
    defaults = loss_search.defaults_values("inverse_dynamics")
    others = [(-1.0, {**OTHER, "controller learning rate": 2e-3 + 1e-5 * k})
              for k in range(loss_search.TRIALS - 1)]  # fmt: skip
    _search(tmp_path, "inverse_dynamics", {
        "joint": _runs(ARM, OTHER, loss_search.TRIALS),
        "task": [(-2.0, OTHER), *others, (-5.0, defaults)],
    })  # fmt: skip
    runs, out = tmp_path / "runs", tmp_path / "out"
    # The second block of seeds (20-29; quick: 20-21), recorded in its own folders.
    flags = ["--only", "inverse_dynamics", "--quick", "--quiet", "--search", str(tmp_path),
             "--out", str(out), "--blocks", "20"]  # fmt: skip
    comparison.main([*flags, "--runs", str(runs), "--cells", "own"])
    cells = out / "cells" / "inverse_dynamics"
    block = "seeds-20-29"
    assert not (cells / "own-joint" / "metrics.csv").exists()  # the first block: not run
    metrics = pd.read_csv(cells / "own-joint" / block / "metrics.csv")
    assert set(metrics.loss) == {"joint"} and sorted(set(metrics.seed)) == [20, 21]
    with open(cells / "own-joint" / block / "config.json") as f:
        ran = json.load(f)
    assert ran["loop"]["babbling"] == "home" and ran["forward"]["kind"] == "mlp"
    assert ran["controller"]["learning_rate"] == 5e-4
    # A finished cell is not run again: its record stays as it is.
    before = (cells / "own-joint" / block / "metrics.csv").read_bytes()
    comparison.main([*flags, "--runs", str(tmp_path / "none"), "--cells", "own"])
    assert (cells / "own-joint" / block / "metrics.csv").read_bytes() == before
    comparison.main([*flags, "--runs", str(runs), "--cells", "shared"])
    shared = pd.read_csv(cells / "shared" / block / "metrics.csv")
    for loss, reused in (("task", True), ("joint", False)):
        own = pd.read_csv(cells / f"own-{loss}" / block / "metrics.csv")
        mine = shared[shared.loss == loss].drop(columns="cell").reset_index(drop=True)
        if reused:
            pd.testing.assert_frame_equal(mine, own.drop(columns="cell"), check_exact=True)
        else:
            assert not mine.tracking_mse.equals(own.tracking_mse)
        sweep_cells = runs / "inverse_dynamics" / "shared" / block / "cells"
        (cell,) = [c for c in sweep_cells.iterdir() if c.name.startswith(f"{loss}-")]
        assert (cell / "run").exists() != reused


def test_the_blocks_of_seeds_are_disjoint_and_a_later_block_runs_own_cells_first(tmp_path):
    """Seeds 10-29 in two blocks (issue 68), each cell's block its own sweep and record
    folder; in the second block a task's own cells come before its shared cell, so that the
    shared cell can reuse their runs. Oracle: the seeds written out by hand."""
    values = {"normaliser": "data", "forward model": "rigid_body", "controller goal": "desired",
              "loss form": "norm", "fit start": "warm", "s*": "pd",
              "forward learning rate": 3e-4, "controller learning rate": 1e-3}  # fmt: skip
    _search(tmp_path, "walk", {"task": _runs(values, {**values, "s*": "next_velocity"},
                                             loss_search.TRIALS, "walk")})  # fmt: skip
    found = comparison.cells(["walk"], str(tmp_path))
    assert [(c.name, c.first_seed) for c in found] == [
        ("shared", 10),
        ("own-task", 10),
        ("own-task", 20),
        ("shared", 20),
    ]
    seeds = {(c.name, c.first_seed): config_lib.seeds_of(c.config()) for c in found}
    assert seeds[("shared", 10)] == seeds[("own-task", 10)] == tuple(range(10, 20))
    assert seeds[("shared", 20)] == seeds[("own-task", 20)] == tuple(range(20, 30))
    assert [c.folder for c in found] == ["shared", "own-task", "own-task/seeds-20-29",
                                         "shared/seeds-20-29"]  # fmt: skip
    record = comparison.record_dir("out", found[-1])
    assert record == os.path.join("out", "cells", "walk", "shared", "seeds-20-29")
    with pytest.raises(SystemExit):  # a block that is not one of BLOCKS: a usage error
        comparison.main(["--only", "walk", "--blocks", "15", "--search", str(tmp_path),
                         "--runs", str(tmp_path / "r"), "--out", str(tmp_path / "o")])  # fmt: skip
    assert not (tmp_path / "o").exists()


def test_cells_and_losses_select_the_cells_to_run(tmp_path):
    shared = comparison.Cell("walk", "shared", ("joint", "task", "distal", "supervised"))
    found = [shared, *(comparison.Cell("walk", f"own-{n}", (n,)) for n in ("joint", "supervised"))]

    def names(which, losses):
        return [c.name for c in comparison.selected(found, which, losses)]

    assert names("all", ["supervised"]) == ["shared", "own-supervised"]
    assert names("own", ["joint", "supervised"]) == ["own-joint", "own-supervised"]
    assert names("shared", ["joint"]) == ["shared"]
    flags = ["--search", str(tmp_path), "--runs", str(tmp_path / "runs"),
             "--out", str(tmp_path / "out")]  # fmt: skip
    with pytest.raises(SystemExit):  # an unknown loss: a usage error, nothing run
        comparison.main(["--only", "walk", "--losses", "walks", *flags])
    assert not (tmp_path / "out").exists()


def test_a_cell_refuses_to_run_on_more_than_one_core(tmp_path, monkeypatch):
    """Every cell runs pinned to one core (``comparison.CORES``: jaxlib 0.10's LAPACK stall,
    and the thread count changes the numbers): a process that may use two is refused before
    anything is written, naming the cores, the rule and the command that pins it."""
    monkeypatch.setattr(comparison.os, "sched_getaffinity", lambda pid: {0, 1})
    with pytest.raises(SystemExit, match=r"may run on 2 cores; every cell runs on 1 .*taskset"):
        comparison.main(["--only", "inverse_dynamics", "--cells", "shared", "--quiet",
                         "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out"),
                         "--search", str(tmp_path)])  # fmt: skip
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def test_a_swap_block_is_the_shared_cells_config_of_its_seeds_and_blocks_combine_apart(tmp_path):
    """Issue 68's swap runs two blocks of 10 seeds; a block's task and joint collection is
    the comparison's shared inverse-dynamics cell of the same block, config for config (the
    sweep cell ``--collected`` finds by its id), and ``--combine`` refuses blocks that
    share a seed. Oracle: the comparison's cell config, and two metrics files written here."""
    import swap_study

    from cfm_jax.runs import sweeps

    for first in comparison.BLOCKS:
        shared = comparison.Cell("inverse_dynamics", "shared", ("task", "joint"), (), first)
        for loss in ("task", "joint"):
            mine = swap_study.base_config(comparison.SEEDS, 10, False, first).replace(loss=loss)
            assert mine == shared.config().replace(loss=loss)
            assert [c.id for c in sweeps.grid(shared.config(), losses=[loss])] == [
                sweeps.cell_id(mine)
            ]
    for name, seeds in (("a", [10, 11]), ("b", [11, 12])):
        block = tmp_path / name
        block.mkdir()
        frame = pd.DataFrame({"seed": seeds, "loss": "task", "data": "task", "iteration": 0,
                              "target": 0, "tracking_mse": 1.0})  # fmt: skip
        frame.to_csv(block / "swap_metrics.csv")
        (block / "swap_table.md").write_text("protocol\n\ntable\n")
        (block / "wall_times.json").write_text("{}")
    with pytest.raises(ValueError, match="share seeds"):
        swap_study.combine([str(tmp_path / "a"), str(tmp_path / "b")], str(tmp_path))
