"""The role kinds a node can have, and what the runtime must know about each to place and wire it.

A kind is a ``Role`` subclass plus the ``RoleKind`` that ``register`` records for it. The process
layout, the host, the scenario loader and the process names read everything kind-specific from
``ROLE_KINDS``, so a new kind is one module that defines its class and registers it
(docs/extending.md, "Adding a role kind").

Each kind declares its place among a node's roles (``order``): worker 0, client 1, controller 2. It
fixes the order in which a host runs roles and their indices on the wire, so it must not change. The
built-in kinds register when ``node_runtime.model`` is imported. The scenario loader writes each
node's kinds in canonical order and the scenario names the class of every kind it uses, so every
process (a node process, a remote host, an attached driver) agrees on the roles and can import a
kind it has not registered itself.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from node_runtime.model.plugins import PluginError, load
from node_runtime.model.rng import MOBILITY
from node_runtime.model.role import Role

if TYPE_CHECKING:
    from node_runtime.model.spec import NodeSpec, Scenario

Topics = Callable[["NodeSpec", "Scenario"], tuple[str, ...]]
KIND_NAME = re.compile(r"[a-z][a-z0-9_]*")  # it becomes part of role ids, process names and scenario keys


def no_topics(node: NodeSpec, scenario: Scenario) -> tuple[str, ...]:
    return ()


@dataclass(frozen=True)
class RoleKind:
    """What the runtime needs to know about one kind of role."""

    base: type[Role]  # its class (its ``kind`` attribute is the kind's name); a scenario's ``roles:`` class extends it
    order: int  # its place among a node's roles; never change one
    stream: int  # the role number of its random streams (``rng.stream``); never change or reuse one
    letter: str = ""  # its processes show as z<letter>-<node> in ps and top; "" = the first letter of its name
    default: bool = False  # whether a node has this role unless the scenario says otherwise
    needs: tuple[str, ...] = ()  # kinds that must be on the same node
    publishes: Topics = no_topics  # broadcast topics a role of this kind on ``node`` publishes on
    subscribes: Topics = no_topics  # broadcast topics it listens to
    # An agent can drive it: its class takes ``reset(seed, external, policy)`` and ``tick(t, inbox, out,
    # action)``, and keeps the observation it made in ``last`` (reported in ``Done`` while driven).
    agent: bool = False

    @property
    def name(self) -> str:
        return self.base.kind

    @property
    def path(self) -> str:
        """Where a process that has not registered the kind imports it from."""
        return f"{self.base.__module__}:{self.base.__qualname__}"

    @property
    def process_prefix(self) -> str:
        return f"z{self.letter or self.name[0]}"


ROLE_KINDS: dict[str, RoleKind] = {}  # by name, in canonical order


def register(kind: RoleKind) -> RoleKind:
    """Add a role kind (once per process, when its module is imported). Returns it, for the module's
    own use (its stream number)."""
    name = getattr(kind.base, "kind", None)
    if not isinstance(name, str) or not KIND_NAME.fullmatch(name):
        raise ValueError(f"{kind.base.__qualname__}: a role kind needs a class attribute 'kind', a name of "
                         f"lower-case letters, digits and '_' (got {name!r})")
    known = ROLE_KINDS.get(name)
    if known is not None and known.path != kind.path:
        raise ValueError(f"role kind {name!r} is already registered, by {known.path}")
    if kind.stream == MOBILITY:
        raise ValueError(f"role kind {name!r}: stream {MOBILITY} is the moving nodes' (rng.MOBILITY)")
    for other in ROLE_KINDS.values():
        for number in ("order", "stream"):
            if getattr(other, number) == getattr(kind, number) and other.name != name:
                raise ValueError(f"role kind {name!r}: {number} {getattr(kind, number)} is taken by {other.name!r}")
    ROLE_KINDS[name] = kind
    for k in sorted(ROLE_KINDS.values(), key=lambda k: k.order):
        ROLE_KINDS[k.name] = ROLE_KINDS.pop(k.name)
    return kind


def kinds_of(scenario: Scenario) -> dict[str, RoleKind]:
    """The kinds the scenario's nodes have, importing any this process has not registered yet (a
    user's kind, in a node process) from where the scenario says it lives."""
    paths = dict(scenario.kinds)
    out: dict[str, RoleKind] = {}
    for name in dict.fromkeys(k for n in scenario.nodes for k in n.roles):
        if name not in ROLE_KINDS and name in paths:
            load(paths[name], Role)  # registers it
        if name not in ROLE_KINDS:
            where = f"importing {paths[name]} did not register it" if name in paths else "no module registers it"
            raise PluginError(f"role kind {name!r} is unknown in this process: {where}")
        out[name] = ROLE_KINDS[name]
    return out
