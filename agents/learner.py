"""The part every learning agent shares: decision tracking, parameter sharing, checkpoints.

An agent only acts when it has a task (``task[TaskField.PRESENT] == 1``); the steps in between are
no-ops whose action the environment ignores. A learner therefore sees each agent as a semi-MDP over
its own decisions: the transition opened at a decision is closed at the agent's next decision,
carrying the rewards received in between (discounted per environment step) and the discount gamma^k
to bootstrap with, k being the number of steps it lasted. At the end of an episode an open transition
is closed as terminal when the agent terminated, or bootstraps from the final observation when
truncated with a task in it; truncated without a task there is no decision state to bootstrap from,
and it is closed as terminal too.

With ``credit="task"`` a decision's reward is not what the steps after it bring, but
its tasks' own account as the environment credits it once they settle (``env.credit``,
``infos[agent]["credits"]``): a transition is learnt from only once its credit has come.

With ``shared=True`` one network serves every agent: the spaces must be uniform (pass
``uniform_spaces=True`` to the environment) and the agent's one-hot id is appended to its features.
With ``agent_id=False`` as well it is not, and the network acts for any agent whose spaces match, of any
scenario (``neighbour_slots=K``): a generalist sees its regime only through its observations.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from gymnasium.wrappers.utils import RunningMeanStd

from agents.common import (
    Action,
    AgentSpec,
    Observation,
    flat_dim,
    flatten_one,
    has_decision,
    one_hot,
    resolve_device,
    specs_of,
)

SHARED = "shared"  # the group name of the network every agent uses when parameters are shared


@dataclass
class LearnerConfig:
    """Settings common to every learner."""

    gamma: float = 0.99  # discount per environment step
    reward_scale: float = 1e-3  # the paper reward is in the hundreds to thousands; keep targets near 1
    normalize_reward: bool = False  # divide (scaled) rewards by the running std of the discounted return
    hidden: tuple[int, ...] = (128, 128)
    lr: float = 5e-4
    shared: bool = False  # one network for all agents (needs uniform spaces), agent id appended
    seed: int = 0
    credit: str = "step"  # "step": the rewards of the steps after a decision; "task": its tasks' credits (env.credit)
    agent_id: bool = True  # shared: the agent's one-hot id is part of the input; False: any agent, any scenario

    def __post_init__(self) -> None:  # named choices are checked here, so a command line fails before any work
        if self.credit not in CREDITS:
            raise ValueError(f"credit must be one of {', '.join(CREDITS)}, not {self.credit!r}")
        if not self.agent_id and not self.shared:
            raise ValueError("agent_id=false applies to a shared network (shared=true) only")


CREDITS = ("step", "task")


@dataclass
class OpenTransition:
    """An agent's open transition: its last decision and what happened since."""

    features: np.ndarray
    mask: np.ndarray
    action: int
    extras: dict[str, Any] = field(default_factory=dict)  # what the learner stored when acting (log-prob ...)
    reward: float = 0.0  # scaled, discounted sum of the rewards since the decision
    discount: float = 1.0  # gamma ** (steps since the decision)
    step: int = 0  # of the episode, counted from 0: the decision's key in the environment's credits
    credit: float | None = None  # credit="task": the scaled credit of its tasks, once they have all settled
    # (None for good when its episode ends first: it is not learnt from)


@dataclass
class Closed:
    """A transition closed at the agent's next decision or at the end of the episode."""

    agent: str
    pending: OpenTransition
    next_obs: Observation | None  # None: nothing to bootstrap from
    discount: float  # to apply to the next state's value (0 when terminal)
    last: bool  # closed by the end of the episode: the agent's next transition starts a new one


class Learner(ABC):
    """A policy that learns: ``explore`` while training, ``observe`` the outcome, ``act`` to evaluate."""

    name: ClassVar[str]
    Config: ClassVar[type[LearnerConfig]]
    task_credit: ClassVar[bool] = False  # whether it can learn from per-task credits (credit="task")

    def __init__(self, specs: Mapping[str, AgentSpec], config: LearnerConfig | None = None,
                 device: str = "cpu") -> None:
        self.specs = dict(specs)
        self.agents = list(self.specs)
        self.config = config if config is not None else self.Config()
        self.device = resolve_device(device)
        self.index = {a: i for i, a in enumerate(self.agents)}
        if self.config.shared and len(set(self.specs.values())) > 1:
            raise ValueError("shared parameters need every agent to have the same spaces: "
                             "create the environment with uniform_spaces=True")
        if self.config.credit == "task" and not self.task_credit:
            raise ValueError(f"{self.name} learns from step rewards only: credit='task' needs a learner that "
                             "waits for each decision's credit (ppo, a2c, ddqn)")
        self.pending: dict[str, OpenTransition] = {}
        self.step = 0  # of the episode
        self.awaiting: dict[tuple[str, int], OpenTransition] = {}  # credit="task": decisions whose credit has not come
        self.uncredited = 0  # decisions whose credit never came (their tasks outlived the episode): not learnt
        self.env_steps = 0  # environment steps observed while training
        self.returns = ReturnScale(self.config.gamma)
        self.total_steps = 1  # the training horizon, for schedules (set by start_training)
        self.rng = np.random.default_rng(self.config.seed)
        self.generator = torch.Generator(device=self.device).manual_seed(self.config.seed)
        torch.manual_seed(self.config.seed)  # network initialisation

    @classmethod
    def for_env(cls, env: Any, config: LearnerConfig | None = None, device: str = "cpu") -> Learner:
        """A learner for every possible agent of a PettingZoo parallel environment."""
        return cls(specs_of(env), config, device)

    # ----- features -----

    def group(self, agent: str) -> str:
        """The network that acts for ``agent``: the shared one, or its own."""
        if self.config.shared:
            if self.config.agent_id and agent not in self.index:
                raise KeyError(f"{agent} is not an agent this learner was made for ({', '.join(self.agents)}); "
                               "a network for any agent needs agent_id=false")
            return SHARED
        return agent

    def spec(self, group: str) -> AgentSpec:
        return self.specs[self.agents[0] if group == SHARED else group]

    def input_dim(self, group: str) -> int:
        return flat_dim(self.spec(group).slots) + (len(self.agents) if group == SHARED and self.config.agent_id else 0)

    def n_actions(self, group: str) -> int:
        return self.spec(group).n_actions

    def groups(self) -> list[str]:
        return [SHARED] if self.config.shared else list(self.agents)

    def features(self, agent: str, obs: Observation) -> np.ndarray:
        x = flatten_one(obs)
        if not (self.config.shared and self.config.agent_id):
            return x
        return np.concatenate([x, one_hot(self.index[agent], len(self.agents))])

    # ----- acting -----

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: forget open transitions (an unfinished episode's are dropped), reseed sampling."""
        self.pending.clear()
        self.step = 0
        self.uncredited += len(self.awaiting)  # the last episode ended before their credit came
        self.awaiting.clear()
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            self.generator.manual_seed(seed)

    def act(self, observations: Mapping[str, Observation]) -> dict[str, Action]:
        """The evaluation policy (greedy for DDQN, the learnt distribution for actor-critics)."""
        return self._decide(observations, explore=False)

    def explore(self, observations: Mapping[str, Observation]) -> dict[str, Action]:
        """The behaviour policy while training; opens a transition for every agent that decides."""
        return self._decide(observations, explore=True)

    def _decide(self, observations: Mapping[str, Observation], explore: bool) -> dict[str, Action]:
        actions: dict[str, Action] = {a: int(np.flatnonzero(o["action_mask"])[0]) for a, o in observations.items()}
        by_group: dict[str, list[str]] = {}
        for agent, obs in observations.items():
            if has_decision(obs):
                by_group.setdefault(self.group(agent), []).append(agent)
        for group, agents in by_group.items():
            feats = np.stack([self.features(a, observations[a]) for a in agents])
            masks = np.stack([np.asarray(observations[a]["action_mask"], dtype=bool) for a in agents])
            chosen, extras = self.choose(group, agents, feats, masks, observations, explore)
            for i, agent in enumerate(agents):
                actions[agent] = int(chosen[i])
                if explore:
                    if agent in self.pending:
                        raise RuntimeError(f"{agent}: explore() called twice without observe() in between")
                    p = self.pending[agent] = OpenTransition(feats[i], masks[i], int(chosen[i]),
                                                      {k: v[i] for k, v in extras.items()}, step=self.step)
                    if self.config.credit == "task":
                        self.awaiting[(agent, self.step)] = p
        return actions

    @abstractmethod
    def choose(self, group: str, agents: list[str], feats: np.ndarray, masks: np.ndarray,
               observations: Mapping[str, Observation], explore: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Actions for the deciding agents of one group, and per-agent extras to keep with the decision."""

    # ----- learning -----

    def start_training(self, total_steps: int) -> None:
        """Set the horizon (environment steps) that the exploration and learning-rate schedules span."""
        self.total_steps = max(1, int(total_steps))

    def observe(self, rewards: Mapping[str, float], next_observations: Mapping[str, Observation],
                terminations: Mapping[str, bool], truncations: Mapping[str, bool],
                credits: Mapping[str, list[tuple[int, float]]] | None = None) -> None:
        """Feed back one environment step; closes transitions and learns when the learner's schedule says so.
        ``credits``: ``infos[agent]["credits"]``, which credit="task" learns from instead of ``rewards``."""
        gamma = self.config.gamma
        scale = self.config.reward_scale
        ended = {a for a in rewards if terminations.get(a, False) or truncations.get(a, False)}
        if self.config.credit == "task":
            if credits is None:
                raise ValueError("credit='task' learns from the environment's infos[agent]['credits']: pass them "
                                 "to observe(credits=...)")
            self.settle(credits, list(rewards), ended)
            scaled = dict.fromkeys(rewards, 0.0)
        else:
            scaled = {a: float(r) * scale for a, r in rewards.items()}
            if self.config.normalize_reward:
                scaled = self.returns.normalize(scaled, ended)
        closed: list[Closed] = []
        for agent, reward in scaled.items():
            p = self.pending.get(agent)
            if p is None:
                continue
            p.reward += p.discount * reward
            p.discount *= gamma
            nxt = next_observations.get(agent)
            can_bootstrap = nxt is not None and has_decision(nxt) and not terminations.get(agent, False)
            if terminations.get(agent, False) or truncations.get(agent, False):
                closed.append(Closed(agent, p, nxt if can_bootstrap else None, p.discount if can_bootstrap else 0.0,
                                     last=True))
            elif can_bootstrap:
                closed.append(Closed(agent, p, nxt, p.discount, last=False))
        for c in closed:
            del self.pending[c.agent]
        self.env_steps += 1
        self.step += 1
        self.learn(closed, next_observations)

    def settle(self, credits: Mapping[str, list[tuple[int, float]]], agents: list[str], ended: set[str]) -> None:
        """Give each credited decision its scaled credit (normalised as the rewards would be: by the running
        std of each agent's discounted sum of the credits as they come)."""
        scale = self.config.reward_scale
        if self.config.normalize_reward:
            self.returns.normalize({a: scale * sum(v for _, v in credits.get(a, ())) for a in agents}, ended)
        for agent, pairs in credits.items():
            for step, value in pairs:
                p = self.awaiting.pop((agent, step), None)
                if p is None:
                    raise ValueError(f"a credit for {agent}'s step {step}, which took no decision awaiting one")
                p.credit = self.returns.divide(value * scale) if self.config.normalize_reward else value * scale

    @abstractmethod
    def learn(self, closed: list[Closed], next_observations: Mapping[str, Observation]) -> None:
        """Store the transitions closed at this step and update the networks when due."""

    @abstractmethod
    def stats(self) -> dict[str, float]:
        """Training diagnostics for the log (always the same keys; NaN when not yet available)."""

    # ----- checkpoints -----

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers and counters."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def save(self, path: str | Path) -> None:
        """Write a checkpoint: algorithm, config, agent specs and weights (not the replay buffer)."""
        torch.save({"algo": self.name, "config": asdict(self.config),
                    "specs": {a: asdict(s) for a, s in self.specs.items()}, "state": self.state_dict(),
                    "return_stats": self.returns.stats()}, path)

    @classmethod
    def load(cls, path: str | Path, device: str = "cpu") -> Learner:
        """Rebuild a learner from ``save``'s checkpoint, ready to act or to go on training."""
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        if ckpt["algo"] != cls.name:
            raise ValueError(f"{path} is a {ckpt['algo']} checkpoint, not {cls.name}")
        config = cls.Config(**{**ckpt["config"], "hidden": tuple(ckpt["config"]["hidden"])})
        learner = cls({a: AgentSpec(**s) for a, s in ckpt["specs"].items()}, config, device)
        learner.load_state_dict(ckpt["state"])
        if "return_stats" in ckpt:  # checkpoints from before reward normalisation have none
            learner.returns.load(ckpt["return_stats"])
        return learner


class ReturnScale:
    """Gymnasium's ``NormalizeReward`` for many agents: each agent's discounted return is accumulated
    every step, their running variance kept over all agents, and rewards divided by its square root.
    A reward's scale then no longer depends on the reward function or the scenario (a count of tasks a
    step, hundreds of seconds), so the learning rate and the value targets need no tuning per reward.
    Normalised rewards are clipped to +-``clip`` (as Stable-Baselines3's VecNormalize does): while few
    returns have been seen their variance is near 0, and one reward must not swamp the first updates."""

    def __init__(self, gamma: float, epsilon: float = 1e-8, clip: float = 10.0) -> None:
        self.gamma, self.epsilon, self.clip = gamma, epsilon, clip
        self.rms = RunningMeanStd(shape=())
        self.running: dict[str, float] = {}

    def normalize(self, rewards: Mapping[str, float], ended: set[str]) -> dict[str, float]:
        for agent, r in rewards.items():
            self.running[agent] = self.running.get(agent, 0.0) * self.gamma + r
        if rewards:
            self.rms.update(np.array([self.running[a] for a in rewards]))
        for agent in ended:  # a new episode starts a new return
            self.running.pop(agent, None)
        std = float(np.sqrt(self.rms.var + self.epsilon))
        clip = self.clip
        return {a: max(-clip, min(clip, r / std)) for a, r in rewards.items()}  # every step: no numpy per scalar

    def normalize_all(self, rewards: np.ndarray, running: np.ndarray, ended: bool) -> np.ndarray:
        """``normalize`` for agents held as an array: ``running`` (their discounted returns, updated in place, reset
        when ``ended``) beside ``rewards``, all of them in one update of the statistics."""
        running *= self.gamma
        running += rewards
        self.rms.update(running.ravel())
        if ended:
            running[:] = 0.0
        return self.divide(rewards)

    def divide(self, reward: Any) -> Any:
        """A reward (or an array of them) normalised by the running std as it stands (``normalize`` updates it)."""
        scaled = reward / float(np.sqrt(self.rms.var + self.epsilon))
        if isinstance(scaled, np.ndarray):
            return np.clip(scaled, -self.clip, self.clip)
        return max(-self.clip, min(self.clip, scaled))

    def stats(self) -> list[float]:
        return [float(self.rms.mean), float(self.rms.var), float(self.rms.count)]

    def load(self, stats: list[float]) -> None:
        self.rms.mean, self.rms.var, self.rms.count = (np.float64(x) for x in stats)
