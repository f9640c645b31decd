"""Clients whose arrival rate follows a daily cycle (docs/extending.md, example 2).

Named in a scenario as ``workload: {source: diurnal_source:DiurnalSource}``; per client node (or
profile) ``params``: rate_base (tasks/s), rate_amplitude (0..1), period_s, phase_s.
lambda(t) = base * (1 + amplitude * sin(2 pi (t + phase) / period)), drawn as Poisson(lambda dt) per tick.
"""

import math

from node_runtime import TaskSource


class DiurnalSource(TaskSource):
    def __init__(self, scenario, node, counts_rng, types_rng):
        spec = scenario.node[node]
        self.base = float(spec.param("rate_base", 0.17))
        self.amplitude = float(spec.param("rate_amplitude", 0.8))
        self.period = float(spec.param("period_s", 500.0))
        self.phase = float(spec.param("phase_s", 0.0))
        super().__init__(scenario, node, counts_rng, types_rng)

    def rate(self, tick):
        seconds = tick * self.dt + self.phase
        return self.base * (1.0 + self.amplitude * math.sin(2.0 * math.pi * seconds / self.period))
