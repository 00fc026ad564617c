"""Learning, end to end, on the native simulator (MuJoCo C): the config, the rule and its
measured margins are in tests/learning.py."""

from __future__ import annotations

import pytest
from learning import (
    BEST_BELOW_PD,
    FACTOR,
    check_learns,
    learning_config,
    summarise,
    train_all_losses,
)


@pytest.fixture(scope="module")
def native():
    return summarise(train_all_losses(learning_config("native"))[1])


# Native: the four losses in one batched run, 31 s wall under pytest with the other core
# busy. Kept in the default run: it is the one test that fails when learning stops.
def test_every_loss_learns_native(native):
    check_learns(native, factor=FACTOR, best_below_pd=BEST_BELOW_PD)
