"""Scenario files: YAML in, a validated ``node_runtime.model.spec.Scenario`` out (docs/scenario.md).

Three parts: ``schema`` (the file format, checked for structure by pydantic), ``resolve`` (meaning:
references, profiles, link rates, connectivity, extensions) and ``errors`` (every problem becomes
one line naming the file, the key path and what was expected).
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

import yaml

from node_runtime.model.spec import Scenario
from orchestrator.scenario.errors import ScenarioError
from orchestrator.scenario.resolve import resolve
from topologies import bundled_scenarios, scenario_path

__all__ = ["ScenarioError", "load_scenario"]

MAX_BASES = 16  # a chain of ``extends`` longer than this is a mistake (or a file made to exhaust the stack)


def load_scenario(source: str | Path | dict[str, Any], *, name_hint: str = "") -> Scenario:
    """A scenario from a bundled name ("aot2"), a YAML path, or a dict. Raises ``ScenarioError``."""
    if isinstance(source, dict):
        data, bases = _inherit(dict(source), Path.cwd(), "<dict>", ())
        return resolve(data, Path.cwd(), name_hint or "scenario", "<dict>", bases)
    path = _locate(str(source))
    label = str(source)
    data, bases = _inherit(_read(path, label, label), path.parent, label, (path.resolve(),))
    return resolve(data, path.parent, path.stem, label, bases)


def _locate(ref: str, folder: Path = Path()) -> Path:
    """A scenario file by path (relative to ``folder``) or by a bundled scenario's name."""
    path = folder / ref
    if not path.exists() and not Path(ref).suffix and scenario_path(ref).exists():
        return scenario_path(ref)
    return path


def _read(path: Path, label: str, ref: str) -> dict[str, Any]:
    """The top-level mapping of the scenario file ``ref`` names, or a one-line error."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError([f"{label}: {_not_found(ref)}"]) from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise ScenarioError([f"{label}: cannot read: {exc}"]) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError([f"{label}{where}: invalid YAML: {problem}"]) from None
    except RecursionError:  # PyYAML composes nested collections recursively
        raise ScenarioError([f"{label}: invalid YAML: nested too deeply"]) from None
    if data is None:
        raise ScenarioError([f"{label}: the file is empty; expected a scenario mapping with at least 'topology'"])
    if not isinstance(data, dict):
        raise ScenarioError([f"{label}: expected a mapping at the top level, got {type(data).__name__}"])
    return data


def _inherit(data: dict[str, Any], folder: Path, label: str,
             chain: tuple[Path, ...]) -> tuple[dict[str, Any], tuple[Path, ...]]:
    """Apply ``extends: BASE``: the base scenario's keys, overridden key by key by this file's (mappings
    merge, anything else replaces; the base's name and description are not inherited). Also returns the
    bases' folders, nearest first: the files the scenario names are looked for there after its own."""
    if "extends" not in data:
        return data, ()
    ref = data.pop("extends")
    if not isinstance(ref, str) or not ref.strip():
        raise ScenarioError([f"{label}: extends: expected a bundled scenario's name or the path of a scenario "
                             f"file, got {ref!r}"])
    if len(chain) > MAX_BASES:
        raise ScenarioError([f"{label}: extends: more than {MAX_BASES} scenarios deep"])
    path = _locate(ref, folder)
    chain = (*chain, path.resolve())
    if chain[-1] in chain[:-1]:
        raise ScenarioError([f"{label}: extends: {ref!r} extends itself ({' -> '.join(p.name for p in chain)})"])
    label = f"{label}: extends: {ref}"
    base = _read(path, label, ref)
    for own in ("name", "description"):
        base.pop(own, None)
    base, folders = _inherit(base, path.parent, label, chain)
    return _merge(base, data), (path.parent, *folders)


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in over.items():
        merged[key] = (_merge(merged[key], value) if isinstance(value, dict) and isinstance(merged.get(key), dict)
                       else value)
    return merged


def _not_found(name: str) -> str:
    """'file not found'; for a bare name, also the bundled scenarios and the closest one."""
    if Path(name).parent != Path(".") and not name.startswith("examples/"):
        return "file not found"
    bundled = bundled_scenarios()
    hint = difflib.get_close_matches(name.removesuffix(".yaml"), bundled, n=1)
    return ("no such file or bundled scenario" + (f" (did you mean '{hint[0]}'?)" if hint else "")
            + f"; bundled: {', '.join(bundled)}")
