"""Double DQN (van Hasselt et al. 2016) for independent learners, or one network shared by all agents.

The target of a transition (s, a, r, s') is y = r + g * Q_target(s', argmax_{a' valid in s'} Q_online(s', a')):
the online network picks the next action among the valid ones, the target network values it, which
removes the max operator's overestimation. ``double=False`` gives the vanilla max-target of DQN for
comparison. Each independent learner has its own network, target network, optimiser and replay buffer;
with ``shared=True`` there is one of each and the agent id is part of the input.

With ``credit="task"`` r is the decision's own credit (env.credit), which comes when its tasks have
settled, often after the transition closed: a closed transition waits for it before it enters the replay
buffer, and one whose credit never comes (its tasks outlived the episode) is never stored.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from agents.common import AgentSpec, Observation, masked_argmax, mlp, polyak
from agents.learner import Closed, Learner, LearnerConfig, OpenTransition


@dataclass
class DDQNConfig(LearnerConfig):
    buffer_size: int = 100_000  # transitions per replay buffer
    batch_size: int = 64
    learning_starts: int = 256  # transitions a buffer holds before its network learns
    train_freq: int = 1  # new transitions per round of gradient steps
    gradient_steps: int = 1
    target_update: Literal["hard", "soft"] = "hard"
    target_update_interval: int = 500  # gradient steps between hard copies
    tau: float = 0.005  # soft update rate, every gradient step, when target_update == "soft"
    eps_start: float = 1.0
    eps_end: float = 0.05
    exploration_fraction: float = 0.5  # of the training horizon over which epsilon decays linearly
    max_grad_norm: float = 10.0
    double: bool = True  # False: vanilla DQN target, for ablations


class ReplayBuffer:
    """A ring buffer of (features, mask, action, reward, discount, next features, next mask)."""

    def __init__(self, capacity: int, dim: int, n_actions: int) -> None:
        self.capacity = capacity
        self.obs = np.zeros((capacity, dim), dtype=np.float32)
        self.mask = np.zeros((capacity, n_actions), dtype=bool)
        self.action = np.zeros(capacity, dtype=np.int64)
        self.reward = np.zeros(capacity, dtype=np.float32)
        self.discount = np.zeros(capacity, dtype=np.float32)  # gamma^k, or 0 when terminal
        self.next_obs = np.zeros((capacity, dim), dtype=np.float32)
        self.next_mask = np.zeros((capacity, n_actions), dtype=bool)
        self.added = 0

    def __len__(self) -> int:
        return min(self.added, self.capacity)

    def add(self, obs: np.ndarray, mask: np.ndarray, action: int, reward: float, discount: float,
            next_obs: np.ndarray, next_mask: np.ndarray) -> None:
        i = self.added % self.capacity
        self.obs[i], self.mask[i], self.action[i], self.reward[i] = obs, mask, action, reward
        self.discount[i], self.next_obs[i], self.next_mask[i] = discount, next_obs, next_mask
        self.added += 1

    def sample(self, n: int, rng: np.random.Generator, device: torch.device) -> dict[str, torch.Tensor]:
        idx = rng.integers(len(self), size=n)
        return {k: torch.as_tensor(getattr(self, k)[idx], device=device)
                for k in ("obs", "mask", "action", "reward", "discount", "next_obs", "next_mask")}


def td_target(online: nn.Module, target: nn.Module, reward: torch.Tensor, discount: torch.Tensor,
              next_obs: torch.Tensor, next_mask: torch.Tensor, double: bool = True) -> torch.Tensor:
    """r + discount * Q_target(s', a*), a* = argmax over the valid actions of Q_online (double) or Q_target."""
    with torch.no_grad():
        q_next = target(next_obs)
        chooser = online(next_obs) if double else q_next
        best = masked_argmax(chooser, next_mask)
        return reward + discount * q_next.gather(1, best.unsqueeze(1)).squeeze(1)


class QLearner:
    """One Q-network with its target network, optimiser and replay buffer."""

    def __init__(self, dim: int, n_actions: int, cfg: DDQNConfig, device: torch.device) -> None:
        self.online = mlp(dim, cfg.hidden, n_actions).to(device)
        self.target = mlp(dim, cfg.hidden, n_actions).to(device)
        self.target.load_state_dict(self.online.state_dict())
        self.optimizer = torch.optim.Adam(self.online.parameters(), lr=cfg.lr)
        self.buffer = ReplayBuffer(cfg.buffer_size, dim, n_actions)
        self.updates = 0


class DDQN(Learner):
    """Double DQN with masked epsilon-greedy acting, Huber loss, gradient clipping and target syncs."""

    name = "ddqn"
    Config = DDQNConfig
    config: DDQNConfig
    task_credit = True

    def __init__(self, specs: Mapping[str, AgentSpec], config: DDQNConfig | None = None, device: str = "cpu") -> None:
        super().__init__(specs, config, device)
        self.nets = {g: QLearner(self.input_dim(g), self.n_actions(g), self.config, self.device) for g in self.groups()}
        self.uncredited_closed: list[tuple[Closed, np.ndarray, np.ndarray]] = []  # credit="task": closed, awaiting
        self.last_loss = float("nan")
        self.last_q = float("nan")

    @property
    def epsilon(self) -> float:
        c = self.config
        frac = min(1.0, self.env_steps / max(1.0, c.exploration_fraction * self.total_steps))
        return c.eps_start + frac * (c.eps_end - c.eps_start)

    def q_values(self, group: str, feats: np.ndarray) -> torch.Tensor:
        with torch.no_grad():
            return self.nets[group].online(torch.as_tensor(feats, device=self.device))

    def choose(self, group: str, agents: list[str], feats: np.ndarray, masks: np.ndarray,
               observations: Mapping[str, Observation], explore: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        greedy = masked_argmax(self.q_values(group, feats), torch.as_tensor(masks, device=self.device)).cpu().numpy()
        if explore:
            eps = self.epsilon
            for i, mask in enumerate(masks):
                if self.rng.random() < eps:
                    greedy[i] = self.rng.choice(np.flatnonzero(mask))
        return greedy, {}

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.uncredited_closed.clear()  # their credit will never come (Learner.reset counted them)

    def learn(self, closed: list[Closed], next_observations: Mapping[str, Observation]) -> None:
        ready = []
        for t in closed:
            p = t.pending
            if t.next_obs is None:  # terminal: the next state is never valued (discount 0)
                next_feats, next_mask = np.zeros_like(p.features), np.zeros_like(p.mask)
                next_mask[0] = True
            else:
                next_feats = self.features(t.agent, t.next_obs)
                next_mask = np.asarray(t.next_obs["action_mask"], dtype=bool)
            ready.append((t, next_feats, next_mask))
        if self.config.credit == "task":
            waiting = self.uncredited_closed + ready
            ready = [w for w in waiting if w[0].pending.credit is not None]
            self.uncredited_closed = [w for w in waiting if w[0].pending.credit is None]
        for t, next_feats, next_mask in ready:
            p = t.pending
            reward = p.reward if p.credit is None else p.credit
            self.store(self.nets[self.group(t.agent)], p, reward, t.discount, next_feats, next_mask)

    def store(self, net: QLearner, p: OpenTransition, reward: float, discount: float, next_feats: np.ndarray,
              next_mask: np.ndarray) -> None:
        """Add a transition to the replay buffer, then learn when the schedule says so."""
        c = self.config
        net.buffer.add(p.features, p.mask, p.action, reward, discount, next_feats, next_mask)
        if len(net.buffer) >= c.learning_starts and net.buffer.added % c.train_freq == 0:
            for _ in range(c.gradient_steps):
                self.update(net)

    def update(self, net: QLearner) -> None:
        """One gradient step on a minibatch of the learner's replay buffer, then the target schedule."""
        c = self.config
        b = net.buffer.sample(c.batch_size, self.rng, self.device)
        target = td_target(net.online, net.target, b["reward"], b["discount"], b["next_obs"], b["next_mask"],
                           c.double)
        q = net.online(b["obs"]).gather(1, b["action"].unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(q, target)
        net.optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(net.online.parameters(), c.max_grad_norm)
        net.optimizer.step()
        net.updates += 1
        if c.target_update == "soft":
            polyak(net.target, net.online, c.tau)
        elif net.updates % c.target_update_interval == 0:
            polyak(net.target, net.online, 1.0)
        self.last_loss = loss.item()
        self.last_q = q.mean().item()

    def stats(self) -> dict[str, float]:
        return {"epsilon": self.epsilon, "loss": self.last_loss, "q_mean": self.last_q,
                "updates": float(sum(n.updates for n in self.nets.values()))}

    def state_dict(self) -> dict[str, Any]:
        return {"env_steps": self.env_steps, "total_steps": self.total_steps,
                "nets": {g: {"online": n.online.state_dict(), "target": n.target.state_dict(),
                             "optimizer": n.optimizer.state_dict(), "updates": n.updates}
                         for g, n in self.nets.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env_steps, self.total_steps = state["env_steps"], state["total_steps"]
        for g, s in state["nets"].items():
            net = self.nets[g]
            net.online.load_state_dict(s["online"])
            net.target.load_state_dict(s["target"])
            net.optimizer.load_state_dict(s["optimizer"])
            net.updates = s["updates"]
