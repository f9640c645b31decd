"""The worker role: a FIFO buffer, a work-conserving CPU, and the node's radio links.

One tick, in this order (docs/model.md, "The worker, one tick"):

1. failure: a node that goes down drops everything it holds (``node_failure``);
2. overload is sampled: the buffer was full at the start of the tick;
3. the inbox, in canonical order: tasks are set aside for admission, results are forwarded
   towards their origin, decisions are set aside;
4. expiry: every held task older than its deadline is dropped (``expired``);
5. decisions are applied: keep locally, or transmit to a neighbour;
6. arrivals are admitted while occupancy (queue + undecided) < Q_max, else ``queue_full``;
7. the CPU spends cores * frequency * dt cycles on the queue head first, and a finished task's
   result leaves in the same tick;
8. the state is broadcast to the neighbours, and the undecided list reported to the controller,
   when they changed.

With ``admission: queue_first`` (the reference implementation's worker) arrivals join the queue at
once, and a decision diverts a queued task that has not started yet; the controller is told about
those tasks instead of undecided ones.

The worker owns its node's outgoing links, so every inter-node transmission from a worker node
queues on one FIFO per neighbour, whichever role asked for it.
"""

from __future__ import annotations

import math
from collections import deque
from itertools import islice

from node_runtime.model.energy import compute_energy, idle_energy
from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Pending, Report, Result, Task
from node_runtime.model.payload import Payloads
from node_runtime.model.radio import Radio
from node_runtime.model.registry import RoleKind, register
from node_runtime.model.rng import stream
from node_runtime.model.role import STAT_FIELDS, Outbox, Role, role_id, state_topic
from node_runtime.model.spec import NodeSpec, Scenario

EPS_CYCLES = 1e-6  # a task with fewer cycles left than this is done (float rounding of budgets)
COAST_TICKS = 256  # the longest a worker coasts at once: finding a finish tick costs a step per tick ahead
# the counters a coasting worker changes each tick (``Worker.wake``), in the order of STAT_FIELDS
OVERLOADED_TICKS, BUSY_CYCLES, ENERGY_COMPUTE, ENERGY_IDLE = (
    STAT_FIELDS.index(name) for name in ("overloaded_ticks", "busy_cycles", "energy_compute", "energy_idle"))


class Worker(Role):
    kind = "worker"

    def __init__(self, node: NodeSpec, scenario: Scenario) -> None:
        super().__init__(node, scenario)
        self.dt = scenario.dt
        self.neighbours = scenario.neighbours[node.id]
        self.radio = Radio.for_node(scenario, node.id, self.neighbours,
                                    None if self.positions is None else self.positions.rate)
        # neighbours whose link to this node follows positions: a state is re-sent to one that comes into range
        self.moving = tuple(j for j in self.neighbours if scenario.moving_link(node.id, j))
        self.decides = node.has("controller") and scenario.max_hops > 0
        self.controller = role_id("controller", node.id) if node.has("controller") else ""
        # a co-located controller (control_latency 0) reads this worker itself; any other is sent reports
        self.reports = bool(self.controller) and not scenario.colocated_control
        self.queue_first = scenario.admission == "queue_first"
        self.tracks_divertible = self.queue_first and self.decides
        self.topic = state_topic(node.id)
        self.budget = node.capacity * scenario.dt
        self.idle_w = node.idle_power_w
        self.payloads = Payloads.of(node, scenario)  # None: no task type has real work to run
        # a class that serves or publishes otherwise may act in every tick of a service: it never coasts
        self.coasts = type(self).serve is Worker.serve and type(self).publish is Worker.publish
        self.reset(scenario.seed)

    def reset(self, seed: int) -> None:
        super().reset(seed)
        self.queue: deque[list] = deque()  # [task, remaining cycles], head in service; queue_first adds
        # [..., arrival tick, kept here by a decision]
        self.undecided: dict[int, tuple[Task, int]] = {}  # id -> (task, arrival tick), in arrival order
        self.next_expiry = math.inf  # no held task expires before this tick (it may be early, never late)
        self.failed = False
        self.radio.reset(stream(seed, self.index, WORKER.stream))
        self._last_state: tuple[int, int, float] | None = None
        self._drain_key = (0, -1, -1)  # the queue (length, head id, tail id) ``drains_at`` was computed for: empty ...
        self._drain = 0.0  # ... and what it gave (an empty queue's work is done, whatever tick it names)
        # bumped whenever what the controller is told changes: the undecided set (queue_first: the divertible
        # tasks), or the links while tasks wait for a decision
        self.tasks_version = 0
        self._reported_version = -1
        self._links_changed = False  # since the last report
        self._divertible: list[list] = []  # queue_first: the queue entries a decision may still divert
        self._serving = -1  # the id of the task in service (the queue's head) ...
        self._imposed = 0.0  # ... and the delay its service has imposed so far
        self.drift = None
        self._coasting = -1  # while ``drift`` is set: the last tick this worker ran
        if self.payloads is not None:
            self.payloads.seed = seed

    # ----- helpers -----

    @property
    def occupancy(self) -> int:
        return len(self.queue) + len(self.undecided)

    def route_result(self, t: int, result: Result, out: Outbox) -> None:
        """Move a result one step towards its origin client.

        Straight to the origin when it is this node or a neighbour; otherwise to the previous
        worker on the task's path (``result.hop`` is this node's position on it).
        """
        task = result.task
        if task.expired(t, self.dt):
            self.drop(out, "expired", task.id)
            return
        origin = task.origin
        if origin == self.node.id:
            out.send(Kind.RESULT, role_id("client", origin), result)
        elif origin in self.radio:
            self.transmit(t, Kind.RESULT, origin, role_id("client", origin), result,
                          task.size.output_bytes * 8.0, out)
        else:
            result.hop -= 1
            prev = task.path[result.hop]
            self.transmit(t, Kind.RESULT, prev, role_id("worker", prev), result, task.size.output_bytes * 8.0, out)

    def pending(self) -> list[Pending]:
        """The tasks the controller may place, oldest first."""
        if self.queue_first:
            return [Pending.of(e[0], e[2]) for e in self._divertible]
        return [Pending.of(task, at) for task, at in self.undecided.values()]

    def divertible(self) -> list[list]:
        """queue_first: queued tasks that have not started, were not kept here by a decision, and may
        still be offloaded."""
        if not self.decides:
            return []
        max_hops = self.scenario.max_hops
        return [e for e in self.queue if not self.started(e) and not e[3] and e[0].hops < max_hops]

    def started(self, entry: list) -> bool:
        """Whether a queued task has had cycles of the CPU (a payload's task starts with other cycles than its
        nominal ones, so its remaining count alone cannot tell)."""
        return entry[1] != entry[0].size.cycles or entry[0].id == self._serving

    def transmit(self, t: int, kind: Kind, dst_node: str, dst_role: str, body: Task | Result, bits: float,
                 out: Outbox) -> None:
        """A transmission changes a link's backlog: the controller is told with the tasks it may place."""
        super().transmit(t, kind, dst_node, dst_role, body, bits, out, charged=kind == Kind.TASK)  # an offload
        self._links_changed = True
        if self.undecided or self._divertible:
            self.tasks_version += 1

    def drop_all(self, out: Outbox, cause: str) -> None:
        for task in [e[0] for e in self.queue] + [task for task, _ in self.undecided.values()]:
            self.drop(out, cause, task.id)
        self.queue.clear()
        self.undecided.clear()
        self.next_expiry = math.inf
        self.tasks_version += 1

    # ----- the tick -----

    def tick(self, t: int, inbox: list[Envelope], out: Outbox) -> None:
        st = self.stats
        if self.drift is not None:
            self.catch_up(t, out)
        if not inbox and not self.queue and not self.undecided and not self.outages and not self.idle_w:
            # idle: nothing held, nothing arriving, nothing that can fail; only the levels are refreshed
            if st.overloaded:
                out.emit("overload", self.node.id, overloaded=False, occupancy=0)
            st.overloaded = 0
            self.publish(t, out)
            return
        failed = self.down(t)
        if failed != self.failed:
            out.emit("failure", self.node.id, down=failed)
            if failed:
                self.drop_all(out, "node_failure")
                self.radio.reset(self.radio.rng)
                self._links_changed = True
        self.failed = failed
        overloaded = int(self.occupancy >= self.node.buffer)
        if overloaded != st.overloaded:
            out.emit("overload", self.node.id, overloaded=bool(overloaded), occupancy=self.occupancy)
        st.overloaded = overloaded
        st.overloaded_ticks += overloaded

        arrivals: list[Task] = []
        decisions: list[Decision] = []
        for env in inbox:
            kind = env.kind
            if kind == Kind.TASK:
                arrivals.append(env.body)
            elif kind == Kind.RESULT:
                if failed:
                    self.drop(out, "node_failure", env.body.task.id)
                else:
                    self.route_result(t, env.body, out)
            elif kind == Kind.DECISION:
                decisions.extend(env.body)
        if failed:
            for task in arrivals:
                self.drop(out, "node_failure", task.id)
            self.publish(t, out)
            return

        if t >= self.next_expiry:
            self.expire(t, out)
        if decisions:
            if self.queue_first:
                self.divert(t, decisions, out)
            else:
                self.apply(t, decisions, out)
        if arrivals:
            self.admit(t, arrivals, out)
        if self.queue:
            self.serve(t, out)
        if self.idle_w:
            st.energy_idle += idle_energy(self.idle_w, self.dt)
        self.publish(t, out)

    def wake(self, t: int) -> float:
        """The next tick in which something may change without mail: a task finishes or expires, the buffer's
        level changes (full or not), a changed state reaches its broadcast slot; every tick while the node can
        fail. Until then only counters move, by the same amounts each tick (the CPU's full budget, idle power,
        one overloaded tick): the worker *coasts*. ``drift`` then holds those amounts, for whoever accounts
        for this worker while it sleeps, and its next tick first replays the skipped ones (``catch_up``)."""
        self.drift = None
        full = int(self.occupancy >= self.node.buffer)
        if self.outages or self.stats.overloaded != full:
            return t + 1
        wake = self.next_expiry if self.queue or self.undecided else math.inf
        if self.state(t) != self._last_state or self.moving:
            interval = self.scenario.state_interval
            wake = min(wake, t + interval - t % interval)
        if self.queue:
            wake = min(wake, t + self._service_ticks())
        if not (self.queue or self.idle_w or full):
            return wake  # nothing moves: a plain sleep
        if wake <= t + 1 or not self.coasts:
            return t + 1
        drift = [0.0] * len(STAT_FIELDS)
        drift[OVERLOADED_TICKS] = full
        if self.queue:
            drift[BUSY_CYCLES] = self.budget
            drift[ENERGY_COMPUTE] = compute_energy(self.node.kappa, self.budget, self.node.frequency)
        if self.idle_w:
            drift[ENERGY_IDLE] = idle_energy(self.idle_w, self.dt)
        self.drift = tuple(drift)
        self._coasting = t
        return wake

    def _service_ticks(self) -> int:
        """In how many ticks the head of the queue finishes (at most COAST_TICKS: waking before is always
        right), by the same float steps ``serve`` takes; 1 if it has not started (a task that starts changes
        what the controller may divert)."""
        task, remaining = self.queue[0][0], self.queue[0][1]
        if task.id != self._serving or remaining == task.size.cycles:
            return 1
        budget, ticks = self.budget, 1
        while remaining > budget + EPS_CYCLES and ticks < COAST_TICKS:
            remaining -= budget
            ticks += 1
        return ticks

    def catch_up(self, t: int, out: Outbox) -> None:
        """Replay the ticks skipped while coasting, each exactly as ``tick`` would have run it with no mail:
        by ``wake``'s choice of tick, no task finishes or expires and no level or state changes in them."""
        st = self.stats
        for skipped in range(self._coasting + 1, t):
            st.overloaded_ticks += st.overloaded
            if self.queue:
                self.serve(skipped, out)
            if self.idle_w:
                st.energy_idle += idle_energy(self.idle_w, self.dt)
        self.drift = None

    def expire(self, t: int, out: Outbox) -> None:
        """Drop every held task past its deadline; then find when the next one expires."""
        dt = self.dt
        if self.queue and any(e[0].expired(t, dt) for e in self.queue):
            kept = deque()
            for entry in self.queue:
                if entry[0].expired(t, dt):
                    self.drop(out, "expired", entry[0].id)
                else:
                    kept.append(entry)
            self.queue = kept
        if self.undecided:
            gone = [k for k, (task, _) in self.undecided.items() if task.expired(t, dt)]
            for k in gone:
                del self.undecided[k]
                self.drop(out, "expired", k)
            self.tasks_version += bool(gone)
        held = [e[0] for e in self.queue] + [task for task, _ in self.undecided.values()]
        self.next_expiry = min((task.expires_at(dt) for task in held), default=math.inf)

    def apply(self, t: int, decisions: list[Decision], out: Outbox) -> None:
        st = self.stats
        self.tasks_version += bool(decisions)
        for d in decisions:
            held = self.undecided.pop(d.task_id, None)
            if held is None:  # dropped or expired after the controller saw it
                st.stale_decisions += 1
                continue
            task = held[0]
            if not d.target or d.target == self.node.id:
                self.queue.append([task, task.size.cycles])
            else:
                task.hops += 1
                st.offloaded += 1
                out.emit("offloaded", self.node.id, task=task.id, to=d.target)
                self.transmit(t, Kind.TASK, d.target, role_id("worker", d.target), task,
                              task.size.input_bytes * 8.0, out)

    def divert(self, t: int, decisions: list[Decision], out: Outbox) -> None:
        """queue_first: a decision keeps a queued task here or takes it out of the queue to a neighbour,
        if it has not started meanwhile (else it is stale)."""
        st = self.stats
        for d in decisions:
            at = next((i for i, e in enumerate(self.queue) if e[0].id == d.task_id), None)
            entry = self.queue[at] if at is not None else None
            if entry is None or self.started(entry) or entry[3]:
                st.stale_decisions += 1
                continue
            if not d.target or d.target == self.node.id:
                entry[3] = True
                continue
            del self.queue[at]
            task = entry[0]
            task.hops += 1
            st.offloaded += 1
            out.emit("offloaded", self.node.id, task=task.id, to=d.target)
            self.transmit(t, Kind.TASK, d.target, role_id("worker", d.target), task, task.size.input_bytes * 8.0, out)

    def admit(self, t: int, arrivals: list[Task], out: Outbox) -> None:
        buffer = self.node.buffer
        for task in arrivals:
            if task.expired(t, self.dt):
                self.drop(out, "expired", task.id)
            elif self.occupancy >= buffer:
                self.drop(out, "queue_full", task.id)
            else:
                task.path = (*task.path, self.node.id)
                self.next_expiry = min(self.next_expiry, task.expires_at(self.dt))
                if self.queue_first:
                    self.queue.append([task, task.size.cycles, t, False])
                elif self.decides and task.hops < self.scenario.max_hops:
                    self.undecided[task.id] = (task, t)
                    self.tasks_version += 1
                else:
                    self.queue.append([task, task.size.cycles])

    def serve(self, t: int, out: Outbox) -> None:
        """Spend the tick's cycles on the queue, head first. While the head is served, every task behind it
        waits: each second of that service is charged to the head as 1/deadline per waiting task (the delay
        it imposes, ``Result.imposed``), a waiter that later expires or is diverted included."""
        budget = self.budget
        used = 0.0
        queue = self.queue
        capacity = self.node.capacity
        urgency = self.urgency
        while queue and budget > 0.0:
            entry = queue[0]
            task = entry[0]
            if task.id != self._serving:  # a new head (the last one finished, or left the queue)
                self._serving, self._imposed = task.id, 0.0
                if self.payloads is not None and (cycles := self.payloads.cycles(task)) is not None:
                    entry[1] = cycles  # its real work, run now: the tick waits for it
            remaining = entry[1]
            finishes = remaining <= budget + EPS_CYCLES
            if len(queue) > 1:
                spent = remaining if finishes else budget
                self._imposed += spent / capacity * sum(urgency(e[0]) for e in islice(queue, 1, None))
            if finishes:
                budget -= remaining
                used += remaining
                queue.popleft()
                self.route_result(t, Result(task, self.node.id, t, len(task.path) - 1, self._imposed), out)
            else:
                entry[1] = remaining - budget
                used += budget
                budget = 0.0
        if used:
            st = self.stats
            st.busy_cycles += used
            st.energy_compute += compute_energy(self.node.kappa, used, self.node.frequency)

    def publish(self, t: int, out: Outbox) -> None:
        """Broadcast the state and report the undecided list, each only when it changed.

        Skipping an unchanged broadcast is invisible to receivers: they keep the last state they
        heard, which is exactly what a repeated broadcast would have told them.
        """
        st = self.stats
        st.queue = len(self.queue)
        st.undecided = len(self.undecided)
        if self.failed:
            return
        state = self.state(t)
        interval = self.scenario.state_interval
        if t % interval == 0 and (state != self._last_state or (self.moving and self.arrived(t, interval))):
            self._last_state = state
            out.broadcast(Kind.STATE, self.topic, NodeState(self.node.id, *state))
        if self.tracks_divertible:
            divertible = self.divertible()
            if [e[0].id for e in divertible] != [e[0].id for e in self._divertible]:
                self.tasks_version += 1
            self._divertible = divertible
        if self.reports and self.tasks_version != self._reported_version:
            self._reported_version = self.tasks_version
            busy = self.radio.busy_until() if self._links_changed else None
            self._links_changed = False
            out.send(Kind.REPORT, self.controller, Report(self.pending(), busy))

    def state(self, t: int) -> tuple[int, int, float]:
        """What the broadcast says at the end of tick ``t``: queue, occupancy and ``drains_at``."""
        return len(self.queue), self.occupancy, self.drains_at(t)

    def drains_at(self, t: int) -> float:
        """The tick in which the CPU would finish the admitted tasks (the queue's cycles left, head first) at its
        capacity: (t + 1) + cycles / budget, computed when the queue last changed (its length, head or tail), so that it
        stays the same while the CPU only works through it. A neighbour's seconds of work left at the end of tick s
        are max(0, drains_at - (s + 1)) x dt, as for a link's backlog; an estimate (a payload's real work, or a
        class that serves otherwise, can make it early or late)."""
        q = self.queue
        key = (len(q), q[0][0].id, q[-1][0].id) if q else (0, -1, -1)
        if key != self._drain_key:
            self._drain_key = key
            self._drain = t + 1 + sum(e[1] for e in q) / self.budget
        return self._drain

    def arrived(self, t: int, interval: int) -> bool:
        """Whether a moving neighbour is in range at this broadcast instant and was not at the last one: it
        missed what was said meanwhile, so an unchanged state is said again (the neighbour hears only what is
        sent while it is in range; docs/model.md, "Moving nodes")."""
        me, near = self.node.id, self.positions.in_range
        return any(near(me, j, t) and (t < interval or not near(me, j, t - interval)) for j in self.moving)


def own_state(node: NodeSpec, scenario: Scenario) -> tuple[str, ...]:
    return (state_topic(node.id),)


WORKER = register(RoleKind(Worker, order=0, stream=0, default=True, publishes=own_state))
