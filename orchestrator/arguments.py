"""Argument types for the command lines: numbers are checked as strictly as the scenario's YAML is.

argparse turns the ``ArgumentTypeError`` into ``error: argument --steps: expected an integer >= 1
(got '-5')`` and exit status 2.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from node_runtime.runtime.layout import check_layout


def integer(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An integer >= ``minimum`` (and <= ``maximum``)."""
    expected = f"an integer >= {minimum}" if maximum is None else f"an integer from {minimum} to {maximum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected} (got {text!r})") from None
        if value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"expected {expected} (got {text!r})")
        return value
    return parse


def number(minimum: float, *, strict: bool) -> Callable[[str], float]:
    """A finite number > ``minimum`` (``strict``) or >= ``minimum``."""
    op = ">" if strict else ">="

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < minimum or (strict and value == minimum):
            raise argparse.ArgumentTypeError(f"expected a number {op} {minimum:g} (got {text!r})")
        return value
    return parse


def layout_name(text: str) -> str:
    """A process layout name (node_runtime.runtime.layout.check_layout)."""
    try:
        return check_layout(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


COUNT = integer(1)
POSITIVE = number(0, strict=True)
NON_NEGATIVE = number(0, strict=False)
