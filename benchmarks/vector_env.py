"""Aggregate agent-steps/s of K in-process simulations stepped together (TorchRL ParallelEnv), against K.

    python benchmarks/vector_env.py --scenario aot2 --steps 300 [--no-info-numbers]

K = 1 is a bare ``PettingZooWrapper`` in this process; K >= 2 is ``ParallelEnv(K, ...)``, one worker
process per simulation. Every env steps with uniformly random allowed actions (read from the masks in
the tensordict) and resets when its episode ends. All rows are measured in one run, so their ratios
hold when the machine's speed drifts; the load average is printed with them.
"""

from __future__ import annotations

import argparse
import os
import time
from functools import partial

import torch
from torchrl.envs import ParallelEnv, PettingZooWrapper

from env import ZenohEdgeEnv


def make(scenario: str, max_steps: int, info_numbers: bool = True) -> PettingZooWrapper:
    env = ZenohEdgeEnv(scenario, transport="inproc", observation="flat", max_steps=max_steps,
                       info_numbers=info_numbers)
    return PettingZooWrapper(env, use_mask=True, categorical_actions=True, group_map={"agents": env.possible_agents})


def masked_random(td):
    mask = td["agents", "action_mask"]
    td["agents", "action"] = torch.multinomial(mask.flatten(0, -2).float(), 1).view(mask.shape[:-1])
    return td


def rate(k: int, scenario: str, steps: int, max_steps: int, info_numbers: bool = True) -> tuple[float, int]:
    """Agent-steps per second over ``steps`` steps of every env (after a warm-up), and the agent count."""
    factory = partial(make, scenario, max_steps, info_numbers)
    env = factory() if k == 1 else ParallelEnv(k, factory)
    env.set_seed(0)
    env.rollout(10, masked_random, break_when_any_done=False)  # start the workers, first reset
    start = time.perf_counter()
    td = env.rollout(steps, masked_random, break_when_any_done=False)
    elapsed = time.perf_counter() - start
    n_agents = td["agents", "action"].shape[-1]
    env.close()
    return k * steps * n_agents / elapsed, n_agents


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="aot2")
    p.add_argument("--steps", type=int, default=300, help="steps of every env per measurement (default 300)")
    p.add_argument("--max-steps", type=int, default=100, help="episode length: the run crosses resets (default 100)")
    p.add_argument("--k", type=int, nargs="+", default=[1, 2, 4], help="numbers of simulations (default 1 2 4)")
    p.add_argument("--no-info-numbers", dest="info_numbers", action="store_false",
                   help="empty per-agent infos (ZenohEdgeEnv(info_numbers=False)): no info tensors each step")
    args = p.parse_args()
    torch.set_num_threads(1)
    print(f"{args.scenario}, {args.steps} steps per env, info numbers {'on' if args.info_numbers else 'off'}, "
          f"{os.cpu_count()} cores, "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| K | agents per env | agent-steps/s | env steps/s | ratio to K=1 |\n| ---: | ---: | ---: | ---: | ---: |")
    base = None
    for k in args.k:
        agent_steps, n = rate(k, args.scenario, args.steps, args.max_steps, args.info_numbers)
        base = base or agent_steps
        print(f"| {k} | {n} | {agent_steps:,.0f} | {agent_steps / n:,.0f} | {agent_steps / base:.2f} |", flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
