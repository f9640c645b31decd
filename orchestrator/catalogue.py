"""The metric catalogue: every metric the orchestrator reports, declared once.

Roles count (``Counters`` in node_runtime/model/role.py); the orchestrator sums the counters over
roles and nodes every tick (orchestrator/metrics.py). A ``Metric`` says which counters it sums, how
it aggregates over ticks, its unit, and where it is shown. summary.json, ticks.csv, nodes.csv, the
bus's metrics record, ``orchestrator monitor``, the launch summary table, the plots' numbers panel
and the environment's infos are all built by iterating ``CATALOGUE``: a new metric is a counter in
the model and one entry here (docs/extending.md, "Adding a metric").

Each output lists its metrics in catalogue order, with three exceptions that keep the files as they
have always been: a row ends with its samples' mean, then its ratios; a node's row starts with its levels (what it
holds now, then what it did); and summary.json groups metrics in sections (``totals`` for task
counts), each section in the place of its first metric, its single counts first, then the counts
broken down by part, then the levels.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum, Flag, auto
from functools import cache
from typing import Any

from node_runtime.model.role import DROP_CAUSES


class Agg(Enum):
    """How a metric aggregates over ticks (over roles and nodes, it is always a sum)."""

    COUNT = "count"  # cumulative since the episode began; a row (ticks.csv, nodes.csv, delta) shows the tick's change
    LEVEL = "level"  # the value at the end of the tick
    SHARE = "share"  # cycles used / cycles the workers have: of the tick in a row, of the episode in the summary
    SAMPLES = "samples"  # one value per completion: a row shows their mean, the summary count, mean, p50, p95, max
    RATIO = "ratio"  # cumulative ``fields`` / cumulative ``of`` (None while the latter is 0), in every output


class Out(Flag):
    """Where a metric is shown."""

    SUMMARY = auto()  # summary.json: the episode's value (a LEVEL's at the end, or its mean over the ticks)
    SUMMARY_NODES = auto()  # summary.json "nodes": the same per node
    TICKS = auto()  # ticks.csv: one column per metric (a COUNT's change in the tick)
    NODES = auto()  # nodes.csv: the same per node
    BUS = auto()  # the bus's metrics record (docs/bus.md), "totals" (SAMPLES: the tick's, as a list beside it)
    BUS_DELTA = auto()  # the record's "delta": the tick's change
    BUS_NODES = auto()  # the record's "nodes": one list, indexed like "nodes.id"
    MONITOR = auto()  # `orchestrator monitor` (from what the record carries)
    TABLE = auto()  # the summary table of `orchestrator launch` and the numbers panel of `orchestrator plot`
    ENV = auto()  # ZenohEdgeEnv's infos[agent]["node"]: the agent's node, cumulative
    ENV_DELTA = auto()  # RewardContext.node_delta: the change of the agent's node during the step


BUS_ANY = Out.BUS | Out.BUS_DELTA | Out.BUS_NODES
NODE_VIEWS = Out.NODES | Out.BUS_NODES | Out.ENV
ROWS = Out.TICKS | Out.NODES | Out.SUMMARY_NODES
CHANGES = Out.TICKS | Out.NODES | Out.BUS_DELTA | Out.ENV_DELTA  # where a COUNT shows its change, not its total
# where the job metrics show: the job counts where the task counts are, the job ratios where theirs are
JOB_COUNTS = (Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.MONITOR
              | Out.TABLE | Out.ENV | Out.ENV_DELTA)
JOB_RATIOS = Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.BUS | Out.MONITOR | Out.TABLE


class Form(Enum):
    """How a metric with parts appears in an output."""

    TOTAL = "total"  # one value, the sum of the parts
    PARTS = "parts"  # an object {part: value}
    PARTS_TOTAL = "parts and total"  # an object {part: value, ..., "total": value}
    FLAT = "flat"  # the total under the metric's name, then each part as <name>_<part> beside it


@dataclass(frozen=True, slots=True)
class Part:
    key: str  # its name in outputs
    field: str  # the counter it reads
    label: str  # for people
    moving: bool = False  # shown only for a scenario whose nodes move (elsewhere it is always 0)


@dataclass(frozen=True, slots=True, eq=False)
class Metric:
    """One metric. ``fields`` are the counters it sums (``Counters`` fields, or the orchestrator's
    ``in_flight``); by default the counter of its own name, or its parts' counters."""

    name: str
    unit: str  # "tasks", "nodes", "node-ticks", "J", "s", "ratio" (0-1)
    agg: Agg
    label: str  # in the launch summary table and the monitor
    short: str  # column heading in the monitor's node table
    show: Out
    fields: tuple[str, ...] = ()
    parts: tuple[Part, ...] = ()
    forms: Mapping[Out, Form] = field(default_factory=dict)  # where the parts are shown (else the total only)
    names: Mapping[Out, str] = field(default_factory=dict)  # its name in an output, where it is not ``name``
    dtype: type = int  # of its values (SHARE and SAMPLES are always float)
    episode_mean: bool = False  # LEVEL: the summary gives its mean over the episode's ticks, not its last value
    share_of: str | None = None  # the table also gives it as a percentage of this metric
    of: tuple[str, ...] = ()  # RATIO: the counters of its denominator
    jobs: bool = False  # a metric of jobs: shown only for a scenario of jobs (workload.jobs), so others' outputs stay

    def __post_init__(self) -> None:
        if not self.fields and self.agg is not Agg.SAMPLES:
            object.__setattr__(self, "fields", tuple(p.field for p in self.parts) or (self.name,))
        if self.agg in (Agg.SHARE, Agg.SAMPLES, Agg.RATIO):
            object.__setattr__(self, "dtype", float)
        problems = [
            *(f"a form for {o.name}, which it does not show" for o in self.forms if o not in self.show),
            *(f"form {f.value} but no parts" for f in self.forms.values() if f is not Form.TOTAL and not self.parts),
            *(["MONITOR without a bus output"] if Out.MONITOR in self.show and not self.show & BUS_ANY else []),
            *(["TABLE without SUMMARY"] if Out.TABLE in self.show and Out.SUMMARY not in self.show else []),
            *(["a SHARE reads exactly one counter"] if self.agg is Agg.SHARE and len(self.fields) != 1 else []),
            *(["a RATIO needs its denominator's counters (of)"] if (self.agg is Agg.RATIO) != bool(self.of) else []),
        ]
        if problems:
            raise ValueError(f"metric {self.name}: {'; '.join(problems)}")

    def parts_of(self, moving: bool) -> tuple[Part, ...]:
        """The parts a scenario's outputs show: those of moving nodes only where nodes move."""
        return tuple(p for p in self.parts if moving or not p.moving)

    def key(self, out: Out) -> str:
        """Its name in ``out``; in the summary a dotted path (task counts are under "totals")."""
        if out in self.names:
            return self.names[out]
        if out is Out.SUMMARY and self.unit == "tasks":
            return f"totals.{self.name}"
        return self.name

    def form(self, out: Out) -> Form:
        return self.forms.get(out, Form.TOTAL)

    def columns(self, out: Out) -> list[str]:
        """The column names (or flat keys) it takes in ``out``: its own, then its parts' if FLAT (those that
        every scenario shows)."""
        key = self.key(out)
        if self.form(out) is Form.FLAT:
            return [key, *(f"{key}_{p.key}" for p in self.parts_of(moving=False))]
        return [key]

    def summary_section(self) -> str:
        return self.key(Out.SUMMARY).partition(".")[0]


DROP_PARTS = tuple(Part(c, c, c.replace("_", " "), moving=c == "link_broken") for c in DROP_CAUSES)
ENERGY_PARTS = (Part("compute", "energy_compute", "compute"), Part("idle", "energy_idle", "idle"),
                Part("transmit", "energy_transmit", "radio"))

CATALOGUE: tuple[Metric, ...] = (
    # tasks created by the clients
    Metric("generated", "tasks", Agg.COUNT, "generated", "gen",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.MONITOR
           | Out.TABLE | Out.ENV | Out.ENV_DELTA),
    # results received by their origin client within the deadline (counted at the origin)
    Metric("completed", "tasks", Agg.COUNT, "completed", "done",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.BUS_NODES
           | Out.MONITOR | Out.TABLE | Out.ENV | Out.ENV_DELTA, share_of="generated"),
    # (tick of the result's arrival - tick of creation) x dt, per completed task
    Metric("response_time", "s", Agg.SAMPLES, "response time", "rt",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.BUS | Out.MONITOR | Out.TABLE,
           names={Out.TICKS: "response_time_mean", Out.SUMMARY_NODES: "response_time_mean",
                  Out.BUS: "response_times"}),
    # the sum of the response times of the completions (of the node's own tasks, counted at the origin), for
    # rewards that weigh each completion by its timeliness (env.reward.score_reward)
    Metric("response_time_total", "s", Agg.COUNT, "response time (sum)", "rts", Out.ENV_DELTA,
           fields=("response_time_sum",), dtype=float),
    # the waiting the node's decisions imposed on other tasks (in executors' CPU queues and on its links), each
    # wait in deadlines of the task that waited, for rewards that price congestion (env.reward.marginal_reward)
    Metric("delay_imposed", "deadlines", Agg.COUNT, "delay imposed on others", "dimp", Out.SUMMARY | Out.ENV_DELTA,
           dtype=float),
    # completed / generated so far: the share of the tasks created that came back in time
    Metric("completion_ratio", "ratio", Agg.RATIO, "completion ratio", "c/g",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.BUS | Out.MONITOR | Out.TABLE,
           fields=("completed",), of=("generated",)),
    # completed / (completed + dropped): the same over the tasks whose fate is settled (in_system left out)
    Metric("completion_ratio_settled", "ratio", Agg.RATIO, "completion ratio (settled)", "c/s",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.TABLE,
           fields=("completed",), of=("completed", *(p.field for p in DROP_PARTS))),
    # mean over the generated tasks of the response time if completed, else the penalty (docs/model.md)
    Metric("penalised_response_time", "s", Agg.RATIO, "penalised response time", "prt",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.BUS | Out.MONITOR | Out.TABLE,
           fields=("penalised_s",), of=("generated",)),
    # tasks lost, each by exactly one cause
    Metric("dropped", "tasks", Agg.COUNT, "dropped", "drops",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.BUS_NODES
           | Out.MONITOR | Out.TABLE | Out.ENV | Out.ENV_DELTA, parts=DROP_PARTS, share_of="generated",
           forms={Out.SUMMARY: Form.PARTS_TOTAL, Out.TICKS: Form.FLAT, Out.BUS: Form.PARTS}),
    # tasks a worker transmitted to a neighbour on a decision (a task offloaded twice counts twice)
    Metric("offloaded", "tasks", Agg.COUNT, "offloaded", "offl",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.BUS_NODES
           | Out.MONITOR | Out.TABLE | Out.ENV | Out.ENV_DELTA),
    # tasks a controller placed
    Metric("decisions", "tasks", Agg.COUNT, "decisions", "dec", Out.SUMMARY | Out.ENV),
    # decisions that reached a worker which no longer held the task
    Metric("stale_decisions", "tasks", Agg.COUNT, "stale decisions", "stale", Out.SUMMARY),
    # ticks in which a node's buffer was full at the start
    Metric("overloaded_ticks", "node-ticks", Agg.COUNT, "overloaded node-ticks", "ovl",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TABLE, names={Out.SUMMARY: "overloaded.node_ticks"}),
    # queued + undecided + in flight: generated = completed + dropped + in_system, every tick
    Metric("in_system", "tasks", Agg.LEVEL, "in the system", "sys",
           Out.SUMMARY | Out.TICKS | Out.BUS | Out.MONITOR | Out.TABLE, fields=("queue", "undecided", "in_flight")),
    # tasks admitted for local processing, the one in service included
    Metric("queue", "tasks", Agg.LEVEL, "queued", "queue", Out.TICKS | Out.NODES | Out.BUS_NODES | Out.ENV,
           names={Out.TICKS: "queued"}),
    # tasks waiting for the controller's decision
    Metric("undecided", "tasks", Agg.LEVEL, "undecided", "undec", Out.TICKS | Out.NODES | Out.BUS_NODES | Out.ENV),
    # tasks and results on links
    Metric("in_flight", "tasks", Agg.LEVEL, "in flight", "fly", Out.TICKS),
    # workers whose buffer was full at the start of the tick
    Metric("overloaded", "nodes", Agg.LEVEL, "overloaded nodes", "ovl",
           Out.SUMMARY | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_NODES | Out.MONITOR | Out.TABLE | Out.ENV,
           names={Out.SUMMARY: "overloaded.mean_nodes", Out.TICKS: "overloaded_nodes", Out.BUS: "overloaded_nodes"},
           episode_mean=True),
    # CPU cycles spent / (cores x frequency x dt), over the nodes with a worker
    Metric("utilisation", "ratio", Agg.SHARE, "utilisation", "util",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS_NODES | Out.MONITOR | Out.TABLE,
           fields=("busy_cycles",)),
    # compute + idle + transmit (radio) energy
    Metric("energy_j", "J", Agg.COUNT, "energy", "energy",
           Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.MONITOR | Out.TABLE | Out.ENV,
           parts=ENERGY_PARTS, dtype=float, forms={Out.SUMMARY: Form.PARTS_TOTAL, Out.BUS: Form.FLAT}),
    # ----- jobs (docs/model.md, "Jobs as DAGs"), counted at their origin; only for a scenario of jobs -----
    # jobs created
    Metric("jobs", "jobs", Agg.COUNT, "jobs", "jobs", JOB_COUNTS, names={Out.SUMMARY: "jobs.generated"}, jobs=True),
    # jobs whose every task's result came back in time
    Metric("jobs_completed", "jobs", Agg.COUNT, "jobs completed", "jdone", JOB_COUNTS,
           names={Out.SUMMARY: "jobs.completed"}, share_of="jobs", jobs=True),
    # jobs that reached their deadline before completing
    Metric("jobs_missed", "jobs", Agg.COUNT, "jobs missed", "jmiss", JOB_COUNTS, names={Out.SUMMARY: "jobs.missed"},
           share_of="jobs", jobs=True),
    # jobs still running: jobs = jobs_completed + jobs_missed + jobs_active, every tick
    Metric("jobs_active", "jobs", Agg.LEVEL, "jobs running", "jrun", Out.SUMMARY | Out.TICKS | Out.NODES | Out.ENV,
           names={Out.SUMMARY: "jobs.active"}, jobs=True),
    # jobs_completed / jobs so far
    Metric("job_completion_ratio", "ratio", Agg.RATIO, "job completion ratio", "jc/g", JOB_RATIOS,
           fields=("jobs_completed",), of=("jobs",), names={Out.SUMMARY: "jobs.completion_ratio"}, jobs=True),
    # the mean makespan of the completed jobs: (tick of its last result's arrival - tick of creation) x dt
    Metric("makespan", "s", Agg.RATIO, "makespan (mean)", "mksp", JOB_RATIOS, fields=("makespan_sum",),
           of=("jobs_completed",), names={Out.SUMMARY: "jobs.makespan_mean", Out.TICKS: "makespan_mean",
                                           Out.SUMMARY_NODES: "makespan_mean"}, jobs=True),
    # mean over the jobs created of the makespan if completed, else the penalty (docs/model.md)
    Metric("penalised_makespan", "s", Agg.RATIO, "penalised makespan", "pmk", JOB_RATIOS,
           fields=("job_penalised_s",), of=("jobs",), names={Out.SUMMARY: "jobs.penalised_makespan"}, jobs=True),
)
METRIC: dict[str, Metric] = {m.name: m for m in CATALOGUE}


def _summary_order(metrics: list[Metric]) -> list[Metric]:
    sections: dict[str, list[Metric]] = {}
    for m in metrics:
        sections.setdefault(m.summary_section(), []).append(m)
    return [m for group in sections.values()
            for m in sorted(group, key=lambda m: (m.agg is Agg.LEVEL, m.form(Out.SUMMARY) is not Form.TOTAL))]


def _in_rows(out: Out) -> Callable[[Metric], Any]:
    node_view, row = bool(out & NODE_VIEWS), bool(out & ROWS)
    return lambda m: (node_view and m.agg is not Agg.LEVEL, row and m.agg in (Agg.SAMPLES, Agg.RATIO),
                      row and m.agg is Agg.RATIO)


def shown(out: Out, jobs: bool = False) -> tuple[Metric, ...]:
    """The metrics ``out`` shows, in its order (the launch table follows the summary's); the job metrics only
    with ``jobs`` (a scenario of jobs). Read at every call, so that a test may extend ``CATALOGUE``."""
    return _shown(out, CATALOGUE, jobs)


@cache
def _shown(out: Out, catalogue: tuple[Metric, ...], jobs: bool = False) -> tuple[Metric, ...]:
    metrics = [m for m in catalogue if out in m.show and (jobs or not m.jobs)]
    if out in (Out.SUMMARY, Out.TABLE):
        return tuple(_summary_order(metrics))
    return tuple(sorted(metrics, key=_in_rows(out)))


def shown_as(out: Out, jobs: bool = False) -> tuple[tuple[Metric, str, Form], ...]:
    """``shown(out, jobs)``, each metric with its key and form in ``out``: what every tick's table of ``out``
    reads."""
    return _shown_as(out, CATALOGUE, jobs)


@cache
def _shown_as(out: Out, catalogue: tuple[Metric, ...], jobs: bool) -> tuple[tuple[Metric, str, Form], ...]:
    return tuple((m, m.key(out), m.form(out)) for m in _shown(out, catalogue, jobs))


def columns(out: Out, jobs: bool = False) -> list[str]:
    """The metric columns of ticks.csv (``Out.TICKS``) or nodes.csv (``Out.NODES``), in order; with ``jobs``,
    those of a scenario of jobs."""
    return [c for m in shown(out, jobs) for c in m.columns(out)]
