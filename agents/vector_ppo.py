"""PPO over K copies of a scenario stepped together on the array backend: the project's PPO, fed in arrays.

    learner = PPO(specs, PPOConfig(shared=True, agent_id=False, credit="task", gamma=0.0))
    trainer = VectorPPO(learner, env, envs=64)      # env: ZenohEdgeEnv(observation="flat", backend="array", ...)
    rows = trainer.episode(seeds)                    # one episode of every copy, learning as it goes

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
sample stream: K episodes of one regime run at once, and an update comes every ``rollout_steps`` steps of
all K copies, so it holds K times the decisions of a serial one (``num_minibatches`` times larger minibatches).
Binary mode only (one task per decision); no centralised critic and no teacher (they read Dict observations).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from agents.common import MaskedCategorical, flatten, one_hot
from agents.learner import SHARED
from agents.onpolicy import advantages
from agents.ppo import PPO
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
        "copy": np.int64, "agent": np.int64, "step": np.int64, "task": np.int64, "action": np.int64,
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


class VectorPPO:
    """Trains a shared-network ``PPO`` on K copies of ``env``'s scenario and settings (module docstring)."""

    def __init__(self, learner: PPO, env: ZenohEdgeEnv, envs: int = 64, rollout_steps: int | None = None) -> None:
        reason = unsupported(learner, env)
        if reason is not None:
            raise ValueError(f"the vectorised PPO loop does not train {reason}")
        self.learner, self.env = learner, env
        self.steps = BatchedSteps.of(env, envs)
        self.k, self.n = envs, len(self.steps.agents)
        # steps of every copy between updates: by default as many copy-steps per update as the serial loop's
        self.rollout = rollout_steps or max(1, learner.config.rollout_steps // envs)
        s = env.builders[self.steps.agents[0]].slices
        self.own = s["own"]
        self.task = slice(s["task"].start, s["task"].start + len(TaskField))
        self.neighbours = s["neighbours"]
        self.slots = self.steps.slots
        c = learner.config
        self.credit = ArrayCredit(env.penalty, env.reward_settings) if c.credit == "task" else None
        self.ids = (np.stack([one_hot(learner.index[a], len(learner.agents)) for a in self.steps.agents])
                    if c.agent_id else None)
        self.table = Decisions.empty(learner.input_dim(SHARED), self.steps.n_actions)
        self.learnt = 0  # decisions learnt from so far (the others: learner.uncredited)

    def close(self) -> None:
        self.env.close()

    # ----- features and acting -----

    def features(self, observation: np.ndarray, agents: np.ndarray) -> np.ndarray:
        """The learner's features (``Learner.features``) of flat observations (rows) of ``agents``."""
        if not len(observation):
            return np.zeros((0, self.table.features.shape[1]), np.float32)
        own = observation[:, self.own]
        task = observation[:, self.task]
        nb = observation[:, self.neighbours].reshape(len(observation), self.slots, len(NeighbourField))
        x = flatten(own, task, nb)
        return x if self.ids is None else np.concatenate([x, self.ids[agents]], axis=1)

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

    def episode(self, seeds: Sequence[int], learn: bool = True) -> list[dict[str, float]]:
        """Run one episode in every copy (copy c seeded ``seeds[c]``), learning from it; one row per copy: the
        return (summed over agents), the task counts and ratios of the episode, the wall time and the learner's
        diagnostics after it."""
        start = time.perf_counter()
        learner, steps, table, k, n = self.learner, self.steps, self.table, self.k, self.n
        learner.rng = np.random.default_rng(seeds[0])  # as Learner.reset reseeds its sampling per episode
        learner.generator.manual_seed(int(seeds[0]))
        observation, mask, _ = steps.reset(seeds)
        if self.credit is not None:
            self.credit.reset(k, steps.sim.m)
        open_row = self.open_row = np.full((k, n), -1)  # each agent's open decision (its row), -1: none
        running = np.zeros((k, n))  # each agent's discounted return so far (ReturnScale's, per copy)
        returns = np.zeros(k)
        decisions = 0
        x, deciders = self._deciders(observation)
        for step in range(self.env.max_steps):
            # act for every agent with a task, and open its decision
            dc, da = deciders
            act, logp, value = self._act(x, mask[dc, da])
            task = steps.shown[dc, da, 0]
            rows = table.add(x, mask[dc, da], copy=dc, agent=da, step=np.full(len(dc), step), task=task,
                             action=act, logp=logp, value=value, discount=np.ones(len(dc)))
            open_row[dc, da] = rows
            decisions += len(dc)
            actions = np.zeros((k, n), dtype=np.int64)
            actions[dc, da] = act
            if self.credit is not None:
                settled = self.credit.place(dc, task)
                table["credit"][rows[settled]] = 0.0  # normalised below with the step's other credits
            observation, mask, rewards, truncated, _ = steps.step(actions, mask)
            returns += rewards.sum(axis=1)
            # the step's rewards or credits reach the open decisions
            self._rewards(rewards, open_row, running, truncated, fresh=rows)
            # close what the step ends: at the agent's next decision, or everything at the episode's end
            x, deciders = self._deciders(observation)
            nc, na = deciders
            next_value = self._values(x)
            closing = open_row[nc, na] >= 0
            self._close(open_row[nc[closing], na[closing]], next_value[closing], last=truncated)
            open_row[nc[closing], na[closing]] = -1
            if truncated:
                self._close(open_row[open_row >= 0], None, last=True)
                open_row[:] = -1
            learner.env_steps += k
            if learn and ((step + 1) % self.rollout == 0 or truncated):
                self._update(episode_over=truncated)
            if truncated:
                break
        return self._rows(seeds, returns, decisions, time.perf_counter() - start)

    def _deciders(self, observation: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The features of the agents that hold a task, and who they are (copies, agents)."""
        dc, da = np.nonzero(self.steps.present[:, :, 0])
        return self.features(observation[dc, da], da), (dc, da)

    def _rewards(self, rewards: np.ndarray, open_row: np.ndarray, running: np.ndarray, truncated: bool,
                 fresh: np.ndarray) -> None:
        """Add the step's scaled rewards to the open decisions (``Learner.observe``), or, with credit per task,
        give every decision whose tasks all settled its normalised credit (``Learner.settle``)."""
        learner, table = self.learner, self.table
        c = learner.config
        gamma, scale = c.gamma, c.reward_scale
        rows = open_row[open_row >= 0]
        if self.credit is None:
            scaled = rewards * scale
            if c.normalize_reward:
                scaled = self._normalised(scaled, running, truncated)
            who = open_row >= 0
            table["reward"][rows] += table["discount"][rows] * scaled[who]
        else:
            for ledger in self.steps.ledgers:
                self.credit.settle(ledger)
            waiting = np.flatnonzero(np.isnan(table["credit"]))
            copy, task = table["copy"][waiting], table["task"][waiting]
            came = waiting[~np.isnan(self.credit.credit[copy, task])]
            table["credit"][came] = self.credit.credit[table["copy"][came], table["task"][came]]
            came = np.concatenate([came, fresh[table["credit"][fresh] == 0.0]])  # credited 0 when placed
            came = np.unique(came)
            values = table["credit"][came] * scale
            if c.normalize_reward:
                sums = np.zeros(running.shape)
                np.add.at(sums, (table["copy"][came], table["agent"][came]), values)
                self._normalised(sums, running, truncated)
                std = math.sqrt(learner.returns.rms.var + learner.returns.epsilon)
                values = np.clip(values / std, -learner.returns.clip, learner.returns.clip)
            table["credit"][came] = values
        table["discount"][rows] *= gamma

    def _normalised(self, scaled: np.ndarray, running: np.ndarray, truncated: bool) -> np.ndarray:
        """``ReturnScale.normalize`` for every (copy, agent) at once."""
        r = self.learner.returns
        running *= r.gamma
        running += scaled
        r.rms.update(running.ravel())
        if truncated:
            running[:] = 0.0
        std = math.sqrt(r.rms.var + r.epsilon)
        return np.clip(scaled / std, -r.clip, r.clip)

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

    def _update(self, episode_over: bool) -> None:
        """One PPO update on the decisions that can be learnt from now (``credited``); the others wait. At the
        end of an episode the decisions whose credit never came are dropped (``uncredited_removed``)."""
        learner, table = self.learner, self.table
        c = learner.config
        if episode_over and self.credit is not None:
            self._drop_uncredited()
        closed = table["closed"]
        credited = ~np.isnan(table["credit"]) if self.credit is not None else np.ones(table.rows, dtype=bool)
        chain = table["copy"] * self.n + table["agent"]
        # an agent's decisions from its first closed one without credit on wait (in time order)
        first_wait = np.full(self.k * self.n, np.iinfo(np.int64).max)
        blocked = np.flatnonzero(closed & ~credited)
        np.minimum.at(first_wait, chain[blocked], blocked)
        ready = np.flatnonzero(closed & credited & (np.arange(table.rows) < first_wait[chain]))
        if c.anneal_lr:  # the rate at the start of the rollout, so the last one still learns
            started = learner.env_steps - self.rollout * self.k
            for opt in learner.optimizers.values():
                for pg in opt.param_groups:
                    pg["lr"] = c.lr * max(0.0, 1.0 - started / learner.total_steps)
        if len(ready):
            reward = table["credit"][ready] if self.credit is not None else table["reward"][ready]
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
        each (of the same agent) ends its chain there, bootstrapping from the state that followed it."""
        table = self.table
        gone = np.isnan(table["credit"])
        chain = table["copy"] * self.n + table["agent"]
        learner = self.learner
        learner.uncredited += int(gone.sum())
        kept = np.flatnonzero(~gone)
        if not len(kept):
            self._keep(kept)
            return
        # a kept decision ends its chain when the chain's next decision is removed
        order = np.lexsort((np.arange(table.rows), chain))
        following = np.full(table.rows, -1)
        same = chain[order[1:]] == chain[order[:-1]]
        following[order[:-1][same]] = order[1:][same]
        ends = kept[(following[kept] >= 0) & gone[np.maximum(following[kept], 0)]]
        table["last"][ends] = True
        self._keep(kept)

    # ----- episode rows -----

    def _rows(self, seeds: Sequence[int], returns: np.ndarray, decisions: int, wall: float) -> list[dict[str, float]]:
        totals = self.steps.totals()
        generated, completed, dropped = totals["generated"], totals["completed"], totals["dropped"]
        response = totals["response_time_total"]
        penalty = self.env.penalty
        stats = self.learner.stats()
        rows = []
        for c, seed in enumerate(seeds):
            g, done = float(generated[c]), float(completed[c])
            rows.append({"seed": int(seed), "steps": self.steps.steps, "decisions": decisions / self.k,
                         "return": float(returns[c]), "generated": g, "completed": done, "dropped": float(dropped[c]),
                         "completion_ratio": done / g if g else math.nan,
                         "response_time_mean": float(response[c]) / done if done else math.nan,
                         "penalised_response_time": (float(response[c]) + penalty * (g - done)) / g if g else math.nan,
                         "wall_s": wall / self.k, **stats})
        return rows
