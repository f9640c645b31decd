"""Tasks from the Alibaba cluster trace (v2018 ``batch_task.csv``), the way the PeersimGym paper reads it.

``batch_task.csv`` has no header; its columns are task_name, instance_num, job_name, task_type,
status, start_time, end_time, plan_cpu, plan_mem — ``plan_cpu`` in hundredths of a core and
``plan_mem`` normalised to [0, 100]. The paper does not model the DAGs of a job: "we interpret the
jobs ... as necessitating the peak CPU and memory resources identified across all tasks within a job.
We calculate task instructions by factoring in the CPU frequency, the requested cores, and task
duration. The maximum memory usage ... is considered equivalent to the data size". So each job becomes
one task:

- arrives at the job's first start time (relative to the trace's first job, scaled by ``time_scale``);
- instructions = peak cores x (job end - job start) x ``frequency``;
- input bytes = peak memory share x ``memory_bytes``; output bytes = input bytes x ``output_ratio``;
- deadline = ``deadline_factor`` x the job's duration (at least ``min_deadline``);
- client: the task sources in turn (round robin), so the load spreads evenly.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from node_runtime.model.spec import TraceRow

COLUMNS = ("task_name", "instance_num", "job_name", "task_type", "status", "start_time", "end_time", "plan_cpu",
           "plan_mem")


class TraceError(ValueError):
    pass


@dataclass(frozen=True)
class Conversion:
    frequency: float = 4.0e6  # instructions per second of one core (the rpi3's, as the AoT scenarios)
    memory_bytes: float = 1.0e9  # what plan_mem = 100 means
    output_ratio: float = 1.0
    deadline_factor: float = 3.0
    min_deadline: float = 10.0
    time_scale: float = 1.0  # seconds of emulation per second of trace
    cpi: float = 1.0
    limit: int | None = None  # at most this many tasks (the earliest jobs)


@dataclass
class _Job:
    start: float
    end: float
    cpu: float  # cores
    mem: float  # share of memory_bytes


def read_jobs(path: Path) -> dict[str, _Job]:
    if not Path(path).is_file():
        raise TraceError(f"{path}: file not found")
    try:
        with Path(path).open(newline="") as fh:
            jobs = _jobs(path, fh)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise TraceError(f"{path}: not a CSV text file ({type(exc).__name__})") from None
    if not jobs:
        raise TraceError(f"{path}: no finished task with a CPU request")
    return jobs


def _jobs(path: Path, fh: Any) -> dict[str, _Job]:
    """The trace's jobs: each one's span and its largest CPU and memory requests."""
    jobs: dict[str, _Job] = {}
    for line, row in enumerate(csv.reader(fh), start=1):
        if not row or len(row) != len(COLUMNS):
            raise TraceError(f"{path}:{line}: expected {len(COLUMNS)} columns ({', '.join(COLUMNS)}), "
                             f"got {len(row)}")
        rec = dict(zip(COLUMNS, row, strict=True))
        try:
            start, end = float(rec["start_time"]), float(rec["end_time"])
            cpu = float(rec["plan_cpu"] or 0) / 100.0
            mem = float(rec["plan_mem"] or 0) / 100.0
            finite = all(map(math.isfinite, (start, end, cpu, mem)))
        except ValueError:
            finite = False
        if not finite:
            raise TraceError(f"{path}:{line}: start_time, end_time, plan_cpu and plan_mem must be finite "
                             "numbers")
        if end <= start or cpu <= 0:
            continue  # unfinished or empty tasks carry no work
        job = jobs.get(rec["job_name"])
        if job is None:
            jobs[rec["job_name"]] = _Job(start, end, cpu, mem)
        else:
            job.start, job.end = min(job.start, start), max(job.end, end)
            job.cpu, job.mem = max(job.cpu, cpu), max(job.mem, mem)
    return jobs


def convert(path: Path, clients: list[str], conversion: Conversion = Conversion()) -> list[dict[str, float | str]]:
    """Rows of the emulator's trace format (docs/scenario.md), sorted by time."""
    if not clients:
        raise TraceError("the scenario has no task source to give the tasks to")
    jobs = sorted(read_jobs(path).values(), key=lambda j: (j.start, j.end))
    if conversion.limit is not None:
        jobs = jobs[:conversion.limit]
    origin = jobs[0].start
    rows = []
    for i, job in enumerate(jobs):
        duration = job.end - job.start
        input_bytes = max(1.0, job.mem * conversion.memory_bytes)
        rows.append({
            "time": (job.start - origin) * conversion.time_scale,
            "client": clients[i % len(clients)],
            "instructions": job.cpu * duration * conversion.frequency,
            "input_bytes": input_bytes,
            "output_bytes": max(1.0, input_bytes * conversion.output_ratio),
            "cpi": conversion.cpi,
            "deadline": max(conversion.min_deadline, conversion.deadline_factor * duration * conversion.time_scale),
        })
    return rows


def write(rows: list[dict[str, float | str]], out: Path) -> None:
    with Path(out).open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=TraceRow.columns())
        w.writeheader()
        w.writerows(rows)
