"""The client role: creates tasks and records their response times when results come back.

A client on a worker node hands its tasks to that worker (next tick, no radio). A client on a node
without a worker owns the node's links and transmits to one of its worker neighbours, picked
uniformly at random per task. With ``workload.jobs`` it creates jobs instead, holds each until it ends
and releases its tasks as they become ready (``jobs.JobBook``), each then sent as a new task.
"""

from __future__ import annotations

from collections.abc import Sequence

from node_runtime.model.jobs import Job, JobBook
from node_runtime.model.messages import Envelope, Kind, Task, TaskSize
from node_runtime.model.plugins import load
from node_runtime.model.radio import Radio
from node_runtime.model.registry import RoleKind, register
from node_runtime.model.rng import stream
from node_runtime.model.role import CHARGED, COMPLETED, Outbox, Role, role_id
from node_runtime.model.spec import NodeSpec, Scenario
from node_runtime.model.workload import TaskSource, draws_deadlines

COUNTS, TYPES, TARGETS, LINKS, DEADLINES = 0, 1, 2, 3, 4  # purposes of the client's random streams


class Client(Role):
    kind = "client"

    def __init__(self, node: NodeSpec, scenario: Scenario) -> None:
        super().__init__(node, scenario)
        self.targets = scenario.targets[node.id]
        self.local = node.has("worker")  # hands tasks to its own worker
        rates = None if self.positions is None else self.positions.rate  # of links with a moving end
        self.radio = None if self.local else Radio.for_node(scenario, node.id, self.targets, rates)
        self.reset(scenario.seed)

    def reset(self, seed: int) -> None:
        super().reset(seed)
        source = self.scenario.workload.source
        cls = load(source, TaskSource) if source else TaskSource
        self.source = cls(self.scenario, self.node.id, stream(seed, self.index, CLIENT.stream, COUNTS),
                          stream(seed, self.index, CLIENT.stream, TYPES))
        if draws_deadlines(self.scenario):
            self.source.deadlines_rng = stream(seed, self.index, CLIENT.stream, DEADLINES)
        self.target_rng = stream(seed, self.index, CLIENT.stream, TARGETS)
        self.seq = 0
        wl = self.scenario.workload
        self.book = JobBook(self.scenario.dt, tuple(t.name for t in wl.task_types)) if wl.jobs is not None else None
        if self.radio is not None:
            self.radio.reset(stream(seed, self.index, CLIENT.stream, LINKS))

    def task_id(self) -> int:
        self.seq += 1
        return (self.index << 32) | self.seq

    def tick(self, t: int, inbox: list[Envelope], out: Outbox) -> None:
        st = self.stats
        dt = self.scenario.dt
        failed = self.down(t)
        book = self.book
        ready: list[tuple[Job, int]] = []
        for env in inbox:
            if env.kind != Kind.RESULT:
                raise ValueError(f"{self.id}: unexpected {env.kind.name} from {env.src}")
            task = env.body.task
            imposed = env.body.imposed  # whatever became of the task, its service delayed others
            if imposed:
                st.delay_imposed += imposed
                st.ledger.append((task.id, CHARGED, imposed))
            if failed:
                self.drop(out, "node_failure", task.id)
            elif task.expired(t, dt):
                self.drop(out, "expired", task.id)
            else:
                response = (t - task.created) * dt
                st.completed += 1
                st.ledger.append((task.id, COMPLETED, response))
                out.emit("completed", self.node.id, task=task.id, response_time=response,
                         executor=env.body.executor)
                if book is not None and task.job is not None:
                    ready.extend(book.finished(task.job, t, st))
        if book is not None:
            book.expire(t, st)
        if failed:
            return
        me = self.node.id
        if book is not None:
            for job, index in ready:
                self.send(t, book.task(job, index, self.task_id(), me, t), out)
            for spec in self.source.draw_jobs(t):
                for job, index in book.start(self.task_id(), spec, t, st):
                    self.send(t, book.task(job, index, self.task_id(), me, t), out)
            return
        for size, kind in self.source.tasks_at(t):
            self.send(t, Task(self.task_id(), me, t, size, type=kind), out)

    def send(self, t: int, task: Task, out: Outbox) -> None:
        """A new task: to the own worker, or over the radio to a target worker in range."""
        self.stats.generated += 1
        out.emit("created", self.node.id, task=task.id, **task.size._asdict())
        if self.local:
            out.send(Kind.TASK, role_id("worker", self.node.id), task)
            return
        targets = self.reachable(t)
        target = targets[0]
        if len(targets) > 1:
            target = targets[int(self.target_rng.integers(len(targets)))]
        self.transmit(t, Kind.TASK, target, role_id("worker", target), task, task.size.input_bytes * 8.0, out)

    def reachable(self, t: int) -> tuple[str, ...]:
        """Its targets in range in tick ``t`` (all of them if none is, or if no node moves)."""
        if self.positions is None:
            return self.targets
        me, near = self.node.id, self.positions.in_range
        return tuple(j for j in self.targets if not self.scenario.moving_link(me, j) or near(me, j, t)) \
            or self.targets

    def wake(self, t: int) -> float:
        """At its next arrival: results come by mail, and nothing else happens in between."""
        if self.outages:  # a failed client draws nothing, so its draws depend on the failure schedule
            return t + 1
        if self.book is not None:  # and when a job it holds misses its deadline
            return min(self.source.next_arrival(t), self.book.next_expiry())
        return self.source.next_arrival(t)


CLIENT = register(RoleKind(Client, order=1, stream=1))


def arrivals(sc: Scenario, seed: int, ticks: int) -> list[tuple[int, int, TaskSize]]:
    """(tick, client node index, size) of every task the clients of ``sc`` create in ticks 0 .. ``ticks`` - 1
    of the episode with ``seed``, in the order they are created. It is the clients' own code and random
    streams, which no decision moves, so it is every run's workload task for task: the array backend's, and
    the arrival trace the clairvoyant bound sees. It reads the tasks as the client does (``TaskSource.tasks_at``)
    and leaves out their types, which only a payload reads: the array backend refuses payloads, and the bound
    serves every task its nominal cycles. Jobs have no such trace: which of their tasks arrive, and when,
    depends on where the earlier ones ran."""
    return arrivals_of(sc, (seed,), ticks)[0]


def arrivals_of(sc: Scenario, seeds: Sequence[int], ticks: int) -> list[list[tuple[int, int, TaskSize]]]:
    """``arrivals`` of each seed, the clients made once and reset for each."""
    if sc.workload.jobs is not None:
        raise ValueError(f"{sc.name}: a scenario of jobs (workload.jobs) has no arrival trace of its tasks")
    clients = [Client(node, sc) for node in sc.nodes if node.has("client")]
    runs = []
    for seed in seeds:
        out = []
        for client in clients:
            client.reset(seed)
            t = 0
            while t < ticks:  # only the ticks it wakes at: the others draw nothing, so skipping them changes no draw
                if not client.down(t):
                    out.extend((t, client.index, size) for size, _ in client.source.tasks_at(t))
                t = int(client.wake(t))
        out.sort(key=lambda task: (task[0], task[1]))  # stable: each client's tasks of a tick in the order drawn
        runs.append(out)
    return runs
