"""The Transport interface, run against both implementations: the in-process bus and Zenoh on loopback.

Serving, the monitor and the node processes use nothing but this interface, so each behaviour they
rely on is checked here once per transport. Every wait is on a message, a token or a matching
status, with a timeout that fails loudly.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest

from node_runtime.runtime.inproc import InprocBus
from node_runtime.runtime.protocol import SCHEMA_VERSION
from node_runtime.runtime.transport import Transport, TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport, free_port
from tests.launcher import TIMEOUT


@pytest.fixture(params=["inproc", pytest.param("zenoh", marks=pytest.mark.zenoh)])
def connect(request) -> Iterator[Callable[[], Transport]]:
    """Opens endpoints of one bus. Over Zenoh the first is a router (as an orchestrator's is) and the
    others are its clients."""
    opened: list[Transport] = []
    if request.param == "inproc":
        bus = InprocBus()
        make = bus.endpoint
    else:
        endpoint = f"tcp/127.0.0.1:{free_port()}"

        def make() -> Transport:
            return ZenohTransport.router(endpoint) if not opened else ZenohTransport.client(endpoint)

    def open_one() -> Transport:
        opened.append(make())
        return opened[-1]

    yield open_one
    for transport in reversed(opened):
        transport.close()


def test_requests_are_answered_by_whoever_serves_the_key(connect):
    hub, client = connect(), connect()
    asked = []

    def answer(message: dict) -> dict:
        asked.append(message)
        return {"type": "answer", "n": message["n"] + 1}

    hub.serve("t/a/session", answer)
    v = SCHEMA_VERSION  # every message carries it
    assert client.request("t/a/session", {"type": "question", "n": 1}, TIMEOUT) == {"type": "answer", "n": 2, "v": v}
    assert client.request("t/*/session", {"type": "question", "n": 5}, TIMEOUT)["n"] == 6  # a wildcard asks all
    assert asked == [{"type": "question", "n": 1, "v": v}, {"type": "question", "n": 5, "v": v}]
    with pytest.raises(TransportError, match="t/b/session"):
        client.request("t/b/session", {"type": "question", "n": 1}, 1.0)


def test_tokens_are_listed_watched_and_vanish_with_their_endpoint(connect):
    hub, watcher, holder = connect(), connect(), connect()
    seen: list[tuple[str, bool]] = []
    watcher.watch_tokens("t/*/alive/*", lambda key, alive: seen.append((key, alive)))
    holder.declare_token("t/x/alive/one")
    watcher.dispatch(until=lambda: ("t/x/alive/one", True) in seen, timeout=TIMEOUT)
    assert hub.tokens("t/*/alive/*", TIMEOUT) == ["t/x/alive/one"]
    assert hub.tokens("t/y/alive/*", TIMEOUT) == []
    holder.close()
    watcher.dispatch(until=lambda: ("t/x/alive/one", False) in seen, timeout=TIMEOUT)
    assert seen == [("t/x/alive/one", True), ("t/x/alive/one", False)]
    assert hub.tokens("t/*/alive/*", TIMEOUT) == []


def test_wait_matching_then_every_publication_arrives_in_dispatch(connect):
    hub, client = connect(), connect()
    got: list[dict] = []
    client.subscribe("t/x/data", lambda key, message: got.append(message))
    hub.wait_matching(["t/x/data"], TIMEOUT)
    for n in range(3):
        hub.publish("t/x/data", {"type": "data", "n": n})
    client.dispatch(until=lambda: len(got) == 3, timeout=TIMEOUT)
    assert [m["n"] for m in got] == [0, 1, 2]
    with pytest.raises(TransportError, match="t/x/nobody"):
        hub.wait_matching(["t/x/data", "t/x/nobody"], 1.0)


def test_closing_an_endpoint_ends_its_subscriptions(connect):
    hub, client = connect(), connect()
    monitored = hub.monitored("t/x/metrics")
    assert not monitored.listened
    client.subscribe("t/x/metrics", lambda key, message: None)
    hub.dispatch(until=lambda: monitored.listened, timeout=TIMEOUT)
    client.close()
    hub.dispatch(until=lambda: not monitored.listened, timeout=TIMEOUT)


@pytest.mark.zenoh
def test_a_stall_in_a_handler_does_not_count_against_a_wait():
    """Time this process stood still does not count against a wait for others (they were not silent): a stall
    in a handler (here one that sleeps 2 s; in the orchestrator, SIGSTOP while it handles a report at hundreds
    of ticks a second) used not to count as one, so its wait for the other reports ended at once and it
    blamed them. The wait goes on for its 1 s after the stall, and ends with a timeout."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = ZenohTransport.router(endpoint)
    client = ZenohTransport.client(endpoint)
    try:
        got: list[float] = []
        client.subscribe("t/x/data", lambda key, message: (time.sleep(2), got.append(time.monotonic())))
        hub.wait_matching(["t/x/data"], TIMEOUT)
        hub.publish("t/x/data", {"type": "data", "n": 0})
        started = time.monotonic()
        with pytest.raises(TimeoutError):
            client.dispatch(until=lambda: False, timeout=1.0)
        assert len(got) == 1 and time.monotonic() - got[0] >= 0.9, f"ended {time.monotonic() - got[0]:.2f} s after"
        assert time.monotonic() - started >= 2.9
    finally:
        client.close()
        hub.close()
