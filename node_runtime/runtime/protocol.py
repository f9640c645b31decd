"""Messages of the clock protocol (docs/protocol.md), as opposed to the model's messages.

- ``Tick``: the orchestrator opens tick t for a process (or for all of them), telling it how many
  publications sent in tick t - 1 it must have received first, and carrying the agents' actions;
- ``Batch``: one process's mail of one tick for one destination process (or one broadcast topic);
- ``Done``: a process finished tick t: what it sent to whom, its roles' accounting, and the next
  tick at which it has work of its own. Only processes with mail or work due get a tick: the others
  sleep, which is what makes a mostly idle network cheap;
- ``Dones``: the ``Done`` reports of one tick from the processes of one host, sent by that host's
  aggregator, so that the orchestrator hears one message a host, not one a process.

Processes and roles are named by their canonical index (``ProcessLayout.procs`` / ``ProcessLayout.roles``
order): every participant derives the same indices from the scenario and the layout, and small ints
decode faster than strings in dozens of processes every tick.

Every message names its episode, so mail from a previous episode that is still on the wire after
a reset is recognised and ignored. Ticks, reports and hosts' reports also name the *epoch* of the clock
they belong to (who held it: the orchestrator, or one claim of a driver) and carry a MAC that proves who
sent them (``origin``, docs/security.md); ``mac`` and ``signed`` (what the MAC covers) are filled as the
message is sent and received, and are no part of its content.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from node_runtime.model.messages import Envelope
from node_runtime.model.view import Observation

SCHEMA_VERSION = 15
Command = Literal["run", "reset", "stop", "fence"]  # fence: only says a new epoch began (docs/protocol.md)


@dataclass(slots=True)
class Tick:
    episode: int
    tick: int
    command: Command = "run"
    expect: dict[int, int] = field(default_factory=dict)  # process index -> publications to take: sent in
    # tick - 1, and those held for it since it last ran (``Done.held``)
    actions: dict[str, Any] = field(default_factory=dict)  # controller role -> action
    seed: int = 0  # reset only
    external: list[str] = field(default_factory=list)  # reset only: controllers an agent drives
    policy: str | None = None  # reset only: node-side policy override for every controller
    # worker role index -> (queue, occupancy, drains_at, tick sent, seq): the latest state it broadcast that roles
    # of this process (of any, in a tick for all) have yet to read, when its states go through the clock
    # (``host.states_by_clock``)
    states: dict[int, tuple[int, int, float, int, int]] = field(default_factory=dict)
    epoch: int = 0  # of the clock: a node takes ticks of the newest epoch it has seen only
    mac: bytes | None = field(default=None, compare=False, repr=False)
    signed: bytes = field(default=b"", compare=False, repr=False)


@dataclass(slots=True)
class Batch:
    episode: int
    tick: int  # sent in
    src: str  # sending process
    envelopes: list[Envelope]


@dataclass(slots=True)
class Done:
    """A process's report at the end of a tick: what it sent, and the state of its roles."""

    proc: str
    episode: int
    tick: int
    sent: dict[int, int]  # destination process index -> publications
    stats: dict[int, tuple]  # role index -> values of STAT_FIELDS (changed roles only)
    response_times: dict[int, list[float]] = field(default_factory=dict)  # client role index -> this tick's
    flights: dict[int, dict[int, int]] = field(default_factory=dict)  # role index -> {arrival tick: tasks/results sent}
    wake: int | None = None  # the next tick this process must run without mail; None: only mail wakes it
    obs: dict[int, Observation] = field(default_factory=dict)  # externally driven controller index -> its view
    error: str | None = None  # set when the process failed; it exits after sending this
    rejected: dict[str, int] = field(default_factory=dict)  # reason -> messages this process refused so far;
    # only in the first Done after the counts changed (docs/bus.md, "Rejected messages")
    ledger: dict[int, list[tuple[int, int, float]]] = field(default_factory=dict)  # role index -> this tick's
    # (task id, kind, value) entries (``role.Counters.ledger``); only while an agent drives the episode
    drift: dict[int, tuple] = field(default_factory=dict)  # role index -> what each tick it sleeps through adds
    # to its stats (``Role.drift``), from the next tick until it reports again; given with its stats
    held: dict[int, tuple[int, int | None]] = field(default_factory=dict)  # destination process index ->
    # (publications that need not wake it next tick, the tick it must run by to read them in time, or None: at
    # its next run): mail that arrives later, broadcasts to roles that hold them (docs/protocol.md)
    # worker role index -> the (queue, occupancy, drains_at, seq) it broadcast this tick: when its states go through
    # the clock (``Tick.states``), and while an agent drives the episode (the environment's re-timed observations)
    states: dict[int, tuple[int, int, float, int]] = field(default_factory=dict)
    reports: dict[int, tuple[int, int, list[float] | None]] = field(default_factory=dict)  # controller role index
    # -> (arrival tick, tasks pending, links' busy-until ticks or None) of a report its worker sent it this tick
    # that it reads later (``Role.reads_later``); only while an agent drives the episode, as ``states``
    epoch: int = 0  # of the tick it answers: the report is sealed with the process's key of that epoch
    mac: bytes | None = field(default=None, compare=False, repr=False)
    signed: bytes = field(default=b"", compare=False, repr=False)


@dataclass(slots=True)
class Dones:
    """A host's reports, forwarded together; each is checked as if it had come alone."""

    group: str  # the placement group the host runs
    dones: list[Done]
    epoch: int = 0  # of the tick they answer: sealed with the host's key of that epoch
    mac: bytes | None = field(default=None, compare=False, repr=False)
    signed: bytes = field(default=b"", compare=False, repr=False)
