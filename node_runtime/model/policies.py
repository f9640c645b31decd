"""Decision policies: what a controller does when no RL agent drives it, and the agents' heuristics.

A policy maps an ``Observation`` to one action per task in it (0 = keep locally, i = neighbour
i - 1). Policies only pick valid actions. In batch mode they place the tasks one after another,
counting each placed task against its target so a batch does not all pile onto one node. Each rule
is defined here only: ``agents.baselines`` runs the same classes on the environment's observations.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from node_runtime.model.plugins import is_import_path, load
from node_runtime.model.view import NodeView, Observation, TaskView


class Policy:
    name: ClassVar[str]

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def decide(self, obs: Observation) -> list[int]:
        valid = [i for i, ok in enumerate(obs.valid_actions()) if ok]
        extra = [0] * (1 + len(obs.neighbours))  # tasks this batch already sent to each target
        actions = []
        for task in obs.tasks:
            a = self.choose(obs, task, valid, extra)
            extra[a] += 1
            actions.append(a)
        return actions

    def choose(self, obs: Observation, task: TaskView, valid: list[int], extra: list[int]) -> int:
        raise NotImplementedError


class Local(Policy):
    """Never offload."""

    name = "local"

    def choose(self, obs, task, valid, extra):
        return 0


class Random(Policy):
    """A uniformly random valid target, the node itself included."""

    name = "random"

    def choose(self, obs, task, valid, extra):
        return valid[int(self.rng.integers(len(valid)))]


class RoundRobin(Policy):
    """Cycle through the valid targets, the node itself first."""

    name = "round_robin"

    def reset(self, rng):
        super().reset(rng)
        self.next = 0

    def choose(self, obs, task, valid, extra):
        a = valid[self.next % len(valid)]
        self.next += 1
        return a


def _target(obs: Observation, action: int) -> NodeView:
    return obs.own if action == 0 else obs.neighbours[action - 1]


class LeastQueue(Policy):
    """The target with the shortest queue as last heard (ties: the lowest action, so local first)."""

    name = "least_queue"

    def choose(self, obs, task, valid, extra):
        return min(valid, key=lambda a: (_target(obs, a).queue + extra[a], a))


class Greedy(Policy):
    """The least estimated completion time: upload + wait + execution + result download.

    Waiting is estimated as the target's queue times this task's cycles over its capacity; a target
    whose buffer is full is skipped, since the task would be dropped there.
    """

    name = "greedy"

    def choose(self, obs, task, valid, extra):
        return min(valid, key=lambda a: (self.estimate(obs, task, a, extra[a]), a))

    @staticmethod
    def estimate(obs: Observation, task: TaskView, action: int, extra: int) -> float:
        node = _target(obs, action)
        cycles = task.size.cycles
        wait = (node.queue + extra) * cycles / node.capacity
        run = cycles / node.capacity
        if action == 0:
            return wait + run
        if node.occupancy + extra >= node.buffer:
            return math.inf
        transfer = (task.size.input_bytes + task.size.output_bytes) * 8.0 / node.rate_bps
        return transfer + wait + run


class GreedyBacklog(Greedy):
    """Greedy, with the transfers already queued on the link to a target (``NodeView.backlog_s``) added
    to the upload: the per-link FIFO contention that plain greedy does not see."""

    name = "greedy_backlog"

    @staticmethod
    def estimate(obs: Observation, task: TaskView, action: int, extra: int) -> float:
        estimate = Greedy.estimate(obs, task, action, extra)
        return estimate if action == 0 else estimate + _target(obs, action).backlog_s


class LocalFirst(GreedyBacklog):
    """Keep the task when greedy_backlog's estimate for the node itself meets its deadline; otherwise
    greedy_backlog's choice. It offloads only what would miss its deadline at home, so the fast nodes
    are left to the tasks that need them instead of filling up with tasks that did not."""

    name = "local_first"

    def choose(self, obs, task, valid, extra):
        if 0 in valid and self.estimate(obs, task, 0, extra[0]) <= task.time_left:
            return 0
        return super().choose(obs, task, valid, extra)


POLICIES: dict[str, type[Policy]] = {p.name: p for p in (Local, Random, RoundRobin, LeastQueue, Greedy, GreedyBacklog,
                                                         LocalFirst)}


def make_policy(name: str) -> Policy:
    """A built-in policy by name, or a user's ``Policy`` subclass by import path ("module:Class")."""
    if is_import_path(name):
        return load(name, Policy)()
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; expected one of {', '.join(POLICIES)}") from None
