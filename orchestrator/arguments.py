"""Argument types for the command lines: numbers are checked as strictly as the scenario's YAML is.

argparse turns the ``ArgumentTypeError`` into ``error: argument --steps: expected an integer >= 1
(got '-5')`` and exit status 2.
"""

from __future__ import annotations

import argparse

from node_runtime.model.plugins import PluginError, is_import_path, load_from_command_line
from node_runtime.model.policies import POLICIES, Policy
from node_runtime.runtime.cli_options import integer, number
from node_runtime.runtime.layout import check_layout


def layout_name(text: str) -> str:
    """A process layout name (node_runtime.runtime.layout.check_layout)."""
    try:
        return check_layout(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def policy_name(text: str) -> str:
    """A built-in node-side policy, or a user's ``Policy`` subclass by import path ("module:Class"), imported
    here so that a typo fails before any process starts (modules in the working directory are importable,
    as with ``python -m``)."""
    if text in POLICIES:
        return text
    if not is_import_path(text):
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(sorted(POLICIES))} or an import path "
                                         f"'module:Class' (got {text!r})")
    try:
        load_from_command_line(text, Policy)
    except PluginError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


COUNT = integer(1)
POSITIVE = number(0, strict=True)
NON_NEGATIVE = number(0, strict=False)
