"""Golden master: the digests of a fixed set of runs, so that a refactor can prove it changed nothing.

Every case is a run of a bundled scenario (a launch with node-side policies, or an environment episode
driven by seeded random actions). Its outputs are reduced to SHA-256 digests: the model's part of
``summary.json``, ``ticks.csv`` and ``nodes.csv`` for a launch; every observation, reward, termination,
truncation and info for an environment episode. ``tests/golden.json`` holds the expected digests, with a
few totals beside them so that a reviewer sees what an intended change moved.

    python -m tests.golden                  # check every case (about a minute on 2 cores)
    python -m tests.golden --quick          # only the cases CI checks (tests/test_golden.py)
    python -m tests.golden --update         # an intended change: rewrite golden.json, review its diff, commit

docs/contributing.md says when to update, and how to review the change.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

GOLDEN = Path(__file__).with_name("golden.json")


@dataclass(frozen=True)
class Case:
    """One run. ``env`` runs a ZenohEdgeEnv episode of ``steps`` steps; otherwise a launch of ``steps`` ticks."""

    scenario: str
    steps: int
    seed: int = 1
    policy: str | None = None  # node-side policy of a launch (None: the scenario's own)
    layout: str | None = None  # in-process layouts give the same results; a few cases prove it stays so
    env: bool = False
    reward: str | None = None
    observation: str | None = None  # "flat", or None for the Dict observation
    quick: bool = False  # part of the set CI checks

    @property
    def name(self) -> str:
        parts = [self.scenario.replace("/", "."), "env" if self.env else "launch", f"{self.steps}", f"s{self.seed}"]
        parts += [p for p in (self.policy, self.layout, self.reward, self.observation) if p]
        return "-".join(parts)


def _cases() -> list[Case]:
    from topologies import bundled_scenarios

    quick = [
        Case("aot1", 300, seed=3, policy="least_queue", quick=True),
        Case("aot2", 300, seed=7, policy="random", quick=True),
        Case("aot2", 300, seed=7, policy="random", layout="per-node", quick=True),
        Case("aot3_compute", 200, seed=2, policy="greedy", quick=True),
        Case("aot4_urgent", 200, seed=5, policy="round_robin", quick=True),
        Case("aot2_reference", 300, seed=4, policy="random", quick=True),
        Case("examples/failures", 200, seed=1, quick=True),
        Case("examples/trace", 200, seed=1, quick=True),
        Case("examples/zigzag_workload", 200, seed=9, policy="least_queue", quick=True),
        Case("examples/n_tier_cloud", 200, seed=2, policy="random", quick=True),
        Case("aot2", 120, seed=11, env=True, reward="paper", quick=True),
        Case("aot1_compute", 120, seed=12, env=True, reward="marginal", observation="flat", quick=True),
        Case("aot2_reference", 120, seed=13, env=True, reward="reference", quick=True),
    ]
    full = [Case(name, 1000, seed=1, policy=policy)
            for name in bundled_scenarios() if not _measures(name) for policy in (None, "random", "least_queue")]
    full += [Case("aot2", 1000, seed=1, policy="random", layout=layout) for layout in ("per-node", "groups:3")]
    full += [Case(name, 300, seed=21, env=True, reward=reward)
             for name in ("aot1", "aot3_compute", "aot2_urgent")
             for reward in ("paper", "sparse", "team", "score", "team_score", "marginal")]
    full += [Case("aot4", 300, seed=22, env=True, reward="marginal", observation="flat")]
    return quick + full


def _measures(name: str) -> bool:
    """Whether a bundled scenario's tasks run payloads: it measures real CPU times, so no run of it repeats
    another and it has no digest here (tests/test_payload.py replays recorded runs of it instead)."""
    import yaml

    from topologies import scenario_path

    data = yaml.safe_load(scenario_path(name).read_text()) or {}
    return any("payload" in task for task in (data.get("workload") or {}).get("tasks") or [])


CASES = _cases()


# ----- digests -----

def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:20]


def _canonical(obj: Any) -> Any:
    """Numbers, strings, lists and dicts, with arrays as (dtype, shape, hash of bytes): hashable as JSON."""
    if isinstance(obj, np.ndarray):
        return [str(obj.dtype), list(obj.shape), _sha(np.ascontiguousarray(obj).tobytes())]
    if isinstance(obj, np.generic):
        return _canonical(obj.item())
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, float):
        return repr(obj)  # every bit of the float, nan included
    return obj


def _digest(obj: Any) -> str:
    return _sha(json.dumps(_canonical(obj), sort_keys=True, separators=(",", ":")).encode())


def _model_part(summary: dict[str, Any]) -> dict[str, Any]:
    """What the emulation decides; not how fast, where or from which checkout it ran."""
    return {k: v for k, v in summary.items() if k not in ("run", "code")}


def _model_infos(infos: dict[str, Any]) -> dict[str, Any]:
    """Infos with the episode summary of the last step reduced to its model part."""
    return {a: {**info, "episode": _model_part(info["episode"])} if isinstance(info.get("episode"), dict) else info
            for a, info in infos.items()}


def _launch(case: Case, scenario: Any, transport: str = "inproc") -> dict[str, Any]:
    from orchestrator.session import Simulation

    with tempfile.TemporaryDirectory() as tmp, Simulation.open(scenario, transport, layout=case.layout) as sim:
        summary = sim.run(case.steps, seed=case.seed, policy=case.policy)
        sim.metrics.write(Path(tmp), summary)
        digests = outputs(Path(tmp))
    totals = summary["totals"]
    return {**digests, "totals": {k: totals[k] for k in ("generated", "completed") if k in totals}}


def outputs(out: Path) -> dict[str, str]:
    """The digests of a launch's outputs in ``out``: the model's part of summary.json, ticks.csv and nodes.csv.
    Any run written there compares with a case: a launch of the real CLI over several hosts too."""
    summary = json.loads((out / "summary.json").read_text())
    return {"summary": _digest(_model_part(summary)),
            **{name: _sha((out / name).read_bytes()) for name in ("ticks.csv", "nodes.csv")}}


def _episode(case: Case, scenario: Any) -> dict[str, Any]:
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv(scenario, transport="inproc", reward=case.reward, observation=case.observation,
                       max_steps=case.steps)
    rng = np.random.default_rng(case.seed)
    stream = hashlib.sha256()
    returns = 0.0
    try:
        obs, infos = env.reset(seed=case.seed)
        stream.update(_digest([obs, _model_infos(infos)]).encode())
        while env.agents:
            actions = {a: _sample(env, a, obs[a], rng) for a in env.agents}
            obs, rewards, terms, truncs, infos = env.step(actions)
            returns += sum(rewards.values())
            stream.update(_digest([actions, obs, rewards, terms, truncs, _model_infos(infos),
                                   _model_infos(env.step_details)]).encode())
    finally:
        env.close()
    return {"episode": stream.hexdigest()[:20], "totals": {"return": round(returns, 6)}}


def _sample(env: Any, agent: str, obs: Any, rng: np.random.Generator) -> Any:
    """A seeded random action among those the mask allows (the same draws whatever the environment does)."""
    mask = obs["action_mask"]
    space = env.action_space(agent)
    if mask.ndim == 1:
        return int(rng.choice(np.flatnonzero(mask))) if mask.any() else 0
    return np.array([int(rng.choice(np.flatnonzero(row))) if row.any() else 0 for row in mask], dtype=space.dtype)


def run_case(case: Case) -> dict[str, Any]:
    from orchestrator.scenario import load_scenario

    scenario = load_scenario(case.scenario)
    return _episode(case, scenario) if case.env else _launch(case, scenario)


def compute(cases: list[Case], progress: bool = False) -> Iterator[tuple[Case, dict[str, Any]]]:
    for i, case in enumerate(cases, 1):
        if progress:
            print(f"[{i}/{len(cases)}] {case.name}", file=sys.stderr, flush=True)
        yield case, run_case(case)


def load() -> dict[str, dict[str, Any]]:
    return json.loads(GOLDEN.read_text())["cases"]


def differences(expected: dict[str, Any], got: dict[str, Any]) -> list[str]:
    return [f"{key}: expected {expected.get(key)!r}, got {got.get(key)!r}"
            for key in sorted(set(expected) | set(got)) if expected.get(key) != got.get(key)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.golden", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="An intended change: --update, then review `git diff tests/golden.json` "
                                            "(the totals beside each digest show what moved) and commit it.")
    parser.add_argument("--quick", action="store_true", help="only the cases CI checks")
    parser.add_argument("--update", action="store_true", help="rewrite tests/golden.json with what the code gives now")
    parser.add_argument("-k", metavar="TEXT", default="", help="only the cases whose name contains TEXT")
    args = parser.parse_args(argv)
    cases = [c for c in CASES if (c.quick or not args.quick) and args.k in c.name]
    if args.update:
        known = load() if GOLDEN.exists() else {}
        for case, got in compute(cases, progress=True):
            known[case.name] = {**got, "case": {k: v for k, v in asdict(case).items() if v not in (None, False)}}
        names = {c.name for c in CASES}
        stale = sorted(set(known) - names)
        for name in stale:
            del known[name]
        GOLDEN.write_text(json.dumps({"cases": dict(sorted(known.items()))}, indent=1) + "\n")
        print(f"wrote {len(cases)} cases to {GOLDEN}" + (f"; removed {len(stale)} stale" if stale else ""))
        return 0
    expected = load()
    failed = 0
    for case, got in compute(cases, progress=True):
        want = {k: v for k, v in expected.get(case.name, {}).items() if k != "case"}
        diff = differences(want, got)
        if diff:
            failed += 1
            print(f"DIFFERS {case.name}: " + "; ".join(diff))
    print(f"{len(cases) - failed} of {len(cases)} cases identical")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
