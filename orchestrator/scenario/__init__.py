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


def load_scenario(source: str | Path | dict[str, Any], *, name_hint: str = "") -> Scenario:
    """A scenario from a bundled name ("aot2"), a YAML path, or a dict. Raises ``ScenarioError``."""
    if isinstance(source, dict):
        return resolve(source, Path.cwd(), name_hint or "scenario", "<dict>")
    path = Path(source)
    if not path.exists() and not path.suffix and scenario_path(str(source)).exists():
        path = scenario_path(str(source))
    label = str(source)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError([f"{label}: {_not_found(str(source))}"]) from None
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
    return resolve(data, path.parent, path.stem, label)




def _not_found(name: str) -> str:
    """'file not found'; for a bare name, also the bundled scenarios and the closest one."""
    if Path(name).parent != Path(".") and not name.startswith("examples/"):
        return "file not found"
    bundled = bundled_scenarios()
    hint = difflib.get_close_matches(name.removesuffix(".yaml"), bundled, n=1)
    return ("no such file or bundled scenario" + (f" (did you mean '{hint[0]}'?)" if hint else "")
            + f"; bundled: {', '.join(bundled)}")
