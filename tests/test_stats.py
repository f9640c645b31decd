"""experiments.stats: every estimator against values computed by hand on tiny arrays, and the bootstrap's
intervals where their answer is known (no spread, or one that must cover the point)."""

from __future__ import annotations

import numpy as np
import pytest

from experiments import stats

# 2 runs x 4 tasks
X = np.array([[0.0, 0.2, 0.4, 1.0],
              [0.2, 0.6, 0.8, 1.4]])


def test_the_aggregates_by_hand():
    # per-task means 0.1, 0.4, 0.6, 1.2: mean 2.3 / 4, median (0.4 + 0.6) / 2
    assert stats.mean(X) == pytest.approx(0.575)
    assert stats.median(X) == pytest.approx(0.5)
    # the 8 entries sorted: 0 .2 .2 .4 | .6 .8 | 1 1.4; trimming 2 at each end keeps .2 .4 .6 .8
    assert stats.iqm(X) == pytest.approx(0.5)
    # shortfalls below 1: 1 .8 .6 0 / .8 .4 .2 0 -> 3.8 / 8
    assert stats.optimality_gap(X) == pytest.approx(0.475)
    assert stats.optimality_gap(X, gamma=0.5) == pytest.approx((0.5 + 0.3 + 0.1 + 0.3) / 8)


def test_aggregates_take_a_stack_of_matrices():
    stack = np.stack([X, X + 1.0])
    assert np.allclose(stats.iqm(stack), [0.5, 1.5])
    assert np.allclose(stats.mean(stack), [0.575, 1.575])


def test_probability_of_improvement_by_hand():
    x = np.array([[1.0, 0.0], [3.0, 0.0]])  # 2 runs x 2 tasks
    y = np.array([[2.0, 0.0]])
    # task 0: 1 < 2, 3 > 2 -> 1/2; task 1: two ties -> 1/2; mean 0.5
    assert stats.probability_of_improvement(x, y) == pytest.approx(0.5)
    y2 = np.array([[0.5, -1.0]])
    # task 0: both above -> 1; task 1: both above -> 1
    assert stats.probability_of_improvement(x, y2) == pytest.approx(1.0)
    assert stats.probability_of_improvement(y2, x) == pytest.approx(0.0)


def test_performance_profile_by_hand():
    # fraction of the 8 entries above 0, 0.5, 1: 7/8, 4/8, 1/8
    assert np.allclose(stats.performance_profile(X, [0.0, 0.5, 1.0]), [7 / 8, 4 / 8, 1 / 8])


def scores(*per_task: list[list[float]]) -> stats.Scores:
    return stats.Scores(tuple(f"r{i}" for i in range(len(per_task))), tuple(np.array(t) for t in per_task))


def test_the_matrix_averages_each_run_over_its_episodes():
    s = scores([[0.0, 1.0, 2.0], [3.0, 3.0, 3.0]], [[5.0], [7.0]])  # 2 runs; 3 episodes, then 1
    assert np.allclose(s.matrix(), [[1.0, 5.0], [3.0, 7.0]])


def test_a_constant_policy_has_an_interval_of_no_width():
    s = scores([[0.3, 0.3]], [[0.7, 0.7, 0.7]])
    for aggregate in stats.AGGREGATES.values():
        found = stats.bootstrap(s, aggregate, reps=200)
        assert found.low == found.point == found.high


def test_bootstrap_intervals_cover_the_point_and_shrink_with_more_runs():
    rng = np.random.default_rng(3)
    few = stats.Scores(("a", "b"), (rng.random((3, 4)), rng.random((3, 4))))
    many = stats.Scores(("a", "b"), (rng.random((30, 4)), rng.random((30, 4))))
    a, b = stats.bootstrap(few, stats.mean, reps=500), stats.bootstrap(many, stats.mean, reps=500)
    assert a.low <= a.point <= a.high and b.low <= b.point <= b.high
    assert b.high - b.low < a.high - a.low


def test_the_bootstrap_stays_within_each_task():
    # task a always 0, task b always 1: every resample keeps one of each, so the mean is exactly 0.5
    s = scores([[0.0, 0.0], [0.0, 0.0]], [[1.0, 1.0], [1.0, 1.0]])
    found = stats.bootstrap(s, stats.mean, reps=300)
    assert (found.low, found.high) == (0.5, 0.5)


def test_improvement_and_profile_intervals():
    x, y = scores([[1.0], [1.0]]), scores([[0.0]])
    assert stats.bootstrap_improvement(x, y, reps=100) == stats.Interval(1.0, 1.0, 1.0)
    profile, low, high = stats.bootstrap_profile(scores([[0.2, 0.8]]), [0.0, 0.5, 0.9], reps=400)
    assert np.allclose(profile, [1.0, 0.0, 0.0])  # one run: its mean 0.5 is above 0, not above 0.5
    # resampled, its mean is 0.2, 0.5 or 0.8 (a quarter of the time): above 0.5 in some resamples only
    assert low[0] == high[0] == 1.0 and low[1] == 0.0 and high[1] == 1.0
    with pytest.raises(ValueError, match="different tasks"):
        stats.bootstrap_improvement(x, stats.Scores(("other",), (np.array([[0.0]]),)))


def test_paired_by_hand():
    a = {("r1", 1): 0.9, ("r1", 2): 0.5, ("r2", 1): 0.7, ("r2", 9): 0.1}
    b = {("r1", 1): 0.8, ("r1", 2): 0.5, ("r2", 1): 0.9}  # ("r2", 9) is not B's: left out
    found = stats.paired(a, b)
    assert found.difference.point == pytest.approx((0.1 + 0.0 - 0.2) / 3)
    assert (found.wins, found.ties, found.losses) == (1, 1, 1)
    assert found.difference.low <= found.difference.point <= found.difference.high
    lower = stats.paired(a, b, higher_is_better=False)  # a response time: less is better
    assert (lower.wins, lower.ties, lower.losses) == (1, 1, 1) and lower.difference == found.difference
    always = stats.paired({("r", k): 1.0 + k for k in range(5)}, {("r", k): float(k) for k in range(5)})
    assert always.difference == stats.Interval(1.0, 1.0, 1.0) and always.wins == 5


def test_bad_scores_are_refused():
    with pytest.raises(ValueError, match="same runs"):
        scores([[0.0]], [[0.0], [1.0]])
    with pytest.raises(ValueError, match="NaN"):
        scores([[float("nan")]])
    with pytest.raises(ValueError, match="no episode in common"):
        stats.paired({("a", 1): 1.0}, {("a", 2): 1.0})
