"""The raw per-episode rows every benchmark table is built from: one schema for experiments.evaluate,
experiments.bound, experiments.regimes and anything else that runs policies, read back by experiments.report.

One row per policy, training run and episode (docs/benchmark.md, "Raw per-episode rows"):

- ``policy``; ``train_seed``: the learner's training seed, empty for a baseline (which is not trained);
- ``suite``: the suite folder a regime comes from (``test``, ``validation``, ...; ``bundled`` for a scenario
  of the project's own); ``split``: the seed set of the episode seed (``experiments.protocol``);
- ``regime``, ``episode`` (its index), ``seed`` (what ``env.reset`` took), ``steps``;
- the episode's metrics: ``generated``, ``completed``, ``completion_ratio``, ``penalised_response_time``,
  ``response_time_mean``, ``dropped``;
- the job metrics (``agents.training.JOB_METRICS``): ``jobs``, ``jobs_completed``, ``jobs_missed``,
  ``job_completion_ratio``, ``makespan_mean``, ``penalised_makespan``; in every row, empty where the scenario has
  no jobs (a file written before them has no such columns, and reads the same: NaN);
- optional, where the bound was computed: ``local`` (what ``local`` completed on the episode), ``bound``,
  ``bound_kind`` and ``normalised_score``. The report joins them by (suite, regime, seed) onto every policy.

Other columns (a learner's return, wall time) may follow; the reader keeps only these.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from agents.training import JOB_METRICS
from experiments.protocol import split_of

KEYS = ("policy", "train_seed", "suite", "split", "regime", "episode", "seed", "steps")
METRICS = ("generated", "completed", "completion_ratio", "penalised_response_time", "response_time_mean", "dropped")
JOBS = tuple(JOB_METRICS)
OPTIONAL = ("local", "bound", "bound_kind", "normalised_score")
TEXT = ("policy", "suite", "split", "regime", "bound_kind")
INTEGERS = ("episode", "seed", "steps")


class RawError(ValueError):
    """A raw CSV that does not follow the schema: the message names the file, the line and the column."""


def suite_of(scenario: str | Path) -> str:
    """The suite a scenario file belongs to: its folder's name when a suite manifest lies beside it."""
    path = Path(scenario)
    return path.parent.name if (path.parent / "manifest.csv").is_file() else "bundled"


def row(policy: str, train_seed: int | None, scenario: str | Path, regime: str, episode: Mapping[str, Any],
        extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A raw row from an ``agents.training.evaluate`` row of ``policy`` on ``regime`` (of ``scenario``'s suite), the
    job columns empty where it has none; then ``extra`` (the optional columns, or a caller's own), then the rest
    of the episode's columns."""
    head = {"policy": policy, "train_seed": "" if train_seed is None else train_seed, "suite": suite_of(scenario),
            "split": split_of(int(episode["seed"])) or "", "regime": regime, "episode": episode["episode"],
            "seed": episode["seed"], "steps": episode["steps"], **{m: episode[m] for m in METRICS},
            **{m: episode.get(m, "") for m in JOBS}}
    return {**head, **(extra or {}), **{k: v for k, v in episode.items() if k not in head and k != "wall_s"}}


def read(paths: Iterable[str | Path]) -> list[dict[str, Any]]:
    """Every row of the files, typed: numbers as float (NaN when empty, or absent in an optional column),
    ``episode``, ``seed`` and ``steps`` as int, ``train_seed`` as int or None. A file or a value outside the
    schema raises RawError."""
    rows = []
    for path in paths:
        try:
            with open(path, newline="") as f:
                reader = csv.DictReader(f)
                missing = [k for k in (*KEYS, *METRICS) if k not in (reader.fieldnames or [])]
                if missing:
                    raise RawError(f"{path}: not a raw per-episode CSV: no column {', '.join(missing)}")
                for line, r in enumerate(reader, start=2):
                    rows.append(_typed(r, f"{path}:{line}"))
        except OSError as e:
            raise RawError(f"{path}: {e.strerror or e}") from None
    return rows


def _typed(r: Mapping[str, str | None], where: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in (*KEYS, *METRICS, *JOBS, *OPTIONAL):
        value = r.get(key)
        value = "" if value is None else value.strip()
        try:
            if key in TEXT:
                out[key] = value
            elif key == "train_seed":
                out[key] = int(value) if value else None
            elif key in INTEGERS:
                out[key] = int(value)
            else:
                out[key] = float(value) if value else math.nan
        except ValueError:
            kind = "an integer" if key in (*INTEGERS, "train_seed") else "a number"
            raise RawError(f"{where}: column {key}: expected {kind}, got {value!r}") from None
    for key in ("policy", "suite", "split", "regime"):
        if not out[key]:
            raise RawError(f"{where}: column {key}: empty")
    return out
