"""Trace scenarios whose every outcome is computed by hand below, checked on both transports.

Timing rules used in the hand computations (docs/model.md):
- a message sent in tick t arrives at t + 1 at the earliest (radio: at the first tick boundary
  after the transmission ends, FIFO per link);
- a client's task created at t reaches its own worker at t + 1, where it waits undecided; the worker
  reports it to the controller (t + 2), which decides at the end of the epoch and applies the
  decision in the next tick (t + 3); the decision reaches the worker at t + 4;
- a worker spends cores * frequency * dt cycles per tick on its queue head first; a task whose last
  cycle runs in tick t sends its result in tick t;
- response time = (tick the result reaches the client - creation tick) * dt.
"""

from __future__ import annotations

import pytest

from orchestrator.scenario import load_scenario
from tests.conftest import model_part, run_summary, write_scenario

HEADER = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n"


def single_node(tmp_path, rows: str):
    (tmp_path / "trace.csv").write_text(HEADER + rows)
    return load_scenario(write_scenario(tmp_path, {
        "simulation": {"dt": 1.0, "steps": 30, "policy": "local"},
        "workload": {"trace": "trace.csv"},
        "energy": {"kappa": 1.0e-27, "idle_power_w": 0.5},
        "topology": {"nodes": [
            {"id": "a", "cores": 1, "frequency": 1.0e6, "buffer": 2, "controller": True, "client": True},
            {"id": "b", "cores": 1, "frequency": 1.0e6, "buffer": 2},
        ], "links": [{"between": ["a", "b"], "rate_bps": 8.0e6}]},
    }))


def test_local_queueing_drops_and_expiry(tmp_path):
    scenario = single_node(tmp_path, "\n".join([
        "0,a,3e6,1000,1000,1,100",  # task 1
        "0,a,2e6,1000,1000,1,100",  # task 2
        "1,a,1e6,1000,1000,1,100",  # task 3
        "10,a,5e6,1000,1000,1,4",   # task 4: too short a deadline
    ]) + "\n")
    # tick 1: tasks 1, 2 enter a's buffer (undecided; occupancy 2 = Q_max)
    # tick 2: task 3 arrives at a full buffer -> dropped (queue_full)
    # decisions: task 1 applied by the controller at 3, at the worker at 4; task 2 at 4 / 5
    # CPU 1e6 cycles per tick: task 1 runs 4, 5, 6 -> result at the client at 7 -> 7 s
    #                          task 2 runs 7, 8    -> result at 9                -> 9 s
    # task 4 (created 10): worker 11, decided 13, queued 14 and runs 1e6 cycles; at tick 15 its age is
    # 5 s > 4 s -> dropped (expired) with 4e6 cycles left
    s = run_summary(scenario, ticks=30)
    assert s["totals"]["generated"] == 4
    assert s["totals"]["completed"] == 2
    assert s["totals"]["dropped"] == {"queue_full": 1, "expired": 1, "node_failure": 0, "link_loss": 0, "total": 2}
    assert s["response_time"]["mean"] == pytest.approx(8.0)
    assert s["response_time"]["max"] == pytest.approx(9.0)
    assert s["totals"]["offloaded"] == 0
    # busy ticks 4..8 and 14: 6e6 cycles of a's 30 ticks * 1e6 capacity; b idle.
    assert s["nodes"]["a"]["utilisation"] == pytest.approx(6e6 / 30e6)
    # energy of a: compute 1e-27 * 6e6 * (1e6)^2 = 6e-9 J, idle 0.5 W * 30 s = 15 J; b: idle 15 J
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(15.0 + 6e-9)
    assert s["energy_j"]["total"] == pytest.approx(30.0 + 6e-9)
    # the buffer holds 2 of 2 at the start of ticks 2..6 (undecided or queued, task 1 leaves in tick 6)
    assert s["nodes"]["a"]["overloaded_ticks"] == 5
    assert s["totals"]["in_system"] == 0


def round_robin_pair(tmp_path, rows: str, steps: int, buffer: int):
    """a (1e6 cycles/s) places its tasks round robin over itself and b (2e6), over an 8e6 bit/s link."""
    (tmp_path / "trace.csv").write_text(HEADER + rows)
    return load_scenario(write_scenario(tmp_path, {
        "simulation": {"dt": 1.0, "steps": steps, "policy": "round_robin"},
        "workload": {"trace": "trace.csv"},
        "topology": {"nodes": [
            {"id": "a", "frequency": 1.0e6, "buffer": buffer, "controller": True, "client": True},
            {"id": "b", "frequency": 2.0e6, "buffer": buffer},
        ], "links": [{"between": ["a", "b"], "rate_bps": 8.0e6}]},
    }))


def test_offload_over_a_link(tmp_path):
    scenario = round_robin_pair(tmp_path, "0,a,1e6,2e6,1e6,1,100\n0,a,1e6,2e6,1e6,1,100\n", steps=12, buffer=4)
    # round robin over [local, b]: task 1 stays, task 2 goes to b.
    # task 1: queued at 4, done in 4 (1e6 cycles) -> client at 5 -> 5 s
    # task 2: decision reaches a at 5; 2 MB = 16e6 bits at 8e6 bit/s = 2 s on air (5.0 -> 7.0) -> b at 7;
    #   b runs 1e6 of its 2e6 cycles in 7; the 1 MB result takes 1 s (7.0 -> 8.0) -> a's client at 8 -> 8 s
    s = run_summary(scenario, ticks=12)
    assert s["totals"]["completed"] == 2
    assert s["totals"]["offloaded"] == 1
    assert sorted([s["response_time"]["p50"], s["response_time"]["max"]]) == [pytest.approx(6.5), pytest.approx(8.0)]
    assert s["response_time"]["mean"] == pytest.approx(6.5)
    # transmit energy at 20 dBm = 0.1 W: a 2 s on air, b 1 s; compute 1e-27 * 1e6 * f^2
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(0.2 + 1e-27 * 1e6 * 1e12)
    assert s["nodes"]["b"]["energy_j"] == pytest.approx(0.1 + 1e-27 * 1e6 * 4e12)
    assert s["nodes"]["b"]["utilisation"] == pytest.approx(1e6 / (12 * 2e6))


def test_delay_imposed_in_a_cpu_queue_and_on_a_link(tmp_path):
    scenario = round_robin_pair(tmp_path, "0,a,3e6,4e6,1000,1,100\n0,a,2e6,4e6,1000,1,100\n"
                                          "0,a,1e6,4e6,1000,1,50\n0,a,2e6,4e6,1000,1,40\n", steps=20, buffer=8)
    # round robin over [local, b], one decision a tick reaching a at 4, 5, 6, 7: tasks 1 and 3 stay, 2 and 4
    # go to b. Task 1 runs 4, 5, 6; task 3 (due in 50 s) joins the queue at 6 and waits behind it for that
    # last second: 0.02 of a deadline. Task 2 is on air 5.0 -> 9.0 (32e6 bits at 8e6 bit/s); task 4 (due in
    # 40 s), sent at 7, waits its last 2 s: 0.05. Task 3 (tick 7), and tasks 2 (b, 9) and 4 (b, 13) run with
    # nothing behind them: 0.07 in all.
    s = run_summary(scenario, ticks=20)
    assert s["totals"]["completed"] == 4
    assert s["delay_imposed"] == pytest.approx(0.07)


def test_a_waiter_that_expires_still_charges_the_head_for_the_seconds_it_waited(tmp_path):
    scenario = single_node(tmp_path, "0,a,3e6,1000,1000,1,100\n0,a,1e6,1000,1000,1,5\n")
    # task 1 runs 4, 5, 6 (decided at 4); task 2 (due in 5 s) joins the queue at 5 and waits behind it in
    # tick 5; at 6 it is 6 s old and expires. Task 1 imposed 1 s on a task due in 5 s: 0.2 of a deadline,
    # which the result brings back to a's client (7 s response).
    s = run_summary(scenario, ticks=20)
    assert s["totals"]["completed"] == 1 and s["totals"]["dropped"]["expired"] == 1
    assert s["response_time"]["mean"] == pytest.approx(7.0)
    assert s["delay_imposed"] == pytest.approx(0.2)


@pytest.mark.zenoh
def test_hand_computed_trace_is_the_same_over_zenoh(tmp_path):
    scenario = single_node(tmp_path, "0,a,3e6,1000,1000,1,100\n0,a,2e6,1000,1000,1,100\n1,a,1e6,1000,1000,1,100\n")
    inproc = run_summary(scenario, ticks=20)
    for layout in ("per-role", "per-node"):
        assert model_part(run_summary(scenario, ticks=20, transport="zenoh", layout=layout)) == model_part(inproc)
