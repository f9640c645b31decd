"""Placement files: which node processes run on which host (docs in deploy/README.md).

    groups:
      edge-a: [rpi3_0, rpi3_1, nuc_0, tx2_0]
      edge-b: [rpi3_6, rpi3_7, nuc_1, tx2_2]

Every process of a listed node (all its roles, whatever the layout) runs in that group, on the host
where ``zenohedge-node --group NAME`` is started; unlisted nodes run on the orchestrator's host.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from node_runtime.runtime.keys import CHUNK
from node_runtime.runtime.layout import ProcessLayout
from orchestrator.scenario import ScenarioError


def load_placement(path: str | Path, plan: ProcessLayout) -> dict[str, list[str]]:
    """Group name -> the processes it runs. Raises ScenarioError with one line per problem."""
    label = str(path)
    try:
        data = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError:
        raise ScenarioError([f"{label}: file not found"]) from None
    except yaml.YAMLError as exc:
        raise ScenarioError([f"{label}: invalid YAML: {exc}".splitlines()[0]]) from None
    if not isinstance(data, dict) or not isinstance(data.get("groups"), dict) or set(data) != {"groups"}:
        raise ScenarioError([f"{label}: expected a mapping with one key, 'groups': {{group: [node, ...]}}"])
    if plan.layout == "single":
        raise ScenarioError([f"{label}: the 'single' layout has one process; use per-role or per-node"])
    errors: list[str] = []
    owner: dict[str, str] = {}
    procs_of_node: dict[str, list[str]] = {}
    for role, proc in plan.proc_of.items():
        procs_of_node.setdefault(role.split(":", 1)[1], [])
        if proc not in procs_of_node[role.split(":", 1)[1]]:
            procs_of_node[role.split(":", 1)[1]].append(proc)
    placement: dict[str, list[str]] = {}
    for group, nodes in data["groups"].items():
        where = f"groups.{group}"
        if not isinstance(group, str) or not CHUNK.match(group):
            errors.append(f"{label}: {where}: expected a group name of letters, digits, '_', '.' or '-'")
            continue
        if not isinstance(nodes, list) or not nodes:
            errors.append(f"{label}: {where}: expected a non-empty list of node ids")
            continue
        placement[group] = []
        for i, node in enumerate(nodes):
            if node not in procs_of_node:
                errors.append(f"{label}: {where}[{i}]: unknown node {node!r} in scenario {plan.scenario.name}")
            elif node in owner:
                errors.append(f"{label}: {where}[{i}]: node {node!r} is already placed in group {owner[node]!r}")
            else:
                owner[node] = group
                placement[group].extend(procs_of_node[node])
    if errors:
        raise ScenarioError(errors)
    return placement
