"""The stronger online baselines (threshold, drift-plus-penalty) by hand, their parameters, and their tuning
on the validation suite (experiments.tune_baselines)."""

from __future__ import annotations

import json

import pytest

from agents import BASELINES
from experiments import bound, tune_baselines
from node_runtime.model.messages import TaskSize
from node_runtime.model.policies import DriftPlusPenalty, GreedyBacklog, Threshold, configured, make_policy
from node_runtime.model.view import NodeView, Observation, TaskView

TASK = TaskView(1, TaskSize(2e6, 1e6, 1e6, 1.0, 30.0), 30.0, 0, "a")  # 2 s on a, 0.5 s on b; 2 s on the link


def view(own_queue: int, b_queue: int = 1, b_occupancy: int = 1, backlog: float = 0.5) -> Observation:
    own = NodeView("a", own_queue, own_queue, 10, 1e6, 0, 0.0, 0, True)
    b = NodeView("b", b_queue, b_occupancy, 5, 4e6, 1, 8e6, 1, True, backlog)
    return Observation(3, "a", own, 1, [TASK], [b])


def test_drift_plus_penalty_by_hand():
    """a: service 2 s behind 2 tasks: drift (2 x 2 + 2/2) x 2 = 10, expected response 2 x 2 + 2 = 6.
    b: service 0.5 s behind 1 task: (0.5 + 0.25) x 0.5 = 0.375, link (0.5 + 2/2) x 2 = 3; response
    2 (transfer) + 0.5 (wait) + 0.5 (run) + 0.5 (backlog) = 3.5."""
    obs = view(2)
    rule = configured(DriftPlusPenalty, v=2.0)()
    assert rule.cost(obs, TASK, 0, 0) == pytest.approx(10 + 2 * 6)
    assert rule.cost(obs, TASK, 1, 0) == pytest.approx(3.375 + 2 * 3.5)
    assert rule.decide(obs) == [1]
    assert DriftPlusPenalty.cost(rule, view(2, b_occupancy=5), TASK, 1, 0) == float("inf")  # b's buffer is full


def test_drift_plus_penalty_with_a_large_v_is_greedy_backlog():
    """a: drift (2 + 1) x 2 = 6, response 4 s; b: drift 0.375 + (1.5 + 1) x 2 = 5.375, response 2 + 0.5 + 0.5 +
    1.5 = 4.5 s. Drift alone (v = 0) balances the queues onto b; a large v follows the response, as greedy_backlog."""
    obs = view(1, b_queue=1, backlog=1.5)
    assert configured(DriftPlusPenalty, v=0.0)().decide(obs) == [1]
    assert configured(DriftPlusPenalty, v=1e6)().decide(obs) == GreedyBacklog().decide(obs) == [0]


def test_threshold_by_hand():
    assert configured(Threshold, threshold=2)().decide(view(1)) == [0]  # below the threshold: kept
    assert configured(Threshold, threshold=2)().decide(view(2)) == [1]  # at it: offloaded to b
    assert configured(Threshold, threshold=2)().decide(view(2, b_occupancy=5)) == [0]  # b full: kept anyway
    assert configured(Threshold, threshold=0)().decide(view(0)) == [1]  # 0: always offload
    obs = view(2)
    obs.tasks = [TASK, TASK, TASK]
    assert configured(Threshold, threshold=4)().decide(obs) == [0, 0, 1]  # a batch counts the tasks it kept


def test_parameters_are_checked_and_the_defaults_run_node_side():
    with pytest.raises(ValueError, match="threshold takes threshold, not v"):
        configured(Threshold, v=1.0)
    assert configured(DriftPlusPenalty, v=3).v == 3.0 and DriftPlusPenalty.v == 1.0  # the rule's own is untouched
    assert isinstance(make_policy("drift_plus_penalty"), DriftPlusPenalty)
    assert {"threshold", "drift_plus_penalty"} <= set(BASELINES)


def test_choose_takes_the_best_mean_completion_and_the_first_on_a_tie():
    rows = [{"policy": "threshold", "value": v, "completion_ratio": c} for v, c in
            ((0.0, 0.5), (1.0, 0.7), (1.0, 0.5), (2.0, 0.6), (3.0, 0.6), (4.0, 0.1), (6.0, 0.1), (8.0, 0.1))]
    rows.append({"policy": "threshold", "value": 3.0, "completion_ratio": float("nan")})  # nan: not counted
    rows += [{"policy": "drift_plus_penalty", "value": v, "completion_ratio": 0.4} for v in tune_baselines.GRID[
        "drift_plus_penalty"][1]]
    # threshold 1, 2 and 3 all average 0.6: the first wins; every v ties: the first
    assert tune_baselines.choose(rows) == {"threshold": {"threshold": 1.0}, "drift_plus_penalty": {"v": 0.0}}


def test_tuning_reads_validation_only_and_its_choice_runs_against_the_bound(tmp_path):
    tune_baselines.main(["--count", "1", "--episodes", "1", "--steps", "20", "--out", str(tmp_path / "tune"),
                         "--no-progress"])
    chosen = json.loads((tmp_path / "tune" / "chosen.json").read_text())
    assert chosen["split"] == "validation" and chosen["episode_seeds"] == [100_000]
    assert list(chosen["regimes"].values()) == [2_000_000]
    rules = tune_baselines.chosen(tmp_path / "tune" / "chosen.json")
    assert rules["threshold"].rule.threshold == chosen["chosen"]["threshold"]["threshold"]
    bound.main(["--suite", str(tmp_path / "tune" / "validation"), "--episodes", "1", "--tuned",
                str(tmp_path / "tune" / "chosen.json"), "--out", str(tmp_path / "b.csv"), "--no-progress"])
    text = (tmp_path / "b.csv").read_text()
    assert "threshold_tuned" in text and "drift_plus_penalty_tuned" in text and ",100000," in text
