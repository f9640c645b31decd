"""Scenarios nobody wrote by hand: random topologies, workloads and semantics give the same emulation in
every process layout, conserve tasks at every tick, and agree with Zenoh.

Hypothesis draws each scenario from every option that changes the model's behaviour (generators,
policies, binary and batch mode, decision and state intervals, hops, admission, control latency, link
loss, arrival schedules and processes, task mixes, deadline ranges, outages). The examples are fixed
(``derandomize``), so a failure reproduces; the scenario is printed with it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orchestrator.scenario import load_scenario
from tests.conftest import model_part, run_summary
from tests.test_conservation import recompute_from_csv

POLICIES = ["local", "random", "round_robin", "least_queue", "greedy", "greedy_backlog", "local_first"]

GENERATORS = st.one_of(
    st.builds(lambda n: {"kind": "ring", "n": n, "profile": "tier0"}, st.integers(3, 7)),
    st.builds(lambda r, c: {"kind": "grid", "rows": r, "cols": c, "profile": "tier0"},
              st.integers(1, 3), st.integers(2, 3)),
    st.builds(lambda n: {"kind": "fully_connected", "n": n, "profile": "tier0"}, st.integers(2, 5)),
    st.builds(lambda c, s: {"kind": "bridged_clusters", "clusters": c, "size": s, "profile": "tier0"},
              st.integers(2, 3), st.integers(2, 3)),
    st.builds(lambda lo, hi, top: {"kind": "n_tier", "tiers": [lo, hi], "profiles": ["tier0", top], "cloud": "tier2"},
              st.integers(2, 4), st.integers(1, 2), st.sampled_from(["tier1", "tier2"])),
)

DEADLINES = st.one_of(st.sampled_from([5.0, 20.0, 100.0]),
                      st.builds(lambda lo, span, grace: {"low": lo, "high": lo + span, "grace": grace},
                                st.sampled_from([5.0, 20.0]), st.sampled_from([10.0, 40.0]),
                                st.sampled_from([0.0, 2.0])))

TASKS = st.lists(st.fixed_dictionaries({
    "weight": st.sampled_from([0.5, 1.0, 2.0]),
    "instructions": st.sampled_from([4e6, 4e7, 1e8, 3e8]),
    "input_bytes": st.sampled_from([1e4, 1e6, 2e7]),
    "output_bytes": st.sampled_from([1e3, 1e6, 1e7]),
    "cpi": st.sampled_from([1.0, 1.5]),
    "deadline": DEADLINES,
}), min_size=1, max_size=3)

ARRIVALS = st.one_of(
    st.builds(lambda rate: {"kind": "constant", "rate": rate}, st.sampled_from([0.1, 0.5, 1.5])),
    st.just({"kind": "zigzag", "low": 0.1, "high": 1.0, "period": 30.0}),
    st.just({"kind": "linear", "start": 0.05, "end": 1.2}),
    st.just({"kind": "uniform", "low": 0.1, "high": 0.8}),
).flatmap(lambda a: st.builds(lambda p: {**a, "process": p}, st.sampled_from(["poisson", "exponential_gaps"])))


@st.composite
def scenarios(draw: st.DrawFn) -> dict[str, Any]:
    mode = draw(st.sampled_from(["binary", "batch"]))
    simulation = {
        "steps": draw(st.integers(30, 90)), "seed": draw(st.integers(0, 999)),
        "policy": draw(st.sampled_from(POLICIES)), "mode": mode,
        "decision_interval": draw(st.sampled_from([1, 2, 3])), "max_hops": draw(st.integers(0, 3)),
        "state_interval": draw(st.sampled_from([1, 2, 4])),
        "admission": draw(st.sampled_from(["decide_first", "queue_first"])),
        "control_latency": draw(st.sampled_from([0, 2])),
    }
    if mode == "batch":
        simulation["batch_size"] = draw(st.integers(1, 4))
    data = {"name": "random", "simulation": simulation,
            "workload": {"arrival": draw(ARRIVALS), "tasks": draw(TASKS)},
            "network": {"loss": draw(st.sampled_from([0.0, 0.0, 0.1]))},
            "topology": {"generator": draw(GENERATORS)}}
    sc = load_scenario(data, name_hint="random")  # the generated node names, for an outage
    if draw(st.booleans()):
        node = draw(st.sampled_from(sorted(sc.node)))
        data["failures"] = [{"node": node, "at": draw(st.integers(5, 30)), "duration": draw(st.integers(1, 20))}]
    return data


def outputs(data: dict[str, Any], out: Path, **kw: Any) -> tuple[dict[str, Any], str, str]:
    summary = run_summary(load_scenario(data, name_hint="random"), out=out, **kw)
    return model_part(summary), (out / "ticks.csv").read_text(), (out / "nodes.csv").read_text()


EXAMPLES = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@EXAMPLES
@given(data=scenarios())
def test_every_layout_runs_the_same_emulation_and_conserves_tasks(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("random")
    ref = outputs(data, tmp / "single")
    recompute_from_csv(tmp / "single" / "ticks.csv")
    for layout in ("per-role", "per-node", "groups:2"):
        assert outputs(data, tmp / layout, layout=layout) == ref, f"{layout} differs from one process"


@pytest.mark.zenoh
@settings(EXAMPLES, max_examples=4)
@given(data=scenarios())
def test_zenoh_runs_the_same_emulation_as_one_process(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("random-zenoh")
    ref = outputs(data, tmp / "inproc")
    assert outputs(data, tmp / "zenoh", transport="zenoh", layout="per-node") == ref
