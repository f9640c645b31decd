"""Evaluate a baseline or a trained checkpoint over K episodes; print the metrics and write a CSV.

    python -m experiments.evaluate least_queue --scenario aot2 --episodes 10
    python -m experiments.evaluate runs/ddqn-aot2/ddqn.pt --scenario aot2 --episodes 10 --csv runs/ddqn-eval.csv
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path

from agents import BASELINES, evaluate, load_learner
from agents.training import progress_bar, write_csv
from experiments.common import add_env_arguments, make_env, set_threads
from experiments.plot import mean_ci


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m experiments.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("policy", help=f"a baseline ({', '.join(BASELINES)}) or a checkpoint file (.pt)")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of the baselines' random choices (default 0)")
    p.add_argument("--csv", type=Path, default=None, help="write one row per episode here")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda, for checkpoints")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    add_env_arguments(p)
    args = p.parse_args(argv)
    set_threads(1)
    if args.policy in BASELINES:
        policy = BASELINES[args.policy](args.seed)
    elif Path(args.policy).is_file():
        policy = load_learner(args.policy, args.device)
    else:
        p.error(f"{args.policy!r} is neither a baseline nor a checkpoint file")
    env = make_env(args.scenario, args.lam, args.max_steps, args.reward, args.transport, args.seed)
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        rows = evaluate(env, policy, args.episodes, progress=progress, label=f"evaluate {policy.name}")
    env.close()
    for metric in ("response_time_mean", "completion_ratio", "penalised_response_time", "dropped",
                   "overloaded_node_ticks", "completed", "return"):
        mean, ci = mean_ci([r[metric] for r in rows])
        print(f"{metric:>22}: {mean:10.2f} ± {ci:.2f} (95% CI, {len(rows)} episodes)")
    if args.csv:
        write_csv(args.csv, rows)


if __name__ == "__main__":
    main()
