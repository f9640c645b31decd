"""What every role shares: identity, an outbox to send through, and the accounting counters.

A role is a deterministic function of (its state, the tick, its inbox in canonical order). It never
touches a transport: it hands envelopes to its ``Outbox`` and the host decides how they travel.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from operator import attrgetter
from typing import ClassVar

from node_runtime.model.energy import transmit_energy
from node_runtime.model.messages import Body, Envelope, Kind, Task
from node_runtime.model.positions import Positions
from node_runtime.model.radio import Radio
from node_runtime.model.spec import NodeSpec, Scenario


def role_id(kind: str, node: str) -> str:
    """A role's address: mail is sent to it, and message order is fixed by it."""
    return f"{kind}:{node}"


def role_kind(role: str) -> str:
    return role.split(":", 1)[0]


def role_node(role: str) -> str:
    return role.split(":", 1)[1]


def state_topic(node: str) -> str:
    """The topic a node's worker broadcasts its load on."""
    return f"state/{node}"


DROP_CAUSES = ("queue_full", "expired", "node_failure", "link_loss", "link_broken")

# what a ``Counters.ledger`` entry (task id, kind, value) says of its task
COMPLETED = 0  # its result reached its origin; value: the response time in seconds
LOST = 1  # it was dropped, by any cause; value: 0
CHARGED = 2  # it made another task wait (in a CPU queue or on a link); value: that wait, in the waiter's deadlines


@dataclass(slots=True)
class Counters:
    """Cumulative per-role accounting since the last reset, plus a few current levels.

    Conservation is checked over the sum of these across all roles: every task a client generated
    is completed, dropped (by exactly one cause), or held by some role or link (the tasks and results
    on links are counted by the orchestrator, from the arrival ticks that ``Done`` reports).
    """

    generated: int = 0
    completed: int = 0
    queue_full: int = 0
    expired: int = 0
    node_failure: int = 0
    link_loss: int = 0
    link_broken: int = 0  # on a link whose moving end went out of range (docs/model.md, "Moving nodes")
    offloaded: int = 0
    decisions: int = 0
    stale_decisions: int = 0
    overloaded_ticks: int = 0
    busy_cycles: float = 0.0
    energy_compute: float = 0.0
    energy_idle: float = 0.0
    energy_transmit: float = 0.0
    # waiting this node's decisions imposed on other tasks, each wait in deadlines of the task that waited
    # (2 s imposed on a task due in 10 s count 0.2): on its links (the sending worker counts it) and in the
    # CPU queue of the task's executor (the origin's client counts it from the result)
    delay_imposed: float = 0.0
    # levels at the end of the tick
    queue: int = 0
    undecided: int = 0
    overloaded: int = 0  # 1 if the buffer was full at the start of this tick
    # jobs (docs/model.md, "Jobs as DAGs"), counted by the client that created them: created, completed (every
    # task's result back in time), missed (past the deadline first), the sum of the completed ones' makespans
    # in seconds, and the level of those still running
    jobs: int = 0
    jobs_completed: int = 0
    jobs_missed: int = 0
    makespan_sum: float = 0.0
    jobs_active: int = 0
    # this tick's entries per task, (task id, COMPLETED | LOST | CHARGED, value), drained by the host every
    # tick: the response times of the tick's completions, and what follows a task to the decision that placed
    # it (the environment's per-task credit)
    ledger: list[tuple[int, int, float]] = field(default_factory=list)


STAT_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(Counters) if f.name != "ledger")
read_stats = attrgetter(*STAT_FIELDS)  # Counters -> tuple of STAT_FIELDS, in one C call


class Outbox:
    """Collects one role's envelopes during its tick, numbering them with the role's sequence."""

    __slots__ = ("_seq", "broadcasts", "envelopes", "events", "role", "tick")

    def __init__(self, role: str) -> None:
        self.role = role
        self.tick = 0
        self._seq = 0
        self.envelopes: list[Envelope] = []  # addressed to one role
        self.broadcasts: list[Envelope] = []  # addressed to a topic
        self.events: list[tuple[str, str, dict]] | None = None  # (kind, node, fields) while a monitor listens

    def reset(self) -> None:
        self._seq = 0
        self.envelopes.clear()
        self.broadcasts.clear()

    def send(self, kind: Kind, dst: str, body: Body, arrive: int | None = None) -> None:
        """Send to role ``dst``; ``arrive`` defaults to the next tick (the minimum delay)."""
        t = self.tick
        if arrive is None:
            arrive = t + 1
        elif arrive <= t:
            raise ValueError(f"{self.role}: a message sent in tick {t} cannot arrive at tick {arrive}")
        self._seq += 1
        self.envelopes.append(Envelope(kind, self.role, dst, self._seq, t, arrive, body))

    def emit(self, kind: str, node: str, **fields: object) -> None:
        """Record a monitoring event (docs/bus.md). Costs nothing when nobody listens."""
        if self.events is not None:
            self.events.append((kind, node, fields))

    def broadcast(self, kind: Kind, topic: str, body: Body) -> None:
        """Publish on a topic; every subscribing role receives it next tick."""
        self._seq += 1
        t = self.tick
        self.broadcasts.append(Envelope(kind, self.role, topic, self._seq, t, t + 1, body))


class Role:
    """Base of every role kind (worker, client, controller, and those users register: ``registry``).
    Subclasses implement ``reset`` and ``tick``, and may implement ``wake`` to let their process
    sleep through ticks in which they have nothing to do."""

    kind: ClassVar[str]
    radio: Radio | None = None  # set by the role that owns the node's links
    # set by ``wake`` when the role coasts through the ticks it skips: what each of them adds to its
    # counters (STAT_FIELDS order); None when they change nothing
    drift: tuple[float, ...] | None = None
    # True when its tick, at a tick it is not due (``wake``) and with only broadcasts in its inbox, would do
    # nothing but record them for later: its process may then take them at its next run rather than wake
    # for them (docs/protocol.md, "Mail that waits")
    holds_broadcasts: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: object) -> None:
        """A class that redefines ``tick`` but not ``wake`` may act in ticks its parent's ``wake``
        skips: it runs every tick, so its results cannot depend on the process layout."""
        super().__init_subclass__(**kwargs)
        if "tick" in cls.__dict__ and "wake" not in cls.__dict__:
            cls.wake = Role.wake

    def __init__(self, node: NodeSpec, scenario: Scenario) -> None:
        self.node = node
        self.scenario = scenario
        self.id = role_id(self.kind, node.id)
        self.index = scenario.index[node.id]
        self.stats = Counters()
        self.outages = scenario.failure_windows.get(node.id, ())  # [start, end) tick windows
        self.positions = None if scenario.radio is None else Positions(scenario)  # where nodes are, if some move

    def down(self, t: int) -> bool:
        """Whether this role's node has failed at tick ``t`` (scheduled in the scenario)."""
        return bool(self.outages) and any(a <= t < b for a, b in self.outages)

    def reset(self, seed: int) -> None:
        self.stats = Counters()
        if self.positions is not None:
            self.positions.reset(seed)

    def drop(self, out: Outbox, cause: str, task_id: int) -> None:
        """Account for one lost task, by exactly one cause (conservation depends on it)."""
        setattr(self.stats, cause, getattr(self.stats, cause) + 1)
        self.stats.ledger.append((task_id, LOST, 0.0))
        if out.events is not None:
            out.emit("dropped", self.node.id, task=task_id, cause=cause, role=self.kind)

    def urgency(self, task: Task) -> float:
        """What one second of waiting costs ``task``, in its own deadlines (a deadline under a tick counts
        one tick): the weight of the delay imposed on it (``Counters.delay_imposed``)."""
        return 1.0 / max(task.size.deadline, self.scenario.dt)

    def transmit(self, t: int, kind: Kind, dst_node: str, dst_role: str, body: Body, bits: float,
                 out: Outbox, charged: bool = False) -> None:
        """Queue a message on this node's link to ``dst_node``; it may expire in the queue or be lost.
        ``charged``: the message is this node's decision, and the waiting it imposes on the later messages
        of the link counts as this node's ``delay_imposed`` (and in the ledger, as its task's charge)."""
        task = body if kind == Kind.TASK else body.task
        sent = self.radio.send(t, dst_node, bits, task.created + task.size.deadline / self.scenario.dt,
                               task.id if charged else None)
        if isinstance(sent, str):
            self.drop(out, sent, task.id)
            return
        arrive, seconds, ahead = sent
        st = self.stats
        st.energy_transmit += transmit_energy(self.node.tx_power_dbm, seconds)
        if ahead:
            urgency = self.urgency(task)
            for other, waited in ahead:
                charge = waited * urgency
                st.delay_imposed += charge
                st.ledger.append((other, CHARGED, charge))
        out.send(kind, dst_role, body, arrive)

    def tick(self, t: int, inbox: list[Envelope], out: Outbox) -> None:
        raise NotImplementedError

    def wake(self, t: int) -> float:
        """After tick ``t``: the next tick at which this role must run even if no mail arrives for it
        (``math.inf``: only mail wakes it). Its ``tick`` with an empty inbox at any tick before that
        must change nothing, so a process may skip it (docs/protocol.md, "Sleeping through idle ticks"),
        or nothing but its counters, by the same ``drift`` each tick, which its next ``tick`` replays;
        the default runs every tick."""
        return t + 1

    def reads_later(self, env: Envelope) -> bool:
        """Whether ``env``, mail from a role of the same process, may wait unread until this role next runs:
        its tick at the envelope's arrival, were it not due then, would only record it (docs/protocol.md,
        "Mail that waits"). The host then does not wake the process for it. By default only broadcasts
        wait (mail to a topic rather than to this role), and only for a role that ``holds_broadcasts``."""
        return self.holds_broadcasts and env.dst != self.id
