"""The transport interface: keyed publish/subscribe, liveliness, request/reply, and a dispatch loop.

Two implementations share it: ``ZenohTransport`` (a Zenoh session) and ``InprocBus`` endpoints (an
in-memory bus inside one process). Subscription and token handlers always run in the thread that
calls ``dispatch``, so protocol code never needs locks and behaves the same on both. Request
handlers (``serve``) are the exception: a simulation must answer ``…/session`` while its owner is
busy elsewhere, so they run outside ``dispatch`` (see ``serve``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any

from node_runtime.runtime.rejections import Rejections

Handler = Callable[[str, Any], None]
TokenHandler = Callable[[str, bool], None]  # (key, alive)
RequestHandler = Callable[[Any], Any]  # request message -> answer


class TransportError(RuntimeError):
    pass


class Refused(TransportError):
    """Raised by a request handler (``serve``) for a request it will not answer: the asker gets an error
    reply saying ``why``, and the serving side counts and logs it under ``reason`` (rejections.py)."""

    def __init__(self, reason: str, why: str) -> None:
        super().__init__(why)
        self.reason = reason
        self.why = why


class Contested(TransportError):
    """Several sessions answered one request for the same key (``Transport.request``)."""


class Transport(ABC):
    rejections: Rejections  # messages refused: undecodable ones by ``dispatch``, untrusted ones by handlers

    @abstractmethod
    def publish(self, key: str, message: Any, seal: bytes | None = None) -> None:
        """Send ``message`` to every subscriber of ``key``; reliable, ordered per publisher. ``seal``: the
        sender's key, for a tick, done or dones that must prove its origin (``origin``)."""

    @abstractmethod
    def subscribe(self, key_expr: str, handler: Handler) -> None:
        """Call ``handler(key, message)`` (from ``dispatch``) for every message matching ``key_expr``."""

    @abstractmethod
    def wait_matching(self, keys: list[str], timeout: float) -> None:
        """Return once a subscriber is known for each key, so that no first publication is lost; raise
        ``TransportError`` naming the keys still unmatched after ``timeout`` seconds."""

    @abstractmethod
    def declare_token(self, key: str) -> None:
        """Announce presence; the token vanishes when this endpoint closes or its process dies."""

    @abstractmethod
    def watch_tokens(self, key_expr: str, handler: TokenHandler) -> None:
        """Be told (from ``dispatch``) of tokens appearing and vanishing, current ones included."""

    @abstractmethod
    def tokens(self, key_expr: str, timeout: float) -> list[str]:
        """The keys of the tokens alive now that match ``key_expr``, sorted (waits at most ``timeout``)."""

    @abstractmethod
    def serve(self, key: str, handler: RequestHandler) -> None:
        """Answer every request on ``key`` with ``handler(message)``, until this endpoint closes.

        The handler does not run in ``dispatch``: over Zenoh it runs in a Zenoh thread, in-process in
        the requester's ``request`` call. It may thus run while another thread dispatches, so it must
        guard what it reads and must neither publish nor dispatch. ``message`` is None for a request without
        payload. A request that cannot be decoded, or that the handler ``Refused``, gets an error reply and is
        counted in ``rejections``."""

    @abstractmethod
    def request(self, key: str, message: Any, timeout: float) -> Any:
        """The answer of whoever serves ``key`` (a wildcard key: the first to answer); raises
        ``TransportError`` when nobody answers within ``timeout`` seconds, and ``Contested`` when more than one
        answers for one key: one of them is an impostor, and no answer is believed."""

    @abstractmethod
    def dispatch(self, until: Callable[[], bool], timeout: float | None = None,
                 idle: Callable[[], None] | None = None) -> None:
        """Run handlers until ``until()`` holds. ``idle`` runs whenever nothing arrived for a moment,
        so callers can check process health. Raises ``TimeoutError`` after ``timeout`` seconds."""

    @abstractmethod
    def monitored(self, key: str) -> Monitored:
        """A best-effort publisher for monitors (never blocks) that knows whether anyone listens."""

    @abstractmethod
    def close(self) -> None: ...


class Monitored(ABC):
    listened: bool

    @abstractmethod
    def put(self, message: Any) -> None: ...
