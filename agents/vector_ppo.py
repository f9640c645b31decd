"""PPO over K copies of a scenario stepped together on the array backend: the project's PPO, fed in arrays.

    learner = PPO(specs, PPOConfig(shared=True, agent_id=False, credit="task", gamma=0.0))
    regimes = [Regime(learner, env, 16) for env in envs]  # envs: ZenohEdgeEnv(observation="flat", backend="array")
    rows = VectorPPO(learner).episode(regimes, seeds)     # one episode of every copy, learning as it goes

The serial loop (``agents.training.train``) steps one environment and asks the learner for one agent at a
time; on 2 cores it makes about 200 training steps a second. Here ``env.batched.BatchedSteps`` gives every
copy's flat observations and masks at once, one forward pass acts for every deciding agent of every copy, and
each decision is a row of arrays. What is learnt is the serial learner's, rule for rule:

- the semi-MDP over each agent's own decisions (``agents.learner``): a transition opens at a decision and
  closes at the agent's next one, or at the end of the episode (bootstrapping from the final state when it
  holds a task);
- the rewards: the step's reward (``credit="step"``) or each decision's tasks' credit (``credit="task"``,
  ``env.credit.ArrayCredit``, the same numbers as ``TaskCredit``), scaled and normalised by the running std of
  each agent's discounted return (``ReturnScale``'s statistics, each (copy, agent) an agent);
- a decision is learnt from once its credit has come, an agent's later ones wait behind it (``credited``),
  and the credit of a decision whose tasks outlive the episode never comes: it is not learnt from;
- GAE over each agent's decisions (``agents.onpolicy.advantages``) and the update itself
  (``PPO.update_group``), with the learning rate annealed over the horizon in environment steps.

So a checkpoint is an ordinary PPO checkpoint: it acts and is evaluated on any backend. What differs is the
sample stream: the episodes of all copies run at once, so an update mixes the regimes stepped together; by default
it comes after as many copy-steps as a serial update (``rollout_steps``), so the updates per frame are the serial
loop's. Several regimes stepped together keep the diversity of the serial loop, which draws a regime per episode:
K copies of one regime train on that regime alone for K episodes' worth of updates.
Binary mode only (one task per decision); no centralised critic and no teacher (they read Dict observations).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from rich.progress import Progress

from agents.common import MaskedCategorical, flatten, one_hot
from agents.learner import SHARED
from agents.onpolicy import advantages
from agents.ppo import PPO
from agents.training import CsvWriter
from env import ArrayCredit, BatchedSteps, NeighbourField, TaskField, ZenohEdgeEnv

CHUNK = 1024  # decision rows added at a time when the table grows


def unsupported(learner: PPO, env: ZenohEdgeEnv) -> str | None:
    """Why ``VectorPPO`` cannot train ``learner`` on ``env`` (one line), or None."""
    c = learner.config
    if not c.shared:
        return "independent networks (shared=false): the vectorised loop trains one shared network"
    if c.centralised_critic:
        return "centralised_critic=true (the critic reads every agent's Dict observation)"
    if c.teacher:
        return f"teacher {c.teacher!r} (the baselines read Dict observations)"
    if not env.flat or env.scenario.mode != "binary":
        return "an environment other than observation='flat' in binary mode"
    if c.agent_id and list(learner.agents) != list(env.possible_agents):
        return "agent ids of another scenario's agents (agent_id=true)"
    return None


@dataclass
class Decisions:
    """Every decision not yet learnt from, one row each: what the update needs, what closing fills in, and the
    credit once it has come. Rows stay in the order the decisions were taken (time order)."""

    features: np.ndarray
    mask: np.ndarray
    rows: int = 0
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    SPEC: ClassVar[dict[str, type]] = {
        "group": np.int64, "copy": np.int64, "chain": np.int64, "step": np.int64, "task": np.int64, "action": np.int64,
        "logp": np.float32, "value": np.float32, "reward": np.float64, "discount": np.float64,
        "next_value": np.float64, "last": bool, "closed": bool, "credit": np.float64}

    @classmethod
    def empty(cls, width: int, actions: int) -> Decisions:
        return cls(np.zeros((0, width), np.float32), np.zeros((0, actions), bool), 0,
                   {k: np.zeros(0, dtype) for k, dtype in cls.SPEC.items()})

    def add(self, features: np.ndarray, mask: np.ndarray, **values: np.ndarray) -> np.ndarray:
        """Append decisions; returns their row numbers."""
        n = len(features)
        if self.rows + n > len(self.features):
            size = max(2 * len(self.features), self.rows + n + CHUNK)  # doubling: few copies
            self.features = _grown(self.features, size)
            self.mask = _grown(self.mask, size)
            self.columns = {k: _grown(v, size) for k, v in self.columns.items()}
        rows = np.arange(self.rows, self.rows + n)
        self.features[rows], self.mask[rows] = features, mask
        for k, dtype in self.SPEC.items():
            self.columns[k][rows] = values.get(k, np.zeros(n, dtype) if k != "credit" else np.full(n, np.nan))
        self.rows += n
        return rows

    def __getitem__(self, key: str) -> np.ndarray:
        return self.columns[key][:self.rows]

    def keep(self, rows: np.ndarray) -> None:
        """Keep only ``rows`` (in order)."""
        self.features = self.features[rows]
        self.mask = self.mask[rows]
        self.columns = {k: v[rows] for k, v in self.columns.items()}
        self.rows = len(rows)


def _grown(a: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((size, *a.shape[1:]), dtype=a.dtype)
    out[:len(a)] = a
    return out


class Regime:
    """One scenario's K copies in the loop: its batched steps, its per-task credit, and where the learner's
    features lie in its flat observations."""

    def __init__(self, learner: PPO, env: ZenohEdgeEnv, k: int) -> None:
        reason = unsupported(learner, env)
        if reason is not None:
            raise ValueError(f"the vectorised PPO loop does not train {reason}")
        self.env, self.k = env, k
        self.steps = BatchedSteps.of(env, k)
        self.n = len(self.steps.agents)
        s = env.builders[self.steps.agents[0]].slices
        self.own, self.neighbours = s["own"], s["neighbours"]
        self.task = slice(s["task"].start, s["task"].start + len(TaskField))
        self.credit = ArrayCredit(env.penalty, env.reward_settings) if learner.config.credit == "task" else None
        self.ids = (np.stack([one_hot(learner.index[a], len(learner.agents)) for a in self.steps.agents])
                    if learner.config.agent_id else None)
        self.width = learner.input_dim(SHARED)
        self.rewards = np.zeros((k, self.n))  # of its last step

    def features(self, observation: np.ndarray, agents: np.ndarray) -> np.ndarray:
        """The learner's features (``Learner.features``) of flat observations (rows) of ``agents``."""
        if not len(observation):
            return np.zeros((0, self.width), np.float32)
        nb = observation[:, self.neighbours].reshape(len(observation), self.steps.slots, len(NeighbourField))
        x = flatten(observation[:, self.own], observation[:, self.task], nb)
        return x if self.ids is None else np.concatenate([x, self.ids[agents]], axis=1)

    def close(self) -> None:
        self.env.close()


def _length(regimes: Sequence[Regime]) -> int:
    """The episode length of regimes stepped together, which must share it and their action space."""
    lengths = {r.env.max_steps for r in regimes}
    if len(lengths) > 1 or len({r.steps.n_actions for r in regimes}) > 1:
        raise ValueError("regimes stepped together need one episode length and one action space")
    return lengths.pop()


class VectorPPO:
    """Trains a shared-network ``PPO`` on the copies of one or more regimes stepped together (module docstring).
    ``rollout_steps``: steps of every copy between updates (default: as many copy-steps per update as the
    serial loop's ``rollout_steps``)."""

    def __init__(self, learner: PPO, rollout_steps: int | None = None) -> None:
        self.learner, self.rollout_steps = learner, rollout_steps
        self.table = Decisions.empty(learner.input_dim(SHARED), learner.n_actions(SHARED))
        self.learnt = 0  # decisions learnt from so far (the others: learner.uncredited)
        self.open_row = np.zeros(0, dtype=np.int64)

    # ----- acting -----

    def _act(self, x: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sampled actions, their log-probabilities and the critic's values, for the rows of ``x``."""
        learner = self.learner
        net = learner.nets[SHARED]
        with torch.no_grad():
            xt = torch.as_tensor(x, device=learner.device)
            dist = MaskedCategorical(net.actor(xt), torch.as_tensor(mask, device=learner.device))
            actions = dist.sample(learner.generator)
            return actions.cpu().numpy(), dist.log_prob(actions).cpu().numpy(), net.value(xt).cpu().numpy()

    def _values(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.learner.nets[SHARED].value(torch.as_tensor(x, device=self.learner.device)).cpu().numpy()

    # ----- one episode of every copy -----

    def episode(self, regimes: Sequence[Regime], seeds: Sequence[Sequence[int]],
                learn: bool = True) -> list[list[dict[str, float]]]:
        """Run one episode in every copy of every regime (copy c of regime g seeded ``seeds[g][c]``), all stepped
        together, learning from them; per regime, one row per copy: the return (summed over agents), the task
        counts and ratios of the episode, the wall time and the learner's diagnostics after it."""
        start = time.perf_counter()
        learner, table = self.learner, self.table
        length = _length(regimes)
        copies = sum(r.k for r in regimes)
        rollout = self.rollout_steps or max(1, learner.config.rollout_steps // copies)
        learner.rng = np.random.default_rng(seeds[0][0])  # as Learner.reset reseeds its sampling per episode
        learner.generator.manual_seed(int(seeds[0][0]))
        base = np.cumsum([0] + [r.k * r.n for r in regimes])  # chain (copy, agent) numbers of each regime
        self.open_row = np.full(base[-1], -1)  # each chain's open decision (its row), -1: none
        running = np.zeros(base[-1])  # each chain's discounted return so far (ReturnScale's)
        returns = [np.zeros(r.k) for r in regimes]
        observations, masks = [], []
        for r, s in zip(regimes, seeds, strict=True):
            observation, mask, _ = r.steps.reset(s)
            observations.append(observation)
            masks.append(mask)
            if r.credit is not None:
                r.credit.reset(r.k, r.steps.sim.m)
        decisions = 0
        x, deciders = self._deciders(regimes, observations, base)
        for step in range(length):
            # act for every agent with a task, and open its decision
            act, logp, value = self._act(x, np.concatenate([m[dc, da] for m, (dc, da, _) in zip(masks, deciders,
                                                                                                 strict=True)]))
            fresh, at = [], 0
            for g, (r, (dc, da, chain)) in enumerate(zip(regimes, deciders, strict=True)):
                part = slice(at, at + len(dc))
                at = part.stop
                task = r.steps.shown[dc, da, 0]
                rows = table.add(x[part], masks[g][dc, da], group=np.full(len(dc), g), copy=dc, chain=chain,
                                 step=np.full(len(dc), step), task=task, action=act[part], logp=logp[part],
                                 value=value[part], discount=np.ones(len(dc)))
                self.open_row[chain] = rows
                actions = np.zeros((r.k, r.n), dtype=np.int64)
                actions[dc, da] = act[part]
                if r.credit is not None:
                    settled = r.credit.place(dc, task)
                    table["credit"][rows[settled]] = 0.0  # normalised below with the step's other credits
                fresh.append(rows)
                observations[g], masks[g], rewards, truncated, _ = r.steps.step(actions, masks[g])
                returns[g] += rewards.sum(axis=1)
                r.rewards = rewards
            decisions += at
            # the step's rewards or credits reach the open decisions
            self._rewards(regimes, running, truncated, np.concatenate(fresh))
            # close what the step ends: at the agent's next decision, or everything at the episode's end
            x, deciders = self._deciders(regimes, observations, base)
            chain = np.concatenate([c for _, _, c in deciders])
            closing = self.open_row[chain] >= 0
            self._close(self.open_row[chain[closing]], self._values(x)[closing], last=truncated)
            self.open_row[chain[closing]] = -1
            if truncated:
                self._close(self.open_row[self.open_row >= 0], None, last=True)
                self.open_row[:] = -1
            learner.env_steps += copies
            if learn and ((step + 1) % rollout == 0 or truncated):
                self._update(len(running), rollout * copies, episode_over=truncated)
            if truncated:
                break
        wall, stats = time.perf_counter() - start, learner.stats()
        return [self._rows(r, s, ret, np.full(r.k, decisions / copies), wall / copies, stats)
                for r, s, ret in zip(regimes, seeds, returns, strict=True)]

    def play(self, regimes: Sequence[Regime], seeds: Sequence[Sequence[int]], greedy: bool = True
             ) -> list[list[dict[str, float]]]:
        """One episode of every copy of every regime with the learnt policy and no learning (``episode``'s rows):
        its most likely action (``greedy``, the serial ``sample_eval=false``: the same episodes, action for
        action) or a sample at ``eval_temperature`` (the serial policy's distribution, but another random stream:
        the draws of all copies come from one generator). The learner's state is left as it was, its sampling
        streams aside."""
        start = time.perf_counter()
        learner = self.learner
        length = _length(regimes)
        learner.generator.manual_seed(int(seeds[0][0]))
        base = np.cumsum([0] + [r.k * r.n for r in regimes])
        returns, decided = [np.zeros(r.k) for r in regimes], [np.zeros(r.k) for r in regimes]
        observations, masks = zip(*(r.steps.reset(s)[:2] for r, s in zip(regimes, seeds, strict=True)), strict=True)
        observations, masks = list(observations), list(masks)
        for _ in range(length):
            x, deciders = self._deciders(regimes, observations, base)
            mask = np.concatenate([m[dc, da] for m, (dc, da, _) in zip(masks, deciders, strict=True)])
            with torch.no_grad():
                logits = learner.nets[SHARED].actor(torch.as_tensor(x, device=learner.device))
                if not greedy:
                    logits = logits / learner.config.eval_temperature
                dist = MaskedCategorical(logits, torch.as_tensor(mask, device=learner.device))
                act = (dist.mode() if greedy else dist.sample(learner.generator)).cpu().numpy()
            at, truncated = 0, False
            for g, (r, (dc, da, _)) in enumerate(zip(regimes, deciders, strict=True)):
                actions = np.zeros((r.k, r.n), dtype=np.int64)
                actions[dc, da] = act[at:at + len(dc)]
                at += len(dc)
                np.add.at(decided[g], dc, 1)
                observations[g], masks[g], rewards, truncated, _ = r.steps.step(actions, masks[g])
                returns[g] += rewards.sum(axis=1)
            if truncated:
                break
        wall = (time.perf_counter() - start) / sum(r.k for r in regimes)
        return [self._rows(r, s, ret, d, wall, {})
                for r, s, ret, d in zip(regimes, seeds, returns, decided, strict=True)]

    def _deciders(self, regimes: Sequence[Regime], observations: Sequence[np.ndarray], base: np.ndarray
                  ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
        """The features of the agents that hold a task (all regimes, in order), and per regime who they are:
        (copies, agents, chains)."""
        who, parts = [], []
        for r, observation, b in zip(regimes, observations, base[:-1], strict=True):
            dc, da = np.nonzero(r.steps.present[:, :, 0])
            who.append((dc, da, b + dc * r.n + da))
            parts.append(r.features(observation[dc, da], da))
        return np.concatenate(parts), who

    def _rewards(self, regimes: Sequence[Regime], running: np.ndarray, truncated: bool, fresh: np.ndarray) -> None:
        """Add the step's scaled rewards to the open decisions (``Learner.observe``), or, with credit per task,
        give every decision whose tasks all settled its normalised credit (``Learner.settle``)."""
        learner, table = self.learner, self.table
        c = learner.config
        scale = c.reward_scale
        open_chains = np.flatnonzero(self.open_row >= 0)
        rows = self.open_row[open_chains]
        if regimes[0].credit is None:
            scaled = np.concatenate([r.rewards.ravel() for r in regimes]) * scale
            if c.normalize_reward:
                scaled = learner.returns.normalize_all(scaled, running, truncated)
            table["reward"][rows] += table["discount"][rows] * scaled[open_chains]
        else:
            waiting = np.flatnonzero(np.isnan(table["credit"]))
            for g, r in enumerate(regimes):
                for ledger in r.steps.ledgers:
                    r.credit.settle(ledger)
                mine = waiting[table["group"][waiting] == g]
                table["credit"][mine] = r.credit.credit[table["copy"][mine], table["task"][mine]]
            came = waiting[~np.isnan(table["credit"][waiting])]
            came = np.union1d(came, fresh[table["credit"][fresh] == 0.0])  # with those credited 0 when placed
            values = table["credit"][came] * scale
            if c.normalize_reward:
                sums = np.zeros(running.shape)
                np.add.at(sums, table["chain"][came], values)
                learner.returns.normalize_all(sums, running, truncated)
                values = learner.returns.divide(values)
            table["credit"][came] = values
        table["discount"][rows] *= c.gamma

    def _close(self, rows: np.ndarray, next_value: np.ndarray | None, last: bool) -> None:
        """Close decisions: bootstrapping from ``next_value`` with their discount, or as terminal (None)."""
        table = self.table
        table["closed"][rows] = True
        table["last"][rows] = last
        if next_value is None:
            table["discount"][rows] = 0.0
            table["next_value"][rows] = 0.0
        else:
            table["next_value"][rows] = next_value

    # ----- learning -----

    def _update(self, chains: int, steps: int, episode_over: bool) -> None:
        """One PPO update on the decisions that can be learnt from now (``credited``); the others wait. At the
        end of an episode the decisions whose credit never came are dropped (``uncredited_removed``).
        ``steps``: the copy-steps since the last update, for the learning rate's schedule."""
        learner, table = self.learner, self.table
        c = learner.config
        credit = c.credit == "task"
        if episode_over and credit:
            self._drop_uncredited()
        closed = table["closed"]
        credited = ~np.isnan(table["credit"]) if credit else np.ones(table.rows, dtype=bool)
        chain = table["chain"]
        # a chain's decisions from its first closed one without credit on wait (in time order)
        first_wait = np.full(chains, np.iinfo(np.int64).max)
        blocked = np.flatnonzero(closed & ~credited)
        np.minimum.at(first_wait, chain[blocked], blocked)
        ready = np.flatnonzero(closed & credited & (np.arange(table.rows) < first_wait[chain]))
        learner.anneal(learner.env_steps - steps)
        if len(ready):
            reward = table["credit"][ready] if credit else table["reward"][ready]
            value = table["value"][ready]
            adv = advantages(reward.tolist(), value.tolist(), table["next_value"][ready].tolist(),
                             table["discount"][ready].tolist(), table["last"][ready].tolist(),
                             chain[ready].tolist(), c.gae_lambda)
            batch = {"obs": table.features[ready], "critic": table.features[ready], "mask": table.mask[ready],
                     "action": table["action"][ready], "logp": table["logp"][ready], "value": value,
                     "advantage": adv, "return": adv + value, "teacher": np.full(len(ready), -1)}
            stats = learner.update_group(SHARED, {key: torch.as_tensor(v, device=learner.device)
                                                  for key, v in batch.items()})
            learner.updates += 1
            self.learnt += len(ready)
            learner.last_stats = {key: float(stats[key]) for key in learner.stat_names}
        self._keep(np.setdiff1d(np.arange(table.rows), ready))

    def _keep(self, rows: np.ndarray) -> None:
        """Keep only these decisions, renumbering the open ones (none of which leaves)."""
        new = np.full(self.table.rows + 1, -1)  # old row -> new row; the last entry maps -1 to -1
        new[rows] = np.arange(len(rows))
        self.open_row[:] = new[self.open_row]
        self.table.keep(rows)

    def _drop_uncredited(self) -> None:
        """``uncredited_removed``: the decisions whose credit will never come leave, and the decision before
        each (of the same chain) ends its chain there, bootstrapping from the state that followed it."""
        table = self.table
        gone = np.isnan(table["credit"])
        self.learner.uncredited += int(gone.sum())
        chain = table["chain"]
        order = np.lexsort((np.arange(table.rows), chain))  # by chain, then time
        following = np.full(table.rows, -1)  # the chain's next decision
        same = chain[order[1:]] == chain[order[:-1]]
        following[order[:-1][same]] = order[1:][same]
        kept = np.flatnonzero(~gone)
        ends = kept[(following[kept] >= 0) & gone[np.maximum(following[kept], 0)]]
        table["last"][ends] = True
        self._keep(kept)

    # ----- episode rows -----

    def _rows(self, regime: Regime, seeds: Sequence[int], returns: np.ndarray, decisions: np.ndarray,
              wall: float, extra: dict[str, float]) -> list[dict[str, float]]:
        totals = regime.steps.totals()
        generated, completed, dropped = totals["generated"], totals["completed"], totals["dropped"]
        response = totals["response_time_total"]
        penalty = regime.env.penalty
        rows = []
        for c, seed in enumerate(seeds):
            g, done = float(generated[c]), float(completed[c])
            rows.append({"seed": int(seed), "steps": regime.steps.steps, "decisions": float(decisions[c]),
                         "return": float(returns[c]), "generated": g, "completed": done, "dropped": float(dropped[c]),
                         "completion_ratio": done / g if g else math.nan,
                         "response_time_mean": float(response[c]) / done if done else math.nan,
                         "penalised_response_time": (float(response[c]) + penalty * (g - done)) / g if g else math.nan,
                         "wall_s": wall, **extra})
        return rows


def train(regime: Regime, learner: PPO, episodes: int, *, seed: int = 0, csv_path: str | Path | None = None,
          progress: Progress | None = None, label: str = "") -> list[dict]:
    """``agents.training.train`` on K copies of one regime: ``episodes`` episodes (seeds seed, seed + 1, ...),
    K at a time, one CSV row each (``episodes`` a multiple of K)."""
    if episodes % regime.k:
        raise ValueError(f"{episodes} episodes cannot run {regime.k} at a time")
    learner.start_training(episodes * regime.env.max_steps)
    trainer = VectorPPO(learner)
    task = progress.add_task(label or "train ppo", total=episodes, info="") if progress else None
    writer = CsvWriter(csv_path) if csv_path else None
    rows: list[dict] = []
    for k in range(0, episodes, regime.k):
        (out,) = trainer.episode([regime], [list(range(seed + k, seed + k + regime.k))])
        for j, row in enumerate(out):
            rows.append({"episode": k + j, **row})
            if writer:
                writer.write(rows[-1])
        if progress is not None:
            progress.update(task, advance=regime.k, info=f"return {np.mean([r['return'] for r in out]):.0f}")
    if writer:
        writer.close()
    return rows
