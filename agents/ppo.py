"""PPO (Schulman et al. 2017) with parameter sharing across agents: IPPO by default, MAPPO with
``centralised_critic=True`` (de Witt et al. 2020; Yu et al. 2022).

One actor-critic serves every agent, whose one-hot id is part of the input. Each rollout is used for
``update_epochs`` passes of ``num_minibatches`` shuffled minibatches: clipped surrogate objective on
normalised GAE advantages, squared-error value loss, entropy bonus, gradient clipping; the learning
rate decays linearly to 0 over the training horizon. The masked categorical never gives a masked
action any probability.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from agents.onpolicy import ActorCriticConfig, OnPolicyLearner


@dataclass
class PPOConfig(ActorCriticConfig):
    lr: float = 3e-4
    shared: bool = True
    rollout_steps: int = 256  # environment steps per rollout (about 400 decisions on aot2 at lambda = 0.17)
    gae_lambda: float = 0.95
    clip_coef: float = 0.2
    update_epochs: int = 4
    num_minibatches: int = 4
    norm_adv: bool = True
    anneal_lr: bool = True
    target_kl: float | None = None  # stop the epochs early when the approximate KL exceeds it
    normalize_reward: bool = True  # any reward, any scenario: no reward_scale to tune (ReturnScale)


class PPO(OnPolicyLearner):
    name = "ppo"
    Config = PPOConfig
    config: PPOConfig
    stat_names = ("policy_loss", "value_loss", "entropy", "approx_kl", "clipfrac")

    def update_group(self, group: str, b: dict[str, torch.Tensor]) -> dict[str, float]:
        c = self.config
        n = len(b["action"])
        stats: dict[str, float] = {}
        for _ in range(c.update_epochs):
            order = torch.as_tensor(self.rng.permutation(n), device=self.device)
            for idx in torch.tensor_split(order, min(c.num_minibatches, n)):
                logp, entropy, value, imitation = self.evaluate_actions(group, b, idx)
                log_ratio = logp - b["logp"][idx]
                ratio = log_ratio.exp()
                adv = b["advantage"][idx]
                if c.norm_adv and len(idx) > 1:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                policy_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - c.clip_coef, 1 + c.clip_coef)).mean()
                value_loss = 0.5 * (b["return"][idx] - value).pow(2).mean()
                loss = policy_loss + c.vf_coef * value_loss - c.ent_coef * entropy.mean() + imitation
                self.step_optimizer(group, loss)
                with torch.no_grad():  # http://joschu.net/blog/kl-approx.html
                    approx_kl = float(((ratio - 1) - log_ratio).mean())
                    clipfrac = float(((ratio - 1).abs() > c.clip_coef).float().mean())
                stats = {"policy_loss": policy_loss.item(), "value_loss": value_loss.item(),
                         "entropy": entropy.mean().item(), "approx_kl": approx_kl, "clipfrac": clipfrac}
            if c.target_kl is not None and stats["approx_kl"] > c.target_kl:
                break
        return stats
