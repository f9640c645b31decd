"""Rollouts, advantages and networks shared by the on-policy actor-critics (A2C and PPO).

Every ``rollout_steps`` environment steps the transitions closed since the last update are turned into
advantages, per agent and in time order, with GAE over the agent's own decisions:

    delta_k = r_k + g_k V(s_{k+1}) - V(s_k),    A_k = delta_k + g_k lambda A_{k+1}

where g_k = gamma^(steps between the two decisions), 0 when terminal. The recursion stops at the end of
an episode and at the agent's last transition of the rollout, which bootstraps from V of its next
decision state (computed when the transition closed). lambda = 1 gives A2C's n-step returns
(Mnih et al. 2016), bootstrapped at the end of the rollout.

``centralised_critic=True`` gives the critic the observations of every agent (MAPPO-style, Yu et al.
2022) instead of the agent's own; the actor always sees only its own observation.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from agents.baselines import BASELINES
from agents.common import (
    AgentSpec,
    MaskedCategorical,
    Observation,
    TargetScorer,
    flat_dim,
    flatten_one,
    mlp,
    one_hot,
)
from agents.learner import Closed, Learner, LearnerConfig, OpenTransition


@dataclass
class ActorCriticConfig(LearnerConfig):
    rollout_steps: int = 32  # environment steps between updates
    gae_lambda: float = 1.0
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    anneal_lr: bool = False  # decay the learning rate linearly to 0 over the training horizon
    centralised_critic: bool = False  # the critic sees every agent's observation (MAPPO)
    actor: str = "targets"  # "targets": one MLP scores each target (TargetScorer); "mlp": one logit per slot
    sample_eval: bool = True  # act() samples the learnt policy; False: its most likely action
    eval_temperature: float = 1.0  # act() samples softmax(logits / T): below 1 greedier, toward the mode as T -> 0
    teacher: str = ""  # a baseline the actor imitates at first (kickstarting); "" for none
    teacher_coef: float = 1.0  # weight of the imitation loss at the start, annealed linearly to 0 ...
    teacher_fraction: float = 0.25  # ... over this fraction of the training horizon

    def __post_init__(self) -> None:  # named choices are checked here, so a command line fails before any work
        super().__post_init__()
        if self.actor not in ACTORS:
            raise ValueError(f"actor must be one of {', '.join(ACTORS)}, not {self.actor!r}")
        if self.teacher and self.teacher not in BASELINES:
            raise ValueError(f"teacher must be one of {', '.join(BASELINES)}, not {self.teacher!r}")
        if not self.eval_temperature > 0:
            raise ValueError(f"eval_temperature must be > 0, not {self.eval_temperature!r} (sample_eval=false "
                             "takes the most likely action)")
        if self.centralised_critic and not self.agent_id:
            raise ValueError("centralised_critic=true needs agent_id=true: it reads every agent of one scenario")


ACTORS = ("targets", "mlp")


class ActorCritic(nn.Module):
    """Separate actor and critic networks (CleanRL's layout); a small last actor layer keeps the first
    policy close to uniform over the valid actions."""

    def __init__(self, dim: int, critic_dim: int, hidden: tuple[int, ...], spec: AgentSpec, actor: str) -> None:
        super().__init__()
        self.actor = (TargetScorer(spec.slots, hidden) if actor == "targets"
                      else mlp(dim, hidden, spec.n_actions, out_gain=0.01))
        self.critic = mlp(critic_dim, hidden, 1, out_gain=1.0)

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self.critic(x).squeeze(-1)


@dataclass
class Record:
    """One closed transition, with what the update needs."""

    agent: str
    features: np.ndarray
    critic: np.ndarray
    mask: np.ndarray
    action: int
    logp: float
    value: float
    reward: float
    discount: float
    next_value: float
    last: bool
    teacher: int = -1  # the teacher's action in that state (-1: no teacher)
    source: OpenTransition | None = None  # credit="task": the decision, whose credit is its reward once it has come


def credited(records: list[Record]) -> tuple[list[Record], list[Record]]:
    """The records that can be learnt from now, and those that wait: credit="task" holds each agent's records
    from its first decision whose credit has not come (its advantage needs every reward after it)."""
    ready: list[Record] = []
    waiting: list[Record] = []
    held: set[str] = set()
    for r in records:
        if r.agent in held or (r.source is not None and r.source.credit is None):
            held.add(r.agent)
            waiting.append(r)
        else:
            ready.append(r)
    return ready, waiting


def uncredited_removed(records: list[Record]) -> list[Record]:
    """The records without those whose credit will never come; the record before each removed one (of the same
    agent) ends its chain there, bootstrapping from the value of the state that followed it."""
    kept: list[Record] = []
    last: dict[str, Record] = {}
    for r in records:
        if r.source is not None and r.source.credit is None:
            if r.agent in last:
                last[r.agent].last = True
            continue
        kept.append(r)
        last[r.agent] = r
    return kept


def advantages(reward: Sequence[float], value: Sequence[float], next_value: Sequence[float],
               discount: Sequence[float], last: Sequence[bool], chain: Sequence[Hashable], lam: float) -> np.ndarray:
    """GAE over transitions listed in time order: each continues the next one of its chain (its agent's) in the
    list, unless it is the ``last`` of an episode; the last of a chain in the list bootstraps from its
    ``next_value`` alone (the module docstring's recursion, in Python floats, then float32)."""
    adv = np.zeros(len(reward), dtype=np.float32)
    following: dict[Hashable, float] = {}  # advantage of the chain's next transition, walking backwards
    for i in range(len(reward) - 1, -1, -1):
        delta = reward[i] + discount[i] * next_value[i] - value[i]
        cont = 0.0 if last[i] else following.get(chain[i], 0.0)
        adv[i] = following[chain[i]] = delta + discount[i] * lam * cont
    return adv


class OnPolicyLearner(Learner):
    """Acting with a masked categorical, collecting records, and handing batches to ``update_group``."""

    config: ActorCriticConfig
    stat_names: tuple[str, ...] = ("policy_loss", "value_loss", "entropy")
    task_credit = True

    def __init__(self, specs: Mapping[str, AgentSpec], config: ActorCriticConfig | None = None,
                 device: str = "cpu") -> None:
        super().__init__(specs, config, device)
        self.nets = {g: ActorCritic(self.input_dim(g), self.critic_dim(g), self.config.hidden, self.spec(g),
                                    self.config.actor).to(self.device) for g in self.groups()}
        self.optimizers = {g: torch.optim.Adam(n.parameters(), lr=self.config.lr, eps=1e-5)
                           for g, n in self.nets.items()}
        self.rollout: dict[str, list[Record]] = {g: [] for g in self.groups()}
        self.teacher = BASELINES[self.config.teacher](self.config.seed) if self.config.teacher else None
        self.updates = 0
        self.last_stats: dict[str, float] = dict.fromkeys(self.stat_names, float("nan"))
        self._global: tuple[Mapping[str, Observation], np.ndarray] | None = None

    # ----- critic input -----

    def critic_dim(self, group: str) -> int:
        if not self.config.centralised_critic:
            return self.input_dim(group)
        return sum(flat_dim(s.slots) for s in self.specs.values()) + len(self.agents)

    def critic_features(self, agent: str, observations: Mapping[str, Observation]) -> np.ndarray:
        if not self.config.centralised_critic:
            return self.features(agent, observations[agent])
        if self._global is None or self._global[0] is not observations:  # once per step, not per agent
            parts = [flatten_one(observations[a]) if a in observations else np.zeros(flat_dim(s.slots), np.float32)
                     for a, s in self.specs.items()]
            self._global = (observations, np.concatenate(parts))
        return np.concatenate([self._global[1], one_hot(self.index[agent], len(self.agents))])

    # ----- acting -----

    def choose(self, group: str, agents: list[str], feats: np.ndarray, masks: np.ndarray,
               observations: Mapping[str, Observation], explore: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        net = self.nets[group]
        with torch.no_grad():
            logits = net.actor(torch.as_tensor(feats, device=self.device))
            if not explore and self.config.eval_temperature != 1.0:
                logits = logits / self.config.eval_temperature
            dist = MaskedCategorical(logits, torch.as_tensor(masks, device=self.device))
            actions = dist.sample(self.generator) if explore or self.config.sample_eval else dist.mode()
            if not explore:
                return actions.cpu().numpy(), {}
            critic = np.stack([self.critic_features(a, observations) for a in agents])
            value = net.value(torch.as_tensor(critic, device=self.device))
        extras = {"logp": dist.log_prob(actions).cpu().numpy(), "value": value.cpu().numpy(), "critic": critic}
        if self.teacher is not None and self.teacher_weight() > 0:
            taught = self.teacher.act({a: observations[a] for a in agents})
            extras["teacher"] = np.array([taught[a] for a in agents])
        return actions.cpu().numpy(), extras

    def reset(self, seed: int | None = None) -> None:
        if self.awaiting:  # decisions whose tasks outlived their episode: what they lead to is not known
            for group, records in self.rollout.items():
                self.rollout[group] = uncredited_removed(records)
        super().reset(seed)
        if self.teacher is not None:  # its own state (round robin's counters, random's draws) follows the episode
            self.teacher.reset(seed)

    # ----- learning -----

    def learn(self, closed: list[Closed], next_observations: Mapping[str, Observation]) -> None:
        by_group: dict[str, list[Closed]] = {}
        for c in closed:
            by_group.setdefault(self.group(c.agent), []).append(c)
        for group, items in by_group.items():
            boot = [c for c in items if c.next_obs is not None]
            next_values = {}
            if boot:
                x = np.stack([self.critic_features(c.agent, next_observations) for c in boot])
                with torch.no_grad():
                    v = self.nets[group].value(torch.as_tensor(x, device=self.device)).cpu().numpy()
                next_values = {c.agent: float(vi) for c, vi in zip(boot, v, strict=True)}
            for c in items:
                p = c.pending
                self.rollout[group].append(Record(
                    c.agent, p.features, p.extras["critic"], p.mask, p.action, float(p.extras["logp"]),
                    float(p.extras["value"]), p.reward, c.discount, next_values.get(c.agent, 0.0), c.last,
                    int(p.extras.get("teacher", -1)), p if self.config.credit == "task" else None))
        if self.env_steps % self.config.rollout_steps == 0:
            self.anneal(self.env_steps - self.config.rollout_steps)
            stats = []
            for group, records in self.rollout.items():
                ready, waiting = credited(records)
                if ready:
                    stats.append(self.update_group(group, self.batch(ready)))
                    self.updates += 1
                records[:] = waiting
            if stats:  # averaged over the networks updated (one per agent when independent)
                self.last_stats = {k: float(np.mean([s[k] for s in stats])) for k in self.stat_names}

    def anneal(self, started: int) -> None:
        """With ``anneal_lr``, the learning rate for a rollout that started after ``started`` environment steps:
        the rate at its start, so that the last one still learns."""
        if self.config.anneal_lr:
            lr = self.config.lr * max(0.0, 1.0 - started / self.total_steps)
            for opt in self.optimizers.values():
                for pg in opt.param_groups:
                    pg["lr"] = lr

    def batch(self, records: list[Record]) -> dict[str, torch.Tensor]:
        """Tensors of a rollout, with GAE advantages and the critic's targets (returns)."""
        adv = advantages([r.reward if r.source is None else r.source.credit for r in records],
                         [r.value for r in records], [r.next_value for r in records], [r.discount for r in records],
                         [r.last for r in records], [r.agent for r in records], self.config.gae_lambda)
        values = np.array([r.value for r in records], dtype=np.float32)
        out = {"obs": np.stack([r.features for r in records]), "critic": np.stack([r.critic for r in records]),
               "mask": np.stack([r.mask for r in records]), "action": np.array([r.action for r in records]),
               "logp": np.array([r.logp for r in records], dtype=np.float32), "value": values,
               "advantage": adv, "return": adv + values, "teacher": np.array([r.teacher for r in records])}
        return {k: torch.as_tensor(v, device=self.device) for k, v in out.items()}

    def evaluate_actions(self, group: str, b: dict[str, torch.Tensor], idx: torch.Tensor | slice = slice(None)
                         ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Log-probabilities of the taken actions, entropies and values under the current networks, and the
        imitation loss: the weighted cross-entropy of the teacher's actions (0 without a teacher)."""
        net = self.nets[group]
        dist = MaskedCategorical(net.actor(b["obs"][idx]), b["mask"][idx])
        imitation = torch.zeros((), device=self.device)
        weight = self.teacher_weight()
        if weight > 0:  # past the imitation phase (or without a teacher) the minibatch's teacher column is not read
            taught = b["teacher"][idx]
            known = taught >= 0
            if bool(known.any()):
                imitation = -weight * dist.log_prob(taught.clamp(min=0))[known].mean()
        return dist.log_prob(b["action"][idx]), dist.entropy(), net.value(b["critic"][idx]), imitation

    def teacher_weight(self) -> float:
        """Kickstarting (Schmitt et al. 2018): the imitation loss's weight, from ``teacher_coef`` at the start
        of training to 0 after ``teacher_fraction`` of its horizon."""
        if self.teacher is None or self.config.teacher_fraction <= 0:
            return 0.0
        done = self.env_steps / (self.config.teacher_fraction * self.total_steps)
        return self.config.teacher_coef * max(0.0, 1.0 - done)

    def step_optimizer(self, group: str, loss: torch.Tensor) -> None:
        opt = self.optimizers[group]
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.nets[group].parameters(), self.config.max_grad_norm)
        opt.step()

    @abstractmethod
    def update_group(self, group: str, b: dict[str, torch.Tensor]) -> dict[str, float]:
        """Learn from one group's rollout; returns the values of ``stat_names``."""

    def stats(self) -> dict[str, float]:
        return {**self.last_stats, "updates": float(self.updates), "uncredited": float(self.uncredited)}

    # ----- checkpoints -----

    def state_dict(self) -> dict[str, Any]:
        return {"env_steps": self.env_steps, "total_steps": self.total_steps, "updates": self.updates,
                "nets": {g: n.state_dict() for g, n in self.nets.items()},
                "optimizers": {g: o.state_dict() for g, o in self.optimizers.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env_steps, self.total_steps, self.updates = state["env_steps"], state["total_steps"], state["updates"]
        for g, s in state["nets"].items():
            self.nets[g].load_state_dict(s)
            self.optimizers[g].load_state_dict(state["optimizers"][g])
