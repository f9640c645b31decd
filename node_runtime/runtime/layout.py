"""Who runs where: role ids, process layouts and broadcast subscriptions.

Roles are the unit of behaviour (worker, client, controller of one node, or a registered kind);
processes are the unit of deployment. A layout maps roles to processes. Message order never depends
on the layout: it is fixed by role ids, so every layout yields the same emulation.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property

import psutil

from node_runtime.model.registry import RoleKind, kinds_of
from node_runtime.model.role import role_id, role_kind, role_node
from node_runtime.model.spec import Scenario

Layout = str  # per-role, per-node, single or groups:K (check_layout)
LAYOUT_HELP = ("per-role: a process per role; per-node: a process per node; single: one process; groups:K: "
               "K processes, each running a contiguous block of nodes (fewer processes than nodes, for large "
               "scenarios)")


def check_layout(name: str) -> Layout:
    """``name`` if it names a layout; a ValueError saying what is expected otherwise."""
    if name in ("per-role", "per-node", "single"):
        return name
    kind, sep, count = name.partition(":")
    if kind == "groups" and sep and count.isdigit() and int(count) >= 1:
        return f"groups:{int(count)}"
    raise ValueError(f"unknown layout {name!r}: expected per-role, per-node, single or groups:K with K >= 1")


def _groups(layout: Layout) -> int:
    return int(layout.partition(":")[2])


# The default layout over Zenoh (docs/protocol.md#the-default-layout). Measured on 2 cores: per-role is ready
# in 1-2.5 s up to 72 processes (aot1-aot4), 10 s at 102 and 27 s at 300 (3,000 were reported not ready in 7 min);
# a node process has 43 MB resident, 7-10 MB of it its own (the rest shared with the fork server).
PROCESSES_PER_CPU = 50  # per-role while its processes number at most this per core ...
PROCESS_MEMORY = 32 * 2**20  # ... and this much memory each (bytes, with a margin over the measured) ...
MEMORY_SHARE = 0.5  # ... fits in this share of the memory available
GROUPS_PER_CPU = 2  # otherwise groups:K with K = this x cores: K from 2 to 16 ran within 2x of each other
DEFAULT_LAYOUT_HELP = (f"per-role while its processes fit this machine (at most {PROCESSES_PER_CPU} a core, and "
                       f"{PROCESS_MEMORY // 2**20} MB each within {MEMORY_SHARE * 100:.0f} percent of the memory "
                       f"available), else groups:K with K = {GROUPS_PER_CPU} x cores "
                       "(docs/protocol.md#the-default-layout)")


@dataclass(frozen=True)
class Machine:
    """What the default layout must fit: the cores this process may run on, the memory available."""

    cpus: int
    memory: int  # bytes

    @classmethod
    def here(cls) -> Machine:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        return cls(cpus, psutil.virtual_memory().available)

    @property
    def processes(self) -> int:
        """How many node processes fit: per core, and in the memory."""
        return min(PROCESSES_PER_CPU * self.cpus, int(self.memory * MEMORY_SHARE) // PROCESS_MEMORY)


@dataclass(frozen=True)
class Choice:
    """A default layout, and the line that says why when it is not per-role (None when it is)."""

    layout: Layout
    note: str | None = None


def default_layout(processes: int, nodes: int, machine: Machine) -> Choice:
    """The layout over Zenoh when none is given: per-role (a process per role, ``processes`` of them)
    while that fits ``machine``; else ``groups:K``, K = GROUPS_PER_CPU x cores (at most ``nodes``)."""
    if processes <= machine.processes:
        return Choice("per-role")
    layout = f"groups:{max(1, min(nodes, GROUPS_PER_CPU * machine.cpus))}"
    return Choice(layout, f"layout {layout}: {processes} processes (per-role) would not fit {machine.cpus} "
                          f"core{'s' if machine.cpus != 1 else ''} and {machine.memory / 2**30:.1f} GB available "
                          f"(at most {machine.processes}); --layout per-role forces a process per role")


def layout_for(scenario: Scenario, transport: str, machine: Machine | None = None, placed: bool = False) -> Choice:
    """The default layout of a simulation: ``single`` in-process; over Zenoh, ``default_layout`` of this
    machine, or per-role when nodes are placed on other hosts (their processes are not this machine's)."""
    if transport == "inproc":
        return Choice("single")
    if placed:
        return Choice("per-role")
    per_role = ProcessLayout(scenario, "per-role")
    return default_layout(len(per_role.procs), len(scenario.nodes), machine or Machine.here())


@dataclass(frozen=True)
class ProcessLayout:
    """Which process hosts each role, and who listens to which broadcast: derived by every process
    from the scenario and the layout name, so no table travels on the bus."""

    scenario: Scenario
    layout: Layout

    def __post_init__(self) -> None:
        check_layout(self.layout)

    def proc_for(self, role: str) -> str:
        node = role_node(role)
        if self.layout == "per-role":
            return f"{role_kind(role)}-{node}"
        if self.layout == "per-node":
            return f"node-{node}"
        if self.layout == "single":
            return "all"
        k, n = _groups(self.layout), len(self.scenario.nodes)
        return f"group-{self.scenario.index[node] * min(k, n) // n}"

    @cached_property
    def kinds(self) -> dict[str, RoleKind]:
        """The role kinds of the scenario (node_runtime.model.registry), imported here if need be."""
        return kinds_of(self.scenario)

    @cached_property
    def roles(self) -> tuple[str, ...]:
        """All roles in canonical order: by node, then by kind (worker, client, controller, ...)."""
        return tuple(role_id(kind, n.id) for n in self.scenario.nodes for kind in n.roles)

    def kind_of(self, role: str) -> RoleKind:
        return self.kinds[role_kind(role)]

    @cached_property
    def role_index(self) -> dict[str, int]:
        """Roles are named by this index on the wire (a small int instead of a string)."""
        return {r: i for i, r in enumerate(self.roles)}

    @cached_property
    def proc_index(self) -> dict[str, int]:
        return {p: i for i, p in enumerate(self.procs)}

    @cached_property
    def proc_of(self) -> dict[str, str]:
        """With co-located control (control_latency 0) a controller always shares its worker's process."""
        colocated = self.scenario.colocated_control
        return {r: self.proc_for(role_id("worker", role_node(r))
                                 if colocated and role_kind(r) == "controller" else r) for r in self.roles}

    @cached_property
    def procs(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.proc_of[r] for r in self.roles))

    @cached_property
    def roles_of(self) -> dict[str, tuple[str, ...]]:
        out: dict[str, list[str]] = {p: [] for p in self.procs}
        for r in self.roles:
            out[self.proc_of[r]].append(r)
        return {p: tuple(rs) for p, rs in out.items()}

    @cached_property
    def subscriptions(self) -> dict[str, tuple[str, ...]]:
        """Broadcast topics each role listens to, as its kind declares (a controller: its own node's
        and its neighbours' states)."""
        sc = self.scenario
        return {r: self.kind_of(r).subscribes(sc.node[role_node(r)], sc) for r in self.roles}

    @cached_property
    def publications(self) -> dict[str, tuple[str, ...]]:
        """Broadcast topics each role publishes on, as its kind declares (a worker: its node's state)."""
        sc = self.scenario
        return {r: self.kind_of(r).publishes(sc.node[role_node(r)], sc) for r in self.roles}

    @cached_property
    def subscribers(self) -> dict[str, tuple[str, ...]]:
        """Roles listening to each topic, in canonical role order."""
        out: dict[str, list[str]] = {}
        for r in self.roles:
            for topic in self.subscriptions[r]:
                out.setdefault(topic, []).append(r)
        return {t: tuple(rs) for t, rs in out.items()}

    def destinations(self, proc: str) -> tuple[str, ...]:
        """Processes this one may send mail to: those hosting roles of its nodes or their neighbours."""
        nodes: dict[str, None] = {}
        for n in self.node_of_proc(proc):
            nodes[n] = None
            nodes.update(dict.fromkeys(self.scenario.neighbours[n]))
        procs = dict.fromkeys(self.proc_of[r] for r in self.roles if role_node(r) in nodes)
        procs.pop(proc, None)
        return tuple(procs)

    @cached_property
    def listeners(self) -> dict[str, tuple[str, ...]]:
        """The other processes hearing each process's broadcasts: those hosting a subscriber of a topic
        that one of its roles publishes on. They all get the process's broadcasts of a tick as one batch,
        so a process of many nodes sends one message per tick rather than one per node."""
        out = {}
        for proc in self.procs:
            heard = {self.proc_of[r] for w in self.roles_of[proc] for topic in self.publications[w]
                     for r in self.subscribers.get(topic, ())}
            heard.discard(proc)
            out[proc] = tuple(sorted(heard, key=self.proc_index.__getitem__))
        return out

    @cached_property
    def broadcasters(self) -> dict[str, tuple[str, ...]]:
        """The processes whose broadcasts each process hears (the inverse of ``listeners``)."""
        out: dict[str, list[str]] = {p: [] for p in self.procs}
        for proc, them in self.listeners.items():
            for p in them:
                out[p].append(proc)
        return {p: tuple(them) for p, them in out.items()}

    @cached_property
    def recipients(self) -> dict[str, frozenset[str]]:
        """Processes each process may publish to: those it may mail, and those hearing its roles' broadcasts."""
        return {proc: frozenset(self.destinations(proc)).union(self.listeners[proc]) for proc in self.procs}

    def node_of_proc(self, proc: str) -> tuple[str, ...]:
        """Nodes whose roles a process hosts (for error messages naming a node)."""
        return tuple(dict.fromkeys(role_node(r) for r in self.roles_of[proc]))
