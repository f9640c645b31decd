"""The scenario model: what every node process needs to know, and nothing about files.

One typed description of each fact. The scenario file's sections that are values of the model (the
``simulation`` settings, task types and their deadlines, the arrival schedule, failures) are these
classes, validated where a scenario enters (``orchestrator.scenario`` for a file, ``from_dict`` for one
received over the bus) and then used as they are by every process. Nodes and links are resolved from
the file's profiles, topology sources and radio model, so the file describes them in its own terms
(``orchestrator.scenario.schema``) and ``NodeSpec``/``LinkSpec`` hold the result.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, field_validator, model_validator

from node_runtime.model.arrival import Arrival, Constant
from node_runtime.model.dag import Jobs
from node_runtime.model.messages import TaskSize
from node_runtime.model.mobility import Mobility, RadioRange
from node_runtime.model.plugins import is_import_path
from node_runtime.model.policies import POLICIES
from node_runtime.model.rng import MAX_SEED
from node_runtime.model.values import Count, Decibels, NonNeg, Pos, Strict, Tick

Mode = Literal["binary", "batch"]
Admission = Literal["decide_first", "queue_first"]
MIB = 1024 * 1024
# The most ticks an episode may last (steps x decision_interval): 2^31. The model could count further (a
# tick is exact as a msgpack int64 and its time tick x dt as a float up to 2^53), but no run gets there:
# at the fastest rate measured (about 7,000 ticks/s, docs/benchmarks.md) 2^31 ticks take 3.5 days and
# write hundreds of GB of CSV, so a longer episode is a typo (1e12 for 1e2), refused before it runs forever.
MAX_EPISODE_TICKS = 2**31
EpisodeLength = Annotated[int, Field(ge=1, le=MAX_EPISODE_TICKS)]


def episode_too_long(steps: int, decision_interval: int) -> str | None:
    """Why an episode of ``steps`` decision epochs of ``decision_interval`` ticks is too long, or None."""
    if steps * decision_interval <= MAX_EPISODE_TICKS:
        return None
    return (f"expected at most 2^31 ({MAX_EPISODE_TICKS}) ticks an episode, but {steps} steps of "
            f"{decision_interval} tick(s) are {steps * decision_interval}")


class Hardware(Strict):
    """What a node is made of. A scenario file's profiles and node entries give any of these (each one
    optional there, ``schema.ProfileCfg``); a resolved node has them all."""

    tier: Tick
    cores: Count
    frequency: Pos  # cycles per second, per core
    buffer: Count  # Q_max: queued + undecided tasks
    tx_power_dbm: Decibels
    idle_power_w: NonNeg
    kappa: NonNeg  # switched capacitance: compute energy = kappa * cycles * frequency**2
    payload_hz: Pos | None = None  # cycles per CPU-second of a payload measured on the host (None: cores x frequency)


class NodeSpec(Hardware):
    """One network node: its hardware, where it stands and the roles it has (usually a worker, optionally
    a client and a controller)."""

    id: str
    position: tuple[float, float]
    roles: tuple[str, ...]  # its role kinds, in canonical order (node_runtime.model.registry)
    policy: str = "local"  # node-side decision policy (a name, or an import path "module:Class")
    profile: str = ""  # hardware profile name, for display
    impls: tuple[tuple[str, str], ...] = ()  # kind -> import path of a user subclass of the kind's class
    params: tuple[tuple[str, Any], ...] = ()  # free parameters for user extensions (``params:`` key)
    mobility: Mobility | None = None  # how it moves from ``position`` (None: it stays there)

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


class DeadlineRange(Strict):
    """A deadline drawn per task: U[low, high) seconds, plus ``grace``."""

    low: Pos
    high: Pos
    grace: NonNeg = 0.0

    @model_validator(mode="after")
    def _ordered(self) -> DeadlineRange:
        if self.high <= self.low:
            raise ValueError("high must be > low (for a fixed deadline, give a number)")
        return self


# A number, or a range; the tags name the alternatives in errors (the scenario's key paths skip them).
Deadline = Annotated[Annotated[Pos, Tag("<number>")] | Annotated[DeadlineRange, Tag("<range>")],
                     Discriminator(lambda v: "<range>" if isinstance(v, dict | DeadlineRange) else "<number>")]


class Payload(Strict):
    """``workload.tasks[].payload``: the callable a worker runs for each task of the type, as
    ``call(task_id, **args)``; what it returns is ignored."""

    call: str  # import path "package.module:function"
    args: dict[str, Any] = Field(default_factory=dict)  # keyword arguments of every call

    @field_validator("call")
    @classmethod
    def _import_path(cls, v: str) -> str:
        if not is_import_path(v):
            raise ValueError(f"expected an import path like 'package.module:function' (got {v!r})")
        return v


class PayloadLog(Strict):
    """What a run does with its payloads' measured times (a run setting, not a scenario key:
    ``--payload-record``, ``--payload-replay``; ``node_runtime.model.payload``): measure only, measure and
    append each to ``path``, or replay ``path``."""

    mode: Literal["measure", "record", "replay"] = "measure"
    path: str = ""

    @model_validator(mode="after")
    def _path(self) -> PayloadLog:
        if (self.mode == "measure") != (not self.path):
            raise ValueError("record and replay need a path; measure takes none")
        return self


class TaskType(Strict):
    """A kind of task the clients create, tau = <rho, alpha_in, alpha_out, xi, delta>, and how often
    (``weight``, relative to the other types). Defaults follow the paper's parameter table."""

    name: str = "task"
    weight: Pos = 1.0
    instructions: Pos = 8.0e7  # rho
    input_bytes: Pos = 150.0 * MIB  # alpha_in
    output_bytes: Pos = 150.0 * MIB  # alpha_out
    cpi: Pos = 1.0  # xi, cycles per instruction
    deadline: Deadline = 100.0  # delta: seconds from creation until the result must be back
    payload: Payload | None = None  # real work a worker runs when a task of this type starts service

    @property
    def cycles(self) -> float:
        """CPU cycles one task of this type needs."""
        return self.size(self.longest_deadline).cycles

    def size(self, deadline: float) -> TaskSize:
        """The size of one task of this type, with the deadline drawn for it."""
        return TaskSize(self.instructions, self.input_bytes, self.output_bytes, self.cpi, deadline)

    @property
    def drawn(self) -> bool:
        """Whether each task of this type draws its own deadline."""
        return isinstance(self.deadline, DeadlineRange)

    @property
    def longest_deadline(self) -> float:
        """The bound of every deadline this type gives a task: the range's high end plus its grace (or
        the fixed value). No task of the type completes later than this."""
        d = self.deadline
        return d.high + d.grace if isinstance(d, DeadlineRange) else d

    def draw_deadline(self, rng: np.random.Generator | None) -> float:
        """δ of one new task: U[low, high) plus the grace for a range (drawn from ``rng``), else the fixed value."""
        d = self.deadline
        if isinstance(d, DeadlineRange):
            return float(rng.uniform(d.low, d.high)) + d.grace
        return d


@dataclass(frozen=True, slots=True)
class TraceRow:
    """One task of a trace: when, which client creates it, its size, and (an optional column) its task type."""

    time: float  # seconds from the episode start
    client: str
    size: TaskSize
    type: int | None = None  # index of the task type in workload.tasks it names (None: the column is empty)

    @classmethod
    def columns(cls) -> list[str]:
        """A trace file's header: time, client, then the fields of a task's size."""
        return ["time", "client", *TaskSize._fields]


class Workload(Strict):
    task_types: tuple[TaskType, ...]
    arrival: Arrival = Constant()
    client_rates: tuple[tuple[str, float], ...] = ()  # per-client constant overrides
    client_targets: tuple[tuple[str, tuple[str, ...]], ...] = ()  # client node -> worker nodes
    trace: tuple[TraceRow, ...] | None = None
    source: str = ""  # import path of a user TaskSource subclass ("" = Poisson / trace)
    jobs: Jobs | None = None  # every arrival is a job, a DAG of tasks (None: a task, of ``task_types``)


class Failure(Strict):
    """Node ``node`` is down for ``duration`` ticks from tick ``at``."""

    node: str
    at: Tick
    duration: Count

    @property
    def end(self) -> int:
        """The first tick the node is up again."""
        return self.at + self.duration


def known_policy(name: str) -> str:
    """A built-in policy's name, or an import path (imported when the scenario's extensions are checked)."""
    if name not in POLICIES and not is_import_path(name):
        raise ValueError(f"expected one of {', '.join(POLICIES)}, or an import path 'module:Class'")
    return name


class SimulationSettings(Strict):
    """The file's ``simulation`` section: how time runs and how decisions are made. Defaults follow the
    paper (1,000 steps of 1 s)."""

    dt: Pos = 1.0
    steps: EpisodeLength = 1000  # decision epochs in an episode
    seed: Annotated[int, Field(ge=0, le=MAX_SEED)] = 0
    mode: Mode = "binary"
    decision_interval: EpisodeLength = 1  # ticks per decision epoch
    max_hops: Tick = 1
    batch_size: Count = 4  # decisions per epoch in batch mode (fixed action shape)
    state_interval: Count = 1  # ticks between one-hop state broadcasts
    policy: str = "local"  # node-side decision policy of every node that names none
    admission: Admission = "decide_first"  # queue_first: arrivals are queued at once, decisions divert queued tasks
    control_latency: Literal[0, 2] = 2  # ticks between the state a controller observes and its decision's effect

    @field_validator("policy")
    @classmethod
    def _known_policy(cls, v: str) -> str:
        return known_policy(v)

    @model_validator(mode="after")
    def _episode_fits(self) -> SimulationSettings:
        if why := episode_too_long(self.steps, self.decision_interval):
            raise ValueError(f"steps x decision_interval: {why}")
        return self

    @property
    def episode_ticks(self) -> int:
        """Ticks in an episode: its steps of ``decision_interval`` ticks each."""
        return self.steps * self.decision_interval


class Scenario(SimulationSettings):
    """A resolved scenario: the settings, every node with its hardware and roles, every directed link with
    its rate, the workload and the failures."""

    name: str
    nodes: tuple[NodeSpec, ...]
    links: tuple[LinkSpec, ...]
    workload: Workload
    failures: tuple[Failure, ...] = ()
    kinds: tuple[tuple[str, str], ...] = ()  # role kinds the nodes have, in canonical order: (name, class path)
    source: str = ""  # the file it came from, for messages only
    extra: dict[str, Any] = Field(default_factory=dict)  # free-form metadata (description ...)
    payload_log: PayloadLog = PayloadLog()  # the run's payload times: measured, recorded or replayed (not hashed)
    radio: RadioRange | None = None  # the links of moving nodes: range, break rule, radio (None: no node moves)

    def replace(self, **changes: Any) -> Scenario:
        """A copy with ``changes``, validated again (its derived views are computed afresh)."""
        return type(self)(**{name: getattr(self, name) for name in type(self).model_fields} | changes)

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
    def moving(self) -> frozenset[str]:
        """The nodes that move."""
        return frozenset(n.id for n in self.nodes if n.mobility is not None)

    def moving_link(self, src: str, dst: str) -> bool:
        """Whether the link src -> dst follows positions (an end moves): it exists only within range."""
        return src in self.moving or dst in self.moving

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
            windows.setdefault(f.node, []).append((f.at, f.end))
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
        """Plain lists, dicts, strings and numbers, every default filled in: what travels over the bus
        (msgpack) or into JSON."""
        return self.model_dump(mode="json")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scenario:
        """A scenario received over the bus, validated as a file's sections are."""
        return cls.model_validate(d)

    def digest(self) -> str:
        """Content hash of everything that affects the emulation (not the source path, nor the modules
        the role kinds come from: code is not hashed). The hashed form is the one scenarios were first
        hashed in, so that summary.json's scenario_hash stays comparable across versions."""
        blob = json.dumps(_hashed(self), sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


# Kinds that every node's hash names, present or not, as before kinds were registered: scenarios keep
# their hashes (summary.json's scenario_hash).
DIGEST_KINDS = ("worker", "client", "controller")


def _hashed(sc: Scenario) -> dict[str, Any]:
    """The scenario in the form it was first hashed in: ``episode_ticks`` rather than steps, no default
    policy (each node's is hashed), every arrival key, a deadline as (deadline, deadline_high, grace), a
    failure as [start, end); settings added later are left out while they hold their defaults."""
    wl = sc.workload
    d: dict[str, Any] = {
        "name": sc.name, "dt": sc.dt, "episode_ticks": sc.episode_ticks, "seed": sc.seed, "mode": sc.mode,
        "decision_interval": sc.decision_interval, "max_hops": sc.max_hops, "batch_size": sc.batch_size,
        "state_interval": sc.state_interval,
        "nodes": [_hashed_node(n.model_dump()) for n in sc.nodes],
        "links": [asdict(lk) for lk in sc.links],
        "workload": {
            "task_types": [_hashed_task_type(t) for t in wl.task_types],
            "arrival": {"kind": wl.arrival.kind, **LEGACY_ARRIVAL, **wl.arrival.model_dump(exclude={"kind"})},
            "client_rates": [list(kv) for kv in wl.client_rates],
            "client_targets": [[c, list(ts)] for c, ts in wl.client_targets],
            "trace": None if wl.trace is None else [{"time": r.time, "client": r.client, **r.size._asdict(),
                                                     **({} if r.type is None else {"type": r.type})}
                                                    for r in wl.trace],
            "source": wl.source,
            **({} if wl.jobs is None else {"jobs": _hashed_jobs(wl.jobs)}),
        },
        "failures": [{"node": f.node, "start": f.at, "end": f.end} for f in sc.failures],
        "admission": sc.admission, "control_latency": sc.control_latency,
        "radio": None if sc.radio is None else sc.radio.model_dump(),
    }
    for part, later in [(d, LATER_SETTINGS), (d["workload"]["arrival"], LATER_ARRIVAL),
                        *((t, LATER_TASK_TYPE) for t in d["workload"]["task_types"])]:
        for key, default in later.items():
            if part.get(key, default) == default:
                part.pop(key, None)
    return json.loads(json.dumps(d))  # tuples as lists, as they were hashed


# Every arrival key with the default it had when all kinds shared one record
LEGACY_ARRIVAL: dict[str, Any] = {"rate": 0.17, "start": 0.0, "end": 0.0, "low": 0.0, "high": 0.0, "period": 100.0}


def _hashed_jobs(jobs: Jobs) -> dict[str, Any]:
    """The jobs, a task's ``type`` (added later) left out while unset."""
    d = jobs.model_dump(mode="json")
    for part in [d["generator"] or {}, *(t for job in d["dags"] for t in job["tasks"])]:
        if "type" in part and part["type"] is None:
            del part["type"]
    return d


def _hashed_task_type(t: TaskType) -> dict[str, Any]:
    d = t.deadline
    deadline = {"deadline": d.low, "deadline_high": d.high, "grace": d.grace} if isinstance(d, DeadlineRange) \
        else {"deadline": d, "deadline_high": None, "grace": 0.0}
    payload = {} if t.payload is None else {"payload": t.payload.model_dump()}
    return {"name": t.name, "weight": t.weight, "instructions": t.instructions, "input_bytes": t.input_bytes,
            "output_bytes": t.output_bytes, "cpi": t.cpi, **deadline, **payload}


def _hashed_node(node: dict[str, Any]) -> dict[str, Any]:
    """A node as the digest has always hashed it: ``<kind>: bool`` and ``<kind>_impl: str`` for the
    ``DIGEST_KINDS`` and for every other kind the node has or names a class for."""
    node = dict(node)
    for later in ("payload_hz", "mobility"):  # added later: left out while unset
        if node.get(later) is None:
            node.pop(later, None)
    roles, impls = node.pop("roles"), dict(node.pop("impls"))
    for kind in dict.fromkeys((*DIGEST_KINDS, *roles, *impls)):
        node[kind] = kind in roles
        node[f"{kind}_impl"] = impls.get(kind, "")
    return node


# Settings added after scenarios were first hashed, with their defaults: left out of the digest while
# they hold them, so a scenario that does not use them keeps its hash.
LATER_SETTINGS: dict[str, Any] = {"admission": "decide_first", "control_latency": 2, "radio": None}
LATER_ARRIVAL: dict[str, Any] = {"process": "poisson"}
LATER_TASK_TYPE: dict[str, Any] = {"deadline_high": None, "grace": 0.0}
