"""The batched steps of ``ZenohEdgeVectorEnv(backend="array")``: all K copies' flat observations, action masks,
rewards and info numbers at once, read from the array backend's arrays.

``ZenohEdgeEnv`` makes each agent's step in Python (an ``Observation`` per agent, its encoding, per-node info
dicts, ``Metrics``); over K copies of the array backend that is nearly all the time. ``BatchedSteps`` makes the
same numbers for every copy and agent with a few numpy calls per step: the rules of ``FlatObservation`` (the
fields of ``env.observations``, in their float32 columns), ``ObservationLayout.masks``, ``ActionRules`` (a
masked choice keeps its task local and counts as invalid), the rewards of ``env.reward`` named in ``REWARDS``
below (the paper's terms, or the step's node and network counter changes) and the catalogue's ``Out.ENV``
numbers. It is a second implementation of those rules, allowed only because ``tests/test_array_env.py``
compares it with K in-process environments tensor by tensor, exactly.

``uncovered`` says why a setting takes the per-copy path instead (each copy's ``ZenohEdgeEnv`` reading its
copy): another reward, ``invalid_action="raise"``, an info number of a form other than a total, rendering.
What the batched path leaves out: the environments' ``step_details`` (reward terms, credits per task) and
their ``summary()``, which need the per-copy ``Metrics`` it does not keep.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from env.environment import ZenohEdgeEnv
from env.observations import NeighbourField, OwnField, TaskField
from env.reward import (
    marginal_reward,
    paper_reward,
    score_reward,
    sparse_reward,
    team_reward,
    team_score_reward,
)
from node_runtime.model.array import FIELDS as ARRAY_FIELDS
from node_runtime.model.array import LedgerRows
from node_runtime.model.controller import always_fresh, heard_at
from orchestrator.array_session import ArrayBatch
from orchestrator.catalogue import METRIC, Agg, Form, Out, shown_as
from orchestrator.metrics import FIELDS as METRICS_FIELDS
from orchestrator.metrics import counters, share, total

# the rewards it computes: from the paper's terms of the decisions, or from the step's counter changes
# (of the agent's node, or of the network)
REWARDS = {paper_reward: "paper", sparse_reward: "node", score_reward: "node", marginal_reward: "node",
           team_reward: "network", team_score_reward: "network"}
DELTA_KEYS = ("completed", "dropped", "response_time_total", "delay_imposed")  # what those rewards read


def uncovered(env: ZenohEdgeEnv) -> str | None:
    """Why the batched path cannot make this environment's steps (one line), or None."""
    if env.reward_fn not in REWARDS:
        name = _name(env.reward_fn) if hasattr(env.reward_fn, "__name__") else repr(env.reward_fn)
        return (f"reward {name} (the batched path computes {', '.join(sorted(set(map(_name, REWARDS))))}; "
                "others take the per-copy path)")
    if env.action_rules.raise_invalid:
        return "invalid_action='raise' (the per-copy path raises InvalidActionError)"
    if env.render_mode is not None:
        return f"render_mode {env.render_mode!r}"
    for m, key, form in shown_as(Out.ENV, env.scenario.workload.jobs is not None):
        if m.agg is Agg.RATIO or form is not Form.TOTAL or not set(m.fields) <= set(ARRAY_FIELDS):
            return f"info number node_{key} ({m.agg.name.lower()}, {form.value})"
    return None


def seconds_left(busy: np.ndarray, t: int, dt: float) -> np.ndarray:
    """``node_runtime.model.view.backlog`` of every entry, in its float operations: the seconds of work left at the
    end of tick ``t`` on links busy, or CPUs draining, until the ticks ``busy``."""
    end = t + 1
    return np.where(busy > end, (busy - end) * dt, 0.0)


def _name(fn) -> str:
    return fn.__name__.removesuffix("_reward")


class BatchedSteps:
    """The steps of K copies of ``env``'s settings over ``batch`` (``env`` is one of the vector env's
    environments: its scenario, agents, layouts and reward settings are everyone's)."""

    def __init__(self, env: ZenohEdgeEnv, batch: ArrayBatch, info_keys: Sequence[str]) -> None:
        reason = uncovered(env)
        if reason is not None:
            raise ValueError(f"the batched array path does not cover {reason}")
        self.env, self.batch, self.sim = env, batch, batch.sim
        self.sim.listing = False  # nothing here reads the copies' ledgers as lists: ``ledgers`` keeps the arrays
        sc = env.scenario
        self.agents = list(env.possible_agents)
        self.nodes = np.array([env._row[a] for a in self.agents])
        self.reward_kind = REWARDS[env.reward_fn]
        self.settings = env.reward_settings
        self.info_keys = list(info_keys)
        self._layout(env)
        self._metrics_plan(env, batch)
        self.steps = 0
        self.invalid_count = np.zeros((batch.sim.k, len(self.agents)), dtype=np.int64)
        self.ledgers: list[LedgerRows] = []  # the ledgers of the last reset's or step's ticks, one per tick
        self.counters = np.zeros((batch.sim.k, 0, len(ARRAY_FIELDS)))  # every role's counters after the last tick
        self._ages_at: dict[int, np.ndarray] = {}
        self._fresh = np.array([always_fresh(sc, (sc.nodes[i].id, *sc.neighbours[sc.nodes[i].id]))
                                for i in self.nodes])
        self._sc = sc

    @classmethod
    def of(cls, env: ZenohEdgeEnv, k: int, info_keys: Sequence[str] = ()) -> BatchedSteps:
        """K copies of ``env``'s scenario and settings in a new array batch (``Unsupported`` or a ValueError
        says in one line what they do not cover)."""
        return cls(env, ArrayBatch(env.scenario, k, env.episode_ticks), info_keys)

    # ----- set-up: what does not change -----

    def _layout(self, env: ZenohEdgeEnv) -> None:
        """The flat vector's columns, the static features (filled once, as ``DictObservation`` does from its
        first view), the neighbour table and each agent's allowed targets."""
        sc, sim = env.scenario, self.sim
        first = env.builders[self.agents[0]]
        lay = first.layout
        self.slots, self.batch_size = lay.slots, lay.batch
        self.per_epoch = 1 if lay.batch is None else lay.batch
        self.n_actions = lay.n_actions
        s = first.slices
        self.own0, self.task0, self.nb0 = s["own"].start, s["task"].start, s["neighbours"].start
        n, d = len(self.agents), self.slots
        width = s["agent_id"].stop
        template = np.zeros((n, width), dtype=np.float32)
        self.neighbour = np.full((n, d), -1)  # node index of each agent's neighbour slot (-1: padding)
        self.allowed = np.zeros((n, self.n_actions), dtype=bool)  # the mask of a task slot
        self.allowed[:, 0] = True
        for a, node in enumerate(self.nodes):
            nd = sc.nodes[node]
            template[a, self.own0 + OwnField.BUFFER] = nd.buffer
            template[a, self.own0 + OwnField.CAPACITY_GCPS] = nd.capacity * 1e-9
            template[a, self.own0 + OwnField.TIER] = nd.tier
            for k, j in enumerate(sc.neighbours[nd.id]):
                other, col = sc.node[j], self.nb0 + k * len(NeighbourField)
                template[a, col + NeighbourField.PRESENT] = 1.0
                template[a, col + NeighbourField.BUFFER] = other.buffer
                template[a, col + NeighbourField.CAPACITY_GCPS] = other.capacity * 1e-9
                template[a, col + NeighbourField.TIER] = other.tier
                template[a, col + NeighbourField.RATE_MBPS] = sc.link[(nd.id, j)].rate_bps * 1e-6  # no moving node
                self.neighbour[a, k] = sc.index[j]
                self.allowed[a, 1 + k] = sim.valid[node, 1 + k]
            template[a, s["agent_id"].start + a] = 1.0
        self.template = template
        self.id0 = s["agent_id"].start  # before it, what an agent whose node is down sees as zeros
        self.real_a, self.real_s = np.nonzero(self.neighbour >= 0)
        self.real_j = self.neighbour[self.real_a, self.real_s]
        self.real_col = self.nb0 + self.real_s * len(NeighbourField)

    def _metrics_plan(self, env: ZenohEdgeEnv, batch: ArrayBatch) -> None:
        """Which counters the infos and the reward read, and how roles sum into nodes (``Metrics._record``: the
        node's roles in canonical order)."""
        metrics = batch.metrics[0]
        self.capacity = metrics.capacity
        self.penalty = env.penalty
        jobs = env.scenario.workload.jobs is not None
        self.env_metrics = [(m, f"node_{key}") for m, key, _ in shown_as(Out.ENV, jobs)
                            if m.agg is not Agg.SAMPLES and f"node_{key}" in self.info_keys]
        # each agent's node's roles (at most one of each kind, contiguous in canonical order): ``_tick`` adds them
        # in canonical order, as ``Metrics._record`` does; the array's counters are the metrics' first columns
        assert METRICS_FIELDS[:len(ARRAY_FIELDS)] == ARRAY_FIELDS
        owner = metrics.incidence.argmax(axis=0)
        roles = [np.flatnonzero(owner == node) for node in self.nodes]
        self.node_roles = [(np.array([a for a, r in enumerate(roles) if len(r) > p]),
                            np.array([r[p] for r in roles if len(r) > p])) for p in range(max(map(len, roles)))]
        self.network = self.reward_kind == "network"

    # ----- episodes -----

    def reset(self, seeds: Sequence[int]) -> tuple[np.ndarray, ...]:
        """Start an episode in every copy: (observations, masks, infos)."""
        env, sim = self.env, self.sim
        self.batch.begin(seeds, external=env._driven())
        self._sizes()
        k = sim.k
        self.steps = 0
        self.invalid_count[:] = 0
        self.last_nodes = np.zeros((k, len(self.nodes), len(ARRAY_FIELDS)))
        self.last_totals = np.zeros((k, len(ARRAY_FIELDS)))
        self.ledgers = []
        nodes, _, _ = self._tick()
        observation, mask = self._observe()
        invalid = np.zeros((k, len(self.agents)), dtype=bool)
        return observation, mask, self._infos(nodes, nodes - nodes, 1, invalid)

    def _sizes(self) -> None:
        """Every task's size as columns (instructions, input, output bytes, cycles per instruction, deadline)."""
        sim = self.sim
        self.size = np.zeros((sim.k, sim.m, 5))
        for c, sizes in enumerate(sim.sizes):
            if sizes:
                self.size[c, :len(sizes)] = sizes

    def step(self, actions: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, ...]:
        """One step of every copy from the agents' actions ((K, N) or (K, N, B)) and the masks they saw:
        (observations, masks, rewards, truncated, infos)."""
        sim, sc = self.sim, self._sc
        acts, invalid = self._resolve(actions, mask)
        rewards = self._paper(acts) if self.reward_kind == "paper" else None
        sim.act_all(self.nodes, acts)
        self.ledgers = []
        nodes, node_delta, network_delta = self._tick()
        for _ in range(sc.decision_interval - 1):
            nodes, more, more_network = self._tick()
            node_delta = node_delta + more
            network_delta = None if more_network is None else network_delta + more_network
        self.steps += 1
        self.invalid_count += invalid
        observation, new_mask = self._observe()
        if rewards is None:
            rewards = self._counted(node_delta, network_delta)
        infos = self._infos(nodes, node_delta, sc.decision_interval, invalid)
        return observation, new_mask, rewards, self.steps >= self.env.max_steps, infos

    def totals(self) -> dict[str, np.ndarray]:
        """Each copy's task counts so far, as the summary counts them: generated, completed, dropped, and the sum
        of the completions' response times (s)."""
        rows = self.counters.sum(axis=1)  # (K, FIELDS): every role's counters added up
        return {key: total(METRIC[key], rows) for key in ("generated", "completed", "dropped", "response_time_total")}

    # ----- one tick -----

    def _tick(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Run a tick of every copy: the agents' nodes' counters at its end, their change
        and (for a network's reward) the network's change over the tick (``Metrics._record``'s sums)."""
        counters = self.counters = self.sim.step()  # (K, roles, FIELDS)
        self.ledgers.append(self.sim.ledger_rows)
        (_, first), *others = self.node_roles
        nodes = counters[:, first]
        for agents, roles in others:
            nodes[:, agents] = nodes[:, agents] + counters[:, roles]
        node_delta = nodes - self.last_nodes
        self.last_nodes = nodes
        if not self.network:
            return nodes, node_delta, None
        totals = counters.sum(axis=1)
        network_delta = totals - self.last_totals
        self.last_totals = totals
        return nodes, node_delta, network_delta

    # ----- observations -----

    def _ages(self, t: int) -> np.ndarray:
        """Each agent's neighbour slots' information age at epoch ``t`` (``ArraySim.observation``'s)."""
        ages = self._ages_at.get(t)
        if ages is None:
            sc = self._sc
            stale = np.array([t - heard_at(sc, sc.nodes[j].id, t) for j in range(self.sim.n)])
            ages = np.where(self._fresh[self.real_a], 1, stale[self.real_j])
            self._ages_at = {t: ages}
        return ages

    def _observe(self) -> tuple[np.ndarray, np.ndarray]:
        """The flat observations (K, N, F) and masks (K, N, [B,] A) of the epoch the copies just observed."""
        sim, nodes = self.sim, self.nodes
        t, dt = sim.seen, sim.dt
        k = sim.k
        out = np.repeat(self.template[None], k, axis=0)
        own = self.own0
        own_queue, own_occupancy, own_drain = sim.seen_own  # its own node (co-located: as it is)
        out[:, :, own + OwnField.QUEUE] = own_queue[:, nodes]
        out[:, :, own + OwnField.OCCUPANCY] = own_occupancy[:, nodes]
        work = seconds_left(sim.seen_drain, t, dt)  # ``NodeView.work_s``
        out[:, :, own + OwnField.WORK_S] = seconds_left(own_drain, t, dt)[:, nodes]
        out[:, :, own + OwnField.UNDECIDED] = sim.seen_undecided[:, nodes]
        a, j, col = self.real_a, self.real_j, self.real_col
        out[:, a, col + NeighbourField.QUEUE] = sim.seen_heard[:, j]
        out[:, a, col + NeighbourField.OCCUPANCY] = sim.seen_occupancy[:, j]
        out[:, a, col + NeighbourField.WORK_S] = work[:, j]
        out[:, a, col + NeighbourField.AGE_TICKS] = self._ages(t)
        busy = sim.seen_busy[:, nodes[a], self.real_s]
        out[:, a, col + NeighbourField.BACKLOG_S] = seconds_left(busy, t, dt)
        slots = sim.slots[:, nodes, :self.per_epoch]  # (K, N, B) task indices, -1: none
        present = slots >= 0
        c, ag, b = np.nonzero(present)
        i = slots[c, ag, b]
        size = self.size[c, i]
        base = self.task0 + b * len(TaskField)
        out[c, ag, base + TaskField.PRESENT] = 1.0
        out[c, ag, base + TaskField.INSTRUCTIONS_G] = size[:, 0] * 1e-9
        out[c, ag, base + TaskField.INPUT_MB] = size[:, 1] * 1e-6
        out[c, ag, base + TaskField.OUTPUT_MB] = size[:, 2] * 1e-6
        out[c, ag, base + TaskField.CPI] = size[:, 3]
        out[c, ag, base + TaskField.TIME_LEFT_S] = size[:, 4] - (t - sim.created[c, i]) * dt
        out[c, ag, base + TaskField.WAITED_TICKS] = t - sim.arrived[c, i]
        down = sim.down[t, nodes]  # its controller observed nothing: the empty observation (``layout.empty``)
        if down.any():
            out[:, down, :self.id0] = 0.0
        mask = np.where(present[..., None], self.allowed[None, :, None, :], False)
        mask[..., 0] = True
        self.present, self.shown = present, slots  # shown: the task index in each slot (-1: none)
        return out, mask if self.batch_size is not None else mask[:, :, 0]

    # ----- actions and rewards -----

    def _resolve(self, actions: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``ActionRules.resolve`` for every copy: (actions (K, N, B), masked choices replaced by 0 where a task
        is; whether each agent broke its mask)."""
        if actions.min(initial=0) < 0 or actions.max(initial=0) >= self.n_actions:
            bad = actions[(actions < 0) | (actions >= self.n_actions)].flat[0]
            raise ValueError(f"action {bad} is outside the action space: expected 0 (local) to {self.n_actions - 1}")
        acts = actions.reshape(*actions.shape[:2], self.per_epoch).astype(np.int64)
        masks = mask.reshape(*mask.shape[:2], self.per_epoch, self.n_actions)
        allowed = np.take_along_axis(masks, acts[..., None], axis=-1)[..., 0]
        broken = self.present & (acts != 0) & ~allowed
        acts = np.where(broken, 0, acts)
        return acts, broken.any(axis=-1)

    def _paper(self, acts: np.ndarray) -> np.ndarray:
        """The paper reward (``paper_terms``, in its float operations) summed over each agent's placed tasks."""
        sim, w = self.sim, self.settings.weights
        rewards = np.zeros(acts.shape[:2])
        slots = sim.slots[:, self.nodes, :self.per_epoch]
        node = np.broadcast_to(self.nodes[None, :], acts.shape[:2])
        copy = np.broadcast_to(np.arange(sim.k)[:, None], acts.shape[:2])
        for b in range(self.per_epoch):
            placed = self.present[:, :, b]
            c, nd, a, i = copy[placed], node[placed], acts[:, :, b][placed], slots[:, :, b][placed]
            target = sim.target[nd, a]
            local = a == 0
            cycles = sim.cycles[c, i]
            capacity, own_capacity = sim.capacity[target], sim.capacity[nd]
            size = self.size[c, i]
            queue = np.where(local, sim.seen_own[0][c, nd], sim.seen_heard[c, target])  # the target's view
            t_wait = queue * cycles / capacity
            with np.errstate(divide="ignore"):
                t_comm = np.where(local, 0.0, 8.0 * (size[:, 1] + size[:, 2]) / sim.rate[sim.links[nd, a]])
            t_exc = cycles / capacity - cycles / own_capacity
            delay = w.wait * t_wait + w.comm * t_comm + w.exc * t_exc
            occupancy = np.where(local, sim.seen_own[1][c, nd], sim.seen_occupancy[c, target]) - local
            finish_per_tick = capacity * sim.dt / cycles
            buffer = sim.buffer[target].astype(float)
            q_next = np.minimum(np.maximum(0.0, occupancy - finish_per_tick) + 1.0, buffer)
            p = np.maximum(w.epsilon, (buffer - q_next) / buffer)
            overload = -np.log(p) / 3.0
            rewards[placed] = rewards[placed] + (w.utility - (delay + w.overload * overload))
        return rewards

    def _counted(self, node_delta: np.ndarray, network_delta: np.ndarray) -> np.ndarray:
        """The rewards of counter changes (``sparse``, ``score``, ``marginal``; ``team``, ``team_score``)."""
        fn = self.env.reward_fn
        rows = network_delta[:, None] if self.reward_kind == "network" else node_delta
        delta = {key: self._shown(METRIC[key], rows) for key in DELTA_KEYS}
        if fn is sparse_reward or fn is team_reward:
            reward = delta["completed"] - delta["dropped"]
        else:
            reward = delta["completed"] - delta["response_time_total"] / self.penalty  # timeliness
            if fn is marginal_reward:
                reward = reward - self.settings.congestion_price * delta["delay_imposed"]
        return np.broadcast_to(reward, node_delta.shape[:2])  # a network's reward: the same for every agent

    @staticmethod
    def _shown(m, rows: np.ndarray) -> np.ndarray:
        """A count or level as the outputs show it: its counters' total, whole for an integer metric."""
        values = total(m, rows)
        return values.astype(np.int64) if m.dtype is int else values

    # ----- infos -----

    def _infos(self, nodes: np.ndarray, node_delta: np.ndarray, ticks: int, invalid: np.ndarray) -> np.ndarray:
        """The info numbers (K, N, keys), in ``info_keys`` order: ``ZenohEdgeEnv._numbers`` of ``Out.ENV``."""
        k, n = nodes.shape[:2]
        values: dict[str, np.ndarray] = {"tick": np.full((k, n), self.sim.t - 1), "invalid_action": invalid,
                                         "invalid_action_count": self.invalid_count}
        for m, key in self.env_metrics:
            if m.agg is Agg.SHARE:
                values[key] = share(node_delta[..., counters(m)[0]], (self.capacity * ticks)[self.nodes])
            else:
                values[key] = self._shown(m, nodes)  # Out.ENV shows a count's total so far, as a level
        return np.stack([values[key] for key in self.info_keys], axis=-1).astype(np.float32) if self.info_keys \
            else np.zeros((k, n, 0), dtype=np.float32)
