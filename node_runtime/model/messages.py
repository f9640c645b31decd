"""Tasks and the messages roles exchange. Plain data: the codec maps them to msgpack arrays."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

# The longest deadline, in ticks, whose expiry tick is computed exactly: up to it, (tick - created) * dt
# tells consecutive ticks apart whatever dt. Scenarios are held to it; past it (a user's task source)
# a task is taken never to expire, which no run of fewer ticks can tell from the truth.
LONGEST_DEADLINE_TICKS = 2**50


class TaskSize(NamedTuple):
    """What one task asks of the network, <rho, alpha_in, alpha_out, xi, delta>: the one value that a
    trace row, a task, a worker's snapshot of it and a controller's view of it all carry. A tuple, so
    that a user's task source may give one as a plain tuple, and the codec writes it as its fields."""

    instructions: float  # rho
    input_bytes: float  # alpha_in
    output_bytes: float  # alpha_out
    cpi: float  # xi, cycles per instruction
    deadline: float  # delta, seconds from creation until the result must be back

    @property
    def cycles(self) -> float:
        return self.instructions * self.cpi


class JobRef(NamedTuple):
    """What a task of a job (docs/model.md, "Jobs as DAGs") carries of it: which job and which of its tasks,
    and what a DAG scheduler weighs: the cycles on the longest path from this task to the job's end (this
    task's own included), and the bytes its successors need from it."""

    job: int  # the job's id
    index: int  # the task's index in its job
    critical_cycles: float  # remaining critical path: the most cycles on a path from this task to an exit task
    successor_bytes: float  # the data of its out-edges, which its result carries back to the job's origin


@dataclass(slots=True)
class Task:
    """tau = <id, size>, plus where it comes from and where it went.

    ``path`` lists the worker nodes that have held the task, first the one its client handed it to;
    the result travels back along it. Ownership moves with the message that carries the task.
    """

    id: int
    origin: str  # node of the client that created it
    created: int  # tick
    size: TaskSize
    hops: int = 0  # offloads so far
    path: tuple[str, ...] = ()
    job: JobRef | None = None  # a task of a job, or a task on its own
    type: int | None = None  # index of its task type in workload.tasks (None: a trace row or source gave no type)

    def expired(self, tick: int, dt: float) -> bool:
        """Older than its deadline: (now - created) > delta."""
        return (tick - self.created) * dt > self.size.deadline

    def expires_at(self, dt: float) -> int:
        """The first tick at which ``expired`` holds (computed with ``expired`` itself, so that both
        always agree whatever the float rounding)."""
        ticks = self.size.deadline // dt
        if not ticks <= LONGEST_DEADLINE_TICKS:  # nan too; the loops below would never end
            return self.created + LONGEST_DEADLINE_TICKS
        t = self.created + int(ticks)
        while not self.expired(t, dt):
            t += 1
        while t > self.created and self.expired(t - 1, dt):
            t -= 1
        return t


@dataclass(slots=True)
class Result:
    """A finished task's output on its way back to the origin client."""

    task: Task
    executor: str  # node that ran it
    finished: int  # tick in which its last cycle ran
    hop: int  # position on task.path of the worker it is travelling to (or at)
    imposed: float = 0.0  # the waiting its service imposed on the tasks queued behind it, in their deadlines


@dataclass(slots=True)
class Decision:
    """Where one undecided task goes: ``target`` is a neighbour node, or "" to process locally."""

    task_id: int
    target: str


@dataclass(frozen=True, slots=True)
class Pending:
    """A snapshot of an undecided task, as the worker reports it to its controller.

    A snapshot rather than the task itself: the worker keeps owning (and may change) the task.
    """

    id: int
    origin: str
    created: int
    size: TaskSize
    arrived: int  # tick it entered the worker's buffer
    job: JobRef | None = None

    @classmethod
    def of(cls, task: Task, arrived: int) -> Pending:
        return cls(task.id, task.origin, task.created, task.size, arrived, task.job)


@dataclass(slots=True)
class Report:
    """What a worker tells its controller: the tasks it may place, and, when it changed since the last
    report, how long each of the node's links stays busy with what is queued on it
    (``LinkTransmitter.busy_until``, ticks, in the canonical neighbour order; None: unchanged)."""

    pending: list[Pending]
    busy_until: list[float] | None


@dataclass(slots=True)
class NodeState:
    """The one-hop state broadcast of a worker (static facts come from the scenario)."""

    node: str
    queue: int  # tasks admitted for local processing (including the one in service)
    occupancy: int  # queue + undecided: what counts against Q_max
    drains_at: float = 0.0  # the tick its CPU would finish those tasks at its capacity (``Worker.drains_at``)


class Kind(IntEnum):
    TASK = 1
    RESULT = 2
    DECISION = 3
    REPORT = 4
    STATE = 5


Body = Task | Result | list[Decision] | Report | NodeState


@dataclass(slots=True)
class Envelope:
    """A message between roles. Applied at tick ``arrive`` in canonical order (arrive, src, seq)."""

    kind: Kind
    src: str  # sending role id
    dst: str  # receiving role id, or a broadcast topic
    seq: int  # per-sender sequence number
    sent: int  # tick it was sent in
    arrive: int  # tick it is delivered at (>= sent + 1)
    body: Body

    def order(self) -> tuple[int, str, int]:
        return (self.arrive, self.src, self.seq)
