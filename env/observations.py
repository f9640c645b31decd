"""From a controller's raw view (``node_runtime.model.view.Observation``) to fixed-shape arrays.

Every agent observes a ``Dict`` of float32 arrays in units that keep magnitudes near 1 (documented
in docs/env.md):

- ``own`` (7,): queue, occupancy, buffer, capacity [Gcycles/s], tier, undecided tasks, work [s];
- ``task`` (7,) — or (B, 7) in batch mode: present (0/1), instructions [G], input [MB],
  output [MB], cycles per instruction, time to deadline [s], ticks waited undecided;
- ``neighbours`` (D, 10): present (0/1), queue, occupancy, buffer, capacity [Gcycles/s], tier,
  link rate [Mbit/s], age of the information [ticks], backlog of the link [s], work [s] — in the canonical
  neighbour order, which is also the order of actions 1..D; work is the seconds of CPU time the node's
  admitted tasks still need, as last heard (``NodeView.work_s``: a queue of mixed task sizes is not its length);
- ``job`` (3,) — or (B, 3) — only in a scenario of jobs (``workload.jobs``): in a job (0/1), the task's
  remaining critical path [Gcycles] (its own cycles plus the most on a path to its job's end), and its
  successors' data [MB] (the bytes its result carries on to them);
- ``action_mask`` (1 + D,) int8 — in batch mode a tuple of B such arrays, one per task slot (the form
  ``MultiDiscrete.sample(mask)`` takes): 1 where the action is allowed.

D is the agent's degree, or the largest degree of all agents with ``uniform_spaces=True``, or K with
``neighbour_slots=K`` whatever the scenario (padding slots have present = 0 and a masked action), so that
one network can serve every agent, of one scenario or of many. The columns are
named by ``OwnField``, ``TaskField`` and ``NeighbourField``, for the encoder here and for the agents.

``FlatObservation`` (``ZenohEdgeEnv(observation="flat")``) gives the same numbers as one float32 vector
per agent, plus a one-hot agent id, beside ``action_mask``: the ``{"observation", "action_mask"}``
convention that MARL libraries (TorchRL, RLlib, AgileRL, PettingZoo's masking examples) take as is.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property
from typing import Any

import numpy as np
from gymnasium import spaces

from node_runtime.model.view import Observation


class OwnField(IntEnum):
    """Columns of ``own``: ``obs["own"][OwnField.QUEUE]``."""

    QUEUE = 0  # tasks admitted for processing
    OCCUPANCY = 1  # queued + undecided
    BUFFER = 2  # Q_max
    CAPACITY_GCPS = 3
    TIER = 4
    UNDECIDED = 5
    WORK_S = 6  # seconds of CPU work left in the admitted tasks (``NodeView.work_s``)


class TaskField(IntEnum):
    """Columns of ``task`` (of each row of it in batch mode): ``obs["task"][TaskField.PRESENT]``."""

    PRESENT = 0  # 1 when there is a task to place; 0: nothing to decide
    INSTRUCTIONS_G = 1
    INPUT_MB = 2
    OUTPUT_MB = 3
    CPI = 4
    TIME_LEFT_S = 5  # < 0 once past the deadline
    WAITED_TICKS = 6


class JobField(IntEnum):
    """Columns of ``job`` (of each row in batch mode), in a scenario of jobs only:
    ``obs["job"][JobField.CRITICAL_GCYCLES]``."""

    IN_JOB = 0  # 1 when the task to place belongs to a job
    CRITICAL_GCYCLES = 1  # remaining critical path: its cycles plus the most on a path to an exit task of its job
    SUCCESSOR_MB = 2  # the data of its out-edges, which its successors need


class NeighbourField(IntEnum):
    """Columns of ``neighbours`` (one row per slot): ``obs["neighbours"][:, NeighbourField.QUEUE]``."""

    PRESENT = 0  # 0 in a padding slot
    QUEUE = 1
    OCCUPANCY = 2
    BUFFER = 3
    CAPACITY_GCPS = 4
    TIER = 5
    RATE_MBPS = 6  # of the link from this node
    AGE_TICKS = 7  # of the information
    BACKLOG_S = 8  # seconds of transfer already queued on the link from this node (FIFO contention)
    WORK_S = 9  # seconds of CPU work left in its admitted tasks, as last heard (``NodeView.work_s``)


# Columns the encoder fills once (static) and at every step (dynamic), as index arrays.
_OWN_STATIC = np.array([OwnField.BUFFER, OwnField.CAPACITY_GCPS, OwnField.TIER])
_NEIGHBOUR_STATIC = np.array([NeighbourField.PRESENT, NeighbourField.BUFFER, NeighbourField.CAPACITY_GCPS,
                              NeighbourField.TIER])
# the rate is dynamic: a moving neighbour's follows the distance (0 out of range)
_NEIGHBOUR_DYNAMIC = np.array([NeighbourField.QUEUE, NeighbourField.OCCUPANCY, NeighbourField.RATE_MBPS,
                               NeighbourField.AGE_TICKS, NeighbourField.BACKLOG_S, NeighbourField.WORK_S])


@dataclass(frozen=True)
class ObservationLayout:
    """The shape of one agent's observation: its degree, the padded degree and the batch size."""

    degree: int
    slots: int  # neighbour slots (>= degree when padded)
    batch: int | None  # None in binary mode: one task, and no batch axis
    jobs: bool = False  # a scenario of jobs: a ``job`` block beside ``task``
    dt: float = 1.0  # seconds a tick: the work columns are in seconds

    @property
    def n_actions(self) -> int:
        return 1 + self.slots

    def space(self) -> spaces.Dict:
        inf = np.float32(np.inf)
        task_shape = (len(TaskField),) if self.batch is None else (self.batch, len(TaskField))
        task_low = np.zeros(task_shape, dtype=np.float32)
        task_low[..., TaskField.TIME_LEFT_S] = -inf  # an undecided task may already be past its deadline
        mask = spaces.Box(0, 1, (self.n_actions,), np.int8)
        job = {"job": spaces.Box(0.0, inf, self.job_shape, np.float32)} if self.jobs else {}
        return spaces.Dict({
            "own": spaces.Box(0.0, inf, (len(OwnField),), np.float32),
            "task": spaces.Box(task_low, np.full(task_shape, inf, dtype=np.float32), task_shape, np.float32),
            **job,
            "neighbours": spaces.Box(0.0, inf, (self.slots, len(NeighbourField)), np.float32),
            "action_mask": mask if self.batch is None else spaces.Tuple([mask] * self.batch),
        })

    @property
    def job_shape(self) -> tuple[int, ...]:
        return (len(JobField),) if self.batch is None else (self.batch, len(JobField))

    def action_space(self) -> spaces.Space:
        if self.batch is None:
            return spaces.Discrete(self.n_actions)
        return spaces.MultiDiscrete(np.full(self.batch, self.n_actions, dtype=np.int64))

    @cached_property
    def _template(self) -> dict[str, np.ndarray]:
        out = {k: np.zeros(s.shape, dtype=s.dtype) for k, s in self.space().spaces.items() if k != "action_mask"}
        mask = np.zeros(self.n_actions, dtype=np.int8)
        mask[0] = 1
        out["action_mask"] = mask if self.batch is None else tuple(mask.copy() for _ in range(self.batch))
        return out

    def empty(self) -> dict[str, np.ndarray]:
        """The observation of an agent whose node is down or has not been heard yet."""
        return copy_obs(self._template)


    def masks(self, obs: Observation | None) -> np.ndarray | tuple[np.ndarray, ...]:
        """The action mask(s) of this observation: what the environment validates actions against."""
        base = np.zeros(self.n_actions, dtype=np.int8)
        base[0] = 1
        rows = [base.copy() for _ in range(1 if self.batch is None else self.batch)]
        if obs is not None:
            worker = obs.valid_actions()[1:]
            for k in range(len(obs.tasks)):
                rows[k][1:1 + self.degree] = worker
        return rows[0] if self.batch is None else tuple(rows)


class ObservationBuilder:
    """Turns a controller's raw view into what its agent observes.

    Subclass it and name it in the scenario (``observation: mylab.obs:MyBuilder``) or pass the class as
    ``ZenohEdgeEnv(observation=...)``. Override ``space`` and ``encode``; the action masks the
    environment enforces come from ``layout.masks(obs)`` whatever the observation holds.
    """

    def __init__(self, layout: ObservationLayout) -> None:
        self.layout = layout

    def space(self) -> spaces.Space:
        raise NotImplementedError

    def encode(self, obs: Observation | None) -> Any:
        """``obs`` is None when the agent's node is down (nothing was heard from its controller)."""
        raise NotImplementedError


class DictObservation(ObservationBuilder):
    """The default: the documented Dict of float32 arrays and the action mask.

    Static features (buffers, capacities, tiers, which neighbours take tasks) are filled once, from the
    first view; the changing ones (queues, link rates, ages, tasks) at every step.
    """

    def __init__(self, layout: ObservationLayout) -> None:
        super().__init__(layout)
        self.template: dict[str, Any] | None = None

    def space(self) -> spaces.Dict:
        return self.layout.space()

    def _fill_static(self, first: Observation) -> dict[str, Any]:
        template = self.layout.empty()
        own = first.own
        template["own"][_OWN_STATIC] = (own.buffer, own.capacity * 1e-9, own.tier)
        nb = template["neighbours"]
        for i, n in enumerate(first.neighbours):
            nb[i, _NEIGHBOUR_STATIC] = (1.0, n.buffer, n.capacity * 1e-9, n.tier)
        return template

    def encode(self, obs: Observation | None) -> dict[str, Any]:
        if obs is None:
            return self.layout.empty()
        if self.template is None:
            self.template = self._fill_static(obs)
        out = copy_obs(self.template)
        own = out["own"]
        own[OwnField.QUEUE] = obs.own.queue
        own[OwnField.OCCUPANCY] = obs.own.occupancy
        own[OwnField.UNDECIDED] = obs.undecided
        t, dt = obs.tick, self.layout.dt
        own[OwnField.WORK_S] = obs.own.work_s(t, dt)
        if obs.neighbours:
            out["neighbours"][:len(obs.neighbours), _NEIGHBOUR_DYNAMIC] = [
                (n.queue, n.occupancy, n.rate_bps * 1e-6, n.age, n.backlog_s, n.work_s(t, dt)) for n in obs.neighbours]
        if obs.tasks:
            tasks = out["task"] if self.layout.batch is not None else out["task"][None, :]
            for k, task in enumerate(obs.tasks):  # the columns of TaskField, in order
                size = task.size
                tasks[k] = (1.0, size.instructions * 1e-9, size.input_bytes * 1e-6, size.output_bytes * 1e-6, size.cpi,
                            task.time_left, task.waited)
            if self.layout.jobs:
                jobs = out["job"] if self.layout.batch is not None else out["job"][None, :]
                for k, task in enumerate(obs.tasks):  # the columns of JobField, in order
                    if task.job is not None:
                        jobs[k] = (1.0, task.job.critical_cycles * 1e-9, task.job.successor_bytes * 1e-6)
            out["action_mask"] = self.layout.masks(obs)
        return out


class FlatObservation(ObservationBuilder):
    """``observation="flat"``: ``{"observation": (F,) float32, "action_mask": int8}``, one shape for all agents.

    ``observation`` is ``own``, ``task`` (row-major in batch mode), ``job`` (likewise, only in a scenario
    of jobs), ``neighbours`` (row-major, padded to
    the largest degree) and the one-hot index of the agent in ``possible_agents``, so that a network
    shared by all agents can tell them apart; ``slices`` says where each block lies. ``action_mask`` is
    (1 + D,), or (B, 1 + D) in batch mode.
    """

    def __init__(self, layout: ObservationLayout, agent_index: int = 0, n_agents: int = 1) -> None:
        super().__init__(layout)
        self.fields = DictObservation(layout)
        self.agent_id = np.zeros(n_agents, dtype=np.float32)
        self.agent_id[agent_index] = 1.0
        spaces_ = layout.space().spaces
        self.blocks = ("own", "task", "job", "neighbours") if layout.jobs else ("own", "task", "neighbours")
        sizes = {k: int(np.prod(spaces_[k].shape)) for k in self.blocks} | {"agent_id": n_agents}
        ends = np.cumsum(list(sizes.values()))
        self.slices = {k: slice(int(end - n), int(end)) for (k, n), end in zip(sizes.items(), ends, strict=True)}
        self._low = np.concatenate([spaces_[k].low.ravel() for k in self.blocks]
                                   + [np.zeros(n_agents, dtype=np.float32)])
        self._high = np.concatenate([spaces_[k].high.ravel() for k in self.blocks]
                                    + [np.ones(n_agents, dtype=np.float32)])

    def space(self) -> spaces.Dict:
        mask_shape = (self.layout.n_actions,) if self.layout.batch is None else (self.layout.batch,
                                                                                  self.layout.n_actions)
        return spaces.Dict({"observation": spaces.Box(self._low, self._high, self._low.shape, np.float32),
                            "action_mask": spaces.Box(0, 1, mask_shape, np.int8)})

    def encode(self, obs: Observation | None) -> dict[str, np.ndarray]:
        return self.flatten(self.fields.encode(obs))

    def flatten(self, fields: dict[str, Any]) -> dict[str, np.ndarray]:
        """The flat form of this agent's Dict observation (``observation=None``, the default, with
        ``uniform_spaces=True``): what a policy trained on flat observations acts on."""
        mask = fields["action_mask"]
        return {"observation": np.concatenate([*(fields[k].ravel() for k in self.blocks), self.agent_id]),
                "action_mask": mask if isinstance(mask, np.ndarray) else np.stack(mask)}


def copy_obs(obs: dict) -> dict:
    mask = obs["action_mask"]
    return {**{k: v.copy() for k, v in obs.items() if k != "action_mask"},
            "action_mask": mask.copy() if isinstance(mask, np.ndarray) else tuple(m.copy() for m in mask)}
