"""The jobs of the Alibaba cluster trace (v2018 ``batch_task.csv``) as DAGs of tasks, dependencies kept.

A task's name encodes what it runs after: ``M1`` is task 1 with no predecessor; ``R2_1`` is task 2,
which runs after task 1; ``J3_1_2`` is task 3, after tasks 1 and 2 (the letter is the task's kind, map,
reduce or join, and plays no part here). A name of another form (``task_Nzg3…``, ``MergeTask``) is a task
with no dependency. Columns, units and the conversion are ``topologies.alibaba``'s:

- a task's instructions = instance_num x cores (plan_cpu / 100) x (end_time - start_time) x ``frequency``;
- an edge carries the predecessor's memory share (plan_mem / 100) x ``memory_bytes`` x ``output_ratio``;
  an entry task brings its own memory share x ``memory_bytes`` from the origin, an exit task returns its
  own x ``output_ratio``;
- the job's deadline = ``deadline_factor`` x its span (first start to last end) x ``time_scale``, at least
  ``min_deadline``.

A job is kept whole or not at all: one with a task that did not finish (``Terminated``, end after start,
a CPU request), a name that repeats, or a predecessor missing from the job, or a cycle, is skipped. Jobs are
taken in order of their first start (``limit``: the earliest ones); their tasks in a topological order,
ties by task number. When jobs arrive is the arrival process's (``workload.arrival``), not the trace's.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

from node_runtime.model.dag import DagTask, JobSpec
from topologies.alibaba import COLUMNS, Conversion, TraceError

NAME = re.compile(r"[A-Za-z]+(\d+)((?:_\d+)*)")


def dependencies(name: str) -> tuple[int, tuple[int, ...]] | None:
    """``R2_1`` -> (2, (1,)); None for a name that encodes no dependency."""
    m = NAME.fullmatch(name)
    if m is None:
        return None
    return int(m.group(1)), tuple(sorted({int(x) for x in m.group(2).split("_")[1:]}))


def read_dags(path: Path, conversion: Conversion | None = None) -> list[JobSpec]:
    """Every whole job of the file, as a DAG, earliest first (``conversion``: the defaults if None)."""
    conversion = conversion or Conversion()
    path = Path(path)
    if not path.is_file():
        raise TraceError(f"{path}: file not found")
    rows: dict[str, list[tuple[int, dict[str, str]]]] = {}
    try:
        with path.open(newline="") as fh:
            for line, row in enumerate(csv.reader(fh), start=1):
                if len(row) != len(COLUMNS):
                    raise TraceError(f"{path}:{line}: expected {len(COLUMNS)} columns ({', '.join(COLUMNS)}), "
                                     f"got {len(row)}")
                rec = dict(zip(COLUMNS, row, strict=True))
                rows.setdefault(rec["job_name"], []).append((line, rec))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise TraceError(f"{path}: not a CSV text file ({type(exc).__name__})") from None
    jobs = [job for name, recs in rows.items() if (job := _job(path, name, recs, conversion)) is not None]
    if not jobs:
        raise TraceError(f"{path}: no job whose every task finished")
    jobs.sort(key=lambda j: j[0])
    if conversion.limit is not None:
        jobs = jobs[:conversion.limit]
    return [spec for _, spec in jobs]


def _job(path: Path, name: str, recs: list[tuple[int, dict[str, str]]],
         c: Conversion) -> tuple[tuple[float, str], JobSpec] | None:
    """(sort key, DAG) of one job, or None when it is not whole."""
    tasks: dict[object, tuple[float, float, float, int, tuple[int, ...]]] = {}
    for line, rec in recs:
        try:
            instances = float(rec["instance_num"] or 1)
            start, end = float(rec["start_time"]), float(rec["end_time"])
            cpu, mem = float(rec["plan_cpu"] or 0) / 100.0, float(rec["plan_mem"] or 0) / 100.0
            finite = all(map(math.isfinite, (instances, start, end, cpu, mem)))
        except ValueError:
            finite = False
        if not finite:
            raise TraceError(f"{path}:{line}: instance_num, start_time, end_time, plan_cpu and plan_mem must be "
                             "finite numbers")
        if rec["status"] != "Terminated" or end <= start or cpu <= 0 or instances <= 0:
            return None
        parsed = dependencies(rec["task_name"])
        key: object = parsed[0] if parsed else rec["task_name"]
        if key in tasks:
            return None
        work = instances * cpu * (end - start) * c.frequency
        tasks[key] = (start, end, work, max(1.0, mem * c.memory_bytes), parsed[1] if parsed else ())
    if any(p not in tasks for *_, deps in tasks.values() for p in deps):
        return None
    order = _topological(tasks)
    if order is None:
        return None
    index = {key: i for i, key in enumerate(order)}
    fed = {p for *_, deps in tasks.values() for p in deps}
    edges = sorted((index[p], index[key], tasks[p][3] * c.output_ratio) for key in order for p in tasks[key][4])
    dag = tuple(DagTask(name=str(key), instructions=tasks[key][2], cpi=c.cpi,
                        input_bytes=0.0 if tasks[key][4] else tasks[key][3],
                        output_bytes=0.0 if key in fed else tasks[key][3] * c.output_ratio) for key in order)
    first, last = min(t[0] for t in tasks.values()), max(t[1] for t in tasks.values())
    deadline = max(c.min_deadline, c.deadline_factor * (last - first) * c.time_scale)
    return (first, name), JobSpec(name=name, deadline=deadline, tasks=dag, edges=tuple(edges))


def _topological(tasks: dict[object, tuple]) -> list[object] | None:
    """Kahn's order, numbered tasks by number then named ones by name; None on a cycle."""
    def rank(key: object) -> tuple[int, int, str]:
        return (0, key, "") if isinstance(key, int) else (1, 0, str(key))

    left = {key: len(t[4]) for key, t in tasks.items()}
    after: dict[object, list[object]] = {key: [] for key in tasks}
    for key, t in tasks.items():
        for p in t[4]:
            after[p].append(key)
    order: list[object] = []
    ready = sorted((k for k, n in left.items() if not n), key=rank)
    while ready:
        key = ready.pop(0)
        order.append(key)
        for s in after[key]:
            left[s] -= 1
            if not left[s]:
                ready.append(s)
        ready.sort(key=rank)
    return order if len(order) == len(tasks) else None
