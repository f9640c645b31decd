"""``orchestrator plot``: time-series PNGs of a finished run, from the files ``orchestrator launch`` writes.

Reads only ``summary.json``, ``ticks.csv`` and ``nodes.csv`` (columns: ``Metrics.tick_table`` and
``Metrics.node_table``), so a run can be plotted long after it finished, on another machine. Writes
``overview.png`` (a dashboard), ``queues.png``, ``drops.png``, ``response_time.png`` and ``energy.png``.
Anything missing or malformed is a ``PlotError`` whose message is one line naming the file.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: never open a window, never need a display

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import BoundaryNorm, ListedColormap, PowerNorm
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from orchestrator.catalogue import METRIC, Out, columns
from orchestrator.units import prefix, quantity, si
from orchestrator.viewers.draw import TIER_COLOURS
from orchestrator.viewers.summary import policy_text, rows

DPI = 130
HINT = "is this a directory written by `orchestrator launch`?"
TICK_COLUMNS = ("tick", "time_s", *columns(Out.TICKS))
NODE_COLUMNS = ("tick", "node", *columns(Out.NODES))
ENERGY = METRIC["energy_j"]
MAX_HEATMAP_COLUMNS = 1200  # longer runs are binned (max per bin) so that no tick disappears between pixels

# One colour per concept, the same in every figure.
C_GENERATED, C_COMPLETED, C_DROPPED, C_SYSTEM = "#7f7f7f", "#2ca02c", "#d62728", "#1f77b4"
C_QUEUED, C_UNDECIDED, C_IN_FLIGHT = "#1f77b4", "#ff7f0e", "#9ecae1"
C_RESPONSE, C_ENERGY, C_UTIL, C_OVERLOAD = "#6a3d9a", "#b15928", "#17becf", "#e377c2"
CAUSE_COLOURS = {"queue_full": "#e6550d", "expired": "#756bb1", "node_failure": "#8c564b", "link_loss": "#e7298a",
                 "link_broken": "#17becf"}


class PlotError(ValueError):
    """A run directory that cannot be plotted; the message is one line naming the file."""


@dataclass(frozen=True)
class RunData:
    """A run directory's contents, as arrays: ``ticks[col]`` has one value per tick, ``nodes[col]`` one row
    per node (in ``node_ids`` order) and one column per tick."""

    path: Path
    summary: dict[str, Any]
    ticks: dict[str, np.ndarray]
    node_ids: tuple[str, ...]
    nodes: dict[str, np.ndarray]
    tiers: dict[str, tuple[int, str]] | None = None  # node -> (tier, profile), when the scenario is at hand

    @property
    def x(self) -> np.ndarray:
        return self.ticks["tick"]

    @property
    def causes(self) -> tuple[str, ...]:
        """Drop causes, from the ``dropped_<cause>`` columns (so new causes need no change here)."""
        return tuple(k.removeprefix("dropped_") for k in self.ticks if k.startswith("dropped_"))

    @property
    def title(self) -> str:
        s = self.summary
        n = len(self.x)
        parts = [f"seed {s.get('seed', '?')}", f"{n} tick{'s' if n != 1 else ''} of {self.dt:g} s"]
        if s.get("policy"):
            parts.append(policy_text(s["policy"]))
        return f"{s.get('scenario', self.path.name)}, " + ", ".join(parts)

    @property
    def dt(self) -> float:
        return float(self.summary.get("dt") or 1.0)

    @property
    def tick_label(self) -> str:
        return f"tick (1 tick = {self.dt:g} s)"


# ----- reading -----

def load_run(run_dir: Path) -> RunData:
    """Read and check a run directory; every problem is a ``PlotError``."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise PlotError(f"{run_dir}: no such directory")
    names = ("summary.json", "ticks.csv", "nodes.csv")
    missing = [n for n in names if not (run_dir / n).is_file()]
    if missing:
        episodes = sorted(p.name for p in run_dir.iterdir() if (p / "ticks.csv").is_file())
        if episodes:
            raise PlotError(f"{run_dir}: no {', '.join(missing)}; it holds the run directories "
                            f"{', '.join(episodes[:5])}{' ...' if len(episodes) > 5 else ''}: plot one of those")
        raise PlotError(f"{run_dir}: no {', '.join(missing)} ({HINT})")
    summary = _read_summary(run_dir / "summary.json")
    ticks = _read_columns(run_dir / "ticks.csv", TICK_COLUMNS, text=())
    if ticks["tick"].size == 0:
        raise PlotError(f"{run_dir / 'ticks.csv'}: no ticks recorded (the file has a header only)")
    node_ids, nodes = _read_nodes(run_dir / "nodes.csv", ticks["tick"])
    return RunData(run_dir, summary, ticks, node_ids, nodes, node_tiers(summary, node_ids))


def node_tiers(summary: dict[str, Any], node_ids: tuple[str, ...]) -> dict[str, tuple[int, str]] | None:
    """Each node's (tier, profile), if the run's scenario can still be loaded (from its recorded source or
    as a bundled name) and is the very one that ran (same hash); else None, and figures group by node."""
    from orchestrator.scenario import ScenarioError, load_scenario

    for source in dict.fromkeys((summary.get("source"), summary.get("scenario"))):
        if not isinstance(source, str) or not source or source.startswith("<"):
            continue
        try:
            sc = load_scenario(source)
        except (ScenarioError, OSError, ValueError):  # only an enrichment: never a reason not to plot
            continue
        if sc.digest() == summary.get("scenario_hash") and set(sc.node) == set(node_ids):
            return {n.id: (n.tier, n.profile) for n in sc.nodes}
    return None


def _read_summary(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise PlotError(f"{path}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise PlotError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    if not isinstance(data, dict):
        raise PlotError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def _load_fast(path: Path, header: list[str], text: tuple[str, ...]) -> dict[str, np.ndarray]:
    numeric = [i for i, name in enumerate(header) if name not in text]
    kw: dict[str, Any] = {"delimiter": ",", "skiprows": 1, "quotechar": '"', "encoding": "utf-8"}
    values = np.loadtxt(path, usecols=numeric, ndmin=2, dtype=float, **kw)
    out = {header[i]: values[:, k] for k, i in enumerate(numeric)}
    for i, name in enumerate(header):
        if name in text:
            out[name] = np.loadtxt(path, usecols=[i], ndmin=1, dtype=str, **kw).astype(object)
    return {name: out[name] for name in header}


def _read_table(path: Path, required: tuple[str, ...], *, head_only: bool = False) -> tuple[list[str], list[list[str]]]:
    """Header and rows (with ``head_only``, the first row at most) as strings, checked for shape."""
    try:
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            rows = [row for _, row in zip(range(1), reader, strict=False)] if head_only else list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PlotError(f"{path}: cannot read: {exc}") from None
    if header is None:
        raise PlotError(f"{path}: the file is empty; expected a header with {', '.join(required)}")
    absent = [c for c in required if c not in header]
    if absent:
        raise PlotError(f"{path}: missing column{'s' if len(absent) > 1 else ''} {', '.join(absent)} ({HINT})")
    for line, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise PlotError(f"{path}:{line}: expected {len(header)} values, got {len(row)}")
    return header, rows


def _numbers(path: Path, column: str, values: list[str], first_line: int = 2) -> np.ndarray:
    """Floats; an empty cell (a tick without completions has no mean response time) is NaN."""
    out = np.empty(len(values))
    for i, v in enumerate(values):
        try:
            out[i] = float(v) if v != "" else math.nan
        except ValueError:
            raise PlotError(f"{path}:{i + first_line}: {column}: expected a number, got {v!r}") from None
    return out


def _read_columns(path: Path, required: tuple[str, ...], text: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Column name -> array. numpy parses well-formed files (fast: nodes.csv has a row per node per tick);
    anything it rejects (blank cells, bad values, ragged rows) goes through the csv module, which says where."""
    header, rows = _read_table(path, required, head_only=True)
    if rows:
        try:
            return _load_fast(path, header, text)
        except ValueError:
            pass
    header, rows = _read_table(path, required)
    columns = list(zip(*rows, strict=True)) if rows else [() for _ in header]
    return {name: (np.array(col, dtype=object) if name in text else _numbers(path, name, list(col)))
            for name, col in zip(header, columns, strict=True)}


def _read_nodes(path: Path, ticks: np.ndarray) -> tuple[tuple[str, ...], dict[str, np.ndarray]]:
    """nodes.csv to (node ids in file order, column -> nodes x ticks array)."""
    table = _read_columns(path, NODE_COLUMNS, text=("node",))
    names = table.pop("node")
    node_ids = tuple(dict.fromkeys(names.tolist()))
    n, t = len(node_ids), len(ticks)
    if len(names) != n * t:
        raise PlotError(f"{path}: {len(names)} rows, expected {n} nodes x {t} ticks = {n * t} "
                        "(does it belong to the same run as ticks.csv?)")
    shaped = {k: v.reshape(t, n).T for k, v in table.items()}  # rows are tick-major, nodes in canonical order
    if not (np.all(shaped["tick"] == ticks[None, :]) and all(
            names[i * n:(i + 1) * n].tolist() == list(node_ids) for i in (0, t - 1))):
        raise PlotError(f"{path}: rows are not one per node per tick in ticks.csv's order "
                        "(does it belong to the same run as ticks.csv?)")
    return node_ids, shaped


# ----- helpers -----

def window(n: int) -> int:
    """Rolling-mean window: about 1/25 of the run, 10 to 500 ticks (never more than the run)."""
    return max(1, min(n, int(np.clip(n // 25, 10, 500))))


def rolling_sum(values: np.ndarray, w: int) -> np.ndarray:
    """Trailing sums over ``w`` ticks (shorter at the start), NaN treated as 0."""
    c = np.cumsum(np.nan_to_num(values))
    out = c.copy()
    out[w:] = c[w:] - c[:-w]
    return out


def rolling_response(run: RunData, w: int) -> np.ndarray:
    """Mean response time of the completions in the last ``w`` ticks (weighted by completions, so it is
    the true mean over those tasks, not a mean of per-tick means); NaN where none completed."""
    done = run.ticks["completed"]
    total = rolling_sum(run.ticks["response_time_mean"] * done, w)
    count = rolling_sum(done, w)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.where(count > 0, count, 1), np.nan)


def _figure(run: RunData, rows: int, cols: int, size: tuple[float, float], subtitle: str, **kw: Any) -> tuple[
        Figure, np.ndarray]:
    fig, axes = plt.subplots(rows, cols, figsize=size, dpi=DPI, squeeze=False, layout="constrained", **kw)
    fig.suptitle(f"{subtitle} — {run.title}", fontsize=13, x=0.01, ha="left")
    return fig, axes


def _save(fig: Figure, path: Path) -> Path:
    try:
        fig.savefig(path, dpi=DPI, facecolor="white", format="png")
    except OSError as exc:
        raise PlotError(f"{path}: cannot write: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
    return path


def _empty(ax: Axes, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", color="#777777")


def _energy_scale(values: np.ndarray) -> tuple[float, str]:
    """The scale and unit ("µJ", "J", "kJ", ...) that an energy axis reaching ``max(values)`` reads best in."""
    name, scale = prefix(float(np.nanmax(values, initial=0.0)))
    return scale, f"{name}{ENERGY.unit}"


# ----- panels (each draws one family of series on one axes; the figures combine them) -----

def _time_axes(ax: Axes, run: RunData, title: str, ylabel: str) -> None:
    ax.set(title=title, xlabel=run.tick_label, ylabel=ylabel)
    ax.set_xlim(*((run.x[0], run.x[-1]) if len(run.x) > 1 else (run.x[0] - 0.5, run.x[0] + 0.5)))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylim(bottom=0)
    ax.grid(True, color="#eeeeee", linewidth=0.6)
    ax.set_axisbelow(True)


def rolling_mean(run: RunData, values: np.ndarray) -> tuple[np.ndarray, int]:
    w = window(len(run.x))
    return rolling_sum(values, w) / np.minimum(np.arange(1, len(values) + 1), w), w


def panel_tasks(ax: Axes, run: RunData) -> None:
    t = run.ticks
    ax.plot(run.x, np.cumsum(t["generated"]), color=C_GENERATED, linestyle="--", label="generated")
    ax.plot(run.x, np.cumsum(t["completed"]), color=C_COMPLETED, label="completed")
    ax.plot(run.x, np.cumsum(t["dropped"]), color=C_DROPPED, label="dropped")
    ax.plot(run.x, t["in_system"], color=C_SYSTEM, label="in the system (a level, not cumulative)")
    _time_axes(ax, run, "tasks", "tasks (cumulative)")
    ax.legend(fontsize=8, loc="upper left")


def panel_system(ax: Axes, run: RunData) -> None:
    t = run.ticks
    ax.stackplot(run.x, t["queued"], t["undecided"], t["in_flight"], colors=[C_QUEUED, C_UNDECIDED, C_IN_FLIGHT],
                 labels=["queued at workers", "awaiting a decision", "in flight on links"], alpha=0.9, linewidth=0)
    _time_axes(ax, run, "tasks in the system, by state (stacked)", "tasks")
    ax.legend(fontsize=8, loc="upper left")


def panel_response(ax: Axes, run: RunData, *, points: bool = True) -> None:
    rt = run.ticks["response_time_mean"]
    ratio = run.summary.get("completion_ratio")
    done = f" ({quantity(ratio, 'ratio')} of the generated)" if ratio is not None else ""
    _time_axes(ax, run, f"response time of completed tasks{done}", "response time (s)")
    if np.all(np.isnan(rt)):
        _empty(ax, "no task completed")
        return
    penalised = run.ticks["penalised_response_time"]  # so far; drops and unfinished tasks charged the penalty
    w = window(len(run.x))
    smooth = rolling_response(run, w)
    if points:
        ax.scatter(run.x, rt, s=7, color=C_RESPONSE, alpha=0.3, linewidths=0, label="mean of one tick's completions")
    ax.plot(run.x, smooth, color=C_RESPONSE, linewidth=1.8, label=f"rolling mean ({w} ticks)")
    ax.plot(run.x, penalised, color="#333333", linewidth=1.4,
            label="penalised response time so far (every generated task)")
    r = run.summary.get("response_time", {})
    top = max(float(np.nanmax(rt if points else smooth)), float(np.nanmax(penalised)))
    for key, style in (("p50", ":"), ("p95", "--")):
        if r.get(key) is not None:
            ax.axhline(r[key], color="#333333", linestyle=style, linewidth=1, label=f"{key} of the run: {r[key]:.3g} s")
            top = max(top, r[key])
    ax.set_ylim(0, top * 1.3)  # headroom for the legend
    ax.legend(fontsize=8, loc="upper left", ncols=2)


def panel_utilisation(ax: Axes, run: RunData) -> None:
    util, w = rolling_mean(run, 100 * run.ticks["utilisation"])
    over, _ = rolling_mean(run, run.ticks["overloaded_nodes"])
    ax.plot(run.x, util, color=C_UTIL, label="utilisation of all workers (%)")
    _time_axes(ax, run, f"load, rolling means over {w} ticks", "utilisation (%)")
    ax.set_ylim(0, max(5.0, float(np.nanmax(util)) * 1.3))
    right = ax.twinx()
    right.plot(run.x, over, color=C_OVERLOAD, label="overloaded nodes")
    right.set_ylabel("overloaded nodes", color=C_OVERLOAD)
    right.tick_params(axis="y", colors=C_OVERLOAD)
    right.set_ylim(0, max(1.0, float(np.nanmax(over)) * 1.3))
    ax.tick_params(axis="y", colors=C_UTIL)
    ax.yaxis.label.set_color(C_UTIL)
    lines = ax.get_lines() + right.get_lines()
    ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper left")


def panel_energy(ax: Axes, run: RunData) -> None:
    energy = np.cumsum(run.ticks[ENERGY.name])
    scale, unit = _energy_scale(energy)
    ax.plot(run.x, energy / scale, color=C_ENERGY, linewidth=1.8)
    _time_axes(ax, run, "energy, all nodes", f"energy, cumulative ({unit})")


def panel_figures(ax: Axes, run: RunData) -> None:
    """The run's key numbers, from summary.json, as text."""
    lines = rows(run.summary)
    ax.axis("off")
    ax.set_title("the run in numbers (summary.json)")
    step = min(0.075, 0.95 / max(len(lines), 1))
    for i, (k, v) in enumerate(lines):
        y = 0.95 - i * step
        ax.text(0.02, y, k, transform=ax.transAxes, fontsize=9.5, va="top", color="#444444")
        ax.text(0.98, y, v, transform=ax.transAxes, fontsize=9.5, va="top", ha="right", family="monospace")


# ----- figures -----

def plot_overview(run: RunData, path: Path) -> Path:
    fig, ax = _figure(run, 2, 3, (17, 9), "overview")
    panel_tasks(ax[0, 0], run)
    panel_system(ax[0, 1], run)
    panel_response(ax[0, 2], run, points=False)
    panel_utilisation(ax[1, 0], run)
    panel_energy(ax[1, 1], run)
    panel_figures(ax[1, 2], run)
    return _save(fig, path)


def _binned(values: np.ndarray, ticks: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """At most MAX_HEATMAP_COLUMNS columns: the max of each bin of ticks, and the bins' tick edges."""
    n = values.shape[1]
    size = max(1, math.ceil(n / MAX_HEATMAP_COLUMNS))
    cols = math.ceil(n / size)
    padded = np.full((values.shape[0], cols * size), -np.inf)
    padded[:, :n] = np.nan_to_num(values)
    binned = padded.reshape(values.shape[0], cols, size).max(axis=2)
    edges = np.append(ticks[::size], ticks[-1] + 1) - 0.5
    return binned, edges, size


def _tier_colour(tier: int) -> str:
    return TIER_COLOURS[tier % len(TIER_COLOURS)]


def _tier_names(run: RunData) -> dict[int, str]:
    """tier -> "tier 1 (2 nuc, 4 tx2)"."""
    assert run.tiers is not None
    groups: dict[int, dict[str, int]] = {}
    for tier, profile in run.tiers.values():
        groups.setdefault(tier, {})
        groups[tier][profile or "nodes"] = groups[tier].get(profile or "nodes", 0) + 1
    return {t: f"tier {t} ({', '.join(f'{c} {p}' for p, c in sorted(g.items()))})" for t, g in sorted(groups.items())}


def _node_ticklabels(ax: Axes, run: RunData, labels: list[str], axis: str) -> None:
    """Colour node names by tier (same colours as `orchestrator topology`), when tiers are known."""
    if run.tiers is None:
        return
    ticks = ax.get_yticklabels() if axis == "y" else ax.get_xticklabels()
    for label, nid in zip(ticks, labels, strict=True):
        label.set_color(_tier_colour(run.tiers[nid][0]))


def plot_queues(run: RunData, path: Path) -> Path:
    n = len(run.node_ids)
    fig, ax = _figure(run, 2, 1, (14, 3.6 + 0.2 * n), "queue length per node", sharex=True,
                      gridspec_kw={"height_ratios": [max(3.0, n / 6), 2.0]})
    top, bottom = ax[0, 0], ax[1, 0]
    values, edges, size = _binned(run.nodes["queue"], run.x)
    vmax = int(max(1, values.max()))
    base = plt.get_cmap("YlOrRd")
    if vmax <= 12:  # few levels: one colour per task count (0 = white), easier to read than a gradient
        cmap = ListedColormap(["#ffffff", *base(np.linspace(0.2, 1.0, vmax))])
        norm = BoundaryNorm(np.arange(-0.5, vmax + 1.5), cmap.N)
    else:  # many levels: square-root scale keeps short queues visible next to long ones; empty stays white
        cmap, norm = base.with_extremes(under="#ffffff"), PowerNorm(0.5, vmin=0.5, vmax=vmax)
    mesh = top.pcolormesh(edges, np.arange(n + 1) - 0.5, values, cmap=cmap, norm=norm, shading="flat",
                          rasterized=True)
    top.set_yticks(np.arange(n), run.node_ids, fontsize=7 if n > 20 else 8)
    _node_ticklabels(top, run, list(run.node_ids), "y")
    top.set_ylim(n - 0.5, -0.5)
    top.set_ylabel("node" + (" (names coloured by tier)" if run.tiers else ""))
    top.set_title("tasks queued at each worker, per tick" + (f" (max over bins of {size} ticks)" if size > 1 else ""))
    top.tick_params(labelbottom=True)
    bar = fig.colorbar(mesh, ax=top, pad=0.01, fraction=0.025, extend="neither")
    bar.set_label("queued tasks")
    if vmax <= 12:
        bar.set_ticks(range(vmax + 1))
    t = run.ticks
    bottom.plot(run.x, t["queued"], color=C_QUEUED, label="queued at workers, all nodes")
    bottom.plot(run.x, t["undecided"], color=C_UNDECIDED, label="awaiting a decision, all nodes")
    _time_axes(bottom, run, "network totals", "tasks")
    right = bottom.twinx()
    right.plot(run.x, t["in_flight"], color=C_IN_FLIGHT, linestyle="--", label="in flight on links (right axis)")
    right.set_ylabel("tasks in flight")
    right.set_ylim(bottom=0)
    lines = bottom.get_lines() + right.get_lines()
    bottom.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper left", ncols=3)
    bottom.set_ylim(0, max(1.0, float(max(t["queued"].max(), t["undecided"].max()))) * 1.35)
    right.set_ylim(0, max(1.0, float(t["in_flight"].max())) * 1.35)
    bottom.set_xlim(edges[0], edges[-1])  # whole heatmap cells (the x axis is shared)
    fig.colorbar(mesh, ax=bottom, pad=0.01, fraction=0.025).ax.set_visible(False)  # keeps both x axes aligned
    return _save(fig, path)


def plot_drops(run: RunData, path: Path) -> Path:
    fig, ax = _figure(run, 1, 2, (15, 5.5), "where the tasks went", width_ratios=[2.2, 1])
    left, right = ax[0, 0], ax[0, 1]
    cum = {c: np.cumsum(run.ticks[f"dropped_{c}"]) for c in run.causes}
    shown = [c for c in run.causes if cum[c][-1] > 0]
    if shown:
        left.stackplot(run.x, *(cum[c] for c in shown), colors=[CAUSE_COLOURS.get(c, "#999999") for c in shown],
                       labels=[f"dropped: {c.replace('_', ' ')} ({int(cum[c][-1])})" for c in shown], alpha=0.85,
                       linewidth=0)
    completed = np.cumsum(run.ticks["completed"])
    generated = np.cumsum(run.ticks["generated"])
    left.plot(run.x, completed, color=C_COMPLETED, linewidth=2, label=f"completed ({int(completed[-1])})")
    left.plot(run.x, generated, color=C_GENERATED, linestyle="--", label=f"generated ({int(generated[-1])})")
    none = [c.replace("_", " ") for c in run.causes if c not in shown]
    if none:
        left.plot([], [], " ", label="no drops: " + ", ".join(none))
    _time_axes(left, run, "cumulative drops by cause (stacked); completions for reference", "tasks (cumulative)")
    left.legend(fontsize=8, loc="upper left")
    # Right: rates, to see when each cause starts to bite.
    w = window(len(run.x))
    for c in shown:
        rate, _ = rolling_mean(run, run.ticks[f"dropped_{c}"] / run.dt)
        right.plot(run.x, rate, color=CAUSE_COLOURS.get(c, "#999999"), label=f"dropped: {c.replace('_', ' ')}")
    rate, _ = rolling_mean(run, run.ticks["completed"] / run.dt)
    right.plot(run.x, rate, color=C_COMPLETED, label="completed")
    _time_axes(right, run, f"rates, rolling mean over {w} ticks", "tasks per second")
    right.set_ylim(0, right.get_ylim()[1] * 1.25)
    right.legend(fontsize=8, loc="upper left", ncols=2)
    return _save(fig, path)


def plot_response_time(run: RunData, path: Path) -> Path:
    fig, ax = _figure(run, 1, 2, (15, 5.5), "response time (result back at the source − task creation)",
                      width_ratios=[2.2, 1], sharey=True)
    left, right = ax[0, 0], ax[0, 1]
    panel_response(left, run)
    rt, done = run.ticks["response_time_mean"], run.ticks["completed"]
    ok = ~np.isnan(rt) & (done > 0)
    if ok.any():
        right.hist(rt[ok], bins=np.linspace(0, float(rt[ok].max()) * 1.0001, 41), weights=done[ok], color=C_RESPONSE,
                   alpha=0.8, orientation="horizontal")
        r = run.summary.get("response_time", {})
        for key, style in (("mean", "-"), ("p50", ":"), ("p95", "--")):
            if r.get(key) is not None:
                right.axhline(r[key], color="#333333", linestyle=style, linewidth=1, label=f"{key} {r[key]:.3g} s")
        right.legend(fontsize=8, loc="upper right")
    else:
        _empty(right, "no task completed")
    right.set(title="distribution over completed tasks", xlabel="completed tasks (by their tick's mean)")
    right.grid(True, color="#eeeeee", linewidth=0.6)
    right.set_axisbelow(True)
    return _save(fig, path)


def plot_energy(run: RunData, path: Path, top: int = 8) -> Path:
    e = run.summary.get(ENERGY.name, {})
    parts = ", ".join(f"{p.label} {si(e[p.key], ENERGY.unit)}" for p in ENERGY.parts if p.key in e)
    fig, ax = _figure(run, 1, 2, (15, max(5.5, 1.8 + 0.17 * len(run.node_ids))),
                      "energy" + (f" ({parts})" if parts else ""), width_ratios=[2.2, 1])
    left, right = ax[0, 0], ax[0, 1]
    total = np.cumsum(run.ticks[ENERGY.name])
    scale, unit = _energy_scale(total)
    per_node = np.cumsum(np.nan_to_num(run.nodes[ENERGY.name]), axis=1) / scale
    final = per_node[:, -1]
    order = [int(i) for i in np.argsort(-final, kind="stable")]
    if run.tiers is not None:  # stacked by tier, bars coloured by tier
        names = _tier_names(run)
        tiers = list(names)
        series = [per_node[[i for i, nid in enumerate(run.node_ids) if run.tiers[nid][0] == t]].sum(axis=0)
                  for t in tiers]
        labels, colours = [names[t] for t in tiers], [_tier_colour(t) for t in tiers]
        bar_colours = [_tier_colour(run.tiers[run.node_ids[i]][0]) for i in order]
        heading = "cumulative energy, stacked by tier"
    else:  # stacked by the largest consumers, the rest in grey
        shown = [i for i in order[:top] if final[i] > 0]
        rest = [i for i in order if i not in shown]
        series = [per_node[i] for i in shown]
        labels = [run.node_ids[i] for i in shown]
        colours = list(plt.get_cmap("tab10").colors[:len(shown)])
        if rest:
            series.append(per_node[rest].sum(axis=0))
            labels.append(f"other {len(rest)} nodes")
            colours.append("#c7c7c7")
        bar_colours = [colours[shown.index(i)] if i in shown else "#c7c7c7" for i in order]
        heading = f"cumulative energy, stacked by node (the {len(shown)} largest consumers)"
    left.stackplot(run.x, *series, labels=labels, colors=colours, alpha=0.9, linewidth=0)
    left.plot(run.x, total / scale, color="black", linewidth=1.2, label="total")
    _time_axes(left, run, heading, f"energy, cumulative ({unit})")
    left.legend(fontsize=8, loc="upper left", ncols=1 if run.tiers else 2)
    ys = np.arange(len(order))
    names_in_order = [run.node_ids[i] for i in order]
    right.barh(ys, final[order], color=bar_colours)
    right.set_yticks(ys, names_in_order, fontsize=7 if len(order) > 20 else 8)
    right.set_ylim(len(order) - 0.5, -0.5)
    right.set(title="energy per node over the run", xlabel=f"energy ({unit})")
    right.grid(axis="x", color="#eeeeee")
    right.set_axisbelow(True)
    return _save(fig, path)


FIGURES: dict[str, Callable[[RunData, Path], Path]] = {
    "overview.png": plot_overview,
    "queues.png": plot_queues,
    "drops.png": plot_drops,
    "response_time.png": plot_response_time,
    "energy.png": plot_energy,
}


def plot_run(run_dir: Path, out_dir: Path | None = None) -> list[Path]:
    """Write every figure of a run directory to ``out_dir`` (default ``run_dir/plots``); return their paths."""
    run = load_run(Path(run_dir))
    out = Path(out_dir) if out_dir is not None else run.path / "plots"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PlotError(f"{out}: cannot create the output directory: {exc.strerror or exc}") from None
    return [draw(run, out / name) for name, draw in FIGURES.items()]


# ----- command line -----

def cmd_plot(args: argparse.Namespace) -> int:
    try:
        paths = plot_run(Path(args.run_dir), Path(args.out) if args.out else None)
    except PlotError as exc:
        print(exc, file=sys.stderr, flush=True)
        return 2
    for p in paths:
        print(p)
    return 0
