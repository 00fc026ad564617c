"""Learning, end to end, on the native simulator (MuJoCo C): the config, the rule and its
measured margins are in tests/learning.py."""

from __future__ import annotations

import pytest
from learning import BEST_BELOW_PD, FACTOR, check_learns, learning_config, run_all_losses


@pytest.fixture(scope="module")
def native():
    return run_all_losses(learning_config("native"))


# Native: 59 s of CPU (user time) for the whole module run under pytest, almost all of it
# XLA compilation (babbling and initial fit once, then one iteration program per loss; the
# native rollouts' host callbacks keep them out of the persistent compilation cache); wall
# 207 s on the 2 shared cores at load 8. Kept in the default run: it is the one test that
# fails when learning stops.
def test_every_loss_learns_native(native):
    check_learns(native, factor=FACTOR, best_below_pd=BEST_BELOW_PD)
