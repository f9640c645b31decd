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
    owner: dict[str, str] = {}  # node -> group
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
            if node not in plan.scenario.node:
                errors.append(f"{label}: {where}[{i}]: unknown node {node!r} in scenario {plan.scenario.name}")
            elif node in owner:
                errors.append(f"{label}: {where}[{i}]: node {node!r} is already placed in group {owner[node]!r}")
            else:
                owner[node] = group
    # A process runs on one host: every node it holds must be in the same group (or in none)
    for proc in plan.procs:
        nodes = plan.node_of_proc(proc)
        where = {owner.get(node) for node in nodes}
        if len(where) > 1:
            held = ", ".join(f"{node} ({owner.get(node) or 'unplaced'})" for node in nodes[:6])
            held += " ..." if len(nodes) > 6 else ""
            errors.append(f"{label}: process {proc} of layout {plan.layout} holds nodes of different groups: {held}; "
                          "place all of its nodes in one group")
        elif (group := where.pop()) is not None and group in placement:
            placement[group].append(proc)
    if errors:
        raise ScenarioError(errors)
    return placement
