"""The reward wrappers: what they add, that they add nothing else, and that the PettingZoo API passes through."""

from __future__ import annotations

import pytest
from pettingzoo.test import parallel_api_test

from env import InvalidActionPenalty, OwnField, PotentialShaping, ZenohEdgeEnv
from tests.conftest import same


def occupancy_potential(obs) -> float:
    return -float(obs["own"][OwnField.OCCUPANCY])  # fewer tasks in the buffer is better


def test_invalid_action_penalty_adds_the_penalty_to_invalid_actions_only():
    """rpi3_0 has 2 neighbours padded to 11 slots: action 7 is a padding slot, masked when a task is there."""
    plain = ZenohEdgeEnv("aot1", transport="inproc", uniform_spaces=True, max_steps=60)
    wrapped = InvalidActionPenalty(ZenohEdgeEnv("aot1", transport="inproc", uniform_spaces=True, max_steps=60),
                                   penalty=-7.0)
    obs, _ = plain.reset(seed=2)
    wrapped.reset(seed=2)
    agent = "ctrl_rpi3_0"
    penalised = ignored = 0
    while plain.agents:
        actions = dict.fromkeys(plain.agents, 0) | {agent: 7}
        obs, rewards, _, _, infos = plain.step(actions)
        got_obs, got_rewards, _, _, got_infos = wrapped.step(actions)
        assert same(got_obs, obs) and same(got_infos, infos)
        for a, r in rewards.items():
            assert got_rewards[a] == pytest.approx(r + (-7.0 if infos[a]["invalid_action"] else 0.0))
        penalised += infos[agent]["invalid_action"]
        ignored += not infos[agent]["invalid_action"]
    assert penalised > 0 and ignored > 0  # no task, no penalty
    assert wrapped.summary()["invalid_actions"]["by_agent"][agent] == penalised
    plain.close()
    wrapped.close()


def test_potential_shaping_adds_gamma_times_the_next_potential_minus_the_last():
    plain = ZenohEdgeEnv("aot1", transport="inproc", reward="sparse", max_steps=40)
    shaped = PotentialShaping(ZenohEdgeEnv("aot1", transport="inproc", reward="sparse", max_steps=40),
                              occupancy_potential, gamma=0.9)
    plain.reset(seed=8)
    obs_s, _ = shaped.reset(seed=8)
    changed = 0
    while plain.agents:
        actions = dict.fromkeys(plain.agents, 0)
        _, r_p, *_ = plain.step(actions)
        next_s, r_s, *_ = shaped.step(actions)
        for agent in plain.possible_agents:
            expected = r_p[agent] + 0.9 * occupancy_potential(next_s[agent]) - occupancy_potential(obs_s[agent])
            assert r_s[agent] == pytest.approx(expected)
            changed += r_s[agent] != r_p[agent]
        obs_s = next_s
    assert changed > 0
    plain.close()
    shaped.close()


def test_wrapped_environment_keeps_the_pettingzoo_api_and_the_environments_attributes():
    env = PotentialShaping(InvalidActionPenalty(ZenohEdgeEnv("aot1", transport="inproc", uniform_spaces=True,
                                                             max_steps=15)), occupancy_potential)
    parallel_api_test(env, num_cycles=20)
    assert env.max_steps == 15 and env.unwrapped.scenario.name == "aot1"
    env.reset(seed=1)
    while env.agents:
        env.step({a: env.action_space(a).sample() for a in env.agents})
    assert env.summary()["ticks"] == 16
    env.close()
