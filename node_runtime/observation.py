"""What a controller knows when it decides: its own worker, the tasks to place, its neighbours.

This is the raw, partial and stale view (neighbours are heard one tick late, DESIGN §2). Node-side
policies read it directly; the RL environment turns it into fixed-shape arrays.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(slots=True)
class TaskView:
    id: int
    instructions: float
    input_bytes: float
    output_bytes: float
    cpi: float
    deadline: float  # seconds, as created
    time_left: float  # seconds until the deadline passes
    waited: int  # ticks spent undecided
    origin: str

    @property
    def cycles(self) -> float:
        return self.instructions * self.cpi


@dataclass(slots=True)
class NodeView:
    """A node as the controller sees it: last broadcast load plus static facts."""

    node: str
    queue: int
    occupancy: int
    buffer: int
    capacity: float  # cycles per second
    tier: int
    rate_bps: float  # link rate from the observing node (0 for itself)
    age: int  # ticks since the state it reports was current
    worker: bool  # can take tasks


@dataclass(slots=True)
class Observation:
    tick: int
    node: str
    own: NodeView
    undecided: int  # undecided tasks at the own worker, as last reported
    tasks: list[TaskView]  # the tasks this decision places (binary: at most one)
    neighbours: list[NodeView]  # canonical neighbour order: action i -> neighbours[i - 1]

    def valid_actions(self) -> list[bool]:
        """Action 0 keeps a task locally; action i sends it to neighbour i - 1 if that one is a worker."""
        return [True, *(n.worker for n in self.neighbours)]

    def to_wire(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_wire(cls, d: dict[str, Any]) -> Observation:
        return cls(
            tick=d["tick"],
            node=d["node"],
            own=NodeView(**d["own"]),
            undecided=d["undecided"],
            tasks=[TaskView(**t) for t in d["tasks"]],
            neighbours=[NodeView(**n) for n in d["neighbours"]],
        )
