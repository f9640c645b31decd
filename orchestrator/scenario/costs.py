"""What one task costs on each device, against its deadline: what ``orchestrator validate`` prints under the
counts, so that a scenario whose tasks cannot be served in time says so before it runs.

A device is the distinct hardware (profile, cores, frequency) of the nodes that serve tasks. One task
alone on it takes ``TaskType.cycles / NodeSpec.capacity`` seconds of service (docs/model.md: the CPU
spends cores x frequency cycles a second on the head of its queue), and its input and output take
8 x bytes / rate seconds on a link (the median rate of the links into the device's nodes). A device
*receives* a task type when its nodes are targets of a task source (tasks arrive there) or lie within
``max_hops`` hops of one (tasks are offloaded there: one transfer each way at the least).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

from node_runtime.model.spec import NodeSpec, Scenario, TaskType
from node_runtime.model.workload import nominal_arrivals


@dataclass(frozen=True)
class Device:
    name: str  # the profile's name, or cores x frequency where nodes of one profile differ
    nodes: tuple[NodeSpec, ...]
    rate_bps: float | None  # median rate of the links into its nodes (None: no link reaches them)

    @property
    def capacity(self) -> float:
        return self.nodes[0].capacity

    def service_s(self, task: TaskType) -> float:
        return task.cycles / self.capacity

    def transfer_s(self, size_bytes: float) -> float | None:
        return None if self.rate_bps is None else size_bytes * 8.0 / self.rate_bps


def devices(sc: Scenario) -> list[Device]:
    """The devices of the nodes with a worker, fastest first."""
    groups: dict[tuple[str, int, float], list[NodeSpec]] = {}
    for n in sc.nodes:
        if n.has("worker"):
            groups.setdefault((n.profile, n.cores, n.frequency), []).append(n)
    profiles = [profile for profile, _, _ in groups]
    out = []
    for (profile, cores, frequency), nodes in groups.items():
        name = profile if profile and profiles.count(profile) == 1 else \
            f"{profile or 'node'} ({cores}x{frequency / 1e6:g} MHz)"
        ids = {n.id for n in nodes}
        rates = [link.rate_bps for link in sc.links if link.dst in ids]
        out.append(Device(name, tuple(nodes), statistics.median(rates) if rates else None))
    return sorted(out, key=lambda d: -d.capacity)


def within(sc: Scenario, start: set[str], hops: int) -> set[str]:
    """Nodes at most ``hops`` hops from ``start``."""
    seen, frontier = set(start), set(start)
    for _ in range(hops):
        frontier = {m for n in frontier for m in sc.neighbours[n]} - seen
        seen |= frontier
    return seen


def seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g} s"


def report(sc: Scenario) -> list[str]:
    """The table of costs, then one ``warning:`` line per task type that cannot meet its deadline even alone
    on a device that receives it, and per task target that receives more work than it can serve."""
    if sc.workload.trace is not None:
        return [f"trace workload: {len(sc.workload.trace)} tasks, each sized by its row (no task types to cost)"]
    if (jobs := sc.workload.jobs) is not None:
        source = (f"{len(jobs.dags)} listed DAG(s), {sum(len(d.tasks) for d in jobs.dags)} tasks in all"
                  if jobs.dags else "DAGs drawn by the layered generator")
        paid = [t.name for t in sc.workload.task_types if t.payload is not None]
        runs = f"; the tasks of type(s) {', '.join(paid)} run a payload" if paid else ""
        return [f"jobs workload: every arrival is a job, one of {source}, due in at most {jobs.longest_deadline:g} s "
                f"(no task types to cost){runs}"]
    arriving = {n for targets in sc.targets.values() for n in targets}
    reached = within(sc, arriving, sc.max_hops)
    kinds = devices(sc)
    rows = [("task type", "device", "nodes", "service", "input", "output", "deadline")]
    warnings = []
    for task in sc.workload.task_types:
        deadline = f"{task.deadline:g} s" if not task.drawn else f"{task.deadline.low:g}-{task.longest_deadline:g} s"
        for d in kinds:
            service, up, down = d.service_s(task), d.transfer_s(task.input_bytes), d.transfer_s(task.output_bytes)
            rows.append((task.name, d.name, str(len(d.nodes)), seconds(service), seconds(up), seconds(down), deadline))
            ids = {n.id for n in d.nodes}
            if ids & arriving:
                best = service  # served where it arrives
            elif ids & reached and up is not None and down is not None:
                best = up + service + down  # offloaded there
            else:
                continue  # no task of this type gets there
            if best > task.longest_deadline:
                how = "of service" if ids & arriving else f"with its input and output on {d.rate_bps / 1e6:.3g} Mbit/s"
                warnings.append(f"warning: task type {task.name!r} cannot meet its deadline "
                                f"({task.longest_deadline:g} s) even alone on {d.name}: {best:.3g} s {how}")
    warnings += overloads(sc, kinds) + undecided(sc)
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    table = ["  " + "  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                              for i, (c, w) in enumerate(zip(r, widths, strict=True))) for r in rows]
    intro = (f"one task alone: service = instructions x cpi / (cores x frequency); input and output at the median "
             f"rate of the links into the device; tasks arrive at {len(arriving)} node(s) and are offloaded at most "
             f"{sc.max_hops} hop(s)")
    paid = [t.name for t in sc.workload.task_types if t.payload is not None]
    if paid:  # their real service is known only when they run
        intro += (f"; task type(s) {', '.join(paid)} run a payload: their service is its measured CPU time x the "
                  "node's payload_hz, the nominal one above until they run")
    return [intro, *table, *warnings]


def overloads(sc: Scenario, kinds: list[Device]) -> list[str]:
    """One ``warning:`` line per device whose nodes receive more work from task sources than they serve."""
    total = sum(t.weight for t in sc.workload.task_types)
    cycles = sum(t.weight * t.cycles for t in sc.workload.task_types) / total  # of a task on average
    arrivals = nominal_arrivals(sc)
    out = []
    for d in kinds:
        loads = {n.id: arrivals[n.id] * cycles / d.capacity for n in d.nodes if n.id in arrivals}
        over = [n for n, load in loads.items() if load > 1.0]
        if over:
            worst = max(over, key=loads.__getitem__)
            named = ", ".join(over[:3]) + (" ..." if len(over) > 3 else "")
            out.append(f"warning: {len(over)} {d.name} node(s) ({named}) "
                       f"receive more work than they serve, up to {loads[worst]:.3g} times ({arrivals[worst]:.3g} "
                       f"tasks/s of {cycles / d.capacity:.3g} s of service at {worst}): what they do not offload "
                       "queues, and is dropped when the buffer is full or the deadline passes")
    return out


def load_ratio(sc: Scenario) -> float:
    """The work the task sources bring each second (nominal arrivals x a task's mean cycles) over the cycles
    every worker of the network serves each second. Above 1 no policy serves every task: some must be lost."""
    total = sum(t.weight for t in sc.workload.task_types)
    cycles = sum(t.weight * t.cycles for t in sc.workload.task_types) / total
    capacity = sum(n.capacity for n in sc.nodes if n.has("worker"))
    return sum(nominal_arrivals(sc).values()) * cycles / capacity if capacity else math.inf


def undecided(sc: Scenario) -> list[str]:
    """A ``warning:`` line when tasks reach controllers faster than they place them. A controller places one
    task a step in binary mode (``batch_size`` in batch mode); with decide_first admission the rest wait
    undecided, count against the buffer and expire (docs/model.md, "The controller")."""
    if sc.admission != "decide_first":
        return []
    places = 1 if sc.mode == "binary" else sc.batch_size
    arrivals = nominal_arrivals(sc)
    per_step = {n: arrivals[n] * sc.dt * sc.decision_interval for n in sc.controllers if n in arrivals}
    over = [n for n, tasks in per_step.items() if tasks > places]
    if not over:
        return []
    worst = max(over, key=per_step.__getitem__)
    named = ", ".join(over[:3]) + (" ..." if len(over) > 3 else "")
    need = math.ceil(per_step[worst])
    return [f"warning: tasks reach the controllers of {len(over)} node(s) ({named}) faster than they place them, up to "
            f"{per_step[worst]:.3g} a step at {worst} where a controller places {places} a step ({sc.mode} mode): "
            f"the rest wait undecided, fill the buffer and expire (batch mode with batch_size >= {need}, or "
            "admission: queue_first, places them all)"]
