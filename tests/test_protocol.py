"""The benchmark's seed sets (experiments.protocol): disjoint, and fixed once and for all."""

from __future__ import annotations

import itertools

import pytest

from agents.training import EVAL_SEED
from experiments import protocol
from node_runtime.model.rng import MAX_SEED


@pytest.mark.parametrize("sets", [protocol.EPISODES, protocol.REGIMES], ids=["episodes", "regimes"])
def test_the_three_sets_are_disjoint(sets):
    assert tuple(sets) == protocol.SPLITS
    for a, b in itertools.combinations(sets.values(), 2):
        assert a.start + a.size <= b.start or b.start + b.size <= a.start, (a, b)
    assert all(s.start >= 0 and s.start + s.size - 1 <= MAX_SEED for s in sets.values())


def test_episode_and_regime_seeds_never_meet():
    last_episode = max(s.start + s.size for s in protocol.EPISODES.values())
    assert last_episode <= min(s.start for s in protocol.REGIMES.values())


def test_the_sets_are_stable():
    """Changing a set changes every suite and every test number: these values are the protocol."""
    assert {k: (s.start, s.size) for k, s in protocol.EPISODES.items()} == {
        "train": (0, 100_000), "validation": (100_000, 100_000), "test": (200_000, 100_000)}
    assert {k: (s.start, s.size) for k, s in protocol.REGIMES.items()} == {
        "train": (1_000_000, 1_000_000), "validation": (2_000_000, 1_000_000), "test": (3_000_000, 1_000_000)}
    assert protocol.EPISODES["test"].seeds(3) == [200_000, 200_001, 200_002]


def test_the_evaluation_seeds_so_far_are_validation_episodes():
    """The settings of the project's results were screened on EVAL_SEED, ...: by the rule they are validation."""
    assert protocol.split_of(EVAL_SEED) == "validation"
    assert protocol.split_of(0) == "train" and protocol.split_of(250_000) == "test"
    assert protocol.split_of(3_000_004, protocol.REGIMES) == "test" and protocol.split_of(-1) is None


def test_asking_past_a_set_is_an_error():
    with pytest.raises(ValueError, match=r"validation: seeds 99999\.\.100000 asked of a set of 100000"):
        protocol.EPISODES["validation"].seeds(2, offset=99_999)
