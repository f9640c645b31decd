"""The resolved scenario: what every node process needs to know, and nothing about files.

The orchestrator parses and validates a YAML scenario into these frozen dataclasses; node
processes receive them (pickled by the launcher, or as a dict over the bus for remote hosts).
Everything here is plain data so that it round-trips through ``to_dict``/``from_dict``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property
from typing import Any, Literal

Mode = Literal["binary", "batch"]
Admission = Literal["decide_first", "queue_first"]


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """One network node and the roles it has (usually a worker, optionally a client and a controller)."""

    id: str
    tier: int
    cores: int
    frequency: float  # cycles per second, per core
    buffer: int  # Q_max: queued + undecided tasks
    position: tuple[float, float]
    tx_power_dbm: float
    idle_power_w: float
    kappa: float  # switched capacitance: compute energy = kappa * cycles * frequency**2
    roles: tuple[str, ...]  # its role kinds, in canonical order (node_runtime.model.registry)
    policy: str = "local"  # node-side decision policy (a name, or an import path "module:Class")
    profile: str = ""  # hardware profile name, for display
    impls: tuple[tuple[str, str], ...] = ()  # kind -> import path of a user subclass of the kind's class
    params: tuple[tuple[str, Any], ...] = ()  # free parameters for user extensions (``params:`` key)

    def has(self, kind: str) -> bool:
        return kind in self.roles

    def impl(self, kind: str) -> str:
        """The class the scenario gives this node's role ``kind`` ("" = the kind's own)."""
        return dict(self.impls).get(kind, "")

    @property
    def capacity(self) -> float:
        """Cycles per second the worker can spend on its queue."""
        return self.cores * self.frequency

    def param(self, name: str, default: Any = None) -> Any:
        """A value of the node's ``params`` (set in its profile or its own entry of the scenario)."""
        return dict(self.params).get(name, default)


@dataclass(frozen=True, slots=True)
class LinkSpec:
    """A directed link src -> dst and the rate its sender transmits at."""

    src: str
    dst: str
    rate_bps: float
    loss: float = 0.0  # probability that a message on this link is lost


@dataclass(frozen=True, slots=True)
class TaskType:
    name: str
    weight: float
    instructions: float  # rho
    input_bytes: float  # alpha_in
    output_bytes: float  # alpha_out
    cpi: float  # xi, cycles per instruction
    deadline: float  # delta, seconds from creation until the result must be back; with a range, its low end
    deadline_high: float | None = None  # a range: delta ~ U[deadline, deadline_high) + grace, drawn per task
    grace: float = 0.0  # seconds added to every drawn deadline

    @property
    def cycles(self) -> float:
        """CPU cycles one task of this type needs (as ``Task.cycles``)."""
        return self.instructions * self.cpi

    @property
    def drawn(self) -> bool:
        """Whether each task of this type draws its own deadline."""
        return self.deadline_high is not None

    @property
    def longest_deadline(self) -> float:
        """The bound of every deadline this type gives a task: the range's high end (or the fixed value)
        plus the grace. No task of the type completes later than this."""
        return (self.deadline_high if self.drawn else self.deadline) + self.grace


@dataclass(frozen=True, slots=True)
class Arrival:
    """Arrival-rate schedule lambda(t), tasks per second per client.

    kinds: constant(rate); linear(start -> end over the episode); zigzag(low..high, period s);
    uniform(each client draws a constant rate in [low, high] at every reset). The process: poisson
    (a Poisson count per tick) or exponential_gaps (one task at a time, max(1, floor(Exp(lambda) / dt))
    ticks apart, the reference implementation's client).
    """

    kind: Literal["constant", "linear", "zigzag", "uniform"] = "constant"
    rate: float = 0.17
    start: float = 0.0
    end: float = 0.0
    low: float = 0.0
    high: float = 0.0
    period: float = 100.0
    process: Literal["poisson", "exponential_gaps"] = "poisson"


@dataclass(frozen=True, slots=True)
class TraceRow:
    time: float  # seconds from the episode start
    client: str
    instructions: float
    input_bytes: float
    output_bytes: float
    cpi: float
    deadline: float


@dataclass(frozen=True, slots=True)
class Workload:
    task_types: tuple[TaskType, ...]
    arrival: Arrival = Arrival()
    client_rates: tuple[tuple[str, float], ...] = ()  # per-client constant overrides
    client_targets: tuple[tuple[str, tuple[str, ...]], ...] = ()  # client node -> worker nodes
    trace: tuple[TraceRow, ...] | None = None
    source: str = ""  # import path of a user TaskSource subclass ("" = Poisson / trace)


@dataclass(frozen=True, slots=True)
class Failure:
    """Node ``node`` is down for ticks [start, end)."""

    node: str
    start: int
    end: int


@dataclass(frozen=True)
class Scenario:
    name: str
    dt: float
    episode_ticks: int
    seed: int
    mode: Mode
    decision_interval: int
    max_hops: int
    batch_size: int  # decisions per epoch in batch mode (fixed action shape)
    state_interval: int  # ticks between one-hop state broadcasts
    nodes: tuple[NodeSpec, ...]
    links: tuple[LinkSpec, ...]
    workload: Workload
    failures: tuple[Failure, ...] = ()
    kinds: tuple[tuple[str, str], ...] = ()  # role kinds the nodes have, in canonical order: (name, class path)
    source: str = ""  # the file it came from, for messages only
    extra: dict[str, Any] = field(default_factory=dict)  # free-form metadata (description ...)
    admission: Admission = "decide_first"  # queue_first: arrivals are queued at once, decisions divert queued tasks
    control_latency: int = 2  # ticks between the state a controller observes and its decision's effect (2 or 0)

    # ----- derived views (cached, never serialised) -----

    @cached_property
    def node(self) -> dict[str, NodeSpec]:
        return {n.id: n for n in self.nodes}

    @cached_property
    def index(self) -> dict[str, int]:
        """Canonical node index: declaration order."""
        return {n.id: i for i, n in enumerate(self.nodes)}

    @cached_property
    def neighbours(self) -> dict[str, tuple[str, ...]]:
        """One-hop neighbours of every node, in canonical (declaration) order."""
        adj: dict[str, set[str]] = {n.id: set() for n in self.nodes}
        for link in self.links:
            adj[link.src].add(link.dst)
        return {nid: tuple(sorted(ns, key=self.index.__getitem__)) for nid, ns in adj.items()}

    @cached_property
    def link(self) -> dict[tuple[str, str], LinkSpec]:
        return {(lk.src, lk.dst): lk for lk in self.links}

    @cached_property
    def targets(self) -> dict[str, tuple[str, ...]]:
        """Worker nodes each client hands its new tasks to."""
        explicit = dict(self.workload.client_targets)
        out: dict[str, tuple[str, ...]] = {}
        for n in self.nodes:
            if not n.has("client"):
                continue
            if n.id in explicit:
                out[n.id] = explicit[n.id]
            elif n.has("worker"):
                out[n.id] = (n.id,)
            else:
                out[n.id] = tuple(j for j in self.neighbours[n.id] if self.node[j].has("worker"))
        return out

    @cached_property
    def failure_windows(self) -> dict[str, tuple[tuple[int, int], ...]]:
        windows: dict[str, list[tuple[int, int]]] = {}
        for f in self.failures:
            windows.setdefault(f.node, []).append((f.start, f.end))
        return {k: tuple(sorted(v)) for k, v in windows.items()}

    def is_failed(self, node: str, tick: int) -> bool:
        return any(a <= tick < b for a, b in self.failure_windows.get(node, ()))

    @property
    def colocated_control(self) -> bool:
        """Each controller reads its own worker and hands it decisions within the tick (control_latency 0)."""
        return self.control_latency == 0

    @property
    def controllers(self) -> tuple[str, ...]:
        return tuple(n.id for n in self.nodes if n.has("controller"))

    @property
    def clients(self) -> tuple[str, ...]:
        return tuple(n.id for n in self.nodes if n.has("client"))

    @property
    def undirected_links(self) -> int:
        return len({frozenset((lk.src, lk.dst)) for lk in self.links})

    # ----- serialisation -----

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scenario:
        wl = d["workload"]
        workload = Workload(
            task_types=tuple(TaskType(**t) for t in wl["task_types"]),
            arrival=Arrival(**wl["arrival"]),
            client_rates=tuple((c, float(r)) for c, r in wl["client_rates"]),
            client_targets=tuple((c, tuple(ts)) for c, ts in wl["client_targets"]),
            trace=None if wl["trace"] is None else tuple(TraceRow(**r) for r in wl["trace"]),
            source=wl.get("source", ""),
        )
        return cls(
            name=d["name"],
            dt=float(d["dt"]),
            episode_ticks=int(d["episode_ticks"]),
            seed=int(d["seed"]),
            mode=d["mode"],
            decision_interval=int(d["decision_interval"]),
            max_hops=int(d["max_hops"]),
            batch_size=int(d["batch_size"]),
            state_interval=int(d["state_interval"]),
            nodes=tuple(NodeSpec(**{**n, "position": tuple(n["position"]), "roles": tuple(n["roles"]),
                                     "impls": tuple(tuple(kv) for kv in n["impls"]),
                                     "params": tuple(tuple(kv) for kv in n.get("params", ()))}) for n in d["nodes"]),
            links=tuple(LinkSpec(**lk) for lk in d["links"]),
            workload=workload,
            failures=tuple(Failure(**f) for f in d["failures"]),
            kinds=tuple(tuple(kv) for kv in d["kinds"]),
            source=d.get("source", ""),
            extra=dict(d.get("extra", {})),
            admission=d.get("admission", "decide_first"),
            control_latency=int(d.get("control_latency", 2)),
        )

    def digest(self) -> str:
        """Content hash of everything that affects the emulation (not the source path, nor the modules
        the role kinds come from: code is not hashed)."""
        d = self.to_dict()
        d.pop("source", None)
        d.pop("extra", None)
        d.pop("kinds", None)
        d["nodes"] = [_hashed_node(n) for n in d["nodes"]]
        _drop_later_defaults(d)
        blob = json.dumps(d, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


# Kinds that every node's hash names, present or not, as before kinds were registered: scenarios keep
# their hashes (summary.json's scenario_hash).
DIGEST_KINDS = ("worker", "client", "controller")


def _hashed_node(node: dict[str, Any]) -> dict[str, Any]:
    """A node as the digest has always hashed it: ``<kind>: bool`` and ``<kind>_impl: str`` for the
    ``DIGEST_KINDS`` and for every other kind the node has or names a class for."""
    node = dict(node)
    roles, impls = node.pop("roles"), dict(node.pop("impls"))
    for kind in dict.fromkeys((*DIGEST_KINDS, *roles, *impls)):
        node[kind] = kind in roles
        node[f"{kind}_impl"] = impls.get(kind, "")
    return node


# Settings added after scenarios were first hashed, with their defaults: left out of the digest while
# they hold them, so a scenario that does not use them keeps its hash.
LATER_SETTINGS: dict[str, Any] = {"admission": "decide_first", "control_latency": 2}
LATER_ARRIVAL: dict[str, Any] = {"process": "poisson"}
LATER_TASK_TYPE: dict[str, Any] = {"deadline_high": None, "grace": 0.0}


def _drop_later_defaults(d: dict[str, Any]) -> None:
    for part, later in [(d, LATER_SETTINGS), (d["workload"]["arrival"], LATER_ARRIVAL),
                        *((t, LATER_TASK_TYPE) for t in d["workload"]["task_types"])]:
        for key, default in later.items():
            if part.get(key, default) == default:
                part.pop(key, None)


def _plain(value: Any) -> Any:
    """Dataclasses and tuples to dicts and lists, so the result is JSON/msgpack friendly."""
    if hasattr(value, "__dataclass_fields__"):
        return {k: _plain(v) for k, v in asdict(value).items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value
