"""Train one learning agent and save its checkpoint and per-episode log.

    python -m experiments.train ddqn --scenario aot2 --lam 0.17 --episodes 50 --out runs/ddqn-aot2
    python -m experiments.train ppo --episodes 100 --set ppo.centralised_critic=true --out runs/mappo
    python -m experiments.train ppo --scenario aot3_wired --lam 0.2 --max-steps 400 --episodes 100
    python -m experiments.train ppo --scenario aot2 --backend emulator   # the node code, not the array backend
    python -m experiments.train ppo --scenario aot2 --episodes 100 --envs 25   # 25 episodes at a time (vector_ppo)

Training runs on the array backend where it models the scenario (``--backend auto``, the default: the same
results as the node code, step for step), else on the emulator; one line on stderr says which, and
config.json records it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path

from agents import LEARNERS, train, vector_ppo
from agents.training import progress_bar
from agents.vector_ppo import Regime
from experiments.common import (
    Parser,
    add_env_arguments,
    add_learner_arguments,
    choose_backend,
    learner_config,
    make_env,
    positive_int,
    set_threads,
)

# the reward PPO beats the baselines with; DDQN and A2C keep the paper's, which their reward_scale was tuned on
DEFAULT_REWARD = {"ppo": "marginal"}


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.train", description=__doc__.splitlines()[0])
    p.add_argument("algo", choices=list(LEARNERS))
    p.add_argument("--episodes", type=positive_int, default=50, help="training episodes (default 50)")
    p.add_argument("--out", type=Path, default=None, help="output directory (default runs/<algo>-<scenario>)")
    per_learner = ", ".join(f"{reward} for {algo}" for algo, reward in DEFAULT_REWARD.items())
    add_env_arguments(p, reward=None, reward_default_help=f"{per_learner}, paper for the others; on marginal, the "
                      "built-in learners learn from each decision's own credit (credit=task, gamma=0; --set "
                      "credit=step for the steps' rewards; docs/agents.md)")
    add_learner_arguments(p)
    p.add_argument("--envs", type=positive_int, default=1,
                   help="ppo only: episodes run at once, K copies on the array backend (agents.vector_ppo: the same "
                        "learner, fed in arrays; --episodes a multiple of K); default 1, the serial loop")
    args = p.parse_args(argv)
    args.reward = args.reward or DEFAULT_REWARD.get(args.algo, "paper")
    try:
        config = learner_config(args.algo, seed=args.seed, reward=args.reward, hidden=args.hidden,
                                overrides=args.overrides)
    except ValueError as e:
        p.error(str(e))
    backend = choose_backend(p.prog, [(args.scenario, args.lam)], args.backend, args.transport)[args.scenario, args.lam]
    if args.envs > 1 and (args.algo != "ppo" or backend != "array" or args.episodes % args.envs):
        p.error(f"--envs {args.envs} trains ppo on the array backend, --episodes a multiple of it (here {args.algo} "
                f"on the {backend} backend, {args.episodes} episodes)")
    set_threads(args.threads)
    out = args.out or Path("runs") / f"{args.algo}-{Path(args.scenario).stem}"
    out.mkdir(parents=True, exist_ok=True)
    env = make_env(args.scenario, args.lam, args.max_steps, args.reward, args.transport, args.seed,
                   args.congestion_price, backend)
    learner = LEARNERS[args.algo].for_env(env, config, args.device)
    (out / "config.json").write_text(json.dumps({"algo": args.algo, "scenario": args.scenario, "lambda": args.lam,
                                                 "backend": backend,
                                                 "max_steps": env.max_steps, "reward": args.reward,
                                                 "congestion_price": env.reward_settings.congestion_price,
                                                 "episodes": args.episodes, "envs": args.envs,
                                                 "config": dataclasses.asdict(config)},
                                                indent=1))
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        if args.envs == 1:
            train(env, learner, args.episodes, seed=args.seed * args.episodes, csv_path=out / "train.csv",
                  progress=progress, label=f"train {args.algo}")
        else:
            try:
                copies = Regime(learner, make_env(args.scenario, args.lam, args.max_steps, args.reward, args.transport,
                                                  args.seed, args.congestion_price, backend, flat=True), args.envs)
            except ValueError as e:
                p.error(str(e).splitlines()[0])
            vector_ppo.train(copies, learner, args.episodes, seed=args.seed * args.episodes,
                             csv_path=out / "train.csv", progress=progress, label=f"train {args.algo} ×{args.envs}")
            copies.close()
    env.close()
    learner.save(out / f"{args.algo}.pt")
    print(f"wrote {out / 'train.csv'} and {out / f'{args.algo}.pt'}")


if __name__ == "__main__":
    main()
