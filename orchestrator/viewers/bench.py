"""``orchestrator bench``: emulator ticks/s next to a bare Zenoh barrier with the same process count.

The bare barrier (docs/protocol.md, "Speed") is the floor a one-barrier-per-tick design approaches: a router, N
client processes from the same fork server, one publication to all of them per tick and N replies,
no simulation work. Both are measured in the same run, so their ratio holds when the machine's speed
drifts. Timing excludes start-up; every number is ticks per second of wall time.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from node_runtime.runtime.access import LOCAL_LINK
from node_runtime.runtime.forkserver import ForkServer
from node_runtime.runtime.keys import Keys, new_sim_id
from node_runtime.runtime.process import PR_SET_NAME, _prctl
from node_runtime.runtime.zenoh_bus import (
    ZenohTransport,
    close_session,
    reliable_publisher,
    use_lean_runtime,
    zenoh_config,
)
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation, open_router

CONFIGS = (("inproc", "single"), ("zenoh", "per-role"), ("zenoh", "per-node"), ("zenoh", "groups:2"))


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
    pub = reliable_publisher(session, f"{root}/done/{index}")  # as node processes publish
    token = session.liveliness().declare_token(f"{root}/alive/{index}")
    while (t := ticks.get()) != b"stop":
        pub.put(t)
    token.undeclare()
    sub.undeclare()
    close_session(session)
    os._exit(0)


def barrier_host(upstream: str, root: str, indices: range) -> None:
    """One host's share of a bare barrier, laid out as ``zenohedge-node`` lays out a host: a router joined
    to ``upstream``, and the participants ``indices`` connected to it over a unix socket. Returns when they
    have all ended (the barrier's ``close``)."""
    with tempfile.TemporaryDirectory(prefix="zenohedge-barrier-") as folder:
        local = f"{LOCAL_LINK}/{folder}/router.sock"
        router = ZenohTransport.router(local, [upstream])
        forks = ForkServer.shared()
        try:
            forks.wait([forks.start(f"barrier-{i}", barrier_peer, local, root, i) for i in indices], None)
        finally:
            router.close()


class BareBarrier:
    """N idle participants around a router of its own; ``rate(ticks)`` drives that many barrier rounds.

    By default the participants are forked here and connect to that router on loopback. ``spawn(endpoint,
    root)`` starts them elsewhere instead, e.g. behind other hosts' routers (``barrier_host``); the router
    then listens on ``host`` and the barrier waits for participants 0 … N-1 to announce themselves."""

    def __init__(self, processes: int, host: str = "127.0.0.1", spawn: Callable[[str, str], None] | None = None,
                 timeout: float = 60.0) -> None:
        self.n = processes
        self.router, endpoint = open_router(host)
        self.root = Keys(new_sim_id(), "zbench").root
        self.forks = ForkServer.shared()
        self.pids: list[int] = []
        self.replies: queue.SimpleQueue[int] = queue.SimpleQueue()
        try:
            ready: set[str] = set()
            self.router.watch_tokens(f"{self.root}/alive/*", lambda key, alive: alive and ready.add(key))
            # raw bytes straight from the session: no codec on the hot path
            self.sub = self.router.session.declare_subscriber(f"{self.root}/done/*", lambda s: self.replies.put(1))
            if spawn is not None:
                spawn(endpoint, self.root)
            else:
                for i in range(processes):
                    self.pids.append(self.forks.start(f"barrier-{i}", barrier_peer, endpoint, self.root, i))
            self.router.dispatch(until=lambda: len(ready) == processes, timeout=timeout)
            self.pub = self.router.put_publisher(f"{self.root}/tick")
            self.rate(50)  # warm-up
        except BaseException:
            self.close()
            raise

    def rate(self, ticks: int) -> float:
        t0 = time.perf_counter()
        for t in range(ticks):
            self.pub.put(str(t).encode())
            for _ in range(self.n):
                self.replies.get(timeout=30)
        return ticks / (time.perf_counter() - t0)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.pub.put(b"stop")
        self.forks.wait(self.pids, 10.0)
        self.router.close()


def alternate(rate: Callable[[int], float], barrier: BareBarrier | None, ticks: int, rounds: int
              ) -> tuple[float, float | None, float | None]:
    """(rate, barrier rate, ratio): medians over ``rounds`` chunks of ``ticks / rounds``, ``rate(n)`` (what is
    measured, per second) and the barrier timed in turn.

    Both sets of processes stay up together (idle ones cost nothing) and the two are timed in turn, so a
    drift of the machine's speed hits both alike; the ratio is the median of the per-round ratios.
    """
    chunk = max(1, ticks // rounds)
    own, base = [], []
    for _ in range(rounds):
        own.append(rate(chunk))
        if barrier is not None:
            base.append(barrier.rate(chunk))
    if barrier is None:
        return statistics.median(own), None, None
    return statistics.median(own), statistics.median(base), statistics.median(
        [a / b for a, b in zip(own, base, strict=True)])


def ticks_per_s(sim: Simulation) -> Callable[[int], float]:
    """``rate(n)``: step ``sim`` n ticks and return the ticks per second of wall time."""
    def rate(n: int) -> float:
        t0 = time.perf_counter()
        for _ in range(n):
            sim.step()
        return n / (time.perf_counter() - t0)
    return rate


def measure(name: str, transport: str, layout: str, ticks: int, rounds: int) -> tuple[int, float, float | None,
                                                                                         float | None]:
    """(processes, emulator ticks/s, barrier ticks/s, ratio), from ``alternate``."""
    with Simulation.open(load_scenario(name), transport, layout=layout) as sim:
        sim.reset(policy="random")
        ticks_per_s(sim)(min(50, ticks))  # warm-up
        procs = len(sim.plan.procs)
        barrier = BareBarrier(procs) if transport == "zenoh" else None
        try:
            rate, base, ratio = alternate(ticks_per_s(sim), barrier, ticks, rounds)
        finally:
            if barrier is not None:
                barrier.close()
    return (1 if barrier is None else procs), rate, base, ratio


def run(scenarios: list[str], ticks: int, configs=CONFIGS, rounds: int = 5, progress=None) -> list[Row]:
    rows: list[Row] = []
    for name in scenarios:
        for transport, layout in configs:
            if progress:
                progress(f"{name} {transport} {layout}")
            procs, rate, base, ratio = measure(name, transport, layout, ticks, rounds)
            rows.append(Row(name, transport, layout, procs, round(rate, 1),
                            None if base is None else round(base, 1), None if ratio is None else round(ratio, 3)))
    return rows


def save(rows: list[Row], path: Path) -> None:
    path.write_text(json.dumps([asdict(r) for r in rows], indent=2) + "\n")
