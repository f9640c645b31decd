"""A clairvoyant offline upper bound on the tasks an episode completes by their deadlines, and the normalised
score that places every policy between ``local`` (0) and that bound (1). docs/benchmark.md explains the model.

The bound sees the episode's whole arrival trace (``arrival_trace``: every task the clients create, with
its origin, creation tick, size and deadline) and chooses, for each task, where it runs (its origin's
worker, a one-hop neighbour, or nowhere) to complete as many as possible. It is a MILP over x[task, node]
in {0, 1}, solved by HiGHS (``scipy.optimize.milp``):

- each task runs at most once, only where the model lets it go (its origin; a neighbour with a worker
  when the origin has a controller and ``max_hops`` is 1), and only where it can make its deadline
  alone: decision, release, service and transfers at their earliest;
- interval capacity, on every CPU, every directed link and every controller (the decisions it places):
  for every interval [a, b], the work of the tasks placed on it that become available at or after a and
  are due by b fits in its capacity over [a, b]. Every schedule satisfies this (the classic necessary
  condition for release times and deadlines on one machine), FIFO or not, preemptive or not;
- the origin's buffer: at every tick, the completed tasks that must be in it then (each for its shortest
  possible stay) fit in it.

Every rule of the model that it leaves out can only make it larger, so it bounds every online policy,
clairvoyant or not (the relaxations are listed in docs/benchmark.md). It is exact (``kind`` "exact") when
HiGHS proves the MILP's optimum within ``time_limit``; otherwise the MILP's dual bound ("milp_dual"),
and when even that is missing the LP relaxation's ("lp"), both rounded down, and when the LP is not solved
in time either, the tasks that have an option at all ("options"): weaker, still bounds.

    python -m experiments.bound --suite runs/suites/test --episodes 2 --max-steps 60 --out runs/bound.csv
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.sparse import coo_array

from agents import BASELINES, Baseline, evaluate
from agents.training import progress_bar, write_csv
from experiments import raw, tune_baselines
from experiments.common import Parser, make_env, positive_int, positive_number
from experiments.protocol import EPISODES, SPLITS
from experiments.suite import read_suite
from node_runtime.model.client import arrivals
from node_runtime.model.messages import Task, TaskSize
from node_runtime.model.spec import Scenario

# Every tight interval becomes a row while all of them take at most ALL_ROWS nonzeros; past that, only those
# up to the resource's longest job window (longer ones on a grid). Twice that window was tried: tighter on
# 100-step episodes, but on 400-step ones HiGHS ran out of time and its dual bound was far weaker.
ALL_ROWS = 1_000_000
EPS = 1e-9  # rounding of transfer and service ticks toward the bound's side
BoundKind = Literal["exact", "milp_dual", "lp", "options"]


class BoundError(ValueError):
    """A scenario outside what the bound models (a client without a worker, tasks that travel two hops, payloads)."""


@dataclass(frozen=True)
class TraceTask:
    """One task of an episode: who created it, when, and what it asks."""

    origin: str
    created: int  # tick
    size: TaskSize


def arrival_trace(sc: Scenario, seed: int, ticks: int) -> list[TraceTask]:
    """Every task the clients of ``sc`` create in ticks 0 .. ``ticks`` - 1 of the episode with ``seed``: the
    clients' own code and random streams, which no policy moves, so a policy's run creates the same tasks."""
    return [TraceTask(sc.nodes[node].id, t, size) for t, node, size in arrivals(sc, seed, ticks)]


@dataclass(frozen=True)
class Job:
    """A task's demand on one resource if it runs at a node: ``amount`` of work within [release, due]."""

    var: int  # its x[task, node]
    release: float
    due: float
    amount: float


@dataclass(frozen=True)
class Bound:
    value: int  # no policy completes more of the trace's tasks
    kind: BoundKind
    tasks: int  # tasks in the trace
    variables: int
    constraints: int
    seconds: float


def _ticks(amount: float) -> int:
    """Whole ticks to cover ``amount`` ticks of work, at least one, rounded down within EPS (toward the bound)."""
    return max(1, math.ceil(amount - EPS))


Variables = list[tuple[int, str]]  # x[task index, node]


def jobs(sc: Scenario, trace: Sequence[TraceTask], last_tick: int) -> tuple[Variables, dict[Any, list[Job]]]:
    """The MILP's variables (task index, node) and the jobs of each resource: ("cpu", node), ("link", src,
    dst) and ("controller", node), the decisions a controller places.

    Times are ticks, each at its earliest (docs/model.md): a result must arrive by ``last_tick`` (the
    episode's last) and within the task's deadline, at tick L = expires_at - 1. The task reaches its origin's
    worker at created + 1; a decision for it takes effect at created + 2 + control_latency at the earliest.
    Kept local, it is served from created + 1 (queue first, or no controller) or from its decision, until
    L - 1 (the result reaches the client the tick after its last cycle). Offloaded to k, its input leaves at
    its decision and arrives ``up`` ticks later (``max(1, ceil(bits / rate / dt))``, the idle link's time), k
    serves it from then until L - ``down``, and the two links carry the input and the result in between."""
    if sc.max_hops > 1:
        raise BoundError(f"{sc.name}: max_hops {sc.max_hops}; the bound models one hop (max_hops 0 or 1)")
    if sc.moving:
        raise BoundError(f"{sc.name}: moving nodes; the bound models links of fixed rates")
    real = [t.name for t in sc.workload.task_types if t.payload is not None]
    if real:
        raise BoundError(f"{sc.name}: task types with payloads ({', '.join(real)}); the bound serves each task its "
                         "nominal cycles, and a payload's are only known once it runs")
    dt = sc.dt
    variables: Variables = []
    resources: dict[Any, list[Job]] = {}

    def add(i: int, node: str, parts: list[tuple[Any, float, float, float]]) -> None:
        var = len(variables)
        variables.append((i, node))
        for key, release, due, amount in parts:
            resources.setdefault(key, []).append(Job(var, release, due, amount))

    for i, task in enumerate(trace):
        origin = sc.node[task.origin]
        if not origin.has("worker"):
            raise BoundError(f"{sc.name}: client {origin.id} has no worker; the bound needs every client on a worker")
        cycles, c = task.size.cycles, task.created
        last = min(Task(0, task.origin, c, task.size).expires_at(dt) - 1, last_tick)  # latest arrival of the result
        decides = origin.has("controller") and sc.max_hops >= 1  # tasks wait for its decisions (decide first)
        decided = c + 2 + sc.control_latency  # the first tick a decision for the task takes effect
        control, buffer = ("controller", origin.id), ("buffer", origin.id)
        service = _ticks(cycles / (origin.capacity * dt))
        held = (buffer, c + 1, c + 1 + sc.control_latency, 1.0)  # undecided, or queued until a decision diverts it
        if decides and sc.admission == "decide_first":
            if last - decided >= service:  # served in decided .. last - 1
                add(i, origin.id, [(("cpu", origin.id), decided, last - 1, cycles),
                                   (control, decided, last - service, 1.0),
                                   (buffer, c + 1, decided + service - 1, 1.0)])
        elif last - 1 - c >= service:  # served in c + 1 .. last - 1, queued at once
            add(i, origin.id, [(("cpu", origin.id), c + 1, last - 1, cycles), (buffer, c + 1, c + service, 1.0)])
        if not decides:
            continue
        for k in sc.neighbours[origin.id]:
            target = sc.node[k]
            if not target.has("worker"):
                continue
            send, back = sc.link[(origin.id, k)], sc.link[(k, origin.id)]
            up_d = task.size.input_bytes * 8.0 / send.rate_bps / dt  # ticks on air
            down_d = task.size.output_bytes * 8.0 / back.rate_bps / dt
            arrive, finish = decided + _ticks(up_d), last - _ticks(down_d)  # first tick at k, last tick of service
            service = _ticks(cycles / (target.capacity * dt))
            if finish - arrive + 1 < service:
                continue  # misses its deadline even alone
            latest = finish - service + 1  # the latest tick its input may arrive at k
            add(i, k, [(("cpu", k), arrive, finish, cycles),
                       (("link", origin.id, k), decided, latest, up_d),
                       (("link", k, origin.id), arrive + service - 1, last, down_d),
                       (control, decided, latest - _ticks(up_d), 1.0), held])
    return variables, resources


def _capacity(sc: Scenario, key: Any, a: float, b: float) -> float:
    """Work a resource does over [a, b]: a CPU's cycles in ticks a..b, a link's ticks on air in [a, b], a
    controller's decisions in ticks a..b (one a decision epoch in binary mode, ``batch_size`` in batch mode;
    epochs are ``decision_interval`` ticks apart)."""
    if key[0] == "cpu":
        return sc.node[key[1]].capacity * sc.dt * (b - a + 1)
    if key[0] == "controller":
        return (1 if sc.mode == "binary" else sc.batch_size) * ((b - a) // sc.decision_interval + 1)
    return b - a


def buffer_rows(sc: Scenario, key: Any, found: list[Job]) -> list[tuple[list[int], list[float], float]]:
    """The buffer constraints of one node: at every tick, the tasks its buffer must hold then fit in it. A
    job here is a task's stay, [release, due], that no schedule shortens; a set is largest at a stay's first tick."""
    rows = []
    capacity = float(sc.node[key[1]].buffer)
    for t in sorted({j.release for j in found}):
        held = [j.var for j in found if j.release <= t <= j.due]
        if len(held) > capacity:
            rows.append((held, [1.0] * len(held), capacity))
    return rows


class TooMany(Exception):
    """More nonzeros than the budget of ``interval_rows``."""


def interval_rows(sc: Scenario, key: Any, found: list[Job], span: float = math.inf,
                  budget: list[int] | None = None) -> list[tuple[list[int], list[float], float]]:
    """The interval constraints of one resource: the jobs inside [a, b] fit in its capacity over [a, b].

    Every interval's row is valid, so any subset keeps the bound; these are chosen to keep the matrix small.
    Up to ``span`` long (infinity: all): each tight one, from a job's release a to a job's due b, whose set
    has a job released at a and exceeds the capacity (others are implied or empty). Longer: a and b on a grid
    of span / 2. ``budget``: [nonzeros left], raising ``TooMany`` when they run out."""
    if key[0] == "buffer":
        return buffer_rows(sc, key, found)
    rows = []

    def add(a: float, b: float, members: list[Job], total: float | None = None) -> None:
        capacity = _capacity(sc, key, a, b)
        if (sum(m.amount for m in members) if total is None else total) > capacity + EPS:
            rows.append(([m.var for m in members], [m.amount for m in members], capacity))
            if budget is not None:
                budget[0] -= len(members)
                if budget[0] < 0:
                    raise TooMany

    by_due = sorted(found, key=lambda j: j.due)
    releases = sorted({j.release for j in found})
    for a in releases:
        inside = [j for j in by_due if j.release >= a and j.due <= a + span]
        total, has_a = 0.0, False
        for n, j in enumerate(inside):
            total += j.amount
            has_a = has_a or j.release == a
            if n + 1 < len(inside) and inside[n + 1].due == j.due:
                continue  # the set grows until every job due by j.due is in
            if has_a and total > _capacity(sc, key, a, j.due) + EPS:
                add(a, j.due, inside[:n + 1], total)
    if math.isinf(span):
        return rows
    step = max(1.0, span / 2)
    grid = list(np.arange(releases[0], by_due[-1].due + step, step))
    for i, a in enumerate(grid):
        for b in grid[i + 1:]:
            if b - a > span:
                add(float(a), float(b), [j for j in found if j.release >= a and j.due <= b])
    return rows


def solve(sc: Scenario, trace: Sequence[TraceTask], last_tick: int, time_limit: float = 60.0) -> Bound:
    """The bound for one episode's trace; ``last_tick``: the episode's last tick (results later do not count)."""
    start = time.perf_counter()
    variables, resources = jobs(sc, trace, last_tick)
    if not variables:
        return Bound(0, "exact", len(trace), 0, 0, time.perf_counter() - start)
    r, col, val, ub = [], [], [], []
    by_task: dict[int, list[int]] = {}
    for var, (i, _) in enumerate(variables):
        by_task.setdefault(i, []).append(var)
    for vars_ in by_task.values():  # each task runs at most once
        if len(vars_) > 1:
            r += [len(ub)] * len(vars_)
            col += vars_
            val += [1.0] * len(vars_)
            ub.append(1.0)
    try:
        budget = [ALL_ROWS]
        rows = [row for key, found in resources.items() for row in interval_rows(sc, key, found, budget=budget)]
    except TooMany:
        rows = [row for key, found in resources.items()
                for row in interval_rows(sc, key, found, max(j.due - j.release for j in found))]
    for members, amounts, capacity in rows:
        scale = max(amounts)  # rows in units of their largest job, for the solver's tolerances
        r += [len(ub)] * len(members)
        col += members
        val += [a / scale for a in amounts]
        ub.append(capacity / scale)
    n = len(variables)
    c = -np.ones(n)
    constraints = [LinearConstraint(coo_array((val, (r, col)), shape=(len(ub), n)).tocsr(), -np.inf, ub)] if ub else []
    res = milp(c, constraints=constraints, integrality=np.ones(n), bounds=Bounds(0, 1),
               options={"time_limit": time_limit})
    if res.status == 0:
        value, kind = round(-res.fun), "exact"
    elif getattr(res, "mip_dual_bound", None) is not None and math.isfinite(res.mip_dual_bound):
        value, kind = math.floor(-res.mip_dual_bound + 1e-6), "milp_dual"
    else:
        lp = milp(c, constraints=constraints, integrality=np.zeros(n), bounds=Bounds(0, 1),
                  options={"time_limit": time_limit})
        if lp.status == 0:  # only a proven LP optimum bounds the MILP's: a time-limited LP value does not
            value, kind = math.floor(-lp.fun + 1e-6), "lp"
        else:
            value, kind = len({i for i, _ in variables}), "options"
    return Bound(value, kind, len(trace), n, len(ub), time.perf_counter() - start)


def episode_bound(sc: Scenario, seed: int, steps: int, time_limit: float = 60.0) -> Bound:
    """The bound of an environment's episode of ``steps`` steps on ``seed``: ticks 0 .. steps x decision_interval."""
    last = steps * sc.decision_interval
    return solve(sc, arrival_trace(sc, seed, last + 1), last, time_limit)


def normalised_score(completed: float, local: float, bound: float) -> float:
    """How far a policy got from ``local`` (0) to the bound (1) on one episode, in completed tasks: negative
    below local; NaN when the bound leaves no room above local (bound == local)."""
    room = bound - local
    return (completed - local) / room if room > 0 else math.nan


def measure(scenario: str | Path, seeds: Sequence[int], max_steps: int | None, policies: Mapping[str, type[Baseline]],
            time_limit: float, progress: Any = None) -> list[dict[str, Any]]:
    """One raw row (``experiments.raw``) per episode (seeds: consecutive) and policy: its metrics, what ``local``
    completed, the bound (its kind and the seconds it took) and the normalised score.
    ``policies`` must hold ``local``, which the score starts from."""
    env = make_env(str(scenario), None, max_steps)
    try:
        bounds = [episode_bound(env.scenario, s, env.max_steps, time_limit) for s in seeds]
        done = {b: evaluate(env, cls(0), len(seeds), seed=seeds[0], progress=progress,
                            label=f"{Path(scenario).stem} {b}")
                for b, cls in policies.items()}
    finally:
        env.close()
    rows = []
    for k, bd in enumerate(bounds):
        local = done["local"][k]["completed"]
        for b in policies:
            episode = done[b][k]
            rows.append(raw.row(b, None, scenario, Path(scenario).stem, episode, {
                "local": local, "bound": bd.value, "bound_kind": bd.kind, "bound_s": round(bd.seconds, 3),
                "normalised_score": normalised_score(episode["completed"], local, bd.value)}))
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.bound", description=__doc__.splitlines()[0])
    p.add_argument("--suite", type=Path, required=True, help="a folder written by python -m experiments.suite")
    p.add_argument("--split", choices=SPLITS, default=None,
                   help="episode seeds from this set (default: the suite's own split)")
    p.add_argument("--episodes", type=positive_int, default=2, help="episodes per regime (default 2)")
    p.add_argument("--max-steps", type=positive_int, default=None, help="steps per episode (default: the regime's)")
    p.add_argument("--time-limit", type=positive_number, default=60.0,
                   help="seconds HiGHS may take per episode (default 60)")
    p.add_argument("--tuned", type=Path, default=None,
                   help="a chosen.json of python -m experiments.tune_baselines: its baselines run too, as <name>_tuned")
    p.add_argument("--out", type=Path, default=None, help="CSV of the rows (default: <suite>/bound.csv)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    args = p.parse_args(argv)
    try:
        suite = read_suite(args.suite)
    except ValueError as e:
        p.error(str(e))
    split = args.split or args.suite.name
    if split not in EPISODES:
        p.error(f"{args.suite}: say which episode seeds to use with --split ({', '.join(SPLITS)})")
    seeds = EPISODES[split].seeds(args.episodes)
    policies = dict(BASELINES)
    if args.tuned is not None:
        policies |= {f"{name}_tuned": cls for name, cls in tune_baselines.chosen(args.tuned).items()}
    rows: list[dict[str, Any]] = []
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        for regime in suite:
            try:
                rows += measure(regime.path, seeds, args.max_steps, policies, args.time_limit, progress)
            except BoundError as e:  # a regime outside the bound's model: one line, before its episodes run
                p.error(str(e))
    out = args.out or args.suite / "bound.csv"
    write_csv(out, rows)
    print(f"wrote {len(rows)} rows to {out} ({split} episodes {seeds[0]}..{seeds[-1]})")


if __name__ == "__main__":
    main()
