"""The benchmark's statistics: rliable's aggregates with stratified bootstrap intervals, and paired
per-episode comparisons (docs/benchmark.md, "Statistics").

The estimators are rliable's (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS
2021), written on numpy because rliable 1.2.0 cannot be imported here: it needs ``arch`` < 8, and
``arch`` 7.2.0, which pip resolves with pandas 3, fails on import (pandas 3 changed ``deprecate_kwarg``).
``tests/test_stats.py`` checks each against values computed by hand.

A policy's scores are a matrix of runs (training seeds; one for a baseline) x tasks (regimes), each entry
the run's mean over the regime's evaluation episodes. Aggregates map such a matrix, or a stack of them with
leading axes, to one number:

- ``mean``: the mean over tasks of the per-task mean over runs;
- ``median``: the median over tasks of the per-task mean over runs;
- ``iqm``: the interquartile mean of all runs x tasks entries (the middle 50 %, rliable's trimmed mean);
- ``optimality_gap``: how far the entries fall short of ``gamma`` (1: the bound), mean of max(gamma - x, 0).

``bootstrap`` resamples, within each task (the strata), the runs with replacement and, within each run,
the task's episodes: the interval then covers what another training seed and other episodes of the same
regimes would give, the same estimator for a learner and a baseline (whose interval is over episodes alone).
Intervals are percentile intervals, 95 % by default.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import trim_mean

Aggregate = Callable[[np.ndarray], np.ndarray]  # (..., runs, tasks) -> (...)


def mean(x: np.ndarray) -> np.ndarray:
    return np.mean(np.mean(x, axis=-2), axis=-1)


def median(x: np.ndarray) -> np.ndarray:
    return np.median(np.mean(x, axis=-2), axis=-1)


def iqm(x: np.ndarray) -> np.ndarray:
    flat = np.reshape(x, (*np.shape(x)[:-2], -1))
    return trim_mean(flat, proportiontocut=0.25, axis=-1)


def optimality_gap(x: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    return np.mean(gamma - np.minimum(x, gamma), axis=(-2, -1))


AGGREGATES: dict[str, Aggregate] = {"IQM": iqm, "mean": mean, "median": median, "optimality gap": optimality_gap}


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y): for each task, the chance that a run of X scores above a run of Y (a tie counts a half, the
    Mann-Whitney U over the product of the run counts), averaged over the tasks. ``x`` (..., m, tasks) and
    ``y`` (..., n, tasks)."""
    a, b = np.asarray(x)[..., :, None, :], np.asarray(y)[..., None, :, :]
    per_task = np.mean((a > b) + 0.5 * (a == b), axis=(-3, -2))
    return np.mean(per_task, axis=-1)


def performance_profile(x: np.ndarray, taus: Sequence[float] | np.ndarray) -> np.ndarray:
    """The fraction of runs x tasks entries above each threshold tau (rliable's score distribution)."""
    t = np.asarray(taus, dtype=float)
    return np.mean(np.asarray(x)[..., None] > t, axis=(-3, -2))


@dataclass(frozen=True)
class Scores:
    """One policy's per-episode scores, by task: ``episodes[t]`` is a (runs, episodes of task t) array; the
    runs (training seeds) are the same for every task, the episodes may differ in number between tasks."""

    tasks: tuple[str, ...]
    episodes: tuple[np.ndarray, ...]

    def __post_init__(self) -> None:
        runs = {e.shape[0] for e in self.episodes}
        if len(runs) > 1 or any(e.ndim != 2 or e.shape[1] == 0 for e in self.episodes):
            raise ValueError(f"scores: every task needs the same runs and an episode; shapes "
                             f"{[e.shape for e in self.episodes]}")
        if any(np.isnan(e).any() for e in self.episodes):
            raise ValueError("scores: NaN among the episodes; leave such episodes out")

    @property
    def runs(self) -> int:
        return self.episodes[0].shape[0]

    def matrix(self) -> np.ndarray:
        """Runs x tasks: each run's mean over the task's episodes."""
        return np.stack([e.mean(axis=1) for e in self.episodes], axis=1)

    def resampled(self, reps: int, rng: np.random.Generator) -> np.ndarray:
        """``reps`` bootstrap matrices (reps, runs, tasks): per task, runs drawn with replacement, and each
        drawn run's mean over the task's episodes drawn with replacement."""
        out = np.empty((reps, self.runs, len(self.tasks)))
        for t, e in enumerate(self.episodes):
            runs, episodes = e.shape
            r = rng.integers(runs, size=(reps, runs))
            k = rng.integers(episodes, size=(reps, runs, episodes))
            out[:, :, t] = e[r[:, :, None], k].mean(axis=-1)
        return out


@dataclass(frozen=True)
class Interval:
    point: float
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.point:.3f} [{self.low:.3f}, {self.high:.3f}]"


def _interval(point: float, replicates: np.ndarray, confidence: float) -> Interval:
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail])
    return Interval(float(point), float(low), float(high))


def bootstrap(scores: Scores, aggregate: Aggregate, reps: int = 2000, confidence: float = 0.95,
              seed: int = 0) -> Interval:
    """The aggregate of ``scores`` and its stratified bootstrap percentile interval."""
    rng = np.random.default_rng(seed)
    return _interval(aggregate(scores.matrix()), aggregate(scores.resampled(reps, rng)), confidence)


def bootstrap_improvement(x: Scores, y: Scores, reps: int = 2000, confidence: float = 0.95,
                          seed: int = 0) -> Interval:
    """P(X > Y) with its interval, X and Y resampled independently (on the same tasks)."""
    if x.tasks != y.tasks:
        raise ValueError(f"probability of improvement: different tasks {x.tasks} and {y.tasks}")
    rng = np.random.default_rng(seed)
    point = probability_of_improvement(x.matrix(), y.matrix())
    return _interval(point, probability_of_improvement(x.resampled(reps, rng), y.resampled(reps, rng)), confidence)


def bootstrap_profile(scores: Scores, taus: Sequence[float] | np.ndarray, reps: int = 2000,
                      confidence: float = 0.95, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The performance profile at ``taus`` and its pointwise interval: (profile, low, high)."""
    rng = np.random.default_rng(seed)
    replicates = performance_profile(scores.resampled(reps, rng), taus)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail], axis=0)
    return performance_profile(scores.matrix(), taus), low, high


@dataclass(frozen=True)
class Paired:
    """A against B on the same episodes: the mean difference A - B with its interval, and the episodes where
    A is better (``wins``), equal within ``tolerance`` (``ties``) or worse (``losses``)."""

    difference: Interval
    wins: int
    ties: int
    losses: int


def paired(a: Mapping[tuple, float], b: Mapping[tuple, float], higher_is_better: bool = True, reps: int = 2000,
           confidence: float = 0.95, tolerance: float = 1e-9, seed: int = 0) -> Paired:
    """Compare two policies episode by episode. ``a`` and ``b`` map an episode's key (regime, episode seed) to
    the policy's value there (a learner's mean over its training seeds); only the keys both have count. The
    interval resamples episodes within each regime (the key's first part), as the aggregates do."""
    keys = sorted(set(a) & set(b), key=str)
    if not keys:
        raise ValueError("paired comparison: no episode in common")
    d = np.array([a[k] - b[k] for k in keys], dtype=float)
    better = d if higher_is_better else -d
    strata = [np.flatnonzero([k[0] == s for k in keys]) for s in sorted({k[0] for k in keys}, key=str)]
    rng = np.random.default_rng(seed)
    total = np.zeros(reps)
    for idx in strata:
        total += d[idx[rng.integers(len(idx), size=(reps, len(idx)))]].sum(axis=1)
    wins, losses = int(np.sum(better > tolerance)), int(np.sum(better < -tolerance))
    return Paired(_interval(d.mean(), total / len(d), confidence), wins, len(d) - wins - losses, losses)
