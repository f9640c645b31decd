"""``ZenohEdgeEnv``: a PettingZoo ParallelEnv whose agents are the controllers of an emulated network.

    from env import ZenohEdgeEnv
    env = ZenohEdgeEnv()                      # aot1 over Zenoh, one process per role
    obs, infos = env.reset(seed=42)
    while env.agents:
        actions = {a: env.action_space(a).sample(obs[a]["action_mask"]) for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    env.close()

One ``step`` is one decision epoch (``decision_interval`` ticks of the emulation). The actions reach
the controllers with the first of those ticks (counted in the clock protocol like any message); the
observations come back with the controllers' reports at the end of the last one. Observations are
partial and one tick stale, by design (docs/model.md, "What neighbours know"). What happens to each
action is ruled in ``env.actions``; penalties and shaping are wrappers (``env.wrappers``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from env.actions import ActionRules, ResolvedActions
from env.credit import TaskCredit
from env.observations import FlatObservation, ObservationBuilder, ObservationLayout
from env.overrides import ScenarioOverrides
from env.reward import (
    PaperWeights,
    RewardContext,
    RewardFn,
    RewardSettings,
    RewardTerms,
    resolve_reward,
    terms_for,
)
from env.settings import FLAT, Connection, EpisodeSettings, ObservationSettings, check_seed
from node_runtime.model.plugins import load
from node_runtime.model.role import role_id
from node_runtime.model.spec import Scenario
from node_runtime.model.view import Observation
from node_runtime.model.workload import nominal_arrivals
from node_runtime.runtime.layout import Layout
from orchestrator.array_session import ArrayCopy
from orchestrator.catalogue import Out
from orchestrator.metrics import TickReport, output_values, penalty_s
from orchestrator.session import Simulation

AGENT_PREFIX = "ctrl_"


@dataclass(frozen=True, slots=True)
class Placed:
    """A step's actions, before the simulation runs it: checked, as the controllers' actions by role, and the
    reward terms and credits of the decisions, by agent."""

    resolved: ResolvedActions
    controller_actions: dict[str, Any]
    terms: dict[str, tuple[RewardTerms, ...]]
    credits: dict[str, list[tuple[int, float]]]


def agent_name(node: str) -> str:
    return f"{AGENT_PREFIX}{node}"


class ZenohEdgeEnv(ParallelEnv):
    """Multi-agent task offloading over a Zenoh-emulated edge network.

    Args (sorted into the settings of ``env.settings`` and ``env.reward.RewardSettings``, each checked there):
        scenario: a bundled name ("aot1" … "aot4"), a YAML path, a dict in the scenario format, or a
            ``Scenario``.
        seed: seed of the first episode (later resets without a seed draw from a stream it seeds).
        backend: "emulator" (default: the node code, over ``transport``) or "array" (the model's array program
            in this process, docs/array.md: the same observations, rewards and infos step for step, much faster,
            for the scenarios it covers; any other is refused in one line, ``Unsupported``). docs/env.md, "Backends".
        transport: with the emulator backend, "zenoh" (node processes over a Zenoh router) or "inproc" (same
            code, one process).
        layout: "per-role", "per-node", "single" (default for inproc) or "groups:K"; the default for zenoh is
            per-role while its processes fit this machine, else groups:K (docs/protocol.md#the-default-layout).
        reward: "paper" (Eq. 1–5, see docs/reward.md), "reference", "sparse", "team", "score", "team_score", "marginal",
            a callable ``f(RewardContext)`` or its import path (default: the scenario's ``reward`` key, else
            "paper").
        observation: an ``ObservationBuilder`` subclass or its import path (default: the scenario's
            ``observation`` key, else the documented Dict observation), or "flat": one float32 vector and
            the action mask per agent, padded to the largest degree, with numbers-only infos (for MARL
            libraries; the full infos stay in ``env.step_details``).
        info_numbers: in flat mode, False leaves every agent's infos empty: libraries that turn each info
            number into a tensor every step (TorchRL's PettingZooWrapper) run faster without them, and
            ``env.step_details`` still has them all.
        reward_weights: ``PaperWeights`` overriding the paper's r_u and chi weights.
        overrides: ``ScenarioOverrides`` of the decision mode, decision interval, batch size and arrival rate.
        max_steps: episode length in steps (default: the scenario's ``simulation.steps``, 1000); an episode
            is the reset tick plus ``max_steps`` decision epochs.
        agents: controllers the agents drive (node ids); the others keep their node-side policy.
        uniform_spaces: pad every agent to the largest degree, so one network fits all agents.
        neighbour_slots: pad every agent to this many neighbour slots (at least the largest degree), so that
            one network fits the agents of every scenario of up to that degree (a generalist across
            topologies); padding slots are absent (present = 0) and their actions masked.
        invalid_action: what a choice the mask forbids does: "local" (default: the task stays local, and
            ``infos[agent]["invalid_action"]`` says so) or "raise" (``InvalidActionError``, for debugging).
            Penalise it with ``env.wrappers.InvalidActionPenalty``.
        render_mode: None, "ansi", "rgb_array" or "human".
        connect: attach to a simulation served by ``orchestrator launch --serve`` instead of starting one:
            the endpoint it printed, e.g. "tcp/10.0.0.5:7447".
        sim_id: with ``connect``, the id of the simulation to attach to.
        security: with ``connect`` to a router that requires TLS and logins (``launch --security``), the
            directory of the ``driver`` identity written by deploy/make-certs.sh (deploy/README.md).
        congestion_price: the price c that the ``marginal`` reward and the credits per task charge for a
            deadline's worth of waiting imposed on another task (default ``CONGESTION_PRICE``, 2; docs/reward.md).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "zenohedge_v0", "render_modes": ["ansi", "rgb_array", "human"], "render_fps": 4,
        "is_parallelizable": True,
    }

    def __init__(self, scenario: str | Path | dict | Scenario = "aot1", *, seed: int | None = None,
                 backend: str = "emulator", transport: str = "zenoh", layout: Layout | None = None,
                 reward: str | RewardFn | None = None,
                 observation: type[ObservationBuilder] | str | None = None,
                 reward_weights: PaperWeights | None = None, overrides: ScenarioOverrides | None = None,
                 max_steps: int | None = None, agents: Sequence[str] | None = None, uniform_spaces: bool = False,
                 neighbour_slots: int | None = None, invalid_action: str = "local", render_mode: str | None = None,
                 info_numbers: bool = True,
                 connect: str | None = None, sim_id: str | None = None, timeout: float = 30.0,
                 security: str | Path | None = None, congestion_price: float | None = None) -> None:
        self.connection = Connection(backend=backend, transport=transport, layout=layout, timeout=timeout,
                                     connect=connect, sim_id=sim_id, security=security)
        self.episode = EpisodeSettings(max_steps=max_steps, agents=agents, seed=seed)
        self.observing = ObservationSettings(observation=observation, uniform_spaces=uniform_spaces,
                                             neighbour_slots=neighbour_slots, info_numbers=info_numbers)
        self.reward_settings = RewardSettings(**_given(weights=reward_weights, congestion_price=congestion_price))
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.render_mode = render_mode
        self.scenario = self.connection.scenario(scenario, overrides)
        self.connection.check(self.scenario)
        self.max_steps = self.episode.steps(self.scenario)
        self.episode_ticks = 1 + self.max_steps * self.scenario.decision_interval  # the reset tick, then the steps'
        self._set_reward(reward)
        self._set_agents()
        self._set_spaces(invalid_action)
        self._set_episode_state()

    def _set_reward(self, reward: str | RewardFn | None) -> None:
        """The reward function (the argument, else the scenario's ``reward`` key, else "paper"), what it needs
        of the scenario, and the credits per task (infos[agent]["credits"])."""
        sc = self.scenario
        self.reward_fn = resolve_reward(reward or sc.extra.get("reward") or "paper")
        self.terms_fn = terms_for(self.reward_fn)  # what infos["reward_terms"] shows
        self.arrivals = nominal_arrivals(sc)
        self.penalty = penalty_s(sc)  # what the headline score charges a task that does not complete
        self.credit = TaskCredit(self.penalty, self.reward_settings)

    def _set_agents(self) -> None:
        """One agent per driven controller, named ``ctrl_<node>``, in the scenario's order."""
        sc = self.scenario
        self.node_of = {agent_name(n): n for n in self.episode.nodes(sc)}
        self.possible_agents = list(self.node_of)
        self._role = {a: role_id("controller", n) for a, n in self.node_of.items()}
        self._row = {a: sc.index[n] for a, n in self.node_of.items()}
        self.agents: list[str] = []

    def _set_spaces(self, invalid_action: str) -> None:
        """Every agent's observation layout, builder and spaces, and the rules its actions follow."""
        sc = self.scenario
        degrees = {a: len(sc.neighbours[n]) for a, n in self.node_of.items()}
        largest = max(degrees.values(), default=0)
        fixed = self.observing.slots(sc, largest)
        slots = largest if fixed is None else fixed
        batch = None if sc.mode == "binary" else sc.batch_size
        builder = self.observing.builder(sc)
        self.flat = builder == FLAT
        padded = self.observing.uniform_spaces or self.flat or fixed is not None
        jobs = sc.workload.jobs is not None  # a scenario of jobs: its tasks' DAG features too
        self.layouts = {a: ObservationLayout(d, slots if padded else d, batch, jobs, sc.dt) for a, d in degrees.items()}
        if self.flat:
            n = len(self.possible_agents)
            self.builders = {a: FlatObservation(lay, i, n) for i, (a, lay) in enumerate(self.layouts.items())}
        else:
            if isinstance(builder, str):
                builder = load(builder, ObservationBuilder)
            self.builders = {a: builder(lay) for a, lay in self.layouts.items()}
        self.observation_spaces = {a: b.space() for a, b in self.builders.items()}
        self.action_spaces = {a: lay.action_space() for a, lay in self.layouts.items()}
        targets = {a: ("local", *sc.neighbours[n]) for a, n in self.node_of.items()}
        self.action_rules = ActionRules(self.layouts, targets, invalid_action)

    def _set_episode_state(self) -> None:
        """No simulation until the first reset; the seeds of the episodes to come."""
        self.sim: Simulation | ArrayCopy | None = None
        self._seeds = np.random.default_rng(self.episode.seed)
        self._next_seed = self.episode.seed
        self._raw: dict[str, Observation | None] = {}
        self._obs: dict[str, dict[str, np.ndarray]] = {}
        self._steps = 0
        self._invalid = dict.fromkeys(self.possible_agents, 0)  # this episode's invalid actions, per agent
        self._last_actions: dict[str, Any] = {}  # the last step's decisions, for the renderer
        self._renderer = None
        self._closed = False
        self.step_details: dict[str, dict[str, Any]] = {}  # the last reset's or step's full infos, per agent

    # ----- PettingZoo API -----

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start an episode; the node processes stay up. ``options``: {"policy": name} for the
        controllers the agents do not drive."""
        episode_seed = self._episode_seed(seed)
        if self.sim is None:
            self.sim = self._open()
            self._closed = False
        report = self.sim.reset(episode_seed, external=self._driven(), policy=(options or {}).get("policy"))
        return self._started(report)

    def _episode_seed(self, seed: int | None) -> int:
        """The seed of the episode a reset starts: ``seed``, else the first one, else one drawn from the stream."""
        check_seed(seed, "reset")
        if seed is not None:
            self._seeds = np.random.default_rng(seed)
            episode_seed = int(seed)
        elif self._next_seed is not None:
            episode_seed = int(self._next_seed)
        else:
            episode_seed = int(self._seeds.integers(2**31))
        self._next_seed = None
        return episode_seed

    def _driven(self) -> list[str]:
        """The controller roles the agents drive."""
        return [role_id("controller", n) for n in self.node_of.values()]

    def _started(self, report: TickReport):
        """The reset's observations and infos, from the report of the episode's tick 0."""
        self.agents = list(self.possible_agents)
        self._steps = 0
        self._invalid = dict.fromkeys(self.possible_agents, 0)
        self._last_actions = {}
        self.credit.reset()
        self.sim.open_next()
        self._observe()
        nodes = _by_node(output_values(Out.ENV, report.nodes, report.node_delta, self.sim.metrics.capacity,
                                            jobs=self.sim.metrics.jobs))
        infos = {a: self._info(a, nodes, ()) for a in self.agents}
        self.step_details = infos
        return dict(self._obs), self._numbers(infos) if self.flat else infos

    def step(self, actions: dict[str, Any]):
        """``actions``: one per live agent; docs/env.md "Actions" says what each may be and what it does."""
        placed = self._place(actions)
        reports = [self.sim.step(placed.controller_actions)]
        for _ in range(self.scenario.decision_interval - 1):
            reports.append(self.sim.step())
        return self._stepped(placed, reports)

    def _place(self, actions: dict[str, Any]) -> Placed:
        """The step's actions checked, what the controllers carry out, and the reward terms and credits of
        the decisions: all that is known before the simulation runs the step."""
        if not self.agents:
            self._not_running()
        resolved = self.action_rules.resolve(actions, self.agents, self._raw)
        dt, weights = self.scenario.dt, self.reward_settings.weights
        controller_actions: dict[str, Any] = {}
        terms: dict[str, tuple[RewardTerms, ...]] = {}
        credits: dict[str, list[tuple[int, float]]] = {}
        for agent, action in resolved.decisions.items():
            raw = self._raw[agent]
            controller_actions[self._role[agent]] = action
            if isinstance(action, int):
                terms[agent] = (self.terms_fn(raw, raw.tasks[0], action, dt, weights, self.arrivals),)
                placed = (raw.tasks[0].id,)
            else:
                terms[agent] = tuple(self.terms_fn(raw, t, a, dt, weights, self.arrivals)
                                     for t, a in zip(raw.tasks, action, strict=True))
                placed = tuple(t.id for t in raw.tasks)
            credits.update(self.credit.place(agent, self._steps, placed))
        for agent in resolved.invalid:
            self._invalid[agent] += 1
        self._last_actions = resolved.decisions
        return Placed(resolved, controller_actions, terms, credits)

    def _stepped(self, placed: Placed, reports: list[TickReport]):
        """The step's observations, rewards, terminations, truncations and infos, from the reports of its ticks."""
        resolved, terms, credits = placed.resolved, placed.terms, placed.credits
        dt = self.scenario.dt
        self._steps += 1
        truncated = self._steps >= self.max_steps
        if not truncated:
            self.sim.open_next()
        before = dict(self._raw)
        self._observe()
        for report in reports:
            _extend(credits, self.credit.settle(report.ledger))

        node_delta = reports[0].node_delta if len(reports) == 1 else sum(r.node_delta for r in reports)
        capacity = self.sim.metrics.capacity * len(reports)  # the step's cycles, for a share
        jobs = self.sim.metrics.jobs
        deltas = _by_node(output_values(Out.ENV_DELTA, reports[-1].nodes, node_delta, capacity, jobs=jobs))
        network_delta = output_values(Out.ENV_DELTA, reports[-1].totals, sum(r.delta for r in reports), capacity.sum(),
                                      jobs=jobs)
        nodes = _by_node(output_values(Out.ENV, reports[-1].nodes, node_delta, capacity, jobs=jobs))
        rewards, infos = {}, {}
        for agent in self.agents:
            row = self._row[agent]
            delta = deltas[row]
            agent_terms = terms.get(agent, ())
            ctx = RewardContext(agent=agent, node=self.node_of[agent], obs=before[agent],
                                action=resolved.actions[agent], next_obs=self._raw[agent], terms=agent_terms,
                                node_delta=delta, network_delta=network_delta, dt=dt, arrivals=self.arrivals,
                                penalty=self.penalty, settings=self.reward_settings)
            rewards[agent] = float(self.reward_fn(ctx))
            infos[agent] = {**self._info(agent, nodes, agent_terms, credits.get(agent, [])),
                            "invalid_action": agent in resolved.invalid, "invalid_action_count": self._invalid[agent]}
        terminations = dict.fromkeys(self.agents, False)
        truncations = dict.fromkeys(self.agents, truncated)
        observations = dict(self._obs)
        if truncated:  # the episode's metrics, as in env.summary(), without the wall-clock "run" block
            episode = {k: v for k, v in self.summary().items() if k != "run"}
            for agent in self.agents:
                infos[agent]["episode"] = episode
            self.agents = []
        if self.render_mode == "human":
            self.render()
        self.step_details = infos
        return observations, rewards, terminations, truncations, self._numbers(infos) if self.flat else infos

    def render(self):
        if self.render_mode is None:
            return None
        from env.render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(self)
        return self._renderer.render(self.render_mode)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self.sim is not None:
            self.sim.close()
            self.sim = None
        self.agents = []
        self._closed = True

    # ----- results -----

    def summary(self) -> dict[str, Any]:
        """The episode's metrics so far, as in ``summary.json`` of ``orchestrator launch``, plus the agents'
        invalid actions (``invalid_actions``: total and per agent)."""
        if self.sim is None:
            raise RuntimeError("no episode has run yet" if not self._closed else "the environment is closed")
        invalid = {"total": sum(self._invalid.values()), "by_agent": dict(self._invalid)}
        return {**self.sim.summary(), "invalid_actions": invalid}

    # ----- internals -----

    def _not_running(self) -> None:
        """Why there is no episode to step: never reset, closed, or over."""
        if self._closed:
            raise RuntimeError("step() after close(): call reset() to start the environment again")
        if self.sim is None:
            raise RuntimeError("step() before reset(): call reset() to start an episode")
        raise RuntimeError(f"step() after the episode ended (every agent truncated at step {self._steps}): "
                           "call reset() to start a new one")

    def _open(self) -> Simulation | ArrayCopy:
        sim = self.connection.open(self.scenario, self.episode_ticks)
        sim.metrics.history = False  # infos need the running totals only: memory stays flat over long episodes
        return sim

    def _observe(self) -> None:
        by_role = self.sim.observations()
        for agent, role in self._role.items():
            raw = by_role.get(role)
            self._raw[agent] = raw
            self._obs[agent] = self.builders[agent].encode(raw)

    def _info(self, agent: str, nodes: list[dict[str, Any]], terms: tuple[RewardTerms, ...],
              credits: list[tuple[int, float]] | None = None) -> dict[str, Any]:
        return {"tick": self.sim.tick, "node": nodes[self._row[agent]], "reward_terms": [t.as_dict() for t in terms],
                "credits": credits or []}

    def _numbers(self, infos: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
        """Flat mode's infos: the same keys at every reset and step, each a number (libraries stack them);
        none at all with ``info_numbers=False``."""
        if not self.observing.info_numbers:
            return {agent: {} for agent in infos}
        out = {}
        for agent, info in infos.items():
            numbers = {"tick": info["tick"], "invalid_action": info.get("invalid_action", False),
                       "invalid_action_count": info.get("invalid_action_count", 0)}
            out[agent] = numbers | {f"node_{k}": v for k, v in _flat_items(info["node"])}
        return out


def _extend(credits: dict[str, list[tuple[int, float]]], more: dict[str, list[tuple[int, float]]]) -> None:
    for agent, pairs in more.items():
        credits.setdefault(agent, []).extend(pairs)


def _flat_items(values: dict[str, Any], prefix: str = ""):
    """(key, number) pairs of a nested dict of numbers, nested keys joined by "_"."""
    for key, value in values.items():
        if isinstance(value, dict):
            yield from _flat_items(value, f"{prefix}{key}_")
        else:
            yield f"{prefix}{key}", value


def _by_node(values: dict[str, Any]) -> list[dict[str, Any]]:
    """One dict per node from the catalogue's per-node lists (Out.ENV: the counters in
    infos[agent]["node"]; Out.ENV_DELTA: their change during the step, the reward's ``node_delta``)."""
    columns = [_by_node(v) if isinstance(v, dict) else v for v in values.values()]
    return [dict(zip(values, row, strict=True)) for row in zip(*columns, strict=True)]


def _given(**values: Any) -> dict[str, Any]:
    """The keyword arguments a user gave (not None): the settings' own defaults stand for the others."""
    return {k: v for k, v in values.items() if v is not None}
