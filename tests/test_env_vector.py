"""ZenohEdgeVectorEnv: K simulations as one TorchRL batch, each one exactly a ZenohEdgeEnv of its seed."""

from __future__ import annotations

import re
from functools import partial

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl")

from torchrl.envs import ParallelEnv, PettingZooWrapper
from torchrl.envs.utils import check_env_specs

from env import ScenarioOverrides, ZenohEdgeEnv
from env.vector import ZenohEdgeVectorEnv
from tests.conftest import ROOT
from tests.test_env_torchrl import STEPS, check_rollout, masked_random


def test_specs_match_the_pettingzoo_wrapper_with_a_leading_batch_axis():
    env = ZenohEdgeVectorEnv("aot2", num_envs=3, max_steps=STEPS)
    check_env_specs(env)  # TorchRL's own check: a rollout's keys, shapes and dtypes match the specs
    base = ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=STEPS)
    wrapper = PettingZooWrapper(base, use_mask=True, categorical_actions=True,
                                group_map={"agents": base.possible_agents})
    for name in ("full_observation_spec", "full_action_spec", "full_reward_spec", "full_done_spec"):
        ours, theirs = getattr(env, name), getattr(wrapper, name)
        assert set(ours.keys(True, True)) == set(theirs.keys(True, True)), name
        for key in theirs.keys(True, True):
            assert ours[key].shape == (3, *theirs[key].shape), (name, key)
            assert ours[key].dtype == theirs[key].dtype, (name, key)
    env.close()
    wrapper.close()


def test_each_simulation_is_the_single_env_of_its_seed_across_episode_ends():
    """Simulation k, seeded s + k, gives what ZenohEdgeEnv(seed=s + k) gives for the same actions."""
    k, seed = 3, 11
    env = ZenohEdgeVectorEnv("aot2", num_envs=k, max_steps=STEPS, reward="team_score")
    env.set_seed(seed)
    td = env.rollout(2 * STEPS + 2, masked_random, break_when_any_done=False)
    assert td.batch_size == (k, 2 * STEPS + 2)
    check_rollout(td, len(env.agent_names))
    for i in range(k):
        single = ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=STEPS, reward="team_score")
        observations, infos = single.reset(seed=seed + i)
        for t in range(td.batch_size[1]):
            row = td[i, t]
            assert np.array_equal(_stacked(observations, "observation"), row["agents", "observation", "observation"])
            assert np.array_equal(_stacked(observations, "action_mask"), row["agents", "action_mask"])
            actions = dict(zip(single.possible_agents, row["agents", "action"].tolist(), strict=True))
            observations, rewards, _, truncations, infos = single.step(actions)
            after = row["next", "agents"]
            assert np.allclose([rewards[a] for a in single.possible_agents], after["reward"].squeeze(-1))
            for key in ("node_completed", "node_generated", "tick"):
                assert np.array_equal([infos[a][key] for a in single.possible_agents], after["info", key]), key
            assert bool(row["next", "done"]) == truncations[single.possible_agents[0]]
            if not single.agents:
                observations, infos = single.reset()
        single.close()
    env.close()


def test_a_seed_argument_seeds_simulation_k_with_seed_plus_k():
    env = ZenohEdgeVectorEnv("aot2", num_envs=2, max_steps=STEPS, seed=5)
    first = env.reset()["agents", "observation", "observation"]
    for k in range(2):
        single = ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=STEPS)
        observations, _ = single.reset(seed=5 + k)
        assert np.array_equal(_stacked(observations, "observation"), first[k])
        single.close()
    unseeded = [ZenohEdgeVectorEnv("aot2", num_envs=1, max_steps=STEPS) for _ in range(2)]
    a, b = (e.rollout(STEPS, masked_random)["next", "agents", "info", "node_generated"] for e in unseeded)
    assert not torch.equal(a, b)  # fresh entropy, not a fixed seed
    env.close()


def test_a_partial_reset_restarts_only_the_flagged_simulations():
    """TorchRL resets the simulations that "_reset" flags, from the current step's data (as rollouts do)."""
    env = ZenohEdgeVectorEnv("aot2", num_envs=3, max_steps=STEPS)
    env.set_seed(0)
    td = env.rollout(3, masked_random)
    current = env.step_mdp(td[:, -1])
    current["_reset"] = torch.tensor([[False], [True], [False]])
    current = env.reset(current)
    assert current["agents", "info", "tick"][:, 0].tolist() == [3.0, 0.0, 3.0]
    after = env.step(masked_random(current))["next"]
    assert after["agents", "info", "tick"][:, 0].tolist() == [4.0, 1.0, 4.0]  # the others went on
    env.close()


def test_batch_mode_places_b_tasks_per_agent_and_step():
    batch = ScenarioOverrides(mode="batch", batch_size=3, arrival_rate=0.6)
    check_env_specs(ZenohEdgeVectorEnv("aot2", num_envs=2, max_steps=STEPS, overrides=batch))  # spec-random actions
    env = ZenohEdgeVectorEnv("aot2", num_envs=2, max_steps=STEPS, invalid_action="raise", overrides=batch)
    td = env.rollout(STEPS + 2, masked_random, break_when_any_done=False)
    mask, action = td["agents", "action_mask"], td["agents", "action"]
    assert action.shape == (2, STEPS + 2, len(env.agent_names), 3) and mask.shape == (*action.shape, 19)
    assert mask.gather(-1, action.unsqueeze(-1)).all()  # invalid_action="raise": the env checked them too
    assert (action > 0).any()  # some tasks were offloaded
    env.close()


def test_without_info_numbers_there_are_no_info_keys():
    env = ZenohEdgeVectorEnv("aot2", num_envs=2, max_steps=STEPS, info_numbers=False)
    td = env.rollout(STEPS + 1, masked_random, break_when_any_done=False)
    assert ("agents", "info") not in td["next"].keys(include_nested=True)
    assert td["next", "done"].squeeze(-1)[:, STEPS - 1].all()
    env.close()


def test_parallel_env_of_vector_envs_steps_four_simulations_on_two_workers():
    env = ParallelEnv(2, partial(ZenohEdgeVectorEnv, "aot2", num_envs=2, max_steps=STEPS))
    env.set_seed(5)
    td = env.rollout(2 * STEPS + 2, masked_random, break_when_any_done=False)
    assert td.batch_size == (2, 2, 2 * STEPS + 2)
    check_rollout(td, td["agents", "action"].shape[-1])
    generated = td["next", "agents", "info", "node_generated"][..., STEPS - 1, :].sum(-1).flatten()
    assert len(set(generated.tolist())) > 1  # the four simulations run different episodes
    env.close()


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"num_envs": 0}, ValueError, "num_envs must be an integer >= 1"),
    ({"num_envs": 2.0}, ValueError, "num_envs must be an integer >= 1"),
    ({"observation": "flat"}, TypeError, "observation= cannot be given"),
    ({"transport": "zenoh"}, TypeError, "transport= cannot be given"),
    ({"connect": "tcp/127.0.0.1:7447"}, TypeError, "connect= cannot be given"),
])
def test_bad_arguments_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        ZenohEdgeVectorEnv("aot2", **kwargs)


def _stacked(observations: dict, key: str) -> np.ndarray:
    return np.stack([obs[key] for obs in observations.values()])  # in the agents' order


def test_the_docs_snippet_runs():
    """docs/env.md's first vector-env example, shortened: its shape comment holds."""
    text = (ROOT / "docs" / "env.md").read_text()
    section = text[text.index("### K simulations stepped together"):]
    snippet = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    assert "(4, 1000, 15, 209)" in snippet
    namespace: dict = {}
    exec(snippet.replace("rollout(1000", "rollout(20").replace("max_steps=300", "max_steps=8"), namespace)
    assert namespace["td"]["agents", "observation", "observation"].shape == (4, 20, 15, 209)
