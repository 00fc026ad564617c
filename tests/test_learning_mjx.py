"""Learning, end to end, on the MJX simulator: the config, the rule and its measured
margins are in tests/learning.py (the same as on native). The same run is the MJX oracle
of the losses' batch axis: a loss's slice equals that loss trained alone."""

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
from tiny import assert_each_loss_equals_it_alone


@pytest.fixture(scope="module")
def mjx():
    return train_all_losses(learning_config("mjx"))


# MJX: the same config, 15 seeds: per seed final / iteration 0 at most 0.13 (joint) and
# every loss at most 0.079 of PD-only, as on native. The four losses in one batched run:
# 59 s wall under pytest with the other core busy. In the default run (issue 29 item 1:
# learning on both simulators); its own file, queued among the longest and before the
# native one (tests/conftest.py, FILE_SECONDS), whose fits then load from the compilation
# cache the programs this run compiled.
def test_every_loss_learns_mjx(mjx):
    check_learns(summarise(mjx[1]), factor=FACTOR, best_below_pd=BEST_BELOW_PD)


# Issue 46 on MJX, where the rollouts are one on-device program (on native,
# tests/test_train.py): a loss trained with the others (distal, index 2 of 4) against
# distal trained alone, bit for bit.
def test_a_loss_of_the_batch_equals_it_alone_mjx(mjx):
    experiment, result = mjx
    assert_each_loss_equals_it_alone(experiment, result, losses=["distal"])
