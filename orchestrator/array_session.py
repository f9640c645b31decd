"""The array backend as the environment drives it: K copies of a scenario in one ``ArraySim``, each summed into
its own ``Metrics`` exactly as a ``Simulation``'s processes are, and a ``Simulation``-like view of each copy.

``ZenohEdgeEnv(backend="array")`` holds the view of a batch of one copy where it would hold a ``Simulation``:
the same ``reset``, ``step``, ``observations``, ``tick``, ``metrics`` and ``summary``, so that the environment's
own code makes its observations, masks, rewards, credits and infos from them. ``ZenohEdgeVectorEnv`` steps
the batch once for all its copies (``ArrayBatch.step``) and lets each copy's environment read its view.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from node_runtime.model.array import ArraySim
from node_runtime.model.controller import Action
from node_runtime.model.role import role_node
from node_runtime.model.spec import Scenario
from node_runtime.model.view import Observation
from node_runtime.runtime.layout import ProcessLayout
from orchestrator.metrics import Metrics, TickReport
from orchestrator.session import node_policies
from orchestrator.version import code_version


class ArrayBatch:
    """K copies of ``scenario`` stepped together; ``ticks``: the longest episode, in ticks (the arrivals of
    that many are drawn at each reset). Every copy starts its episodes together (``reset``)."""

    def __init__(self, scenario: Scenario, k: int, ticks: int | None = None) -> None:
        self.scenario = scenario
        self.sim = ArraySim(scenario, k)  # refuses what it does not model (``Unsupported``), in one line
        self.ticks = ticks
        plan = ProcessLayout(scenario, "single")
        self.metrics = [Metrics(plan, history=False) for _ in range(k)]
        self.copies = [ArrayCopy(self, c) for c in range(k)]
        self.external: tuple[str, ...] = ()
        self._nodes: tuple[int, ...] = ()
        self.started = 0.0

    def reset(self, seeds: Sequence[int], external: Sequence[str] | None = None,
              policy: str | None = None) -> list[TickReport]:
        """Start an episode in every copy (copy c with ``seeds[c]``) and run its tick 0. ``external``: the
        controller roles an agent drives; ``policy``: the node-side policy of the others, for this episode."""
        self.begin(seeds, external, policy)
        return self._tick()

    def begin(self, seeds: Sequence[int], external: Sequence[str] | None = None, policy: str | None = None) -> None:
        """``reset`` up to its tick 0, which the caller runs (``sim.step()``): the batched vector env reads the
        copies' arrays itself (env/batched.py), so their ``Metrics`` are left at their reset."""
        sc, sim = self.scenario, self.sim
        self.external = tuple(external or ())
        self._nodes = tuple(sc.index[role_node(r)] for r in self.external)
        sim.drive([role_node(r) for r in self.external])
        sim.use_policy(policy)
        sim.reset([int(s) for s in seeds], self.ticks)
        for metrics, view, seed in zip(self.metrics, self.copies, seeds, strict=True):
            metrics.reset()
            view.seed, view.policy = int(seed), policy
        self.started = time.perf_counter()

    def step(self, actions: Sequence[dict[str, Action] | None]) -> list[TickReport]:
        """One tick of every copy; ``actions[c]``: copy c's driven controllers' answers to their last
        observations, by role (an int in binary mode, one int per task in batch mode)."""
        index = self.scenario.index
        for copy, given in enumerate(actions):
            for role, action in (given or {}).items():
                self.sim.act(copy, index[role_node(role)], [action] if isinstance(action, int) else action)
        return self._tick()

    def _tick(self) -> list[TickReport]:
        sim = self.sim
        t = sim.t
        counters = sim.step()
        return [m.add_counters(t, counters[c], sim.completions[c], sim.ledger[c]) for c, m in enumerate(self.metrics)]

    def observations(self, copy: int) -> dict[str, Observation]:
        """What copy ``copy``'s driven controllers observe at the current tick, by role (none between epochs, and none
        of a controller whose node is down: the environment reads it as an empty observation)."""
        sim = self.sim
        if sim.seen != sim.t - 1:
            return {}
        down = sim.down[sim.seen]
        return {role: sim.observation(copy, node) for role, node in zip(self.external, self._nodes, strict=True)
                if not down[node]}


class ArrayCopy:
    """One copy of an ``ArrayBatch``, read as a ``Simulation`` is (``ZenohEdgeEnv.sim``). ``reset`` and ``step``
    drive the batch itself, so they serve a batch of one copy; a vector env steps its batch instead."""

    transport_name = "array"

    def __init__(self, batch: ArrayBatch, copy: int) -> None:
        self.batch = batch
        self.copy = copy
        self.seed = batch.scenario.seed
        self.policy: str | None = None

    @property
    def metrics(self) -> Metrics:
        return self.batch.metrics[self.copy]

    @property
    def tick(self) -> int:
        return self.batch.sim.t - 1

    def _alone(self) -> None:
        if len(self.batch.copies) > 1:
            raise RuntimeError("a copy of an array batch of several is reset and stepped with its batch")

    def reset(self, seed: int | None = None, external: list[str] | None = None,
              policy: str | None = None) -> TickReport:
        self._alone()
        return self.batch.reset([self.batch.scenario.seed if seed is None else seed], external, policy)[0]

    def step(self, actions: dict[str, Action] | None = None) -> TickReport:
        self._alone()
        return self.batch.step([actions])[0]

    def open_next(self) -> None:
        """Nothing runs ahead: the batch steps when asked."""

    def observations(self) -> dict[str, Observation]:
        return self.batch.observations(self.copy)

    def summary(self) -> dict[str, Any]:
        """As ``Simulation.summary``; its "run" block says which backend ran it."""
        s = self.metrics.summary()
        s["seed"] = self.seed
        s["policy"] = node_policies(self.batch.scenario, self.policy)
        s["code"] = code_version()
        wall = time.perf_counter() - self.batch.started
        s["run"] = {"backend": "array", "copies": len(self.batch.copies), "wall_time_s": round(wall, 3)}
        return s

    def close(self) -> None:
        """Nothing to stop: no process, no bus."""
