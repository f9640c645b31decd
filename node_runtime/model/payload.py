"""Real work in the loop: a task type's payload, run by the worker that serves the task.

A task type may name a Python callable (``workload.tasks[].payload``). When a task of that type (the index
a task carries, ``Task.type``) starts service, its worker calls it, measures the CPU time the call took on
its own thread and serves the task for that work instead of the type's nominal ρ·ξ cycles (docs/model.md,
"Payloads"):

    cycles = measured CPU seconds x payload_hz,   payload_hz = the node's, else cores x frequency

Measured times vary from run to run; a record of them (``--payload-record``) makes a run replayable: a
replay (``--payload-replay``) uses the recorded seconds instead of calling anything, so it gives the
recorded run's results bit for bit, in any transport and process layout. Each worker appends its own
measurements to the record, one JSON line each, keyed by (seed, task id, serving node), which no layout
changes.

``python -m node_runtime.model.calibrate`` measures a machine's reference rate, from which a device's
``payload_hz`` follows (docs/extending.md, "Real work in the loop").
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from node_runtime.model.messages import Task
from node_runtime.model.plugins import load
from node_runtime.model.spec import NodeSpec, Payload, PayloadLog, Scenario


class PayloadError(RuntimeError):
    """A payload that cannot run or be replayed: the run fails, naming the node, task type and payload."""


RecordKey = tuple[int, int, str]  # (seed, task id, serving node)


def read_record(path: str) -> dict[RecordKey, float]:
    """The measured CPU seconds of a record file. A last line without its newline (a run killed while it
    wrote) is left out; anything else malformed, or a key recorded twice, is refused with its line."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise PayloadError(f"{path}: cannot read the payload record ({exc.strerror})") from None
    out: dict[RecordKey, float] = {}
    lines = text.split("\n")[:-1]  # the part after the last newline is an unfinished line, or empty
    for number, line in enumerate(lines, 1):
        try:
            row = json.loads(line)
            key = (int(row["seed"]), int(row["task"]), str(row["node"]))
            seconds = float(row["cpu_s"])
        except (ValueError, KeyError, TypeError):
            raise PayloadError(f"{path}:{number}: expected a JSON object with seed, task, node and cpu_s "
                               f"(got {line[:80]!r})") from None
        if not (math.isfinite(seconds) and seconds >= 0):
            raise PayloadError(f"{path}:{number}: cpu_s must be a number >= 0 (got {row['cpu_s']!r})")
        if key in out:
            raise PayloadError(f"{path}:{number}: task {key[1]} on node {key[2]!r} with seed {key[0]} is recorded "
                               "twice (record each seed once)")
        out[key] = seconds
    return out


_records: dict[tuple[str, int, int], dict[RecordKey, float]] = {}  # (path, mtime, size) -> record, per process


def _replayed(path: str) -> dict[RecordKey, float]:
    """``read_record``, once per file and version in a process, whose workers share it."""
    st = os.stat(path)
    key = (path, st.st_mtime_ns, st.st_size)
    if key not in _records:
        _records.clear()
        _records[key] = read_record(path)
    return _records[key]


class Payloads:
    """One worker's payloads: which tasks have one, and the cycles each takes on this node."""

    def __init__(self, node: NodeSpec, scenario: Scenario) -> None:
        self.node = node.id
        self.hz = node.payload_hz if node.payload_hz is not None else node.capacity
        self.types = {i: t for i, t in enumerate(scenario.workload.task_types) if t.payload is not None}
        self.log = scenario.payload_log
        self.functions: dict[str, Callable[..., Any]] = {}
        self.seed = scenario.seed  # the episode's: the worker sets it at every reset

    @classmethod
    def of(cls, node: NodeSpec, scenario: Scenario) -> Payloads | None:
        """None when no task type has a payload: the worker then runs as it always has."""
        if not any(t.payload is not None for t in scenario.workload.task_types):
            return None
        return cls(node, scenario)

    def cycles(self, task: Task) -> float | None:
        """The cycles ``task`` takes here: its payload's measured (or recorded) CPU seconds x payload_hz;
        None for a task without a payload (its type has none, or it has no type): it keeps its nominal ρ·ξ."""
        ttype = self.types.get(task.type)
        if ttype is None:
            return None
        if self.log.mode == "replay":
            seconds = _replayed(self.log.path).get((self.seed, task.id, self.node))
            if seconds is None:
                raise PayloadError(f"node {self.node}: task type {ttype.name!r}: {self.log.path} has no time for "
                                   f"task {task.id} with seed {self.seed} (replay the scenario and seed it was "
                                   "recorded with)")
        else:
            seconds = self.measure(ttype.name, ttype.payload, task.id)
        return seconds * self.hz

    def measure(self, type_name: str, payload: Payload, task_id: int) -> float:
        """Run the payload once; its CPU time on this thread, appended to the record when one is kept."""
        fn = self.functions.get(payload.call)
        where = f"node {self.node}: task type {type_name!r}: payload {payload.call}"
        if fn is None:
            try:
                fn = self.functions[payload.call] = load(payload.call, callable_ok=True)
            except ValueError as exc:
                raise PayloadError(f"{where}: {exc}") from None
        start = time.thread_time()
        try:
            fn(task_id, **payload.args)
        except Exception as exc:
            raise PayloadError(f"{where} raised {type(exc).__name__}: {exc}") from exc
        seconds = time.thread_time() - start
        if self.log.mode == "record":
            line = json.dumps({"seed": self.seed, "task": task_id, "node": self.node, "type": type_name,
                               "cpu_s": seconds}) + "\n"
            fd = os.open(self.log.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:  # one write of one line, appended: lines of several processes never interleave
                os.write(fd, line.encode())
            finally:
                os.close(fd)
        return seconds


def run_log(record: str | None = None, replay: str | None = None) -> PayloadLog:
    """The ``payload_log`` of a run that records to or replays from a file (paths made absolute, since node
    processes may start elsewhere). Recording starts a new file; a replay's file is read once here, so a
    bad one fails before any process starts."""
    if record and replay:
        raise PayloadError("record or replay payload times, not both")
    if record:
        path = os.path.abspath(record)
        Path(path).write_text("")
        return PayloadLog(mode="record", path=path)
    if replay:
        path = os.path.abspath(replay)
        read_record(path)
        return PayloadLog(mode="replay", path=path)
    return PayloadLog()
