"""Import an Ether topology (JSON: ``nodes`` by name, ``links.neighbours`` by numeric id).

Ether (Rausch et al., HotEdge'20) describes devices by CPU (``cpu_milis``) and memory. Following the
PeersimGym reference mapping, a node becomes one core of cpu_milis * 1000 instructions per second,
and its buffer holds memory / (expected task size) tasks. The profile is the name's prefix
(``rpi3_4`` -> ``rpi3``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from topologies.draft import Draft, DraftLink, DraftNode


class EtherError(ValueError):
    pass


def profile_of(name: str) -> str:
    return name.rsplit("_", 1)[0] if "_" in name else name


def load_ether(path: Path, task_bytes: float, wired_rates: bool = False) -> Draft:
    """Read an Ether JSON file. ``task_bytes``: expected input + output size of a task, for buffers."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise EtherError(f"file not found: {path}") from None
    except json.JSONDecodeError as exc:
        raise EtherError(f"{path}: invalid JSON: {exc}") from None
    try:
        raw_nodes = data["nodes"]
        neighbours = data["links"]["neighbours"]
    except (KeyError, TypeError):
        raise EtherError(f"{path}: expected an Ether topology with 'nodes' and 'links.neighbours'") from None
    by_id: dict[str, str] = {}
    nodes = []
    for name, node in raw_nodes.items():
        try:
            cap = node["capacity"]
            x, y = node["coordinates"]
            by_id[str(node["id"])] = name
            nodes.append(DraftNode(
                id=name,
                profile=profile_of(name),
                position=(float(x), float(y)),
                hints={"cores": 1, "frequency": float(cap["cpu_milis"]) * 1000.0,
                       "buffer": max(1, math.floor(float(cap["memory"]) / task_bytes))},
            ))
        except (KeyError, TypeError, ValueError):
            raise EtherError(f"{path}: node {name!r} lacks capacity.cpu_milis/memory or coordinates") from None
    bandwidth: dict[frozenset[str], float] = {}
    if wired_rates:
        for info in data["links"].get("path_info", []):
            a, b = by_id.get(str(info["source"])), by_id.get(str(info["target"]))
            if a and b:  # Mbit/s; the slower direction bounds a symmetric link
                key = frozenset((a, b))
                bandwidth[key] = min(bandwidth.get(key, math.inf), float(info["min_bandwidth"]) * 1e6)
    links: dict[frozenset[str], DraftLink] = {}
    for src, dsts in neighbours.items():
        a = by_id.get(str(src))
        if a is None:
            raise EtherError(f"{path}: links.neighbours names unknown node id {src}")
        for dst in dsts:
            b = by_id.get(str(dst))
            if b is None:
                raise EtherError(f"{path}: links.neighbours[{src}] names unknown node id {dst}")
            key = frozenset((a, b))
            if key not in links:
                links[key] = DraftLink(a, b, bandwidth.get(key))
    return Draft(nodes, list(links.values()))
