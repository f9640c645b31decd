"""env.step() steps/s with random masked actions, next to a bare Zenoh barrier with the same process count.

    python benchmarks/env_steps.py                      # aot1..aot4, inproc + zenoh per-role + per-node
    python benchmarks/env_steps.py aot2 --steps 2000 --configs inproc:single zenoh:per-node
    python benchmarks/env_steps.py --configs zenoh:per-node --rounds 10 --repeats 3   # a range over process sets

Only env.step() is timed: choosing the random actions (from each agent's action mask) happens outside
the timed region, so the figure is the environment's cost, not the agent's. The bare barrier (see
`orchestrator bench`) runs beside it and both are timed in alternating chunks; the ratio is the median
of the per-chunk ratios, so it holds when the machine's speed drifts. It still moves between fresh sets
of processes (on the 2-core development machine by up to ±0.07 for the same code within an hour):
``--repeats K`` measures K sets and reports the median ratio with its range.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from env import ZenohEdgeEnv
from orchestrator.version import version_line
from orchestrator.viewers.bench import BareBarrier, alternate
from orchestrator.viewers.progress import progress_steps

CONFIGS = ("inproc:single", "zenoh:per-role", "zenoh:per-node", "zenoh:groups:2")


def random_steps(env: ZenohEdgeEnv, seed: int = 0) -> Callable[[int], float]:
    """Reset ``env``; then ``rate(n)`` makes n ``env.step()`` calls with random actions from each agent's
    mask and returns steps per second of ``step()`` time alone."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)

    def rate(n: int) -> float:
        nonlocal obs
        spent = 0.0
        for _ in range(n):
            actions = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) for a in env.agents}
            t0 = time.perf_counter()
            obs, *_ = env.step(actions)
            spent += time.perf_counter() - t0
        return n / spent

    return rate


def measure(scenario: str, transport: str, layout: str, steps: int, rounds: int) -> dict:
    env = ZenohEdgeEnv(scenario, transport=transport, layout=layout, max_steps=10**9)
    barrier = None
    try:
        run = random_steps(env)
        run(50)  # warm-up
        processes = len(env.sim.plan.procs) if transport == "zenoh" else 1
        barrier = BareBarrier(processes) if transport == "zenoh" else None
        rate, base, ratio = alternate(run, barrier, steps, rounds)
    finally:
        if barrier is not None:
            barrier.close()
        env.close()
    return {"scenario": scenario, "transport": transport, "layout": layout, "processes": processes,
            "steps_per_s": round(rate, 1), "barrier_ticks_per_s": None if base is None else round(base, 1),
            "ratio": None if ratio is None else round(ratio, 3)}


def repeated(runs: list[dict]) -> dict:
    """Medians over fresh sets of processes, and the range of the ratios (None for one set, or no barrier)."""
    row = dict(runs[0])
    for key, digits in (("steps_per_s", 1), ("barrier_ticks_per_s", 1), ("ratio", 3)):
        values = [r[key] for r in runs if r[key] is not None]
        row[key] = round(statistics.median(values), digits) if values else None
    ratios = [r["ratio"] for r in runs if r["ratio"] is not None]
    row["ratio_range"] = [min(ratios), max(ratios)] if len(ratios) > 1 else None
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", default=["aot1", "aot2", "aot3", "aot4"])
    parser.add_argument("--steps", type=int, default=1000, help="timed steps per configuration (default 1000)")
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), help="transport:layout pairs")
    parser.add_argument("--rounds", type=int, default=5, help="alternating chunks; medians are reported (default 5)")
    parser.add_argument("--repeats", type=int, default=1,
                        help="fresh sets of processes per configuration, measured one after the other: the median "
                             "ratio is reported with its range (default 1)")
    parser.add_argument("--out", metavar="FILE", help="also write the rows as JSON")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    rows = []
    with progress_steps(len(args.scenarios) * len(args.configs) * args.repeats, "env_steps") as step:
        for scenario in args.scenarios:
            for config in args.configs:
                transport, layout = config.split(":", 1)
                runs = []
                for k in range(args.repeats):
                    step(f"{scenario} {config}" + (f" ({k + 1}/{args.repeats})" if args.repeats > 1 else ""))
                    runs.append(measure(scenario, transport, layout, args.steps, args.rounds))
                rows.append(repeated(runs))
    title = (f"env.step() steps/s, medians of {args.rounds} alternating chunks of {args.steps // args.rounds} "
             "steps, random masked actions")
    if args.repeats > 1:
        title += f"; medians over {args.repeats} sets of processes, and the range of their ratios"
    table = Table(title=title, title_justify="left", caption=f"measured with {version_line()}", caption_justify="left")
    columns = ["scenario", "transport", "layout", "processes", "steps/s", "barrier ticks/s", "ratio"]
    for col in columns + (["range"] if args.repeats > 1 else []):
        table.add_column(col, justify="left" if col in ("scenario", "transport", "layout") else "right")
    for r in rows:
        cells = [r["scenario"], r["transport"], r["layout"], str(r["processes"]), f"{r['steps_per_s']:,.0f}",
                 "-" if r["barrier_ticks_per_s"] is None else f"{r['barrier_ticks_per_s']:,.0f}",
                 "-" if r["ratio"] is None else f"{r['ratio']:.2f}"]
        if args.repeats > 1:
            low_high = r["ratio_range"]
            cells.append("-" if low_high is None else f"{low_high[0]:.2f}–{low_high[1]:.2f}")
        table.add_row(*cells)
    Console(width=max(Console().width, 120)).print(table)  # the range column fits when piped too
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
