"""Per-tick and per-episode metrics from the processes' reports, and the conservation invariant.

Each ``Done`` carries cumulative counters per role, and the arrival ticks of the tasks and results
its roles put on links; a process that sleeps through a tick keeps its last counters. Per tick they
are stacked in canonical role order (so float sums do not depend on which process reported first),
summed per node and in total, and checked:

    generated = completed + dropped + (queued + undecided + in flight)

A violation stops the run: a task was lost or invented, and no result after that can be trusted.

Two more columns are the orchestrator's own, kept per role like the counters so that nodes and totals
sum them alike: the sum of the response times of a client's completed tasks, and ``penalised_s``, that
sum plus ``penalty_s`` for every task it generated that has not completed (docs/model.md, "Metrics"). In a
scenario of jobs a third, ``job_penalised_s``, is the same for jobs (their makespans, and ``penalty_s`` for
every job not completed), and the jobs are conserved too: jobs = completed + missed + running.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from node_runtime.model.role import STAT_FIELDS, role_node
from node_runtime.model.spec import Scenario
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.protocol import Done
from orchestrator.catalogue import CATALOGUE, CHANGES, METRIC, Agg, Form, Metric, Out, shown, shown_as

# in_flight: tasks and results a role sent that have not arrived yet; response_time_sum and penalised_s:
# seconds, for the penalised response time
FIELDS = (*STAT_FIELDS, "in_flight", "response_time_sum", "penalised_s", "job_penalised_s")
F = {name: i for i, name in enumerate(FIELDS)}
IN_FLIGHT, RT_SUM, PENALISED = F["in_flight"], F["response_time_sum"], F["penalised_s"]
GENERATED, COMPLETED = F["generated"], F["completed"]
JOBS, JOBS_COMPLETED, MAKESPAN_SUM, JOB_PENALISED = (F[name] for name in ("jobs", "jobs_completed", "makespan_sum",
                                                                          "job_penalised_s"))
# jobs = jobs_completed + jobs_missed + jobs_active, in a scenario of jobs
JOBS_CONSERVED = ("jobs_completed", "jobs_missed", "jobs_active")
N_STATS = len(STAT_FIELDS)
# generated = completed + dropped + in_system, counter by counter
CONSERVED = tuple(f for name in ("completed", "dropped", "in_system") for f in METRIC[name].fields)
EPISODE_MEANS = tuple(m for m in CATALOGUE if m.episode_mean)  # summarised by their mean over the ticks


class ConservationError(RuntimeError):
    pass


@cache
def counters(m: Metric) -> tuple[int, ...]:
    """The columns of FIELDS that ``m`` sums."""
    return tuple(F[f] for f in m.fields)


def total(m: Metric, rows: np.ndarray) -> Any:
    """``m``'s counters summed for every row (the last axis runs over FIELDS), one counter after the other
    in catalogue order, so that a float total is the same number in every output."""
    cols = counters(m)
    out = rows[..., cols[0]]
    for c in cols[1:]:
        out = out + rows[..., c]
    return out


def penalty_s(sc: Scenario) -> float:
    """What a task that never completes costs the penalised response time: the scenario's longest
    deadline (of its trace's rows, or of its task types: a range's high end plus its grace), so it is
    never less than a completion's time and letting a task expire never lowers the score."""
    if sc.workload.jobs is not None:  # a job's deadline bounds its tasks' and its own time
        return sc.workload.jobs.longest_deadline
    trace = sc.workload.trace
    deadlines = [row.size.deadline for row in trace or ()] or [t.longest_deadline for t in sc.workload.task_types]
    return max(deadlines, default=0.0)


@cache
def denominators(m: Metric) -> tuple[int, ...]:
    """The columns of FIELDS that a RATIO ``m`` divides by."""
    return tuple(F[f] for f in m.of)


def ratio(m: Metric, rows: np.ndarray) -> Any:
    """A RATIO of cumulative counters, for one row (a float, None while the denominator is 0) or several (a list)."""
    num = total(m, rows)
    cols = denominators(m)
    den = rows[..., cols[0]]
    for c in cols[1:]:
        den = den + rows[..., c]
    if np.ndim(den) == 0:
        return float(num / den) if den else None
    with np.errstate(divide="ignore", invalid="ignore"):
        values = num / den
    return [float(v) if d else None for v, d in zip(values.ravel(), den.ravel(), strict=True)] \
        if den.ndim == 1 else [ratio(m, r) for r in rows]


def share(used: Any, capacity: Any) -> Any:
    """Cycles used / cycles available, 0 where there are none."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(capacity > 0, used / np.where(capacity > 0, capacity, 1), 0.0)


def _plain(m: Metric, values: Any) -> Any:
    """numpy values as Python numbers of the metric's type (nested lists for arrays)."""
    return (values.astype(np.int64) if m.dtype is int else values).tolist()


def output_values(out: Out, level: np.ndarray, change: np.ndarray, capacity: Any,
                  samples: Callable[[Metric], Any] | None = None, jobs: bool = False,
                  moving: bool = False) -> dict[str, Any]:
    """What ``out`` shows of the catalogue, by key: Python numbers for one row, lists for several (the last
    axis of ``level``, the values at the end of the tick, and of ``change``, their change over the tick or
    step, runs over FIELDS; ``capacity``: the cycles available in that tick or step, per row). A count
    shows its change where ``out`` is one of CHANGES, else its cumulative value. ``samples(metric)``
    gives a SAMPLES metric's value; without it they are left out. ``jobs``: with the job metrics (a scenario
    of jobs). ``moving``: the scenario's nodes move, so the parts only such scenarios have are shown too."""
    counts = change if out in CHANGES else level
    shown_values: dict[str, Any] = {}
    for m, key, form in shown_as(out, jobs):
        if m.agg is Agg.SAMPLES:
            if samples is not None:
                shown_values[key] = samples(m)
        elif m.agg is Agg.SHARE:
            shown_values[key] = share(change[..., counters(m)[0]], capacity).tolist()
        elif m.agg is Agg.RATIO:
            shown_values[key] = ratio(m, level)
        else:
            put(shown_values, key, m, form, counts if m.agg is Agg.COUNT else level, moving)
    return shown_values


def put(into: dict[str, Any], key: str, m: Metric, form: Form, row: np.ndarray, moving: bool = False) -> None:
    """A count or level ``m`` from ``row`` (or rows) of FIELDS, in ``form``, under ``key`` (in the FLAT
    form, its parts beside it; those of moving nodes only if ``moving``)."""
    if form is Form.TOTAL:
        into[key] = _plain(m, total(m, row))
        return
    parts = {p.key: row[..., F[p.field]] for p in m.parts_of(moving)}
    if form is Form.PARTS:
        into[key] = {k: _plain(m, v) for k, v in parts.items()}
    elif form is Form.PARTS_TOTAL:
        into[key] = {**{k: _plain(m, v) for k, v in parts.items()}, "total": _plain(m, sum(parts.values()))}
    else:  # FLAT
        into[key] = _plain(m, total(m, row))
        into.update({f"{key}_{k}": _plain(m, v) for k, v in parts.items()})


@dataclass(slots=True)
class TickReport:
    """One tick, summed over the network: counts are this tick's, levels are at its end."""

    tick: int
    totals: np.ndarray  # cumulative FIELDS over all roles
    delta: np.ndarray  # this tick's change of FIELDS
    nodes: np.ndarray  # cumulative FIELDS per node (canonical node order)
    node_delta: np.ndarray
    response_times: list[float]  # completions this tick, seconds
    ledger: list[tuple[int, int, float]] = field(default_factory=list)  # the roles' per-task entries this tick,
    # in canonical role order (role.Counters.ledger); only while an agent drives the episode

    def __getitem__(self, name: str) -> int | float:
        """A count or level of the catalogue over the network at the end of the tick (cumulative)."""
        m = METRIC[name]
        return _plain(m, total(m, self.totals))


def bus_record(report: TickReport, metrics: Metrics, sim_id: str, episode: int) -> dict[str, Any]:
    """The ``…/metrics/tick`` message for monitors (schema in docs/bus.md): this tick's totals, its
    changes, its completions' response times, and one column per node metric."""
    t, d = report.totals, report.delta
    record = {
        "type": "metrics", "sim": sim_id, "episode": episode, "tick": report.tick,
        "time_s": report.tick * metrics.scenario.dt,
        "totals": output_values(Out.BUS, t, d, metrics.capacity.sum(), jobs=metrics.jobs, moving=metrics.moving),
        "delta": output_values(Out.BUS_DELTA, t, d, metrics.capacity.sum(), jobs=metrics.jobs,
                               moving=metrics.moving),
    }
    record.update((m.key(Out.BUS), report.response_times) for m in shown(Out.BUS) if m.agg is Agg.SAMPLES)
    record["nodes"] = {"id": list(metrics.node_ids), "buffer": [n.buffer for n in metrics.scenario.nodes],
                       **output_values(Out.BUS_NODES, report.nodes, report.node_delta, metrics.capacity,
                                       jobs=metrics.jobs)}
    return record


STREAM_BLOCK = 256  # ticks gathered before their rows are written: vectorised, and memory stays bounded
SUMMARY = "summary.json"
# what summary.json says from the start of a streamed episode until its results replace it: only a run
# killed outright (kill -9, power lost) leaves it
UNFINISHED = "unknown: the run stopped before writing its results (killed?)"


def write_summary(out_dir: Path, summary: dict[str, Any]) -> None:
    """summary.json, whole or not at all: written beside it, then renamed over it, so that a reader or a
    crash never finds half a file."""
    partial = out_dir / f".{SUMMARY}.tmp"
    try:
        partial.write_text(json.dumps(summary, indent=2) + "\n")
        partial.replace(out_dir / SUMMARY)
    finally:
        partial.unlink(missing_ok=True)


def unfinished(scenario: str) -> dict[str, Any]:
    """The summary.json of an episode from its start: incomplete, until the results replace it."""
    return {"scenario": scenario, "ticks": None, "incomplete": {"reason": UNFINISHED, "last_tick": None}}


@dataclass(frozen=True)
class _Block:
    """Rows given to a table: their CSV bytes, the file's length once they are on disk, their last tick."""

    data: bytes
    end: int
    through: int


class _Table:
    """A CSV file that grows by blocks of rows, each row once whatever interrupts the writing (Ctrl-C, an
    error, at any point): a block is rendered in memory, then taken with one assignment, and what of it is
    on disk is read from the file's length, not from a flag set after the write, so that completing it
    later never repeats a row nor loses one."""

    def __init__(self, path: Path, header: list[str]) -> None:
        self.file = path.open("wb", buffering=0)  # unbuffered: the file's length is what was written
        data = _csv([header])
        self.block = _Block(data, len(data), -1)
        self.complete()

    def add(self, rows: list[list[Any]]) -> None:
        """``rows``, each starting with its tick, but those of ticks the table holds already."""
        self.complete()
        last = self.block
        fresh = [row for row in rows if row[0] > last.through]
        if fresh:
            data = _csv(fresh)
            self.block = _Block(data, last.end + len(data), fresh[-1][0])
            self.complete()

    def complete(self) -> None:
        """Write what of the last block is not on disk yet."""
        block = self.block
        while not self.file.closed and (missing := block.end - os.fstat(self.file.fileno()).st_size) > 0:
            self.file.write(block.data[len(block.data) - missing:])

    def close(self) -> None:
        self.complete()
        self.file.close()


def _csv(rows: Sequence[Sequence[Any]]) -> bytes:
    text = io.StringIO()
    csv.writer(text).writerows(rows)
    return text.getvalue().encode()


@dataclass(frozen=True)
class _Recording:
    """A tick being made part of the episode (``Metrics.add``), and the lengths of what it extends."""

    tick: int
    totals: np.ndarray
    nodes: np.ndarray
    rts: list[float]
    rts_by_node: dict[str, list[float]]
    means: dict[str, Any]
    n_ticks: int
    rows: int  # ticks in the rows not written yet, before this one
    times: int  # response times before it
    node_times: dict[str, int]  # response times per node before it


@dataclass
class _Rows:
    """Consecutive ticks not yet written as rows, and the values just before the first (to take changes)."""

    before_totals: np.ndarray
    before_nodes: np.ndarray
    ticks: list[int] = field(default_factory=list)
    totals: list[np.ndarray] = field(default_factory=list)
    nodes: list[np.ndarray] = field(default_factory=list)
    means: list[float | str] = field(default_factory=list)  # mean response time of the tick's completions, or ""

    def add(self, tick: int, totals: np.ndarray, nodes: np.ndarray, rts: list[float]) -> None:
        self.ticks.append(tick)
        self.totals.append(totals)
        self.nodes.append(nodes)
        self.means.append(float(np.mean(rts)) if rts else "")

    def keep(self, n: int) -> None:
        """Keep the first ``n`` ticks."""
        for column in (self.ticks, self.totals, self.nodes, self.means):
            del column[n:]


class Metrics:
    """Sums the processes' counters every tick and keeps what the episode's results need.

    The summary is built from running aggregates, so it costs the same memory after ten ticks or a
    million. ticks.csv and nodes.csv are either streamed to files as the ticks come (``stream``: the
    CLI's case, so a long run's memory stays flat and an interrupted one keeps its rows) or, with
    ``history``, rebuilt at the end from the per-tick arrays kept in memory (tests, short runs).

    An interrupt at any point (Ctrl-C raises where it lands) leaves the results whole: a tick is recorded
    by steps that can be run again (``settle``), and the tables write each row once (``_Table``), so
    that the summary and the tables of an interrupted episode agree tick for tick.
    """

    def __init__(self, plan: ProcessLayout, history: bool = True) -> None:
        sc = plan.scenario
        self.scenario = sc
        self.moving = sc.radio is not None  # its outputs show the drops of broken links
        self.roles = plan.roles
        self.node_ids = tuple(n.id for n in sc.nodes)
        incidence = np.zeros((len(self.node_ids), len(self.roles)))
        for i, r in enumerate(self.roles):
            incidence[sc.index[role_node(r)], i] = 1.0
        self.incidence = incidence
        self.capacity = np.array([n.capacity * sc.dt if n.has("worker") else 0.0 for n in sc.nodes])
        self.penalty = penalty_s(sc)
        self.jobs = sc.workload.jobs is not None  # a scenario of jobs: their metrics are shown, and checked
        self.history = history
        self._stream_to: Path | None = None  # where each episode's tables are streamed (``stream``)
        self._tables: list[_Table] = []  # ticks.csv, nodes.csv while they are open
        self._recording: _Recording | None = None
        self.reset()

    def reset(self) -> None:
        self.close_stream()
        self.n_ticks = 0
        self.last_tick: int | None = None
        self.last_totals = np.zeros(len(FIELDS))
        self.last_nodes = np.zeros((len(self.node_ids), len(FIELDS)))
        self._mean_sums: dict[str, Any] = {}  # episode_mean metric -> sum over the ticks (network, per node)
        self._rows = _Rows(np.zeros(len(FIELDS)), np.zeros((len(self.node_ids), len(FIELDS))))
        self.response_times: list[float] = []
        self.rt_by_node: dict[str, list[float]] = {}
        self._matrix = np.zeros((len(self.roles), len(FIELDS)))
        self._landing: dict[int, list[tuple[int, int]]] = {}  # arrival tick -> [(role, tasks and results)]
        self._drift: dict[int, tuple] = {}  # coasting role -> what each tick adds to its stats (Done.drift)
        self._recording = None
        if self._stream_to is not None:
            self._open_tables(self._stream_to)
            write_summary(self._stream_to, unfinished(self.scenario.name))

    # ----- the per-tick tables -----

    def stream(self, out_dir: Path) -> None:
        """From the next reset on, write ticks.csv and nodes.csv into ``out_dir`` as the ticks come, and a
        summary.json that says the episode is incomplete until ``write`` replaces it. The stream replaces the
        in-memory history, which is then no longer kept."""
        self._stream_to = out_dir
        self.history = False

    def _open_tables(self, out_dir: Path) -> None:
        out_dir.mkdir(parents=True, exist_ok=True)
        for name, header in (("ticks.csv", self.tick_header()), ("nodes.csv", self.node_header())):
            self._tables.append(_Table(out_dir / name, header))

    def close_stream(self) -> None:
        """Write the rows not written yet and close the files (again after an interrupt: nothing is repeated)."""
        if self._tables:
            self.settle()
            self._flush()
        for table in self._tables:
            table.close()
        self._tables = []

    def _flush(self) -> None:
        rows = self._rows
        if rows.ticks:
            ticks, nodes = self._tables
            ticks.add(self._tick_rows(rows))
            nodes.add(self._node_rows(rows))
            if not self.history:  # streamed rows leave memory; a history keeps them for tick_table()
                self._rows = _Rows(rows.totals[-1], rows.nodes[-1])

    # ----- every tick -----

    def add(self, tick: int, dones: list[Done]) -> TickReport:
        m = self._matrix
        rts: list[float] = []
        landing = self._landing
        drift = self._drift
        reported: list[int] = []
        values: list[tuple] = []
        starting: dict[int, tuple] = {}  # drifts given this tick: they count from the next one
        for d in dones:  # roles are named by their canonical index, which is their row
            if d.stats:
                reported.extend(d.stats)
                values.extend(d.stats.values())
            starting.update(d.drift)
            for role, arrivals in d.flights.items():
                for arrive, n in arrivals.items():
                    m[role, IN_FLIGHT] += n
                    landing.setdefault(arrive, []).append((role, n))
        if reported:  # each role at most once: one process hosts it
            m[reported, :N_STATS] = values
            if drift:
                for role in reported:
                    drift.pop(role, None)  # a drift ends, or starts anew, with a report
        if drift:  # roles coasting through this tick: each row moves on as the role's own replay counts it
            m[list(drift), :N_STATS] += list(drift.values())
        drift.update(starting)
        for role, n in landing.pop(tick, ()):  # delivered in this tick: held or accounted by the receiver
            m[role, IN_FLIGHT] -= n
        ledgers: dict[int, list[tuple[int, int, float]]] = {}
        rts_by_node: dict[str, list[float]] = {}
        for d in dones:  # completions, in canonical role order within each process
            for role, times in d.response_times.items():
                rts.extend(times)
                m[role, RT_SUM] += sum(times)
                rts_by_node.setdefault(role_node(self.roles[role]), []).extend(times)
            ledgers.update(d.ledger)
        ledger = [entry for role in sorted(ledgers) for entry in ledgers[role]] if ledgers else []
        return self._record(tick, rts, rts_by_node, ledger)

    def add_counters(self, tick: int, counters: np.ndarray, completions: list[tuple[int, float]],
                     ledger: list[tuple[int, int, float]]) -> TickReport:
        """Tick ``tick`` from every role's cumulative counters (roles by canonical index; the columns of FIELDS
        up to the response times' sum), the response times of its completions (role index, seconds; in canonical
        role order) and its ledger: what ``add`` makes of the processes' reports, from the array backend."""
        self._matrix[:, :RT_SUM + 1] = counters
        rts = [time for _, time in completions]
        rts_by_node: dict[str, list[float]] = {}
        for role, time in completions:
            rts_by_node.setdefault(role_node(self.roles[role]), []).append(time)
        return self._record(tick, rts, rts_by_node, ledger)

    def _record(self, tick: int, rts: list[float], rts_by_node: dict[str, list[float]],
                ledger: list[tuple[int, int, float]]) -> TickReport:
        """The tick's sums, checked, reported and recorded, from the counters in the matrix."""
        m = self._matrix
        m[:, PENALISED] = m[:, RT_SUM] + self.penalty * (m[:, GENERATED] - m[:, COMPLETED])
        if self.jobs:
            m[:, JOB_PENALISED] = m[:, MAKESPAN_SUM] + self.penalty * (m[:, JOBS] - m[:, JOBS_COMPLETED])
        totals = m.sum(axis=0)
        nodes = self.incidence @ m
        self.check(tick, totals)
        report = TickReport(tick, totals, totals - self.last_totals, nodes, nodes - self.last_nodes, rts, ledger)
        means = {}
        for metric in EPISODE_MEANS:
            network, per_node = self._mean_sums.get(metric.name, (0.0, 0.0))
            means[metric.name] = (network + total(metric, totals), per_node + total(metric, nodes))
        self._recording = _Recording(tick, totals, nodes, rts, rts_by_node, means, self.n_ticks + 1,
                                     len(self._rows.ticks), len(self.response_times),
                                     {node: len(self.rt_by_node.get(node, ())) for node in rts_by_node})
        self.settle()
        if self._tables and len(self._rows.ticks) >= STREAM_BLOCK:
            self._flush()
        return report

    def settle(self) -> None:
        """Make the tick being recorded part of the episode (again, if an interrupt cut it short). Every
        step sets a value, or cuts a list back to its length before the tick and extends it, so that the
        whole may run again after an interrupt anywhere in it and the tick is then recorded once."""
        r = self._recording
        if r is None:
            return
        if self.history or self._tables:
            self._rows.keep(r.rows)
            self._rows.add(r.tick, r.totals, r.nodes, r.rts)
        del self.response_times[r.times:]
        self.response_times.extend(r.rts)
        for node, times in r.rts_by_node.items():
            kept = self.rt_by_node.setdefault(node, [])
            del kept[r.node_times[node]:]
            kept.extend(times)
        self._mean_sums = r.means
        self.last_totals, self.last_nodes, self.last_tick = r.totals, r.nodes, r.tick
        self.n_ticks = r.n_ticks
        self._recording = None

    def check(self, tick: int, t: np.ndarray) -> None:
        generated = t[F["generated"]]
        accounted = sum(t[F[name]] for name in CONSERVED)
        if generated != accounted:
            parts = ", ".join(f"{name}={int(t[F[name]])}" for name in CONSERVED)
            raise ConservationError(f"tick {tick}: generated={int(generated)} but {parts} "
                                    f"account for {int(accounted)}: a task was lost or invented (a custom role "
                                    "must hand every task on, keep it, or drop it with Role.drop)")
        if self.jobs and t[JOBS] != sum(t[F[name]] for name in JOBS_CONSERVED):
            parts = ", ".join(f"{name}={int(t[F[name]])}" for name in JOBS_CONSERVED)
            raise ConservationError(f"tick {tick}: jobs={int(t[JOBS])} but {parts}: a job was lost or invented")

    # ----- episode results -----

    def summary(self) -> dict[str, Any]:
        self.settle()
        if not self.n_ticks:
            raise RuntimeError("no tick recorded")
        sc = self.scenario
        out: dict[str, Any] = {
            "scenario": sc.name,
            "scenario_hash": sc.digest(),
            "source": sc.source,
            "seed": None,  # filled in by the session, which knows the episode's seed
            "ticks": self.n_ticks,
            "dt": sc.dt,
            "penalty_s": self.penalty,  # what penalised_response_time charges a task that did not complete
        }
        means = {k: network / self.n_ticks for k, (network, _) in self._mean_sums.items()}
        for m in shown(Out.SUMMARY, self.jobs):
            section, _, key = m.key(Out.SUMMARY).rpartition(".")
            where = out.setdefault(section, {}) if section else out
            self._episode(where, key, m, Out.SUMMARY, self.last_totals, self.n_ticks, means.get(m.name),
                          self.capacity.sum(), self.response_times, self.moving)
        out["nodes"] = {}
        for i, nid in enumerate(self.node_ids):
            where = out["nodes"][nid] = {}
            node_means = {k: per_node[i] / self.n_ticks for k, (_, per_node) in self._mean_sums.items()}
            for m in shown(Out.SUMMARY_NODES, self.jobs):
                self._episode(where, m.key(Out.SUMMARY_NODES), m, Out.SUMMARY_NODES, self.last_nodes[i],
                              self.n_ticks, node_means.get(m.name), self.capacity[i], self.rt_by_node.get(nid, []))
        return out

    @staticmethod
    def _episode(into: dict[str, Any], key: str, m: Metric, out: Out, end: np.ndarray, ticks: int,
                 mean: float | None, capacity: float, times: list[float], moving: bool = False) -> None:
        """``m`` over the episode, from the row of FIELDS at its ``end`` and, for an episode_mean metric,
        its ``mean`` over the ``ticks``: a count's total, a level at the end (or its mean), the share of the
        episode's capacity; for samples the count, mean, p50, p95 and max, or the mean alone in a node's row."""
        if m.agg is Agg.SAMPLES:
            rt = np.array(times)
            if out is Out.SUMMARY_NODES:
                into[key] = float(rt.mean()) if rt.size else None
            elif rt.size:
                into[key] = {"count": int(rt.size), "mean": float(rt.mean()), "p50": float(np.percentile(rt, 50)),
                             "p95": float(np.percentile(rt, 95)), "max": float(rt.max())}
            else:
                into[key] = {"count": 0, "mean": None, "p50": None, "p95": None, "max": None}
        elif m.agg is Agg.RATIO:
            into[key] = ratio(m, end)
        elif m.agg is Agg.SHARE:
            capacity = capacity * ticks
            into[key] = float(end[counters(m)[0]] / capacity) if capacity else 0.0
        elif m.episode_mean:
            into[key] = float(mean)
        else:
            put(into, key, m, m.form(out), end, moving)

    def tick_header(self) -> list[str]:
        one = self.last_totals[None, :]
        return ["tick", "time_s", *output_values(Out.TICKS, one, one, self.capacity.sum(), samples=lambda m: [],
                                                 jobs=self.jobs, moving=self.moving)]

    def node_header(self) -> list[str]:
        one = self.last_nodes[None]
        return ["tick", "node", *output_values(Out.NODES, one, one, self.capacity, jobs=self.jobs)]

    def tick_table(self) -> tuple[list[str], list[list[Any]]]:
        """ticks.csv from the history (``history=True``)."""
        return self.tick_header(), self._tick_rows(self._rows)

    def node_table(self) -> tuple[list[str], list[list[Any]]]:
        """nodes.csv from the history (``history=True``)."""
        return self.node_header(), self._node_rows(self._rows)

    def _tick_rows(self, rows: _Rows) -> list[list[Any]]:
        levels = np.array(rows.totals)
        change = levels - np.vstack([rows.before_totals, levels[:-1]])
        table = output_values(Out.TICKS, levels, change, self.capacity.sum(), samples=lambda m: rows.means,
                              jobs=self.jobs, moving=self.moving)
        dt = self.scenario.dt
        return [[tick, tick * dt, *row] for tick, *row in zip(rows.ticks, *table.values(), strict=True)]

    def _node_rows(self, rows: _Rows) -> list[list[Any]]:
        levels = np.array(rows.nodes)
        change = levels - np.concatenate([rows.before_nodes[None], levels[:-1]])
        columns = list(output_values(Out.NODES, levels, change, self.capacity, jobs=self.jobs).values())
        out = []
        for k, tick in enumerate(rows.ticks):
            at = [column[k] for column in columns]
            out.extend([tick, nid, *(column[i] for column in at)] for i, nid in enumerate(self.node_ids))
        return out

    def write(self, out_dir: Path, summary: dict[str, Any]) -> None:
        """The tables, then summary.json over the stream's incomplete one: a streamed episode's tables are
        completed and closed (they are in the stream's directory, which is ``out_dir``); otherwise they are
        written from the history."""
        out_dir.mkdir(parents=True, exist_ok=True)
        if not self._tables:
            if not self.history:
                raise RuntimeError("no per-tick history was kept: stream the tables into the output directory")
            self._open_tables(out_dir)  # the history is one block of rows, written like the stream's
        self.close_stream()
        write_summary(out_dir, summary)
