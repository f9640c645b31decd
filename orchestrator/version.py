"""Which code produced a run: the package version, and the git commit when run from a checkout.

A seed and a scenario hash replay a run only on the same code; summary.json records all three.
"""

from __future__ import annotations

import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


@cache
def code_version() -> dict[str, Any]:
    """{"version": "0.1.0", "commit": "<sha>" or None, "dirty": bool or None}."""
    try:
        version = metadata.version("zenohedge")
    except metadata.PackageNotFoundError:
        version = None
    commit = dirty = None
    if (ROOT / ".git").exists():
        try:
            commit = _git("rev-parse", "HEAD")
            dirty = bool(_git("status", "--porcelain", "--untracked-files=no"))
        except (OSError, subprocess.SubprocessError):
            commit = dirty = None
    return {"version": version, "commit": commit, "dirty": dirty}


def version_line(code: dict[str, Any] | None = None) -> str:
    """The code version in one line, to stamp a measurement: "zenohedge 0.1.0, commit e8dab53 (uncommitted
    changes)". Benchmarks print it under their tables, so that a table pasted into the docs says what it measured."""
    code = code_version() if code is None else code
    line = f"zenohedge {code['version'] or '(not installed)'}"
    if code["commit"]:
        line += f", commit {code['commit'][:7]}" + (" (uncommitted changes)" if code["dirty"] else "")
    return line


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True,
                          timeout=10).stdout.strip()
