"""observation="flat": one vector and one mask shape for every agent, numbers-only infos, full detail aside."""

from __future__ import annotations

import numbers

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from env import NeighbourField, OwnField, ScenarioOverrides, TaskField, ZenohEdgeEnv
from tests.test_env import masked_random

TRANSPORTS = ["inproc", pytest.param("zenoh", marks=pytest.mark.zenoh)]


def flat_env(transport: str = "inproc", **kwargs) -> ZenohEdgeEnv:
    if transport == "zenoh":
        return ZenohEdgeEnv("aot2", observation="flat", max_steps=12, **kwargs)
    return ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=12, **kwargs)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_parallel_api_test_in_flat_mode(transport):
    env = flat_env(transport)
    parallel_api_test(env, num_cycles=20)
    env.close()


def test_every_agent_has_the_same_flat_spaces_with_its_id_one_hot():
    env = flat_env()
    spaces = {a: env.observation_space(a) for a in env.possible_agents}
    assert all(set(s.spaces) == {"observation", "action_mask"} for s in spaces.values())
    n = len(env.possible_agents)
    slots = max(len(env.scenario.neighbours[node]) for node in env.node_of.values())
    width = len(OwnField) + len(TaskField) + len(NeighbourField) * slots + n
    assert {s["observation"].shape for s in spaces.values()} == {(width,)}
    assert {s["action_mask"].shape for s in spaces.values()} == {(1 + slots,)}
    assert {env.action_space(a).n for a in env.possible_agents} == {1 + slots}
    obs, _ = env.reset(seed=1)
    for i, agent in enumerate(env.possible_agents):
        ids = obs[agent]["observation"][env.builders[agent].slices["agent_id"]]
        assert ids.tolist() == np.eye(n)[i].tolist()
    env.close()


def test_flat_observations_hold_the_dict_observations_numbers():
    """Same seed, same actions: the flat vector is the padded Dict observation, block by block."""
    flat, full = flat_env(), ZenohEdgeEnv("aot2", transport="inproc", uniform_spaces=True, max_steps=12)
    f_obs, _ = flat.reset(seed=4)
    d_obs, _ = full.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(12):
        for agent in flat.possible_agents:
            b = flat.builders[agent]
            assert np.array_equal(f_obs[agent]["observation"], b.flatten(d_obs[agent])["observation"])
            assert np.array_equal(f_obs[agent]["observation"][b.slices["neighbours"]],
                                  d_obs[agent]["neighbours"].ravel())
            assert np.array_equal(f_obs[agent]["action_mask"], d_obs[agent]["action_mask"])
        actions = masked_random(full, d_obs, rng)
        f_obs, *_ = flat.step(actions)
        d_obs, *_ = full.step(actions)
    flat.close()
    full.close()


def test_flat_infos_are_numbers_with_the_same_keys_and_the_details_stay_reachable():
    env = flat_env()
    obs, infos = env.reset(seed=2)
    keys = {a: set(i) for a, i in infos.items()}
    rng = np.random.default_rng(1)
    while env.agents:
        obs, _, _, _, infos = env.step(masked_random(env, obs, rng))
        assert {a: set(i) for a, i in infos.items()} == keys
        assert all(isinstance(v, numbers.Number | bool) for i in infos.values() for v in i.values())
        details = env.step_details[env.possible_agents[0]]
        assert {"node", "reward_terms", "invalid_action"} <= set(details)
        assert infos[env.possible_agents[0]]["node_completed"] == details["node"]["completed"]
    assert "episode" in env.step_details[env.possible_agents[0]]
    assert env.summary()["totals"]["generated"] > 0
    env.close()


def test_batch_mode_flat_masks_are_one_array():
    """(B, 1 + D): gymnasium's MultiDiscrete.sample takes it as tuple(mask)."""
    env = ZenohEdgeEnv("aot1", transport="inproc", observation="flat", max_steps=10,
                       overrides=ScenarioOverrides(mode="batch", batch_size=3))
    agent = env.possible_agents[0]
    assert env.observation_space(agent)["action_mask"].shape == (3, 12)
    width = len(OwnField) + 3 * len(TaskField) + 11 * len(NeighbourField) + 10
    assert env.observation_space(agent)["observation"].shape == (width,)
    obs, _ = env.reset(seed=5)
    while env.agents:
        assert all(env.observation_space(a).contains(o) for a, o in obs.items())
        actions = {a: env.action_space(a).sample(tuple(obs[a]["action_mask"])) for a in env.agents}
        obs, _, _, _, infos = env.step(actions)
        assert not any(i["invalid_action"] for i in infos.values())
    env.close()


def test_info_numbers_false_leaves_the_infos_empty_and_the_details_reachable():
    """For libraries that make a tensor of every info number each step; the run itself is unchanged."""
    lean, full = flat_env(info_numbers=False), flat_env()
    obs, infos = lean.reset(seed=2)
    f_obs, _ = full.reset(seed=2)
    assert infos == {a: {} for a in lean.possible_agents}
    rng = np.random.default_rng(1)
    while lean.agents:
        actions = masked_random(lean, obs, rng)
        obs, rewards, _, _, infos = lean.step(actions)
        f_obs, f_rewards, _, _, f_infos = full.step(actions)
        assert infos == {a: {} for a in actions}
        assert rewards == f_rewards
        assert all(np.array_equal(obs[a]["observation"], f_obs[a]["observation"]) for a in obs)
        details = lean.step_details[lean.possible_agents[0]]
        assert f_infos[lean.possible_agents[0]]["node_completed"] == details["node"]["completed"]
    assert lean.summary()["totals"] == full.summary()["totals"]
    lean.close()
    full.close()
    with pytest.raises(ValueError, match='info_numbers=False applies to observation="flat" only'):
        ZenohEdgeEnv("aot2", transport="inproc", info_numbers=False)
