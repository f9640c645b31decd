"""Agent-steps/s of the array backend against K, beside the in-process emulator and envs, in one run; its memory
and set-up against K and against the node count.

    python benchmarks/array_env.py                                   # aot2 and aot4, K = 1 ... 4096; N = 100 ... 1000
    python benchmarks/array_env.py --scenarios aot2 --ks 1 16 256 1024 --nodes 1000 --ticks 200

An agent-step is one controller's tick: ticks x controllers x K over the wall time of the ticks. Rows, per
scenario, measured in one run so that their ratios hold when the machine's speed drifts:
  - ``inproc``: ``Simulation.inproc`` with the node-side policy (the emulator's fastest path, K = 1);
  - ``ZenohEdgeEnv``: the in-process env's ``step()`` alone, random allowed actions (``env_steps.py``'s);
  - ``torchrl env``: ``PettingZooWrapper(ZenohEdgeEnv(observation="flat"))`` under TorchRL, uniformly random
    allowed actions (``vector_env.py``'s reference row), and ``vector K``: ``ZenohEdgeVectorEnv(num_envs=K)``;
  - ``array K``: ``ArraySim`` with K copies (seeds 1..K), the node-side policy, each K in a fresh process: its
    agent-steps per wall second and per CPU second of that process (the machine is shared: the CPU rate is what
    one core gives it), its set-up (the arrivals drawn by the model's clients, per copy), the bytes of its
    arrays at the end, and how far the process's peak resident memory rose above what it held before
    (/proc/self/status, the peak reset first), the set-up's transient lists included.
The array rows run node-side policies, not an agent: they measure the simulation, not an RL loop. Then the
same child measurements for random-geometric scenarios of N nodes (``scale.py``'s) at ``--node-k`` copies.
The load average is printed with each table.

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
import json
import os
import subprocess
import sys
import time
from functools import partial

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


def env_rates(name: str, steps: int, vector_k: int) -> dict[str, float]:
    """Agent-steps/s of the in-process env's step(), of it under TorchRL, and of the vector env with
    ``vector_k`` simulations."""
    import torch
    from env_steps import random_steps
    from vector_env import rate, wrapper

    from env import ZenohEdgeEnv
    from env.vector import ZenohEdgeVectorEnv

    torch.set_num_threads(1)
    env = ZenohEdgeEnv(name, transport="inproc", max_steps=10**9)
    try:
        run = random_steps(env)
        run(20)  # warm-up
        plain = run(steps) * len(env.possible_agents)
    finally:
        env.close()
    return {"ZenohEdgeEnv 1": plain, "torchrl env 1": rate(wrapper(name, 100, True), steps),
            f"vector {vector_k}": rate(ZenohEdgeVectorEnv(name, num_envs=vector_k, max_steps=100), steps)}


def status_mib(field: str) -> float:
    """A memory figure of this process from /proc/self/status (VmRSS: resident now; VmHWM: its peak)."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(field + ":")) / 1024


def reset_peak() -> None:
    """Start the peak resident memory (VmHWM) afresh from what is resident now (Linux >= 4.0)."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def array_rate(sc, policy: str | None, ticks: int, k: int) -> dict[str, float]:
    """One ArraySim run of ``k`` copies: agent-steps per wall and per CPU second, set-up seconds, MiB of its
    arrays, and MiB the process's peak resident memory rose above what it held before."""
    reset_peak()
    before = status_mib("VmRSS")
    start = time.perf_counter()
    sim = ArraySim(sc, k, policy=policy)
    sim.reset(list(range(1, k + 1)), ticks)
    setup = time.perf_counter() - start
    arrays = sum(v.nbytes for v in vars(sim).values() if isinstance(v, np.ndarray)) / 2**20
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(ticks):
        sim.step()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    steps = ticks * len(sc.controllers) * k
    return {"rate": steps / wall, "cpu_rate": steps / cpu, "setup_s": setup, "arrays_mib": arrays,
            "peak_mib": status_mib("VmHWM") - before}


def in_child(*args: str) -> dict[str, float]:
    """``array_rate`` in a fresh process (this script with ``--child``), so that its peak memory is its own."""
    out = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"array_env.py --child {' '.join(args)} failed:\n{out.stderr}")
    return json.loads(out.stdout.splitlines()[-1])


def child(args: list[str]) -> None:
    kind, name, policy, ticks, k = args
    if kind == "nodes":
        from scale import scenario
        sc = scenario(int(name))[1]
    else:
        sc = load_scenario(name)
    print(json.dumps(array_rate(sc, policy or None, int(ticks), int(k))))


def load() -> str:
    return f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores"


ROW = "| {} | {} | {:,.0f} | {} | {} | {} | {} | {} |"


def array_row(name: str, k: int | str, r: dict[str, float], reference: float | None) -> str:
    ratio = "" if reference is None else f"{r['rate'] / reference:,.1f}"
    return ROW.format(name, k, r["rate"], f"{r['cpu_rate']:,.0f}", ratio, f"{r['setup_s']:.2f}",
                      f"{r['arrays_mib']:.1f}", f"{r['peak_mib']:.0f}")


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
    if sys.argv[1:2] == ["--child"]:
        child(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["aot2", "aot4"])
    ap.add_argument("--policy", default="least_queue")
    ap.add_argument("--ticks", type=int, default=200, help="ticks of every run (default 200)")
    ap.add_argument("--ks", type=int, nargs="+", default=[1, 4, 16, 64, 256, 1024, 4096])
    ap.add_argument("--vector-k", type=int, default=4, help="simulations of the vector env's row (default 4)")
    ap.add_argument("--no-envs", dest="envs", action="store_false", help="leave out the env rows (no torch)")
    ap.add_argument("--nodes", type=int, nargs="*", default=[100, 300, 1000],
                    help="node counts of the random-geometric scenarios (default 100 300 1000; none: skip)")
    ap.add_argument("--node-k", type=int, default=16, help="copies of each of those (default 16)")
    ap.add_argument("--env-steps", type=int, default=0, help="also the envs with backend='array', this many steps")
    ap.add_argument("--env-max-steps", type=int, default=100)
    ap.add_argument("--env-ks", type=int, nargs="+", default=[64, 256, 1024, 4096])
    ap.add_argument("--env-scenarios", nargs="+", default=["aot2", "aot4"])
    ap.add_argument("--env-inproc-k", type=int, default=4)
    args = ap.parse_args()
    print(version_line())
    header = ("| backend | K | agent-steps/s | per CPU s | x inproc | set-up s | arrays MiB | peak MiB |\n"
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in args.scenarios:
        print(f"\n{name}, policy {args.policy}, {args.ticks} ticks, {load()}\n{header}")
        reference = inproc_rate(name, args.policy, args.ticks)
        print(ROW.format("inproc", 1, reference, "", "1.0", "", "", ""), flush=True)
        if args.envs:
            for row, rate in env_rates(name, args.ticks, args.vector_k).items():
                kind, _, k = row.rpartition(" ")
                print(ROW.format(kind, k, rate, "", f"{rate / reference:.2f}", "", "", ""), flush=True)
        for k in args.ks:
            print(array_row("array", k, in_child("scenario", name, args.policy, str(args.ticks), str(k)), reference),
                  flush=True)
        print(f"after: {load()}")
    if args.env_steps:
        env_table(args)
    if args.nodes:
        print(f"\nrandom-geometric scenarios of N nodes (benchmarks/scale.py), their own policy, K = {args.node_k}, "
              f"{args.ticks} ticks, {load()}\n{header.replace('backend', 'nodes')}")
        run = partial(in_child, "nodes")
        for n in args.nodes:
            print(array_row(str(n), args.node_k, run(str(n), "", str(args.ticks), str(args.node_k)), None), flush=True)
        print(f"after: {load()}")


if __name__ == "__main__":
    main()
