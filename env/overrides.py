"""``ScenarioOverrides``: the scenario settings an experiment varies without writing a scenario file.

    env = ZenohEdgeEnv("aot2", overrides=ScenarioOverrides(mode="batch", batch_size=3, arrival_rate=0.3))

They change the emulated scenario itself, so a served simulation (``connect=``), whose scenario is
fixed by whoever serves it, refuses them; the episode length (``max_steps``) is the environment's own.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Literal

from node_runtime.model.arrival import Constant
from node_runtime.model.spec import Scenario

MODES = ("binary", "batch")


@dataclass(frozen=True)
class ScenarioOverrides:
    """Each field left at None keeps the scenario's value (docs/env.md, "Scenario overrides")."""

    mode: Literal["binary", "batch"] | None = None  # binary: one task per agent per step; batch: up to batch_size
    decision_interval: int | None = None  # ticks per step; the episode keeps its number of steps
    batch_size: int | None = None  # task slots per step in batch mode
    arrival_rate: float | None = None  # a constant lambda (tasks/s per source) instead of the arrival schedule

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ValueError(f"ScenarioOverrides: mode must be 'binary' or 'batch', not {self.mode!r}")
        for name in ("decision_interval", "batch_size"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1):
                raise ValueError(f"ScenarioOverrides: {name} must be an integer >= 1, not {value!r}")
        rate = self.arrival_rate
        if rate is not None and (isinstance(rate, bool) or not isinstance(rate, numbers.Real) or not rate >= 0):
            raise ValueError(f"ScenarioOverrides: arrival_rate must be a number >= 0 (tasks/s per source), "
                             f"not {rate!r}")

    def apply(self, sc: Scenario) -> Scenario:
        changes: dict[str, object] = {} if self.mode is None else {"mode": self.mode}
        changes |= {k: int(v) for k, v in (("decision_interval", self.decision_interval),
                                           ("batch_size", self.batch_size)) if v is not None}
        if self.arrival_rate is not None:
            # a constant rate, drawn by the scenario's own arrival process (Poisson counts or exponential gaps)
            arrival = Constant(rate=float(self.arrival_rate), process=sc.workload.arrival.process)
            changes["workload"] = sc.workload.model_copy(update={"arrival": arrival, "client_rates": ()})
        return sc.replace(**changes) if changes else sc
