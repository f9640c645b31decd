"""What a controller knows when it decides: its own worker, the tasks to place, its neighbours.

This is the raw, partial and stale view (neighbours are heard one tick late). Node-side
policies read it directly; the RL environment turns it into fixed-shape arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from operator import attrgetter
from typing import Any

from node_runtime.model.messages import JobRef, TaskSize


@dataclass(slots=True)
class TaskView:
    id: int
    size: TaskSize  # the deadline in seconds, as created
    time_left: float  # seconds until the deadline passes
    waited: int  # ticks spent undecided
    origin: str
    job: JobRef | None = None  # a task of a job: its remaining critical path and its successors' data


@dataclass(slots=True)
class NodeView:
    """A node as the controller sees it: last broadcast load plus static facts."""

    node: str
    queue: int
    occupancy: int
    buffer: int
    capacity: float  # cycles per second
    tier: int
    rate_bps: float  # link rate from the observing node now (0 for itself, and for a moving neighbour out of range)
    age: int  # ticks since the state it reports was current
    worker: bool  # can take tasks
    backlog_s: float = 0.0  # seconds of transfer already queued on the link from the observing node to it
    drains_at: float = 0.0  # the tick its CPU would finish its admitted tasks (``Worker.drains_at``), as last heard

    def work_s(self, t: int, dt: float) -> float:
        """Seconds of CPU work left in its admitted tasks at the end of tick ``t``, as last heard."""
        return backlog(self.drains_at, t, dt)


def backlog(busy: float, t: int, dt: float) -> float:
    """Seconds of work still queued at the end of tick ``t`` on a link busy until tick ``busy``, or on a CPU that
    drains its queue at tick ``busy``."""
    end = t + 1
    return (busy - end) * dt if busy > end else 0.0


@dataclass(slots=True)
class Observation:
    tick: int
    node: str
    own: NodeView
    undecided: int  # undecided tasks at the own worker, as last reported
    tasks: list[TaskView]  # the tasks this decision places (binary: at most one)
    neighbours: list[NodeView]  # canonical neighbour order: action i -> neighbours[i - 1]
    busy_until: list[float] = field(default_factory=list)  # per neighbour link: the tick its queue empties at

    def valid_actions(self) -> list[bool]:
        """Action 0 keeps a task locally; action i sends it to neighbour i - 1 if that one is a worker and
        their link exists now (a moving neighbour out of range has rate 0)."""
        return [True, *(n.worker and n.rate_bps > 0.0 for n in self.neighbours)]

    def to_wire(self) -> list[Any]:
        """Compact arrays (field order of the dataclasses), documented in docs/bus.md."""
        return [self.tick, self.node, _node_fields(self.own), self.undecided,
                [[t.id, *t.size, t.time_left, t.waited, t.origin, None if t.job is None else list(t.job)]
                 for t in self.tasks],
                [_node_fields(n) for n in self.neighbours], self.busy_until]

    @classmethod
    def from_wire(cls, a: list[Any]) -> Observation:
        tasks = [TaskView(t[0], TaskSize(*t[1:6]), t[6], t[7], t[8], None if t[9] is None else JobRef(*t[9]))
                 for t in a[4]]
        return cls(a[0], a[1], NodeView(*a[2]), a[3], tasks, [NodeView(*n) for n in a[5]], a[6])


_node_fields = attrgetter(*(f.name for f in fields(NodeView)))
