"""The node-side policies as agents: each heuristic is defined once, in ``node_runtime.model.policies``.

They are the comparison points of the paper (local, random, least queue) plus four stronger ones
(round robin, greedy, greedy_backlog, local_first). A ``Baseline`` reads the observation arrays back
into the controller's view (``node_runtime.model.view.Observation``) and asks its rule, one rule per
agent, where each task goes. In batch mode the tasks of one step are placed one after another, and
each placed task counts against its target, so that a batch does not pile onto one node.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from agents.common import Action, Observation, is_batch, masks_of
from env.observations import NeighbourField, OwnField, TaskField
from node_runtime.model.messages import TaskSize
from node_runtime.model.policies import POLICIES, Policy
from node_runtime.model.view import NodeView, TaskView
from node_runtime.model.view import Observation as View


class Baseline:
    """A node-side ``Policy`` (``rule``) acting on the agents' observations, with the masks they carry.

    Every agent gets its own instance of the rule (round robin counts per agent); all share one random
    stream, seeded by ``reset``. A task slot that is empty, or whose mask leaves one action, takes that
    action without asking the rule. Subclass it with ``rule = YourPolicy`` to run a rule of your own
    among the agents.
    """

    rule: ClassVar[type[Policy]]

    def __init__(self, seed: int | None = None) -> None:
        self.reset(seed)

    @property
    def name(self) -> str:
        return self.rule.name

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)
        self.rules: dict[str, Policy] = {}

    def act(self, observations: Mapping[str, Observation]) -> dict[str, Action]:
        actions: dict[str, Action] = {}
        for agent, obs in observations.items():
            masks = masks_of(obs)
            slots = np.asarray(obs["task"]).reshape(len(masks), -1)[:, TaskField.PRESENT] > 0
            valid = [np.flatnonzero(mask).tolist() for mask in masks]
            if not any(present and len(v) > 1 for present, v in zip(slots, valid, strict=True)):
                chosen = [v[0] for v in valid]  # nothing to decide (or a single choice): the only valid action
            else:
                chosen = self._place(self._rule(agent), view_of(obs, masks[0]), slots, valid)
            actions[agent] = chosen if is_batch(obs) else chosen[0]
        return actions

    @staticmethod
    def _place(rule: Policy, view: View, slots: np.ndarray, valid: list[list[int]]) -> list[int]:
        """One action per task slot, asking ``rule`` where a filled slot has a choice."""
        tasks = iter(view.tasks)
        extra = [0] * (1 + len(view.neighbours))  # tasks of this step already sent to each target
        chosen = []
        for present, v in zip(slots, valid, strict=True):
            task = next(tasks) if present else None
            if task is not None and len(v) > 1:
                a = rule.choose(view, task, v, extra)
                extra[a] += 1
            else:
                a = v[0]
            chosen.append(a)
        return chosen

    def _rule(self, agent: str) -> Policy:
        rule = self.rules.get(agent)
        if rule is None:
            rule = self.rules[agent] = self.rule()
            rule.reset(self.rng)
        return rule


def view_of(obs: Observation, mask: np.ndarray) -> View:
    """The controller's view, as far as the arrays tell it (units back to cycles, bytes and bit/s).

    Node names, the tasks' ids, origins and deadlines are not observed; a neighbour takes tasks when
    ``mask`` (of the first task slot) allows it. ``tasks`` holds the filled slots, in order."""
    own, nb = obs["own"], obs["neighbours"]
    rows = np.asarray(obs["task"]).reshape(-1, len(TaskField))
    o, n = OwnField, NeighbourField
    return View(tick=0, node="", own=NodeView("", int(own[o.QUEUE]), int(own[o.OCCUPANCY]), int(own[o.BUFFER]),
                                             float(own[o.CAPACITY_GCPS]) * 1e9, int(own[o.TIER]), 0.0, 0, True),
                undecided=int(own[o.UNDECIDED]), tasks=[task_of(r) for r in rows if r[TaskField.PRESENT] > 0],
                neighbours=[NodeView("", int(r[n.QUEUE]), int(r[n.OCCUPANCY]), int(r[n.BUFFER]),
                                     float(r[n.CAPACITY_GCPS]) * 1e9, int(r[n.TIER]), float(r[n.RATE_MBPS]) * 1e6,
                                     int(r[n.AGE_TICKS]), bool(mask[1 + i]), float(r[n.BACKLOG_S]))
                            for i, r in enumerate(nb)])


def task_of(row: np.ndarray) -> TaskView:
    """One task slot's row (``TaskField`` columns) as the controller's ``TaskView``."""
    t = TaskField
    size = TaskSize(float(row[t.INSTRUCTIONS_G]) * 1e9, float(row[t.INPUT_MB]) * 1e6, float(row[t.OUTPUT_MB]) * 1e6,
                    float(row[t.CPI]), math.nan)
    return TaskView(0, size, float(row[t.TIME_LEFT_S]), int(row[t.WAITED_TICKS]), "")


def baseline(rule: type[Policy]) -> type[Baseline]:
    """The ``Baseline`` class of a node-side policy."""
    return type(f"{rule.__name__}Baseline", (Baseline,), {"rule": rule, "__module__": __name__,
                                                          "__doc__": rule.__doc__})


BASELINES: dict[str, type[Baseline]] = {name: baseline(rule) for name, rule in POLICIES.items()}
