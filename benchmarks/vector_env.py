"""Aggregate agent-steps/s of K in-process simulations stepped together under TorchRL, against K.

    python benchmarks/vector_env.py --scenario aot2 --steps 300 [--no-info-numbers]

Rows, all measured in one run so that their ratios hold when the machine's speed drifts:
  - ``wrapper``: one ``PettingZooWrapper(ZenohEdgeEnv(observation="flat"))``, the reference (K = 1);
  - ``vector``: ``ZenohEdgeVectorEnv(num_envs=K)``, K simulations as one batch in this process;
  - ``vector x W``: TorchRL's ``ParallelEnv(W, ZenohEdgeVectorEnv(num_envs=K / W))``, W worker processes.
Every env steps with uniformly random allowed actions (read from the masks in the tensordict) and resets
when its episode ends. The load average is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import time
from functools import partial

import torch
from torchrl.envs import EnvBase, ParallelEnv, PettingZooWrapper

from env import ZenohEdgeEnv
from env.vector import ZenohEdgeVectorEnv
from orchestrator.version import version_line


def wrapper(scenario: str, max_steps: int, info_numbers: bool) -> PettingZooWrapper:
    env = ZenohEdgeEnv(scenario, transport="inproc", observation="flat", max_steps=max_steps,
                       info_numbers=info_numbers)
    return PettingZooWrapper(env, use_mask=True, categorical_actions=True, group_map={"agents": env.possible_agents})


def masked_random(td):
    mask = td["agents", "action_mask"]
    td["agents", "action"] = torch.multinomial(mask.flatten(0, -2).float(), 1).view(mask.shape[:-1])
    return td


def rate(env: EnvBase, steps: int) -> float:
    """Agent-steps per second over ``steps`` steps of every simulation (after a warm-up)."""
    env.set_seed(0)
    env.rollout(10, masked_random, break_when_any_done=False)  # start the workers, first reset
    start = time.perf_counter()
    td = env.rollout(steps, masked_random, break_when_any_done=False)
    elapsed = time.perf_counter() - start
    env.close()
    return td["agents", "action"].numel() / elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="aot2")
    p.add_argument("--steps", type=int, default=300, help="steps of every simulation per measurement (default 300)")
    p.add_argument("--max-steps", type=int, default=100, help="episode length: the run crosses resets (default 100)")
    p.add_argument("--k", type=int, nargs="+", default=[1, 2, 4, 8], help="numbers of simulations (default 1 2 4 8)")
    p.add_argument("--workers", type=int, default=2,
                   help="worker processes of the ParallelEnv rows, each with K / W simulations (default 2; 0: none)")
    p.add_argument("--no-info-numbers", dest="info_numbers", action="store_false",
                   help="no per-agent info numbers (ZenohEdgeEnv(info_numbers=False))")
    args = p.parse_args()
    torch.set_num_threads(1)
    print(f"{args.scenario}, {args.steps} steps per simulation, info numbers {'on' if args.info_numbers else 'off'}, "
          f"{os.cpu_count()} cores, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| env | K | agent-steps/s | ratio to wrapper | ratio to vector K=1 |\n| --- | ---: | ---: | ---: | ---: |")
    settings = (args.scenario, args.max_steps, args.info_numbers)
    vector = partial(ZenohEdgeVectorEnv, args.scenario, max_steps=args.max_steps, info_numbers=args.info_numbers)
    rows = [("wrapper", 1, partial(wrapper, *settings))]
    rows += [("vector", k, partial(vector, num_envs=k)) for k in args.k]
    if args.workers:
        w = args.workers
        rows += [(f"vector x {w}", k, partial(ParallelEnv, w, partial(vector, num_envs=k // w)))
                 for k in args.k if k >= w and k % w == 0]
    measured: dict[tuple[str, int], float] = {}
    for name, k, make in rows:
        measured[name, k] = rate(make(), args.steps)
        to_vector = measured[name, k] / measured[("vector", 1)] if ("vector", 1) in measured else None
        print(f"| {name} | {k} | {measured[name, k]:,.0f} | {measured[name, k] / measured['wrapper', 1]:.2f} | "
              f"{'–' if to_vector is None else f'{to_vector:.2f}'} |", flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; measured with {version_line()}")


if __name__ == "__main__":
    main()
