"""The in-process transport: an in-memory bus shared by endpoints living in one process.

Delivery is synchronous and in publication order: ``publish`` queues the message for every
matching subscriber and, unless a delivery is already running, delivers until the queue is empty.
Messages are passed as objects (no encoding), which is what makes this path fast; a sealed one
(``origin``) carries a MAC over who sent it for which tick, since its content cannot change on the way. Requests, rare
and never on the tick path, do go through the codec and its size limits (limits.py), so that an answer
is a copy with the types it would have over Zenoh. Nothing here is thread-safe: one thread owns the bus.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from node_runtime.runtime import codec, origin
from node_runtime.runtime.limits import payload_limit
from node_runtime.runtime.rejections import Rejections
from node_runtime.runtime.transport import (
    Handler,
    Monitored,
    Refused,
    RequestHandler,
    TokenHandler,
    Transport,
    TransportError,
)


def key_matches(a: str, b: str) -> bool:
    """Whether two Zenoh key expressions intersect, with ``*`` (one chunk) and ``**`` (any number of
    chunks) on either side: a subscription and a key, or a wildcard publisher used to detect listeners."""
    return _intersect(tuple(a.split("/")), tuple(b.split("/")))


def _intersect(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a or not b:
        return all(c == "**" for c in a + b)
    if a[0] == "**":
        return _intersect(a[1:], b) or _intersect(a, b[1:])
    if b[0] == "**":
        return _intersect(a, b[1:]) or _intersect(a[1:], b)
    return (a[0] == b[0] or a[0] == "*" or b[0] == "*") and _intersect(a[1:], b[1:])


class _ByPrefix:
    """Wildcard key expressions filed under their literal prefix (the chunks before the first wildcard),
    so that an exact key meets only those it could match: set-up stays near-linear in the node count."""

    def __init__(self) -> None:
        self._items: dict[str, list[tuple[str, Any]]] = {}

    def add(self, key: str, item: Any) -> None:
        chunks = key.split("/")
        n = next((i for i, c in enumerate(chunks) if "*" in c), len(chunks))
        self._items.setdefault("/".join(chunks[:n]), []).append((key, item))

    def matching(self, expr: str) -> list[Any]:
        """The items whose key intersects ``expr``."""
        if "*" in expr:
            candidates = [entry for entries in self._items.values() for entry in entries]
        else:
            chunks = expr.split("/")
            candidates = [e for k in range(len(chunks) + 1) for e in self._items.get("/".join(chunks[:k]), ())]
        return [item for key, item in candidates if key_matches(expr, key)]


class InprocBus:
    def __init__(self) -> None:
        self._subs: list[tuple[str, Handler]] = []
        # the same subscriptions, indexed: exact keys by key, wildcards in a list, each with its place in _subs
        self._exact: dict[str, list[tuple[int, Handler]]] = {}
        self._wild: list[tuple[int, str, Handler]] = []
        self._routes: dict[str, list[Handler]] = {}  # key -> handlers in subscription order (cache)
        self._wild_routes = _ByPrefix()  # the cached routes of wildcard keys (a monitor asking who listens)
        self._watchers: list[tuple[str, TokenHandler]] = []
        self._tokens: set[str] = set()
        self._queue: deque[tuple[Callable[..., None], tuple]] = deque()
        self._delivering = False
        self._monitors: list[InprocMonitor] = []
        self._unheard = _ByPrefix()  # monitors that nobody listened to yet
        self._served: dict[str, RequestHandler] = {}

    def endpoint(self) -> InprocEndpoint:
        return InprocEndpoint(self)

    def _handlers(self, key: str) -> list[Handler]:
        hs = self._routes.get(key)
        if hs is None:
            if "*" in key:
                found = [(i, h) for i, (expr, h) in enumerate(self._subs) if key_matches(expr, key)]
                self._wild_routes.add(key, key)
            else:
                found = self._exact.get(key, []) + [(i, h) for i, expr, h in self._wild if key_matches(expr, key)]
            hs = self._routes[key] = [h for _, h in sorted(found, key=lambda item: item[0])]
        return hs

    def _post(self, fn: Callable[..., None], *args: Any) -> None:
        self._queue.append((fn, args))
        if not self._delivering:
            self._deliver()

    def _deliver(self) -> None:
        self._delivering = True
        try:
            while self._queue:
                fn, args = self._queue.popleft()
                fn(*args)
        finally:
            self._delivering = False

    def publish(self, key: str, message: Any) -> None:
        for h in self._handlers(key):
            self._queue.append((h, (key, message)))
        if not self._delivering:
            self._deliver()

    def subscribe(self, key_expr: str, handler: Handler) -> tuple[str, Handler]:
        """Returns the subscription, to ``drop`` it later. The newest subscription comes last in every
        route, so the cached routes and monitors are extended, not recomputed (set-up stays linear in N)."""
        sub = (key_expr, handler)
        self._index(len(self._subs), sub)
        self._subs.append(sub)
        routes = self._wild_routes.matching(key_expr)
        if "*" in key_expr:
            routes += [key for key in self._routes if "*" not in key and key_matches(key_expr, key)]
        elif key_expr in self._routes:
            routes.append(key_expr)
        for key in routes:
            self._routes[key].append(handler)
        for monitor in self._unheard.matching(key_expr):
            monitor.listened = True
        return sub

    def _index(self, i: int, sub: tuple[str, Handler]) -> None:
        expr, handler = sub
        if "*" in expr:
            self._wild.append((i, expr, handler))
        else:
            self._exact.setdefault(expr, []).append((i, handler))

    def drop(self, subs: list[tuple[str, Handler]], watchers: list[tuple[str, TokenHandler]]) -> None:
        """Remove these subscriptions and token watchers (the very objects returned when declared)."""
        gone = {id(x) for x in subs + watchers}
        self._subs = [s for s in self._subs if id(s) not in gone]
        self._watchers = [w for w in self._watchers if id(w) not in gone]
        self._exact, self._wild = {}, []
        for i, sub in enumerate(self._subs):
            self._index(i, sub)
        self._routes.clear()
        self._wild_routes, self._unheard = _ByPrefix(), _ByPrefix()
        for monitor in self._monitors:
            self._watch_listeners(monitor)

    def unmatched(self, keys: list[str]) -> list[str]:
        return [key for key in keys if not self._handlers(key)]

    def monitored(self, key: str) -> InprocMonitor:
        monitor = InprocMonitor(self, key)
        self._monitors.append(monitor)
        self._watch_listeners(monitor)
        return monitor

    def _watch_listeners(self, monitor: InprocMonitor) -> None:
        monitor.listened = bool(self._handlers(monitor.key))
        if not monitor.listened:
            self._unheard.add(monitor.key, monitor)

    def token(self, key: str, alive: bool) -> None:
        (self._tokens.add if alive else self._tokens.discard)(key)
        for expr, h in self._watchers:
            if key_matches(expr, key):
                self._post(h, key, alive)

    def watch(self, key_expr: str, handler: TokenHandler) -> tuple[str, TokenHandler]:
        watcher = (key_expr, handler)
        self._watchers.append(watcher)
        for key in sorted(self._tokens):
            if key_matches(key_expr, key):
                self._post(handler, key, True)
        return watcher

    def alive(self, key_expr: str) -> list[str]:
        return sorted(key for key in self._tokens if key_matches(key_expr, key))

    def serve(self, key: str, handler: RequestHandler) -> None:
        if key in self._served:
            raise TransportError(f"{key} is already served on this in-process bus")
        self._served[key] = handler

    def unserve(self, key: str) -> None:
        del self._served[key]

    def request(self, key_expr: str, message: Any) -> Any:
        """The answer of the first served key (in key order) matching ``key_expr``."""
        for key in sorted(self._served):
            if key_matches(key_expr, key):
                limit = payload_limit(key)
                answer = self._served[key](codec.decode(codec.encode(message), limit))
                return codec.decode(codec.encode(answer), limit)
        raise TransportError(f"nobody serves {key_expr} on the in-process bus")


class InprocMonitor(Monitored):
    def __init__(self, bus: InprocBus, key: str) -> None:
        self.bus = bus
        self.key = key
        self.listened = False  # kept up to date by the bus

    def put(self, message: Any) -> None:
        self.bus.publish(self.key, message)


class InprocEndpoint(Transport):
    def __init__(self, bus: InprocBus) -> None:
        self.bus = bus
        self._tokens: list[str] = []
        self._subs: list[tuple[str, Handler]] = []
        self._watchers: list[tuple[str, TokenHandler]] = []
        self._served: list[str] = []
        self.rejections = Rejections()

    def publish(self, key: str, message: Any, seal: bytes | None = None) -> None:
        if seal is not None:  # the object never leaves this process: its MAC covers who sent it (origin.identity)
            origin.seal(message, seal)
        self.bus.publish(key, message)

    def subscribe(self, key_expr: str, handler: Handler) -> None:
        self._subs.append(self.bus.subscribe(key_expr, handler))

    def wait_matching(self, keys: list[str], timeout: float) -> None:
        """Returns or raises at once: on a bus owned by one thread, nobody can subscribe meanwhile."""
        missing = self.bus.unmatched(keys)
        if missing:
            raise TransportError(f"no subscriber on the in-process bus for: {', '.join(sorted(missing))}")

    def declare_token(self, key: str) -> None:
        self._tokens.append(key)
        self.bus.token(key, True)

    def watch_tokens(self, key_expr: str, handler: TokenHandler) -> None:
        self._watchers.append(self.bus.watch(key_expr, handler))

    def tokens(self, key_expr: str, timeout: float) -> list[str]:
        return self.bus.alive(key_expr)

    def serve(self, key: str, handler: RequestHandler) -> None:
        def answer(message: Any) -> Any:
            try:
                return handler(message)
            except Refused as exc:  # the asker gets it raised, as a Zenoh error reply raises it there
                self.rejections.add(key, exc.reason, exc.why)
                raise TransportError(f"{key} refused the request: {exc.why}") from None

        self.bus.serve(key, answer)
        self._served.append(key)

    def request(self, key: str, message: Any, timeout: float) -> Any:
        return self.bus.request(key, message)

    def dispatch(self, until: Callable[[], bool], timeout: float | None = None,
                 idle: Callable[[], None] | None = None) -> None:
        if self.bus._queue and not self.bus._delivering:
            self.bus._deliver()
        if not until():
            raise TransportError("in-process bus is idle but the awaited condition does not hold")

    def monitored(self, key: str) -> InprocMonitor:
        return self.bus.monitored(key)

    def close(self) -> None:
        """Undeclare what this endpoint declared, as closing a Zenoh session does."""
        for key in self._served:
            self.bus.unserve(key)
        self._served.clear()
        if self._subs or self._watchers:
            self.bus.drop(self._subs, self._watchers)
            self._subs.clear()
            self._watchers.clear()
        for key in self._tokens:
            self.bus.token(key, False)
        self._tokens.clear()
