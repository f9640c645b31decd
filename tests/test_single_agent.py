"""The single-agent Gymnasium wrapper passes Gymnasium's own environment checker."""

from __future__ import annotations

import os

import pytest
from gymnasium.utils.env_checker import check_env

from env.single_agent import SingleAgentEnv

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


@pytest.mark.parametrize("node", ["rpi3_0", "server_0"])
def test_check_env(node):
    env = SingleAgentEnv("aot1", node=node, transport="inproc", max_steps=50, others_policy="least_queue")
    check_env(env, skip_render_check=True)
    env.close()


def test_render_and_episode():
    env = SingleAgentEnv("aot1", transport="inproc", max_steps=30, render_mode="ansi")
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(0)
        done = terminated or truncated
    assert "episode" in info and "rpi3_0" in env.render()
    env.close()
