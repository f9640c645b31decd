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
    params: ClassVar[tuple[str, ...]] = ()  # numeric class attributes that ``configured`` may set

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


class Threshold(Policy):
    """Keep the task while the own queue (as last reported, plus the tasks this batch kept) is below
    ``threshold`` tasks; from there on, offload it to the neighbour with the least greedy_backlog estimate,
    or keep it when no neighbour can take it. The classic threshold rule; ``threshold`` is tuned on the
    validation suite (``python -m experiments.tune_baselines``)."""

    name = "threshold"
    params = ("threshold",)
    threshold: ClassVar[float] = 2.0

    def choose(self, obs, task, valid, extra):
        if obs.own.queue + extra[0] < self.threshold:
            return 0
        costs = {a: GreedyBacklog.estimate(obs, task, a, extra[a]) for a in valid if a}
        best = min(costs, key=lambda a: (costs[a], a), default=0)
        return best if best and math.isfinite(costs[best]) else 0


class DriftPlusPenalty(Policy):
    """Lyapunov drift-plus-penalty: the target minimising drift + ``v`` x penalty.

    The queues are each target's CPU queue and the link to it, in seconds of work. Sending a task adds
    its service time s to the target's queue Q (the queue as last heard, plus this batch's tasks, times
    s), and its transfer time u to the link's backlog B; the growth of the quadratic Lyapunov function
    ½ΣQ² is then (Q + s/2)·s + (B + u/2)·u. The penalty is the task's expected response time, greedy_backlog's
    estimate; a target whose buffer is full costs infinity. ``v`` (seconds) trades queue balance (small)
    against each task's own response (large: greedy_backlog); it is tuned on the validation suite."""

    name = "drift_plus_penalty"
    params = ("v",)
    v: ClassVar[float] = 1.0

    def choose(self, obs, task, valid, extra):
        return min(valid, key=lambda a: (self.cost(obs, task, a, extra[a]), a))

    def cost(self, obs: Observation, task: TaskView, action: int, extra: int) -> float:
        node = _target(obs, action)
        service = task.size.cycles / node.capacity
        drift = ((node.queue + extra) * service + service / 2) * service
        if action:
            transfer = (task.size.input_bytes + task.size.output_bytes) * 8.0 / node.rate_bps
            drift += (node.backlog_s + transfer / 2) * transfer
        return drift + self.v * GreedyBacklog.estimate(obs, task, action, extra)


POLICIES: dict[str, type[Policy]] = {p.name: p for p in (Local, Random, RoundRobin, LeastQueue, Greedy, GreedyBacklog,
                                                         LocalFirst, Threshold, DriftPlusPenalty)}


def configured(rule: type[Policy], **params: float) -> type[Policy]:
    """``rule`` with parameters set (``Threshold.threshold``, ``DriftPlusPenalty.v``): a subclass of the same
    name, which ``agents.baselines.baseline`` runs as an agent. A name the rule does not take is a ValueError."""
    unknown = sorted(set(params) - set(rule.params))
    if unknown:
        raise ValueError(f"{rule.name} takes {', '.join(rule.params) or 'no parameters'}, not {', '.join(unknown)}")
    return type(rule.__name__, (rule,), {k: float(v) for k, v in params.items()} | {"__doc__": rule.__doc__})


def make_policy(name: str) -> Policy:
    """A built-in policy by name, or a user's ``Policy`` subclass by import path ("module:Class")."""
    if is_import_path(name):
        return load(name, Policy)()
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; expected one of {', '.join(POLICIES)}") from None
