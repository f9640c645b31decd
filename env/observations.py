"""From a controller's raw view (``node_runtime.model.view.Observation``) to fixed-shape arrays.

Every agent observes a ``Dict`` of float32 arrays in units that keep magnitudes near 1 (documented
in docs/env.md):

- ``own`` (6,): queue, occupancy, buffer, capacity [Gcycles/s], tier, undecided tasks;
- ``task`` (7,) — or (B, 7) in batch mode: present (0/1), instructions [G], input [MB],
  output [MB], cycles per instruction, time to deadline [s], ticks waited undecided;
- ``neighbours`` (D, 8): present (0/1), queue, occupancy, buffer, capacity [Gcycles/s], tier,
  link rate [Mbit/s], age of the information [ticks] — in the canonical neighbour order, which is
  also the order of actions 1..D;
- ``action_mask`` (1 + D,) int8 — in batch mode a tuple of B such arrays, one per task slot (the form
  ``MultiDiscrete.sample(mask)`` takes): 1 where the action is allowed.

D is the agent's degree, or the largest degree of all agents with ``uniform=True`` (padding slots
have present = 0 and a masked action), so that one network can serve every agent.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from gymnasium import spaces

from node_runtime.model.view import Observation

OWN_FIELDS = ("queue", "occupancy", "buffer", "capacity_gcps", "tier", "undecided")
TASK_FIELDS = ("present", "instructions_g", "input_mb", "output_mb", "cpi", "time_left_s", "waited_ticks")
NEIGHBOUR_FIELDS = ("present", "queue", "occupancy", "buffer", "capacity_gcps", "tier", "rate_mbps", "age_ticks")
TIME_LEFT = TASK_FIELDS.index("time_left_s")


@dataclass(frozen=True)
class ObservationLayout:
    """The shape of one agent's observation: its degree, the padded degree and the batch size."""

    degree: int
    slots: int  # neighbour slots (>= degree when padded)
    batch: int | None  # None in binary mode: one task, and no batch axis

    @property
    def n_actions(self) -> int:
        return 1 + self.slots

    def space(self) -> spaces.Dict:
        inf = np.float32(np.inf)
        task_shape = (len(TASK_FIELDS),) if self.batch is None else (self.batch, len(TASK_FIELDS))
        task_low = np.zeros(task_shape, dtype=np.float32)
        task_low[..., TIME_LEFT] = -inf  # an undecided task may already be past its deadline
        mask = spaces.Box(0, 1, (self.n_actions,), np.int8)
        return spaces.Dict({
            "own": spaces.Box(0.0, inf, (len(OWN_FIELDS),), np.float32),
            "task": spaces.Box(task_low, np.full(task_shape, inf, dtype=np.float32), task_shape, np.float32),
            "neighbours": spaces.Box(0.0, inf, (self.slots, len(NEIGHBOUR_FIELDS)), np.float32),
            "action_mask": mask if self.batch is None else spaces.Tuple([mask] * self.batch),
        })

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
            worker = [n.worker for n in obs.neighbours]
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

    Static features (buffers, capacities, tiers, link rates, which neighbours take tasks) are filled
    once, from the first view; the changing ones (queues, ages, tasks) at every step.
    """

    def __init__(self, layout: ObservationLayout) -> None:
        super().__init__(layout)
        self.template: dict[str, Any] | None = None

    def space(self) -> spaces.Dict:
        return self.layout.space()

    def _fill_static(self, first: Observation) -> dict[str, Any]:
        template = self.layout.empty()
        own = first.own
        template["own"][2:5] = (own.buffer, own.capacity * 1e-9, own.tier)
        nb = template["neighbours"]
        for i, n in enumerate(first.neighbours):
            nb[i, [0, 3, 4, 5, 6]] = (1.0, n.buffer, n.capacity * 1e-9, n.tier, n.rate_bps * 1e-6)
        return template

    def encode(self, obs: Observation | None) -> dict[str, Any]:
        if obs is None:
            return self.layout.empty()
        if self.template is None:
            self.template = self._fill_static(obs)
        out = copy_obs(self.template)
        own = out["own"]
        own[0] = obs.own.queue
        own[1] = obs.own.occupancy
        own[5] = obs.undecided
        if obs.neighbours:
            out["neighbours"][:len(obs.neighbours), [1, 2, 7]] = [(n.queue, n.occupancy, n.age) for n in obs.neighbours]
        if obs.tasks:
            tasks = out["task"] if self.layout.batch is not None else out["task"][None, :]
            for k, task in enumerate(obs.tasks):
                tasks[k] = (1.0, task.instructions * 1e-9, task.input_bytes * 1e-6, task.output_bytes * 1e-6, task.cpi,
                            task.time_left, task.waited)
            out["action_mask"] = self.layout.masks(obs)
        return out


def copy_obs(obs: dict) -> dict:
    mask = obs["action_mask"]
    return {"own": obs["own"].copy(), "task": obs["task"].copy(), "neighbours": obs["neighbours"].copy(),
            "action_mask": mask.copy() if isinstance(mask, np.ndarray) else tuple(m.copy() for m in mask)}
