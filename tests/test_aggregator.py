"""A host's aggregator forwards its processes' reports of a tick as one message; the clock checks each report
in it as if it had come alone. In one process, on the in-process bus; tests/test_join.py runs it over Zenoh."""

from __future__ import annotations

from node_runtime.runtime.aggregator import DoneAggregator
from node_runtime.runtime.inproc import InprocBus
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.protocol import Done, Dones, Tick
from orchestrator.clock import Clock

PROCS = ["node-a", "node-b", "node-c"]
KEYS = Keys("agg")
KEYRING = Keyring.new(PROCS, ["g"])


class Host:
    """An aggregator for group ``g`` on an in-process bus, and what it forwards."""

    def __init__(self) -> None:
        bus = InprocBus()
        self.aggregator = DoneAggregator(bus.endpoint(), KEYS, "g", PROCS, KEYRING.of(PROCS, "g"))
        self.bus = bus.endpoint()
        self.forwarded: list[list[tuple[str, int]]] = []
        self.bus.subscribe(KEYS.dones(), self.on_dones)

    def on_dones(self, key: str, dones: Dones) -> None:
        assert key == KEYS.dones("g") and dones.group == "g"
        self.forwarded.append([(d.proc, d.tick) for d in dones.dones])

    def tick(self, t: int, *procs: str, command: str = "run") -> None:
        """The clock opens tick t for ``procs`` (each on its own key), or for all."""
        for key in [KEYS.tick(p) for p in procs] or [KEYS.tick()]:
            self.bus.publish(key, Tick(0, t, command), KEYRING.clock_key(0))

    def report(self, proc: str, t: int, error: str | None = None) -> None:
        self.bus.publish(KEYS.host_done("g", proc), Done(proc, 0, t, {}, {}, error=error), KEYRING.proc_key(proc, 0))


def test_a_tick_for_all_goes_on_once_all_reported():
    host = Host()
    host.tick(0, command="reset")
    host.report("node-b", 0)
    host.report("node-a", 0)
    assert host.forwarded == []
    host.report("node-c", 0)
    assert host.forwarded == [[("node-b", 0), ("node-a", 0), ("node-c", 0)]]


def test_only_the_processes_a_tick_was_opened_for_are_awaited():
    host = Host()
    host.tick(5, "node-a", "node-c")
    host.bus.publish(KEYS.tick("node-x"), Tick(0, 5), KEYRING.clock_key(0))  # another host's process
    host.report("node-c", 5)
    assert host.forwarded == []
    host.report("node-a", 5)
    assert host.forwarded == [[("node-c", 5), ("node-a", 5)]]


def test_reports_that_race_their_tick_go_on_alone_and_none_is_lost():
    """Nothing orders a process's report against the aggregator hearing the tick of another process."""
    host = Host()
    host.report("node-b", 3)  # before the aggregator heard any tick 3: nothing to wait for
    host.tick(3, "node-a")
    host.report("node-a", 3)
    host.tick(3, "node-c")  # heard after node-a's report went on
    host.report("node-c", 3)
    assert host.forwarded == [[("node-b", 3)], [("node-a", 3)], [("node-c", 3)]]


def test_a_tick_heard_after_a_report_that_went_on_waits_for_it_no_more():
    """Else the others' reports would wait for a quiet bus, which a flood of refused forgeries never leaves."""
    host = Host()
    host.report("node-a", 4)  # before the aggregator heard tick 4: it goes on alone
    host.tick(4)
    host.report("node-b", 4)
    host.report("node-c", 4)
    assert host.forwarded == [[("node-a", 4)], [("node-b", 4), ("node-c", 4)]]


def test_a_failure_goes_at_once_and_a_quiet_bus_sends_what_waits():
    """Reports are never held for a process that may never report: the orchestrator blames only the silent."""
    host = Host()
    host.tick(1)
    host.report("node-a", 1)
    host.report("node-b", 1, error="Traceback ...")
    assert host.forwarded == [[("node-a", 1), ("node-b", 1)]]
    host.tick(2)
    host.report("node-c", 2)
    host.aggregator.flush()  # node-a and node-b are hung
    assert host.forwarded[1:] == [[("node-c", 2)]]
    host.aggregator.flush()
    assert len(host.forwarded) == 2


def test_a_new_tick_sends_what_the_last_one_left():
    host = Host()
    host.tick(7, "node-a", "node-b")
    host.report("node-a", 7)
    host.tick(8, "node-c")
    assert host.forwarded == [[("node-a", 7)]]


def test_reports_it_cannot_trust_are_refused_and_counted():
    host = Host()
    host.tick(1)
    host.bus.publish(KEYS.host_done("g", "node-a"), Done("node-b", 0, 1, {}, {}))  # on another's key
    host.bus.publish(KEYS.host_done("g", "node-x"), Done("node-x", 0, 1, {}, {}))  # not this host's process
    host.bus.publish(KEYS.host_done("g", "node-a"), Tick(0, 1))
    assert host.forwarded == []
    assert host.aggregator.rejections.counts == {"unknown_sender": 2, "wrong_shape": 1}


def test_reports_and_ticks_without_their_senders_mac_are_refused():
    """A report without its process's MAC, or with another process's, is refused; a tick without the clock's is
    not heard; a second report of a process for one tick sends the first on, so that the orchestrator judges."""
    host = Host()
    host.tick(1, "node-a", "node-b")
    host.bus.publish(KEYS.tick("node-c"), Tick(0, 1))  # unsealed: node-c is not awaited
    host.bus.publish(KEYS.host_done("g", "node-a"), Done("node-a", 0, 1, {}, {}))
    host.bus.publish(KEYS.host_done("g", "node-a"), Done("node-a", 0, 1, {}, {}), KEYRING.proc_key("node-b", 0))
    assert host.forwarded == []
    assert host.aggregator.rejections.counts == {"bad_mac": 2}
    host.report("node-a", 1)
    host.report("node-a", 1, error="a second, different report")
    assert host.forwarded == [[("node-a", 1)], [("node-a", 1)]]
    host.report("node-b", 1)
    assert host.forwarded[2:] == [[("node-b", 1)]]


def test_the_clock_takes_a_hosts_reports_and_refuses_what_the_host_does_not_run(aot1):
    plan = ProcessLayout(aot1, "per-node")
    ours, others = list(plan.procs[:3]), list(plan.procs[3:])
    bus = InprocBus()
    keyring = Keyring.new(plan.procs, ["g", "h"])
    clock = Clock(bus.endpoint(), KEYS, plan, keyring, placement={"g": ours, "h": []})
    hosts = bus.endpoint()

    def answer(key: str, tick: Tick) -> None:  # every process reports; group g's through its aggregator
        def done(proc: str, error: str | None = None) -> Done:
            return Done(proc, tick.episode, tick.tick, {}, {}, error=error)

        g, h = keyring.host_key("g", 0), keyring.host_key("h", 0)
        hosts.publish(KEYS.dones("g"), Dones("g", [done(others[0], error="forged")]))  # without g's MAC
        hosts.publish(KEYS.dones("g"), Dones("g", [done(others[0], error="forged"), *map(done, ours)]), g)
        hosts.publish(KEYS.dones("h"), Dones("h", [done(others[1], error="forged")]), h)
        hosts.publish(KEYS.dones("g"), Tick(tick.episode, tick.tick))
        for proc in others:
            hosts.publish(KEYS.done(proc), done(proc), keyring.proc_key(proc, 0))

    hosts.subscribe(KEYS.tick(), answer)
    dones = clock.reset(seed=1)
    assert [d.proc for d in dones] == list(plan.procs)
    assert clock.reports == {"alone": len(others), "from_hosts": len(ours), "host_messages": 1}
    assert clock.rejections.counts == {"bad_mac": 1, "unknown_sender": 2, "wrong_shape": 1}


def test_what_the_aggregator_refused_is_said_once_more_when_it_ends(caplog):
    host = Host()
    host.aggregator.rejections.who = "zenohedge-node g"
    host.aggregator.rejections.log_total()
    assert not caplog.records  # nothing refused, nothing to say
    host.bus.publish(KEYS.host_done("g", "node-a"), Done("node-b", 0, 1, {}, {}))
    host.bus.publish(KEYS.host_done("g", "node-a"), Tick(0, 1))
    caplog.clear()
    host.aggregator.rejections.log_total()
    assert [r.getMessage() for r in caplog.records] == [
        "zenohedge: zenohedge-node g rejected 2 messages in all: unknown_sender 1, wrong_shape 1"]
