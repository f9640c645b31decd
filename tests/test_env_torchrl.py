"""TorchRL over observation="flat": PettingZooWrapper with masks and one group, and K simulations in ParallelEnv."""

from __future__ import annotations

from functools import partial

import pytest
import torch

pytest.importorskip("torchrl")

from torchrl.envs import ParallelEnv, PettingZooWrapper

from env import ZenohEdgeEnv

STEPS = 6  # episode length: every rollout below crosses at least one episode end


def torchrl_env(transport: str = "inproc", seed: int | None = None) -> PettingZooWrapper:
    env = ZenohEdgeEnv("aot2", transport=transport, observation="flat", max_steps=STEPS, seed=seed)
    return PettingZooWrapper(env, use_mask=True, categorical_actions=True, group_map={"agents": env.possible_agents},
                             seed=seed)


def masked_random(td):
    """Uniform over the allowed actions, read from the tensordict: ParallelEnv's rand_action does not see
    its workers' masks."""
    mask = td["agents", "action_mask"]
    choice = torch.multinomial(mask.flatten(0, -2).float(), 1)
    td["agents", "action"] = choice.view(mask.shape[:-1])
    return td


def check_rollout(td, n_agents: int) -> None:
    """Masked random actions over two episodes and a bit: dones where due, ticks restart, no masked choice."""
    steps = td.batch_size[-1]
    assert td["agents", "observation", "observation"].shape[-2] == n_agents
    done = td["next", "done"].squeeze(-1)
    due = (torch.arange(steps) + 1) % STEPS == 0
    assert torch.equal(done, due.expand_as(done))
    ticks = td["next", "agents", "info", "tick"][..., 0]
    assert torch.equal(ticks, ((torch.arange(steps) % STEPS) + 1).float().expand_as(ticks))
    mask, action = td["agents", "action_mask"], td["agents", "action"]
    assert mask.gather(-1, action.unsqueeze(-1)).all()  # every action its mask allowed
    assert (td["next", "agents", "info", "invalid_action"] == 0).all()
    assert torch.isfinite(td["next", "agents", "reward"]).all()


@pytest.mark.parametrize("transport", ["inproc", pytest.param("zenoh", marks=pytest.mark.zenoh)])
def test_pettingzoo_wrapper_with_masks_and_one_group_crosses_episode_ends(transport):
    env = torchrl_env(transport, seed=3)
    n = len(env.group_map["agents"])
    assert list(env.group_map) == ["agents"]
    assert env.full_observation_spec["agents", "action_mask"].shape == (n, env.action_spec["agents", "action"].space.n)
    td = env.rollout(2 * STEPS + 2, break_when_any_done=False)
    check_rollout(td, n)
    env.close()


def test_parallel_env_of_two_simulations_steps_and_resets():
    """K = 2 in-process simulations, each in its own worker process, stepped together."""
    env = ParallelEnv(2, partial(torchrl_env, "inproc"))
    env.set_seed(7)
    n = len(ZenohEdgeEnv("aot2", transport="inproc").possible_agents)
    td = env.rollout(2 * STEPS + 2, masked_random, break_when_any_done=False)
    assert td.batch_size == (2, 2 * STEPS + 2)
    check_rollout(td, n)
    generated = td["next", "agents", "info", "node_generated"][:, STEPS - 1].sum(-1)
    assert generated[0] != generated[1]  # the workers got different seeds
    env.close()


def test_without_info_numbers_the_wrapper_steps_with_no_info_keys():
    base = ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=STEPS, info_numbers=False)
    env = PettingZooWrapper(base, use_mask=True, categorical_actions=True, group_map={"agents": base.possible_agents})
    td = env.rollout(2 * STEPS + 2, break_when_any_done=False)
    assert ("agents", "info") not in td["next"].keys(include_nested=True)
    done = td["next", "done"].squeeze(-1)
    assert torch.equal(done, (torch.arange(2 * STEPS + 2) + 1) % STEPS == 0)
    assert td["agents", "action_mask"].gather(-1, td["agents", "action"].unsqueeze(-1)).all()
    env.close()
