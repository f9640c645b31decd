"""The layout stays as docs/architecture.md draws it: every module is on the map, and layers import
only downward (agents/experiments -> env -> orchestrator -> node_runtime.runtime -> node_runtime.model)."""

from __future__ import annotations

import ast
import re

import pytest

from tests.conftest import ROOT

PACKAGES = ("node_runtime", "orchestrator", "env", "topologies", "agents", "experiments")
# What each layer must never import (at module level or inside a function).
FORBIDDEN = {
    "node_runtime.model": ("node_runtime.runtime", "orchestrator", "env", "agents", "experiments", "topologies"),
    "node_runtime.runtime": ("orchestrator", "env", "agents", "experiments", "topologies"),
    "topologies": ("node_runtime.runtime", "orchestrator", "env", "agents", "experiments"),
    "orchestrator": ("env", "agents", "experiments"),
    "env": ("agents", "experiments"),
    "agents": ("experiments", "orchestrator"),
}


def modules() -> list[str]:
    return sorted(str(p.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def imported(path: str) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse((ROOT / path).read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_every_module_is_on_the_map():
    text = (ROOT / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"[`/]([a-z_0-9]+\.py)`", text))
    missing = [m for m in modules() if not m.endswith("__init__.py") and m.rsplit("/", 1)[1] not in named]
    assert not missing, f"docs/architecture.md does not name: {', '.join(missing)}"


@pytest.mark.parametrize("path", modules())
def test_layers_import_only_downward(path):
    dotted = path.removesuffix(".py").replace("/", ".")
    layer = next((layer for layer in sorted(FORBIDDEN, key=len, reverse=True) if dotted.startswith(layer)), None)
    if layer is None:
        return
    upward = sorted(name for name in imported(path)
                    if any(name == bad or name.startswith(bad + ".") for bad in FORBIDDEN[layer]))
    assert not upward, f"{path} ({layer}) imports {', '.join(upward)}"
