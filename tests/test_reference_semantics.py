"""The reference implementation's semantics, each a scenario setting (docs/model.md, docs/scenario.md
"Scenario families"): outcomes computed by hand in the comments, and the same emulation whatever the
process layout or transport.

Timing rules used below, besides those of tests/test_trace_by_hand.py:
- ``admission: queue_first``: an arriving task joins the FIFO queue at once and may start in the tick it
  arrives; the controller is told of the queued tasks that have not started (not the one in service);
  a decision keeps such a task or takes it out of the queue, unless it has started meanwhile (stale);
- ``control_latency: 0``: the controller reads its worker at the end of tick t (after the worker ran) and
  decides; its decision reaches the worker at the start of tick t + 1, before the worker runs.
  ``control_latency: 2`` (default): report at t reaches the controller at t + 1, which decides at the end
  of t + 1 and sends at t + 2; the worker applies it at t + 3.
"""

from __future__ import annotations

import json
import math
from typing import ClassVar

import numpy as np
import pytest

from node_runtime.model.messages import TaskSize
from node_runtime.model.policies import POLICIES, Greedy, LeastQueue, Policy, make_policy
from node_runtime.model.spec import Scenario
from node_runtime.model.view import NodeView, Observation, TaskView
from node_runtime.model.workload import BLOCK, TaskSource
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from tests.conftest import ROOT, model_part, run_summary, write_scenario
from tests.test_determinism import outputs

HEADER = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n"


def two_nodes(tmp_path, rows: str, simulation: dict, a: dict | None = None, b: dict | None = None) -> Scenario:
    """a (task source with a controller) and b, one 8 Mbit/s wired link: 1 MB takes 1 s."""
    (tmp_path / "trace.csv").write_text(HEADER + rows)
    return load_scenario(write_scenario(tmp_path, {
        "simulation": {"dt": 1.0, "steps": 30, **simulation},
        "workload": {"trace": "trace.csv"},
        "topology": {"nodes": [
            {"id": "a", "frequency": 1.0e6, "buffer": 2, "controller": True, "client": True, **(a or {})},
            {"id": "b", "frequency": 1.0e6, "buffer": 2, **(b or {})},
        ], "links": [{"between": ["a", "b"], "rate_bps": 8.0e6}]},
    }))


# the rows of tests/test_trace_by_hand.py::test_local_queueing_drops_and_expiry, where decide_first with the
# default latency completes tasks 1 and 2 in 7 s and 9 s
LOCAL_ROWS = "0,a,3e6,1000,1000,1,100\n0,a,2e6,1000,1000,1,100\n1,a,1e6,1000,1000,1,100\n10,a,5e6,1000,1000,1,4\n"


def test_queue_first_computes_while_the_decision_is_on_its_way(tmp_path):
    scenario = two_nodes(tmp_path, LOCAL_ROWS, {"policy": "local", "admission": "queue_first"})
    # tick 1: tasks 1, 2 join the queue (occupancy 2 = Q_max); task 1 runs 1e6 of its 3e6 cycles; task 2 has
    #   not started, so the worker reports it
    # tick 2: task 3 finds the buffer full (queue_full); task 1 runs; the controller hears of task 2 and
    #   decides "local"
    # tick 3: task 1 finishes (budget used up exactly: task 2 has still not started); the decision leaves
    # tick 4: the result of task 1 reaches the client: 4 s. The decision keeps task 2, which runs 4 and 5
    # tick 6: the result of task 2: 6 s
    # task 4 (created 10) arrives at 11 at an empty queue and starts at once: it is never offered to the
    #   controller; 4e6 of its 5e6 cycles run in 11..14, and at 15 it is 5 s old > 4 s: expired
    s = run_summary(scenario, ticks=30)
    assert s["totals"]["completed"] == 2
    assert s["response_time"]["mean"] == pytest.approx(5.0) and s["response_time"]["max"] == pytest.approx(6.0)
    assert s["totals"]["dropped"] == {"queue_full": 1, "expired": 1, "node_failure": 0, "link_loss": 0, "total": 2}
    assert (s["totals"]["decisions"], s["totals"]["stale_decisions"], s["totals"]["offloaded"]) == (1, 0, 0)
    # the buffer holds 2 at the start of ticks 2 and 3; a's CPU works in 1..5 and 11..14
    assert s["nodes"]["a"]["overloaded_ticks"] == 2
    assert s["nodes"]["a"]["utilisation"] == pytest.approx(9e6 / 30e6)


def test_co_located_control_applies_a_decision_in_the_next_tick(tmp_path):
    scenario = two_nodes(tmp_path, LOCAL_ROWS, {"policy": "local", "control_latency": 0})
    # tick 1: tasks 1, 2 wait undecided; at the end of the tick the controller sees both and keeps task 1
    # tick 2: the decision arrives before the worker runs: task 1 is queued, task 3 finds 1 queued +
    #   1 undecided = Q_max (queue_full); task 1 runs 1e6; the controller keeps task 2
    # tick 3: task 2 queued; task 1 runs; tick 4: task 1 finishes -> client at 5: 5 s
    # ticks 5, 6: task 2 -> client at 7: 7 s (2 ticks earlier than with the default latency: 7 s, 9 s)
    # task 4: arrives 11, kept at 12, runs 12..14, expired at 15
    s = run_summary(scenario, ticks=30)
    assert s["totals"]["completed"] == 2
    assert s["response_time"]["mean"] == pytest.approx(6.0) and s["response_time"]["max"] == pytest.approx(7.0)
    assert s["totals"]["dropped"] == {"queue_full": 1, "expired": 1, "node_failure": 0, "link_loss": 0, "total": 2}
    assert s["totals"]["decisions"] == 3
    # occupancy 2 at the start of ticks 2, 3 and 4; the CPU works in 2..6 and 12..14
    assert s["nodes"]["a"]["overloaded_ticks"] == 3
    assert s["nodes"]["a"]["utilisation"] == pytest.approx(8e6 / 30e6)


# three tasks created at 0: 3e6, 1e6 and 1e6 cycles, 1 MB in (1 s on the link), 0.1 MB out (0.1 s)
THREE_ROWS = "0,a,3e6,1e6,1e5,1,100\n0,a,1e6,1e6,1e5,1,100\n0,a,1e6,1e6,1e5,1,100\n"


@pytest.mark.parametrize(("latency", "responses"), [(0, [4.0, 5.0, 5.0]), (2, [4.0, 5.0, 7.0])])
def test_queue_first_offloads_the_head_of_the_waiting_queue(tmp_path, latency, responses):
    scenario = two_nodes(tmp_path, THREE_ROWS, {"policy": "round_robin", "admission": "queue_first",
                                                "control_latency": latency},
                         a={"buffer": 4}, b={"frequency": 2.0e6, "buffer": 4})
    # Both: tick 1 queues tasks 1, 2, 3 and task 1 starts; tasks 2, 3 wait. Round robin keeps task 2 and
    # sends task 3 to b. Task 1 finishes in tick 3 -> 4 s; task 2 runs in tick 4 -> client at 5: 5 s.
    # latency 0: the decisions reach the worker at 2 (task 2) and 3 (task 3): task 3 leaves at 3, is on the
    #   link 3.0 -> 4.0, runs at b in 4 (2e6 cycles/s), its result is on the link 4.0 -> 4.1: 5 s
    # latency 2: reported at 1, decided at 2 and 3, applied at 4 and 5: task 3 leaves at 5 (it had not
    #   started: task 2 used up tick 4), b has it at 6, its result arrives at 7: 7 s
    s = run_summary(scenario, ticks=20)
    assert s["totals"]["completed"] == 3 and s["totals"]["offloaded"] == 1
    assert (s["totals"]["decisions"], s["totals"]["stale_decisions"]) == (2, 0)
    assert s["response_time"]["mean"] == pytest.approx(sum(responses) / 3)
    assert s["response_time"]["max"] == pytest.approx(max(responses))


class Scripted:
    """A stand-in for a random stream that returns given exponential draws (and checks their scale)."""

    def __init__(self, draws: list[float], scale: float) -> None:
        self.draws = list(draws)
        self.scale = scale

    def exponential(self, scale: float) -> float:
        assert scale == pytest.approx(self.scale)
        return self.draws.pop(0) if self.draws else 1e9


def gap_source(tmp_path, draws: list[float], rate: float, dt: float) -> TaskSource:
    scenario = load_scenario(write_scenario(tmp_path, {
        "simulation": {"dt": dt},
        "workload": {"arrival": {"rate": rate, "process": "exponential_gaps"}},
        "topology": {"nodes": [{"id": "a", "client": True}, {"id": "b"}], "links": [["a", "b"]]}}))
    return TaskSource(scenario, "a", Scripted(draws, 1 / rate), np.random.default_rng(0))


def arrival_ticks(source: TaskSource, until: int) -> list[int]:
    return [t for t in range(until) if source.count(t)]


def test_exponential_gaps_one_task_at_a_time(tmp_path):
    # X (s) ~ Exp(λ = 0.25): the first task at ⌊2.7⌋ = 2; then gaps max(1, ⌊X⌋): ⌊0.4⌋ = 0 -> 1 (tick 3),
    # ⌊3.9⌋ = 3 (tick 6), ⌊0.99⌋ = 0 -> 1 (tick 7), ⌊1.0⌋ = 1 (tick 8), ⌊300.2⌋ = 300 (tick 308, past one block)
    source = gap_source(tmp_path, [2.7, 0.4, 3.9, 0.99, 1.0, 300.2], rate=0.25, dt=1.0)
    assert arrival_ticks(source, 2 * BLOCK) == [2, 3, 6, 7, 8, 308]
    assert (source.next_arrival(3), source.next_arrival(8)) == (6, 8 + BLOCK)  # 8 + BLOCK: none in the window


def test_exponential_gaps_are_counted_in_ticks_of_dt(tmp_path):
    # dt = 0.5 s: ⌊X / dt⌋ ticks: ⌊0.3 / 0.5⌋ = 0 (tick 0), then max(1, ⌊0.2 / 0.5⌋ = 0) = 1 (tick 1),
    # ⌊1.6 / 0.5⌋ = 3 (tick 4)
    source = gap_source(tmp_path, [0.3, 0.2, 1.6], rate=2.0, dt=0.5)
    assert arrival_ticks(source, 10) == [0, 1, 4]


def test_exponential_gaps_cap_arrivals_at_one_per_tick(tmp_path):
    # λ = 1000 tasks/s: every gap is ⌊X⌋ = 0 (P(X >= 1 s) = e^-1000), so a task in every tick from tick 0:
    # 40 ticks, 40 tasks per client, where Poisson(1000) would create about 40,000
    scenario = load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 40},
        "workload": {"arrival": {"rate": 1000, "process": "exponential_gaps"},
                     "tasks": [{"instructions": 1e3, "input_bytes": 1e3, "output_bytes": 1e3}]},
        "topology": {"nodes": [{"id": "a", "client": True, "frequency": 1e9, "buffer": 5},
                               {"id": "b", "client": True, "frequency": 1e9, "buffer": 5}], "links": [["a", "b"]]}}))
    s = run_summary(scenario)
    assert s["totals"]["generated"] == 80


def one_task_in_the_buffer(tmp_path, grace: float) -> dict:
    """a makes a task every tick (λ = 1000, exponential gaps), holds one at a time (buffer 1) and needs 7 s
    for it; deadlines are drawn from U[4, 5) s plus ``grace``."""
    scenario = load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 9},
        "workload": {"arrival": {"rate": 1000, "process": "exponential_gaps"},
                     "tasks": [{"instructions": 7e6, "input_bytes": 1e3, "output_bytes": 1e3,
                                "deadline": {"low": 4, "high": 5, "grace": grace}}]},
        "topology": {"nodes": [{"id": "a", "client": True, "frequency": 1e6, "buffer": 1}, {"id": "b"}],
                     "links": [["a", "b"]]}}))
    return run_summary(scenario)["totals"]


def test_a_drawn_deadline_plus_its_grace_decides_every_outcome(tmp_path):
    # Tasks are created at 0..8 and reach a's worker a tick later. The first (created 0) holds the buffer
    # from tick 1 and runs 1..7; its result reaches the client at 8, when it is 8 s old. Whatever the draw
    # in [4, 5), its deadline δ lies in [4 + grace, 5 + grace), and it is dropped once its age exceeds δ.
    # grace 4, δ in [8, 9): 8 s is in time: completed. Tasks created 1..6 find the buffer full; the one
    #   created 7 is admitted at 8 and the one created 8 is on its way: 2 in the system.
    assert one_task_in_the_buffer(tmp_path, 4) == {
        "generated": 9, "completed": 1, "offloaded": 0, "decisions": 0, "stale_decisions": 0, "in_system": 2,
        "dropped": {"queue_full": 6, "expired": 0, "node_failure": 0, "link_loss": 0, "total": 6}}
    # grace 3, δ in [7, 8): it finishes at 7 (age 7 <= δ) but its result is 8 s old at the client: expired
    t = one_task_in_the_buffer(tmp_path, 3)
    assert (t["completed"], t["dropped"]["expired"], t["dropped"]["queue_full"], t["in_system"]) == (0, 1, 6, 2)
    # grace 1, δ in [5, 6): at tick 6 (age 6 > δ) the worker drops it and admits the task created 5;
    #   the ones created 1..4, 6 and 7 find the buffer full
    t = one_task_in_the_buffer(tmp_path, 1)
    assert (t["completed"], t["dropped"]["expired"], t["dropped"]["queue_full"], t["in_system"]) == (0, 1, 6, 2)


def test_drawn_deadlines_have_a_stream_of_their_own(tmp_path):
    def source(deadline) -> tuple[list[int], list[float]]:
        scenario = load_scenario(write_scenario(tmp_path, {
            "workload": {"arrival": {"rate": 0.3}, "tasks": [{"deadline": deadline}]},
            "topology": {"nodes": [{"id": "a", "client": True}, {"id": "b"}], "links": [["a", "b"]]}}))
        from node_runtime.model.client import Client

        client = Client(scenario.node["a"], scenario)
        draws = [(t, d) for t in range(600) for d in client.source.draws(t)]
        return [t for t, _ in draws], [d[4] for _, d in draws]

    fixed_ticks, fixed = source(150.0)
    drawn_ticks, drawn = source({"low": 100, "high": 200, "grace": 5})
    assert drawn_ticks == fixed_ticks  # the same arrivals: deadlines do not draw from the counts' stream
    assert set(fixed) == {150.0}
    assert all(105 <= d < 205 for d in drawn) and len(set(drawn)) == len(drawn) > 100


class Recorder(Policy):
    """Sends every task to the first neighbour, and records (tick, backlog on the link to it)."""

    name = "recorder"
    seen: ClassVar[list[tuple[int, float]]] = []

    def choose(self, obs, task, valid, extra):
        Recorder.seen.append((obs.tick, obs.neighbours[0].backlog_s))
        return 1


FOUR_BIG = "0,a,1e6,8e6,1e3,1,100\n" * 4  # 8 MB in: 8 s on the 8 Mbit/s link each


@pytest.mark.parametrize(("latency", "seen"), [
    # the worker reports its link when it reports its tasks: at 4 it sends task 1 (on the link 4.0 -> 12.0)
    # and reports; at 5 the controller sees 12 - (5 + 1) = 6 s still queued. Before, it knew of nothing.
    (2, [(2, 0.0), (3, 0.0), (4, 0.0), (5, 6.0)]),
    # co-located: task 1 leaves at 2 (2.0 -> 10.0): at the end of 2, 10 - 3 = 7 s are queued; task 2 follows
    # at 3 (10.0 -> 18.0): 14 s at the end of 3; task 3 at 4 (-> 26.0): 21 s at the end of 4
    (0, [(1, 0.0), (2, 7.0), (3, 14.0), (4, 21.0)]),
])
def test_a_controller_sees_the_backlog_of_each_link(tmp_path, latency, seen):
    scenario = two_nodes(tmp_path, FOUR_BIG, {"policy": "tests.test_reference_semantics:Recorder",
                                              "control_latency": latency},
                         a={"buffer": 4}, b={"frequency": 1e9, "buffer": 4})
    Recorder.seen = []
    run_summary(scenario, ticks=8)
    assert Recorder.seen == seen


def test_greedy_backlog_avoids_a_congested_link():
    def node(name, capacity, backlog=0.0):
        return NodeView(name, 0, 0, 10, capacity, 0, 0.0 if name == "a" else 8e6, 1, True, backlog)

    # a task of 1e8 cycles and 1e6 + 1e3 bytes: locally 100 s; to b (1e9 cycles/s) 1.001 s of transfer +
    # 0.1 s; to c (1e8) 1.001 + 1 s. b's link already has 30 s queued.
    task = TaskView(1, TaskSize(1e8, 1e6, 1e3, 1.0, 200.0), 200.0, 0, "a")
    obs = Observation(5, "a", node("a", 1e6), 1, [task], [node("b", 1e9, backlog=30.0), node("c", 1e8)])
    assert Greedy().decide(obs) == [1]  # b: 1.1 s, not seeing the queue
    assert make_policy("greedy_backlog").decide(obs) == [2]  # b: 31.1 s, c: 2.0 s
    assert "greedy_backlog" in POLICIES


def test_free_space_path_loss():
    # 10 m at 2.4 GHz: 20 log10(4π · 10 · 2.4e9 / c) = 40.05 + 20 = 60.05 dB; SNR = 20 - 60.05 + 110.99 dB
    # = 70.94 dB -> 2 MHz · log2(1 + 10^7.094) = 47.13 Mbit/s
    scenario = load_scenario({"network": {"path_loss": {"frequency_hz": 2.4e9, "exponent": 2}},
                              "topology": {"nodes": [{"id": "a", "client": True, "position": [0, 0]},
                                                     {"id": "b", "position": [10, 0]}], "links": [["a", "b"]]}})
    assert scenario.link[("a", "b")].rate_bps == pytest.approx(47.13e6, rel=1e-3)
    free_space = 20 * math.log10(4 * math.pi * 2.4e9 / 299_792_458)
    assert free_space == pytest.approx(40.05, abs=0.005)


def test_ether_buffers_rounded_by_the_reference_rule(tmp_path):
    (tmp_path / "e.json").write_text(json.dumps({
        "nodes": {"rpi3_0": {"id": 1, "coordinates": [0, 0], "capacity": {"cpu_milis": 4000, "memory": 950}},
                  "rpi3_1": {"id": 2, "coordinates": [5, 0], "capacity": {"cpu_milis": 4000, "memory": 1240}}},
        "links": {"neighbours": {"1": [2], "2": [1]}}}))
    tasks = {"tasks": [{"input_bytes": 250, "output_bytes": 250}]}

    def buffers(topology):
        sc = load_scenario(write_scenario(tmp_path, {"workload": tasks, "topology": {"ether": "e.json", **topology}}))
        return [n.buffer for n in sc.nodes]

    assert buffers({}) == [1, 2]  # ⌊950 / 500⌋, ⌊1240 / 500⌋
    assert buffers({"buffer_bytes": 500}) == [2, 2]  # round(1.9), round(2.48)


REFERENCE = {  # nodes, buffers by profile (round(memory / 3.2e8)), controllers, task sources
    "aot1_reference": (12, 10, 8), "aot2_reference": (19, 15, 12),
    "aot3_reference": (28, 22, 18), "aot4_reference": (31, 23, 18),
}


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_reference_scenarios_run_what_the_reference_ran(name):
    nodes, controllers, sources = REFERENCE[name]
    sc = load_scenario(ROOT / "topologies" / f"{name}.yaml")
    assert (len(sc.nodes), len(sc.controllers), len(sc.clients)) == (nodes, controllers, sources)
    assert {n.profile: n.buffer for n in sc.nodes} == {"rpi3": 3, "tx2": 26, "nuc": 54, "server": 588}
    assert (sc.admission, sc.control_latency, sc.workload.arrival.process) == ("queue_first", 0, "exponential_gaps")
    (task,) = sc.workload.task_types
    assert (task.instructions, task.input_bytes, task.output_bytes) == (3.2e8, 1.5e8, 1.5e8)
    assert (task.deadline.low, task.deadline.high, task.deadline.grace) == (100.0, 200.0, 5.0)
    plain = load_scenario(ROOT / "topologies" / f"{name.removesuffix('_reference')}.yaml")
    assert [n.id for n in sc.nodes] == [n.id for n in plain.nodes] and sc.links != plain.links


def test_new_settings_at_their_defaults_keep_the_scenario_hash(tmp_path):
    base = {"name": "same", "topology": {"ether": "ether/network_2_clusters.json"}}
    explicit = {"simulation": {"admission": "decide_first", "control_latency": 2},
                "workload": {"arrival": {"process": "poisson"}}, **base}
    plain = load_scenario(write_scenario(tmp_path, base, "plain.yaml")).digest()
    assert load_scenario(write_scenario(tmp_path, explicit, "explicit.yaml")).digest() == plain
    for changed in ({"simulation": {"admission": "queue_first"}}, {"simulation": {"control_latency": 0}},
                    {"workload": {"arrival": {"process": "exponential_gaps"}}},
                    {"workload": {"tasks": [{"deadline": {"low": 100, "high": 200}}]}}):
        assert load_scenario(write_scenario(tmp_path, {**changed, **base}, "changed.yaml")).digest() != plain
    sc = load_scenario(ROOT / "topologies" / "aot1_reference.yaml")
    assert Scenario.from_dict(json.loads(json.dumps(sc.to_dict()))) == sc


def everything(tmp_path, latency: int) -> Scenario:
    """Every new rule at once, with the timing rules that decide when roles wake: batches, long epochs,
    sparse broadcasts, two hops, failures, full buffers, expiring deadlines."""
    return load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 150, "policy": "greedy_backlog", "mode": "batch", "batch_size": 2,
                       "decision_interval": 3, "state_interval": 2, "max_hops": 2, "admission": "queue_first",
                       "control_latency": latency},
        "workload": {"arrival": {"rate": 0.6, "process": "exponential_gaps"},
                     "tasks": [{"instructions": 3e6, "input_bytes": 4e5, "output_bytes": 1e5,
                                "deadline": {"low": 6, "high": 14, "grace": 2}}]},
        "topology": {"nodes": [{"id": "a", "frequency": 1e6, "buffer": 4, "client": True, "controller": True},
                               {"id": "b", "frequency": 1e6, "buffer": 4, "client": True, "controller": True},
                               {"id": "c", "frequency": 2e6, "buffer": 6, "controller": True},
                               {"id": "d", "client": True, "worker": False}],
                     "links": [["a", "b"], ["b", "c"], ["d", "a"]]},
        "failures": [{"node": "b", "at": 40, "duration": 15}, {"node": "c", "at": 90, "duration": 5}],
    }), name_hint=f"everything{latency}")


@pytest.mark.parametrize("latency", [0, 2])
def test_layouts_agree_on_the_new_rules(tmp_path, latency):
    scenario = everything(tmp_path, latency)
    ref = outputs(tmp_path, scenario, "single", seed=4)
    totals = ref[0]["totals"]
    assert totals["offloaded"] > 0 and totals["dropped"]["expired"] > 0 and totals["dropped"]["queue_full"] > 0
    assert totals["dropped"]["node_failure"] > 0
    for layout in ("per-role", "per-node"):
        assert outputs(tmp_path, scenario, layout, seed=4, layout=layout) == ref, layout


@pytest.mark.zenoh
def test_zenoh_agrees_on_co_located_control(tmp_path):
    scenario = everything(tmp_path, 0)
    ref = outputs(tmp_path, scenario, "inproc", seed=6)
    assert outputs(tmp_path, scenario, "zenoh", seed=6, transport="zenoh", layout="per-role") == ref


@pytest.mark.parametrize("latency", [0, 2])
def test_an_agent_decides_with_the_timing_of_a_node_policy(latency):
    # The same least-queue rule, once in the nodes and once as an agent driving every controller through
    # the clock: the same emulation, co-located or not.
    scenario = load_scenario(ROOT / "topologies" / "aot1_reference.yaml")
    if latency:
        scenario = Scenario.from_dict({**scenario.to_dict(), "control_latency": latency})
    ticks = 150
    node_side = model_part(run_summary(scenario, ticks=ticks, seed=2, policy="least_queue"))
    rule = LeastQueue()
    with Simulation.inproc(scenario, layout="per-role") as sim:
        roles = [f"controller:{n}" for n in scenario.controllers]
        sim.reset(seed=2, external=roles)
        for _ in range(ticks - 1):
            seen = sim.observations()
            sim.step({r: rule.decide(o)[0] for r, o in seen.items() if o.tasks})
        driven = model_part(sim.summary())
    assert driven["totals"]["decisions"] > 0
    assert driven["totals"] == node_side["totals"] and driven["response_time"] == node_side["response_time"]
