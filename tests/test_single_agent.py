"""The single-agent Gymnasium wrapper passes Gymnasium's own environment checker."""

from __future__ import annotations

import os

import pytest
from gymnasium.utils.env_checker import check_env

from env import TaskField
from env.single_agent import SingleAgentEnv
from tests.conftest import write_scenario

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


def test_a_masked_choice_keeps_the_task_local_and_costs_the_penalty(tmp_path):
    """Node a's neighbour d has no worker: sending a task there is invalid."""
    path = write_scenario(tmp_path, {
        "simulation": {"steps": 40},
        "topology": {"nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b"},
                               {"id": "d", "client": True, "worker": False}],
                     "links": [["a", "b"], ["a", "d"]]},
        "workload": {"arrival": {"rate": 0.5}}})
    env = SingleAgentEnv(path, transport="inproc", reward="sparse", invalid_penalty=-3.0)
    plain = SingleAgentEnv(path, transport="inproc", reward="sparse", invalid_penalty=0.0)
    obs, _ = env.reset(seed=0)
    plain.reset(seed=0)
    seen = 0
    for _ in range(40):
        has_task = obs["task"][TaskField.PRESENT] == 1
        obs, reward, _, _, info = env.step(2)
        _, plain_reward, _, _, plain_info = plain.step(0)
        assert info["invalid_action"] == has_task and plain_info["invalid_action"] is False
        assert reward == pytest.approx(plain_reward - (3.0 if has_task else 0.0))
        seen += has_task
    assert seen > 0
    env.close()
    plain.close()
