"""The paper's figure: overloaded nodes, response time and dropped tasks against the sweep variable,
one line per agent with its 95% confidence band over the evaluation episodes."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

PANELS = (("overloaded_node_ticks", "Overloaded nodes", "node-ticks overloaded per episode"),
          ("response_time_mean", "Response time", "mean response time of completed tasks [s]"),
          ("completion_ratio", "Completion ratio", "completed / generated tasks"),
          ("penalised_response_time", "Penalised response time",
           "mean over generated tasks, a lost one = its deadline [s]"),
          ("dropped", "Dropped tasks", "tasks dropped per episode"))
LEARNING = ("ddqn", "a2c", "ppo")  # drawn as solid lines, the baselines dashed
MARKERS = ("o", "^", "D", "s", "v", "P", "X", "*")
# Two-sided 95% quantiles of Student's t for 1..30 degrees of freedom.
T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)


def t975(df: int) -> float:
    """Student's t quantile; beyond 30 degrees of freedom, its first-order expansion around 1.96."""
    if df <= len(T975):
        return T975[df - 1]
    z = 1.959964
    return z + (z**3 + z) / (4 * df)


def mean_ci(values: Sequence[float]) -> tuple[float, float]:
    """Mean and half-width of its 95% confidence interval (NaNs ignored; 0 width for one value)."""
    x = np.asarray([v for v in values if not math.isnan(v)], dtype=float)
    if len(x) == 0:
        return math.nan, math.nan
    if len(x) == 1:
        return float(x[0]), 0.0
    return float(x.mean()), t975(len(x) - 1) * float(x.std(ddof=1)) / math.sqrt(len(x))


def summarise(rows: Sequence[Mapping[str, Any]], x_key: str, agents: Sequence[str]) -> list[dict[str, Any]]:
    """One row per agent and sweep value: mean and CI half-width of every panel's metric.

    With several training seeds the interval is over the seeds' means (what another training run would
    give); with one (a baseline, evaluated once, or a single seed) over the episodes."""
    out = []
    for agent in agents:
        for x in sorted({r[x_key] for r in rows if r["agent"] == agent}):
            sel = [r for r in rows if r["agent"] == agent and r[x_key] == x]
            seeds = sorted({r.get("train_seed") for r in sel}, key=str)
            row: dict[str, Any] = {"agent": agent, x_key: x, "episodes": len(sel), "seeds": len(seeds),
                                   "ci_over": "seeds" if len(seeds) > 1 else "episodes"}
            groups = [[r for r in sel if r.get("train_seed") == s] for s in seeds] if len(seeds) > 1 else [sel]
            for metric in ("response_time_mean", "completion_ratio", "penalised_response_time", "dropped",
                           "overloaded_node_ticks", "completed"):
                values = [[float(r[metric]) for r in group] for group in groups]
                row[metric], row[f"{metric}_ci95"] = mean_ci([mean_ci(v)[0] for v in values] if len(groups) > 1
                                                             else values[0])
            out.append(row)
    return out


def plot_study(rows: Sequence[Mapping[str, Any]], x_key: str, xlabel: str, agents: Sequence[str], title: str,
               path: str | Path, xticklabels: Mapping[float, str] | None = None) -> None:
    """The panels side by side, lines with markers and shaded 95% confidence bands, a shared legend."""
    summary = summarise(rows, x_key, agents)
    fig, axes = plt.subplots(1, len(PANELS), figsize=(5 * len(PANELS), 4.6), constrained_layout=True)
    colours = plt.get_cmap("tab10").colors
    xs = sorted({float(r[x_key]) for r in rows})
    # Agents that behave alike (greedy and local on the AoT networks) would hide each other: shift each
    # agent's points sideways by a little, and give each its own marker.
    dodge = 0.012 * ((xs[-1] - xs[0]) or 1.0)
    for ax, (metric, name, ylabel) in zip(axes, PANELS, strict=True):
        for i, agent in enumerate(agents):
            pts = [s for s in summary if s["agent"] == agent]
            x = np.array([p[x_key] for p in pts], dtype=float) + (i - (len(agents) - 1) / 2) * dodge
            y = np.array([p[metric] for p in pts], dtype=float)
            ci = np.array([p[f"{metric}_ci95"] for p in pts], dtype=float)
            learning = agent in LEARNING
            colour = colours[i % len(colours)]
            ax.plot(x, y, marker=MARKERS[i % len(MARKERS)], markersize=6, linewidth=2.2 if learning else 1.4,
                    linestyle="-" if learning else "--", color=colour, label=agent, zorder=3 if learning else 2)
            ax.fill_between(x, y - ci, y + ci, color=colour, alpha=0.12, linewidth=0)
        ax.set_title(name, fontsize=13)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.set_xticks(xs)
        if xticklabels:
            ax.set_xticklabels([xticklabels.get(x, f"{x:g}") for x in xs])
        ax.set_ylim(bottom=0)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(agents), frameon=False, fontsize=11)
    fig.suptitle(title, fontsize=13)
    fig.savefig(path, dpi=120)
    plt.close(fig)
