"""Jobs as DAGs: what a job is (its tasks, the bytes each edge carries, its deadline) and where jobs come
from (a list of jobs, or a random layered generator). docs/model.md, "Jobs as DAGs".

A job's tasks are listed in an order its edges respect (every edge goes from a lower index to a higher
one), so a list is acyclic by construction and its index order is a topological order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field, model_validator

from node_runtime.model.values import Count, NonNeg, Pos, Strict


class DagTask(Strict):
    """One task of a job: its work, and the data that flows between it and the job's origin (an entry
    task's input, an exit task's result). The data between tasks is on the job's edges."""

    name: str = ""
    instructions: Pos  # rho
    cpi: Pos = 1.0  # xi
    input_bytes: NonNeg = 0.0  # from the job's origin, beside what its in-edges bring
    output_bytes: NonNeg = 0.0  # back to the job's origin as its result, beside what its out-edges carry
    type: str | None = None  # a task type of workload.tasks, whose payload it runs (its size stays its own)


Edge = tuple[int, int, NonNeg]  # (from task, to task, bytes)


class JobSpec(Strict):
    """A job: a DAG of tasks, the bytes on each edge, and one deadline for the whole job (seconds from its
    creation until its last result must be back at its origin). ``weight``: how often a listed job is
    drawn, relative to the others."""

    name: str = "job"
    weight: Pos = 1.0
    deadline: Pos
    tasks: tuple[DagTask, ...] = Field(min_length=1)
    edges: tuple[Edge, ...] = ()

    @model_validator(mode="after")
    def _acyclic(self) -> JobSpec:
        n = len(self.tasks)
        seen = set()
        for k, (a, b, _) in enumerate(self.edges):
            if not 0 <= a < b < n:
                raise ValueError(f"edges[{k}]: expected [from, to, bytes] with 0 <= from < to < {n} (tasks are "
                                 f"listed in an order their edges respect), got [{a}, {b}, …]")
            if (a, b) in seen:
                raise ValueError(f"edges[{k}]: a second edge from task {a} to task {b}")
            seen.add((a, b))
        return self


@dataclass(frozen=True, slots=True)
class Shape:
    """What the origin derives from a job once: each task's predecessors and successors (ascending), the
    bytes its inputs and its result carry, and its remaining critical path in cycles."""

    preds: tuple[tuple[int, ...], ...]
    succs: tuple[tuple[int, ...], ...]
    input_bytes: tuple[float, ...]  # alpha_in: its own input plus its in-edges' bytes
    output_bytes: tuple[float, ...]  # alpha_out: its own result plus its out-edges' bytes
    successor_bytes: tuple[float, ...]  # its out-edges' bytes
    critical_cycles: tuple[float, ...]  # its cycles plus the most cycles on a path from it to an exit task

    @classmethod
    def of(cls, job: JobSpec) -> Shape:
        n = len(job.tasks)
        preds: list[list[int]] = [[] for _ in range(n)]
        succs: list[list[int]] = [[] for _ in range(n)]
        ins = [t.input_bytes for t in job.tasks]
        outs = [0.0] * n
        for a, b, size in job.edges:
            preds[b].append(a)
            succs[a].append(b)
            ins[b] += size
            outs[a] += size
        critical = [0.0] * n
        for i in reversed(range(n)):
            t = job.tasks[i]
            critical[i] = t.instructions * t.cpi + max((critical[s] for s in succs[i]), default=0.0)
        return cls(tuple(tuple(sorted(p)) for p in preds), tuple(tuple(sorted(s)) for s in succs), tuple(ins),
                   tuple(o + t.output_bytes for o, t in zip(outs, job.tasks, strict=True)), tuple(outs),
                   tuple(critical))


class Span(Strict):
    """A value drawn uniformly from [low, high] (equal ends: that value)."""

    low: NonNeg
    high: NonNeg

    @model_validator(mode="after")
    def _ordered(self) -> Span:
        if self.high < self.low:
            raise ValueError("high must be >= low")
        return self


class CountSpan(Span):
    """A whole number drawn uniformly from low .. high, both included."""

    low: Count
    high: Count


class LayeredDag(Strict):
    """``workload.jobs.generator``: random layered DAGs, the shape of the DAG-offloading literature's
    synthetic jobs (a number of layers, each of a random width; every task after the first layer depends on
    1..``fan_in`` tasks of the layer before it, and every task before the last layer feeds at least one
    task of the next, so the fan-out follows; edges join consecutive layers only). The draw, from the
    client's task-type stream, per job: the number of layers, then each layer's width, then each task's
    instructions, then for each task of each layer after the first (in order) its number of predecessors
    and which (without replacement), then for every task left without a successor (in order) the task of
    the next layer it feeds, uniformly among those with fewer than ``fan_in`` predecessors (among all when
    none has: a layer wider than ``fan_in`` times the next), then each edge's bytes in (from, to) order."""

    layers: CountSpan = CountSpan(low=3, high=5)
    width: CountSpan = CountSpan(low=1, high=3)
    fan_in: Count = 2
    instructions: Span = Span(low=2.0e6, high=8.0e6)
    cpi: Pos = 1.0
    edge_bytes: Span = Span(low=1.0e5, high=1.0e6)
    input_bytes: NonNeg = 1.0e5  # of each entry task, from the origin
    output_bytes: NonNeg = 1.0e4  # of each exit task, to the origin
    deadline: Pos = 100.0
    type: str | None = None  # the task type of every task drawn, whose payload it runs (sizes stay drawn)

    @model_validator(mode="after")
    def _some_work(self) -> LayeredDag:
        if self.instructions.low <= 0:
            raise ValueError("instructions: expected low > 0 (every task has work to do)")
        return self

    def draw(self, rng: np.random.Generator) -> JobSpec:
        n_layers = int(rng.integers(self.layers.low, self.layers.high + 1))
        widths = [int(rng.integers(self.width.low, self.width.high + 1)) for _ in range(n_layers)]
        starts = np.cumsum([0, *widths]).tolist()
        n = starts[-1]
        work = rng.uniform(self.instructions.low, self.instructions.high, size=n).tolist()
        edges: set[tuple[int, int]] = set()
        for k in range(1, n_layers):
            before = widths[k - 1]
            for j in range(widths[k]):
                m = int(rng.integers(1, min(self.fan_in, before) + 1))
                for p in sorted(rng.choice(before, size=m, replace=False).tolist()):
                    edges.add((starts[k - 1] + p, starts[k] + j))
        fed = {a for a, _ in edges}
        fan_in = [0] * n
        for _, b in edges:
            fan_in[b] += 1
        for k in range(n_layers - 1):
            for i in range(starts[k], starts[k + 1]):
                if i not in fed:  # it feeds a task of the next layer with room under fan_in (if none has: any)
                    nxt = range(starts[k + 1], starts[k + 2])
                    room = [j for j in nxt if fan_in[j] < self.fan_in] or list(nxt)
                    j = room[int(rng.integers(len(room)))]
                    edges.add((i, j))
                    fan_in[j] += 1
        ordered = sorted(edges)
        sizes = rng.uniform(self.edge_bytes.low, self.edge_bytes.high, size=len(ordered)).tolist()
        has_pred = {b for _, b in ordered}
        tasks = tuple(DagTask(name=f"t{i}", instructions=work[i], cpi=self.cpi,
                              input_bytes=0.0 if i in has_pred else self.input_bytes,
                              output_bytes=self.output_bytes if i not in fed else 0.0, type=self.type)
                      for i in range(n))
        return JobSpec(name="generated", deadline=self.deadline, tasks=tasks,
                       edges=tuple((a, b, s) for (a, b), s in zip(ordered, sizes, strict=True)))


class Jobs(Strict):
    """``workload.jobs``: every arrival of the arrival process is a job rather than a task. Its DAG is one of
    ``dags`` drawn by weight (listed in the file, or imported from a trace) or drawn by ``generator``."""

    dags: tuple[JobSpec, ...] = ()
    generator: LayeredDag | None = None

    @model_validator(mode="after")
    def _one_source(self) -> Jobs:
        if bool(self.dags) == (self.generator is not None):
            raise ValueError("expected either dags (a list of jobs) or generator, not both nor neither")
        return self

    @property
    def longest_deadline(self) -> float:
        """No job completes later than this: what a job, or a task of one, that never completes costs."""
        if self.generator is not None:
            return self.generator.deadline
        return max(d.deadline for d in self.dags)

    @property
    def mean_tasks(self) -> float:
        """Tasks in a job on average: of the listed jobs by weight, or E[layers] x E[width] of the generator."""
        if self.generator is not None:
            g = self.generator
            return (g.layers.low + g.layers.high) / 2 * (g.width.low + g.width.high) / 2
        return sum(d.weight * len(d.tasks) for d in self.dags) / sum(d.weight for d in self.dags)

    def draw(self, rng: np.random.Generator, probs: np.ndarray | None) -> JobSpec:
        """One job's DAG: generated, or listed (drawn by weight when there are several; ``probs``)."""
        if self.generator is not None:
            return self.generator.draw(rng)
        if len(self.dags) == 1:
            return self.dags[0]
        return self.dags[int(rng.choice(len(self.dags), p=probs))]
