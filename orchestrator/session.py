"""A running simulation: scenario + layout + transport + processes + clock + metrics.

This is what ``orchestrator launch`` drives and what ``ZenohEdgeEnv`` holds:

    with Simulation.over_zenoh(load_scenario("aot2")) as sim:
        sim.reset(seed=1)
        for _ in range(999):
            report = sim.step()

``Simulation.inproc`` runs the same node code in this process over an in-memory bus (layout ``single`` by
default: one host holding every role); ``Simulation.over_zenoh`` starts one OS process per role (``per-role``,
the default while it fits the machine, else ``groups:K``: node_runtime.runtime.layout.layout_for), per node
(``per-node``) or per block of nodes around a Zenoh router owned by this object; ``Simulation.attach`` drives
one served elsewhere.
Either way the bus carries the same liveliness tokens and answers the same requests (``serve``), so
monitors and drivers work on both.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from node_runtime.model.controller import Action, observation_at
from node_runtime.model.role import role_node
from node_runtime.model.spec import Scenario
from node_runtime.model.view import Observation
from node_runtime.runtime.access import access_control
from node_runtime.runtime.driver import HostDriver
from node_runtime.runtime.failure import account
from node_runtime.runtime.host import Host, role_class
from node_runtime.runtime.inproc import InprocBus
from node_runtime.runtime.keys import DEFAULT_PREFIX, Keys, new_sim_id
from node_runtime.runtime.layout import Layout, ProcessLayout, layout_for
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.process import ORCHESTRATOR, READY_TIMEOUT
from node_runtime.runtime.protocol import Done
from node_runtime.runtime.security import Security, protocol
from node_runtime.runtime.transport import Transport, TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport, free_port
from orchestrator.clock import Clock, ProcessFailed
from orchestrator.local_sims import local_endpoint
from orchestrator.metrics import Metrics, TickReport, bus_record
from orchestrator.serve import Server, claim, release
from orchestrator.supervisor import Supervisor
from orchestrator.version import code_version

TransportName = Literal["zenoh", "inproc"]
log = logging.getLogger(__name__)
ROUTER_ATTEMPTS = 5
LEASE_MARGIN_S = 5.0  # a node's Zenoh session outlives the clock's timeout by this much
QUERY_TIMEOUT_S = 5.0  # upper bound of the liveliness query at start; it answers at once when no other has the id


def lease_ms(timeout: float) -> int:
    """The Zenoh lease every session of a simulation announces, in milliseconds: beyond the clock's timeout, so
    that a stalled party is reported by the clock (or the supervisor), not lost to a lapsed session first."""
    return round((timeout + LEASE_MARGIN_S) * 1000)


def check_transport(name: str) -> TransportName:
    """``name`` if it names a transport; a ValueError saying what is expected otherwise."""
    if name not in ("zenoh", "inproc"):
        raise ValueError(f"transport must be 'zenoh' or 'inproc', not {name!r}")
    return name


def default_layout(scenario: Scenario, transport: TransportName, placed: bool) -> Layout:
    """The default: per-role over Zenoh while it fits this machine, said when it does not (``layout_for``)."""
    choice = layout_for(scenario, transport, placed=placed)
    if choice.note is not None:
        log.warning(choice.note)
    return choice.layout


class RouterUnavailable(Exception):
    """The router cannot listen where the user asked (``--listen``)."""


class SimIdInUse(RuntimeError):
    """Another orchestrator on the same Zenoh network already uses this simulation id."""


def open_router(host: str = "127.0.0.1", port: int | None = None, join: list[str] | None = None,
                security: Security | None = None,
                settings: dict[str, Any] | None = None) -> tuple[ZenohTransport, str]:
    """A router session listening on a free port (retrying if another process takes it first).
    ``join``: other routers' endpoints to connect to, making one Zenoh network; ``security``: listen
    with TLS, requiring client certificates and logins; ``settings``: further Zenoh configuration."""
    last: Exception | None = None
    for _ in range(1 if port else ROUTER_ATTEMPTS):
        endpoint = f"{protocol(security)}/{host}:{port or free_port(host)}"
        try:
            return ZenohTransport.router(endpoint, join, security, settings), endpoint
        except Exception as exc:  # zenoh raises ZError when the port is taken
            last = exc
    if port:  # the user's choice: say so in one line
        raise RouterUnavailable(f"cannot listen on {host}:{port}: {str(last).split(' at /')[0]} "
                                "(another program holds the port, or the address is not this host's)")
    raise RuntimeError(f"could not open a Zenoh router on {host}: {last}")


def node_policies(scenario: Scenario, policy: str | None = None) -> str | list[str]:
    """The controllers' node-side policy as summary.json records it: ``policy`` where it overrides them
    all, else the scenario's policies, sorted, each once."""
    return policy or sorted({n.policy for n in scenario.nodes if n.has("controller")})


def refuse_taken_id(router: ZenohTransport, keys: Keys) -> None:
    """Two orchestrators with one simulation id on joined routers would take each other's messages
    for their own: look for the other's liveliness token before declaring anything."""
    if router.tokens(keys.alive(ORCHESTRATOR), QUERY_TIMEOUT_S):
        raise SimIdInUse(f"simulation id {keys.sim_id!r} is already in use on this Zenoh network (an orchestrator "
                         "with that id runs at a joined router): choose another --sim-id")


@dataclass(frozen=True, kw_only=True)
class RouterSettings:
    """Where a Zenoh simulation's router listens and whom it lets in.

    ``listen_host``/``port``: the router's address (``port`` None: a free one); ``join``: other routers'
    endpoints to connect to, making one Zenoh network; ``security``: TLS, logins and access control on the
    router (node_runtime/runtime/access.py), and the identity of the local processes; ``zenoh_settings``:
    merged last into the router's configuration."""

    listen_host: str = "127.0.0.1"
    port: int | None = None
    join: tuple[str, ...] = ()
    security: Security | None = None
    zenoh_settings: Mapping[str, Any] | None = None


@dataclass(frozen=True, kw_only=True)
class RemoteHosts:
    """Node processes left to ``zenohedge-node`` on other hosts: ``placement`` (group -> processes). Their
    start is awaited up to ``join_timeout`` seconds, after calling ``on_waiting(placement, endpoint)`` (the
    router's endpoint, where they connect)."""

    placement: Mapping[str, list[str]]
    join_timeout: float = 600.0
    on_waiting: Callable[[Mapping[str, list[str]], str], None] | None = None


class Simulation:
    """A running simulation. Open one with ``Simulation.inproc``, ``Simulation.over_zenoh`` or ``Simulation.attach``
    (``Simulation.open``: the first two by the transport's name); each wires a bus, a clock and the processes
    around the common core that ``__init__`` makes."""

    transport: Transport  # the orchestrator's (or the attached driver's) end of the bus
    clock: Clock

    def __init__(self, scenario: Scenario, *, transport: TransportName, keys: Keys, layout: Layout | None,
                 placed: bool = False) -> None:
        """What every simulation has, however it is opened: the plan, the metrics, the episode's state.
        ``placed``: some processes run on other hosts (the default layout then stays per-role)."""
        self.scenario = scenario
        self.transport_name = transport
        self.layout = layout or default_layout(scenario, transport, placed)
        self.plan = ProcessLayout(scenario, self.layout)
        self.keys = keys
        self.metrics = Metrics(self.plan)
        self.supervisor: Supervisor | None = None
        self.server: Server | None = None  # answers …/session and …/control (not when attached)
        self.attached: str | None = None  # our driver name, when attached to a served simulation
        self.live = None  # publisher of …/metrics/tick, for monitors
        self.endpoint: str | None = None
        self.drivers: list[HostDriver] = []  # the in-process hosts
        self.startup_s = 0.0
        self.seed = scenario.seed
        self.policy: str | None = None
        self.last: list[Done] = []
        self.seen: dict[str, Observation] = {}  # driven controller -> its latest observation, any tick
        # node -> the (queue, occupancy, drains_at) it last broadcast: before the current tick (heard by its end), in it
        self.heard: dict[str, tuple[int, int, float]] = {}
        self.fresh: dict[str, tuple[int, int, float]] = {}
        # driven controller -> the reports it reads later (arrival tick, tasks pending, busy-until), in order
        self.reports: dict[str, list[tuple[int, int, list[float] | None]]] = {}
        self.retimed: set[str] = set()  # driven controllers whose class observation_at can re-time
        self._closed = False
        self._run_started = 0.0
        self._ticks_run = 0

    @classmethod
    def open(cls, scenario: Scenario, transport: TransportName = "inproc", *, layout: Layout | None = None,
             sim_id: str | None = None, prefix: str = DEFAULT_PREFIX, timeout: float = 30.0,
             router: RouterSettings = RouterSettings(), remote: RemoteHosts | None = None) -> Simulation:
        """``inproc`` or ``over_zenoh`` by the transport's name, for callers that take it from a user (``launch
        --transport``, the environment); ``router`` and ``remote`` apply to Zenoh only."""
        if check_transport(transport) == "inproc":
            return cls.inproc(scenario, layout=layout, sim_id=sim_id, prefix=prefix, timeout=timeout)
        return cls.over_zenoh(scenario, layout=layout, sim_id=sim_id, prefix=prefix, timeout=timeout, router=router,
                              remote=remote)

    @classmethod
    def inproc(cls, scenario: Scenario, *, layout: Layout | None = None, sim_id: str | None = None,
               prefix: str = DEFAULT_PREFIX, timeout: float = 30.0) -> Simulation:
        """The node code in this process, over an in-memory bus: one host per process of the layout (one
        holding every role by default), each driven in this thread."""
        self = cls(scenario, transport="inproc", keys=Keys(sim_id or new_sim_id(), prefix), layout=layout)
        bus = InprocBus()
        keyring = Keyring.new(self.plan.procs)
        for proc in self.plan.procs:
            host = bus.endpoint()
            self.drivers.append(HostDriver(self._host(proc), host, self.keys, keyring.of([proc])))
            host.declare_token(self.keys.alive(proc))  # ready, as a node process says once it is
        self.transport = bus.endpoint()
        self.transport.declare_token(self.keys.alive(ORCHESTRATOR))
        self.transport.rejections.who = ORCHESTRATOR
        self.clock = Clock(self.transport, self.keys, self.plan, keyring, timeout)
        self.live = self.transport.monitored(self.keys.metrics())
        self.server = Server(self.transport, self.keys, self.plan, self.clock)
        return self

    @classmethod
    def over_zenoh(cls, scenario: Scenario, *, layout: Layout | None = None, sim_id: str | None = None,
                   prefix: str = DEFAULT_PREFIX, timeout: float = 30.0, router: RouterSettings = RouterSettings(),
                   remote: RemoteHosts | None = None) -> Simulation:
        """One OS process per process of the layout (per role by default) around a Zenoh router this object
        owns; those of ``remote`` are left to other hosts."""
        placement = dict(remote.placement) if remote is not None else {}
        self = cls(scenario, transport="zenoh", keys=Keys(sim_id or new_sim_id(), prefix), layout=layout,
                   placed=bool(placement))
        # the router's own lease follows the clock's timeout too: processes keep a paused orchestrator as long
        # as it keeps them (Zenoh's default, 10 s, ended runs whose orchestrator stood still that long)
        settings = {"transport/link/tx/lease": lease_ms(timeout), **(router.zenoh_settings or {})}
        if router.security is not None:
            settings = {"access_control": access_control(self.keys, self.plan, placement), **settings}
        self.transport, self.endpoint = open_router(router.listen_host, router.port, list(router.join) or None,
                                                    router.security, settings)
        self.transport.rejections.who = ORCHESTRATOR
        try:
            self._start_processes(timeout, router.security, remote)
        except BaseException:
            self.close()
            raise
        return self

    def _start_processes(self, timeout: float, security: Security | None, remote: RemoteHosts | None) -> None:
        """Supervise, clock and serve the Zenoh simulation, then start its local processes and wait for all."""
        refuse_taken_id(self.transport, self.keys)
        placement = dict(remote.placement) if remote is not None else None
        self.supervisor = Supervisor(self.transport, self.keys, self.plan, placement=placement)
        keyring = Keyring.new(self.plan.procs, list(placement or ()))  # hosts get theirs as they register (serve.py)
        self.clock = Clock(self.transport, self.keys, self.plan, keyring, timeout, health=self.supervisor.check,
                           why_silent=self.supervisor.hung, placement=placement)
        self.live = self.transport.monitored(self.keys.metrics())
        elsewhere = {p for procs in (placement or {}).values() for p in procs}
        local = tuple(p for p in self.plan.procs if p not in elsewhere)
        # readiness may take longer than a tick on a big scenario, never less than --timeout, and waits
        # for hosts that join later; the lease outlives the clock's timeout, so a paused process is
        # reported hung, not died. Processes on other hosts are told the same (the session answer).
        timing = {"ready_timeout": remote.join_timeout if elsewhere else max(READY_TIMEOUT, timeout),
                  "lease_s": lease_ms(timeout) / 1000}
        self.server = Server(self.transport, self.keys, self.plan, self.clock, self.supervisor.check, placement,
                             timing)
        if elsewhere and remote.on_waiting is not None:
            remote.on_waiting(placement, self.endpoint)
        self.startup_s = self.supervisor.start(self.scenario, self.layout, local_endpoint(self.endpoint), local,
                                               keyring, timeout=timing["ready_timeout"], security=security,
                                               lease_s=timing["lease_s"])

    def _host(self, proc: str) -> Host:
        """An in-process host; a role that fails as it is built (a user's class) fails it as it would fail
        a node process: named, with the role's own account."""
        try:
            return Host(proc, self.plan)
        except Exception as exc:
            why = account(exc)
            raise ProcessFailed(proc, self.plan.node_of_proc(proc), f"failed to start: {why.splitlines()[0]}",
                                why) from None

    @classmethod
    def attach(cls, endpoint: str | Transport, sim_id: str, prefix: str = DEFAULT_PREFIX,
               timeout: float = 30.0, security: Security | None = None) -> Simulation:
        """Drive a simulation served by ``orchestrator launch --serve`` (possibly on another host).

        ``endpoint``: its Zenoh router, or an open transport on its bus (e.g. an endpoint of an
        in-process simulation's bus), which this object then owns and closes. ``security``: for a router
        that requires TLS and logins, the ``driver`` identity (deploy/make-certs.sh).
        The served processes stay up when this object closes; the server gets its clock back.
        """
        keys = Keys(sim_id, prefix)
        transport = ZenohTransport.reach(endpoint, security, {"transport/link/tx/lease": lease_ms(timeout)}) \
            if isinstance(endpoint, str) else endpoint
        try:
            info, driver, secret, keyring = claim(transport, keys, timeout)
        except BaseException:
            transport.close()
            raise
        self = cls(Scenario.from_dict(info["scenario"]), keys=keys, layout=info["layout"],
                   transport="zenoh" if isinstance(transport, ZenohTransport) else "inproc")
        self.endpoint = endpoint if isinstance(endpoint, str) else None
        self._run_started = time.perf_counter()
        self.transport = transport
        self.attached = driver
        transport.rejections.who = driver
        self._secret = secret
        try:
            self.supervisor = Supervisor(transport, keys, self.plan, token=None,  # ``claim`` declared ours
                                         placement=info.get("placement"))
            self.supervisor.wait_ready(timeout)
            self.clock = Clock(transport, keys, self.plan, keyring, timeout, health=self.supervisor.check,
                               placement=info.get("placement"))
            self.clock.catch_up(info["episode"])
            self.live = transport.monitored(keys.metrics())
        except BaseException:
            self.close()
            raise
        return self

    # ----- episode control -----

    def reset(self, seed: int | None = None, external: list[str] | None = None,
              policy: str | None = None) -> TickReport:
        """Start an episode (processes stay up) and run its tick 0.

        ``external``: controller roles whose actions the caller supplies to ``step``.
        ``policy``: override every controller's node-side policy for this episode.
        """
        self.seed = self.scenario.seed if seed is None else int(seed)
        self.policy = policy
        self.metrics.reset()
        self.last = self.clock.reset(self.seed, external, policy)
        self.seen, self.heard, self.fresh, self.reports = {}, {}, {}, {}
        # a moving scenario's controllers observe every epoch (their links change): none is re-timed
        self.retimed = {r for r in external or () if getattr(role_class(r, self.plan), "retimed", False)
                        and self.scenario.radio is None}
        self._remember()
        self._run_started = time.perf_counter()
        self._ticks_run = 1
        return self._publish(self.metrics.add(0, self.last))

    def step(self, actions: dict[str, Action] | None = None) -> TickReport:
        self.last = self.clock.step(actions)
        self._remember()
        self._ticks_run += 1
        return self._publish(self.metrics.add(self.clock.tick, self.last))

    def open_next(self) -> None:
        """Let the node processes that cannot get actions run the next tick now, while the caller (an agent)
        decides: only a controller with tasks to place can be given an action, so only the processes of
        those wait for ``step`` (``Clock.open_next``). In-process the hosts run inside the publication, in
        this thread: opening ahead would only run them sooner, so it is left to ``step``."""
        if self.transport_name == "zenoh":
            self.clock.open_next(hold=[role for role, obs in self.seen.items() if obs.tasks])

    def _publish(self, report: TickReport) -> TickReport:
        """Per-tick metrics for monitors, built only when someone listens."""
        if self.live is not None and self.live.listened:
            self.live.put(bus_record(report, self.metrics, self.keys.sim_id, self.clock.episode))
        return report

    @property
    def tick(self) -> int:
        return self.clock.tick

    def observations(self) -> dict[str, Observation]:
        """What each externally driven controller observes at the current tick, by role: the observations
        of the last tick, and for a controller that slept through it, its latest one re-timed
        (``observation_at``: it has nothing to place, and what it heard since it holds unread: states and
        reports, as the processes reported them). A controller whose node has scheduled failures never
        sleeps, so it has one only while its node is up."""
        t, sc = self.clock.tick, self.scenario
        if t % sc.decision_interval:  # controllers observe at decision epochs only
            return {role: obs for role, obs in self.seen.items() if obs.tick == t}
        heard = self.heard
        return {role: obs if obs.tick == t else observation_at(obs, t, sc, heard, self._report(role, t))
                for role, obs in self.seen.items()
                if obs.tick == t or (role in self.retimed and not sc.failure_windows.get(obs.node))}

    def _report(self, role: str, t: int) -> tuple[int, list[float] | None] | None:
        """What the reports ``role`` holds unread at tick ``t`` tell it (tasks pending, and the latest busy-until
        ticks given), or None (``_remember`` keeps only those that arrive after its last observation)."""
        arrived = [r for r in self.reports.get(role, ()) if r[0] <= t]
        if not arrived:
            return None
        return arrived[-1][1], next((r[2] for r in reversed(arrived) if r[2] is not None), None)

    def _remember(self) -> None:
        roles = self.plan.roles
        for d in self.last:
            for i, obs in d.obs.items():
                self.seen[roles[i]] = obs
                if roles[i] in self.reports:  # those that arrived by this observation are in it
                    self.reports[roles[i]] = [r for r in self.reports[roles[i]] if r[0] > obs.tick]
        if not self.retimed:  # the states and reports below serve re-timed observations only
            return
        self.heard.update(self.fresh)  # broadcasts arrive one tick after they leave
        self.fresh = {}
        for d in self.last:
            for i, (*state, _) in d.states.items():
                self.fresh[role_node(roles[i])] = tuple(state)
            for i, report in d.reports.items():
                if roles[i] in self.retimed:  # only their observations are re-timed: nobody else reads these
                    self.reports.setdefault(roles[i], []).append(report)

    def run(self, ticks: int | None = None, seed: int | None = None, policy: str | None = None,
            on_tick: Any = None) -> dict[str, Any]:
        """A whole episode with node-side policies; returns the summary."""
        ticks = self.scenario.episode_ticks if ticks is None else ticks
        report = self.reset(seed, policy=policy)
        if on_tick:
            on_tick(report)
        for _ in range(ticks - 1):
            report = self.step()
            if on_tick:
                on_tick(report)
        return self.summary()

    def summary(self) -> dict[str, Any]:
        s = self.metrics.summary()
        s["seed"] = self.seed
        s["policy"] = node_policies(self.scenario, self.policy)
        s["code"] = code_version()
        wall = time.perf_counter() - self._run_started
        s["run"] = {
            "transport": self.transport_name,
            "layout": self.layout,
            "processes": len(self.plan.procs) if self.transport_name == "zenoh" else 1,
            "sim_id": self.keys.sim_id,
            "startup_s": round(self.startup_s, 3),
            "wall_time_s": round(wall, 3),
            "ticks_per_s": round(self._ticks_run / wall, 1) if wall > 0 else None,
            "finished_at": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            # messages refused on the bus since the simulation started (docs/bus.md, "Rejected messages")
            "rejected_messages": {"orchestrator": dict(sorted(self.transport.rejections.counts.items())),
                                  "nodes": self.clock.node_rejected()},
            # end-of-tick reports taken, and the messages of hosts that forwarded theirs together (docs/protocol.md)
            "reports": dict(self.clock.reports),
        }
        if self.server is not None:  # what happened to the clock (docs/bus.md, "Rejected messages")
            s["run"]["control"] = dict(self.server.counts)
        if any(t.payload is not None for t in self.scenario.workload.task_types):  # measured, or replayed from where
            s["run"]["payloads"] = self.scenario.payload_log.model_dump()
        return s

    # ----- lifetime -----

    def close(self) -> None:
        """Stop every process and close the bus; safe to call twice and after any error."""
        if self._closed:
            return
        self._closed = True
        if self.attached is not None:  # the processes belong to the server: hand the clock back
            with contextlib.suppress(Exception):
                release(self.transport, self.keys, self.attached, self._secret, self.clock.episode, self.clock.epoch)
        elif self.supervisor is not None:
            with contextlib.suppress(Exception):
                self.clock.stop()
            self.supervisor.shutdown()
        try:
            self.transport.close()
        except TransportError as e:  # e.g. a partitioned host's link will not close: say so, do not mask the run's end
            log.warning("zenohedge: %s (a host may be unreachable); the router is left to the process's exit", e)

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
