"""The array backend: K copies of one scenario stepped together, every state a numpy array.

The same model as the roles of ``worker.py``, ``client.py`` and ``controller.py`` (docs/model.md), held as
arrays over (copy, task), (copy, node) and (copy, link) instead of objects, so that one tick of K simulations
costs a few numpy calls rather than K of everything. It has no rule of its own: each number comes from the model's own
functions (``Task.expires_at`` for a task's expiry tick, the link rates of the scenario, ``dbm_to_watts`` and
``compute_energy`` for energy, ``EPS_CYCLES`` for a finishing task), the arrivals are drawn by the model's
``Client`` with its own random streams, and ``tests/test_array_backend.py`` proves it gives the in-process
emulator's counters tick for tick.

Covered today (``refusal`` names the first thing a scenario needs beyond it, in one line): admission
decide-first or queue-first, control latency 2 or 0, binary or batch mode, any decision or state interval,
every built-in node-side policy (``random`` on each controller's own stream), any ``max_hops`` (results
relayed back along the task's path), clients on worker nodes, every arrival schedule and task mix of the
built-in task source, FIFO links with loss (each worker's radio stream), failures, energy. Not yet:
payloads, clients without a worker, and user-defined roles, policies or task sources.

Controllers an agent drives (``drive``) observe every decision epoch (``observation``: the ``Observation`` a
``Controller`` builds; none while their node is down) and place what ``act`` gives them; every tick then keeps the
roles' per-task ledger in their own order, from which the environment's credits and metrics come (docs/array.md,
"The environments on it"). It takes the same scenarios with agents as without.

One tick runs the roles in an order that their one-tick message delay makes equivalent to the emulator's:
controllers (they read the worker's state at the end of the previous tick), clients (results in, new
tasks out), then workers (failure, overload, results relayed, expiry, decisions, admission, CPU, results
back). A co-located controller (control latency 0) observes its worker at the end of each tick, after the
workers, and its answer is handed over at the start of the next, which the worker applies in that tick, as the
emulator's host does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from node_runtime.model.client import arrivals_of
from node_runtime.model.controller import CONTROLLER, always_fresh, heard_at
from node_runtime.model.energy import compute_energy, idle_energy
from node_runtime.model.messages import Task, TaskSize
from node_runtime.model.policies import DriftPlusPenalty, Threshold
from node_runtime.model.radio import dbm_to_watts
from node_runtime.model.rng import stream
from node_runtime.model.role import CHARGED, COMPLETED, LOST, STAT_FIELDS, role_id
from node_runtime.model.spec import Scenario
from node_runtime.model.view import NodeView, Observation, TaskView, backlog
from node_runtime.model.worker import EPS_CYCLES, WORKER

# the node-side policies it runs, vectorised: every built-in one of policies.py
POLICIES = ("local", "round_robin", "least_queue", "greedy", "random", "greedy_backlog", "local_first", "threshold",
            "drift_plus_penalty")
BACKLOG = POLICIES[5:]  # the policies that read the links' backlogs
CHUNK = 64  # numbers of a random stream drawn at once (the same numbers as drawn one at a time)
BUILTIN = {"worker": "node_runtime.model.worker:Worker", "client": "node_runtime.model.client:Client",
           "controller": "node_runtime.model.controller:Controller"}
FIELDS = (*STAT_FIELDS, "in_flight", "response_time_sum")  # per role, as the orchestrator's metrics keep them
F = {name: i for i, name in enumerate(FIELDS)}
# where a task is: not created yet; a task message on its way to a worker; held undecided or queued by a
# worker; its result on its way to its client; gone (completed or dropped)
NEW, TO_WORKER, UNDECIDED, QUEUED, TO_CLIENT, GONE = range(6)
TO_RELAY = 6  # max_hops above 1: a result on its way to the previous worker of its task's path
SEQ_STRIDE = 1 << 20  # message numbers: send call * stride + position in the call (per sender, in send order)
# the parts of a worker's tick that write its ledger, in the order the worker runs them (``Worker.tick``):
# going down, results relayed (max_hops above 1), expiry, decisions, admission, service
FAILURE, RELAY, EXPIRY, DECISIONS, ADMISSION, SERVICE = range(6)


@dataclass(frozen=True)
class LedgerRows:
    """A tick's ledger of every copy as arrays, in the order of ``ArraySim.ledger``: copy, task index (into the
    copy's arrays, not its id), kind (``role.CHARGED``, ``COMPLETED``, ``LOST``) and value. What a batched reader
    takes instead of the per-copy lists (env/credit.py's ``ArrayCredit``)."""

    copy: np.ndarray
    task: np.ndarray
    kind: np.ndarray
    value: np.ndarray

    @classmethod
    def empty(cls) -> LedgerRows:
        none = np.zeros(0, dtype=np.int64)
        return cls(none, none, none, np.zeros(0))


class Streams:
    """One random stream per (copy, node), as a role draws it one number at a time, drawn CHUNK at a time."""

    def __init__(self, streams: dict[tuple[int, int], np.random.Generator],
                 draw: Callable[[np.random.Generator, int], np.ndarray], k: int, n: int, dtype: type) -> None:
        self.streams, self.draw = streams, draw  # draw(stream, node): its next CHUNK numbers
        self.chunk = np.zeros((k, n, CHUNK), dtype=dtype)
        self.used = np.full((k, n), CHUNK)

    def take(self, c: np.ndarray, nd: np.ndarray) -> np.ndarray:
        """The next number of each stream (copy c, node nd); each pair at most once per call."""
        spent = self.used[c, nd] >= CHUNK
        for cc, node in zip(c[spent].tolist(), nd[spent].tolist(), strict=True):
            self.chunk[cc, node] = self.draw(self.streams[cc, node], node)
            self.used[cc, node] = 0
        numbers = self.chunk[c, nd, self.used[c, nd]]
        self.used[c, nd] += 1
        return numbers


class Unsupported(ValueError):
    """A scenario needs what the array backend does not model (yet)."""


def refusal(sc: Scenario, policy: str | None = None) -> str | None:
    """Why the array backend cannot run ``sc`` (one line naming the feature and the backend to use), or None; the
    same whether agents drive controllers (``ArraySim.drive``, the environment) or not."""
    def why() -> str | None:
        kinds = dict(sc.kinds)
        for name, path in kinds.items():
            if BUILTIN.get(name) != path:
                return f"role kind {name!r} ({path}) is user-defined"
        for n in sc.nodes:
            if n.impls:
                return f"node {n.id} has a user-defined role class ({', '.join(p for _, p in n.impls)})"
            if n.has("controller") and (policy or n.policy) not in POLICIES:
                return (f"node-side policy {policy or n.policy!r} (node {n.id}); the array backend runs "
                        f"{', '.join(POLICIES)}")
            if n.has("client") and not n.has("worker"):
                return f"client {n.id} has no worker of its own (its tasks would cross the radio)"
            if n.has("client") and sc.targets[n.id] != (n.id,):
                return f"client {n.id} hands its tasks to other workers ({', '.join(sc.targets[n.id])})"
        if sc.workload.source:
            return f"user task source {sc.workload.source}"
        if sc.workload.jobs is not None:
            return "jobs (workload.jobs: DAGs of tasks)"
        if any(t.payload is not None for t in sc.workload.task_types):
            return "payloads"
        if sc.moving:
            return f"moving nodes ({', '.join(sorted(sc.moving, key=sc.index.__getitem__))})"
        for n in sc.nodes:  # an offloaded task's result comes back over the link it went by, reversed
            for j in sc.neighbours[n.id] if n.has("controller") and sc.max_hops else ():
                if sc.node[j].has("worker") and (j, n.id) not in sc.link:
                    return f"link {j} -> {n.id} is missing (a result could not come back directly)"
        return None

    reason = why()
    return None if reason is None else (f"scenario {sc.name}: the array backend does not support {reason}; "
                                        "run it with the in-process or Zenoh backend (Simulation.inproc / .over_zenoh)")


def expiry_tick(created: int, size: TaskSize, dt: float) -> int:
    """The first tick at which the task is expired: the model's own ``Task.expires_at``."""
    return Task(0, "", created, size).expires_at(dt)


NONE = np.zeros(0, dtype=np.int64)


def by_tick(ticks_of: np.ndarray, ticks: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each tick below ``ticks``, the (copies, task indices) whose entry in ``ticks_of`` is that tick."""
    c, i = np.nonzero(ticks_of < ticks)
    order = np.argsort(ticks_of[c, i], kind="stable")
    c, i = c[order], i[order]
    bounds = np.searchsorted(ticks_of[c, i], np.arange(ticks + 1))
    return [(c[a:b], i[a:b]) for a, b in pairwise(bounds)]


def group_rank(c: np.ndarray, nd: np.ndarray) -> np.ndarray:
    """Each entry's position within its run of equal (copy, node), for entries sorted by them."""
    first = np.r_[True, (c[1:] != c[:-1]) | (nd[1:] != nd[:-1])]
    return np.arange(len(c)) - np.maximum.accumulate(np.where(first, np.arange(len(c)), 0))


class ArraySim:
    """K copies of ``scenario``, each with its own seed, stepped one tick at a time by ``step``.

    ``counters`` is the (K, roles, FIELDS) array of every role's cumulative counters at the end of the last
    tick, roles in canonical order (``roles``): what the orchestrator's metrics sum into ticks.csv and
    nodes.csv (penalised seconds aside, which derive from these)."""

    def __init__(self, scenario: Scenario, k: int, policy: str | None = None) -> None:
        reason = refusal(scenario, policy)
        if reason is not None:
            raise Unsupported(reason)
        sc = self.sc = scenario
        self.k = k
        nodes = sc.nodes
        n = self.n = len(nodes)
        self.dt = sc.dt
        self.roles = tuple(role_id(kind, nd.id) for nd in nodes for kind in nd.roles)
        index = {r: i for i, r in enumerate(self.roles)}
        rank = {r: i for i, r in enumerate(sorted(self.roles))}  # canonical mail order compares sender ids

        def of(kind: str) -> np.ndarray:
            return np.array([index.get(role_id(kind, nd.id), -1) for nd in nodes])

        self.worker, self.client, self.controller = of("worker"), of("client"), of("controller")
        self.worker_rank = np.array([rank.get(role_id("worker", nd.id), -1) for nd in nodes])
        self.client_rank = np.array([rank.get(role_id("client", nd.id), -1) for nd in nodes])
        self.has_worker = self.worker >= 0
        self.buffer = np.array([nd.buffer for nd in nodes])
        self.capacity = np.array([nd.capacity for nd in nodes], dtype=float)
        self.budget = np.array([nd.capacity * sc.dt for nd in nodes])
        self.kappa = np.array([nd.kappa for nd in nodes], dtype=float)
        self.freq = np.array([nd.frequency for nd in nodes], dtype=float)
        self.idle = np.array([idle_energy(nd.idle_power_w, sc.dt) if nd.idle_power_w else 0.0 for nd in nodes])
        self.watts = np.array([dbm_to_watts(nd.tx_power_dbm) for nd in nodes])
        self.decides = np.array([nd.has("controller") and sc.max_hops > 0 for nd in nodes])
        # the actions of each controller: 0 keeps a task, a >= 1 sends it to neighbour a - 1 (-1: no such action)
        width = 1 + max((len(sc.neighbours[nd.id]) for nd in nodes), default=0)
        self.target = np.full((n, width), -1)
        self.valid = np.zeros((n, width), dtype=bool)
        for i, nd in enumerate(nodes):
            self.target[i, 0], self.valid[i, 0] = i, True
            for a, j in enumerate(sc.neighbours[nd.id], 1):
                self.target[i, a] = sc.index[j]
                self.valid[i, a] = sc.node[j].has("worker")
        # the scenario's directed links, numbered in (source, neighbour) order, so that what the links hold grows
        # with their number, not with n * n: ``links[i, a]`` is the link of node i's action a >= 1. Each array
        # over the links has one more entry, the last, for no link (-1: action 0 and a missing neighbour), which
        # reads as a link that is never busy, at 1 bit/s, without loss (the rates of action 0's column are never
        # used). ``link_key`` is each link's src * n + dst, ascending (neighbours are in index order), then n * n.
        real = self.target[:, 1:] >= 0
        self.links = np.full((n, width), -1)
        self.links[:, 1:][real] = np.arange(real.sum())
        self.link_src, dst = np.nonzero(real)[0], self.target[:, 1:][real]
        self.link_key = np.append(self.link_src * n + dst, n * n)
        ends = [sc.link[(nodes[a].id, nodes[b].id)] for a, b in zip(self.link_src, dst, strict=True)]
        self.rate = np.array([lk.rate_bps for lk in ends] + [1.0])
        self.loss = np.array([lk.loss for lk in ends] + [0.0])
        self.valid_list = np.full((n, width), -1)  # the valid actions of each node, in order
        self.n_valid = self.valid.sum(axis=1)
        for i in range(n):
            acts = np.flatnonzero(self.valid[i])
            self.valid_list[i, :len(acts)] = acts
        self.driven = np.zeros(n, dtype=bool)  # controllers whose actions come from ``act`` (an agent's)
        # what a controller's view takes from the scenario: each node's static facts, each controller's links
        # (neighbour indices, rates) and whether all it hears is always one tick old
        self._static = [(nd.id, nd.buffer, nd.capacity, nd.tier, nd.has("worker")) for nd in nodes]
        self._links = [([sc.index[j] for j in sc.neighbours[nd.id]],
                        [sc.link[(nd.id, j)].rate_bps for j in sc.neighbours[nd.id]]) for nd in nodes]
        self._fresh = [always_fresh(sc, (nd.id, *sc.neighbours[nd.id])) for nd in nodes]
        self.recording = False  # keep the per-task ledger and the driven controllers' observations (``drive``)
        self.listing = True  # and the ledger as per-copy lists of tuples too (``ledger``, ``completions``)
        self.use_policy(policy)
        self.per_epoch = 1 if sc.mode == "binary" else sc.batch_size
        self.queue_first = sc.admission == "queue_first"

    def use_policy(self, policy: str | None) -> None:
        """The node-side policy of the controllers no agent drives: ``policy`` for all, or each node's own."""
        reason = refusal(self.sc, policy)
        if reason is not None:
            raise Unsupported(reason)
        self.policy = policy
        self.policy_of = np.array([POLICIES.index(policy or nd.policy) if nd.has("controller") and not driven else -1
                                   for nd, driven in zip(self.sc.nodes, self.driven, strict=True)])
        self.randoms = np.flatnonzero(self.policy_of == POLICIES.index("random"))  # the controllers that draw

    def drive(self, nodes: Sequence[str]) -> None:
        """From the next ``reset`` on, the controllers of ``nodes`` observe every decision epoch and place what
        ``act`` gives them, as an externally driven ``Controller`` does, and every tick keeps the roles' ledger
        (``ledger``, ``completions``): what the environment reads (orchestrator/array_session.py)."""
        self.driven = np.isin(np.arange(self.n), [self.sc.index[n] for n in nodes])
        self.recording = True
        self.use_policy(self.policy)

    # ----- episode -----

    def reset(self, seeds: Sequence[int], ticks: int | None = None) -> None:
        """Start an episode of ``ticks`` ticks (the scenario's by default) in every copy, copy i with seeds[i]."""
        if len(seeds) != self.k:
            raise ValueError(f"{len(seeds)} seeds for {self.k} copies")
        sc, k = self.sc, self.k
        ticks = sc.episode_ticks if ticks is None else ticks
        drawn = arrivals_of(sc, [int(s) for s in seeds], ticks)
        self.sizes = [[size for _, _, size in tasks] for tasks in drawn]
        m = max(1, max(len(d) for d in drawn))
        self.m = m
        shape = (k, m)
        self.created = np.full(shape, ticks, dtype=np.int64)  # padding: never created
        self.origin = np.zeros(shape, dtype=np.int64)
        self.cycles = np.zeros(shape)
        self.in_bits = np.zeros(shape)
        self.io_bytes = np.zeros(shape)  # input and output bytes, as greedy prices a transfer
        self.out_bits = np.zeros(shape)
        self.expires = np.zeros(shape, dtype=np.int64)
        self.latest = np.zeros(shape)  # the last tick (a float) a transmission of it may start
        self.urgency = np.zeros(shape)
        self.deadline = np.zeros(shape)  # seconds, as created (a controller's time left derives from it)
        self.task_id = np.zeros(shape, dtype=np.int64)  # the client's id of it (``Client.task_id``)
        expiry: dict[tuple[int, TaskSize], int] = {}
        for c, tasks in enumerate(drawn):
            if not tasks:
                continue
            n = len(tasks)
            self.created[c, :n] = [t for t, _, _ in tasks]
            self.origin[c, :n] = [node for _, node, _ in tasks]
            sizes = np.array([size for _, _, size in tasks], dtype=float)
            self.cycles[c, :n] = [size.cycles for _, _, size in tasks]
            self.in_bits[c, :n], self.out_bits[c, :n] = sizes[:, 1] * 8.0, sizes[:, 2] * 8.0
            self.io_bytes[c, :n] = sizes[:, 1] + sizes[:, 2]
            self.expires[c, :n] = [expiry[key] if (key := (t, size)) in expiry
                                   else expiry.setdefault(key, expiry_tick(t, size, sc.dt)) for t, _, size in tasks]
            self.latest[c, :n] = [t + size.deadline / sc.dt for t, _, size in tasks]
            self.urgency[c, :n] = [1.0 / max(size.deadline, sc.dt) for _, _, size in tasks]
            self.deadline[c, :n] = [size.deadline for _, _, size in tasks]
            made = [0] * self.n  # tasks each client made so far
            for j, (_, node, _) in enumerate(tasks):
                made[node] += 1
                self.task_id[c, j] = (node << 32) | made[node]
        self.state = np.zeros(shape, dtype=np.int8)
        self.node = np.zeros(shape, dtype=np.int64)  # where it is held, or where its message goes
        self.arrive = np.zeros(shape, dtype=np.int64)
        self.sender = np.zeros(shape, dtype=np.int64)  # role of the message carrying it (in flight)
        self.src_rank = np.zeros(shape, dtype=np.int64)
        self.seq = np.zeros(shape, dtype=np.int64)
        self.order = np.zeros(shape, dtype=np.int64)  # admission order: undecided order, then queue order
        self.rem = self.cycles.copy()
        self.hops = np.zeros(shape, dtype=np.int64)
        self.imposed = np.zeros(shape)
        self.asking = (NONE, NONE)  # (copies, tasks) of the controllers' last observations, to place next tick
        self.ask_action = np.zeros(shape, dtype=np.int64)
        self.ask_rank = np.zeros(shape, dtype=np.int64)
        self.dec_arrive = np.full(shape, -1, dtype=np.int64)  # tick its decision reaches the worker
        self.dec_action = np.zeros(shape, dtype=np.int64)
        self.olink = np.full(shape, -1, dtype=np.int64)  # the link its offload was charged on ...
        self.ostart = np.zeros(shape)  # ... and when it occupied it, in ticks
        self.ofinish = np.zeros(shape)
        # the offloads charged on a link that may still be on the air (copy * links + link, task, start, finish),
        # how many were left when those off it were last dropped, and a mark on the (copy, link)s of a call's
        # transmissions: ``_on_air``'s join
        self.air = (NONE, NONE, np.zeros(0), np.zeros(0))
        self.air_left = 0
        self.sending = np.zeros(k * len(self.link_key), dtype=np.int32)
        self.busy = np.zeros((k, len(self.link_key)))  # when each link frees up, in ticks
        self.heard = np.zeros((k, self.n), dtype=np.int64)  # queue lengths as last broadcast ...
        self.heard_occupancy = np.zeros((k, self.n), dtype=np.int64)  # ... occupancies ...
        self.heard_drain = np.zeros((k, self.n))  # ... and drain ticks (``Worker.drains_at``)
        # each worker's drain tick, and the queue (length; head, tail: -1 if none) it was computed for: at first, empty
        self.drain, self.drain_key = np.zeros((k, self.n)), np.full((3, k, self.n), -1)
        self.drain_key[0] = 0
        self.rr = np.zeros((k, self.n), dtype=np.int64)  # round robin's next
        self.joined = [(NONE, NONE)]  # the tasks queued since the CPU last ran (its queue then first), in order
        self.kept = np.zeros(shape, dtype=bool)  # queue_first: kept by a decision (not offered again)
        self.dec_node = np.zeros(shape, dtype=np.int64)  # the node whose controller asked about it
        # max_hops above 1: the workers that admitted each task, in order, and where its result is on that path
        self.path = np.zeros((k, m, sc.max_hops + 1) if sc.max_hops > 1 else (0, 0, 0), dtype=np.int64)
        self.plen = np.zeros(shape if sc.max_hops > 1 else (0, 0), dtype=np.int64)
        self.hop = np.zeros(shape if sc.max_hops > 1 else (0, 0), dtype=np.int64)
        # failures: which nodes are down in each tick, and the tasks its controller still thinks it may place
        # when its node comes back (its worker's last report before the failure, which dropped them)
        self.down = np.zeros((ticks + 1, self.n), dtype=bool)
        for node, windows in sc.failure_windows.items():
            for a, b in windows:
                self.down[a:b, sc.index[node]] = True
        self.ghosts: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # node -> (copies, tasks)
        self.ghost_count = np.zeros((k, self.n), dtype=np.int64)  # and how many tasks that report held
        self.heard_late = np.zeros((k, self.n), dtype=np.int64)  # co-located: the states heard a tick before
        self.heard_occupancy_late = np.zeros((k, self.n), dtype=np.int64)
        self.heard_drain_late = np.zeros((k, self.n))
        self.queued = np.zeros((k, self.n), dtype=np.int64)
        self.undecided = np.zeros((k, self.n), dtype=np.int64)
        self.serving = np.full((k, self.n), -1, dtype=np.int64)
        self.counters = np.zeros((k, len(self.roles), len(FIELDS)))
        self._reset_driven()
        self.t = 0
        self.ticks = ticks
        # the live window of the task arrays: before ``lo`` every task is gone in every copy (and off its link),
        # from ``hi_at[t]`` on none is created by tick t in any copy
        self.lo = 0
        self.hi_at = np.array([np.searchsorted(row, np.arange(ticks), side="right") for row in self.created]).max(
            axis=0)
        self._counter = 0
        self._calls = 0
        # what happens at each tick, found without a pass over the tasks: mail arriving (tasks and results),
        # decisions reaching workers, tasks created, tasks whose deadline passes
        self.mail: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.decided: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.born = by_tick(self.created, ticks)
        self.dies = by_tick(self.expires, ticks)
        self.flying = np.zeros((k, len(self.roles)), dtype=np.int64)  # messages in flight, by sending role
        # random: each controller's own stream (the policy's, ``Controller.reset``)
        self.choices = Streams({(c, int(nd)): stream(int(s), int(nd), CONTROLLER.stream) for c, s in enumerate(seeds)
                                for nd in self.randoms},
                               lambda g, node: g.integers(self.n_valid[node], size=CHUNK), k, self.n, np.int64)
        # link loss: each worker's radio stream (``Worker.reset``), a number per transmission on a lossy link
        self.losses = Streams({(c, int(nd)): stream(int(s), int(nd), WORKER.stream) for c, s in enumerate(seeds)
                               for nd in np.unique(self.link_src[self.loss[:-1] > 0.0])},
                              lambda g, node: g.random(CHUNK), k, self.n, float)

    def step(self) -> np.ndarray:
        """Run tick ``t`` of every copy; the counters at its end."""
        if self.t >= self.ticks:
            raise ValueError(f"the episode has {self.ticks} ticks")
        t = self.t
        self.win = slice(self.lo, self.hi_at[t])
        mail = self.mail.pop(t, [])
        self.arriving = tuple(np.concatenate(a) for a in zip(*mail, strict=True)) if mail else (NONE, NONE)
        c, i = self.arriving
        self.flying -= np.bincount(c * len(self.roles) + self.sender[c, i], minlength=self.flying.size).reshape(
            self.flying.shape)
        self._entries: list[tuple[np.ndarray, ...]] = []
        if self.recording:
            self.bumped[:] = False
        self._controllers(t)
        self._clients(t)
        self._workers(t)
        self._levels(t)
        if self.sc.colocated_control:  # the co-located controllers observe their workers as the tick leaves them
            self._observe(t)
        if self.recording:
            self._settle_ledger()
        # tasks before the window are gone in every copy, and off their links: a lost offload occupies its link
        # to the end, and charges the messages that wait for it meanwhile (``LinkTransmitter.occupy``)
        w = self.win
        gone = ((self.state[:, w] == GONE) & ((self.olink[:, w] < 0) | (self.ofinish[:, w] <= t + 1))).all(axis=0)
        self.lo += len(gone) if gone.all() else int(np.argmin(gone))
        self.t += 1
        return self.counters

    # ----- what the environment reads and gives: driven controllers, the ledger -----

    def _reset_driven(self) -> None:
        k, n = self.k, self.n
        self.arrived = np.zeros_like(self.created)  # tick it entered its worker's buffer
        self.given = np.zeros(self.created.shape, dtype=bool)  # an agent answered for it (``act``)
        self.bumped = np.zeros((k, n), dtype=bool)  # the worker reports to its controller at the end of this tick
        # each worker's links' busy-until ticks (by neighbour, as the actions: action a is link a - 1), as its
        # controller was last told
        self.told_busy = np.zeros((k, n, self.target.shape[1] - 1))
        # queue_first: the node at which each task was divertible when its worker last published (-1: none), and
        # how many each worker's list held then (``Worker._divertible``, what its reports carry)
        self.listed_at = np.full(self.created.shape, -1)
        self.listed = np.zeros((k, n), dtype=np.int64)
        self.seen = -1  # the last decision epoch, and what the driven controllers knew at it
        self._known = None
        self.slots = np.full((k, n, self.per_epoch), -1)  # the tasks each was shown, by task slot
        self.ledger: list[list[tuple[int, int, float]]] = [[] for _ in range(k)]  # each copy's, the last tick
        self.completions: list[list[tuple[int, float]]] = [[] for _ in range(k)]  # (client role, response time)
        self.ledger_rows = LedgerRows.empty()  # the same ledger as arrays, of every copy

    def _remember_view(self, t: int) -> None:
        """What the driven controllers know at epoch ``t``: the states broadcast by the end of tick t - 1, and
        their worker as its last report told it (its undecided tasks, its links' busy-until ticks). Co-located
        (control_latency 0, observing at the end of tick t), their worker as it is: its queue, occupancy, drain
        tick, undecided tasks and links (``Controller.own_view``, ``Radio.busy_until``)."""
        self.seen = t
        self._known = None
        if self.sc.colocated_control:
            heard = self.heard_late, self.heard_occupancy_late, self.heard_drain_late
            own = self.queued, self.queued + self.undecided, self.drain
            busy = self.busy[:, self.links[:, 1:]]
        else:
            heard = own = self.heard, self.heard_occupancy, self.heard_drain
            busy = self.told_busy
        self.seen_heard, self.seen_occupancy, self.seen_drain = (a.copy() for a in heard)
        self.seen_own = tuple(a.copy() for a in own)  # (queue, occupancy, drain tick) of each controller's own node
        # the tasks it may place that its worker last reported (queue_first: its divertible ones, as listed); back
        # from a failure, its report from before it
        self.seen_undecided = (self.listed if self.queue_first else self.undecided).copy()
        if t and self.sc.failures and not self.sc.colocated_control:
            back = ~self.down[t] & self.down[t - 1]
            self.seen_undecided[:, back] = self.ghost_count[:, back]
        self.seen_busy = busy.copy()
        self.slots[:] = -1

    def observation(self, copy: int, node: int) -> Observation:
        """What the driven controller of node index ``node`` observed at the last decision epoch in copy
        ``copy``: the ``Observation`` that ``Controller.observe`` builds, from the same facts."""
        sc, t, dt = self.sc, self.seen, self.dt
        if self._known is None:  # once per epoch: what every copy knew, as Python numbers
            self._known = (self.seen_heard.tolist(), self.seen_occupancy.tolist(), self.seen_drain.tolist(),
                           self.seen_undecided.tolist(),
                           [[1 if fresh else t - heard_at(sc, sc.nodes[j].id, t) for j in range(self.n)]
                            for fresh in (False, True)], [a.tolist() for a in self.seen_own])
        heard, occupancy, drains, undecided, ages, own = self._known
        queue, occupied, drain, age = heard[copy], occupancy[copy], drains[copy], ages[self._fresh[node]]

        def view(j: int, rate: float, queued: float) -> NodeView:
            nid, buffer, capacity, tier, worker = self._static[j]
            if j == node:  # its own node: co-located, as it is (information 0 ticks old)
                age0 = 0 if sc.colocated_control else age[j]
                return NodeView(nid, own[0][copy][j], own[1][copy][j], buffer, capacity, tier, rate, age0, worker,
                                queued, own[2][copy][j])
            return NodeView(nid, queue[j], occupied[j], buffer, capacity, tier, rate, age[j], worker, queued, drain[j])

        to, rates = self._links[node]
        busy = self.seen_busy[copy, node, :len(to)].tolist()
        tasks = []
        for i in self.slots[copy, node].tolist():
            if i < 0:
                break
            size = self.sizes[copy][i]
            left = size.deadline - (t - int(self.created[copy, i])) * dt
            tasks.append(TaskView(int(self.task_id[copy, i]), size, left, t - int(self.arrived[copy, i]),
                                  self._static[self.origin[copy, i]][0]))
        return Observation(t, self._static[node][0], view(node, 0.0, 0.0), undecided[copy][node], tasks,
                           [view(j, rate, backlog(b, t, dt)) for j, rate, b in zip(to, rates, busy, strict=True)],
                           busy)

    def act(self, copy: int, node: int, actions: Sequence[int]) -> None:
        """The agent's answer for the driven controller of node index ``node`` in copy ``copy``: one action per
        task of its last observation, in order (0 keeps a task, a >= 1 sends it to neighbour a - 1, valid ones
        only), placed by the controller in the next tick. Without one it places nothing, as a ``Controller``."""
        i = self.slots[copy, node, :len(actions)]
        shown = i >= 0
        self.ask_action[copy, i[shown]] = np.asarray(actions)[shown]
        self.given[copy, i[shown]] = True

    def act_all(self, nodes: np.ndarray, actions: np.ndarray) -> None:
        """``act`` for every copy at once: ``actions[c, a, b]`` answers task slot b of the driven controller of node
        index ``nodes[a]`` in copy c (entries of slots without a task are ignored)."""
        i = self.slots[:, nodes, :actions.shape[2]]
        c = np.broadcast_to(np.arange(self.k)[:, None, None], i.shape)
        shown = i >= 0
        self.ask_action[c[shown], i[shown]] = actions[shown]
        self.given[c[shown], i[shown]] = True

    def _enter(self, phase: int, step: int = 0) -> None:
        """The part of its tick a role is in: its ledger entries are ordered by it, then by their key."""
        self._stage = (phase, step)

    def _record(self, c: np.ndarray, roles: np.ndarray, key: np.ndarray | int, i: np.ndarray, kind: int,
                value: np.ndarray | float) -> None:
        """Ledger entries (``role.Counters.ledger``) of tasks ``i`` by ``roles``, in the current stage."""
        n = len(c)
        if n:
            phase, step = self._stage
            self._entries.append((c, roles, np.full(n, phase), np.full(n, step), np.broadcast_to(key, (n,)), i,
                                  np.full(n, kind), np.broadcast_to(value, (n,)).astype(float)))

    def _settle_ledger(self) -> None:
        """The tick's ledger of each copy, in canonical role order and, within a role, in the order its tick
        wrote it; and the response times of its completions, in the same order."""
        self.ledger = [[] for _ in range(self.k)]
        self.completions = [[] for _ in range(self.k)]
        if not self._entries:
            self.ledger_rows = LedgerRows.empty()
            return
        c, role, phase, step, key, i, kind, value = (np.concatenate(a) for a in zip(*self._entries, strict=True))
        by = np.lexsort((key, step, phase, role, c))
        self.ledger_rows = LedgerRows(c[by], i[by], kind[by], value[by])
        if not self.listing:
            return
        task = self.task_id[c, i]
        for copy, r, entry in zip(c[by].tolist(), role[by].tolist(),
                                  zip(task[by].tolist(), kind[by].tolist(), value[by].tolist(), strict=True),
                                  strict=True):
            self.ledger[copy].append(entry)
            if entry[1] == COMPLETED:
                self.completions[copy].append((r, entry[2]))

    # ----- helpers -----

    def _find(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(copies, task indices) where ``mask``, a mask over the live window of tasks, holds."""
        c, i = np.nonzero(mask)
        return c, i + self.win.start

    def _add(self, c: np.ndarray, roles: np.ndarray, field: str, values: np.ndarray | float = 1.0) -> None:
        """Add to a counter of roles (``c``: copies), one addition at a time in the order given."""
        np.add.at(self.counters[:, :, F[field]], (c, roles), values)

    def _send(self, c: np.ndarray, i: np.ndarray, state: int, dst: np.ndarray, arrive: np.ndarray,
              sender: np.ndarray, rank: np.ndarray) -> None:
        """Put tasks (copy ``c``, index ``i``) in messages: numbered in the order given, per sender."""
        self._calls += 1
        self.state[c, i], self.node[c, i], self.arrive[c, i] = state, dst, arrive
        self.sender[c, i], self.src_rank[c, i] = sender, rank
        self.seq[c, i] = self._calls * SEQ_STRIDE + np.arange(len(c))
        for tick in np.unique(arrive):
            at = arrive == tick
            self.mail.setdefault(int(tick), []).append((c[at], i[at]))
        self.flying += np.bincount(c * len(self.roles) + sender, minlength=self.flying.size).reshape(
            self.flying.shape)

    def _drop(self, c: np.ndarray, i: np.ndarray, roles: np.ndarray, cause: str, key: np.ndarray | int = 0) -> None:
        """Tasks leave the system, counted under ``cause`` by ``roles`` (a drop cause, or "completed"); ``key``
        orders their ledger entries within the role's current stage (``_enter``)."""
        self.state[c, i] = GONE
        self._add(c, roles, cause)
        if self.recording and cause != "completed":
            self._record(c, roles, key, i, LOST, 0.0)

    def _next_order(self, count: int) -> np.ndarray:
        first = self._counter
        self._counter += count
        return np.arange(first, first + count)

    # ----- controllers -----

    def _controllers(self, t: int) -> None:
        """The controllers' slot at the start of tick t. control_latency 2: the answer to the last observation is
        placed (it reaches the worker next tick), then the observation of tick t, on its worker's state at the end
        of the last tick as reported. 0: the answer to the observation made at the end of the last tick is handed
        to the worker at once (``_observe`` runs at the end of each tick instead)."""
        if self.sc.colocated_control:
            self._place(t, t)
        else:
            self._place(t, t + 1)
            self._observe(t)

    def _observe(self, seen: int) -> None:
        """The controllers' observations of epoch ``seen`` and the node-side policies' answers to them."""
        k = self.k
        if seen % self.sc.decision_interval:
            return
        if self.driven.any():
            self._remember_view(seen)
        # the oldest tasks the controller may place (queue_first: queued tasks it may divert)
        w = self.win
        offered = self._divertible(w) if self.queue_first else self.state[:, w] == UNDECIDED
        if self.sc.failures:  # a controller that is down does not observe
            offered &= ~self.down[seen, self.node[:, w]]
        c, i = self._find(offered & (self.dec_arrive[:, w] < 0))
        if self.sc.failures and seen:  # one back up sees its worker's last report, from before the failure
            back = [self.ghosts.pop(int(node), (NONE, NONE)) for node in
                    np.flatnonzero(~self.down[seen] & self.down[seen - 1])]
            c, i = np.concatenate([c, *(g[0] for g in back)]), np.concatenate([i, *(g[1] for g in back)])
        if not len(c):
            return
        nd = self.node[c, i]
        by = np.argsort(((c * self.n + nd) << 32) + self.order[c, i], kind="stable")  # by copy, node, order
        c, i, nd = c[by], i[by], nd[by]
        rank = group_rank(c, nd)
        extra = np.zeros((k, self.n, self.target.shape[1]), dtype=np.int64)
        self.asking = (c[rank < self.per_epoch], i[rank < self.per_epoch])
        self.dec_node[self.asking] = nd[rank < self.per_epoch]
        if self.driven.any():
            shown = (rank < self.per_epoch) & self.driven[nd]
            self.slots[c[shown], nd[shown], rank[shown]] = i[shown]
            self.given[c[shown], i[shown]] = False
        for b in range(self.per_epoch):
            sel = rank == b
            cb, ib, nb = c[sel], i[sel], nd[sel]
            if not len(cb):
                break
            action = np.zeros(len(cb), dtype=np.int64)
            pol = self.policy_of[nb]
            rr = pol == POLICIES.index("round_robin")
            if rr.any():
                cr, nr = cb[rr], nb[rr]
                action[rr] = self.valid_list[nr, self.rr[cr, nr] % self.n_valid[nr]]
                self.rr[cr, nr] += 1
            lq = pol == POLICIES.index("least_queue")
            if lq.any():
                cl, nl = cb[lq], nb[lq]
                key = np.where(self.valid[nl], self._seen(cl, nl)[0] + extra[cl, nl], np.iinfo(np.int64).max)
                action[lq] = np.argmin(key, axis=1)  # ties: the lowest action, so local first
            gr = pol == POLICIES.index("greedy")
            if gr.any():
                action[gr] = self._greedy(cb[gr], ib[gr], nb[gr], extra)
            rd = pol == POLICIES.index("random")
            if rd.any():
                action[rd] = self._random(cb[rd], nb[rd])
            for name in BACKLOG:
                on = pol == POLICIES.index(name)
                if on.any():
                    action[on] = self._by_backlog(name, seen, cb[on], ib[on], nb[on], extra)
            extra[cb, nb, action] += 1
            self.ask_action[cb, ib] = action
            self.ask_rank[cb, ib] = b

    def _place(self, t: int, arrive: int) -> None:
        """The answer to the last observation, placed at tick ``t``: decisions that reach the worker at ``arrive``."""
        c, i = self.asking
        self.asking = (NONE, NONE)
        up = ~self.down[t, self.dec_node[c, i]]  # a controller that is down drops its answer
        if self.driven.any():  # a driven controller places what its agent answered (``act``)
            up &= ~self.driven[self.dec_node[c, i]] | self.given[c, i]
        c, i = c[up], i[up]
        if len(c):
            self.dec_arrive[c, i] = arrive
            self.decided[arrive] = (c, i)
            self.dec_action[c, i] = self.ask_action[c, i]
            self._add(c, self.controller[self.dec_node[c, i]], "decisions")

    def _divertible(self, w: slice) -> np.ndarray:
        """queue_first (``Worker.divertible``), over the window ``w``: queued tasks that have not started, were not
        kept by a decision, and may still be offloaded (fewer hops than ``max_hops``, at a node that decides)."""
        nd = self.node[:, w]
        return ((self.state[:, w] == QUEUED) & ~self.kept[:, w] & (self.hops[:, w] < self.sc.max_hops)
                & self.decides[nd] & (self.rem[:, w] == self.cycles[:, w])
                & (np.take_along_axis(self.serving, nd, axis=1) != np.arange(w.start, w.stop)))

    def _seen(self, c: np.ndarray, nd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The queues and occupancies a controller sees of each action's target (a row per task): as broadcast
        and heard a tick later; co-located (control_latency 0), its own worker as it is."""
        to = self.target[nd]
        if not self.sc.colocated_control:
            return self.heard[c[:, None], to], self.heard_occupancy[c[:, None], to]
        queue, occupancy = self.heard_late[c[:, None], to], self.heard_occupancy_late[c[:, None], to]
        queue[:, 0] = self.queued[c, nd]
        occupancy[:, 0] = self.queued[c, nd] + self.undecided[c, nd]
        return queue, occupancy

    def _greedy(self, c: np.ndarray, i: np.ndarray, nd: np.ndarray, extra: np.ndarray) -> np.ndarray:
        """``policies.Greedy``: the least estimated completion time over the valid actions (ties: the lowest)."""
        return np.argmin(np.where(self.valid[nd], self._estimate(c, i, nd, extra), np.inf), axis=1)

    def _estimate(self, c: np.ndarray, i: np.ndarray, nd: np.ndarray, extra: np.ndarray) -> np.ndarray:
        """``Greedy.estimate`` of every action (a row per task), in its float operations."""
        to = self.target[nd]
        more = extra[c, nd]
        cycles = self.cycles[c, i][:, None]
        capacity = self.capacity[to]
        queue, occupancy = self._seen(c, nd)
        wait = (queue + more) * cycles / capacity
        run = cycles / capacity
        transfer = self.io_bytes[c, i][:, None] * 8.0 / self.rate[self.links[nd]]
        full = occupancy + more >= self.buffer[to]
        estimate = np.where(full, np.inf, transfer + wait + run)
        estimate[:, 0] = (wait + run)[:, 0]
        return estimate

    def _random(self, c: np.ndarray, nd: np.ndarray) -> np.ndarray:
        """``policies.Random``: a valid action drawn from each controller's own stream (one (copy, node) per call)."""
        return self.valid_list[nd, self.choices.take(c, nd)]

    def _by_backlog(self, name: str, t: int, c: np.ndarray, i: np.ndarray, nd: np.ndarray,
                    extra: np.ndarray) -> np.ndarray:
        """The policies that add the links' backlogs (``NodeView.backlog_s``, ``controller.backlog``) to greedy's
        estimate, each in its float operations: ``GreedyBacklog``, ``LocalFirst``, ``Threshold`` and
        ``DriftPlusPenalty`` at their default parameters.

        The busy-until ticks a controller knows are its worker's at the end of the last tick it reported in; with
        tasks to place they are the links' at the end of the previous tick, as held here: the worker reports
        whenever its undecided set changes, and whenever it transmits while tasks wait for a decision, so since
        its last report the set stayed the same and not empty, and nothing was sent. (Back from a failure, a
        controller's first observation holds only tasks the failure dropped: their decisions are stale whatever
        they say, so the backlogs it reads then change nothing.)"""
        to = self.target[nd]
        busy = self.busy[c[:, None], self.links[nd]]
        backlog = np.where(busy > t + 1, (busy - (t + 1)) * self.dt, 0.0)
        greedy = self._estimate(c, i, nd, extra)
        estimate = greedy + backlog  # GreedyBacklog.estimate
        estimate[:, 0] = greedy[:, 0]
        valid = self.valid[nd]
        choice = np.argmin(np.where(valid, estimate, np.inf), axis=1)
        if name == "greedy_backlog":
            return choice
        if name == "local_first":
            left = self.deadline[c, i] - (t - self.created[c, i]) * self.dt  # TaskView.time_left
            return np.where(estimate[:, 0] <= left, 0, choice)
        if name == "threshold":
            cost = np.where(valid, estimate, np.inf)
            cost[:, 0] = np.inf
            best = np.argmin(cost, axis=1)
            keep = self._seen(c, nd)[0][:, 0] + extra[c, nd, 0] < Threshold.threshold
            return np.where(keep | ~np.isfinite(cost[np.arange(len(c)), best]), 0, best)
        # drift_plus_penalty
        service = self.cycles[c, i][:, None] / self.capacity[to]
        drift = ((self._seen(c, nd)[0] + extra[c, nd]) * service + service / 2) * service
        transfer = self.io_bytes[c, i][:, None] * 8.0 / self.rate[self.links[nd]]
        drift[:, 1:] += ((backlog + transfer / 2) * transfer)[:, 1:]
        return np.argmin(np.where(valid, drift + DriftPlusPenalty.v * estimate, np.inf), axis=1)

    # ----- clients -----

    def _clients(self, t: int) -> None:
        # results in, in canonical mail order
        c, i = self.arriving
        here = self.state[c, i] == TO_CLIENT
        c, i = c[here], i[here]
        if len(c):
            nd = self.node[c, i]
            by = np.lexsort((self.seq[c, i], self.src_rank[c, i], nd, c))
            c, i, nd = c[by], i[by], nd[by]
            roles = self.client[nd]
            imposed = self.imposed[c, i] != 0.0
            self._add(c[imposed], roles[imposed], "delay_imposed", self.imposed[c[imposed], i[imposed]])
            # the ledger, result by result: its charge, then what became of it
            self._enter(0)  # a client's tick has one part
            key = 2 * np.arange(len(c))
            if self.recording:
                self._record(c[imposed], roles[imposed], key[imposed], i[imposed], CHARGED,
                             self.imposed[c[imposed], i[imposed]])
            failed = self.down[t, nd]
            self._drop(c[failed], i[failed], roles[failed], "node_failure", key[failed] + 1)
            late = (t >= self.expires[c, i]) & ~failed
            self._drop(c[late], i[late], roles[late], "expired", key[late] + 1)
            ok = ~late & ~failed
            self._drop(c[ok], i[ok], roles[ok], "completed")
            if self.recording:
                self._record(c[ok], roles[ok], key[ok] + 1, i[ok], COMPLETED,
                             (t - self.created[c[ok], i[ok]]) * self.dt)
            times = np.zeros(self.counters.shape[:2])
            np.add.at(times, (c[ok], roles[ok]), (t - self.created[c[ok], i[ok]]) * self.dt)
            self.counters[:, :, F["response_time_sum"]] += times
        # new tasks, handed to the node's own worker next tick
        c, i = self.born[t]
        if len(c):
            nd = self.origin[c, i]
            self._add(c, self.client[nd], "generated")
            self._send(c, i, TO_WORKER, nd, np.full(len(c), t + 1), self.client[nd], self.client_rank[nd])

    # ----- workers -----

    def _workers(self, t: int) -> None:
        w = self.has_worker
        if self.sc.failures:
            self._fail(t)
        occupancy = self.queued + self.undecided
        full = (occupancy >= self.buffer) & w
        cnt = self.counters
        cnt[:, :, F["overloaded"]][:, self.worker[w]] = full[:, w]
        cnt[:, :, F["overloaded_ticks"]][:, self.worker[w]] += full[:, w]
        if self.sc.max_hops > 1:
            self._relay(t)
        # expiry of held tasks
        c, i = self.dies[t]  # a held task expires at its expiry tick: it was admitted before, and not expired then
        state = self.state[c, i]
        held = (state == UNDECIDED) | (state == QUEUED)
        c, i = c[held], i[held]
        if len(c):
            nd = self.node[c, i]
            undecided = self.state[c, i] == UNDECIDED
            np.subtract.at(self.queued, (c, nd), ~undecided)
            np.subtract.at(self.undecided, (c, nd), undecided)
            if self.recording:
                self.bumped[c[undecided], nd[undecided]] = True
            self._enter(EXPIRY)  # the queue's tasks in queue order, then the undecided ones in arrival order
            self._drop(c, i, self.worker[nd], "expired", self.order[c, i] + undecided * (1 << 40))
        self._decisions(t)
        self._admit(t)
        self._serve(t)
        if self.idle.any():  # a node that is down spends nothing
            cnt[:, :, F["energy_idle"]][:, self.worker[w]] += np.where(self.down[t, w], 0.0, self.idle[w])

    def _fail(self, t: int) -> None:
        """Nodes going down in tick t drop all they hold (``node_failure``) and reset their links: nothing queued,
        nothing charged (``Worker.tick``, ``Worker.drop_all``)."""
        went = self.down[t] & ~self.down[t - 1] if t else self.down[t]
        if not went.any():
            return
        w = self.win
        held = (self.state[:, w] == UNDECIDED) | (self.state[:, w] == QUEUED)
        c, i = self._find(held & went[self.node[:, w]])
        if not self.sc.colocated_control:  # what its worker last reported as still to place
            offered = (self._divertible(w) if self.queue_first else self.state[:, w] == UNDECIDED)[c, i - w.start]
            offered &= self.dec_arrive[c, i] < 0
            for node in np.flatnonzero(went):
                mine = offered & (self.node[c, i] == node)
                self.ghosts[int(node)] = (c[mine], i[mine])
            self.ghost_count[:, went] = (self.listed if self.queue_first else self.undecided)[:, went]
        self.queued[:, went] = 0
        self.undecided[:, went] = 0
        self._enter(FAILURE)  # ``Worker.drop_all``: the queue in queue order, then the undecided in arrival order
        undecided = self.state[c, i] == UNDECIDED
        self._drop(c, i, self.worker[self.node[c, i]], "node_failure", self.order[c, i] + undecided * (1 << 40))
        self.busy[:, np.flatnonzero(went[self.link_src])] = 0.0
        charged = self.olink[:, w] >= 0
        self.olink[:, w][charged & went[self.olink[:, w] // self.n]] = -1
        reset = went[self.link_src[self.air[0] % len(self.link_key)]]
        self.air = tuple(a[~reset] for a in self.air)

    def _decisions(self, t: int) -> None:
        c, i = self.decided.pop(t, (NONE, NONE))
        if not len(c):
            return
        nd = self.dec_node[c, i]
        up = ~self.down[t, nd]  # a node that is down ignores them
        c, i, nd = c[up], i[up], nd[up]
        if self.recording and not self.queue_first:  # decisions change the undecided set (queue_first: the list of
            # divertible tasks, if they divert or keep one, which ``_list_divertible`` finds)
            self.bumped[c, nd] = True
        if self.queue_first:  # it must still be divertible: queued, not started, not kept
            stale = ((self.state[c, i] != QUEUED) | self.kept[c, i] | (self.rem[c, i] != self.cycles[c, i])
                     | (self.serving[c, nd] == i))
        else:
            stale = self.state[c, i] != UNDECIDED
        stale |= self.node[c, i] != nd  # a result on its way, further along its path
        self._add(c[stale], self.worker[nd[stale]], "stale_decisions")
        c, i, nd = c[~stale], i[~stale], nd[~stale]
        by = np.lexsort((self.ask_rank[c, i], nd, c))
        c, i, nd = c[by], i[by], nd[by]
        rank = self.ask_rank[c, i]
        for b in np.unique(rank):
            sel = rank == b
            cb, ib, nb = c[sel], i[sel], nd[sel]
            action = self.dec_action[cb, ib]
            local = action == 0
            cl, il, nl = cb[local], ib[local], nb[local]
            co, io, no = cb[~local], ib[~local], nb[~local]
            if self.queue_first:  # local: it stays where it is in the queue, kept; else it leaves the queue
                self.kept[cl, il] = True
                np.subtract.at(self.queued, (co, no), 1)
            else:
                np.subtract.at(self.undecided, (cb, nb), 1)
                self.state[cl, il] = QUEUED
                self.order[cl, il] = self._next_order(len(cl))
                self.joined.append((cl, il))
                np.add.at(self.queued, (cl, nl), 1)
            if len(co):
                self.hops[co, io] += 1
                self._add(co, self.worker[no], "offloaded")
                self._enter(DECISIONS, b)
                self._transmit(t, co, io, no, self.target[no, action[~local]], self.in_bits[co, io], TO_WORKER)

    def _transmit(self, t: int, c: np.ndarray, i: np.ndarray, src: np.ndarray, dst: np.ndarray, bits: np.ndarray,
                  kind: int) -> None:
        """Queue messages on links src -> dst (one per link and call), as ``Radio.send`` and ``Role.transmit`` do."""
        roles = self.worker[src]
        if self.recording:  # a worker tells its controller of a link's change while it has tasks to place (queue_first:
            # while its list of divertible tasks, as last published, is not empty)
            self.bumped[c, src] |= (self.listed if self.queue_first else self.undecided)[c, src] > 0
        link = src * self.n + dst
        number = self._link(link)  # (a transmission's link exists)
        start = np.maximum(float(t), self.busy[c, number])
        late = start > self.latest[c, i]  # it could only start after its deadline: never sent
        self._drop(c[late], i[late], roles[late], "expired")
        c, i, src, dst, bits, start, roles, link, number = (a[~late] for a in
                                                            (c, i, src, dst, bits, start, roles, link, number))
        if not len(c):
            return
        seconds = bits / self.rate[number]
        finish = start + seconds / self.dt
        self.busy[c, number] = finish
        # a lost message occupied the link (and is charged for it), but costs no energy and charges nothing
        lost = np.zeros(len(c), dtype=bool)
        if self.losses.streams:
            lossy = np.flatnonzero(self.loss[number] > 0.0)
            lost[lossy] = self.losses.take(c[lossy], src[lossy]) < self.loss[number[lossy]]
        kept = ~lost if lost.any() else slice(None)
        self._add(c[kept], roles[kept], "energy_transmit", (self.watts[src] * seconds)[kept])
        # the charged offloads still on the link, in the order they were sent: each charged what this one waits
        s, j = self._on_air(t, c, number, lost)
        if len(s):
            cs = c[s]
            waited = (self.ofinish[cs, j] - np.maximum(float(t), self.ostart[cs, j])) * self.dt
            self._add(cs, roles[s], "delay_imposed", waited * self.urgency[cs, i[s]])
            if self.recording:  # each charged offload ahead, in sending order
                self._record(cs, roles[s], np.arange(len(s)), j, CHARGED, waited * self.urgency[cs, i[s]])
        if kind == TO_WORKER:  # an offload: charged for what it makes later messages wait
            self.olink[c, i], self.ostart[c, i], self.ofinish[c, i] = link, start, finish
            self._charge(t, c * len(self.link_key) + number, i, start, finish)
        if lost.any():
            self._drop(c[lost], i[lost], roles[lost], "link_loss")
            c, i, dst, finish, roles, src = (a[~lost] for a in (c, i, dst, finish, roles, src))
        arrive = np.maximum(t + 1, np.ceil(finish).astype(np.int64))
        self._send(c, i, kind, dst, arrive, roles, self.worker_rank[src])

    def _link(self, key: np.ndarray) -> np.ndarray:
        """The number of each link src * n + dst (``link_key``); where there is no such link, the number of the next
        one, which ``link_key`` tells apart."""
        return np.searchsorted(self.link_key, key)

    def _charge(self, t: int, key: np.ndarray, i: np.ndarray, start: np.ndarray, finish: np.ndarray) -> None:
        """Offloads charged on links (``key``: copy * links + link): into ``air``, from which those off the air
        for good are dropped whenever it has doubled since, so that it holds about what is on the air."""
        air = self.air
        if len(air[0]) > 2 * self.air_left + 64:
            on = air[3] > t
            air = tuple(a[on] for a in air)
            self.air_left = len(air[0])
        self.air = tuple(np.concatenate(a) for a in zip(air, (key, i, start, finish), strict=True))

    def _on_air(self, t: int, c: np.ndarray, number: np.ndarray, lost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The charged offloads still on the air on each transmission's link (copy ``c``, link ``number``, at most
        one per (copy, link), as ``_transmit``'s callers send; none for a ``lost`` one): pairs (transmission,
        task), by transmission, then by when the offload started, then by task. A join on (copy, link) with the
        offloads sent (``air``), so that it costs what they and the pairs do, not the live window times the
        transmissions."""
        mark, want = self.sending, c * len(self.link_key) + number
        mark[want] = np.where(lost, 0, np.arange(1, len(c) + 1))
        s = mark.take(self.air[0])
        mark[want] = 0
        hit = np.flatnonzero(s)
        if not len(hit):
            return hit, hit
        j, start, finish = (a[hit] for a in self.air[1:])
        # still on the air (a task is charged again only once it has reached a worker: after its last charge left)
        on = finish > t
        s, j, start = s[hit][on] - 1, j[on], start[on]
        by = np.lexsort((j, start, s))
        return s[by], j[by]

    def _mail(self, state: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This tick's messages of ``state`` (tasks or relayed results): copy, task and the worker they reach,
        in the canonical mail order (arrival tick, sender, sender's sequence)."""
        c, i = self.arriving
        here = self.state[c, i] == state
        c, i = c[here], i[here]
        nd = self.node[c, i]
        by = np.lexsort((self.seq[c, i], self.src_rank[c, i], nd, c))
        return c[by], i[by], nd[by]

    def _admit(self, t: int) -> None:
        c, i, nd = self._mail(TO_WORKER)
        if not len(c):
            return
        roles = self.worker[nd]
        self._enter(ADMISSION)
        key = np.arange(len(c))  # mail order
        failed = self.down[t, nd]  # a worker that is down drops what reaches it (after its results: ``_relay``)
        self._drop(c[failed], i[failed], roles[failed], "node_failure", key[failed])
        late = (t >= self.expires[c, i]) & ~failed
        self._drop(c[late], i[late], roles[late], "expired", key[late])
        late |= failed
        c, i, nd, roles, key = c[~late], i[~late], nd[~late], roles[~late], key[~late]
        if not len(c):
            return
        before = group_rank(c, nd)  # admitted ahead of it in this tick
        room = before < self.buffer[nd] - (self.queued[c, nd] + self.undecided[c, nd])
        self._drop(c[~room], i[~room], roles[~room], "queue_full", key[~room])
        c, i, nd = c[room], i[room], nd[room]
        self.order[c, i] = self._next_order(len(c))
        self.arrived[c, i] = t
        self.dec_arrive[c, i], self.kept[c, i] = -1, False  # a task offloaded here is this controller's to place
        if self.sc.max_hops > 1:
            self.path[c, i, self.plen[c, i]] = nd
            self.hop[c, i] = self.plen[c, i]
            self.plen[c, i] += 1
        wait = self.decides[nd] & (self.hops[c, i] < self.sc.max_hops) & (not self.queue_first)
        if self.recording:
            self.bumped[c[wait], nd[wait]] = True
        self.state[c, i] = np.where(wait, UNDECIDED, QUEUED)
        np.add.at(self.undecided, (c[wait], nd[wait]), 1)
        np.add.at(self.queued, (c[~wait], nd[~wait]), 1)
        self.joined.append((c[~wait], i[~wait]))

    def _serve(self, t: int) -> None:
        """The CPU: the tick's cycles on the FIFO queue, head first, work-conserving (``Worker.serve``)."""
        budget = np.where(self.has_worker, self.budget, 0.0)[None, :].repeat(self.k, axis=0)
        used = np.zeros((self.k, self.n))
        active = (self.queued > 0) & (budget > 0.0)
        # the queued tasks (no task joins a queue while the CPU runs): those of the last tick still queued, in
        # order, and the ones queued since, sorted in (a sort of one long sorted run and a short tail)
        qc, qi = (np.concatenate(a) for a in zip(*self.joined, strict=True))
        self.joined = []
        qn = self.node[qc, qi]
        by = np.argsort(((qc * self.n + qn) << 32) + self.order[qc, qi], kind="stable")  # by copy, node, order
        qc, qi, qn = qc[by], qi[by], qn[by]
        queued = qc, qi
        finishing = 0  # the how-manieth task each worker finishes in this tick
        while active.any():  # a queue that stops being served, or a task that leaves one, does not come back
            keep = active[qc, qn] & (self.state[qc, qi] == QUEUED)
            qc, qi, qn = c, i, nd = qc[keep], qi[keep], qn[keep]
            first = np.r_[True, (c[1:] != c[:-1]) | (nd[1:] != nd[:-1])]
            # urgency of the tasks queued behind each head, added in queue order (bincount adds in input order)
            behind = np.bincount(c[~first] * self.n + nd[~first], self.urgency[c[~first], i[~first]],
                                 minlength=self.k * self.n).reshape(self.k, self.n)
            c, i, nd = c[first], i[first], nd[first]
            new = self.serving[c, nd] != i
            self.imposed[c[new], i[new]] = 0.0
            self.serving[c, nd] = i
            remaining = self.rem[c, i]
            left = budget[c, nd]
            done = remaining <= left + EPS_CYCLES
            spent = np.where(done, remaining, left)
            waiting = self.queued[c, nd] > 1
            self.imposed[c[waiting], i[waiting]] += (spent[waiting] / self.capacity[nd[waiting]]
                                                     * behind[c[waiting], nd[waiting]])
            budget[c, nd] = np.where(done, left - remaining, 0.0)
            used[c, nd] += spent
            self.rem[c[~done], i[~done]] = remaining[~done] - left[~done]
            cd, id_, nd_ = c[done], i[done], nd[done]
            self.queued[cd, nd_] -= 1
            self._enter(SERVICE, finishing)
            finishing += 1
            self._results(t, cd, id_, nd_)
            active = (self.queued > 0) & (budget > 0.0)
        c, i = queued
        still = self.state[c, i] == QUEUED
        self.joined.append((c[still], i[still]))
        c, nd = np.nonzero(used)
        if len(c):
            roles = self.worker[nd]
            self.counters[c, roles, F["busy_cycles"]] += used[c, nd]
            self.counters[c, roles, F["energy_compute"]] += compute_energy(self.kappa[nd], used[c, nd], self.freq[nd])

    def _results(self, t: int, c: np.ndarray, i: np.ndarray, nd: np.ndarray) -> None:
        """Results one step towards their origin (``Worker.route_result``): handed over on its own node, sent over
        the link to a neighbour, else to the previous worker on the task's path (one per (copy, node) per call)."""
        late = t >= self.expires[c, i]
        self._drop(c[late], i[late], self.worker[nd[late]], "expired")
        c, i, nd = c[~late], i[~late], nd[~late]
        origin = self.origin[c, i]
        here = origin == nd
        self._send(c[here], i[here], TO_CLIENT, origin[here], np.full(here.sum(), t + 1), self.worker[nd[here]],
                   self.worker_rank[nd[here]])
        key = nd * self.n + origin  # the origin in its radio: the result goes straight to it
        near = ~here & (self.link_key[self._link(key)] == key)
        if near.any():
            self._transmit(t, c[near], i[near], nd[near], origin[near], self.out_bits[c[near], i[near]], TO_CLIENT)
        far = ~here & ~near
        if far.any():
            c, i, nd = c[far], i[far], nd[far]
            self.hop[c, i] -= 1
            self._transmit(t, c, i, nd, self.path[c, i, self.hop[c, i]], self.out_bits[c, i], TO_RELAY)

    def _relay(self, t: int) -> None:
        """Results reaching a worker on their way back, routed on at once in mail order (``Worker.tick``'s inbox);
        a worker that is down drops them."""
        c, i, nd = self._mail(TO_RELAY)
        if not len(c):
            return
        failed = self.down[t, nd]
        self._enter(RELAY)
        self._drop(c[failed], i[failed], self.worker[nd[failed]], "node_failure", np.arange(len(c))[failed])
        c, i, nd = c[~failed], i[~failed], nd[~failed]
        rank = group_rank(c, nd)
        for r in range(int(rank.max(initial=-1)) + 1):  # each worker's r-th result, in its own step of the stage
            self._enter(RELAY, r)
            self._results(t, c[rank == r], i[rank == r], nd[rank == r])

    # ----- end of the tick -----

    def _drains(self, t: int) -> None:
        """``Worker.drains_at`` of every worker up in tick t, while agents drive controllers: (t + 1) + its queue's
        cycles left / its budget, recomputed where the queue's (length, head, tail) changed, with the cycles added in
        queue order (bincount adds in input order, as ``sum`` does)."""
        qc, qi = (np.concatenate(a) for a in zip(*self.joined, strict=True))
        queued = self.state[qc, qi] == QUEUED
        qc, qi = qc[queued], qi[queued]
        group = qc * self.n + self.node[qc, qi]
        if len(self.joined) > 1:  # after the CPU ran, its one list is in queue order already (``_serve``)
            by = np.argsort((group << 32) + self.order[qc, qi], kind="stable")  # by copy, node, order
            qc, qi, group = qc[by], qi[by], group[by]
        size = self.k * self.n
        key = np.full((3, size), -1)
        key[0] = np.bincount(group, minlength=size)
        if len(group):
            edge = group[1:] != group[:-1]
            first, last = np.r_[True, edge], np.r_[edge, True]
            key[1, group[first]], key[2, group[last]] = qi[first], qi[last]
        key = key.reshape(3, self.k, self.n)
        changed = (key != self.drain_key).any(axis=0) & self.has_worker & ~self.down[t]
        c, nd = np.nonzero(changed)
        if len(c):
            work = np.bincount(group, self.rem[qc, qi], minlength=size).reshape(self.k, self.n)
            self.drain_key[:, c, nd] = key[:, c, nd]
            self.drain[c, nd] = (t + 1) + work[c, nd] / self.budget[nd]

    def _list_divertible(self, t: int) -> None:
        """queue_first: each worker up in tick t lists its divertible tasks as the tick leaves them
        (``Worker.publish``); a list that changed is a report to its controller. One down keeps its last list."""
        w = self.win
        nd = self.node[:, w]
        was = self.listed_at[:, w]
        now = np.where(self._divertible(w) & ~self.down[t, nd], nd, -1)
        now = np.where((was >= 0) & self.down[t, was], was, now)
        c, i = np.nonzero(now != was)
        for at in (was[c, i], now[c, i]):  # the worker it left and the one it joined report
            self.bumped[c[at >= 0], at[at >= 0]] = True
        self.listed_at[:, w] = now
        c, i = np.nonzero(now >= 0)
        self.listed = np.bincount(c * self.n + now[c, i], minlength=self.k * self.n).reshape(self.k, self.n)

    def _levels(self, t: int) -> None:
        w = self.has_worker
        if self.recording:  # only the driven controllers' observations read the drain ticks (the policies do not)
            self._drains(t)
        cnt = self.counters
        cnt[:, :, F["queue"]][:, self.worker[w]] = self.queued[:, w]
        cnt[:, :, F["undecided"]][:, self.worker[w]] = self.undecided[:, w]
        cnt[:, :, F["in_flight"]] = self.flying
        if self.recording and self.queue_first:
            self._list_divertible(t)
        if self.recording and t and self.sc.failures:  # a worker back from a failure reports (what it dropped)
            self.bumped[:, ~self.down[t] & self.down[t - 1]] = True
        if self.recording:  # a worker's report tells its controller how long its links stay busy
            c, nd = np.nonzero(self.bumped & (self.controller >= 0))
            if len(c):
                self.told_busy[c, nd] = self.busy[c[:, None], self.links[nd, 1:]]
        if self.sc.colocated_control:  # what a co-located controller has heard at the end of this tick
            self.heard_late[:], self.heard_occupancy_late[:] = self.heard, self.heard_occupancy
            self.heard_drain_late[:] = self.heard_drain
        if t % self.sc.state_interval == 0 and self.sc.failures:  # a node that is down is silent
            up = ~self.down[t]
            self.heard[:, up] = self.queued[:, up]
            self.heard_occupancy[:, up] = (self.queued + self.undecided)[:, up]
            self.heard_drain[:, up] = self.drain[:, up]
        elif t % self.sc.state_interval == 0:
            self.heard[:] = self.queued
            self.heard_occupancy[:] = self.queued + self.undecided
            self.heard_drain[:] = self.drain
