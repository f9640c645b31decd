"""Evaluation results in marl-eval's JSON format (github.com/instadeepai/marl-eval, the format BenchMARL
writes), so that its aggregation and plots, and rliable's, read this project's runs as they are:

    {"zenohedge": {task: {algorithm: {"seed_<k>": {
        "step_0": {"step_count": <environment steps trained>, <metric>: [one value per evaluation episode]},
        "absolute_metrics": {<metric>: [the same values]}}}}}}

Our studies evaluate each trained policy once, at the end of its training, so a run has one logging step
and its absolute metrics are that evaluation. A response time is NaN when an episode completed no task
(written as ``NaN``, which Python's ``json`` and so marl-eval read back)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

ENVIRONMENT = "zenohedge"
NOT_METRICS = frozenset({"episode", "seed", "steps", "decisions", "wall_s"})  # bookkeeping, not outcomes


def run_entry(rows: Sequence[Mapping[str, Any]], step_count: int) -> dict[str, Any]:
    """One run (one algorithm and training seed): ``evaluate``'s rows, one per episode."""
    names = [k for k, v in rows[0].items()
             if k not in NOT_METRICS and isinstance(v, int | float) and not isinstance(v, bool)]
    metrics = {k: [float(r[k]) for r in rows] for k in names}
    return {"step_0": {"step_count": int(step_count), **metrics},
            "absolute_metrics": {k: list(v) for k, v in metrics.items()}}


def add_run(data: dict[str, Any], task: str, algorithm: str, seed: int, entry: dict[str, Any]) -> None:
    data.setdefault(ENVIRONMENT, {}).setdefault(task, {}).setdefault(algorithm, {})[f"seed_{seed}"] = entry


def write(path: str | Path, data: Mapping[str, Any], merge: bool = False) -> None:
    """Write ``data``; with ``merge``, into the runs already in the file (a run given again replaces its own)."""
    path = Path(path)
    if merge and path.is_file():
        old = json.loads(path.read_text())
        for env, tasks in data.items():
            for task, algorithms in tasks.items():
                for algorithm, runs in algorithms.items():
                    old.setdefault(env, {}).setdefault(task, {}).setdefault(algorithm, {}).update(runs)
        data = old
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))
