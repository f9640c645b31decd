"""Per-tick and per-episode metrics from the processes' reports, and the conservation invariant.

Each ``Done`` carries cumulative counters per role, and the arrival ticks of the tasks and results
its roles put on links; a process that sleeps through a tick keeps its last counters. Per tick they
are stacked in canonical role order (so float sums do not depend on which process reported first),
summed per node and in total, and checked:

    generated = completed + dropped + (queued + undecided + in flight)

A violation stops the run: a task was lost or invented, and no result after that can be trusted.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from node_runtime.model.role import DROP_CAUSES, STAT_FIELDS, role_node
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.protocol import Done

FIELDS = (*STAT_FIELDS, "in_flight")  # in_flight: tasks and results a role sent that have not arrived yet
F = {name: i for i, name in enumerate(FIELDS)}
IN_FLIGHT = F["in_flight"]
N_STATS = len(STAT_FIELDS)
COUNTS = ("generated", "completed", *DROP_CAUSES, "offloaded", "decisions", "stale_decisions")
ENERGY = ("energy_compute", "energy_idle", "energy_transmit")


class ConservationError(RuntimeError):
    pass


@dataclass(slots=True)
class TickReport:
    """One tick, summed over the network: counts are this tick's, levels are at its end."""

    tick: int
    totals: np.ndarray  # cumulative FIELDS over all roles
    delta: np.ndarray  # this tick's change of FIELDS
    nodes: np.ndarray  # cumulative FIELDS per node (canonical node order)
    node_delta: np.ndarray
    response_times: list[float]  # completions this tick, seconds

    def __getitem__(self, name: str) -> float:
        return float(self.totals[F[name]])

    @property
    def in_system(self) -> int:
        t = self.totals
        return int(t[F["queue"]] + t[F["undecided"]] + t[F["in_flight"]])

    @property
    def dropped(self) -> int:
        return int(sum(self.totals[F[c]] for c in DROP_CAUSES))

    @property
    def overloaded_nodes(self) -> int:
        return int(self.totals[F["overloaded"]])


def bus_record(report: TickReport, metrics: Metrics, sim_id: str, episode: int) -> dict[str, Any]:
    """The ``…/metrics/tick`` message for monitors (schema in docs/bus.md): this tick's totals, its
    changes, its completions' response times, and one column per node field."""
    t, d = report.totals, report.delta
    nodes, nd = report.nodes, report.node_delta
    cap = metrics.capacity
    with np.errstate(divide="ignore", invalid="ignore"):
        util = np.where(cap > 0, nd[:, F["busy_cycles"]] / np.where(cap > 0, cap, 1), 0.0)
    return {
        "type": "metrics", "sim": sim_id, "episode": episode, "tick": report.tick,
        "time_s": report.tick * metrics.scenario.dt,
        "totals": {
            "generated": int(t[F["generated"]]), "completed": int(t[F["completed"]]),
            "dropped": {c: int(t[F[c]]) for c in DROP_CAUSES}, "offloaded": int(t[F["offloaded"]]),
            "in_system": report.in_system, "overloaded_nodes": report.overloaded_nodes,
            "energy_j": float(sum(t[F[k]] for k in ENERGY)),
        },
        "delta": {"generated": int(d[F["generated"]]), "completed": int(d[F["completed"]]),
                  "dropped": int(sum(d[F[c]] for c in DROP_CAUSES)), "offloaded": int(d[F["offloaded"]])},
        "response_times": report.response_times,
        "nodes": {
            "id": list(metrics.node_ids),
            "buffer": [n.buffer for n in metrics.scenario.nodes],
            "queue": nodes[:, F["queue"]].astype(int).tolist(),
            "undecided": nodes[:, F["undecided"]].astype(int).tolist(),
            "overloaded": nodes[:, F["overloaded"]].astype(int).tolist(),
            "completed": nodes[:, F["completed"]].astype(int).tolist(),
            "dropped": nodes[:, [F[c] for c in DROP_CAUSES]].sum(axis=1).astype(int).tolist(),
            "offloaded": nodes[:, F["offloaded"]].astype(int).tolist(),
            "utilisation": util.tolist(),
        },
    }


class Metrics:
    def __init__(self, plan: ProcessLayout) -> None:
        sc = plan.scenario
        self.scenario = sc
        self.roles = plan.roles
        self.node_ids = tuple(n.id for n in sc.nodes)
        incidence = np.zeros((len(self.node_ids), len(self.roles)))
        for i, r in enumerate(self.roles):
            incidence[sc.index[role_node(r)], i] = 1.0
        self.incidence = incidence
        self.capacity = np.array([n.capacity * sc.dt if n.has("worker") else 0.0 for n in sc.nodes])
        self.reset()

    def reset(self) -> None:
        self.ticks: list[int] = []
        self.totals: list[np.ndarray] = []
        self.nodes: list[np.ndarray] = []
        self.response_times: list[float] = []
        self.rt_by_node: dict[str, list[float]] = {}
        self._prev_totals = np.zeros(len(FIELDS))
        self._prev_nodes = np.zeros((len(self.node_ids), len(FIELDS)))
        self._matrix = np.zeros((len(self.roles), len(FIELDS)))
        self._landing: dict[int, list[tuple[int, int]]] = {}  # arrival tick -> [(role, tasks and results)]

    def add(self, tick: int, dones: list[Done]) -> TickReport:
        m = self._matrix
        rts: list[float] = []
        landing = self._landing
        for d in dones:  # roles are named by their canonical index, which is their row
            for role, values in d.stats.items():
                m[role, :N_STATS] = values
            for role, arrivals in d.flights.items():
                for arrive, n in arrivals.items():
                    m[role, IN_FLIGHT] += n
                    landing.setdefault(arrive, []).append((role, n))
        for role, n in landing.pop(tick, ()):  # delivered in this tick: held or accounted by the receiver
            m[role, IN_FLIGHT] -= n
        for d in dones:  # completions, in canonical role order within each process
            for role, times in d.response_times.items():
                rts.extend(times)
                self.rt_by_node.setdefault(role_node(self.roles[role]), []).extend(times)
        totals = m.sum(axis=0)
        nodes = self.incidence @ m
        self.check(tick, totals)
        report = TickReport(tick, totals, totals - self._prev_totals, nodes, nodes - self._prev_nodes, rts)
        self._prev_totals, self._prev_nodes = totals, nodes
        self.ticks.append(tick)
        self.totals.append(totals)
        self.nodes.append(nodes)
        self.response_times.extend(rts)
        return report

    def check(self, tick: int, t: np.ndarray) -> None:
        generated = t[F["generated"]]
        accounted = (t[F["completed"]] + sum(t[F[c]] for c in DROP_CAUSES) + t[F["queue"]] + t[F["undecided"]]
                     + t[F["in_flight"]])
        if generated != accounted:
            parts = ", ".join(f"{name}={int(t[F[name]])}" for name in
                              ("completed", *DROP_CAUSES, "queue", "undecided", "in_flight"))
            raise ConservationError(f"tick {tick}: generated={int(generated)} but {parts} "
                                    f"account for {int(accounted)}: a task was lost or invented (a custom role "
                                    "must hand every task on, keep it, or drop it with Role.drop)")

    # ----- episode results -----

    def summary(self) -> dict[str, Any]:
        if not self.totals:
            raise RuntimeError("no tick recorded")
        sc = self.scenario
        end = self.totals[-1]
        tot = {name: int(end[F[name]]) for name in COUNTS}
        dropped = {c: tot.pop(c) for c in DROP_CAUSES}
        dropped["total"] = sum(dropped.values())
        rt = np.array(self.response_times)
        overloaded = np.array([t[F["overloaded"]] for t in self.totals])
        capacity = self.capacity.sum() * len(self.totals)
        energy = {k.removeprefix("energy_"): float(end[F[k]]) for k in ENERGY}
        energy["total"] = sum(energy.values())
        node_end = self.nodes[-1]
        nodes = {}
        for i, nid in enumerate(self.node_ids):
            v = node_end[i]
            cap = self.capacity[i] * len(self.totals)
            times = self.rt_by_node.get(nid, [])
            nodes[nid] = {
                "generated": int(v[F["generated"]]), "completed": int(v[F["completed"]]),
                "dropped": int(sum(v[F[c]] for c in DROP_CAUSES)), "offloaded": int(v[F["offloaded"]]),
                "overloaded_ticks": int(v[F["overloaded_ticks"]]),
                "utilisation": float(v[F["busy_cycles"]] / cap) if cap else 0.0,
                "energy_j": float(sum(v[F[k]] for k in ENERGY)),
                "response_time_mean": float(np.mean(times)) if times else None,
            }
        return {
            "scenario": sc.name,
            "scenario_hash": sc.digest(),
            "source": sc.source,
            "seed": None,  # filled in by the session, which knows the episode's seed
            "ticks": len(self.totals),
            "dt": sc.dt,
            "totals": {**tot, "dropped": dropped, "in_system": int(end[F["queue"]] + end[F["undecided"]]
                                                                  + end[F["in_flight"]])},
            "response_time": {
                "count": int(rt.size),
                "mean": float(rt.mean()) if rt.size else None,
                "p50": float(np.percentile(rt, 50)) if rt.size else None,
                "p95": float(np.percentile(rt, 95)) if rt.size else None,
                "max": float(rt.max()) if rt.size else None,
            },
            "overloaded": {"node_ticks": int(end[F["overloaded_ticks"]]),
                           "mean_nodes": float(overloaded.mean())},
            "utilisation": float(end[F["busy_cycles"]] / capacity) if capacity else 0.0,
            "energy_j": energy,
            "nodes": nodes,
        }

    def tick_table(self) -> tuple[list[str], list[list[Any]]]:
        header = ["tick", "time_s", "generated", "completed", "dropped", *(f"dropped_{c}" for c in DROP_CAUSES),
                  "offloaded", "in_system", "queued", "undecided", "in_flight", "overloaded_nodes",
                  "utilisation", "energy_j", "response_time_mean"]
        rows = []
        prev = np.zeros(len(FIELDS))
        cap = self.capacity.sum()
        rt_iter = iter(self._rt_per_tick())
        for tick, t in zip(self.ticks, self.totals, strict=True):
            d = t - prev
            prev = t
            times = next(rt_iter)
            rows.append([
                tick, tick * self.scenario.dt, int(d[F["generated"]]), int(d[F["completed"]]),
                int(sum(d[F[c]] for c in DROP_CAUSES)), *(int(d[F[c]]) for c in DROP_CAUSES),
                int(d[F["offloaded"]]), int(t[F["queue"]] + t[F["undecided"]] + t[F["in_flight"]]),
                int(t[F["queue"]]), int(t[F["undecided"]]), int(t[F["in_flight"]]), int(t[F["overloaded"]]),
                float(d[F["busy_cycles"]] / cap) if cap else 0.0, float(sum(d[F[k]] for k in ENERGY)),
                float(np.mean(times)) if times else "",
            ])
        return header, rows

    def _rt_per_tick(self) -> list[list[float]]:
        """Response times grouped by tick (completions are counted in the same order they were added)."""
        out, pos, prev = [], 0, 0
        for t in self.totals:
            n = int(t[F["completed"]]) - prev
            prev = int(t[F["completed"]])
            out.append(self.response_times[pos:pos + n])
            pos += n
        return out

    def node_table(self) -> tuple[list[str], list[list[Any]]]:
        header = ["tick", "node", "queue", "undecided", "overloaded", "generated", "completed", "dropped",
                  "offloaded", "utilisation", "energy_j"]
        rows = []
        prev = np.zeros((len(self.node_ids), len(FIELDS)))
        for tick, nodes in zip(self.ticks, self.nodes, strict=True):
            d = nodes - prev
            prev = nodes
            for i, nid in enumerate(self.node_ids):
                v, dv = nodes[i], d[i]
                cap = self.capacity[i]
                rows.append([tick, nid, int(v[F["queue"]]), int(v[F["undecided"]]), int(v[F["overloaded"]]),
                             int(dv[F["generated"]]), int(dv[F["completed"]]),
                             int(sum(dv[F[c]] for c in DROP_CAUSES)), int(dv[F["offloaded"]]),
                             float(dv[F["busy_cycles"]] / cap) if cap else 0.0,
                             float(sum(dv[F[k]] for k in ENERGY))])
        return header, rows

    def write(self, out_dir: Path, summary: dict[str, Any]) -> None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        for name, (header, rows) in (("ticks.csv", self.tick_table()), ("nodes.csv", self.node_table())):
            with (out_dir / name).open("w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(header)
                w.writerows(rows)
