"""The benchmark's protocol: three disjoint seed sets, for episodes and for regimes (docs/benchmark.md).

The rule they serve: every setting (rewards, prices, hyperparameters, evaluation mode, early stopping,
baseline parameters) is chosen on ``validation`` only; ``test`` numbers are computed once, at the end;
every table says which set its numbers come from. ``train`` is what learners see while they learn.

Episode seeds are what ``env.reset(seed=...)`` takes: they fix the arrivals, task sizes and deadlines of
an episode. The validation episodes are 100000, 100001, ..., the seeds that ``agents.training.evaluate``
has always used (``EVAL_SEED``): the project's settings so far were screened on them, which makes them
validation episodes by this rule, not test episodes. The test episodes start at 200000, a range no
result before this protocol used. Regime seeds are what ``experiments.suite`` draws a regime from.

The ranges are constants: changing one changes every suite and every test number, so a test pins them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Split = Literal["train", "validation", "test"]
SPLITS: tuple[Split, ...] = ("train", "validation", "test")


@dataclass(frozen=True)
class SeedSet:
    """Seeds ``start``, ``start + 1``, ..., ``start + size - 1``."""

    split: Split
    start: int
    size: int

    def seeds(self, count: int, offset: int = 0) -> list[int]:
        """The first ``count`` seeds after ``offset``; asking past the set's end is a ValueError."""
        if count < 0 or offset < 0 or offset + count > self.size:
            raise ValueError(f"{self.split}: seeds {offset}..{offset + count - 1} asked of a set of {self.size}")
        return list(range(self.start + offset, self.start + offset + count))

    def __contains__(self, seed: int) -> bool:
        return self.start <= seed < self.start + self.size


EPISODES: dict[Split, SeedSet] = {
    "train": SeedSet("train", 0, 100_000),  # agents.training.train: seeds seed, seed + 1, ...
    "validation": SeedSet("validation", 100_000, 100_000),  # agents.training.EVAL_SEED
    "test": SeedSet("test", 200_000, 100_000),
}
REGIMES: dict[Split, SeedSet] = {
    "train": SeedSet("train", 1_000_000, 1_000_000),
    "validation": SeedSet("validation", 2_000_000, 1_000_000),
    "test": SeedSet("test", 3_000_000, 1_000_000),
}


def split_of(seed: int, sets: dict[Split, SeedSet] = EPISODES) -> Split | None:
    """Which set ``seed`` belongs to (None: none of them)."""
    return next((name for name, s in sets.items() if seed in s), None)
