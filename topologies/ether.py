"""Import an Ether topology (JSON: ``nodes`` by name, ``links.neighbours`` by numeric id).

Ether (Rausch et al., HotEdge'20) describes devices by CPU (``cpu_milis``), memory and labels.
Following the PeersimGym reference mapping, a node becomes one core of cpu_milis * 1000 instructions
per second, and its buffer holds memory / (expected task size) tasks, or, with ``buffer_bytes``,
round(memory / buffer_bytes) as the reference implementation's importer computes it. The profile is
the name's prefix (``rpi3_4`` -> ``rpi3``); for a prefix that is not a profile, the device's type label
(``ether.edgerun.io/type``) gives its tier and roles, as the built-in AoT profiles give them to their
devices.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from topologies.draft import Draft, DraftLink, DraftNode


class EtherError(ValueError):
    pass


TYPE_LABEL = "ether.edgerun.io/type"
# Ether's device types and the part each plays, as in the AoT networks (rpi3, tx2, nuc, server)
DEVICE_TYPES: dict[str, dict[str, Any]] = {
    "sbc": {"tier": 0, "client": True, "controller": True},  # single-board computers: the sensing nodes
    "embai": {"tier": 1},  # embedded AI boards: workers only
    "sffc": {"tier": 1, "controller": True},  # small-form-factor computers: the cluster hubs
    "server": {"tier": 2, "controller": True},
}


def _finite(value: Any, positive: bool = False) -> float:
    """A number of the file (Python's json reads NaN and Infinity, which no quantity here may be)."""
    number = float(value)
    if not math.isfinite(number) or (positive and number <= 0):
        raise ValueError(f"{value!r} is not a {'positive ' if positive else ''}finite number")
    return number


def profile_of(name: str) -> str:
    return name.rsplit("_", 1)[0] if "_" in name else name


def load_ether(path: Path, task_bytes: float, wired_rates: bool = False, buffer_bytes: float | None = None) -> Draft:
    """Read an Ether JSON file. Buffers hold ⌊memory / task_bytes⌋ tasks (the expected input + output
    size of a task), or round(memory / buffer_bytes) when that is given; at least one."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise EtherError(f"file not found: {path}") from None
    except json.JSONDecodeError as exc:
        raise EtherError(f"{path}: invalid JSON: {exc}") from None
    except UnicodeDecodeError:
        raise EtherError(f"{path}: not a text file (expected Ether JSON)") from None
    except OSError as exc:  # a directory, no permission
        raise EtherError(f"{path}: cannot read it: {exc.strerror}") from None
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
            x, y = map(_finite, node["coordinates"])
            memory = _finite(cap["memory"], positive=True)
            frequency = _finite(cap["cpu_milis"], positive=True) * 1000.0
            node_id = str(node["id"])
            device = DEVICE_TYPES.get((node.get("labels") or {}).get(TYPE_LABEL), {})
        except (KeyError, TypeError, ValueError, AttributeError):
            raise EtherError(f"{path}: node {name!r} lacks coordinates, or capacity.cpu_milis and memory as "
                             "positive numbers") from None
        tasks = memory / buffer_bytes if buffer_bytes else memory / task_bytes
        if not math.isfinite(tasks):
            raise EtherError(f"{path}: node {name!r}: {memory:g} bytes of memory hold {tasks:g} tasks of "
                             f"{buffer_bytes or task_bytes:g} bytes (topology.buffer_bytes, or the task size)")
        by_id[node_id] = name
        nodes.append(DraftNode(id=name, profile=profile_of(name), position=(x, y), device=device,
                               hints={"cores": 1, "frequency": frequency,
                                      "buffer": max(1, round(tasks) if buffer_bytes else math.floor(tasks))}))
    bandwidth: dict[frozenset[str], float] = {}
    if wired_rates:
        for i, info in enumerate(data["links"].get("path_info", [])):
            try:
                a, b = by_id.get(str(info["source"])), by_id.get(str(info["target"]))
                if a and b:  # Mbit/s; the slower direction bounds a symmetric link
                    key = frozenset((a, b))
                    rate = _finite(info["min_bandwidth"], positive=True) * 1e6
                    bandwidth[key] = min(bandwidth.get(key, math.inf), rate)
            except (KeyError, TypeError, ValueError):
                raise EtherError(f"{path}: links.path_info[{i}] lacks source, target or a positive min_bandwidth") \
                    from None
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
