"""Reward wrappers for ``ZenohEdgeEnv``, as PettingZoo ``BaseParallelWrapper``s: the rest of the API passes through.

    env = PotentialShaping(InvalidActionPenalty(ZenohEdgeEnv("aot2"), penalty=-10), potential=xi, gamma=0.99)

They change rewards only; what the agents do and observe, and the emulation, stay as they were.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

from env.reward import shaped


class InvalidActionPenalty(BaseParallelWrapper):
    """Adds ``penalty`` to the reward of each agent whose action its mask forbade in this step.

    It reads ``infos[agent]["invalid_action"]``: the environment has already kept those tasks local
    (docs/env.md, "Actions"). An ignored action (nothing to decide) is not invalid, so never penalised.
    """

    def __init__(self, env: ParallelEnv, penalty: float = -10.0) -> None:
        super().__init__(env)
        self.penalty = penalty

    def step(self, actions: dict[str, Any]):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent, info in infos.items():
            if info["invalid_action"]:
                rewards[agent] += self.penalty
        return observations, rewards, terminations, truncations, infos


class PotentialShaping(BaseParallelWrapper):
    """Potential-based shaping: adds gamma * Xi(s') - Xi(s) to each agent's reward, from its own observations.

    ``potential`` maps one agent's observation to a float. Shaping of this form keeps the optimal
    policies of the unshaped problem (Ng, Harada & Russell, 1999; docs/reward.md).
    """

    def __init__(self, env: ParallelEnv, potential: Callable[[Any], float], gamma: float = 0.99) -> None:
        super().__init__(env)
        self.potential = potential
        self.gamma = gamma
        self._last: dict[str, float] = {}

    def reset(self, seed: int | None = None, options: dict | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        self._last = {agent: self.potential(obs) for agent, obs in observations.items()}
        return observations, infos

    def step(self, actions: dict[str, Any]):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent in rewards:
            after = self.potential(observations[agent])
            rewards[agent] = shaped(rewards[agent], self._last[agent], after, self.gamma)
            self._last[agent] = after
        return observations, rewards, terminations, truncations, infos
