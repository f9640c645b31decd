"""Proof of origin and a fenced clock (node_runtime/runtime/origin.py, docs/security.md): a report without its
process's MAC, a tick without the clock's or of an epoch that is over, change nothing and are counted; two
different reports of one tick, both with the process's MAC, end the run naming the process."""

from __future__ import annotations

import re
import signal
import threading

import msgpack
import pytest

from node_runtime.model.role import STAT_FIELDS
from node_runtime.runtime import codec
from node_runtime.runtime.inproc import InprocBus
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.origin import Keyring, authentic, seal
from node_runtime.runtime.protocol import Done, Tick
from node_runtime.runtime.transport import TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator.clock import Clock, ProcessFailed
from orchestrator.scenario import load_scenario
from orchestrator.serve import Server
from orchestrator.session import Simulation
from tests.conftest import model_part
from tests.launcher import Launch, assert_all_gone, served

TICKS, SEED, AT = 200, 4, 20
KEYS = Keys("origin")
WAIT_S = 30.0


def test_a_mac_proves_its_key_its_epoch_and_the_message():
    keyring = Keyring.new(["a", "b"], ["g"])
    tick = Tick(0, 5, epoch=3)
    tick_bytes = codec.encode(tick, keyring.clock_key(3))
    heard = codec.decode(tick_bytes)
    assert authentic(keyring.clock_key(3), heard)
    assert not authentic(keyring.clock_key(4), heard) and not authentic(keyring.proc_key("a", 3), heard)
    forged = msgpack.unpackb(tick_bytes)
    forged["t"] = 6  # the genuine MAC, on another tick
    assert not authentic(keyring.clock_key(3), codec.decode(msgpack.packb(forged)))
    assert codec.decode(codec.encode(tick)).mac is None  # unsealed
    granted = Keyring.granted(keyring.grant(3))  # a driver's: its epoch only
    assert granted.clock_key(3) == keyring.clock_key(3) and granted.proc_key("b", 3) == keyring.proc_key("b", 3)
    assert granted.clock_key(4) is None and granted.host_key("g", 2) is None
    done = Done("a", 0, 5, {}, {}, epoch=3)  # in one process: a MAC over who sent it for which tick
    seal(done, keyring.proc_key("a", 3))
    assert authentic(keyring.proc_key("a", 3), done) and not authentic(keyring.proc_key("b", 3), done)


def test_a_group_registers_once(aot1):
    """Its host gets its processes' keys, its own and the clock's, and nothing else; then nobody gets them."""
    plan = ProcessLayout(aot1, "per-node")
    bus = InprocBus()
    keyring = Keyring.new(plan.procs, ["g", "h"])
    ours = list(plan.procs[:2])
    orchestrator = bus.endpoint()
    Server(orchestrator, KEYS, plan, Clock(orchestrator, KEYS, plan, keyring),
           placement={"g": ours, "h": list(plan.procs[2:])})
    asker = bus.endpoint()
    got = Keyring.from_wire(asker.request(KEYS.register("g"), {"type": "register"}, 1.0))
    assert got == Keyring(keyring.clock, {p: keyring.procs[p] for p in ours}, {"g": keyring.hosts["g"]})
    with pytest.raises(TransportError, match="group g is registered already"):
        asker.request(KEYS.register("g"), {"type": "register"}, 1.0)
    assert orchestrator.rejections.counts == {"unknown_sender": 1}


@pytest.mark.parametrize("first", ["other", "own"])
def test_two_different_reports_of_one_tick_end_the_run_naming_the_process(aot1, first):
    """Both carry the process's MAC: its key is in other hands, and nothing tells which is true. A copy of the
    report taken is no such thing (tests/test_hostile_bus.py replays one)."""
    sim = Simulation.inproc(aot1, layout="per-role")
    victim = next(d for d in sim.drivers if d.proc == "worker-rpi3_0")
    publish = victim.transport.publish

    def doubled(key: str, msg, seal=None) -> None:
        if key == victim.done_key and msg.tick >= AT:
            other = Done(victim.proc, msg.episode, msg.tick, {}, {}, epoch=msg.epoch)
            for report in (other, msg) if first == "other" else (msg, other):
                publish(key, report, seal)
        else:
            publish(key, msg, seal)

    victim.transport.publish = doubled
    with sim, pytest.raises(ProcessFailed, match=r"^process worker-rpi3_0 \(node rpi3_0\) sent two different "
                                                 r"reports of tick (\d+), both with its MAC") as failed:
        sim.run(TICKS, seed=SEED)
    tick = int(re.search(r"of tick (\d+)", str(failed.value))[1])
    assert failed.value.proc == "worker-rpi3_0" and AT <= tick == sim.clock.tick


@pytest.mark.zenoh
def test_a_forged_report_and_a_replayed_one_are_refused_over_zenoh(aot1):
    """The issue's attack: a well-formed Done on a real process's own key for an open tick (its energy a million
    joules, and no work due ever again) was taken; and a genuine report, captured from the bus, replayed for a
    later tick. Both are refused (bad_mac), a copy of the genuine one too (wrong_tick); the results are a clean
    run's."""
    clean = model_part(Simulation.inproc(aot1).run(TICKS, seed=SEED, policy="random"))
    victim = "node-rpi3_0"
    with Simulation.over_zenoh(aot1, layout="per-node") as sim:
        keys, plan = sim.keys, sim.plan
        stats = [0.0] * len(STAT_FIELDS)
        stats[STAT_FIELDS.index("energy_compute")] = 1e6
        outsider = ZenohTransport.client(sim.endpoint)
        captured: list[bytes] = []
        forged = threading.Event()

        def on_done(sample) -> None:  # what anyone on the router hears
            if not captured:
                captured.append(sample.payload.to_bytes())

        def on_tick(sample) -> None:  # a tick opened for the victim, later than the report captured
            tick = codec.decode(sample.payload.to_bytes())
            if tick.command != "run" or not captured or forged.is_set():
                return
            replayed = msgpack.unpackb(captured[0], strict_map_key=False)
            if tick.tick <= replayed["t"]:
                return
            lie = Done(victim, tick.episode, tick.tick, {}, {plan.role_index["worker:rpi3_0"]: stats}, epoch=tick.epoch)
            replayed["t"] = tick.tick
            done = keys.done(victim)
            outsider.session.put(done, codec.encode(lie))
            outsider.session.put(done, msgpack.packb(replayed, use_bin_type=True))
            outsider.session.put(done, captured[0])
            forged.set()

        try:
            subscribers = [outsider.session.declare_subscriber(keys.done(victim), on_done),
                           outsider.session.declare_subscriber(keys.tick(), on_tick),
                           outsider.session.declare_subscriber(keys.tick(victim), on_tick)]
            outsider.wait_matching([keys.done(victim)], WAIT_S)
            summary = sim.run(TICKS, seed=SEED, policy="random")
            assert forged.is_set(), "the victim was never opened a tick after its first report"
            want = {"bad_mac": 2, "wrong_tick": 1}
            sim.transport.dispatch(until=lambda: sim.transport.rejections.counts == want, timeout=WAIT_S)
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()
            outsider.close()
    assert model_part(summary) == clean


@pytest.mark.zenoh
def test_ticks_from_anyone_but_the_holder_change_nothing(tmp_path, aot1):
    """A served simulation: a stop and a run tick without the clock's MAC, published before a driver claims it,
    and once that driver released the clock, a stop with its key of its epoch (the orchestrator has moved on to
    a new epoch and told the processes so), change nothing: each process counts them, and the next driver plays
    the episode a local one plays."""
    run = Launch("aot1", "--serve", "--episodes", "0", "--layout", "per-node", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    children = run.descendants()
    endpoint, sim_id = served(run)
    keys = Keys(sim_id)
    n = len(ProcessLayout(aot1, "per-node").procs)
    local = model_part(Simulation.inproc(load_scenario("aot1")).run(30, seed=6))  # as launch names it

    first = ZenohTransport.client(endpoint)  # publishes before it claims, on the session it drives with: in order
    first.publish(keys.tick(), Tick(0, 1, "stop"))
    first.publish(keys.tick(), Tick(0, 1, "run", expect={0: 1}))
    a = Simulation.attach(first, sim_id)
    assert model_part(a.run(30, seed=6)) == local
    assert a.clock.node_rejected() == {"bad_mac": 2 * n}
    held, epoch = a.clock.keyring, a.clock.epoch

    watcher = ZenohTransport.client(endpoint)
    fenced = threading.Event()

    def on_tick(sample) -> None:
        tick = codec.decode(sample.payload.to_bytes())
        if tick.command == "fence" and tick.epoch > epoch:
            fenced.set()

    watched = watcher.session.declare_subscriber(keys.tick(), on_tick)
    a.close()  # releases: the orchestrator holds the clock in a new epoch, and says so when it is idle
    assert fenced.wait(WAIT_S), "no fence after the release"
    watched.undeclare()
    watcher.close()

    second = ZenohTransport.client(endpoint)
    second.publish(keys.tick(), Tick(a.clock.episode, a.clock.tick + 1, "stop", epoch=epoch), held.clock_key(epoch))
    b = Simulation.attach(second, sim_id)
    assert b.clock.epoch > epoch
    assert model_part(b.run(30, seed=6)) == local
    assert b.clock.node_rejected() == {"bad_mac": 2 * n, "stale_epoch": n}
    b.close()

    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert not any("Traceback" in line for line in run.err), "".join(run.err)
    assert_all_gone(children)
