"""Evaluate a baseline or a trained checkpoint over K episodes; print the metrics and write a CSV.

    python -m experiments.evaluate least_queue --scenario aot2 --episodes 10
    python -m experiments.evaluate runs/ddqn-aot2/ddqn.pt --scenario aot2 --episodes 10 --csv runs/ddqn-eval.csv
    python -m experiments.evaluate greedy --scenario aot2 --episodes 10 --marl-eval runs/marl_eval.json
    python -m experiments.evaluate mylab.rules:ShortQueues --scenario aot2   # a Baseline subclass of your own
    python -m experiments.evaluate runs/ddqn-aot2/ddqn.pt --episodes 100 --ray   # one Ray task per episode
    python -m experiments.evaluate greedy --scenario runs/suites/test/test-000-ring.yaml --split test --csv runs/g.csv
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents import BASELINES, AgentPolicy, Learner, evaluate, load_learner, make_policy
from agents.training import progress_bar, write_csv
from experiments import marl_eval, raw
from experiments.common import (
    EVAL_BACKEND,
    Parser,
    add_env_arguments,
    choose_backend,
    make_env,
    positive_int,
    seed_int,
    set_threads,
)
from experiments.distributed import add_ray_arguments, ray_problem, run_on_ray, wants_ray
from experiments.plot import mean_ci
from experiments.protocol import EPISODES, SPLITS
from node_runtime.model.plugins import PluginError, is_import_path


@dataclass(frozen=True)
class Episode:
    """One evaluation episode as a Ray task: the policy travels as a baseline's name or a checkpoint's bytes."""

    k: int  # the episode's index: its seed is first + k
    first: int  # the first episode seed
    baseline: str | None  # a built-in's name or a user's import path
    checkpoint: bytes | None
    seed: int
    device: str
    scenario: str
    lam: float
    max_steps: int | None
    reward: str
    transport: str
    congestion_price: float
    backend: str

    def __str__(self) -> str:
        return f"episode {self.k}"


def run_episode(job: Episode, scratch: Path) -> dict[str, Any]:
    set_threads(1)
    policy: AgentPolicy
    if job.checkpoint is None:
        policy = make_policy(job.baseline, seed=job.seed)
    else:
        (scratch / "policy.pt").write_bytes(job.checkpoint)
        policy = load_learner(scratch / "policy.pt", job.device)
        (scratch / "policy.pt").unlink()  # not an output
    env = make_env(job.scenario, job.lam, job.max_steps, job.reward, job.transport, job.seed, job.congestion_price,
                   job.backend)
    try:
        (row,) = evaluate(env, policy, 1, seed=job.first + job.k)
    finally:
        env.close()
    return {**row, "episode": job.k}


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("policy", help=f"a baseline ({', '.join(BASELINES)}), a Baseline subclass of your own as "
                                  "module:Class (docs/extending.md), or a checkpoint file (.pt)")
    p.add_argument("--episodes", type=positive_int, default=10, help="evaluation episodes (default 10)")
    p.add_argument("--split", choices=SPLITS, default="validation",
                   help="the seed set of the episodes (default validation: seeds 100000, 100001, ...)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the baselines' random choices (default 0)")
    p.add_argument("--csv", type=Path, default=None,
                   help="write one row per episode here (experiments.raw's columns, then the episode's others)")
    p.add_argument("--marl-eval", type=Path, default=None, metavar="JSON",
                   help="add the episodes to this marl-eval JSON file (created if missing; docs/agents.md)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda, for checkpoints")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    add_env_arguments(p, backend=EVAL_BACKEND)
    add_ray_arguments(p)
    args = p.parse_args(argv)
    set_threads(1)
    policy: AgentPolicy
    checkpoint = args.policy not in BASELINES and Path(args.policy).is_file()  # a file wins over an import path
    if checkpoint:
        try:
            policy = load_learner(args.policy, args.device)
        except (OSError, RuntimeError, ValueError, KeyError, pickle.UnpicklingError) as e:
            p.error(f"{args.policy}: not a checkpoint of this project's learners ({str(e).splitlines()[0]})")
    elif args.policy in BASELINES or is_import_path(args.policy):
        try:
            policy = make_policy(args.policy, seed=args.seed)
        except PluginError as e:
            p.error(f"{args.policy}: {e}")
    else:
        p.error(f"{args.policy!r} is neither a baseline ({', '.join(BASELINES)}), an import path module:Class, "
                "nor a checkpoint file")
    if why := ray_problem(args):
        p.error(why)
    backend = choose_backend(p.prog, [(args.scenario, args.lam)], args.backend, args.transport)[args.scenario, args.lam]
    first = EPISODES[args.split].seeds(args.episodes)[0]
    if wants_ray(args):
        weights = Path(args.policy).read_bytes() if checkpoint else None
        jobs = [Episode(k, first, None if checkpoint else args.policy, weights, args.seed, args.device,
                        args.scenario, args.lam, args.max_steps, args.reward, args.transport, args.congestion_price,
                        backend)
                for k in range(args.episodes)]
        rows = run_on_ray(run_episode, jobs, Path.cwd(), args)
    else:
        env = make_env(args.scenario, args.lam, args.max_steps, args.reward, args.transport, args.seed,
                       args.congestion_price, backend)
        progress = progress_bar() if args.progress else None
        with progress or nullcontext():
            rows = evaluate(env, policy, args.episodes, seed=first, progress=progress,
                            label=f"evaluate {policy.name}")
        env.close()
    # a checkpoint's run is its training seed; a baseline's, the seed of its random choices
    seed, trained = (policy.config.seed, policy.env_steps) if isinstance(policy, Learner) else (args.seed, 0)
    regime = Path(args.scenario).stem if args.lam is None else f"{Path(args.scenario).stem}-lam{args.lam:g}"
    rows = [raw.row(policy.name, seed if isinstance(policy, Learner) else None, args.scenario, regime, r,
                    {"backend": backend}) for r in rows]
    for metric in ("response_time_mean", "completion_ratio", "penalised_response_time", "dropped",
                   "overloaded_node_ticks", "completed", "return"):
        mean, ci = mean_ci([r[metric] for r in rows])
        print(f"{metric:>22}: {mean:10.2f} ± {ci:.2f} (95% CI, {len(rows)} episodes)")
    if args.csv:
        write_csv(args.csv, rows)
    if args.marl_eval:
        data: dict = {}
        task_name = args.scenario if args.lam is None else f"{args.scenario}-lam{args.lam:g}"
        marl_eval.add_run(data, task_name, policy.name, seed,
                          marl_eval.run_entry(rows, trained))
        marl_eval.write(args.marl_eval, data, merge=True)


if __name__ == "__main__":
    main()
