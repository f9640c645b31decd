"""What ``step()`` does with the agents' actions: the rules of docs/env.md "Actions", in one place.

- ``actions`` holds one entry per live agent (``env.agents``) and no other key.
- Each action lies in the agent's action space. Binary mode: an integer in [0, 1 + D) (a Python int,
  a NumPy integer scalar, a 0-d array, or a float with a whole value such as 2.0). Batch mode: a
  sequence of B of them, one per task slot. Anything else raises a ``TypeError`` or ``ValueError``
  that names the agent and what was expected.
- The action of an agent with nothing to decide (no task, or its node down) is ignored, and so is the
  entry of an empty task slot: nothing is counted, nothing is penalised.
- A choice the mask forbids for a task (a neighbour that is not a worker, a padding slot) is invalid.
  By default (``invalid_action="local"``) the task stays local (action 0) and the agent's info says so;
  ``invalid_action="raise"`` raises ``InvalidActionError`` instead, for debugging.

Every action is checked before any reaches the emulation, so a step that raises changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from env.observations import ObservationLayout
from node_runtime.model.view import Observation

LOCAL = 0  # the action that keeps a task on the agent's own worker
INVALID_ACTION_RULES = ("local", "raise")

Action = int | list[int]


class InvalidActionError(ValueError):
    """An agent chose a target its action mask forbids, with ``invalid_action="raise"``."""


@dataclass(frozen=True, slots=True)
class ResolvedActions:
    """One step's actions, checked."""

    actions: dict[str, Action]  # every live agent's action as integers, invalid choices replaced by LOCAL
    decisions: dict[str, Action]  # agents with tasks: what their controllers carry out, one entry per task
    invalid: frozenset[str]  # agents whose action broke the mask


class ActionRules:
    """Checks and normalises the actions of one environment's agents."""

    def __init__(self, layouts: Mapping[str, ObservationLayout], targets: Mapping[str, Sequence[str]],
                 invalid_action: str = "local") -> None:
        """``targets``: per agent, the names of actions 0..degree ("local", then the neighbours' ids)."""
        if invalid_action not in INVALID_ACTION_RULES:
            raise ValueError(f"invalid_action must be 'local' (the default: a masked choice keeps the task local) "
                             f"or 'raise', not {invalid_action!r}")
        self.layouts = dict(layouts)
        self.targets = {a: tuple(t) for a, t in targets.items()}
        self.raise_invalid = invalid_action == "raise"
        self.spaces = {a: str(lay.action_space()) for a, lay in self.layouts.items()}

    def resolve(self, actions: Mapping[str, Any], live: Sequence[str],
                views: Mapping[str, Observation | None]) -> ResolvedActions:
        """Check every live agent's action against its space and, for the tasks in ``views``, its mask."""
        if not isinstance(actions, Mapping):
            raise TypeError(f"step() takes a dict {{agent: action}} for the live agents (env.agents), "
                            f"not a {type(actions).__name__}")
        if len(actions) != len(live) or not all(a in actions for a in live):
            self._wrong_agents(actions, live)
        normalised: dict[str, Action] = {}
        decisions: dict[str, Action] = {}
        invalid: set[str] = set()
        for agent in live:
            layout = self.layouts[agent]
            view = views[agent]
            tasks = len(view.tasks) if view is not None else 0
            if layout.batch is None:
                a = self._integer(agent, actions[agent], layout.n_actions)
                if tasks:
                    if a != LOCAL:
                        mask = layout.masks(view)
                        if not mask[a]:
                            self._masked(agent, a, mask)
                            invalid.add(agent)
                            a = LOCAL
                    decisions[agent] = a
                normalised[agent] = a
            else:
                acts = self._integers(agent, actions[agent], layout.batch, layout.n_actions)
                if tasks:
                    masks = layout.masks(view)
                    for k in range(tasks):
                        if acts[k] != LOCAL and not masks[k][acts[k]]:
                            self._masked(agent, acts[k], masks[k], k)
                            invalid.add(agent)
                            acts[k] = LOCAL
                    decisions[agent] = acts[:tasks]
                normalised[agent] = acts
        return ResolvedActions(normalised, decisions, frozenset(invalid))

    # ----- one value -----

    def _integer(self, agent: str, value: Any, n: int, slot: int | None = None) -> int:
        if type(value) is not int:
            value = self._coerce(agent, value, slot)
        if 0 <= value < n:
            return value
        raise ValueError(f"{agent}: action {value}{_in_slot(slot)} is outside the action space {self.spaces[agent]}: "
                         f"expected 0 (local) to {n - 1}")

    def _coerce(self, agent: str, value: Any, slot: int | None) -> int:
        if isinstance(value, np.ndarray) and value.ndim == 0:
            value = value.item()
        if isinstance(value, int | np.integer):
            return int(value)
        expected = f"expected an integer action of {self.spaces[agent]} (0 = local, i = neighbour i)"
        if isinstance(value, float | np.floating):
            if math.isfinite(value) and float(value).is_integer():
                return int(value)
            raise ValueError(f"{agent}: action {value}{_in_slot(slot)} is not a whole number; {expected}")
        raise TypeError(f"{agent}: action {_show(value)}{_in_slot(slot)} is a {type(value).__name__}, "
                        f"not an integer; {expected}")

    def _integers(self, agent: str, value: Any, batch: int, n: int) -> list[int]:
        items = value.tolist() if isinstance(value, np.ndarray) and value.ndim == 1 else value
        if not isinstance(items, list | tuple):
            raise TypeError(f"{agent}: action {_show(value)} is not a sequence; expected {batch} integers, "
                            f"one per task slot, in {self.spaces[agent]} (batch mode)")
        if len(items) != batch:
            raise ValueError(f"{agent}: {len(items)} actions; expected {batch}, one per task slot, "
                             f"in {self.spaces[agent]} (batch mode)")
        return [self._integer(agent, x, n, k) for k, x in enumerate(items)]

    # ----- errors -----

    def _masked(self, agent: str, action: int, mask: np.ndarray, slot: int | None = None) -> None:
        """Raise ``InvalidActionError`` if asked to; otherwise the caller keeps the task local."""
        if not self.raise_invalid:
            return
        targets = self.targets[agent]
        target = targets[action] if action < len(targets) else "a padding slot"
        allowed = ", ".join(f"{i} ({targets[i]})" for i in np.flatnonzero(mask))
        raise InvalidActionError(f"{agent}: action {action}{_in_slot(slot)} ({target}) is masked; allowed now: "
                                 f"{allowed} (invalid_action='raise'; the default, 'local', keeps the task local)")

    def _wrong_agents(self, actions: Mapping[str, Any], live: Sequence[str]) -> None:
        alive = set(live)
        unknown = [k for k in actions if k not in alive]
        if unknown:
            what = "not a live agent" if len(unknown) == 1 else "not live agents"
            raise ValueError(f"step(): actions for {', '.join(map(repr, unknown))}, {what} of this environment; "
                             f"the live agents (env.agents) are {_names(live)}")
        missing = [a for a in live if a not in actions]
        raise ValueError(f"step(): no action for {', '.join(missing)}; every live agent (env.agents) needs one")


def _in_slot(slot: int | None) -> str:
    return "" if slot is None else f" (task slot {slot})"


def _show(value: Any) -> str:
    return repr(value) if isinstance(value, str) else str(value)


def _names(agents: Sequence[str]) -> str:
    return ", ".join(agents) if len(agents) <= 6 else f"{', '.join(agents[:3])}, …, {agents[-1]} ({len(agents)})"
