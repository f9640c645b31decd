"""Serving a simulation to other processes and hosts (``orchestrator launch --serve``).

Every simulation answers two requests through its orchestrator's ``Server`` (over Zenoh, or on its
in-process bus for code in the same process):

- ``…/session``: the scenario (as a dict), the layout, the current episode and the placement of
  processes on hosts — what a remote driver, a remote node group or a monitor needs;
- ``…/control``: ``{"claim": name}`` / ``{"release": name, "token": secret, "episode": n}`` — while the
  orchestrator accepts drivers (``launch --serve``, after its own episodes), one driver at a time (e.g.
  ``ZenohEdgeEnv(connect=...)``) takes the clock. The grant carries a random secret that only the
  claimant receives (a query's reply goes to the querier alone) and that is never published: a release
  must carry it, so knowing the driver's name (the session description shows it) is not enough.

A driver announces itself with the liveliness token ``…/alive/driver/<id>``; if it vanishes (the driver
crashed), the server takes the clock back. Episode numbers only grow, whoever drives, so node
processes can always tell late mail of an old episode from the current one.
"""

from __future__ import annotations

import contextlib
import ipaddress
import secrets
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import psutil

from node_runtime.runtime.keys import DEFAULT_PREFIX, Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.security import Security
from node_runtime.runtime.transport import Transport, TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator.clock import Clock, ClockError

DRIVER_PREFIX = "driver/"
WILDCARDS = {"0.0.0.0": socket.AF_INET, "::": socket.AF_INET6, "[::]": socket.AF_INET6}


def is_loopback(host: str) -> bool:
    """Whether a listener on ``host`` can be reached from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name: it may name any interface
        return False


def reachable(endpoint: str) -> list[str]:
    """Where other processes reach a router listening at ``endpoint``: the endpoint itself, or for one on every
    interface (0.0.0.0, ::), which no client can connect to, this host's addresses of that family (but
    link-local ones, which need an interface named), loopback last."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    family = WILDCARDS.get(host)
    if family is None:
        return [endpoint]
    hosts = {a.address for addrs in psutil.net_if_addrs().values() for a in addrs
             if a.family == family and not ipaddress.ip_address(a.address.split("%")[0]).is_link_local}
    ordered = sorted(hosts, key=lambda h: (is_loopback(h), ipaddress.ip_address(h)))
    return [f"{proto}/{h if family == socket.AF_INET else f'[{h}]'}:{port}" for h in ordered] or [endpoint]


class Busy(ClockError):
    """The clock is held by someone else."""


class Server:
    """Answers ``…/session`` and ``…/control``. Requests are answered outside ``dispatch`` (a Zenoh
    thread, or the requester's call in-process; see ``Transport.serve``), hence the lock.
    ``health`` runs while ``wait`` is idle (the supervisor's check of local processes)."""

    def __init__(self, transport: Transport, keys: Keys, plan: ProcessLayout, clock: Clock,
                 health: Callable[[], None] | None = None, placement: dict[str, list[str]] | None = None,
                 timing: dict[str, float] | None = None) -> None:
        """``timing``: what the processes of other hosts must be told, so that they wait and are kept as long as
        the local ones: ``ready_timeout`` and ``lease_s`` (node_runtime/runtime/process.py's ProcSpec)."""
        self.transport = transport
        self.keys = keys
        self.plan = plan
        self.clock = clock
        self.health = health
        self.placement = placement or {}
        self.timing = timing or {}
        self.driver: str | None = None
        self.secret: str | None = None  # the attached driver's token
        self.refused = 0  # releases with a wrong or missing token
        self.serving = False  # remote drivers may take the clock (launch --serve, after its episodes)
        self._lock = threading.Lock()
        transport.serve(keys.session(), self._session)
        transport.serve(keys.control(), self._control)
        transport.watch_tokens(keys.alive(f"{DRIVER_PREFIX}*"), self._on_driver_token)

    def _session(self, _: Any) -> dict[str, Any]:
        with self._lock:
            return {"type": "session", "sim": self.keys.sim_id, "scenario": self.plan.scenario.to_dict(),
                    "layout": self.plan.layout, "episode": self.clock.latest, "driver": self.driver,
                    "procs": list(self.plan.procs), "placement": self.placement, **self.timing}

    def _control(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            if "claim" in msg:
                if self.driver is not None or not self.serving:
                    who = self.driver or "the orchestrator (it is not serving: launch it with --serve)"
                    return {"type": "control", "granted": False, "reason": f"the clock is held by {who}"}
                self.driver = msg["claim"]
                self.secret = secrets.token_hex(16)
                return {"type": "control", "granted": True, "episode": self.clock.latest, "token": self.secret}
            if "release" in msg:
                if self.driver is None or msg["release"] != self.driver or not isinstance(msg.get("token"), str) \
                        or not secrets.compare_digest(msg["token"], self.secret or ""):
                    self.refused += 1
                    return {"type": "control", "released": False}
                self.driver = self.secret = None
                self.clock.catch_up(int(msg.get("episode", -1)))
                return {"type": "control", "released": True}
        return {"type": "control", "released": False}

    def _on_driver_token(self, key: str, alive: bool) -> None:
        name = DRIVER_PREFIX + key.rsplit("/", 1)[-1]
        with self._lock:
            if not alive and name == self.driver:  # the driver died without releasing
                self.driver = self.secret = None

    @contextlib.contextmanager
    def accepting(self) -> Iterator[None]:
        """Let remote drivers claim the clock inside this block; it is ours again after it."""
        with self._lock:
            self.serving = True
        try:
            yield
        finally:
            with self._lock:
                self.serving = False
                self.driver = self.secret = None

    def wait(self, stop: threading.Event | None = None, ready: Callable[[], None] | None = None) -> None:
        """Serve remote drivers until ``stop`` is set (or Ctrl-C), noticing dead processes meanwhile.
        ``ready`` runs once drivers can claim the clock (to announce it)."""
        stop = stop or threading.Event()
        with self.accepting():
            if ready is not None:
                ready()
            self.transport.dispatch(until=stop.is_set, idle=self.health)


def session_of(transport: Transport, keys: Keys, timeout: float, where: str = "this endpoint") -> dict[str, Any]:
    """The session description of a simulation, without taking its clock."""
    try:
        return transport.request(keys.session(), {"type": "session?"}, timeout=timeout)
    except Exception as exc:
        raise ClockError(f"no simulation {keys.sim_id!r} answers at {where}: {exc}") from None


def describe(endpoint: str, sim_id: str, prefix: str = DEFAULT_PREFIX, timeout: float = 10.0,
             security: Security | None = None) -> dict[str, Any]:
    """The session description of a simulation served at a Zenoh endpoint."""
    transport = ZenohTransport.reach(endpoint, security)
    try:
        return session_of(transport, Keys(sim_id, prefix), timeout, endpoint)
    finally:
        transport.close()


def claim(transport: Transport, keys: Keys, timeout: float) -> tuple[dict[str, Any], str, str]:
    """Take the clock of a served simulation; returns its session description, our driver name and the
    token that releases it."""
    info = session_of(transport, keys, timeout)
    name = f"{DRIVER_PREFIX}{secrets.token_hex(3)}"
    try:
        answer = transport.request(keys.control(), {"type": "control", "claim": name}, timeout=timeout)
    except TransportError as exc:  # with access control, the router drops queries of other identities
        raise ClockError(f"simulation {keys.sim_id}: {exc} (a router with --security answers only the driver "
                         "identity)") from None
    if not answer.get("granted"):
        raise Busy(f"simulation {keys.sim_id}: {answer.get('reason', 'refused')}")
    info["episode"] = answer["episode"]
    return info, name, answer["token"]


def release(transport: Transport, keys: Keys, name: str, token: str, episode: int) -> None:
    transport.request(keys.control(), {"type": "control", "release": name, "token": token, "episode": episode},
                      timeout=5.0)
