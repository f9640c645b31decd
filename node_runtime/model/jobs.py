"""The jobs of one origin: which of their tasks are ready, and whether each job met its deadline.

The client that creates a job holds it until it ends (docs/model.md, "Jobs as DAGs"). A task of the job
is released, as a new task of that client, once the result of every predecessor is back at the origin:
its entry tasks when the job is created, the others in the tick the last of their predecessors' results
arrives. A job completes when the result of its last unfinished task arrives in time; it misses its
deadline at the first tick at which it is older than its deadline without having completed (a task of it
dropped on the way, or late). Every job ends exactly once, in one of the two ways.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from node_runtime.model.dag import JobSpec, Shape
from node_runtime.model.messages import JobRef, Task, TaskSize
from node_runtime.model.role import Counters


@dataclass(slots=True)
class Job:
    id: int
    spec: JobSpec
    shape: Shape
    created: int  # tick
    expires: int  # the first tick at which it has missed its deadline
    waiting: list[int]  # per task: predecessors whose results are not back yet
    left: int  # tasks whose results are not back yet


class JobBook:
    """The active jobs of one client, in creation order, and the job counters they move."""

    def __init__(self, dt: float, types: tuple[str, ...] = ()) -> None:
        """``types``: the names of the task types, in ``workload.tasks`` order (a task of a job that names one
        carries its index)."""
        self.dt = dt
        self.types = {name: i for i, name in enumerate(types)}
        self.active: dict[int, Job] = {}

    def start(self, job_id: int, spec: JobSpec, t: int, stats: Counters) -> list[tuple[Job, int]]:
        """A new job at tick ``t``: its entry tasks, to release now."""
        shape = Shape.of(spec)
        probe = Task(0, "", t, TaskSize(0.0, 0.0, 0.0, 0.0, spec.deadline))
        job = Job(job_id, spec, shape, t, probe.expires_at(self.dt), [len(p) for p in shape.preds], len(spec.tasks))
        self.active[job_id] = job
        stats.jobs += 1
        stats.jobs_active += 1
        return [(job, i) for i, waiting in enumerate(job.waiting) if not waiting]

    def task(self, job: Job, index: int, task_id: int, origin: str, t: int) -> Task:
        """Task ``index`` of ``job``, released at tick ``t``: due when its job is."""
        spec, shape = job.spec, job.shape
        d = spec.tasks[index]
        size = TaskSize(d.instructions, shape.input_bytes[index], shape.output_bytes[index], d.cpi,
                        spec.deadline - (t - job.created) * self.dt)
        return Task(task_id, origin, t, size,
                    job=JobRef(job.id, index, shape.critical_cycles[index], shape.successor_bytes[index]),
                    type=None if d.type is None else self.types[d.type])

    def finished(self, ref: JobRef, t: int, stats: Counters) -> list[tuple[Job, int]]:
        """A result of a task of a job came back in time at tick ``t``: the tasks it makes ready (ascending),
        or the job's completion."""
        job = self.active.get(ref.job)
        if job is None:  # the job has missed its deadline already
            return []
        job.left -= 1
        if not job.left:
            del self.active[job.id]
            stats.jobs_active -= 1
            stats.jobs_completed += 1
            stats.makespan_sum += (t - job.created) * self.dt
            return []
        ready = []
        for s in job.shape.succs[ref.index]:
            job.waiting[s] -= 1
            if not job.waiting[s]:
                ready.append((job, s))
        return ready

    def expire(self, t: int, stats: Counters) -> None:
        """Jobs that have missed their deadline by tick ``t``."""
        for job in [j for j in self.active.values() if j.expires <= t]:
            del self.active[job.id]
            stats.jobs_active -= 1
            stats.jobs_missed += 1

    def next_expiry(self) -> float:
        """The first tick at which an active job misses its deadline (inf: none)."""
        return min((j.expires for j in self.active.values()), default=math.inf)
