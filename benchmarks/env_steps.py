"""env.step() steps/s with random masked actions, next to a bare Zenoh barrier with the same process count.

    python benchmarks/env_steps.py                      # aot1..aot4, inproc + zenoh per-role + per-node
    python benchmarks/env_steps.py aot2 --steps 2000 --configs inproc:single zenoh:per-node

Only env.step() is timed: choosing the random actions (from each agent's action mask) happens outside
the timed region, so the figure is the environment's cost, not the agent's. The bare barrier (see
`orchestrator bench`) is measured in the same run, so the ratio holds when the machine's speed drifts.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from env import ZenohEdgeEnv
from orchestrator.bench import bare_barrier

CONFIGS = ("inproc:single", "zenoh:per-role", "zenoh:per-node")


def env_rate(scenario: str, transport: str, layout: str, steps: int, warmup: int = 50) -> tuple[int, float]:
    env = ZenohEdgeEnv(scenario, transport=transport, layout=layout, max_steps=steps + warmup + 1)
    try:
        obs, _ = env.reset(seed=0)
        rng = np.random.default_rng(0)
        spent = 0.0
        for i in range(steps + warmup):
            actions = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) for a in env.agents}
            t0 = time.perf_counter()
            obs, *_ = env.step(actions)
            if i >= warmup:
                spent += time.perf_counter() - t0
        processes = len(env.sim.routing.procs) if transport == "zenoh" else 1
        return processes, steps / spent
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", default=["aot1", "aot2", "aot3", "aot4"])
    parser.add_argument("--steps", type=int, default=1000, help="timed steps per configuration (default 1000)")
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), help="transport:layout pairs")
    parser.add_argument("--out", metavar="FILE", help="also write the rows as JSON")
    args = parser.parse_args()
    console = Console(stderr=True)
    rows, barrier = [], {}
    with console.status("") as status:
        for scenario in args.scenarios:
            for config in args.configs:
                transport, layout = config.split(":")
                status.update(f"{scenario} {config}")
                procs, rate = env_rate(scenario, transport, layout, args.steps)
                base = None
                if transport == "zenoh":
                    if procs not in barrier:
                        status.update(f"bare barrier, {procs} processes")
                        barrier[procs] = bare_barrier(procs, args.steps)
                    base = barrier[procs]
                rows.append({"scenario": scenario, "transport": transport, "layout": layout, "processes": procs,
                             "steps_per_s": round(rate, 1), "barrier_ticks_per_s": base and round(base, 1),
                             "ratio": base and round(rate / base, 3)})
    table = Table(title=f"env.step() steps/s over {args.steps} steps, random masked actions", title_justify="left")
    for col in ("scenario", "transport", "layout", "processes", "steps/s", "barrier ticks/s", "ratio"):
        table.add_column(col, justify="left" if col in ("scenario", "transport", "layout") else "right")
    for r in rows:
        table.add_row(r["scenario"], r["transport"], r["layout"], str(r["processes"]), f"{r['steps_per_s']:,.0f}",
                      "-" if r["barrier_ticks_per_s"] is None else f"{r['barrier_ticks_per_s']:,.0f}",
                      "-" if r["ratio"] is None else f"{r['ratio']:.2f}")
    Console().print(table)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
