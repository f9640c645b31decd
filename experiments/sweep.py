"""One study of the paper: for every sweep value, train the learners, evaluate every agent, plot.

For each point of the sweep (a scenario and an arrival rate) the learning agents are trained from
scratch, then every agent, learning or not, is evaluated on the same K episodes (the same seeds, so the
same task arrivals). Outputs under ``--out``:

    results.csv          one row per agent x sweep value x evaluation episode
    summary.csv          mean and 95% CI half-width per agent and sweep value
    timings.csv          wall time of every training and evaluation run
    <study>.png          the paper's three panels
    config.json          the settings and learner configs used
    train/<point>/<agent>.csv, checkpoints/<point>/<agent>.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from agents import BASELINES, LEARNERS, Policy, evaluate, train
from agents.training import progress_bar, write_csv
from experiments.common import add_env_arguments, add_learner_arguments, learner_config, make_env, set_threads
from experiments.plot import plot_study, summarise

AGENTS = ("ddqn", "a2c", "ppo", "local", "random", "least_queue", "greedy", "round_robin")


@dataclass(frozen=True)
class Settings:
    """How much work a study does; FULL is the paper's protocol, QUICK a few-minute run of the same code."""

    max_steps: int = 1000  # decision steps per episode (the paper's 1000 s at one decision per second)
    train_episodes: int = 300
    eval_episodes: int = 100
    hidden: tuple[int, ...] = (128, 128)
    learners: dict[str, dict[str, Any]] = field(default_factory=dict)  # per-algorithm config changes


FULL = Settings()
QUICK = Settings(max_steps=300, train_episodes=10, eval_episodes=5, hidden=(64, 64),
                 learners={"ddqn": {"learning_starts": 64, "target_update_interval": 100},
                           "ppo": {"rollout_steps": 100}})


@dataclass(frozen=True)
class Point:
    """One value of the sweep."""

    label: str  # for file names and tables
    scenario: str
    lam: float
    x: float  # abscissa in the figure


def parser(study: str, description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"python -m experiments.{study}", description=description)
    p.add_argument("--quick", action="store_true",
                   help=f"a few minutes instead of hours: {QUICK.max_steps}-step episodes, {QUICK.train_episodes} "
                        f"training and {QUICK.eval_episodes} evaluation episodes, {QUICK.hidden} networks, fewer "
                        "sweep values (docs/agents.md)")
    p.add_argument("--out", type=Path, default=Path(f"runs/{study}"), help=f"output directory (default runs/{study})")
    p.add_argument("--agents", nargs="+", default=list(AGENTS), choices=list(AGENTS), metavar="AGENT",
                   help=f"agents to run (default: all of {', '.join(AGENTS)})")
    p.add_argument("--train-episodes", type=int, default=None,
                   help="training episodes per learner and point (default 300, quick 10)")
    p.add_argument("--eval-episodes", type=int, default=None,
                   help="evaluation episodes per agent and point (default 100, quick 5)")
    add_env_arguments(p, scenario=False)
    add_learner_arguments(p)
    return p


def settings_from(args: argparse.Namespace) -> Settings:
    base = QUICK if args.quick else FULL
    changes = {k: v for k, v in (("max_steps", args.max_steps), ("train_episodes", args.train_episodes),
                                 ("eval_episodes", args.eval_episodes),
                                 ("hidden", tuple(args.hidden) if args.hidden else None)) if v is not None}
    return dataclasses.replace(base, **changes)


def run_study(study: str, points: Sequence[Point], x_key: str, xlabel: str, args: argparse.Namespace,
              xticklabels: dict[float, str] | None = None) -> list[dict[str, Any]]:
    """Train and evaluate every agent at every point; write the CSVs and the figure; return the results rows."""
    set_threads(args.threads)
    settings = settings_from(args)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    configs = {a: learner_config(a, seed=args.seed, hidden=settings.hidden, base=settings.learners.get(a),
                                 overrides=args.overrides) for a in args.agents if a in LEARNERS}
    (out / "config.json").write_text(json.dumps({
        "study": study, "quick": args.quick, "settings": dataclasses.asdict(settings), "seed": args.seed,
        "reward": args.reward, "transport": args.transport, "device": args.device,
        "points": [dataclasses.asdict(p) for p in points],
        "learners": {a: dataclasses.asdict(c) for a, c in configs.items()}}, indent=1))
    console = Console()
    rows: list[dict[str, Any]] = []
    timings: list[dict[str, Any]] = []
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        for point in points:
            env = make_env(point.scenario, point.lam, settings.max_steps, args.reward, args.transport, args.seed)
            for agent in args.agents:
                start = time.perf_counter()
                policy: Policy
                if agent in LEARNERS:
                    policy = learner = LEARNERS[agent].for_env(env, configs[agent], args.device)
                    train(env, learner, settings.train_episodes, seed=args.seed * settings.train_episodes,
                          csv_path=out / "train" / point.label / f"{agent}.csv", progress=progress,
                          label=f"{point.label} train {agent}")
                    (out / "checkpoints" / point.label).mkdir(parents=True, exist_ok=True)
                    learner.save(out / "checkpoints" / point.label / f"{agent}.pt")
                    timings.append(_timing(point, agent, "train", settings.train_episodes, start))
                    start = time.perf_counter()
                else:
                    policy = BASELINES[agent](args.seed)
                for r in evaluate(env, policy, settings.eval_episodes, progress=progress,
                                  label=f"{point.label} eval {agent}"):
                    rows.append({"study": study, "scenario": point.scenario, "lambda": point.lam, x_key: point.x,
                                 "agent": agent, **r})
                timings.append(_timing(point, agent, "eval", settings.eval_episodes, start))
            env.close()
    write_csv(out / "results.csv", rows)
    write_csv(out / "summary.csv", summarise(rows, x_key, args.agents))
    write_csv(out / "timings.csv", timings)
    what = f"{settings.eval_episodes} evaluation episodes of {settings.max_steps} steps per point"
    plot_study(rows, x_key, xlabel, args.agents, f"{study.upper()}: {what}, 95% confidence bands",
               out / f"{study}.png", xticklabels)
    _print_summary(console, rows, x_key, args.agents)
    console.print(f"wrote {out / 'results.csv'}, {out / 'summary.csv'} and {out / f'{study}.png'}")
    return rows


def _timing(point: Point, agent: str, phase: str, episodes: int, start: float) -> dict[str, Any]:
    return {"point": point.label, "agent": agent, "phase": phase, "episodes": episodes,
            "wall_s": round(time.perf_counter() - start, 2)}


def _print_summary(console: Console, rows: list[dict[str, Any]], x_key: str, agents: Sequence[str]) -> None:
    for x in sorted({r[x_key] for r in rows}):
        table = Table(title=f"{x_key} = {x:g}")
        for col in ("agent", "response time [s]", "completion ratio", "penalised resp. time [s]", "dropped",
                    "overloaded node-ticks", "completed"):
            table.add_column(col, justify="left" if col == "agent" else "right")
        for s in summarise([r for r in rows if r[x_key] == x], x_key, agents):
            table.add_row(s["agent"], *(f"{s[m]:.2f} ± {s[m + '_ci95']:.2f}" if m == "completion_ratio"
                                        else f"{s[m]:.1f} ± {s[m + '_ci95']:.1f}" for m in
                                        ("response_time_mean", "completion_ratio", "penalised_response_time",
                                         "dropped", "overloaded_node_ticks", "completed")))
        console.print(table)
