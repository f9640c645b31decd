"""The neutral shape every topology source produces before profiles are applied."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class DraftNode:
    id: str
    profile: str
    position: tuple[float, float]
    hints: dict[str, Any] = field(default_factory=dict)  # hardware the source knows (frequency, buffer, ...)
    device: dict[str, Any] = field(default_factory=dict)  # what its kind of device implies (tier, roles), for a
    # profile that is neither built in nor defined by the scenario


@dataclass
class DraftLink:
    a: str
    b: str
    rate_bps: float | None = None  # wired rate, when the source gives one


@dataclass
class Draft:
    nodes: list[DraftNode]
    links: list[DraftLink]
