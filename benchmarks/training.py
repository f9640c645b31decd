"""Training steps/s of the generalist's PPO: the serial loop against the vectorised loop (``agents.vector_ppo``) at
several K, on the same regime with the same learner settings, measured in one run.

    python benchmarks/training.py                                  # aot2, 400-step episodes, K = 16 and 64
    python benchmarks/training.py --scenario aot3 --episodes 2 --ks 8 32 128 --csv runs/training-speed.csv

A training step is one step of one copy (every agent acts); its rate includes acting, the environment and the
PPO updates. Each row trains a fresh learner with the generalist's default settings (``experiments.generalist``:
marginal reward, credit per task, ``--slots`` neighbour slots): ``serial`` runs ``--episodes`` episodes one after
the other on the array backend (``agents.training.run_episode``, what ``--envs 1`` does); ``vector K`` runs K
copies of one episode at once, ``--rounds`` times. ``update s`` is the time spent in ``PPO.update_group``, the
rest being acting and the simulation. The load average is printed with the table: on a shared machine compare
ratios within one run, not rates across runs.
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

import torch

from agents.training import run_episode
from agents.vector_ppo import Regime, VectorPPO
from experiments.common import learner_config
from experiments.generalist import REWARD, SLOTS, flat_env, generalist, regime_env
from experiments.protocol import EPISODES
from experiments.suite import SuiteRegime


def timed_updates(learner) -> list[float]:
    """Wrap the learner's update so that its wall time is added up; returns the running total (one cell)."""
    spent = [0.0]
    update = learner.update_group

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return update(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - start

    learner.update_group = timed
    return spent


def measure(scenario: str, k: int | None, episodes: int, max_steps: int, slots: int) -> dict[str, float | str]:
    """One row: ``k`` None for the serial loop, else the vectorised loop of K copies."""
    config = learner_config("ppo", seed=0, reward=REWARD, base={"shared": True, "agent_id": False})
    learner = generalist(slots, config)
    spent = timed_updates(learner)
    regime = SuiteRegime(Path(scenario).stem, Path(scenario), None, None)
    env = flat_env(regime, slots, max_steps, None)
    copies = 1 if k is None else k
    learner.start_training(episodes * copies * env.max_steps)
    seeds = EPISODES["train"].seeds(episodes * copies)
    start = time.perf_counter()
    if k is None:
        serial = regime_env(regime, slots, max_steps, None, backend="array")
        for seed in seeds:
            run_episode(serial, learner, seed, learner)
        serial.close()
    else:
        trainer, regimes = VectorPPO(learner), [Regime(learner, env, k)]
        for r in range(episodes):
            trainer.episode(regimes, [seeds[r * k:(r + 1) * k]])
    wall = time.perf_counter() - start
    steps = episodes * copies * env.max_steps
    return {"loop": "serial" if k is None else f"vector {k}", "episodes": episodes * copies, "steps": steps,
            "wall_s": round(wall, 2), "steps_per_s": round(steps / wall, 1), "update_s": round(spent[0], 2),
            "updates": learner.updates}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="aot2", help="a bundled scenario or a file (default aot2)")
    p.add_argument("--episodes", type=int, default=3,
                   help="serial episodes, and rounds of K episodes for each K (default 3)")
    p.add_argument("--ks", type=int, nargs="+", default=[16, 64], help="copies of the vectorised loop (16 64)")
    p.add_argument("--max-steps", type=int, default=400, help="steps per episode (default 400)")
    p.add_argument("--slots", type=int, default=SLOTS, help=f"neighbour slots (default {SLOTS}, the generalist's)")
    p.add_argument("--csv", type=Path, default=None, help="write the rows here too")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = [measure(args.scenario, k, args.episodes, args.max_steps, args.slots) for k in (None, *args.ks)]
    base = rows[0]["steps_per_s"]
    print(f"{args.scenario}, {args.max_steps}-step episodes, load average {os.getloadavg()[0]:.2f}")
    print(f"{'loop':<12}{'episodes':>9}{'wall s':>9}{'steps/s':>10}{'x serial':>10}{'update s':>10}{'updates':>9}")
    for r in rows:
        print(f"{r['loop']:<12}{r['episodes']:>9}{r['wall_s']:>9}{r['steps_per_s']:>10}"
              f"{r['steps_per_s'] / base:>10.2f}{r['update_s']:>10}{r['updates']:>9}")
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
