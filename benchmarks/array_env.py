"""Agent-steps/s of the array backend against K, beside the in-process emulator, in one run.

    python benchmarks/array_env.py --scenario aot2 --ticks 300 --ks 1 16 256 1024 [--policy least_queue]

An agent-step is one controller's tick: ticks x controllers x K over the wall time of the ticks. Rows:
  - ``inproc``: ``Simulation.inproc`` with the node-side policy (the emulator's fastest path, K = 1);
  - ``array K``: ``ArraySim`` with K copies (seeds 1..K), the same policy; its set-up (the arrivals drawn by
    the model's clients, per copy, in Python) is reported apart, as is the memory of its arrays.
Both run node-side policies, not an agent: this measures the simulation, not an RL loop. Numbers from a
shared machine are noisy; the load average is printed with the table.

    python benchmarks/array_env.py --ks 1 --env-steps 50 --env-max-steps 100

``--env-steps N`` adds the environments on each of ``--env-scenarios`` (aot2 and aot4), every agent driven with
uniformly random allowed actions (an agent-step is one agent's step: steps x agents x K over the wall time of
the steps, the actions' drawing included; episodes of ``--env-max-steps``): ``ZenohEdgeEnv`` in-process and
with ``backend="array"`` (flat observations, crossing resets), and ``ZenohEdgeVectorEnv`` with K in-process
simulations (``--env-inproc-k``), with ``backend="array"`` on its per-copy path at that K, and on its batched
path at each K of ``--env-ks`` (64 ... 4096). A vector env's steps are timed after its first reset, which is
reported apart ("reset s": drawing every copy's arrivals, in Python, once an episode); with N above the episode
length they cross resets and include them.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from node_runtime.model.array import ArraySim
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from orchestrator.version import version_line


def inproc_rate(name: str, policy: str, ticks: int) -> float:
    sc = load_scenario(name)
    with Simulation.inproc(sc) as sim:
        start = time.perf_counter()
        sim.run(ticks, seed=1, policy=policy)
        wall = time.perf_counter() - start
    return ticks * len(sc.controllers) / wall


def array_rate(name: str, policy: str, ticks: int, k: int) -> tuple[float, float, float]:
    """(agent-steps/s, set-up seconds, MiB of its arrays)."""
    sc = load_scenario(name)
    sim = ArraySim(sc, k, policy=policy)
    start = time.perf_counter()
    sim.reset(list(range(1, k + 1)), ticks)
    setup = time.perf_counter() - start
    mib = sum(v.nbytes for v in vars(sim).values() if isinstance(v, np.ndarray)) / 2**20
    start = time.perf_counter()
    for _ in range(ticks):
        sim.step()
    wall = time.perf_counter() - start
    return ticks * len(sc.controllers) * k / wall, setup, mib


# ----- the environments -----

def env_rate(backend: str, name: str, steps: int, max_steps: int) -> float:
    """Agent-steps/s of one ``ZenohEdgeEnv`` (flat observations) with random allowed actions."""
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv(name, backend=backend, transport="inproc", observation="flat", max_steps=max_steps)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    start = time.perf_counter()
    for _ in range(steps):
        obs, *_ = env.step({a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in obs.items()})
        if not env.agents:
            obs, _ = env.reset()
    wall = time.perf_counter() - start
    env.close()
    return steps * len(env.possible_agents) / wall


def vector_rate(backend: str, name: str, steps: int, max_steps: int, k: int,
                batched: bool | None = None) -> tuple[float, float, str]:
    """(agent-steps/s, reset seconds, path) of ``ZenohEdgeVectorEnv`` with K simulations and random allowed actions:
    ``steps`` steps after a reset, timed apart from it (a reset draws every copy's arrivals, per copy in Python);
    with ``steps`` > ``max_steps`` the steps cross episode ends and include their resets."""
    import torch

    from env.vector import GROUP, ZenohEdgeVectorEnv

    env = ZenohEdgeVectorEnv(name, num_envs=k, seed=1, backend=backend, max_steps=max_steps,
                             **({} if backend == "emulator" else {"batched": batched}))
    start = time.perf_counter()
    td = env.reset()
    reset = time.perf_counter() - start
    generator = torch.Generator().manual_seed(0)
    start = time.perf_counter()
    for _ in range(steps):
        mask = td[GROUP, "action_mask"]
        td[GROUP, "action"] = (torch.rand(mask.shape, generator=generator) * mask).argmax(-1)  # uniform, allowed
        _, td = env.step_and_maybe_reset(td)
    wall = time.perf_counter() - start
    env.close()
    return steps * k * len(env.agent_names) / wall, reset, env.path


def env_table(args: argparse.Namespace) -> None:
    print(f"\nenvironments: {args.env_steps} steps, episodes of {args.env_max_steps}, random allowed actions, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'scenario':>8} {'env':>28} {'agent-steps/s':>14} {'reset s':>8}")
    for name in args.env_scenarios:
        run = (name, args.env_steps, args.env_max_steps)
        inproc_k = args.env_inproc_k
        rows = [("ZenohEdgeEnv inproc", env_rate, ("emulator", *run)),
                ("ZenohEdgeEnv array", env_rate, ("array", *run)),
                (f"vector inproc {inproc_k}", vector_rate, ("emulator", *run, inproc_k)),
                (f"vector array {inproc_k}", vector_rate, ("array", *run, inproc_k, False))]
        rows += [(f"vector array {k}", vector_rate, ("array", *run, k)) for k in args.env_ks]
        for label, measure, given in rows:
            result = measure(*given)
            rate, reset, path = result if isinstance(result, tuple) else (result, None, "")
            label = f"{label} {path}".strip()
            print(f"{name:>8} {label:>28} {rate:>14,.0f} {'' if reset is None else f'{reset:.2f}':>8}", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="aot2")
    ap.add_argument("--policy", default="least_queue")
    ap.add_argument("--ticks", type=int, default=300)
    ap.add_argument("--ks", type=int, nargs="+", default=[1, 16, 256, 1024])
    ap.add_argument("--env-steps", type=int, default=0, help="also measure the environments, this many steps (0: not)")
    ap.add_argument("--env-max-steps", type=int, default=100)
    ap.add_argument("--env-ks", type=int, nargs="+", default=[64, 256, 1024, 4096])
    ap.add_argument("--env-scenarios", nargs="+", default=["aot2", "aot4"])
    ap.add_argument("--env-inproc-k", type=int, default=4)
    args = ap.parse_args()
    print(version_line())
    print(f"{args.scenario}, policy {args.policy}, {args.ticks} ticks, load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores (a shared machine: noisy)")
    print(f"{'backend':>12} {'agent-steps/s':>14} {'set-up s':>9} {'MiB':>8}")
    print(f"{'inproc':>12} {inproc_rate(args.scenario, args.policy, args.ticks):>14,.0f}")
    for k in args.ks:
        rate, setup, mib = array_rate(args.scenario, args.policy, args.ticks, k)
        print(f"{'array ' + str(k):>12} {rate:>14,.0f} {setup:>9.2f} {mib:>8.1f}", flush=True)
    if args.env_steps:
        env_table(args)


if __name__ == "__main__":
    main()
