"""User extensions named by import path ("package.module:Name") in a scenario.

A scenario may replace a role (``roles: {worker: mylab.roles:BatteryWorker}``), a node-side policy,
the task source of the clients, the reward or the observation builder of the environment. Every node
process imports what its roles need when it starts; the orchestrator imports everything once while
validating, so a typo fails there, with the key path, before any process starts.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Iterable
from typing import Any


class PluginError(ValueError):
    pass


def is_import_path(text: str) -> bool:
    return ":" in text


def load(path: str, base: type | None = None, *, callable_ok: bool = False) -> Any:
    """The object at ``module:qualified.name``; a subclass of ``base`` when given (or, with
    ``callable_ok``, any callable)."""
    module_name, _, attr = path.partition(":")
    if not module_name or not attr:
        raise PluginError(f"expected an import path like 'package.module:Name', not {path!r}")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise PluginError(f"cannot import module {module_name!r} ({exc}); is it on PYTHONPATH?") from None
    except Exception as exc:  # the user's module raised while importing
        raise PluginError(f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    obj: Any = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise PluginError(f"module {module_name!r} has no {attr!r}") from None
    if base is not None and not (isinstance(obj, type) and issubclass(obj, base)):
        if callable_ok and callable(obj):
            return obj
        raise PluginError(f"{path} is not a subclass of {base.__module__}.{base.__qualname__}")
    if base is None and callable_ok and not callable(obj):
        raise PluginError(f"{path} is not callable")
    return obj


def extend_path(paths: Iterable[str]) -> None:
    """Make the orchestrator's import paths visible in a node process (user modules live there)."""
    for p in paths:
        if p not in sys.path:
            sys.path.append(p)


def load_from_command_line(path: str, base: type) -> Any:
    """``load`` for an import path given on a command line: the working directory is importable, as
    ``python -m`` makes it (node processes inherit it)."""
    extend_path([os.getcwd()])
    return load(path, base)
