"""``orchestrator topology``: a picture of a scenario's network, to check it before launching anything.

Nodes sit at their positions in metres (a seeded spring layout when the scenario gives none), coloured
by tier, shaped by role (controller / worker only / no worker), outlined when they are task sources,
sized by the log of their capacity; links are drawn once per node pair, wider for faster links.
Labels are placed greedily around their nodes so that pairs of devices a metre apart stay legible.

With moving nodes, ``--frames N`` draws instead a strip of N frames: where the nodes are at evenly spaced ticks
of an episode (its seed's walks), the links that exist then, and each moving node's path so far.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: never open a window, never need a display

import matplotlib.pyplot as plt
import networkx as nx
import numpy as np
from matplotlib.axes import Axes
from matplotlib.legend import Legend
from matplotlib.lines import Line2D

from node_runtime.model.positions import Positions
from node_runtime.model.spec import NodeSpec, Scenario

DPI = 150
FIGSIZE = (12.0, 8.5)
TIER_COLOURS = ("#4C9BE8", "#F2A93B", "#D1495B", "#58B368", "#8E6CC8", "#8C8C8C")
# Log scales anchored at the scenario's smallest value, with a fixed step per factor of 10, so that
# a 5 % difference in rate looks like one and a 20x difference in capacity looks like a lot more.
NODE_AREA = (70.0, 300.0, 620.0)  # marker area in pt²: smallest capacity, added per decade, most
LINK_WIDTH = (0.6, 3.0, 3.6)  # line width in points: slowest link, added per decade, most
SOURCE_EDGE = "#111111"


def draw_topology(scenario: Scenario, path: Path, *, title: str | None = None) -> Path:
    """Write a PNG of the scenario's network to ``path`` (parent folders created) and return the path."""
    path = Path(path)
    graph = _graph(scenario)
    pos, measured = _positions(scenario, graph)
    fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
    ax = fig.add_axes((0.06, 0.07, 0.66, 0.80))
    try:
        areas = _node_areas(scenario.nodes)
        widths = _link_widths(graph)
        _set_limits(ax, pos, measured)
        nx.draw_networkx_edges(graph, pos, ax=ax, width=[widths[e] for e in graph.edges], edge_color="#6b6b6b",
                               alpha=_edge_alpha(graph.number_of_edges()), node_size=0)
        for node in sorted(scenario.nodes, key=lambda n: -areas[n.id]):  # small on top of big: all stay visible
            _draw_node(ax, node, pos[node.id], areas[node.id])
        _place_labels(fig, ax, scenario, pos, areas)
        _legends(fig, ax, scenario, areas, graph)
        heading = title or scenario.name
        fig.suptitle(f"{heading} — {len(scenario.nodes)} nodes, {scenario.undirected_links} links, "
                     f"{len(scenario.controllers)} controllers, {len(scenario.clients)} task sources",
                     x=0.06, ha="left", fontsize=14, fontweight="bold")
        description = str(scenario.extra.get("description", ""))
        if description:
            fig.text(0.06, 0.925, description, ha="left", fontsize=10, color="#444444")
        if measured:
            # networkx's drawing helpers hide the ticks; positions are metres, so show them.
            ax.tick_params(bottom=True, left=True, labelbottom=True, labelleft=True, labelsize=8)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
            ax.grid(True, color="#eeeeee", linewidth=0.6, zorder=0)
            ax.set_axisbelow(True)
        else:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_xlabel("schematic layout (the scenario gives no distinct positions)")
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=DPI, facecolor="white", format="png")
    finally:
        plt.close(fig)
    return path


# ----- moving nodes: a strip of frames -----

FRAME_COLUMNS = 3
FRAME_WIDTH = 5.2  # inches per frame
TRAIL = "#7a7a7a"


def frame_ticks(scenario: Scenario, frames: int, every: int | None = None) -> list[int]:
    """``frames`` ticks from 0, ``every`` apart (by default spread over the episode), none past its last."""
    last = scenario.episode_ticks - 1
    step = every if every is not None else max(1, last // max(frames - 1, 1))
    return sorted({min(k * step, last) for k in range(frames)})


def draw_frames(scenario: Scenario, path: Path, ticks: list[int], *, seed: int | None = None,
                title: str | None = None) -> Path:
    """Write a PNG of the nodes' positions at each of ``ticks`` (the walks of ``seed``, by default the
    scenario's), one frame each: the links that exist at that tick and each moving node's path so far."""
    path = Path(path)
    seed = scenario.seed if seed is None else seed
    where = Positions(scenario)
    where.reset(seed)
    ids = [n.id for n in scenario.nodes]
    track = {n: [where.at(n, k) for k in range(ticks[-1] + 1)] for n in ids}
    points = np.array([xy for n in ids for xy in (track[n] if n in scenario.moving else track[n][:1])])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = 0.06 * float(max((hi - lo).max(), 1.0))
    areas = {k: v / 3 for k, v in _node_areas(scenario.nodes).items()}
    pairs = {frozenset((lk.src, lk.dst)) for lk in scenario.links}
    rows = math.ceil(len(ticks) / FRAME_COLUMNS)
    cols = min(len(ticks), FRAME_COLUMNS)
    span = hi - lo + 2 * pad
    height = FRAME_WIDTH * min(max(float(span[1] / span[0]), 0.3), 2.0) + 0.6  # a frame's axes keep metres square
    fig, axes = plt.subplots(rows, cols, figsize=(FRAME_WIDTH * cols, height * rows + 0.5), dpi=DPI, squeeze=False)
    try:
        for ax, tick in zip(axes.flat, ticks, strict=False):
            at = {n: track[n][tick] for n in ids}
            for a, b in (sorted(p, key=scenario.index.__getitem__) for p in pairs):
                if not scenario.moving_link(a, b) or where.in_range(a, b, tick):
                    ax.plot(*zip(at[a], at[b], strict=True), color="#6b6b6b", linewidth=0.8, alpha=0.6, zorder=1)
            for n in scenario.moving:
                ax.plot(*zip(*track[n][:tick + 1], strict=True), color=TRAIL, linewidth=0.7, alpha=0.5,
                        linestyle=":", zorder=2)
            for node in scenario.nodes:
                _draw_node(ax, node, at[node.id], areas[node.id])
                ax.annotate(node.id, at[node.id], xytext=(4, 4), textcoords="offset points", fontsize=7, zorder=4)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.set_aspect("equal", adjustable="box")
            ax.set_title(f"tick {tick} ({tick * scenario.dt:g} s)", fontsize=10)
            ax.tick_params(labelsize=7)
            ax.grid(True, color="#eeeeee", linewidth=0.6)
            ax.set_axisbelow(True)
        for ax in list(axes.flat)[len(ticks):]:
            ax.set_axis_off()
        radio = scenario.radio
        fig.suptitle(f"{title or scenario.name} — positions over time, seed {seed}; links of moving nodes within "
                     f"{radio.range_m:g} m; dotted: paths so far", x=0.02, ha="left", fontsize=12,
                     fontweight="bold")
        fig.tight_layout(rect=(0, 0, 1, 1 - 0.5 / fig.get_size_inches()[1]))
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=DPI, facecolor="white", format="png")
    finally:
        plt.close(fig)
    return path


# ----- geometry -----

def _graph(scenario: Scenario) -> nx.Graph:
    """Undirected graph, one edge per node pair, with the mean of both directions' rates."""
    g = nx.Graph()
    g.add_nodes_from(n.id for n in scenario.nodes)
    rates: dict[frozenset[str], list[float]] = {}
    for lk in scenario.links:
        rates.setdefault(frozenset((lk.src, lk.dst)), []).append(lk.rate_bps)
    for lk in scenario.links:
        key = frozenset((lk.src, lk.dst))
        if not g.has_edge(lk.src, lk.dst):
            g.add_edge(lk.src, lk.dst, rate=float(np.mean(rates[key])))
    return g


def _positions(scenario: Scenario, graph: nx.Graph) -> tuple[dict[str, tuple[float, float]], bool]:
    """Positions in metres, or a deterministic spring layout when every node sits at the same point."""
    pos = {n.id: (float(n.position[0]), float(n.position[1])) for n in scenario.nodes}
    if len(set(pos.values())) > 1:
        return pos, True
    layout = nx.spring_layout(graph, seed=0)
    return {k: (float(v[0]), float(v[1])) for k, v in layout.items()}, False


def _set_limits(ax: Axes, pos: dict[str, tuple[float, float]], measured: bool) -> None:
    """Equal scales in x and y (a metre is a metre both ways), filling the axes box, with room around
    the outermost nodes for their labels."""
    xy = np.array(list(pos.values()))
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = float(max((hi - lo).max(), 1.0 if measured else 0.1))
    half = (hi - lo) / 2 + 0.12 * span
    box = ax.get_position()
    fig_w, fig_h = ax.figure.get_size_inches()
    ratio = (box.height * fig_h) / (box.width * fig_w)  # height / width of the axes, in inches
    half = np.array([max(half[0], half[1] / ratio), max(half[1], half[0] * ratio)])
    centre = (lo + hi) / 2
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])


def _scale(values: dict[str, float], scale: tuple[float, float, float]) -> dict[str, float]:
    """``base + per_decade * log10(v / smallest v)``, capped at ``most``."""
    base, per_decade, most = scale
    lo = min(values.values(), default=1.0)
    return {k: min(most, base + per_decade * math.log10(v / lo)) for k, v in values.items()}


def _node_areas(nodes: tuple[NodeSpec, ...]) -> dict[str, float]:
    """Workers by capacity; nodes without a worker have no capacity to show and get the smallest size."""
    areas = _scale({n.id: n.capacity for n in nodes if n.has("worker")}, NODE_AREA)
    return {n.id: areas.get(n.id, NODE_AREA[0]) for n in nodes}


def _link_widths(graph: nx.Graph) -> dict[tuple[str, str], float]:
    by_edge = _scale({f"{a}\0{b}": d["rate"] for a, b, d in graph.edges(data=True)}, LINK_WIDTH)
    return {(a, b): by_edge[f"{a}\0{b}"] for a, b in graph.edges}


def _edge_alpha(edges: int) -> float:
    """Fainter links in dense networks, so that nodes and labels stay on top visually."""
    return float(np.clip(0.75 - edges / 160, 0.3, 0.75))


# ----- nodes -----

def _marker(node: NodeSpec) -> str:
    if not node.has("worker"):
        return "D"
    return "o" if node.has("controller") else "s"


def _draw_node(ax: Axes, node: NodeSpec, xy: tuple[float, float], area: float) -> None:
    colour = TIER_COLOURS[node.tier % len(TIER_COLOURS)]
    edge, lw = (SOURCE_EDGE, 2.2) if node.has("client") else ("white", 1.0)
    ax.scatter([xy[0]], [xy[1]], s=area, c=[colour], marker=_marker(node), edgecolors=edge, linewidths=lw,
               zorder=3)


LABEL_GAPS = (3.0, 14.0, 30.0, 50.0)  # px between a marker and its label; beyond the second, a leader line
LABEL_DIRECTIONS = tuple((math.cos(a), math.sin(a)) for a in np.radians(
    [90, 270, 0, 180, 45, 135, 315, 225, 60, 120, 300, 240, 30, 150, 330, 210]))  # above and below first


def _place_labels(fig: plt.Figure, ax: Axes, scenario: Scenario, pos: dict[str, tuple[float, float]],
                  areas: dict[str, float]) -> None:
    """Greedy label placement in pixels, so that devices a metre apart keep legible names: each label
    takes the nearest spot around its node that overlaps no placed label, no marker and stays inside the
    axes (or, failing that, the spot that overlaps least), most crowded nodes first."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    to_data = ax.transData.inverted().transform
    centres = {nid: ax.transData.transform(xy) for nid, xy in pos.items()}
    radius = {nid: math.sqrt(areas[nid]) / 2 * DPI / 72 for nid in pos}  # marker area pt² -> radius px
    markers = np.array([[*centres[n.id], radius[n.id]] for n in scenario.nodes])
    font = 7 if len(scenario.nodes) > 20 else 8
    crowding = {a: sum(np.hypot(*(centres[a] - centres[b])) < 60 for b in pos if b != a) for a in pos}
    placed: list[np.ndarray] = []
    for node in sorted(scenario.nodes, key=lambda n: (-crowding[n.id], scenario.index[n.id])):
        probe = ax.text(0, 0, node.id, fontsize=font, transform=None)
        extent = probe.get_window_extent(renderer)
        probe.remove()
        size = (extent.width + 4, extent.height + 2)
        box, gap = _label_box(centres[node.id], radius[node.id], size, placed, markers, frame)
        placed.append(box)
        x, y = to_data(((box[0] + box[2]) / 2, (box[1] + box[3]) / 2))
        ax.text(x, y, node.id, fontsize=font, ha="center", va="center", zorder=5,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.75})
        if gap > LABEL_GAPS[1]:
            end = to_data(_box_edge_towards(box, centres[node.id]))
            ax.plot([pos[node.id][0], end[0]], [pos[node.id][1], end[1]], color="#888888", linewidth=0.6,
                    zorder=2.5)


def _label_box(centre: np.ndarray, r: float, size: tuple[float, float], placed: list[np.ndarray],
               markers: np.ndarray, frame) -> tuple[np.ndarray, float]:
    """The label's box (x0, y0, x1, y1 in px) and its gap from the marker."""
    w, h = size
    best: tuple[float, np.ndarray, float] | None = None
    for gap in LABEL_GAPS:
        for dx, dy in LABEL_DIRECTIONS:
            # Box centre on the ray (dx, dy), with the box's border r + gap px from the node's centre.
            t = min(w / 2 / max(abs(dx), 1e-9), h / 2 / max(abs(dy), 1e-9))
            cx, cy = centre[0] + dx * (r + gap + t), centre[1] + dy * (r + gap + t)
            box = np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
            cost = _overlap_cost(box, placed, markers, frame)
            if cost == 0:
                return box, gap
            if best is None or cost < best[0]:
                best = (cost, box, gap)
    assert best is not None
    return best[1], best[2]


def _overlap_cost(box: np.ndarray, placed: list[np.ndarray], markers: np.ndarray, bbox) -> float:
    """Overlap area (px²) with placed labels and node markers, and a large penalty outside the axes."""
    cost = 0.0
    for other in placed:
        ow = min(box[2], other[2]) - max(box[0], other[0])
        oh = min(box[3], other[3]) - max(box[1], other[1])
        if ow > 0 and oh > 0:
            cost += ow * oh * 3
    # Markers approximated by their bounding squares.
    ow = np.minimum(box[2], markers[:, 0] + markers[:, 2]) - np.maximum(box[0], markers[:, 0] - markers[:, 2])
    oh = np.minimum(box[3], markers[:, 1] + markers[:, 2]) - np.maximum(box[1], markers[:, 1] - markers[:, 2])
    cost += float(np.sum(np.clip(ow, 0, None) * np.clip(oh, 0, None)))
    if box[0] < bbox.x0 or box[2] > bbox.x1 or box[1] < bbox.y0 or box[3] > bbox.y1:
        cost += 1e6
    return cost


def _box_edge_towards(box: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    """The point of the box's border closest to ``point`` (where a leader line ends)."""
    return (float(np.clip(point[0], box[0], box[2])), float(np.clip(point[1], box[1], box[3])))


# ----- legends -----

def _capacity_text(cycles_per_s: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if cycles_per_s >= scale:
            return f"{cycles_per_s / scale:.3g} {unit}cycles/s"
    return f"{cycles_per_s:.3g} cycles/s"


def _rate_text(bps: float) -> str:
    for unit, scale in (("Gbit/s", 1e9), ("Mbit/s", 1e6), ("kbit/s", 1e3)):
        if bps >= scale:
            return f"{bps / scale:.3g} {unit}"
    return f"{bps:.3g} bit/s"


def _profile_counts(profiles: dict[str, int]) -> str:
    """"2 nuc, 4 tx2"; nodes without a hardware profile are counted as "nodes"."""
    if set(profiles) == {""}:
        return f"{profiles['']} node{'s' if profiles[''] != 1 else ''}"
    return ", ".join(f"{c} {p or 'other'}" for p, c in sorted(profiles.items(), key=lambda pc: (not pc[0], pc[0])))


def _legends(fig: plt.Figure, ax: Axes, scenario: Scenario, areas: dict[str, float], graph: nx.Graph) -> None:
    """Three legends right of the drawing: tiers (colours), roles (shapes, outline), scales (size, width)."""
    tiers: dict[int, dict[str, int]] = {}
    for n in scenario.nodes:
        profiles = tiers.setdefault(n.tier, {})
        profiles[n.profile] = profiles.get(n.profile, 0) + 1
    tier_handles = [
        Line2D([], [], marker="o", linestyle="", markersize=9, markerfacecolor=TIER_COLOURS[t % len(TIER_COLOURS)],
               markeredgecolor="white", label=f"tier {t}: {_profile_counts(tiers[t])}")
        for t in sorted(tiers)
    ]
    grey = "#bbbbbb"
    role_handles = [
        Line2D([], [], marker="o", linestyle="", markersize=9, markerfacecolor=grey, markeredgecolor="white",
               label="controller (agent) + worker"),
        Line2D([], [], marker="s", linestyle="", markersize=9, markerfacecolor=grey, markeredgecolor="white",
               label="worker only"),
    ]
    if any(not n.has("worker") for n in scenario.nodes):
        role_handles.append(Line2D([], [], marker="D", linestyle="", markersize=8, markerfacecolor=grey,
                                   markeredgecolor="white", label="no worker"))
    role_handles.append(Line2D([], [], marker="o", linestyle="", markersize=9, markerfacecolor=grey,
                               markeredgecolor=SOURCE_EDGE, markeredgewidth=2.2, label="task source (dark outline)"))
    caps = sorted({n.capacity for n in scenario.nodes if n.has("worker")})
    scale_handles = []
    for cap in sorted({caps[0], caps[-1]} if caps else ()):
        area = next(areas[n.id] for n in scenario.nodes if n.has("worker") and n.capacity == cap)
        scale_handles.append(Line2D([], [], marker="o", linestyle="", markersize=math.sqrt(area),
                                    markerfacecolor="#dddddd", markeredgecolor="#777777",
                                    label=f"capacity {_capacity_text(cap)}"))
    if graph.number_of_edges():
        rates = sorted(d["rate"] for _, _, d in graph.edges(data=True))
        widths = _link_widths(graph)
        by_rate = {graph.edges[e]["rate"]: widths[e] for e in graph.edges}
        for rate in sorted({rates[0], rates[-1]}):
            scale_handles.append(Line2D([], [], color="#6b6b6b", linewidth=by_rate[rate],
                                        label=f"link {_rate_text(rate)}"))
    top = 1.0
    renderer = fig.canvas.get_renderer()
    to_axes = ax.transAxes.inverted()
    groups = ((tier_handles, "colour: tier", 0.5), (role_handles, "shape: role", 0.5),
              (scale_handles, "size: log capacity; width: log rate", 1.2))
    for handles, heading, spacing in groups:  # stacked top to bottom, each just below the previous one
        legend = Legend(ax, handles, [h.get_label() for h in handles], title=heading, loc="upper left",
                        bbox_to_anchor=(1.02, top), frameon=False, fontsize=9, title_fontsize=10, alignment="left",
                        labelspacing=spacing, borderaxespad=0.0)
        ax.add_artist(legend)
        bottom = to_axes.transform(legend.get_window_extent(renderer))[0][1]
        top = bottom - 0.04


# ----- command line -----

def cmd_topology(args: argparse.Namespace, run_dir: Callable[[str], Path]) -> int:
    """Scenario errors propagate to the CLI's main (one line per problem, exit 2); so does nothing else.
    Without --png the picture goes to ``run_dir(scenario name)/topology.png``."""
    from orchestrator.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    if args.frames is not None and not scenario.moving:
        print(f"orchestrator topology: --frames: no node of {scenario.name} moves (frames show moving nodes)",
              file=sys.stderr, flush=True)
        return 2
    png = Path(args.png) if args.png else run_dir(scenario.name) / "topology.png"
    try:
        if args.frames is not None:
            out = draw_frames(scenario, png, frame_ticks(scenario, args.frames, args.every), seed=args.seed,
                              title=args.title)
        else:
            out = draw_topology(scenario, png, title=args.title)
    except OSError as exc:
        print(f"orchestrator topology: cannot write {png}: {exc.strerror or exc}", file=sys.stderr, flush=True)
        return 2
    print(out)
    return 0
