"""Learning curves of the generalist's training runs, for ``python -m experiments.report``: return, completion
and penalised response against frames (agent-steps), the mean and its 95 % interval over the training seeds.

They are read from what ``experiments.generalist train --out <run>`` writes: ``config.json`` (the training
seed), ``train.csv`` (one row per training episode, with the cumulative ``frames``) and ``validation.csv``
(every checkpoint's means on the validation suite). Training episodes draw different regimes, so one
episode's values say little; each run's episodes are averaged within ``BINS`` equal spans of frames up to
the shortest run's last frame, and the seeds' bin means are then aggregated. Checkpoints are taken at the
same episodes in every run; their frames differ a little between seeds (the regimes drawn), so a
checkpoint's x is its seeds' mean frames.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from experiments import stats
from experiments.raw import RawError

METRICS = {"return": "return (marginal reward)", "completion_ratio": "completion ratio",
           "penalised_response_time": "penalised response [s]"}
TRAIN_COLUMNS = ("episode", "frames", *METRICS)
CHECK_COLUMNS = ("episode", "frames", "checkpoint", *METRICS)
BINS = 20


@dataclass(frozen=True)
class Run:
    """One training run: its seed, its training episodes and its checkpoints' validation means."""

    seed: int
    folder: Path
    train: dict[str, np.ndarray]  # column -> one value per training episode
    checks: dict[str, np.ndarray]  # column -> one value per checkpoint
    names: tuple[str, ...]  # the checkpoints' files

    @property
    def best(self) -> int:
        """The index of the checkpoint training kept as best.pt: the first of the highest completions."""
        return int(np.argmax(self.checks["completion_ratio"]))


def _columns(path: Path, columns: Sequence[str], text: Sequence[str] = ()) -> dict[str, list[Any]]:
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in columns if c not in (reader.fieldnames or [])]
            if missing:
                raise RawError(f"{path}: no column {', '.join(missing)} (written by python -m experiments.generalist "
                               "train)")
            out: dict[str, list[Any]] = {c: [] for c in columns}
            for line, r in enumerate(reader, start=2):
                for c in columns:
                    try:
                        out[c].append(r[c] if c in text else float(r[c]))
                    except (TypeError, ValueError):
                        raise RawError(f"{path}:{line}: column {c}: expected a number, got {r[c]!r}") from None
    except OSError as e:
        raise RawError(f"{path}: {e.strerror or e}") from None
    if not out[columns[0]]:
        raise RawError(f"{path}: no rows")
    return out


def read(folders: Sequence[Path], episodes: bool = True) -> list[Run]:
    """The training runs in ``folders`` (each an ``--out`` of ``experiments.generalist train``), by seed; without
    ``episodes``, their checkpoints only (no ``train.csv`` needed)."""
    runs = []
    for folder in folders:
        try:
            seed = int(json.loads((folder / "config.json").read_text())["config"]["seed"])
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise RawError(f"{folder / 'config.json'}: no training seed (config.seed) in it ({e})") from None
        train = _columns(folder / "train.csv", TRAIN_COLUMNS) if episodes else {}
        checks = _columns(folder / "validation.csv", CHECK_COLUMNS, text=("checkpoint",))
        names = tuple(checks.pop("checkpoint"))
        runs.append(Run(seed, folder, {k: np.asarray(v) for k, v in train.items()},
                        {k: np.asarray(v) for k, v in checks.items()}, names))
    runs.sort(key=lambda r: r.seed)
    if len({r.seed for r in runs}) < len(runs):
        raise RawError(f"{', '.join(str(r.folder) for r in runs)}: two runs of the same training seed")
    episodes = {tuple(r.checks["episode"]) for r in runs}
    if len(episodes) > 1:
        raise RawError(f"{runs[0].folder} and others: the runs' checkpoints are at different episodes; "
                       "the curves need the same --episodes and --checkpoint-every")
    return runs


def _over_seeds(values: np.ndarray, reps: int) -> stats.Interval:
    """The mean over the seeds (axis 0) and its 95 % bootstrap interval, resampling seeds."""
    return stats.bootstrap(stats.Scores(("run",), (np.asarray(values, dtype=float)[:, None],)), stats.mean, reps)


def binned(runs: Sequence[Run], metric: str, reps: int, bins: int = BINS) -> tuple[np.ndarray, list[stats.Interval]]:
    """Bin centres (frames) and, per bin, the seeds' mean of their episodes' means there, with its interval."""
    last = min(float(r.train["frames"][-1]) for r in runs)
    edges = np.linspace(0.0, last, bins + 1)
    means = np.full((len(runs), bins), math.nan)
    for i, r in enumerate(runs):
        which = np.digitize(r.train["frames"], edges[1:-1], right=True)  # an episode's bin: where it ends
        keep = r.train["frames"] <= last
        for b in range(bins):
            chosen = r.train[metric][keep & (which == b)]
            if chosen.size:
                means[i, b] = np.nanmean(chosen)
    centres = (edges[:-1] + edges[1:]) / 2
    ok = ~np.isnan(means).any(axis=0)  # a bin no episode of some run ends in (a run's longest episode) is left out
    return centres[ok], [_over_seeds(means[:, b], reps) for b in np.flatnonzero(ok)]


def checkpoints(runs: Sequence[Run], metric: str, reps: int) -> tuple[np.ndarray, list[stats.Interval]]:
    """Each checkpoint's mean frames and its seeds' mean validation value, with its interval."""
    frames = np.mean([r.checks["frames"] for r in runs], axis=0)
    values = np.array([r.checks[metric] for r in runs])
    return frames, [_over_seeds(values[:, k], reps) for k in range(values.shape[1])]


def figure(runs: Sequence[Run], path: Path, reps: int) -> None:
    """Training episodes (top) and checkpoints on the validation suite (bottom), each metric against frames."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, len(METRICS), figsize=(13, 7), sharex=True, constrained_layout=True)
    for row, (what, curve) in enumerate((("training episodes", binned), ("validation suite, checkpoints",
                                                                         checkpoints))):
        for ax, (metric, label) in zip(axes[row], METRICS.items(), strict=True):
            x, cis = curve(runs, metric, reps)
            ax.plot(x, [c.point for c in cis], color="C0", marker="o" if row else None, markersize=3)
            ax.fill_between(x, [c.low for c in cis], [c.high for c in cis], color="C0", alpha=0.2, linewidth=0)
            ax.set_title(f"{label}, {what}", fontsize=10)
            ax.grid(alpha=0.3)
            if row:
                ax.set_xlabel("frames (agent-steps)")
    fig.suptitle(f"The generalist's learning curves: mean and 95 % bootstrap interval over {len(runs)} training "
                 f"seeds ({', '.join(str(r.seed) for r in runs)})", fontsize=11)
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)


def _ci(x: stats.Interval, digits: int) -> str:
    return f"{x.point:.{digits}f} [{x.low:.{digits}f}, {x.high:.{digits}f}]"


def section(runs: Sequence[Run], figures: Path, link: str, reps: int) -> str:
    """The learning curves' Markdown: the checkpoints' table and the figure."""
    name = "generalist-learning-curves.png"
    figure(runs, figures / name, reps)
    episodes = [int(e) for e in runs[0].checks["episode"]]
    cols = {m: checkpoints(runs, m, reps) for m in METRICS}
    chosen = [sum(r.best == k for r in runs) for k in range(len(episodes))]
    lines = ["## Learning curves of the generalist", "",
             f"{len(runs)} training runs (seeds {', '.join(str(r.seed) for r in runs)}) of "
             f"`python -m experiments.generalist train`, {len(runs[0].train['episode'])} training episodes each "
             f"(logs: `{runs[0].folder.parent.as_posix()}/`). "
             "Frames: agent-steps (steps × the regime's agents), summed over the training episodes. [x, y]: the 95 % "
             f"bootstrap interval over the training seeds ({reps} resamples). Each checkpoint is scored on the "
             "validation suite (the first `--validation-episodes` of every regime, acting as `--validation-mode` "
             "says); `best.pt` is the checkpoint of highest completion in each run, and the test numbers come from "
             "it.", "",
             "| checkpoint (episode) | frames (mean) | validation completion % | penalised response [s] | return "
             "| best.pt of |", "| --- | --- | --- | --- | --- | --- |"]
    for k, episode in enumerate(episodes):
        completion = cols["completion_ratio"][1][k]
        lines.append(f"| {episode} | {cols['completion_ratio'][0][k]:,.0f} | "
                     f"{_ci(stats.Interval(completion.point * 100, completion.low * 100, completion.high * 100), 1)} | "
                     f"{_ci(cols['penalised_response_time'][1][k], 1)} | {_ci(cols['return'][1][k], 1)} | "
                     f"{chosen[k]} |")
    title = "The generalist's learning curves against frames, mean and 95 % interval over the training seeds"
    lines += ["", "Top: the training episodes' own values (the regimes drawn differ from episode to episode, so "
              f"each run's episodes are averaged in {BINS} equal spans of frames). Bottom: the checkpoints on the "
              "validation suite.", "", f"![{title}]({link}/{name})", ""]
    return "\n".join(lines)


def _settings(run: Run) -> dict[str, Any]:
    """A run's settings as its ``config.json`` has them, flattened (``config.lr``), its seed left out."""
    data = json.loads((run.folder / "config.json").read_text())
    flat = {k: v for k, v in data.items() if k not in ("config", "regimes", "suite", "validation")}
    flat.update({f"config.{k}": v for k, v in data["config"].items() if k != "seed"})
    return flat


def settings_section(candidates: dict[str, Sequence[Run]], default: str, last: int = 4) -> str:
    """The generalist's settings as chosen on the validation suite: for each candidate (a folder of training runs),
    what its settings change from ``default``'s, its runs' ``best.pt`` validation completion and the mean of their
    last ``last`` checkpoints; the chosen one has the highest mean ``best.pt`` completion over its seeds."""
    def mean_best(runs: Sequence[Run]) -> float:
        return float(np.mean([r.checks["completion_ratio"][r.best] for r in runs]))

    settings = {name: _settings(runs[0]) for name, runs in candidates.items()}
    for name, runs in candidates.items():
        if any(_settings(r) != settings[name] for r in runs[1:]):
            raise RawError(f"{runs[0].folder.parent}: its runs differ in more than the training seed (config.json)")
    base = settings[default]
    chosen = max(candidates, key=lambda name: mean_best(candidates[name]))
    lines = ["## Settings chosen on validation", "",
             "Each candidate is a set of training runs of `python -m experiments.generalist train` (one per training "
             f"seed); `{default}` holds the settings the search started from, and each other candidate says what it "
             "changed (the value, then the starting one in brackets). Every checkpoint is scored on the validation "
             "suite; a run's score is its `best.pt`'s validation completion, a candidate's the mean over its seeds. "
             f"Chosen: **{chosen}**.", "",
             f"| candidate | changes | seeds | best.pt completion %, mean | per seed | last {last} checkpoints % | "
             "penalised response at best.pt [s] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, runs in sorted(candidates.items(), key=lambda kv: -mean_best(kv[1])):
        mine = settings[name]
        changes = "; ".join(f"`{k}` {mine.get(k)} ({base.get(k)})" for k in sorted({*mine, *base})
                            if mine.get(k) != base.get(k)) or "—"
        best = [100 * r.checks["completion_ratio"][r.best] for r in runs]
        tail = np.mean([r.checks["completion_ratio"][-last:] for r in runs]) * 100
        response = np.mean([r.checks["penalised_response_time"][r.best] for r in runs])
        mark = f"**{name}**" if name == chosen else name
        lines.append(f"| {mark} | {changes} | {', '.join(str(r.seed) for r in runs)} | {np.mean(best):.2f} | "
                     f"{', '.join(f'{b:.2f}' for b in best)} | {tail:.2f} | {response:.2f} |")
    return "\n".join([*lines, ""])
