"""An orchestrator that stands still (SIGSTOP, a starved machine): its router is in its process, so its processes
lose their router too. Every Zenoh lease follows ``--timeout`` (+ 5 s), so a stall shorter than that costs
nothing; a longer one ends the run with an error that names the orchestrator, not one of its processes.
"""

from __future__ import annotations

import json
import threading
import time

import psutil
import pytest

from node_runtime.runtime.keys import Keys
from node_runtime.runtime.zenoh_bus import ZenohTransport
from tests.conftest import model_part, run_summary
from tests.launcher import Launch, assert_all_gone, served

STEPS = 2000


def stop_mid_run(run: Launch) -> psutil.Process:
    """SIGSTOP the orchestrator once it is inside its episode (a monitor has seen its tick 1)."""
    run.wait_for("processes ready in")
    endpoint, sim = served(run)
    monitor = ZenohTransport.client(endpoint)
    seen = threading.Event()
    try:
        monitor.subscribe(Keys(sim).metrics(), lambda key, record: record["tick"] >= 1 and seen.set())
        monitor.dispatch(until=seen.is_set, timeout=60)
        orchestrator = psutil.Process(run.proc.pid)
        orchestrator.suspend()
    finally:
        monitor.close()
    return orchestrator


@pytest.mark.zenoh
@pytest.mark.slow
def test_a_stall_longer_than_the_default_lease_and_the_timeout_costs_nothing(tmp_path, aot1):
    """12 s: longer than Zenoh's default lease (10 s, which ended the run, naming a node) and than --timeout
    (11 s: the time the orchestrator stood still does not count against its processes), shorter than the
    16 s lease."""
    run = Launch("aot1", "--transport", "zenoh", "--steps", str(STEPS), "--seed", "3", "--timeout", "11",
                 "--out", str(tmp_path))
    orchestrator = stop_mid_run(run)
    children = run.descendants()
    time.sleep(12)  # the stall itself: nothing to wait for while the orchestrator is stopped
    orchestrator.resume()
    assert run.finish(120) == 0, "".join(run.err)
    summary = json.loads((tmp_path / "summary.json").read_text())
    local = model_part(run_summary(aot1, STEPS, seed=3))
    assert {**model_part(summary), "source": local["source"]} == local  # the CLI names the scenario, not its file
    assert_all_gone(children)


@pytest.mark.zenoh
@pytest.mark.slow
def test_a_stall_past_the_lease_names_the_orchestrator(tmp_path):
    """--timeout 1: a 6 s lease; a 9 s stall (under Zenoh's default lease, which would have kept the processes)
    makes them leave, and the error says the orchestrator stood still."""
    run = Launch("aot1", "--transport", "zenoh", "--steps", str(STEPS), "--timeout", "1", "--out", str(tmp_path))
    orchestrator = stop_mid_run(run)
    children = run.descendants()
    time.sleep(9)
    orchestrator.resume()
    assert run.finish(60) == 1
    errors = [line for line in run.err if line.startswith("error:")]
    assert errors and "the orchestrator itself stood still" in errors[0], "".join(run.err)
    assert_all_gone(children)
