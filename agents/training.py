"""Training and evaluation loops over any PettingZoo parallel environment of this project.

``train`` runs a learner's behaviour policy for some episodes, feeds every step back to it and writes
one CSV row per episode: the return (sum over agents), the episode's metrics and the learner's
diagnostics. ``evaluate`` runs any policy for K episodes on fixed seeds and returns the same metrics,
so that every policy is compared on the same task arrivals.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from agents.common import AgentPolicy, has_decision
from agents.learner import Learner

EVAL_SEED = 100_000  # evaluation episodes use seeds EVAL_SEED + k, never met in training (seeds 0, 1, ...)
JOB_METRICS = {"jobs": "generated", "jobs_completed": "completed", "jobs_missed": "missed",
               "job_completion_ratio": "completion_ratio", "makespan_mean": "makespan_mean",
               "penalised_makespan": "penalised_makespan"}
"""The job metrics of an episode's row (a scenario of jobs only), and their keys in its summary's "jobs"."""


def episode_metrics(episode: Mapping[str, Any] | None) -> dict[str, float]:
    """The paper's metrics (and a few more) from ``infos[agent]["episode"]`` at the end of an episode; the drops
    on broken links where nodes move, and the job metrics (``JOB_METRICS``) in a scenario of jobs."""
    if not episode:
        return {}
    totals, rt, jobs = episode["totals"], episode["response_time"], episode.get("jobs")
    moving = {"dropped_link_broken": totals["dropped"]["link_broken"]} if "link_broken" in totals["dropped"] else {}
    job = {column: math.nan if jobs[key] is None else jobs[key] for column, key in JOB_METRICS.items()} if jobs else {}
    return {
        "generated": totals["generated"], "completed": totals["completed"], "offloaded": totals["offloaded"],
        "dropped": totals["dropped"]["total"], "dropped_queue_full": totals["dropped"]["queue_full"],
        "dropped_expired": totals["dropped"]["expired"], "in_system": totals["in_system"],
        "response_time_mean": _number(rt["mean"]), "response_time_p50": _number(rt["p50"]),
        "response_time_p95": _number(rt["p95"]), "overloaded_node_ticks": episode["overloaded"]["node_ticks"],
        "overloaded_mean_nodes": episode["overloaded"]["mean_nodes"], "energy_j": episode["energy_j"]["total"],
        "completion_ratio": _number(episode["completion_ratio"]),
        "completion_ratio_settled": _number(episode["completion_ratio_settled"]),
        "penalised_response_time": _number(episode["penalised_response_time"]), **moving, **job,
    }


def _number(x: float | None) -> float:
    return math.nan if x is None else float(x)


def run_episode(env: Any, policy: AgentPolicy, seed: int, learner: Learner | None = None) -> dict[str, float]:
    """One episode of ``policy`` (of ``learner.explore`` when a learner is given, which then learns)."""
    start = time.perf_counter()
    observations, _ = env.reset(seed=seed)
    policy.reset(seed)
    total, steps, decisions, infos = 0.0, 0, 0, {}
    while env.agents:
        decisions += sum(has_decision(o) for o in observations.values())
        actions = learner.explore(observations) if learner is not None else policy.act(observations)
        observations, rewards, terminations, truncations, infos = env.step(actions)
        if learner is not None:
            known = all("credits" in i for i in infos.values())  # not in flat mode's numbers-only infos
            credits = {a: i["credits"] for a, i in infos.items()} if known else None
            learner.observe(rewards, observations, terminations, truncations, credits)
        total += sum(rewards.values())
        steps += 1
    episode = next((i["episode"] for i in infos.values() if "episode" in i), None)
    return {"seed": seed, "steps": steps, "decisions": decisions, "return": total, **episode_metrics(episode),
            "wall_s": time.perf_counter() - start}


def train(env: Any, learner: Learner, episodes: int, *, seed: int = 0, steps_per_episode: int | None = None,
          csv_path: str | Path | None = None, progress: Progress | None = None, label: str = "") -> list[dict]:
    """Train ``learner`` for ``episodes`` episodes (seeds seed, seed + 1, ...); returns the per-episode rows.

    The exploration and learning-rate schedules span ``episodes * steps_per_episode`` steps (default: the
    environment's ``max_steps``)."""
    per_episode = steps_per_episode or getattr(env, "max_steps", None)
    if per_episode is None:
        raise ValueError("give steps_per_episode: the environment has no max_steps")
    learner.start_training(episodes * per_episode)
    task = progress.add_task(label or f"train {learner.name}", total=episodes, info="") if progress else None
    writer = CsvWriter(csv_path) if csv_path else None
    rows = []
    for k in range(episodes):
        row = {"episode": k, **run_episode(env, learner, seed + k, learner), **learner.stats()}
        rows.append(row)
        if writer:
            writer.write(row)
        if progress is not None:
            progress.update(task, advance=1, info=f"return {row['return']:.0f}  "
                                                  f"response {row.get('response_time_mean', math.nan):.1f} s")
    if writer:
        writer.close()
    return rows


def evaluate(env: Any, policy: AgentPolicy, episodes: int, *, seed: int = EVAL_SEED, progress: Progress | None = None,
             label: str = "") -> list[dict]:
    """Run ``policy.act`` for ``episodes`` episodes on seeds seed, seed + 1, ...; one metrics row each."""
    task = progress.add_task(label or f"evaluate {policy.name}", total=episodes, info="") if progress else None
    rows = []
    for k in range(episodes):
        rows.append({"episode": k, **run_episode(env, policy, seed + k)})
        if progress is not None:
            progress.update(task, advance=1)
    return rows


class CsvWriter:
    """Rows appended and flushed one by one, so that a long run can be watched (and survives a crash)."""

    def __init__(self, path: str | Path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.file = open(path, "w", newline="")  # noqa: SIM115 - kept open across rows, closed by close()
        self.writer: csv.DictWriter | None = None

    def write(self, row: Mapping[str, Any]) -> None:
        if self.writer is None:
            self.writer = csv.DictWriter(self.file, fieldnames=list(row))
            self.writer.writeheader()
        self.writer.writerow(row)
        self.file.flush()

    def close(self) -> None:
        self.file.close()


def write_csv(path: str | Path, rows: list[Mapping[str, Any]]) -> None:
    writer = CsvWriter(path)
    for row in rows:
        writer.write(row)
    writer.close()


def progress_bar() -> Progress:
    """The progress display of training and evaluation runs."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    TextColumn("eta"), TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
