"""``SingleAgentEnv``: a Gymnasium environment with one learning controller.

The other controllers follow their node-side policy (the scenario's, or ``others_policy``). A choice
the mask forbids keeps the task local, as in ``ZenohEdgeEnv``, and costs ``invalid_penalty`` (the
``InvalidActionPenalty`` wrapper), since single-agent learners rarely use masks; the mask is still in
the observation (``obs["action_mask"]``) for those that do.

    from env.single_agent import SingleAgentEnv
    env = SingleAgentEnv("aot1", node="nuc_0")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium

from env.environment import ZenohEdgeEnv, agent_name
from env.wrappers import InvalidActionPenalty


class SingleAgentEnv(gymnasium.Env):
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ZenohEdgeEnv.metadata["render_modes"], "render_fps": 4}

    def __init__(self, scenario: Any = "aot1", node: str | None = None, *, others_policy: str | None = None,
                 invalid_penalty: float = -10.0, render_mode: str | None = None, **kwargs: Any) -> None:
        """``node``: the learning controller (default: the scenario's first); ``kwargs`` go to ZenohEdgeEnv."""
        probe = ZenohEdgeEnv(scenario, render_mode=render_mode, **kwargs)
        node = node or probe.scenario.controllers[0]
        probe.close()
        self.env = InvalidActionPenalty(ZenohEdgeEnv(scenario, agents=[node], render_mode=render_mode, **kwargs),
                                        invalid_penalty)
        self.agent = agent_name(node)
        self.others_policy = others_policy
        self.render_mode = render_mode
        self.observation_space = self.env.observation_space(self.agent)
        self.action_space = self.env.action_space(self.agent)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        if self.others_policy is not None:
            options.setdefault("policy", self.others_policy)
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(self, action):
        obs, rewards, terminations, truncations, infos = self.env.step({self.agent: action})
        a = self.agent
        return obs[a], rewards[a], terminations[a], truncations[a], infos[a]

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()
