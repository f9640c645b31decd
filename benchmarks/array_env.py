"""Agent-steps/s of the array backend against K, beside the in-process emulator, in one run.

    python benchmarks/array_env.py --scenario aot2 --ticks 300 --ks 1 16 256 1024 [--policy least_queue]

An agent-step is one controller's tick: ticks x controllers x K over the wall time of the ticks. Rows:
  - ``inproc``: ``Simulation.inproc`` with the node-side policy (the emulator's fastest path, K = 1);
  - ``array K``: ``ArraySim`` with K copies (seeds 1..K), the same policy; its set-up (the arrivals drawn by
    the model's clients, per copy, in Python) is reported apart, as is the memory of its arrays.
Both run node-side policies, not an agent: this measures the simulation, not an RL loop. Numbers from a
shared machine are noisy; the load average is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from node_runtime.model.array import ArraySim
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from orchestrator.version import version_line


def inproc_rate(name: str, policy: str, ticks: int) -> float:
    sc = load_scenario(name)
    with Simulation.inproc(sc) as sim:
        start = time.perf_counter()
        sim.run(ticks, seed=1, policy=policy)
        wall = time.perf_counter() - start
    return ticks * len(sc.controllers) / wall


def array_rate(name: str, policy: str, ticks: int, k: int) -> tuple[float, float, float]:
    """(agent-steps/s, set-up seconds, MiB of its arrays)."""
    sc = load_scenario(name)
    sim = ArraySim(sc, k, policy=policy)
    start = time.perf_counter()
    sim.reset(list(range(1, k + 1)), ticks)
    setup = time.perf_counter() - start
    mib = sum(v.nbytes for v in vars(sim).values() if isinstance(v, np.ndarray)) / 2**20
    start = time.perf_counter()
    for _ in range(ticks):
        sim.step()
    wall = time.perf_counter() - start
    return ticks * len(sc.controllers) * k / wall, setup, mib


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="aot2")
    ap.add_argument("--policy", default="least_queue")
    ap.add_argument("--ticks", type=int, default=300)
    ap.add_argument("--ks", type=int, nargs="+", default=[1, 16, 256, 1024])
    args = ap.parse_args()
    print(version_line())
    print(f"{args.scenario}, policy {args.policy}, {args.ticks} ticks, load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores (a shared machine: noisy)")
    print(f"{'backend':>12} {'agent-steps/s':>14} {'set-up s':>9} {'MiB':>8}")
    print(f"{'inproc':>12} {inproc_rate(args.scenario, args.policy, args.ticks):>14,.0f}")
    for k in args.ks:
        rate, setup, mib = array_rate(args.scenario, args.policy, args.ticks, k)
        print(f"{'array ' + str(k):>12} {rate:>14,.0f} {setup:>9.2f} {mib:>8.1f}", flush=True)


if __name__ == "__main__":
    main()
