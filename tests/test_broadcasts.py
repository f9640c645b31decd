"""A process sends all its broadcasts of a tick (its workers' states) as one batch, to the processes that hear them;
or, when every one of them holds broadcasts, hands its states to the clock, which gives each listener the latest at
its next tick."""

from __future__ import annotations

from collections import Counter

from node_runtime.model.messages import Kind
from node_runtime.runtime.layout import ProcessLayout
from orchestrator.session import Simulation
from tests.test_sleeping import hearing_every_state


def test_listeners_are_the_processes_hosting_a_subscriber_and_broadcasters_their_inverse(aot2):
    plan = ProcessLayout(aot2, "groups:3")
    for proc in plan.procs:
        heard = {plan.proc_of[r] for w in plan.roles_of[proc] for topic in plan.publications[w]
                 for r in plan.subscribers.get(topic, ())} - {proc}
        assert set(plan.listeners[proc]) == heard
        assert all(proc in plan.broadcasters[p] for p in plan.listeners[proc])
        assert plan.recipients[proc] >= set(plan.listeners[proc])
    per_node = ProcessLayout(aot2, "per-node")  # one worker per process: its listeners are its state's
    for proc in per_node.procs:
        (topic,) = (t for w in per_node.roles_of[proc] for t in per_node.publications[w])
        assert set(per_node.listeners[proc]) == {per_node.proc_of[r] for r in per_node.subscribers[topic]} - {proc}


def broadcast_batches(scenario, layout: str) -> tuple[Counter, Counter, dict]:
    """50 ticks: the broadcast batches published, by (process, tick); the states they carried, by process; the
    summary."""
    sim = Simulation.inproc(scenario, layout=layout)
    seen: Counter[tuple[str, int]] = Counter()
    states: Counter[str] = Counter()

    def count(key: str, batch) -> None:
        seen[(batch.src, batch.tick)] += 1
        for env in batch.envelopes:
            assert env.kind is Kind.STATE and env.dst in sim.plan.publications[env.src]
            states[batch.src] += 1

    sim.transport.bus.endpoint().subscribe(sim.keys.broadcasts("*"), count)
    summary = sim.run(50, seed=1, policy="least_queue")
    sim.close()
    return seen, states, summary


def test_a_process_of_many_nodes_sends_one_broadcast_batch_a_tick(aot2):
    seen, states, _ = broadcast_batches(hearing_every_state(aot2), "groups:3")  # they read every state as mail
    assert seen and max(seen.values()) == 1  # at most one batch per process and tick
    ticks = Counter(src for src, _ in seen)
    assert any(states[src] > ticks[src] for src in ticks)  # batches that carried several nodes' states


def test_states_that_every_listener_holds_go_with_the_ticks(aot2):
    """The built-in controllers hold broadcasts: no state is published as mail, and the run is the one where
    every controller reads each state the tick it arrives."""
    for layout in ("groups:3", "per-node"):
        seen, _, summary = broadcast_batches(aot2, layout)
        assert not seen, layout
        _, _, every = broadcast_batches(hearing_every_state(aot2), layout)
        assert summary["totals"] == every["totals"] and summary["totals"]["completed"] > 0, layout
