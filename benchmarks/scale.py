"""How the emulator scales with the node count: start-up, ticks/s and memory for N = 100, 300, 1000.

    python benchmarks/scale.py                              # N = 100 300 1000, groups:8 over Zenoh
    python benchmarks/scale.py --nodes 100 300 --groups 4 --ticks 100 --json scale.json

Each N is a random-geometric network (mean degree about 12, every node a tier-0 sensing node with
lambda = 0.1, the node-side least_queue policy) generated with the scenario generator. In-process:
the time to build and reset the simulation, then ticks/s. Over Zenoh with the ``groups:K`` layout (K
node processes, each a block of nodes, around one router): start-up until every process is ready,
ticks/s next to a bare Zenoh barrier with the same K processes (timed in alternating chunks, the
ratio is the median of the per-chunk ratios), and the summed resident memory of this process and all
its children at the end.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time
from pathlib import Path
from typing import Any

import psutil
from rich.console import Console
from rich.table import Table

from orchestrator.scenario import ScenarioError, load_scenario
from orchestrator.session import Simulation
from orchestrator.version import version_line
from orchestrator.viewers.bench import BareBarrier, alternate, ticks_per_s

RADIUS = 40.0  # metres
DEGREE = 12  # mean degree aimed at: the square's side is chosen for it
HEADERS = {"inproc_setup_s": "set-up s", "inproc_ticks_per_s": "ticks/s", "processes": "procs",
           "zenoh_startup_s": "start s", "zenoh_ticks_per_s": "ticks/s", "barrier_ticks_per_s": "barrier",
           "rss_mb": "RSS MB", "wall_s": "wall s", "reports_per_tick": "reports/tick"}


def scenario(n: int) -> tuple[dict[str, Any], Any]:
    """A connected random-geometric scenario of ``n`` nodes (the first placement seed that connects it):
    as a scenario file holds it, and loaded."""
    size = round(math.sqrt(n * math.pi * RADIUS**2 / DEGREE))
    for seed in range(100):
        data = {"name": f"rg{n}", "simulation": {"steps": 10**6, "seed": 7, "policy": "least_queue"},
                "workload": {"arrival": {"kind": "constant", "rate": 0.1}},
                "topology": {"generator": {"kind": "random_geometric", "n": n, "radius": RADIUS, "size": size,
                                           "seed": seed, "profile": "tier0"}}}
        try:
            return data, load_scenario(data, name_hint=f"rg{n}")
        except ScenarioError:  # disconnected: try the next placement
            continue
    raise RuntimeError(f"no connected placement of {n} nodes in 100 seeds")


def rss_mb(*pids: int) -> float:
    """Resident memory of these processes (default: this one) and all their descendants, summed."""
    total = 0
    for pid in pids or (None,):
        try:
            root = psutil.Process(pid)
            family = [root, *root.children(recursive=True)]
        except psutil.NoSuchProcess:  # ended meanwhile
            continue
        for proc in family:
            with contextlib.suppress(psutil.NoSuchProcess):  # gone while we looked
                total += proc.memory_info().rss
    return total / 2**20


def inproc(sc: Any, ticks: int) -> dict[str, float]:
    t0 = time.perf_counter()
    with Simulation.inproc(sc) as sim:
        sim.reset()
        build = time.perf_counter() - t0
        rate = ticks_per_s(sim)(ticks)
    return {"inproc_setup_s": round(build, 2), "inproc_ticks_per_s": round(rate, 1)}


def zenoh(sc: Any, groups: int, ticks: int, rounds: int) -> dict[str, float]:
    t0 = time.perf_counter()
    with Simulation.over_zenoh(sc, layout=f"groups:{groups}") as sim:
        sim.reset()
        startup = time.perf_counter() - t0
        barrier = BareBarrier(len(sim.plan.procs))
        try:
            rate, base, ratio = alternate(ticks_per_s(sim), barrier, ticks, rounds)
            memory = rss_mb()
        finally:
            barrier.close()
    return {"processes": len(sim.plan.procs), "zenoh_startup_s": round(startup, 2),
            "zenoh_ticks_per_s": round(rate, 1), "barrier_ticks_per_s": round(base, 1), "ratio": round(ratio, 3),
            "rss_mb": round(memory)}


def cell(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, str):
        return v
    return f"{v:,}" if isinstance(v, int) else f"{v:,.2f}"


def report(rows: list[dict[str, Any]], title: str, path: Path | None) -> None:
    """The rows as a table on the console; also as JSON in ``path``."""
    table = Table(title=title, caption=f"measured with {version_line()}", caption_justify="left")
    columns = list(dict.fromkeys(key for r in rows for key in r))  # a row may leave a column out
    for key in columns:
        table.add_column(HEADERS.get(key, key), justify="right")
    for r in rows:
        table.add_row(*(cell(r.get(key)) for key in columns))
    Console().print(table)
    if path:
        path.write_text(json.dumps(rows, indent=1) + "\n")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, nargs="+", default=[100, 300, 1000], help="node counts (default 100 300 1000)")
    p.add_argument("--groups", type=int, default=8, help="node processes over Zenoh (layout groups:K; default 8)")
    p.add_argument("--ticks", type=int, default=200, help="ticks timed per measurement (default 200)")
    p.add_argument("--rounds", type=int, default=4, help="alternating chunks against the barrier (default 4)")
    p.add_argument("--json", type=Path, help="also write the rows here")
    args = p.parse_args()
    console = Console()
    rows = []
    for n in args.nodes:
        console.print(f"N = {n} ...")
        _, sc = scenario(n)
        rows.append({"nodes": n, "links": len(sc.links), **inproc(sc, args.ticks),
                     **zenoh(sc, min(args.groups, n), args.ticks, args.rounds)})
    report(rows, f"random-geometric networks; in-process, then Zenoh with layout groups:{args.groups}", args.json)


if __name__ == "__main__":
    main()
