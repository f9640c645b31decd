"""Argument types for the command lines: numbers are checked as strictly as the scenario's YAML is.

argparse turns the ``ArgumentTypeError`` into ``error: argument --steps: expected an integer >= 1
(got '-5')`` and exit status 2.
"""

from __future__ import annotations

import argparse

from node_runtime.model.policies import POLICIES, Policy
from node_runtime.model.spec import MAX_EPISODE_TICKS
from node_runtime.runtime.cli_options import builtin_or_import, integer, number
from node_runtime.runtime.layout import check_layout


def layout_name(text: str) -> str:
    """A process layout name (node_runtime.runtime.layout.check_layout)."""
    try:
        return check_layout(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


# a built-in node-side policy, or a user's Policy subclass as module:Class
POLICY = builtin_or_import(sorted(POLICIES), Policy)
COUNT = integer(1)
STEPS = integer(1, MAX_EPISODE_TICKS)  # an episode's length (node_runtime.model.spec)
POSITIVE = number(0, strict=True)
NON_NEGATIVE = number(0, strict=False)
