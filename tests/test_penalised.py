"""Completion ratios and the penalised response time (docs/model.md, "Metrics"), by hand on a tiny trace."""

from __future__ import annotations

import pytest

from node_runtime.model.role import STAT_FIELDS
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.protocol import Done
from orchestrator.catalogue import Out
from orchestrator.metrics import Metrics, output_values, penalty_s
from orchestrator.scenario import load_scenario
from orchestrator.viewers.summary import rows
from tests.conftest import run_summary, write_scenario


def stats(**values: float) -> tuple:
    return tuple(values.get(f, 0) for f in STAT_FIELDS)


@pytest.fixture
def metrics() -> Metrics:
    plan = ProcessLayout(load_scenario("examples/minimal"), "single")  # roles: worker:edge 0, client:edge 1, ...
    return Metrics(plan)


def test_the_penalty_is_the_longest_deadline(metrics):
    assert penalty_s(metrics.scenario) == metrics.penalty == 100.0  # one task type, deadline 100 s


def test_with_drawn_deadlines_the_penalty_is_the_high_end_plus_the_grace(tmp_path):
    """A type with deadlines U[40, 80) + 5 s beside a fixed one: P = max(80 + 5, fixed), never the range's
    low end (which a slow completion can exceed, so that letting tasks expire would lower the score)."""
    for fixed, expected in ((90, 90.0), (60, 85.0)):
        types = [{"name": "drawn", "deadline": {"low": 40, "high": 80, "grace": 5}},
                 {"name": "fixed", "deadline": fixed}]
        sc = load_scenario(write_scenario(tmp_path, {"workload": {"tasks": types},
                                                     "topology": {"nodes": [{"id": "a", "client": True}]}}))
        assert penalty_s(sc) == pytest.approx(expected)


@pytest.mark.parametrize("policy", ["local", "greedy"])
def test_no_completion_takes_longer_than_the_penalty(policy):
    """On a scenario whose deadlines are drawn (U[40, 80) s, a task kept on an rpi3 takes 50 s of compute
    alone), every completion, however late, costs less than a dropped task."""
    sc = load_scenario("aot3_compute")
    summary = run_summary(sc, ticks=400, seed=3, policy=policy)
    assert summary["totals"]["completed"] > 0
    assert summary["response_time"]["max"] <= penalty_s(sc) == 80.0
    assert summary["response_time"]["max"] > 40.0  # the range's low end, the penalty before this was fixed
    assert summary["penalty_s"] == 80.0  # the summary says what its score charged


def test_the_scores_of_a_tiny_trace(metrics):
    """Tick 0: 3 tasks generated, one queued, two undecided. Tick 1: 2 more; two complete in 20 s and
    40 s, one is refused (queue full), one expires, one is still queued at the end (unfinished)."""
    worker, client = 0, 1
    r0 = metrics.add(0, [Done("all", 0, 0, {}, {client: stats(generated=3), worker: stats(queue=1, undecided=2)})])
    # nothing completed yet: 0/3, and every task is charged P: (0 + 100 * 3) / 3 = 100
    tick0 = output_values(Out.TICKS, r0.totals, r0.delta, metrics.capacity.sum())
    assert tick0["completion_ratio"] == 0.0
    assert tick0["completion_ratio_settled"] is None  # nothing settled yet: 0 / 0
    assert tick0["penalised_response_time"] == pytest.approx(100.0)
    metrics.add(1, [Done("all", 0, 1, {}, {client: stats(generated=5, completed=2),
                                           worker: stats(queue=1, queue_full=1, expired=1)},
                         response_times={client: [20.0, 40.0]})])
    s = metrics.summary()
    assert s["completion_ratio"] == pytest.approx(2 / 5)  # 0.4
    assert s["completion_ratio_settled"] == pytest.approx(2 / 4)  # completed / (completed + 2 dropped) = 0.5
    # (20 + 40 + 100 * (5 - 2)) / 5 = 360 / 5 = 72 s, against a mean of 30 s over the completions alone
    assert s["penalised_response_time"] == pytest.approx(72.0)
    assert s["response_time"]["mean"] == pytest.approx(30.0)
    assert s["nodes"]["edge"]["penalised_response_time"] == pytest.approx(72.0)
    assert s["nodes"]["fog"]["completion_ratio"] is None  # fog has no client
    header, table = metrics.tick_table()
    col = header.index("penalised_response_time")
    assert [row[col] for row in table] == pytest.approx([100.0, 72.0])
    labels = dict(rows(s))
    assert labels["completion ratio"].startswith("40.0 %")
    assert labels["penalised response time"] == "72.00 s"
