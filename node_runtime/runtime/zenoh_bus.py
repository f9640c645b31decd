"""The Zenoh transport: one session per process, star-shaped around a router (docs/protocol.md, "Process life").

Node processes open ``client`` sessions to the router the orchestrator runs; multicast scouting is
off and endpoints are explicit. Publications are reliable with blocking congestion control (the
emulation must never lose a message to back-pressure); see ``reliable_publisher``.
Zenoh callbacks only enqueue raw bytes, of a bounded size and in a bounded queue (limits.py); decoding and
handlers run in the ``dispatch`` thread.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import socket
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any, Literal

import zenoh

from node_runtime.runtime import codec
from node_runtime.runtime.limits import LINK_MAX, QUEUE_BYTES, payload_limit
from node_runtime.runtime.rejections import SEVERAL_ANSWERS, Rejections
from node_runtime.runtime.security import Security
from node_runtime.runtime.transport import (
    Contested,
    Handler,
    Monitored,
    Refused,
    RequestHandler,
    TokenHandler,
    Transport,
    TransportError,
)

Mode = Literal["router", "client", "peer"]
ENDPOINT = re.compile(r"^[a-z0-9]+/\S+$")  # Zenoh's <protocol>/<address>
IDLE_SLICE = 0.1  # seconds between idle checks while dispatching
ROOM_POLL_S = 0.002  # how often a Zenoh thread held back by a full receive queue looks for room
STALL_S = 1.0  # seconds a wait in ``dispatch`` may overrun its slice before this process counts as stalled

# Zenoh's thread pools for a node process: receive, network and transmit work handed over to a
# single application thread. Dozens of processes share two cores here, and fewer threads per process
# measured 25-35 % more ticks/s for the bare barrier (19 and 46 processes). A user's own
# ZENOH_RUNTIME setting wins.
LEAN_RUNTIME = "(rx: (handover: app), app: (worker_threads: 1), net: (handover: app), tx: (handover: app))"


LEASE = "transport/link/tx/lease"  # ms: a session silent this long is gone
# µs a reliable, blocking publication may wait for room before Zenoh closes the link (its default: 5 s)
WAIT_BEFORE_CLOSE = "transport/link/tx/queue/congestion_control/block/wait_before_close"


def use_lean_runtime() -> None:
    """Call before the first Zenoh session of this process opens."""
    os.environ.setdefault("ZENOH_RUNTIME", LEAN_RUNTIME)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def zenoh_config(mode: Mode, listen: list[str] | None = None, connect: list[str] | None = None,
                 security: Security | None = None, settings: dict[str, Any] | None = None) -> zenoh.Config:
    """``security``: TLS and login (node_runtime/runtime/security.py); ``settings`` (path -> value), applied
    last: e.g. a router's access control, a user's Zenoh configuration file."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    # Messages here are a few hundred bytes, where shared memory saves nothing; and each session that
    # negotiates it keeps a /dev/shm segment open after close and takes one of the router's SHM slots
    cfg.insert_json5("transport/shared_memory/enabled", "false")
    # Zenoh drops a larger message as it reassembles it, in a router and in a session (limits.py)
    cfg.insert_json5("transport/link/rx/max_message_size", json.dumps(LINK_MAX))
    if listen:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    merged = {**(security.settings() if security else {}), **(settings or {})}
    if LEASE in merged:  # a link blocked by a full receiver (limits.py) closes no sooner than a silent one
        merged.setdefault(WAIT_BEFORE_CLOSE, merged[LEASE] * 1000)
    for path, value in merged.items():
        cfg.insert_json5(path, json.dumps(value))
    return cfg


def reliable_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """How every protocol message is published: reliable, and blocking rather than dropping under
    back-pressure. Not ``express``: Zenoh sends at once when the link is idle either way, but a message that
    queues behind another (a process's batches, then its ``Done``; replies reaching the router together)
    then shares its write, where express ones take one write each. Measured on aot2 ``per-node``: ×1.08–1.11
    env steps/s, and the same bare barrier (whose processes send one message a tick)."""
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK, express=False,
                                     reliability=zenoh.Reliability.RELIABLE)


def close_session(session: zenoh.Session, grace: float = 5.0) -> None:
    """Close a session, but never let a stuck close hang the process."""
    done = threading.Event()

    def closer() -> None:
        try:
            session.close()
        finally:
            done.set()

    threading.Thread(target=closer, daemon=True).start()
    if not done.wait(grace):
        raise TransportError(f"zenoh session did not close within {grace:.0f} s")


_OPEN: weakref.WeakSet[ZenohTransport] = weakref.WeakSet()  # sessions not closed yet


def _close_open_sessions() -> None:
    """zenoh-python runs callbacks in threads that are not daemons, so a session left open (a script that
    raised, or never closed its environment) would keep the interpreter from exiting, forever. This runs as
    the interpreter begins to exit, before it waits for those threads."""
    for transport in list(_OPEN):
        with contextlib.suppress(Exception):
            transport.close()


# the hook concurrent.futures uses for its own worker threads: atexit would run only after the wait
getattr(threading, "_register_atexit", lambda f: None)(_close_open_sessions)


class ReceiveQueue:
    """What Zenoh's threads received, waiting for ``dispatch``: at most ``budget`` bytes of payloads. Past that
    the receiving Zenoh thread waits for dispatch to catch up, which backs up to the publisher (whose reliable,
    blocking publication waits in turn) rather than drop a message or grow without bound. A single payload
    larger than the budget (limits.py keeps them below it) passes alone. Only a sender waits, polling: taking
    costs the dispatch thread one addition (it alone writes ``taken``)."""

    def __init__(self, budget: int = QUEUE_BYTES) -> None:
        self.budget = budget
        self.given = 0  # bytes put, by Zenoh's threads (one at a time)
        self.taken = 0  # bytes taken, by the dispatch thread
        self._items: queue.SimpleQueue[tuple[tuple[Callable[..., None], str, Any], int]] = queue.SimpleQueue()
        self._senders = threading.Lock()
        self.closed = False

    @property
    def held(self) -> int:
        return self.given - self.taken

    def put(self, item: tuple[Callable[..., None], str, Any], size: int = 0) -> None:
        if size:
            with self._senders:
                while self.given > self.taken and self.given - self.taken + size > self.budget and not self.closed:
                    time.sleep(ROOM_POLL_S)
                self.given += size
        self._items.put((item, size))

    def get(self, timeout: float) -> tuple[Callable[..., None], str, Any]:
        """Raises ``queue.Empty`` after ``timeout`` seconds."""
        item, size = self._items.get(timeout=timeout)
        self.taken += size
        return item

    def close(self) -> None:
        """Release the Zenoh threads that wait for room, so that the session can close."""
        self.closed = True


class ZenohTransport(Transport):
    def __init__(self, config: zenoh.Config) -> None:
        self.session = zenoh.open(config)
        _OPEN.add(self)
        self._queue = ReceiveQueue()
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._entities: list[Any] = []
        self._closed = False
        self.rejections = Rejections()

    @classmethod
    def router(cls, endpoint: str, connect: list[str] | None = None, security: Security | None = None,
               settings: dict[str, Any] | None = None) -> ZenohTransport:
        """A router listening on ``endpoint``; ``connect``: other routers to join into one network."""
        return cls(zenoh_config("router", listen=[endpoint], connect=connect, security=security, settings=settings))

    @classmethod
    def client(cls, endpoint: str, security: Security | None = None,
               settings: dict[str, Any] | None = None) -> ZenohTransport:
        return cls(zenoh_config("client", connect=[endpoint], security=security, settings=settings))

    @classmethod
    def reach(cls, endpoint: str, security: Security | None = None,
              settings: dict[str, Any] | None = None) -> ZenohTransport:
        """``client``, for an endpoint a user gave: a TransportError that names it, rather than Zenoh's own
        error, when it is no endpoint or no router answers there."""
        if not ENDPOINT.match(endpoint):
            raise TransportError(f"{endpoint!r} is no Zenoh endpoint: expected <protocol>/<address>, such as "
                                 "tcp/10.0.0.1:7447")
        try:
            return cls.client(endpoint, security, settings)
        except zenoh.ZError:
            refused = " or it refused this certificate or login" if security is not None else ""
            raise TransportError(f"cannot reach {endpoint}: no Zenoh router answers there{refused}") from None

    def publish(self, key: str, message: Any, seal: bytes | None = None) -> None:
        self.put(key, codec.encode(message, seal))

    def put(self, key: str, payload: bytes) -> None:
        pub = self._pubs.get(key) or self.put_publisher(key)
        pub.put(payload)

    def put_publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = reliable_publisher(self.session, key)
        return pub

    def wait_matching(self, keys: list[str], timeout: float) -> None:
        """Blocks on matching listeners: Zenoh filters a publication out until it knows a subscriber."""
        matched: queue.SimpleQueue[str] = queue.SimpleQueue()
        listeners = []
        missing = set()
        for key in keys:
            self.put_publisher(key)
            pub = self._pubs[key]
            if pub.matching_status.matching:
                continue
            missing.add(key)
            listeners.append(pub.declare_matching_listener(
                lambda status, key=key: status.matching and matched.put(key)))
            if pub.matching_status.matching:
                matched.put(key)
        deadline = time.monotonic() + timeout
        try:
            while missing:
                try:
                    missing.discard(matched.get(timeout=max(0.0, deadline - time.monotonic())))
                except queue.Empty:
                    raise TransportError(f"no subscriber appeared within {timeout:.0f} s for: "
                                         f"{', '.join(sorted(missing))}") from None
        finally:
            for listener in listeners:
                listener.undeclare()

    # ----- request / reply (session description, control) -----

    def serve(self, key: str, handler: RequestHandler) -> None:
        """A queryable; ``handler`` runs in a Zenoh thread."""

        limit = payload_limit(key)

        def on_query(query: zenoh.Query) -> None:  # answer on our own key: a wildcard query learns who answered
            try:
                payload = query.payload
                if payload is not None:
                    codec.check_size(len(payload), limit)
                message = codec.decode(payload.to_bytes()) if payload is not None else None
                answer = codec.encode(handler(message))
            except (codec.CodecError, Refused) as exc:  # plain text: the asker may not read our msgpack either
                self.rejections.add(key, exc.reason, str(exc))
                query.reply_err(str(exc).encode())
                return
            query.reply(key, answer)

        self._entities.append(self.session.declare_queryable(key, on_query))

    def request(self, key: str, message: Any, timeout: float) -> Any:
        """Ask every session that serves ``key``, and wait for all their answers (Zenoh ends the query when each
        has answered, or after ``timeout``). Anyone on the router can declare a queryable: when two sessions
        answer for one key, which one is the simulation cannot be told, so none is believed (``Contested``)."""
        replies = list(self.session.get(key, payload=codec.encode(message), timeout=timeout,
                                        target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE))
        by_key: dict[str, set[str]] = {}  # answered key -> the sessions that answered it
        for reply in replies:
            replier = str(reply.replier_id.zid) if reply.replier_id is not None else "an unknown session"
            by_key.setdefault(str(reply.ok.key_expr) if reply.ok is not None else key, set()).add(replier)
        for answered, repliers in sorted(by_key.items()):
            if len(repliers) > 1:
                why = (f"{answered} was answered by {len(repliers)} Zenoh sessions ({', '.join(sorted(repliers))}): "
                       "another session serves this simulation's keys, so no answer is believed")
                self.rejections.add(answered, SEVERAL_ANSWERS, why)
                raise Contested(why)
        refused = ""
        for reply in replies:
            if reply.ok is not None:
                codec.check_size(len(reply.ok.payload), payload_limit(key))
                return codec.decode(reply.ok.payload.to_bytes())
            refused = reply.err.payload.to_bytes().decode(errors="replace")
        if refused:
            raise TransportError(f"{key} refused the request: {refused}")
        raise TransportError(f"no answer from {key} within {timeout:.0f} s")

    # ----- best-effort publications for monitors -----

    def monitored(self, key: str) -> MonitorPublisher:
        """A publisher that drops rather than blocks, and knows whether anyone listens."""
        pub = MonitorPublisher(self.session, key)
        self._entities.append(pub)
        return pub

    def subscribe(self, key_expr: str, handler: Handler) -> None:
        """A payload larger than its kind may be (limits.py) is refused here, before it is copied out of Zenoh."""
        put, limit, rejections = self._queue.put, payload_limit(key_expr), self.rejections

        def on_sample(sample: zenoh.Sample) -> None:
            payload = sample.payload
            size = len(payload)
            try:
                codec.check_size(size, limit)
            except codec.CodecError as exc:
                rejections.add(str(sample.key_expr), exc.reason, str(exc))
                return
            put((handler, str(sample.key_expr), payload.to_bytes()), size)

        # not ``indirect``: zenoh-python would run it in a thread of its own, fed by a queue without bound,
        # and a full ReceiveQueue would hold back nobody (measured: 100 MB held by a slow subscriber)
        callback = zenoh.handlers.Callback(on_sample, indirect=False)
        self._entities.append(self.session.declare_subscriber(key_expr, callback))

    def declare_token(self, key: str) -> None:
        self._entities.append(self.session.liveliness().declare_token(key))

    def watch_tokens(self, key_expr: str, handler: TokenHandler) -> None:
        q = self._queue

        def on_token(sample: zenoh.Sample) -> None:
            q.put((handler, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

        self._entities.append(self.session.liveliness().declare_subscriber(key_expr, on_token, history=True))

    def tokens(self, key_expr: str, timeout: float) -> list[str]:
        """A liveliness query. With zenoh 1.10.2 one sent right after declaring a liveliness subscriber
        on the same keys may miss tokens (docs/bus.md): watch them instead in that case."""
        replies = self.session.liveliness().get(key_expr, timeout=timeout)
        return sorted({str(reply.ok.key_expr) for reply in replies if reply.ok is not None})

    def dispatch(self, until: Callable[[], bool], timeout: float | None = None,
                 idle: Callable[[], None] | None = None) -> None:
        """A time this process stood still (SIGSTOP, a starved machine) does not count against ``timeout``: what
        others sent meanwhile waits in buffers, and they were not silent. That is any time it did not look at
        the queue for more than ``STALL_S``, whether it stood still waiting on it or running a handler."""
        deadline = None if timeout is None else time.monotonic() + timeout
        get = self._queue.get
        looked = time.monotonic()  # when the last wait on the queue ended
        while not until():
            wait = IDLE_SLICE
            now = time.monotonic()
            if deadline is not None:
                if (late := now - looked) > STALL_S:  # stood still in a handler, ``until`` or ``idle``
                    deadline += late
                left = deadline - now
                if left <= 0:
                    raise TimeoutError(f"nothing satisfied the wait within {timeout:.1f} s")
                wait = min(wait, left)
            try:
                handler, key, data = get(timeout=wait)
            except queue.Empty:
                handler = None
            looked = time.monotonic()
            if deadline is not None and (late := looked - now - wait) > STALL_S:
                deadline += late
            if handler is None:
                if idle is not None:
                    idle()
                continue
            if isinstance(data, bytes):
                try:
                    data = codec.decode(data)
                except codec.CodecError as exc:
                    self.rejections.add(key, exc.reason, str(exc))
                    continue
            handler(key, data)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._queue.close()
        for entity in reversed(self._entities):
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
        self._entities.clear()
        self._pubs.clear()
        close_session(self.session)


class MonitorPublisher(Monitored):
    """For traffic nobody in the barrier waits for (metrics, events): never blocks the emulation, and
    ``listened`` (kept current by a matching listener) lets callers skip building unwanted messages."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
        self.listened = self.publisher.matching_status.matching
        self._listener = self.publisher.declare_matching_listener(self._on_matching)

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        self.listened = status.matching

    def put(self, message: Any) -> None:
        self.publisher.put(codec.encode(message))

    def undeclare(self) -> None:
        self._listener.undeclare()
        self.publisher.undeclare()
