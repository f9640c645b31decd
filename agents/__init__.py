"""Offloading agents for the project's PettingZoo environments: heuristics and MARL learners.

    from agents import make_policy
    ddqn = make_policy("ddqn", env)          # or "a2c", "ppo", "local", "random", "least_queue", ...
    train(env, ddqn, episodes=50); evaluate(env, ddqn, episodes=10)

The package only uses the PettingZoo API and the observation conventions (docs/agents.md), with the
column names of ``env.observations``; its baselines run the model's policies (``node_runtime.model.policies``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from agents.a2c import A2C, A2CConfig
from agents.baselines import BASELINES, Baseline
from agents.common import AgentPolicy
from agents.ddqn import DDQN, DDQNConfig
from agents.learner import Learner, LearnerConfig
from agents.ppo import PPO, PPOConfig
from agents.training import evaluate, train
from node_runtime.model.plugins import is_import_path, load_from_command_line

LEARNERS: dict[str, type[Learner]] = {"ddqn": DDQN, "a2c": A2C, "ppo": PPO}
POLICY_NAMES = (*LEARNERS, *BASELINES)


def make_policy(name: str, env: Any = None, config: LearnerConfig | None = None, device: str = "cpu",
                seed: int | None = None) -> AgentPolicy:
    """A baseline by name, a user's ``Baseline`` subclass by import path ("module:Class"; ``PluginError`` if it
    is none), or a fresh learner for ``env``'s agents (``config`` defaults to the learner's)."""
    if is_import_path(name):
        return load_from_command_line(name, Baseline)(seed)
    if name in BASELINES:
        return BASELINES[name](seed)
    if name not in LEARNERS:
        raise ValueError(f"unknown policy {name!r}; expected one of {', '.join(POLICY_NAMES)}")
    if env is None:
        raise ValueError(f"{name} needs the environment, to size its networks")
    return LEARNERS[name].for_env(env, config, device)


def load_learner(path: str | Path, device: str = "cpu") -> Learner:
    """Any learner's checkpoint, whatever its algorithm."""
    algo = torch.load(path, map_location="cpu", weights_only=True)["algo"]
    return LEARNERS[algo].load(path, device)


__all__ = ["A2C", "BASELINES", "DDQN", "LEARNERS", "POLICY_NAMES", "PPO", "A2CConfig", "AgentPolicy", "Baseline",
           "DDQNConfig", "Learner", "LearnerConfig", "PPOConfig", "evaluate", "load_learner", "make_policy", "train"]
