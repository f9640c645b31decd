"""The layout stays as docs/architecture.md draws it.

- Every module is on the map, by its path: two modules with one file name in two packages are two entries.
- Layers import only downward: benchmarks/ and examples/ -> agents/ and experiments/ -> env/ ->
  orchestrator/ -> node_runtime/runtime/ -> node_runtime/model/; nothing imports benchmarks/ or examples/.
- What agents/ and experiments/ take from below the environment's PettingZoo API is what the map lists.
- No import circle among the project's modules, counting the imports inside functions.

Modules are named by their dotted path (``orchestrator.scenario.errors``; ``benchmarks.scale`` for a script),
and an import by what it imports: ``from node_runtime.runtime import process`` is ``node_runtime.runtime.process``.
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import networkx as nx
import pytest

from tests.conftest import ROOT

PACKAGES = ("node_runtime", "orchestrator", "env", "topologies", "agents", "experiments")
SCRIPTS = ("benchmarks", "examples")  # folders of scripts, at the top: they import a sibling by its bare name
TOP_LEVEL = (*PACKAGES, *SCRIPTS, "tests", "deploy")  # a path on the map that starts with one of these is whole
# What each layer must never import (at module level or inside a function); the longest prefix is a module's layer.
FORBIDDEN = {
    "node_runtime.model": ("node_runtime.runtime", "orchestrator", "env", "agents", "experiments", "topologies",
                           *SCRIPTS),
    "node_runtime.runtime": ("orchestrator", "env", "agents", "experiments", "topologies", *SCRIPTS),
    "topologies": ("node_runtime.runtime", "orchestrator", "env", "agents", "experiments", *SCRIPTS),
    "orchestrator": ("env", "agents", "experiments", *SCRIPTS),
    "env": ("agents", "experiments", *SCRIPTS),
    "agents": ("experiments", "orchestrator", *SCRIPTS),
    "experiments": SCRIPTS,
    "benchmarks": ("examples",),
    "examples": ("benchmarks",),
}
ABOVE_THE_API = ("agents", "experiments")  # they use the environment, and below it only what the map lists
BELOW_THE_API = ("env", "orchestrator", "node_runtime", "topologies")
API = "env"  # the package: ZenohEdgeEnv and what it exports
USED_BELOW_HEADING = "What agents and experiments use below the environment"


@cache
def modules() -> dict[str, Path]:
    """Every module of the project by dotted name (a package by its own name), with its file."""
    found = {}
    for top in (*PACKAGES, *SCRIPTS):
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _project_module(name: str, importer: str) -> str | None:
    """The project module an import of ``name`` runs: the longest prefix of it that is one, or a sibling
    script of a script; None for anything else (the standard library, third-party packages)."""
    known = modules()
    if importer.split(".")[0] in SCRIPTS and f"{importer.rpartition('.')[0]}.{name}" in known:
        return f"{importer.rpartition('.')[0]}.{name}"
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


@cache
def imports(module: str) -> frozenset[str]:
    """The project modules ``module`` imports, at module level or inside a function."""
    path = modules()[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1 packages
                parts = package.split(".")
                base = ".".join(filter(None, [*parts[:len(parts) - node.level + 1], base]))
            # ``from package import module`` imports that module; ``from module import name`` the module
            names += [f"{base}.{a.name}" if f"{base}.{a.name}" in modules() else base for a in node.names]
    return frozenset(m for m in (_project_module(n, module) for n in names) if m is not None and m != module)


def _map_text() -> str:
    return (ROOT / "docs" / "architecture.md").read_text()


def on_the_map(text: str | None = None) -> set[str]:
    """The files docs/architecture.md (or ``text``) names, as paths from the root: a name inside a section on
    a folder (a heading or a bullet that starts with `folder/`) is in that folder, unless it starts at the top
    or is a file of the root itself (``mkdocs_hooks.py``)."""
    named, base = set(), ""
    for line in (_map_text() if text is None else text).splitlines():
        folder = re.match(r"(?:#+ |- )[^`]*`([a-z_0-9/]+/)`", line)
        if line.startswith("#"):
            base = folder.group(1) if folder else ""
        elif folder and line.startswith("- "):
            base = folder.group(1)
        for name in re.findall(r"`([A-Za-z0-9_/]+\.py)`", line):
            whole = name.split("/")[0] in TOP_LEVEL or (ROOT / name).is_file()
            named.add(name if whole else base + name)
    return named


def used_below() -> set[str]:
    """The modules below the environment that the map lets agents/ and experiments/ use (its section on them)."""
    section = _map_text().split(f"## {USED_BELOW_HEADING}", 1)[1].split("\n## ", 1)[0]
    return set(re.findall(r"`([a-z_]+(?:\.[a-z_]+)+)`", section))


def _file(module: str) -> str:
    return str(modules()[module].relative_to(ROOT))


def test_every_module_is_on_the_map_by_its_path():
    named = on_the_map()
    missing = [_file(m) for m in modules() if not _file(m).endswith("__init__.py") and _file(m) not in named]
    assert not missing, f"docs/architecture.md does not name: {', '.join(missing)}"


def test_every_file_on_the_map_exists():
    stale = sorted(name for name in on_the_map() if not (ROOT / name).is_file())
    assert not stale, f"docs/architecture.md names files that do not exist: {', '.join(stale)}"


def test_the_map_tells_modules_apart_by_path():
    """Two modules with one file name in two packages: naming one does not put the other on the map."""
    text = ("## `agents/` and more\n\n| `agents/common.py` | x |\n\n"
            "## `orchestrator/`: y\n\n| `scenario/schema.py` | z |\n")
    assert on_the_map(text) == {"agents/common.py", "orchestrator/scenario/schema.py"}
    assert {"agents/common.py", "experiments/common.py"} <= on_the_map()  # the project's own pair


@pytest.mark.parametrize("module", sorted(modules()))
def test_layers_import_only_downward(module):
    layer = next((layer for layer in sorted(FORBIDDEN, key=len, reverse=True)
                  if module == layer or module.startswith(layer + ".")), None)
    if layer is None:
        return
    upward = sorted(name for name in imports(module)
                    if any(name == bad or name.startswith(bad + ".") for bad in FORBIDDEN[layer]))
    assert not upward, f"{_file(module)} ({layer}) imports {', '.join(upward)}"


def test_agents_and_experiments_use_below_the_environment_only_what_the_map_lists():
    listed = used_below()
    assert listed, f"docs/architecture.md has no section '{USED_BELOW_HEADING}'"
    used = {(m, name) for m in modules() if m.split(".")[0] in ABOVE_THE_API for name in imports(m)
            if name.split(".")[0] in BELOW_THE_API and name != API}
    unlisted = sorted(f"{_file(m)} imports {name}" for m, name in used if name not in listed)
    assert not unlisted, f"not in docs/architecture.md '{USED_BELOW_HEADING}': {'; '.join(unlisted)}"
    unused = sorted(listed - {name for _, name in used})
    assert not unused, f"docs/architecture.md '{USED_BELOW_HEADING}' lists what nothing uses: {', '.join(unused)}"


def import_graph() -> nx.DiGraph:
    graph = nx.DiGraph()
    graph.add_nodes_from(modules())
    graph.add_edges_from((m, name) for m in modules() for name in imports(m))
    return graph


def test_no_import_circle():
    circles = [sorted(c) for c in nx.strongly_connected_components(import_graph()) if len(c) > 1]
    assert not circles, "import circles: " + "; ".join(" <-> ".join(c) for c in circles)


def test_the_import_graph_sees_imports_inside_functions_and_from_packages():
    """The checks above would pass vacuously if the graph missed these edges."""
    graph = import_graph()
    assert graph.has_edge("node_runtime.runtime.forkserver", "node_runtime.runtime.process")  # inside serve()
    assert graph.has_edge("node_runtime.runtime.driver", "node_runtime.runtime.failure")
    assert graph.has_edge("benchmarks.hosts", "benchmarks.scale")  # a sibling script, by its bare name
    assert graph.has_edge("examples.random_agent", "env")
