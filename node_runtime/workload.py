"""What a client generates: Poisson arrivals under a rate schedule, or rows of a trace."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from node_runtime.config import Arrival, Scenario, TaskType, TraceRow

BLOCK = 256  # ticks of arrival counts drawn at once (a constant: part of the stream's definition)


def rate_at(arrival: Arrival, seconds: float, horizon: float) -> float:
    """lambda(t) in tasks per second for the deterministic schedules."""
    if arrival.kind == "constant":
        return arrival.rate
    if arrival.kind == "linear":
        frac = min(max(seconds / horizon, 0.0), 1.0) if horizon > 0 else 0.0
        return arrival.start + (arrival.end - arrival.start) * frac
    if arrival.kind == "zigzag":
        phase = (seconds % arrival.period) / arrival.period
        tri = 2 * phase if phase < 0.5 else 2 * (1 - phase)
        return arrival.low + (arrival.high - arrival.low) * tri
    raise ValueError(f"rate_at: no deterministic rate for arrival kind {arrival.kind!r}")


def trace_tick(row: TraceRow, dt: float) -> int:
    return math.floor(row.time / dt + 1e-9)


class TaskSource:
    """Draws (count, types) of new tasks per tick for one client.

    Counts come from one stream and task types from another, so changing the task mix does not
    shift the arrival times. Poisson(lambda * dt) per tick, with no cap on the count.
    """

    def __init__(self, scenario: Scenario, node: str, counts_rng: np.random.Generator,
                 types_rng: np.random.Generator) -> None:
        self.dt = scenario.dt
        self.horizon = scenario.episode_ticks * scenario.dt
        self.arrival = scenario.workload.arrival
        self.types: tuple[TaskType, ...] = scenario.workload.task_types
        weights = np.array([t.weight for t in self.types], dtype=float)
        self.probs = weights / weights.sum()
        self.counts_rng = counts_rng
        self.types_rng = types_rng
        self.fixed_rate = dict(scenario.workload.client_rates).get(node)
        if self.fixed_rate is None and self.arrival.kind == "uniform":
            self.fixed_rate = float(counts_rng.uniform(self.arrival.low, self.arrival.high))
        self._block_start = -1
        self._block: np.ndarray = np.zeros(0, dtype=np.int64)
        self.trace: dict[int, list[TraceRow]] | None = None
        if scenario.workload.trace is not None:
            self.trace = defaultdict(list)
            for row in scenario.workload.trace:
                if row.client == node:
                    self.trace[trace_tick(row, self.dt)].append(row)

    def rate(self, tick: int) -> float:
        if self.fixed_rate is not None:
            return self.fixed_rate
        return rate_at(self.arrival, tick * self.dt, self.horizon)

    def count(self, tick: int) -> int:
        start = tick - tick % BLOCK
        if start != self._block_start:
            lam = np.array([self.rate(s) * self.dt for s in range(start, start + BLOCK)])
            self._block = self.counts_rng.poisson(lam)
            self._block_start = start
        return int(self._block[tick - start])

    def draws(self, tick: int) -> list[tuple[float, float, float, float, float]]:
        """(instructions, input_bytes, output_bytes, cpi, deadline) of every task created at ``tick``."""
        if self.trace is not None:
            return [(r.instructions, r.input_bytes, r.output_bytes, r.cpi, r.deadline)
                    for r in self.trace.get(tick, ())]
        n = self.count(tick)
        if n == 0:
            return []
        if len(self.types) == 1:
            picks = [self.types[0]] * n
        else:
            picks = [self.types[i] for i in self.types_rng.choice(len(self.types), size=n, p=self.probs)]
        return [(t.instructions, t.input_bytes, t.output_bytes, t.cpi, t.deadline) for t in picks]
