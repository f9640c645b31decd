"""``orchestrator bench``: emulator ticks/s next to a bare Zenoh barrier with the same process count.

The bare barrier (DESIGN §6) is the floor a one-barrier-per-tick design approaches: a router, N
client processes from the same fork server, one publication to all of them per tick and N replies,
no simulation work. Both are measured in the same run, so their ratio holds when the machine's speed
drifts. Timing excludes start-up; every number is ticks per second of wall time.
"""

from __future__ import annotations

import json
import os
import queue
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from node_runtime.forkserver import ForkServer
from node_runtime.keys import Keys, new_sim_id
from node_runtime.process import PR_SET_NAME, _prctl
from node_runtime.zenoh_transport import close_session, use_lean_runtime, zenoh_config
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation, open_router

CONFIGS = (("inproc", "single"), ("zenoh", "per-role"), ("zenoh", "per-node"))


@dataclass
class Row:
    scenario: str
    transport: str
    layout: str
    processes: int
    ticks_per_s: float
    barrier_ticks_per_s: float | None  # bare Zenoh barrier with the same number of processes
    ratio: float | None  # emulator / barrier


def barrier_peer(endpoint: str, root: str, index: int) -> None:
    """A bare barrier participant: reply to every tick, do nothing else."""
    import zenoh

    use_lean_runtime()  # the same Zenoh runtime as node processes, so the ratio compares like with like
    _prctl(PR_SET_NAME, f"zb-{index}".encode())
    session = zenoh.open(zenoh_config("client", connect=[endpoint]))
    ticks: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = session.declare_subscriber(f"{root}/tick", lambda s: ticks.put(s.payload.to_bytes()))
    pub = session.declare_publisher(f"{root}/done/{index}", congestion_control=zenoh.CongestionControl.BLOCK,
                                    express=True)
    token = session.liveliness().declare_token(f"{root}/alive/{index}")
    while (t := ticks.get()) != b"stop":
        pub.put(t)
    token.undeclare()
    sub.undeclare()
    close_session(session)
    os._exit(0)


def bare_barrier(processes: int, ticks: int) -> float:
    """Ticks per second of the bare barrier with ``processes`` participants."""
    router, endpoint = open_router()
    root = Keys(new_sim_id(), "zbench").root
    forks = ForkServer.shared()
    pids = []
    try:
        ready: set[str] = set()
        router.watch_tokens(f"{root}/alive/*", lambda key, alive: alive and ready.add(key))
        # raw bytes straight from the session: no codec on the hot path
        replies: queue.SimpleQueue[int] = queue.SimpleQueue()
        sub = router.session.declare_subscriber(f"{root}/done/*", lambda s: replies.put(1))
        for i in range(processes):
            pids.append(forks.start(f"barrier-{i}", barrier_peer, endpoint, root, i))
        router.dispatch(until=lambda: len(ready) == processes, timeout=60)
        pub = router.put_publisher(f"{root}/tick")

        def one(t: int) -> None:
            pub.put(str(t).encode())
            for _ in range(processes):
                replies.get(timeout=30)

        for t in range(min(50, ticks)):  # warm-up
            one(t)
        t0 = time.perf_counter()
        for t in range(ticks):
            one(t)
        rate = ticks / (time.perf_counter() - t0)
        pub.put(b"stop")
        sub.undeclare()
        return rate
    finally:
        forks.wait(pids, 10.0)
        router.close()


def emulator(name: str, transport: str, layout: str, ticks: int) -> tuple[int, float]:
    scenario = load_scenario(name)
    with Simulation(scenario, transport=transport, layout=layout) as sim:
        sim.reset(policy="random")
        for _ in range(min(50, ticks)):  # warm-up
            sim.step()
        t0 = time.perf_counter()
        for _ in range(ticks):
            sim.step()
        rate = ticks / (time.perf_counter() - t0)
        return len(sim.routing.procs), rate


def run(scenarios: list[str], ticks: int, configs=CONFIGS, progress=None) -> list[Row]:
    rows: list[Row] = []
    barrier: dict[int, float] = {}
    for name in scenarios:
        for transport, layout in configs:
            if progress:
                progress(f"{name} {transport} {layout}")
            procs, rate = emulator(name, transport, layout, ticks)
            base = None
            if transport == "zenoh":
                if procs not in barrier:
                    if progress:
                        progress(f"bare barrier, {procs} processes")
                    barrier[procs] = bare_barrier(procs, ticks)
                base = barrier[procs]
            rows.append(Row(name, transport, layout, procs if transport == "zenoh" else 1, round(rate, 1),
                            None if base is None else round(base, 1),
                            None if base is None else round(rate / base, 3)))
    return rows


def save(rows: list[Row], path: Path) -> None:
    path.write_text(json.dumps([asdict(r) for r in rows], indent=2) + "\n")
