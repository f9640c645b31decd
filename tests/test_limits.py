"""Bounded inputs (node_runtime/runtime/limits.py): a payload larger than its kind of message may be is refused
before it is copied or decoded, counted as ``too_large``; Zenoh drops what is larger still; the queue of
received payloads is bounded, and holds the sender back rather than drop or grow."""

from __future__ import annotations

import threading

import msgpack
import pytest

from node_runtime.runtime import codec, limits
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch
from node_runtime.runtime.rejections import TOO_LARGE
from node_runtime.runtime.zenoh_bus import ReceiveQueue, ZenohTransport, free_port
from orchestrator.session import Simulation
from tests.conftest import model_part

TICKS, SEED = 120, 4
VICTIM = "node-rpi3_0"


def test_every_key_has_its_kind():
    keys = Keys("sim")
    kinds = {keys.tick(): limits.TICK, keys.tick("p"): limits.TICK, keys.tick("*"): limits.TICK,
             keys.done("p"): limits.REPORT, keys.done(): limits.REPORT, keys.host_done("g", "p"): limits.REPORT,
             keys.dones("g"): limits.REPORTS, keys.inbox("p"): limits.MAIL, keys.broadcasts("p"): limits.MAIL,
             keys.session(): limits.OTHER, keys.control(): limits.OTHER, keys.metrics(): limits.OTHER,
             keys.alive("p"): limits.OTHER, keys.events(): limits.OTHER}
    assert {key: limits.kind_of(key) for key in kinds} == kinds
    assert max(limits.LIMITS.values()) < limits.LINK_MAX < limits.QUEUE_BYTES


def test_a_payload_over_its_limit_is_refused_before_it_is_decoded():
    bomb = msgpack.packb([{}] * 2_000_000)  # 2 MB that would decode into 2 million dicts
    with pytest.raises(codec.CodecError, match="2000005 bytes, more than the 1048576") as refused:
        codec.decode(bomb, limits.payload_limit(Keys("sim").inbox("p")))
    assert refused.value.reason == TOO_LARGE
    message = Batch(0, 1, "p", [])
    assert codec.decode(codec.encode(message), 100) == message  # at its limit or under it: decoded


def test_the_receive_queue_holds_the_sender_back_and_drops_nothing():
    q = ReceiveQueue(budget=10)
    q.put((print, "a", b"x" * 6), 6)
    second_in = threading.Event()

    def second() -> None:
        q.put((print, "b", b"y" * 6), 6)  # 12 bytes would be over budget: waits for room
        second_in.set()

    sender = threading.Thread(target=second, daemon=True)
    sender.start()
    assert not second_in.wait(0.3)  # held back while the first is queued
    assert q.get(1.0)[1] == "a"
    assert second_in.wait(10)
    assert q.get(1.0)[1] == "b" and q.held == 0
    q.put((print, "c", b"z" * 50), 50)  # one payload over the budget passes alone
    assert q.get(1.0)[1] == "c"


@pytest.mark.zenoh
def test_a_full_receive_queue_holds_the_publisher_back_over_zenoh():
    """Zenoh's own thread waits while the receiving process's queue is full, so the publisher's blocking
    publications wait too; once dispatch catches up, every message arrives, in order. (zenoh-python's
    default, ``indirect`` callbacks, would have queued them all, without bound, in the receiver.) Held back
    longer than Zenoh's default 5 s before it closes a blocked link, nothing is lost: that wait follows the
    lease, as every session of a simulation sets it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    lease = {"transport/link/tx/lease": 15_000}
    router = ZenohTransport.router(endpoint, settings=lease)
    receiver, sender = ZenohTransport.client(endpoint, settings=lease), ZenohTransport.client(endpoint, settings=lease)
    receiver._queue.budget = 2 * limits.MIB
    got: list[int] = []
    try:
        receiver.subscribe("t/inbox", lambda key, message: got.append(message["n"]))
        sender.wait_matching(["t/inbox"], 30)
        pad = "x" * (limits.MIB // 2)
        sent = threading.Event()

        def flood() -> None:
            for n in range(40):  # 20 MiB, ten times the budget
                sender.publish("t/inbox", {"type": "pad", "n": n, "pad": pad})
            sent.set()

        threading.Thread(target=flood, daemon=True).start()
        assert not sent.wait(6.0)  # nobody dispatches: the sender is held back, past Zenoh's default 5 s
        assert receiver._queue.held <= receiver._queue.budget
        receiver.dispatch(until=lambda: len(got) == 40, timeout=60)
        assert sent.wait(30) and got == list(range(40))
    finally:
        for transport in (sender, receiver, router):
            transport.close()


def peak_rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))


@pytest.mark.zenoh
def test_a_message_bomb_on_an_inbox_is_refused_at_a_few_mb(aot1):
    """A 50 MB msgpack array of empty maps on a node process's inbox made it use 3.7 GiB. Now Zenoh drops it
    (over LINK_MAX), a 4 MB batch of nested empty arrays is refused unread (over the inbox's limit) and
    counted, the process's peak memory grows by a few MB at most, and the run's results are a clean run's."""
    clean = model_part(Simulation.inproc(aot1).run(TICKS, seed=SEED, policy="random"))
    with Simulation.over_zenoh(aot1, layout="per-node") as sim:
        keys = sim.keys
        pid = sim.supervisor.children[VICTIM]
        report = sim.reset(SEED, policy="random")
        before = peak_rss_kib(pid)
        outsider = ZenohTransport.client(sim.endpoint)
        try:
            inbox = keys.inbox(VICTIM)
            outsider.wait_matching([inbox], 30)
            outsider.put(inbox, msgpack.packb([{}] * 50_000_000))
            nested = codec.to_wire(Batch(0, report.tick, "intruder", []))
            nested["msgs"] = [[[]] * 1000] * 4000  # 4 MB, 4 million arrays once decoded
            outsider.put(inbox, msgpack.packb({**nested, "v": SCHEMA_VERSION}))
            outsider.put(inbox, b"\xc1 after the bombs")  # the same publisher's: delivered after them
        finally:
            outsider.close()
        while report.tick < TICKS - 1:
            report = sim.step()
        summary = sim.summary()
        after = peak_rss_kib(pid)
    assert model_part(summary) == clean
    assert summary["run"]["rejected_messages"]["nodes"] == {TOO_LARGE: 1, "bad_msgpack": 1}
    assert after - before < 8 * 1024, f"peak memory of {VICTIM} grew from {before} KiB to {after} KiB"
