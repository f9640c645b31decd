"""The settings of a ``ZenohEdgeEnv``, grouped by what they decide, each group checked once as it is made.

``ZenohEdgeEnv(...)`` keeps PettingZoo's keyword arguments for its users; it sorts them into these groups:
what an episode is (``EpisodeSettings``), what the agents see (``ObservationSettings``), how the simulation
is reached (``Connection``); the reward's numbers are ``env.reward.RewardSettings``. A wrong value is a
``ValueError`` (or ``TypeError``) naming the keyword argument, before any process starts.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral
from pathlib import Path
from typing import Any

from env.observations import DictObservation, ObservationBuilder
from env.overrides import ScenarioOverrides
from node_runtime.model.array import Unsupported, refusal
from node_runtime.model.rng import MAX_SEED
from node_runtime.model.spec import Scenario, episode_too_long
from node_runtime.runtime.layout import Layout, check_layout
from node_runtime.runtime.security import Security
from orchestrator.array_session import ArrayBatch, ArrayCopy
from orchestrator.scenario import load_scenario
from orchestrator.serve import describe
from orchestrator.session import Simulation, check_transport

FLAT = "flat"  # observation="flat": FlatObservation and numbers-only infos
BACKENDS = ("emulator", "array")  # the node code (over ``transport``), or the array backend (docs/array.md)


def check_seed(seed: Any, call: str) -> None:
    """None, or what a reset tick can carry as a msgpack integer: 0 to MAX_SEED."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, Integral) or not 0 <= seed <= MAX_SEED):
        raise ValueError(f"{call}(seed={seed!r}): expected an integer from 0 to {MAX_SEED} (2^62 - 1), or None")


@dataclass(frozen=True, kw_only=True)
class EpisodeSettings:
    """What an episode is: ``max_steps`` decision epochs after the reset tick (None: the scenario's), the
    controllers the agents drive (``agents``, node ids; None: all), and the first episode's ``seed``."""

    max_steps: int | None = None
    agents: tuple[str, ...] | None = None
    seed: int | None = None

    def __post_init__(self) -> None:
        m = self.max_steps
        if m is not None and (isinstance(m, bool) or not isinstance(m, Integral) or m < 1):
            raise ValueError(f"max_steps must be an integer >= 1, not {m!r}")
        check_seed(self.seed, "ZenohEdgeEnv")
        if self.agents is not None:
            object.__setattr__(self, "agents", tuple(self.agents))

    def steps(self, sc: Scenario) -> int:
        if self.max_steps and (why := episode_too_long(self.max_steps, sc.decision_interval)):
            raise ValueError(f"max_steps={self.max_steps}: {why}")
        return self.max_steps or sc.steps

    def nodes(self, sc: Scenario) -> list[str]:
        """The driven controllers' nodes, in the scenario's order."""
        nodes = list(self.agents) if self.agents is not None else list(sc.controllers)
        unknown = [n for n in nodes if n not in sc.controllers]
        if unknown:
            raise ValueError(f"not controllers of {sc.name}: {', '.join(unknown)} "
                             f"(controllers: {', '.join(sc.controllers)})")
        return sorted(nodes, key=sc.index.__getitem__)


@dataclass(frozen=True, kw_only=True)
class ObservationSettings:
    """What the agents see: ``observation`` (an ``ObservationBuilder`` subclass, its import path, ``FLAT``, or
    None for the scenario's or the Dict observation), ``uniform_spaces`` (every agent padded to the largest
    degree), ``neighbour_slots`` (every agent padded to this many slots, whatever the scenario: one shape
    across scenarios) and ``info_numbers`` (flat mode only: False leaves the infos empty). Checked in
    ``builder`` and ``slots``, against the scenario."""

    observation: type[ObservationBuilder] | str | None = None
    uniform_spaces: bool = False
    neighbour_slots: int | None = None
    info_numbers: bool = True

    def __post_init__(self) -> None:
        k = self.neighbour_slots
        if k is not None and (isinstance(k, bool) or not isinstance(k, Integral) or k < 1):
            raise ValueError(f"neighbour_slots must be an integer >= 1 (or None: the scenario's degrees), not {k!r}")

    def slots(self, sc: Scenario, largest: int) -> int | None:
        """The padded slot count: ``neighbour_slots`` when set (at least the ``largest`` degree of ``sc``'s
        agents), else None (each agent's own degree, or the largest with ``uniform_spaces`` or flat mode)."""
        k = self.neighbour_slots
        if k is not None and k < largest:
            raise ValueError(f"neighbour_slots={k} is below the largest degree of an agent of {sc.name} ({largest}): "
                             "a neighbour would have no slot")
        return k

    def builder(self, sc: Scenario) -> type[ObservationBuilder] | str:
        """The builder asked for, else the scenario's ``observation`` key, else the Dict observation (``FLAT``
        for flat mode); ``info_numbers`` is checked against it, since the scenario may be what asks for flat."""
        builder = self.observation or sc.extra.get("observation") or DictObservation
        if not self.info_numbers and builder != FLAT:
            raise ValueError('info_numbers=False applies to observation="flat" only (its infos are numbers)')
        return builder


@dataclass(frozen=True, kw_only=True)
class Connection:
    """How the environment reaches its simulation: with the ``emulator`` backend, one it starts on ``transport``
    ("zenoh" or "inproc") with ``layout`` (None: the transport's default), or, with ``connect`` and ``sim_id``, one
    served by ``orchestrator launch --serve``, reached with the ``driver`` identity in the directory ``security``
    (TLS and logins); with the ``array`` backend, the model's array program in this process (no transport, no
    process: ``transport`` is not used, ``layout`` and ``connect`` may not be given).
    ``timeout``: seconds the clock waits for a tick."""

    backend: str = "emulator"
    transport: str = "zenoh"
    layout: Layout | None = None
    timeout: float = 30.0
    connect: str | None = None
    sim_id: str | None = None
    security: Security | str | Path | None = None

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be 'emulator' (the node code, over transport=) or 'array' (docs/array.md), "
                             f"not {self.backend!r}")
        if self.backend == "array" and (self.connect is not None or self.layout is not None):
            raise ValueError("backend='array' runs in this process: connect= and layout= apply to the emulator backend")
        check_transport(self.transport)
        if self.layout is not None:
            object.__setattr__(self, "layout", check_layout(self.layout))
        if self.connect is not None and self.sim_id is None:
            raise ValueError("connect= needs sim_id= (both are printed by `orchestrator launch --serve`)")
        if self.connect is not None and isinstance(self.security, (str, Path)):
            object.__setattr__(self, "security", Security.from_dir(self.security))

    def scenario(self, scenario: str | Path | dict | Scenario, overrides: ScenarioOverrides | None) -> Scenario:
        """The served simulation's scenario when attached, else ``scenario`` loaded, with ``overrides``."""
        if overrides is not None and not isinstance(overrides, ScenarioOverrides):
            raise TypeError(f"overrides must be a ScenarioOverrides, not a {type(overrides).__name__}")
        if self.connect is not None:  # the served simulation fixes the scenario
            if overrides is not None:
                raise ValueError("overrides cannot change a served simulation; set them in its scenario file")
            return Scenario.from_dict(describe(self.connect, self.sim_id, timeout=self.timeout,
                                               security=self.security)["scenario"])
        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        return overrides.apply(sc) if overrides is not None else sc

    def check(self, sc: Scenario) -> None:
        """Refuse, in one line (``Unsupported``), a scenario that the array backend does not model."""
        if self.backend == "array" and (reason := refusal(sc)) is not None:
            raise Unsupported(reason)

    def open(self, sc: Scenario, ticks: int) -> Simulation | ArrayCopy:
        """Attach to the served simulation, or start ``sc`` on this transport, or (array backend) an array
        batch of one copy whose episodes last up to ``ticks`` ticks."""
        if self.backend == "array":
            return ArrayBatch(sc, 1, ticks).copies[0]
        if self.connect is not None:
            return Simulation.attach(self.connect, self.sim_id, timeout=self.timeout, security=self.security)
        return Simulation.open(sc, self.transport, layout=self.layout, timeout=self.timeout)
