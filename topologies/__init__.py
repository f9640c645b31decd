"""Scenario files (aot1–aot4 and examples), topology generators and the Ether importer.

Code here builds a ``Draft``: node ids, positions, hardware hints and edges. The orchestrator's
scenario loader turns a draft plus the YAML's profiles into a resolved ``Scenario``.
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent


def bundled_scenarios() -> list[str]:
    """Names of the bundled scenarios: "aot1" … and "examples/minimal" …, as ``load_scenario`` takes them."""
    top = sorted(p.stem for p in HERE.glob("*.yaml"))
    return top + sorted(f"examples/{p.stem}" for p in (HERE / "examples").glob("*.yaml"))


def bundled_file(ref: str) -> Path | None:
    """A file shipped with the package (an Ether topology, a trace), by its path relative to this folder."""
    path = HERE / ref
    return path if path.is_file() else None


def scenario_path(name: str) -> Path:
    """Path of a bundled scenario, by name ("aot2") or file name ("aot2.yaml")."""
    stem = name[:-5] if name.endswith(".yaml") else name
    return HERE / f"{stem}.yaml"
