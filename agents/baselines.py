"""Heuristic policies that read the same observations as the learning agents and respect the masks.

They are the comparison points of the paper (local, random, least queue) plus four stronger ones
(round robin, greedy, greedy_backlog, local_first): the twins of the node-side policies of the same names. In batch
mode the tasks of one step are placed one after another, and each placed task counts against its
target, so that a batch does not pile onto one node.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping

import numpy as np

from agents.common import Action, Observation, is_batch, masks_of
from env.observations import NeighbourField, OwnField, TaskField


class Baseline(ABC):
    """Shared plumbing: per-slot masks, the extra load a batch puts on each target, no-op slots."""

    name = "baseline"

    def __init__(self, seed: int | None = None) -> None:
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, observations: Mapping[str, Observation]) -> dict[str, Action]:
        actions: dict[str, Action] = {}
        for agent, obs in observations.items():
            masks = masks_of(obs)
            tasks = np.asarray(obs["task"]).reshape(len(masks), -1)
            extra = np.zeros(len(masks[0]), dtype=np.float64)  # tasks of this step already sent to each target
            chosen = []
            for task, mask in zip(tasks, masks, strict=True):
                valid = np.flatnonzero(mask)
                if task[TaskField.PRESENT] > 0 and len(valid) > 1:
                    a = int(self.choose(agent, obs, task, valid, extra))
                    extra[a] += 1
                else:
                    a = int(valid[0])  # nothing to decide (or a single choice): the only valid action
                chosen.append(a)
            actions[agent] = chosen if is_batch(obs) else chosen[0]
        return actions

    @abstractmethod
    def choose(self, agent: str, obs: Observation, task: np.ndarray, valid: np.ndarray, extra: np.ndarray) -> int:
        """One valid action (from ``valid``) for ``task``; ``extra`` counts this step's tasks per target."""


def _queues(obs: Observation) -> np.ndarray:
    """Queue length of every target: the node itself (action 0), then each neighbour slot."""
    return np.concatenate([[obs["own"][OwnField.QUEUE]], obs["neighbours"][:, NeighbourField.QUEUE]])


class Local(Baseline):
    """Never offload."""

    name = "local"

    def choose(self, agent, obs, task, valid, extra):
        return 0 if 0 in valid else valid[0]


class Random(Baseline):
    """A uniformly random valid target, the node itself included."""

    name = "random"

    def choose(self, agent, obs, task, valid, extra):
        return self.rng.choice(valid)


class RoundRobin(Baseline):
    """Cycle through the valid targets, the node itself first, with one counter per agent."""

    name = "round_robin"

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.next: dict[str, int] = {}

    def choose(self, agent, obs, task, valid, extra):
        k = self.next.get(agent, 0)
        self.next[agent] = k + 1
        return valid[k % len(valid)]


class LeastQueue(Baseline):
    """The valid target with the shortest queue as last heard; ties go to the lowest action (local first)."""

    name = "least_queue"

    def choose(self, agent, obs, task, valid, extra):
        load = (_queues(obs) + extra)[valid]
        return valid[int(np.argmin(load))]  # argmin keeps the first of equal values


class Greedy(Baseline):
    """The least estimated completion time: transfer (input + output) * 8 / rate, plus waiting
    queue * cycles / capacity, plus execution cycles / capacity. Local has no transfer; a neighbour whose
    buffer is full is skipped, since the task would be dropped there."""

    name = "greedy"

    def choose(self, agent, obs, task, valid, extra):
        costs = [self.estimate(obs, task, int(a), extra[a]) for a in valid]
        return valid[int(np.argmin(costs))]

    @staticmethod
    def estimate(obs: Observation, task: np.ndarray, action: int, extra: float) -> float:
        cycles = task[TaskField.INSTRUCTIONS_G] * task[TaskField.CPI] * 1e9
        if action == 0:
            own = obs["own"]
            capacity = own[OwnField.CAPACITY_GCPS] * 1e9
            return (own[OwnField.QUEUE] + extra + 1) * cycles / capacity if capacity > 0 else math.inf
        nb = obs["neighbours"][action - 1]
        capacity = nb[NeighbourField.CAPACITY_GCPS] * 1e9
        if nb[NeighbourField.OCCUPANCY] + extra >= nb[NeighbourField.BUFFER] or capacity <= 0:
            return math.inf
        transfer = (task[TaskField.INPUT_MB] + task[TaskField.OUTPUT_MB]) * 8e6 / (nb[NeighbourField.RATE_MBPS] * 1e6)
        return transfer + (nb[NeighbourField.QUEUE] + extra + 1) * cycles / capacity


class GreedyBacklog(Greedy):
    """Greedy, with the seconds of transfer already queued on the link to a neighbour added to its
    estimate: the per-link FIFO contention that plain greedy does not see."""

    name = "greedy_backlog"

    @staticmethod
    def estimate(obs: Observation, task: np.ndarray, action: int, extra: float) -> float:
        estimate = Greedy.estimate(obs, task, action, extra)
        return estimate if action == 0 else estimate + obs["neighbours"][action - 1][NeighbourField.BACKLOG_S]


class LocalFirst(GreedyBacklog):
    """Keep the task when greedy_backlog's estimate for the node itself meets its deadline (the task's
    time left); otherwise greedy_backlog's choice. Only tasks that would miss their deadline at home
    are offloaded, which leaves the fast nodes to them."""

    name = "local_first"

    def choose(self, agent, obs, task, valid, extra):
        if 0 in valid and self.estimate(obs, task, 0, extra[0]) <= task[TaskField.TIME_LEFT_S]:
            return 0
        return super().choose(agent, obs, task, valid, extra)


BASELINES: dict[str, type[Baseline]] = {p.name: p for p in (Local, Random, RoundRobin, LeastQueue, Greedy,
                                                            GreedyBacklog, LocalFirst)}
