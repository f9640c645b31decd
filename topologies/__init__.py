"""Scenario files (aot1–aot4 and examples), topology generators and the Ether importer.

Code here builds a ``Draft``: node ids, positions, hardware hints and edges. The orchestrator's
scenario loader turns a draft plus the YAML's profiles into a resolved ``Scenario``.
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent


def scenario_path(name: str) -> Path:
    """Path of a bundled scenario, by name ("aot2") or file name ("aot2.yaml")."""
    stem = name[:-5] if name.endswith(".yaml") else name
    return HERE / f"{stem}.yaml"
