"""The parameters of the tunable baselines, chosen on the validation suite only (docs/benchmark.md).

``threshold`` (offload once the own queue reaches this many tasks) and ``drift_plus_penalty`` (its V) each
run at every value of a small grid on every regime of the validation suite, on validation episodes; the
value with the highest mean completion ratio over all of them is chosen (ties: the first in the grid).
Nothing here reads a test regime or a test episode.

    python -m experiments.tune_baselines                           # 10 validation regimes, 3 episodes each
    python -m experiments.tune_baselines --count 3 --episodes 2 --max-steps 100 --out runs/tuning-small

Outputs under ``--out`` (default runs/tuning): ``tuning.csv`` (one row per policy, value, regime and
episode), ``chosen.json`` (the values, with the regimes and seeds they were chosen on) and the suite's
files under ``validation/``. ``chosen(path)`` reads the values back as baselines.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from agents.baselines import Baseline, baseline
from agents.training import evaluate, progress_bar, write_csv
from experiments import suite
from experiments.common import Parser, make_env, positive_int
from experiments.protocol import EPISODES
from node_runtime.model.policies import POLICIES, configured

GRID: dict[str, tuple[str, tuple[float, ...]]] = {
    "threshold": ("threshold", (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0)),
    "drift_plus_penalty": ("v", (0.0, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0)),
}
CRITERION = "completion_ratio"  # mean over the validation regimes and episodes; higher is better


def tuned(policy: str, value: float) -> type[Baseline]:
    """The baseline of ``policy`` with its grid parameter at ``value``."""
    param, _ = GRID[policy]
    return baseline(configured(POLICIES[policy], **{param: value}))


def measure(paths: Sequence[Path], episodes: int, max_steps: int | None, progress: Any = None) -> list[dict[str, Any]]:
    """One row per policy, grid value, regime and validation episode."""
    seed = EPISODES["validation"].seeds(episodes)[0]
    rows = []
    for path in paths:
        env = make_env(str(path), None, max_steps)
        try:
            for policy, (param, values) in GRID.items():
                for value in values:
                    for r in evaluate(env, tuned(policy, value)(0), episodes, seed=seed, progress=progress,
                                      label=f"{path.stem} {policy} {param}={value:g}"):
                        rows.append({"regime": path.stem, "policy": policy, "param": param, "value": value,
                                     **{k: v for k, v in r.items() if k != "wall_s"}})
        finally:
            env.close()
    return rows


def choose(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per policy, the grid value with the best mean ``CRITERION`` (the first in the grid on a tie)."""
    out = {}
    for policy, (param, values) in GRID.items():
        means = [float(np.nanmean([r[CRITERION] for r in rows if r["policy"] == policy and r["value"] == v]))
                 for v in values]
        out[policy] = {param: values[int(np.argmax(means))]}
    return out


def chosen(path: Path) -> dict[str, type[Baseline]]:
    """The tuned baselines of a ``chosen.json``, by policy name."""
    values = json.loads(Path(path).read_text())["chosen"]
    return {policy: baseline(configured(POLICIES[policy], **params)) for policy, params in values.items()}


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.tune_baselines", description=__doc__.splitlines()[0])
    p.add_argument("--count", type=positive_int, default=suite.SUITES["validation"],
                   help=f"validation regimes (default {suite.SUITES['validation']})")
    p.add_argument("--episodes", type=positive_int, default=3, help="validation episodes per regime (default 3)")
    p.add_argument("--steps", type=positive_int, default=suite.STEPS, help=f"regime steps (default {suite.STEPS})")
    p.add_argument("--max-steps", type=positive_int, default=None, help="steps per episode (default: the regime's)")
    p.add_argument("--out", type=Path, default=Path("runs/tuning"), help="output folder (default runs/tuning)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    args = p.parse_args(argv)
    regimes = suite.suite("validation", args.count, args.steps)
    paths = suite.write(regimes, args.out / "validation")
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        rows = measure(paths, args.episodes, args.max_steps, progress)
    write_csv(args.out / "tuning.csv", rows)
    values = choose(rows)
    (args.out / "chosen.json").write_text(json.dumps({
        "chosen": values, "criterion": f"mean {CRITERION}", "split": "validation",
        "regimes": {r.name: r.seed for r in regimes}, "episode_seeds": EPISODES["validation"].seeds(args.episodes),
        "max_steps": args.max_steps}, indent=2) + "\n")
    print(", ".join(f"{policy}: {param} = {value:g}" for policy, params in values.items()
                    for param, value in params.items()) + f" (written to {args.out / 'chosen.json'})")


if __name__ == "__main__":
    main()
