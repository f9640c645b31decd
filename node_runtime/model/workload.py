"""What a client generates: arrivals under a rate schedule, or rows of a trace.

Two arrival processes: a Poisson count per tick (the default), or the reference implementation's
client, which draws the gap to its next task, ⌊Exp(λ) / dt⌋ ticks but at least one, so that at most
one task arrives per tick.
"""

from __future__ import annotations

import bisect
import math
from collections import defaultdict
from functools import lru_cache
from numbers import Integral, Real

import numpy as np

from node_runtime.model.arrival import Schedule
from node_runtime.model.dag import JobSpec
from node_runtime.model.messages import TaskSize
from node_runtime.model.spec import Scenario, TaskType, TraceRow

BLOCK = 256  # ticks of arrival counts drawn at once (a constant: part of the stream's definition)
LOOKAHEAD = BLOCK  # ticks ``next_arrival`` searches ahead before giving up
_GIVERS = frozenset({"typed", "draws"})  # the methods a source of one's own may redefine to give its tasks


def nominal_arrivals(sc: Scenario) -> dict[str, float]:
    """Tasks per second each worker receives from clients on average: a client's mean rate (its own
    constant, the schedule's mean, or its trace rows over the episode), split evenly over its targets; with
    jobs, that rate of jobs times the tasks of a job on average."""
    mean = sc.workload.arrival.mean
    fixed = dict(sc.workload.client_rates)
    rows: dict[str, int] = {}
    for row in sc.workload.trace or ():
        rows[row.client] = rows.get(row.client, 0) + 1
    horizon = sc.episode_ticks * sc.dt
    out: dict[str, float] = {}
    for client, targets in sc.targets.items():
        rate = rows.get(client, 0) / horizon if sc.workload.trace is not None else fixed.get(client, mean)
        if sc.workload.jobs is not None:
            rate *= sc.workload.jobs.mean_tasks
        for node in targets:
            out[node] = out.get(node, 0.0) + rate / len(targets)
    return out


def trace_tick(row: TraceRow, dt: float) -> int:
    return math.floor(row.time / dt + 1e-9)


@lru_cache(maxsize=256)
def _block_means(arrival: Schedule, start: int, dt: float, horizon: float) -> np.ndarray:
    """λ(s)·dt over the block of ticks from ``start``: the same for every client of a schedule (and every copy
    of the array backend), so computed once."""
    means = np.array([arrival.rate_at(s * dt, horizon) * dt for s in range(start, start + BLOCK)])
    means.flags.writeable = False
    return means


def _every_tick(source: TaskSource, after: int) -> int:
    return after + 1


def draws_deadlines(scenario: Scenario) -> bool:
    """Whether tasks draw their own deadlines (a task type with a range), from a stream of their own."""
    return any(t.drawn for t in scenario.workload.task_types)


class TaskSource:
    """Draws (count, types) of new tasks per tick for one client.

    Counts come from one stream, task types from another and drawn deadlines from a third, so changing
    the task mix or the deadlines does not shift the arrival times. Poisson(lambda * dt) per tick,
    with no cap on the count, or exponential gaps (``Arrival.process``).
    """

    _gives: str | None = None  # which of a subclass's methods gives its tasks, "typed" or "draws"; None: built in

    def __init__(self, scenario: Scenario, node: str, counts_rng: np.random.Generator,
                 types_rng: np.random.Generator) -> None:
        self.dt = scenario.dt
        self.horizon = scenario.episode_ticks * scenario.dt
        self.arrival = scenario.workload.arrival
        self.types: tuple[TaskType, ...] = scenario.workload.task_types
        weights = np.array([t.weight for t in self.types], dtype=float)
        self.probs = weights / weights.sum()
        self.jobs = scenario.workload.jobs
        self.job_probs: np.ndarray | None = None  # of the listed jobs, by weight
        if self.jobs is not None and self.jobs.dags:
            weights = np.array([d.weight for d in self.jobs.dags], dtype=float)
            self.job_probs = weights / weights.sum()
        self.counts_rng = counts_rng
        self.types_rng = types_rng
        self.deadlines_rng: np.random.Generator | None = None  # set by the client when a type draws deadlines
        self.drawn = any(t.drawn for t in self.types)
        self.gaps = self.arrival.process == "exponential_gaps"
        self._next: int | None = None  # exponential gaps: the tick of the next task, once drawn
        self.fixed_rate = dict(scenario.workload.client_rates).get(node)
        if self.fixed_rate is None:
            self.fixed_rate = self.arrival.client_rate(counts_rng)
        self._blocks: dict[int, np.ndarray] = {}  # block start tick -> counts
        self._hits: dict[int, list[int]] = {}  # block start tick -> the offsets in it with a task, once searched
        self.trace: dict[int, list[TraceRow]] | None = None
        if scenario.workload.trace is not None:
            self.trace = defaultdict(list)
            for row in scenario.workload.trace:
                if row.client == node:
                    self.trace[trace_tick(row, self.dt)].append(row)
            self.trace_ticks = sorted(self.trace)

    def __init_subclass__(cls, **kwargs: object) -> None:
        """A source that redefines ``typed`` or ``draws`` but not ``next_arrival`` is asked every tick. Its
        tasks are what the lowest of the two in its class hierarchy gives (``tasks_at``): ``draws`` alone
        gives tasks without a type."""
        super().__init_subclass__(**kwargs)
        if _GIVERS & cls.__dict__.keys() and "next_arrival" not in cls.__dict__:
            cls.next_arrival = _every_tick
        owner = next(k for k in cls.__mro__ if _GIVERS & k.__dict__.keys())
        cls._gives = None if owner is TaskSource else "typed" if "typed" in owner.__dict__ else "draws"

    def rate(self, tick: int) -> float:
        if self.fixed_rate is not None:
            return self.fixed_rate
        return self.arrival.rate_at(tick * self.dt, self.horizon)

    def count(self, tick: int) -> int:
        start = tick - tick % BLOCK
        block = self._blocks.get(start)
        if block is None:  # ticks are asked in order, so blocks are drawn in order
            if self.gaps:
                block = self._blocks[start] = self.gap_block(start)
            else:
                if self.fixed_rate is None and type(self).rate is TaskSource.rate:
                    lam = _block_means(self.arrival, start, self.dt, self.horizon)
                else:
                    lam = np.array([self.rate(s) * self.dt for s in range(start, start + BLOCK)])
                block = self._blocks[start] = self.counts_rng.poisson(lam)
            self._blocks.pop(start - 2 * BLOCK, None)  # the current tick is at most one block behind
            self._hits.pop(start - 2 * BLOCK, None)
        return int(block[tick - start])

    def gap_block(self, start: int) -> list[int]:
        """Counts (0 or 1) of a block under exponential gaps: a task in tick s draws the gap to the next
        one with λ(s), max(1, ⌊X / dt⌋) ticks with X ~ Exp(λ(s)); the first gap, drawn at the first
        tick with λ > 0, may be 0. While λ is 0 no gap is drawn."""
        counts = [0] * BLOCK
        nxt = self._next
        for s in range(start, start + BLOCK):
            if nxt is None:
                lam = self.rate(s)
                if lam > 0:
                    nxt = s + math.floor(self.counts_rng.exponential(1.0 / lam) / self.dt)
            if nxt == s:
                counts[s - start] = 1
                lam = self.rate(s)
                nxt = s + max(1, math.floor(self.counts_rng.exponential(1.0 / lam) / self.dt)) if lam > 0 else None
        self._next = nxt
        return counts

    def typed(self, tick: int) -> list[tuple[TaskSize, int | None]]:
        """Every task created at ``tick``: its size (a ``TaskSize`` or a plain tuple of its five fields) and the
        index of its task type in ``workload.tasks``, whose payload it runs (None: no type, as a trace row
        without one). A source of your own redefines this to give its tasks types (``super().typed`` is the
        built-in draw), or ``draws`` for sizes alone."""
        if self.trace is not None:
            return [(r.size, r.type) for r in self.trace.get(tick, ())]
        n = self.count(tick)
        if n == 0:
            return []
        picks = [0] * n if len(self.types) == 1 else \
            self.types_rng.choice(len(self.types), size=n, p=self.probs).tolist()
        return [(self.types[i].size(self.types[i].draw_deadline(self.deadlines_rng)), i) for i in picks]

    def draws(self, tick: int) -> list[TaskSize]:
        """The size of every task created at ``tick``: those of ``typed``. A source that redefines this alone
        gives tasks without a type."""
        return [size for size, _ in self.typed(tick)]

    def tasks_at(self, tick: int) -> list[tuple[TaskSize, int | None]]:
        """What the client creates at ``tick``, (size, type) per task, from the method that gives this class's
        tasks (``__init_subclass__``); a user's are checked here, so that a bad one fails naming its class and
        tick, not deep inside a worker."""
        if self._gives is None:
            return self.typed(tick)
        given = self.typed(tick) if self._gives == "typed" else self.draws(tick)
        return [self._checked(task, tick) for task in given]

    def _checked(self, task: object, tick: int) -> tuple[TaskSize, int | None]:
        """``task``, a (size, type) of a user's ``typed`` or a size of a user's ``draws``, as a (TaskSize, type
        index or None), or a ValueError."""
        cls = type(self)
        where = f"task source {cls.__module__}:{cls.__qualname__}.{self._gives}({tick})"
        given, kind = task, None
        if self._gives == "typed":
            try:
                given, kind = task
            except (TypeError, ValueError):
                raise ValueError(f"{where}: gave {task!r}; expected a (size, type) pair per task") from None
        try:
            size = given if type(given) is TaskSize else TaskSize(*given)
        except TypeError:
            size = None
        if size is None or not all(isinstance(x, Real) for x in size):
            raise ValueError(f"{where}: a size of {given!r}; expected {len(TaskSize._fields)} numbers "
                             f"({', '.join(TaskSize._fields)})")
        if kind is not None:
            if not isinstance(kind, Integral) or isinstance(kind, bool) or not 0 <= kind < len(self.types):
                names = ", ".join(f"{i} {t.name!r}" for i, t in enumerate(self.types))
                raise ValueError(f"{where}: a task of type {kind!r}; expected the index of a task type of "
                                 f"workload.tasks ({names}) or None")
            kind = int(kind)  # a numpy integer goes on the wire as a plain one
        return size, kind

    def draw_jobs(self, tick: int) -> list[JobSpec]:
        """The DAG of every job created at ``tick`` (``workload.jobs``): as many as ``count`` says, each drawn
        from the task-type stream."""
        return [self.jobs.draw(self.types_rng, self.job_probs) for _ in range(self.count(tick))]

    def next_arrival(self, after: int) -> int:
        """The first tick after ``after`` with a task, or the end of the search window.

        Counts are drawn a block at a time from their own stream, so looking ahead draws exactly
        the numbers that asking tick by tick would."""
        if self.trace is not None:
            i = bisect.bisect_right(self.trace_ticks, after)
            return self.trace_ticks[i] if i < len(self.trace_ticks) else after + LOOKAHEAD
        tick, end = after + 1, after + LOOKAHEAD
        while tick < end:  # a block at a time, each drawn when its first tick is asked, as ``count`` does
            start = tick - tick % BLOCK
            self.count(tick)
            hits = self._hits.get(start)
            if hits is None:
                hits = self._hits[start] = np.flatnonzero(np.asarray(self._blocks[start])).tolist()
            stop = min(start + BLOCK, end)
            j = bisect.bisect_left(hits, tick - start)
            if j < len(hits) and start + hits[j] < stop:
                return start + hits[j]
            tick = stop
        return end

