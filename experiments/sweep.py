"""One study of the paper: for every sweep value, train the learners, evaluate every agent, plot.

For each point of the sweep (a scenario and an arrival rate) the learning agents are trained from
scratch, then every agent, learning or not, is evaluated on the same K episodes (the same seeds, so the
same task arrivals); all of it once per training seed, except for the baselines, which are evaluated
once: evaluation reseeds every policy from the episode's seed, so for a policy that does not learn the
training seed changes nothing, and identical copies of its episodes would only narrow its intervals.
Each (point, seed, agent) is one independent run, so the grid can run on Ray (experiments.distributed)
with the same outputs. Outputs under ``--out``:

    results.csv          one row per training seed x agent x sweep value x evaluation episode
    summary.csv          mean and 95% CI half-width per agent and sweep value (over the training seeds'
                         means when there are several, else over the episodes)
    timings.csv          wall time of every training and evaluation run
    marl_eval.json       the evaluations in marl-eval's format (experiments.marl_eval)
    <study>.png          the paper's three panels
    config.json          the settings and learner configs used
    train/<point>/seed<k>/<agent>.csv, checkpoints/<point>/seed<k>/<agent>.pt
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
from rich.progress import Progress
from rich.table import Table

from agents import BASELINES, LEARNERS, AgentPolicy, Baseline, LearnerConfig, evaluate, make_policy, train
from agents.training import progress_bar, write_csv
from experiments import marl_eval
from experiments.common import (
    Parser,
    add_env_arguments,
    add_learner_arguments,
    choose_backend,
    learner_config,
    make_env,
    positive_int,
    set_threads,
    usage_error,
)
from experiments.distributed import add_ray_arguments, ray_problem, run_on_ray, wants_ray
from experiments.plot import plot_study, summarise
from node_runtime.runtime.cli_options import builtin_or_import

AGENTS = (*LEARNERS, *BASELINES)  # every learner, then every baseline


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


@dataclass(frozen=True)
class SweepRun:
    """One cell of the grid: train ``agent`` (when it learns) at ``point`` with ``seed``, then evaluate it."""

    study: str
    point: Point
    agent: str
    seed: int
    settings: Settings
    config: LearnerConfig | None  # None for a baseline
    reward: str
    transport: str
    backend: str  # "emulator" or "array", as chosen for the point
    device: str
    threads: int
    congestion_price: float

    def __str__(self) -> str:
        return f"{self.point.label} seed {self.seed} {self.agent}"


@dataclass
class RunResult:
    rows: list[dict[str, Any]]  # evaluate's, one per evaluation episode
    timings: list[dict[str, Any]]
    trained_steps: int  # environment steps the policy learnt from (0 for a baseline)


def parser(study: str, description: str) -> argparse.ArgumentParser:
    p = Parser(prog=f"python -m experiments.{study}", description=description)
    p.add_argument("--quick", action="store_true",
                   help=f"a few minutes instead of hours: {QUICK.max_steps}-step episodes, {QUICK.train_episodes} "
                        f"training and {QUICK.eval_episodes} evaluation episodes, {QUICK.hidden} networks, fewer "
                        "sweep values (docs/agents.md)")
    p.add_argument("--out", type=Path, default=Path(f"runs/{study}"), help=f"output directory (default runs/{study})")
    p.add_argument("--agents", nargs="+", default=list(AGENTS), type=builtin_or_import(AGENTS, Baseline),
                   metavar="AGENT",
                   help=f"agents to run: {', '.join(AGENTS)} (the default: all), or a Baseline subclass of your own "
                        "as module:Class (docs/extending.md)")
    p.add_argument("--train-episodes", type=positive_int, default=None,
                   help="training episodes per learner and point (default 300, quick 10)")
    p.add_argument("--eval-episodes", type=positive_int, default=None,
                   help="evaluation episodes per agent and point (default 100, quick 5)")
    add_env_arguments(p, scenario=False)
    add_learner_arguments(p, seeds=True)
    add_ray_arguments(p)
    return p


def settings_from(args: argparse.Namespace) -> Settings:
    base = QUICK if args.quick else FULL
    changes = {k: v for k, v in (("max_steps", args.max_steps), ("train_episodes", args.train_episodes),
                                 ("eval_episodes", args.eval_episodes),
                                 ("hidden", tuple(args.hidden) if args.hidden else None)) if v is not None}
    return dataclasses.replace(base, **changes)


def run_study(study: str, points: Sequence[Point], x_key: str, xlabel: str, args: argparse.Namespace,
              xticklabels: dict[float, str] | None = None) -> list[dict[str, Any]]:
    """Train and evaluate every agent at every point for every seed, here or on Ray; write the CSVs, the
    marl-eval JSON and the figure; return the results rows."""
    prog = f"python -m experiments.{study}"
    settings = settings_from(args)
    learners = [a for a in args.agents if a in LEARNERS]
    if len(set(args.seeds)) < len(args.seeds):
        usage_error(prog, f"--seed {' '.join(map(str, args.seeds))}: a seed is given more than once")
    if args.overrides and not learners:
        usage_error(prog, f"--set {args.overrides[0]!r}: no learner among --agents")
    try:
        configs = {(a, seed): learner_config(a, seed=seed, reward=args.reward, hidden=settings.hidden,
                                             base=settings.learners.get(a),
                                             overrides=args.overrides, chosen=learners)
                   for seed in args.seeds for a in learners}
    except ValueError as e:
        usage_error(prog, str(e))
    if why := ray_problem(args):
        usage_error(prog, why)
    backends = choose_backend(prog, [(p.scenario, p.lam) for p in points], args.backend, args.transport)
    set_threads(args.threads)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps({
        "study": study, "quick": args.quick, "settings": dataclasses.asdict(settings), "seeds": args.seeds,
        "reward": args.reward, "congestion_price": args.congestion_price, "transport": args.transport,
        "backends": {p.label: backends[p.scenario, p.lam] for p in points}, "device": args.device,
        "points": [dataclasses.asdict(p) for p in points],
        "learners": {a: {k: v for k, v in dataclasses.asdict(configs[a, args.seeds[0]]).items() if k != "seed"}
                     for a in learners}}, indent=1))
    runs = [SweepRun(study, point, agent, seed, settings, configs.get((agent, seed)), args.reward, args.transport,
                     backends[point.scenario, point.lam], args.device, args.threads, args.congestion_price)
            for seed in args.seeds for point in points for agent in args.agents
            if agent in LEARNERS or seed == args.seeds[0]]
    if wants_ray(args):
        results = run_on_ray(run_one, runs, out, args)
    else:
        progress = progress_bar() if args.progress else None
        with progress or nullcontext():
            results = [run_one(run, out, progress) for run in runs]
    rows = [{"study": study, "scenario": run.point.scenario, "lambda": run.point.lam, x_key: run.point.x,
             "agent": run.agent, "train_seed": run.seed, **r} for run, result in zip(runs, results, strict=True)
            for r in result.rows]
    marl: dict[str, Any] = {}
    for run, result in zip(runs, results, strict=True):
        marl_eval.add_run(marl, run.point.label, run.agent, run.seed,
                          marl_eval.run_entry(result.rows, result.trained_steps))
    write_csv(out / "results.csv", rows)
    write_csv(out / "summary.csv", summarise(rows, x_key, args.agents))
    write_csv(out / "timings.csv", [t for result in results for t in result.timings])
    marl_eval.write(out / "marl_eval.json", marl)
    what = f"{settings.eval_episodes} evaluation episodes of {settings.max_steps} steps per point"
    if len(args.seeds) > 1:
        what += f" and each of {len(args.seeds)} training seeds"
    plot_study(rows, x_key, xlabel, args.agents, f"{study.upper()}: {what}, 95% confidence bands",
               out / f"{study}.png", xticklabels)
    console = Console()
    _print_summary(console, rows, x_key, args.agents)
    console.print(f"wrote {out / 'results.csv'}, {out / 'summary.csv'}, {out / 'marl_eval.json'} and "
                  f"{out / f'{study}.png'}")
    return rows


def run_one(run: SweepRun, out: Path, progress: Progress | None = None) -> RunResult:
    """One run of the grid, writing its training log and checkpoint under ``out``."""
    set_threads(run.threads)
    s = run.settings
    env = make_env(run.point.scenario, run.point.lam, s.max_steps, run.reward, run.transport, run.seed,
                   run.congestion_price, run.backend)
    timings = []
    trained_steps = 0
    try:
        start = time.perf_counter()
        policy: AgentPolicy
        if run.config is not None:
            policy = learner = LEARNERS[run.agent].for_env(env, run.config, run.device)
            where = Path(run.point.label) / f"seed{run.seed}"
            train(env, learner, s.train_episodes, seed=run.seed * s.train_episodes,
                  csv_path=out / "train" / where / f"{run.agent}.csv", progress=progress, label=f"{run} train")
            (out / "checkpoints" / where).mkdir(parents=True, exist_ok=True)
            learner.save(out / "checkpoints" / where / f"{run.agent}.pt")
            trained_steps = learner.env_steps
            timings.append(_timing(run, "train", s.train_episodes, start))
            start = time.perf_counter()
        else:
            policy = make_policy(run.agent, seed=run.seed)
        rows = evaluate(env, policy, s.eval_episodes, progress=progress, label=f"{run} eval")
        timings.append(_timing(run, "eval", s.eval_episodes, start))
    finally:
        env.close()
    return RunResult(rows, timings, trained_steps)


def _timing(run: SweepRun, phase: str, episodes: int, start: float) -> dict[str, Any]:
    return {"point": run.point.label, "seed": run.seed, "agent": run.agent, "phase": phase, "episodes": episodes,
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
