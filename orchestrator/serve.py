"""Serving a simulation to other processes and hosts (``orchestrator launch --serve``).

Every simulation answers two requests through its orchestrator's ``Server`` (over Zenoh, or on its
in-process bus for code in the same process):

- ``…/session``: the scenario (as a dict), the layout, the current episode and the placement of
  processes on hosts — what a remote driver, a remote node group or a monitor needs;
- ``…/control``: ``{"claim": name}`` / ``{"release": name, "token": secret, "episode": n, "epoch": e}`` — while
  the orchestrator accepts drivers (``launch --serve``, after its own episodes), one driver at a time (e.g.
  ``ZenohEdgeEnv(connect=...)``) takes the clock. The grant carries a random secret that only the
  claimant receives (a query's reply goes to the querier alone) and that is never published: a release
  must carry it, so knowing the driver's name (the session description shows it) is not enough;
- ``…/register/<group>``: a host that runs a placement group (``zenohedge-node``) gets its processes' keys,
  its own and the clock's (``origin``), once: a second request for the same group is refused.

Each claim holds the clock in an epoch of its own (``origin``): the grant carries the epoch and the keys of
that epoch (the clock's, to seal its ticks, and the processes' and hosts', to check their reports), and the
release must name it. When a claim ends, the orchestrator holds the clock in a new epoch and tells the
processes (``Clock.fence``, at the next idle moment of ``wait``): the former holder's ticks are refused from
then on.

A claim holds only while its driver lives: the driver declares the liveliness token
``…/alive/driver/<id>`` of the name it claims before it claims, and the server frees the clock when that
token vanishes (the driver exited or was killed without releasing, or its Zenoh session lapsed) or, for a
claim whose token never appeared, ``TOKEN_GRACE_S`` after the grant. Episode numbers only grow, whoever
drives, so node processes can always tell late mail of an old episode from the current one.

A request that is no claim or release (an empty one, garbage, a wrong field) gets an error reply; it and
every refused claim or release is counted and logged (node_runtime/runtime/rejections.py), and ``counts``
(summary.json's ``run.control``) says what happened to the clock.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import secrets
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import psutil

from node_runtime.runtime.answers import AnswerError, claim_answer, session_answer
from node_runtime.runtime.keys import CHUNK, DEFAULT_PREFIX, Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.rejections import CLOCK_TAKEN, NOT_HOLDER, STALE_EPOCH, UNKNOWN_SENDER, WRONG_SHAPE
from node_runtime.runtime.security import Security
from node_runtime.runtime.transport import Contested, Refused, Transport, TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator.clock import Clock, ClockError

DRIVER_PREFIX = "driver/"
TOKEN_GRACE_S = 5.0  # how long a claim holds before its driver's liveliness token is seen (it is declared first)
log = logging.getLogger(__name__)
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
        self.unseen_until: float | None = None  # while the driver's liveliness token is not seen: when its claim ends
        self.alive: set[str] = set()  # drivers whose liveliness token is up
        # what happened to the clock: claims granted, releases taken, claims freed because their driver
        # vanished, claims and releases refused
        self.counts = {"granted": 0, "released": 0, "vanished": 0, "refused_claims": 0, "refused_releases": 0}
        self.serving = False  # remote drivers may take the clock (launch --serve, after its episodes)
        self.epochs = clock.epoch  # the newest epoch of the clock handed out
        self.held_epoch: int | None = None  # the attached driver's
        self.fence_due = False  # a claim ended: the processes must hear of the orchestrator's new epoch
        self.registered: set[str] = set()  # groups whose host took its keys
        self._lock = threading.Lock()
        transport.serve(keys.session(), self._session)
        transport.serve(keys.control(), self._control)
        for group in self.placement:
            transport.serve(keys.register(group), lambda msg, group=group: self._register(group, msg))
        transport.watch_tokens(keys.alive(f"{DRIVER_PREFIX}*"), self._on_driver_token)

    def _session(self, msg: Any) -> dict[str, Any]:
        if msg is not None and (type(msg) is not dict or msg.get("type") != "session?"):
            raise Refused(WRONG_SHAPE, "a session request has no payload, or is the map {type: 'session?'}")
        with self._lock:
            self._expire()
            return {"type": "session", "sim": self.keys.sim_id, "scenario": self.plan.scenario.to_dict(),
                    "layout": self.plan.layout, "episode": self.clock.latest, "driver": self.driver,
                    "procs": list(self.plan.procs), "placement": self.placement, **self.timing}

    def _control(self, msg: Any) -> dict[str, Any]:
        if msg is None:
            raise Refused(WRONG_SHAPE, "an empty request: a control request is a claim or a release")
        if type(msg) is not dict or msg.get("type") != "control" or ("claim" in msg) == ("release" in msg):
            raise Refused(WRONG_SHAPE, "a control request is a map of type 'control' with either 'claim' or 'release'")
        if "claim" in msg:
            name = msg["claim"]
            driver_id = name.removeprefix(DRIVER_PREFIX) if type(name) is str and name.startswith(DRIVER_PREFIX) else ""
            if not CHUNK.match(driver_id):
                raise Refused(WRONG_SHAPE, "a claim names its driver 'driver/<id>', the key of its liveliness token")
            return self._claim(name)
        if type(msg["release"]) is not str or type(msg.get("episode", -1)) is not int \
                or type(msg.get("epoch")) is not int:
            raise Refused(WRONG_SHAPE, "a release names its driver and gives its last episode and its epoch (integers)")
        return self._release(msg["release"], msg.get("token"), msg.get("episode", -1), msg["epoch"])

    def _register(self, group: str, msg: Any) -> dict[str, Any]:
        """The keys of a group's host, to the first to ask for them (the group's identity only, with --security)."""
        if type(msg) is not dict or msg.get("type") != "register":
            raise Refused(WRONG_SHAPE, "a registration is the map {type: 'register'}")
        with self._lock:
            if group in self.registered:
                raise Refused(UNKNOWN_SENDER, f"group {group} is registered already: another host runs it, or "
                                              "someone else asked for its keys")
            self.registered.add(group)
        return {"type": "register", **self.clock.keyring.of(self.placement[group], group).to_wire()}

    def _claim(self, name: str) -> dict[str, Any]:
        with self._lock:
            self._expire()
            if self.driver is not None or not self.serving:
                who = self.driver or "the orchestrator (it is not serving: launch it with --serve)"
                self.counts["refused_claims"] += 1
                self.transport.rejections.add(self.keys.control(), CLOCK_TAKEN, f"a claim of {name}: held by {who}")
                return {"type": "control", "granted": False, "reason": f"the clock is held by {who}"}
            self.driver = name
            self.secret = secrets.token_hex(16)
            self.unseen_until = None if name in self.alive else time.monotonic() + TOKEN_GRACE_S
            self.counts["granted"] += 1
            self.epochs += 1
            self.held_epoch = self.epochs
            return {"type": "control", "granted": True, "episode": self.clock.latest, "token": self.secret,
                    "keys": self.clock.keyring.grant(self.epochs)}

    def _release(self, name: str, token: Any, episode: int, epoch: int) -> dict[str, Any]:
        with self._lock:
            if self.driver is None or name != self.driver or not isinstance(token, str) \
                    or not secrets.compare_digest(token, self.secret or ""):
                self.counts["refused_releases"] += 1
                self.transport.rejections.add(self.keys.control(), NOT_HOLDER,
                                              f"a release of {name[:40]!r} without the holder's name and token")
                return {"type": "control", "released": False}
            if epoch != self.held_epoch:
                self.counts["refused_releases"] += 1
                self.transport.rejections.add(self.keys.control(), STALE_EPOCH,
                                              f"a release of epoch {epoch}; the clock is in epoch {self.held_epoch}")
                return {"type": "control", "released": False}
            self._end_claim()
            self.counts["released"] += 1
            self.clock.catch_up(episode)
            return {"type": "control", "released": True}

    def _end_claim(self) -> None:
        """The clock is the orchestrator's again, in a new epoch (call with the lock held)."""
        self.driver = self.secret = self.unseen_until = self.held_epoch = None
        self.epochs += 1
        self.clock.epoch = self.epochs
        self.fence_due = True

    def _on_driver_token(self, key: str, alive: bool) -> None:
        name = DRIVER_PREFIX + key.rsplit("/", 1)[-1]
        with self._lock:
            if alive:
                self.alive.add(name)
                if name == self.driver:
                    self.unseen_until = None
                return
            self.alive.discard(name)
            if name == self.driver:
                self._free("its liveliness token vanished: it exited or was killed, or its Zenoh session lapsed")

    def _expire(self) -> None:
        """Free the clock of a claim whose driver never showed its liveliness token (call with the lock held)."""
        if self.unseen_until is not None and time.monotonic() > self.unseen_until:
            self._free(f"its liveliness token did not appear within {TOKEN_GRACE_S:g} s of its claim")

    def _free(self, why: str) -> None:
        log.warning("zenohedge: driver %s left without releasing the clock (%s); the clock is free again",
                    self.driver, why)
        self._end_claim()
        self.counts["vanished"] += 1

    def _idle(self) -> None:
        with self._lock:
            self._expire()
            fence, self.fence_due = self.fence_due, False
        if fence:  # in the dispatch thread, which may publish
            self.clock.fence()
        if self.health is not None:
            self.health()

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
                if self.driver is not None:
                    self._end_claim()

    def wait(self, stop: threading.Event | None = None, ready: Callable[[], None] | None = None) -> None:
        """Serve remote drivers until ``stop`` is set (or Ctrl-C), noticing dead processes meanwhile.
        ``ready`` runs once drivers can claim the clock (to announce it)."""
        stop = stop or threading.Event()
        with self.accepting():
            if ready is not None:
                ready()
            self.transport.dispatch(until=stop.is_set, idle=self._idle)


def session_of(transport: Transport, keys: Keys, timeout: float, where: str = "this endpoint") -> dict[str, Any]:
    """The session description of a simulation, without taking its clock; one ``ClockError`` line for an answer
    of the wrong shape, or answers from more than one session (``Transport.request``)."""
    try:
        info = transport.request(keys.session(), {"type": "session?"}, timeout=timeout)
    except Contested as exc:
        raise ClockError(f"simulation {keys.sim_id!r} at {where}: {exc}") from None
    except Exception as exc:
        raise ClockError(f"no simulation {keys.sim_id!r} answers at {where}: {exc}") from None
    try:
        return session_answer(info, keys.session())
    except AnswerError as exc:
        raise ClockError(f"simulation {keys.sim_id!r} at {where}: {exc}") from None


def describe(endpoint: str, sim_id: str, prefix: str = DEFAULT_PREFIX, timeout: float = 10.0,
             security: Security | None = None) -> dict[str, Any]:
    """The session description of a simulation served at a Zenoh endpoint."""
    transport = ZenohTransport.reach(endpoint, security)
    try:
        return session_of(transport, Keys(sim_id, prefix), timeout, endpoint)
    finally:
        transport.close()


def claim(transport: Transport, keys: Keys, timeout: float) -> tuple[dict[str, Any], str, str, Keyring]:
    """Take the clock of a served simulation; returns its session description, our driver name, the
    token that releases it and the keys of our epoch. The driver's liveliness token goes up first: the claim
    holds while it lives."""
    info = session_of(transport, keys, timeout)
    name = f"{DRIVER_PREFIX}{secrets.token_hex(3)}"
    transport.declare_token(keys.alive(name))
    try:
        answer = claim_answer(transport.request(keys.control(), {"type": "control", "claim": name}, timeout=timeout),
                              keys.control(), info["episode"])
    except Contested as exc:
        raise ClockError(f"simulation {keys.sim_id}: {exc}") from None
    except TransportError as exc:  # with access control, the router drops queries of other identities
        raise ClockError(f"simulation {keys.sim_id}: {exc} (a router with --security answers only the driver "
                         "identity)") from None
    except AnswerError as exc:
        raise ClockError(f"simulation {keys.sim_id}: {exc}") from None
    if not answer["granted"]:
        raise Busy(f"simulation {keys.sim_id}: {answer.get('reason', 'refused')}")
    info["episode"] = answer["episode"]
    return info, name, answer["token"], Keyring.granted(answer["keys"])


def release(transport: Transport, keys: Keys, name: str, token: str, episode: int, epoch: int) -> None:
    transport.request(keys.control(), {"type": "control", "release": name, "token": token, "episode": episode,
                                       "epoch": epoch}, timeout=5.0)
