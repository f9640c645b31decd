"""Advantage actor-critic (A2C, Mnih et al. 2016): n-step returns, masked softmax policy, entropy bonus.

One synchronous gradient step per rollout on every transition of it: policy gradient weighted by the
advantage, squared error of the critic against the bootstrapped returns, minus an entropy bonus.
Independent learners by default (one actor-critic per agent, as in the paper), or one shared network.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from agents.onpolicy import ActorCriticConfig, OnPolicyLearner


@dataclass
class A2CConfig(ActorCriticConfig):
    lr: float = 7e-4
    rollout_steps: int = 32  # about 5 decisions per rpi3 agent at lambda = 0.17: the "n" of the returns
    gae_lambda: float = 1.0  # plain n-step returns


class A2C(OnPolicyLearner):
    name = "a2c"
    Config = A2CConfig
    config: A2CConfig

    def update_group(self, group: str, b: dict[str, torch.Tensor]) -> dict[str, float]:
        logp, entropy, value, imitation = self.evaluate_actions(group, b)
        policy_loss = -(b["advantage"] * logp).mean()
        value_loss = 0.5 * (b["return"] - value).pow(2).mean()
        loss = policy_loss + self.config.vf_coef * value_loss - self.config.ent_coef * entropy.mean() + imitation
        self.step_optimizer(group, loss)
        return {"policy_loss": policy_loss.item(), "value_loss": value_loss.item(), "entropy": entropy.mean().item()}
