"""Several hosts, emulated with network namespaces: start-up, ticks/s and memory of N nodes whose node
processes run on H "hosts", each behind the router `zenohedge-node` runs there.

    sudo python benchmarks/hosts.py --nodes 1000 10000 --hosts 4 --groups 16

Needs root and iproute2 (deploy/netns.sh makes the namespaces and removes them at the end). Each N is
benchmarks/scale.py's random-geometric network, written to a scenario file, with the layout groups:K;
host h runs processes group-(h·K/H) … of it, placed by a placement file, and the orchestrator runs none.
The orchestrator is the real CLI (`orchestrator launch --listen 0.0.0.0:PORT --insecure --placement …`), each host a
real `zenohedge-node` inside its namespace; the figures are the run's own (summary.json: start-up until
every process is ready, ticks/s) and the peak resident memory summed over every process. All hosts
share this machine's cores, so this measures the protocol and the routers at N, not H machines' speed.

Each host's `zenohedge-node` forwards its processes' reports of a tick as one message (the default);
`--aggregation both` also runs each N with `--no-aggregate`, right after, to compare the two in one
sitting (`reports/tick`: the report messages the orchestrator handled per tick).

Right after each run, a bare Zenoh barrier (`orchestrator bench`'s) with the same processes on the same
hosts: the orchestrator's router on the root namespace, and in each namespace a router joined to it with
that host's share of the participants behind it on a unix socket, as `zenohedge-node` lays a host out.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from scale import report, rss_mb, scenario  # the sibling script: run this one as python benchmarks/hosts.py

from node_runtime.runtime.layout import ProcessLayout
from orchestrator.session import free_port
from orchestrator.viewers.bench import BareBarrier, barrier_host

ROOT = Path(__file__).resolve().parent.parent
NETNS = ROOT / "deploy" / "netns.sh"
SIM = "bench"


def shares(procs: int, hosts: int) -> list[range]:
    """The process indices each host runs: whole processes, in order, the last hosts possibly with fewer."""
    share = -(-procs // hosts)
    return [range(h * share, min(procs, (h + 1) * share)) for h in range(hosts) if h * share < procs]


def placement(sc: Any, procs: int, hosts: int) -> dict[str, list[str]]:
    """host<h> -> the nodes of its share of the groups:K processes."""
    plan = ProcessLayout(sc, f"groups:{procs}")
    return {f"host{h}": [n for i in indices for n in plan.node_of_proc(plan.procs[i])]
            for h, indices in enumerate(shares(procs, hosts), start=1)}


def barrier(procs: int, hosts: int, ticks: int, rounds: int = 5) -> float:
    """Ticks/s of a bare barrier of ``procs`` participants spread over the namespaces like the run's
    processes (median of ``rounds`` chunks of ``ticks``)."""
    members: list[subprocess.Popen] = []

    def spawn(endpoint: str, root: str) -> None:
        port = endpoint.rsplit(":", 1)[1]
        for h, indices in enumerate(shares(procs, hosts), start=1):
            members.append(subprocess.Popen(["ip", "netns", "exec", f"zedge-host{h}", sys.executable, __file__,
                                             "--barrier-host", f"tcp/10.77.{h}.1:{port}", root,
                                             str(indices.start), str(len(indices))], cwd=ROOT))

    try:
        bench = BareBarrier(procs, host="0.0.0.0", spawn=spawn)
        try:
            return statistics.median(bench.rate(ticks) for _ in range(rounds))
        finally:
            bench.close()
    finally:
        for member in members:
            try:
                member.wait(30)
            except subprocess.TimeoutExpired:
                member.kill()
                member.wait()


def peak_rss(pids: list[int], until: subprocess.Popen) -> float:
    """The peak of ``rss_mb(*pids)``, polled until ``until`` exits."""
    peak = 0.0
    while until.poll() is None:
        peak = max(peak, rss_mb(*pids))
        time.sleep(0.5)
    return peak


def measure(n: int, procs: int, hosts: int, ticks: int, work: Path, aggregate: bool = True,
            with_barrier: bool = True) -> dict[str, Any]:
    data, sc = scenario(n)
    (work / "scenario.yaml").write_text(yaml.safe_dump(data))
    groups = placement(sc, procs, hosts)
    (work / "placement.yaml").write_text(yaml.safe_dump({"groups": groups}))
    port = free_port("0.0.0.0")
    log = work / f"launch-{n}.log"
    t0 = time.perf_counter()
    with open(log, "w") as err:
        launch = subprocess.Popen([sys.executable, "-m", "orchestrator.cli", "launch", str(work / "scenario.yaml"),
                                   "--layout", f"groups:{procs}", "--listen", f"0.0.0.0:{port}", "--insecure",
                                   "--sim-id", SIM,
                                   "--placement", str(work / "placement.yaml"), "--steps", str(ticks),
                                   "--timeout", "600", "--out", str(work / f"run-{n}")],
                                  stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
    while "waiting for" not in log.read_text():  # the router listens: the hosts may connect
        if launch.poll() is not None:
            raise RuntimeError(f"launch failed:\n{log.read_text()}")
        time.sleep(0.1)
    members = [subprocess.Popen(["ip", "netns", "exec", f"zedge-host{h}", sys.executable, "-m",
                                 "node_runtime.runtime.remote", "--connect", f"tcp/10.77.{h}.1:{port}", "--sim", SIM,
                                 "--group", group, "--timeout", "600", *([] if aggregate else ["--no-aggregate"])],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
               for h, group in enumerate(groups, start=1)]
    rss = peak_rss([launch.pid, *(m.pid for m in members)], until=launch)
    wall = time.perf_counter() - t0
    for member in members:
        member.wait(60)
    if launch.returncode != 0:
        raise RuntimeError(f"launch exited with status {launch.returncode}:\n{log.read_text()}")
    summary = json.loads((work / f"run-{n}" / "summary.json").read_text())
    run, reports = summary["run"], summary["run"]["reports"]
    row = {"nodes": n, "hosts": len(groups), "processes": run["processes"], "aggregated": "yes" if aggregate else "no",
           "reports_per_tick": round((reports["alone"] + reports["host_messages"]) / summary["ticks"], 1),
           "zenoh_startup_s": run["startup_s"], "zenoh_ticks_per_s": run["ticks_per_s"]}
    if with_barrier:
        row["barrier_ticks_per_s"] = round(barrier(run["processes"], hosts, ticks=200), 1)
    return {**row, "rss_mb": round(rss), "wall_s": round(wall, 1)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--nodes", type=int, nargs="+", default=[1000, 10000], help="node counts (default 1000 10000)")
    p.add_argument("--hosts", type=int, default=4, help="network namespaces standing for hosts (default 4)")
    p.add_argument("--groups", type=int, default=16, help="node processes (layout groups:K; default 16)")
    p.add_argument("--ticks", type=int, default=40, help="ticks per run (default 40)")
    p.add_argument("--aggregation", choices=["on", "off", "both"], default="on",
                   help="hosts forward their processes' reports of a tick as one message (on, the default), each "
                        "process reports alone (off), or both, one run after the other (the barrier once)")
    p.add_argument("--json", type=Path, help="also write the rows here")
    p.add_argument("--barrier-host", nargs=4, metavar=("UPSTREAM", "ROOT", "FIRST", "COUNT"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.barrier_host:  # this script, run inside one namespace by ``barrier``
        upstream, root, first, count = args.barrier_host
        barrier_host(upstream, root, range(int(first), int(first) + int(count)))
        return
    if os.geteuid() != 0:
        p.error("network namespaces need root (and iproute2)")
    console = Console()
    rows = []
    subprocess.run([NETNS, "down"], check=True, capture_output=True)
    subprocess.run([NETNS, "up", str(args.hosts)], check=True, capture_output=True)
    try:
        modes = {"on": [True], "off": [False], "both": [True, False]}[args.aggregation]
        with tempfile.TemporaryDirectory(prefix="zenohedge-hosts-") as work:
            for n in args.nodes:
                console.print(f"N = {n} on {args.hosts} hosts ...")
                rows += [measure(n, min(args.groups, n), args.hosts, args.ticks, Path(work), aggregate, i == 0)
                         for i, aggregate in enumerate(modes)]
    finally:
        subprocess.run([NETNS, "down"], capture_output=True)
    report(rows, f"{args.hosts} hosts (network namespaces), layout groups:{args.groups}, one router per host",
           args.json)


if __name__ == "__main__":
    main()
