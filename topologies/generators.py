"""Synthetic topologies, built with networkx and reachable from YAML as ``topology: {generator: ...}``.

Every generator returns a ``Draft`` whose node ids are ``<prefix><i>`` and whose positions are in
metres (they set the radio distances). ``profile`` names the hardware profile of every node;
``n_tier`` takes one profile per tier instead.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

import networkx as nx

from topologies.draft import Draft, DraftLink, DraftNode


class GeneratorError(ValueError):
    pass


# Far past any run on one machine (10,000 nodes take 6.5 GB over Zenoh); beyond them, building the graph
# alone would exhaust memory or overflow before a line of the model runs
MAX_NODES = 1_000_000
MAX_LINKS = 10_000_000


def _check_size(kind: str, nodes: int, links: int = 0) -> None:
    if nodes > MAX_NODES:
        raise GeneratorError(f"{kind}: {nodes:,} nodes; expected at most {MAX_NODES:,}")
    if links > MAX_LINKS:
        raise GeneratorError(f"{kind}: {links:,} links; expected at most {MAX_LINKS:,}")


def _draft(g: nx.Graph, pos: dict[Any, tuple[float, float]], profile: dict[Any, str] | str, prefix: str) -> Draft:
    order = list(g.nodes)
    name = {v: f"{prefix}{i}" for i, v in enumerate(order)}
    prof = (lambda v: profile) if isinstance(profile, str) else profile.__getitem__
    nodes = [DraftNode(name[v], prof(v), (float(pos[v][0]), float(pos[v][1]))) for v in order]
    links = [DraftLink(name[a], name[b]) for a, b in g.edges]
    return Draft(nodes, links)


def _circle(n: int, spacing: float) -> dict[int, tuple[float, float]]:
    """Positions on a circle whose neighbouring points are ``spacing`` metres apart."""
    radius = spacing / (2 * math.sin(math.pi / n)) if n > 1 else 0.0
    return {i: (radius * math.cos(2 * math.pi * i / n), radius * math.sin(2 * math.pi * i / n)) for i in range(n)}


def ring(n: int, profile: str, spacing: float = 20.0, prefix: str = "n") -> Draft:
    if n < 3:
        raise GeneratorError("ring: n must be at least 3")
    _check_size("ring", n)
    return _draft(nx.cycle_graph(n), _circle(n, spacing), profile, prefix)


def fully_connected(n: int, profile: str, spacing: float = 20.0, prefix: str = "n") -> Draft:
    if n < 2:
        raise GeneratorError("fully_connected: n must be at least 2")
    _check_size("fully_connected", n, n * (n - 1) // 2)
    return _draft(nx.complete_graph(n), _circle(n, spacing), profile, prefix)


def grid(rows: int, cols: int, profile: str, spacing: float = 20.0, prefix: str = "n") -> Draft:
    if rows < 1 or cols < 1 or rows * cols < 2:
        raise GeneratorError("grid: rows and cols must be >= 1 and make at least 2 nodes")
    _check_size("grid", rows * cols)
    g = nx.grid_2d_graph(rows, cols)
    return _draft(g, {v: (v[1] * spacing, v[0] * spacing) for v in g.nodes}, profile, prefix)


def random_geometric(n: int, radius: float, profile: str, size: float = 100.0, seed: int = 0,
                     prefix: str = "n") -> Draft:
    """n nodes uniform in a size x size square, linked when closer than ``radius`` metres."""
    if n < 2:
        raise GeneratorError("random_geometric: n must be at least 2")
    _check_size("random_geometric", n)
    g = nx.random_geometric_graph(n, radius / size, seed=seed)
    pos = {v: (p[0] * size, p[1] * size) for v, p in nx.get_node_attributes(g, "pos").items()}
    return _draft(g, pos, profile, prefix)


def bridged_clusters(clusters: int, size: int, profile: str, spacing: float = 20.0,
                     cluster_distance: float = 100.0, prefix: str = "n") -> Draft:
    """Fully connected clusters in a row; each cluster's first node links to the next cluster's first."""
    if clusters < 1 or size < 1 or clusters * size < 2:
        raise GeneratorError("bridged_clusters: need at least 2 nodes in all")
    _check_size("bridged_clusters", clusters * size, clusters * size * (size - 1) // 2)
    g = nx.Graph()
    pos = {}
    heads = []
    for c in range(clusters):
        members = [(c, i) for i in range(size)]
        g.add_nodes_from(members)
        g.add_edges_from((u, v) for k, u in enumerate(members) for v in members[k + 1:])
        for i, xy in _circle(size, spacing).items():
            pos[(c, i)] = (xy[0] + c * cluster_distance, xy[1])
        heads.append(members[0])
    g.add_edges_from(itertools.pairwise(heads))
    return _draft(g, pos, profile, prefix)


def n_tier(tiers: list[int], profiles: list[str], spacing: float = 20.0, tier_distance: float = 50.0,
           cloud: str | None = None, prefix: str = "n") -> Draft:
    """A hierarchy: node j of tier k links to parent j mod n_{k+1} of tier k+1 (tier 0 at the edge).

    With ``cloud`` (a profile name), one more node links to every node of the top tier.
    """
    if not tiers or any(n < 1 for n in tiers):
        raise GeneratorError("n_tier: tiers must be a non-empty list of positive counts")
    if len(profiles) != len(tiers):
        raise GeneratorError(f"n_tier: {len(tiers)} tiers need {len(tiers)} profiles, got {len(profiles)}")
    _check_size("n_tier", sum(tiers) + (cloud is not None))
    g = nx.Graph()
    pos = {}
    prof = {}
    for k, n in enumerate(tiers):
        width = (n - 1) * spacing
        for j in range(n):
            g.add_node((k, j))
            pos[(k, j)] = (j * spacing - width / 2, k * tier_distance)
            prof[(k, j)] = profiles[k]
        if k > 0:  # each parent's children in increasing order, as every node's neighbours are listed
            g.add_edges_from(((k - 1, child), (k, child % n)) for child in range(tiers[k - 1]))
    if cloud is not None:
        top = len(tiers) - 1
        g.add_node("cloud")
        pos["cloud"] = (0.0, len(tiers) * tier_distance)
        prof["cloud"] = cloud
        g.add_edges_from(("cloud", (top, j)) for j in range(tiers[top]))
    if g.number_of_nodes() < 2:
        raise GeneratorError("n_tier: need at least 2 nodes in all")
    return _draft(g, pos, prof, prefix)


GENERATORS: dict[str, Callable[..., Draft]] = {
    "ring": ring,
    "grid": grid,
    "random_geometric": random_geometric,
    "fully_connected": fully_connected,
    "bridged_clusters": bridged_clusters,
    "n_tier": n_tier,
}
