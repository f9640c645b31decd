"""ZenohEdgeEnv: PettingZoo's own tests, transport agreement, masks, rewards, failures."""

from __future__ import annotations

import os

import numpy as np
import psutil
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, render_test
from pettingzoo.utils.conversions import parallel_to_aec

from env import InvalidActionError, ZenohEdgeEnv
from env.reward import paper_reward, sparse_reward
from orchestrator.clock import ProcessFailed
from tests.conftest import write_scenario

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

N_TIER = {"topology": {"generator": {"kind": "n_tier", "tiers": [6, 3, 1], "profiles": ["tier0", "tier1", "tier2"],
                                     "cloud": "tier2"}},
          "workload": {"arrival": {"rate": 0.3}}}


def masked_random(env, obs, rng):
    actions = {}
    for agent in env.agents:
        mask = obs[agent]["action_mask"]
        if isinstance(mask, np.ndarray):
            actions[agent] = int(rng.choice(np.flatnonzero(mask)))
        else:  # batch mode: one mask per task slot
            actions[agent] = [int(rng.choice(np.flatnonzero(row))) for row in mask]
    return actions


@pytest.fixture
def n_tier(tmp_path):
    return write_scenario(tmp_path, N_TIER)


@pytest.mark.parametrize("scenario", ["aot1", "n_tier"])
def test_parallel_api_inproc(scenario, request):
    source = request.getfixturevalue("n_tier") if scenario == "n_tier" else scenario
    env = ZenohEdgeEnv(source, transport="inproc", max_steps=60)
    parallel_api_test(env, num_cycles=80)
    env.close()


def test_parallel_api_batch_mode_and_uniform_spaces():
    env = ZenohEdgeEnv("aot1", transport="inproc", mode="batch", batch_size=3, uniform_spaces=True, max_steps=40)
    agent = env.possible_agents[0]
    masks = env.observation_space(agent)["action_mask"]
    assert len(masks) == 3 and masks[0].shape == (1 + 11,)  # padded to the largest degree
    assert env.action_space(agent).nvec.tolist() == [12, 12, 12]
    parallel_api_test(env, num_cycles=50)
    env.close()


def test_aec_conversion_api_test():
    env = parallel_to_aec(ZenohEdgeEnv("aot1", transport="inproc", max_steps=30))
    api_test(env, num_cycles=40)
    env.close()


def test_seed_test_inproc():
    parallel_seed_test(lambda: ZenohEdgeEnv("aot1", transport="inproc", invalid_action="penalty", max_steps=50))


def test_render_modes(n_tier):
    for source in ("aot1", n_tier):
        render_test(lambda render_mode=None, s=source: parallel_to_aec(
            ZenohEdgeEnv(s, transport="inproc", render_mode=render_mode, max_steps=20)))


def test_ansi_render_shows_queues_and_decisions():
    env = ZenohEdgeEnv("aot1", transport="inproc", render_mode="ansi", max_steps=30)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(10):
        obs, *_ = env.step(masked_random(env, obs, rng))
    text = env.render()
    assert "rpi3_0" in text and "server_0" in text and "occ/buf" in text
    env.close()


def run_episode(env, seed, actions_rng_seed, steps):
    obs, infos = env.reset(seed=seed)
    rng = np.random.default_rng(actions_rng_seed)
    trace = [(obs, infos)]
    for _ in range(steps):
        actions = masked_random(env, obs, rng)
        obs, rewards, _, trunc, infos = env.step(actions)
        trace.append((actions, obs, rewards, trunc, infos))
    return trace


def same(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    return a == b


@pytest.mark.zenoh
@pytest.mark.parametrize("layout", ["per-role", "per-node"])
def test_zenoh_and_inproc_give_identical_episodes(layout):
    steps = 120
    ref_env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=steps)
    ref = run_episode(ref_env, seed=5, actions_rng_seed=9, steps=steps)
    ref_env.close()
    env = ZenohEdgeEnv("aot1", transport="zenoh", layout=layout, max_steps=steps)
    got = run_episode(env, seed=5, actions_rng_seed=9, steps=steps)
    env.close()
    assert got[-1][3] == dict.fromkeys(got[-1][3], True)  # truncated at the end
    for i, (a, b) in enumerate(zip(ref, got, strict=True)):
        assert same(a, b), f"step {i} differs"


@pytest.mark.zenoh
def test_default_env_over_zenoh_and_reset_keeps_processes():
    env = ZenohEdgeEnv()  # aot1 over Zenoh, one process per role
    obs, _ = env.reset(seed=0)
    assert set(obs) == set(env.possible_agents) and len(env.possible_agents) == 10
    pids = sorted(env.sim.supervisor.pids)
    rng = np.random.default_rng(1)
    for _ in range(5):
        obs, *_ = env.step(masked_random(env, obs, rng))
    env.reset(seed=1)
    assert sorted(env.sim.supervisor.pids) == pids  # a new episode, the same processes
    assert all(psutil.pid_exists(p) for p in pids)
    env.close()
    _, alive = psutil.wait_procs([psutil.Process(p) for p in pids if psutil.pid_exists(p)], timeout=10)
    assert not alive


def test_masked_action_raises_a_clear_error():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=100)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(100):  # until some agent has a task to place
        agent = next((a for a in env.agents if obs[a]["task"][0] == 1), None)
        if agent is not None:
            break
        obs, *_ = env.step(masked_random(env, obs, rng))
    assert agent is not None
    actions = masked_random(env, obs, rng)
    actions[agent] = env.action_space(agent).n  # out of range
    with pytest.raises(InvalidActionError, match=rf"{agent}: action \d+ is masked; allowed now: 0 \(local\)"):
        env.step(actions)
    env.close()


def test_penalty_mode_replaces_masked_action_with_local():
    env = ZenohEdgeEnv("aot1", transport="inproc", invalid_action="penalty", invalid_penalty=-7.0, reward="sparse",
                       max_steps=50)
    obs, _ = env.reset(seed=2)
    agent = env.possible_agents[0]
    # with no task the mask allows only 0: anything else is penalised
    assert obs[agent]["task"][0] == 0 and obs[agent]["action_mask"].tolist() == [1, 0, 0]
    actions = dict.fromkeys(env.agents, 0)
    actions[agent] = 2
    _, rewards, _, _, infos = env.step(actions)
    assert infos[agent]["invalid_action"] is True
    assert rewards[agent] == pytest.approx(-7.0)
    env.close()


def test_observations_match_their_spaces_exactly():
    for mode in ("binary", "batch"):
        env = ZenohEdgeEnv("aot2", transport="inproc", mode=mode, max_steps=200)
        obs, _ = env.reset(seed=4)
        rng = np.random.default_rng(4)
        for _ in range(200):
            for agent in env.agents:
                space = env.observation_space(agent)
                for key, value in obs[agent].items():
                    sub = space[key]
                    pairs = zip(value, sub, strict=True) if isinstance(value, tuple) else [(value, sub)]
                    for v, s in pairs:
                        assert v.shape == s.shape and v.dtype == s.dtype, (agent, key)
                assert space.contains(obs[agent]), agent
            obs, *_ = env.step(masked_random(env, obs, rng))
        env.close()


def test_decision_interval_advances_several_ticks():
    env = ZenohEdgeEnv("aot1", transport="inproc", decision_interval=3, max_steps=10)
    _, infos = env.reset(seed=0)
    assert infos[env.possible_agents[0]]["tick"] == 0
    _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
    assert infos[env.possible_agents[0]]["tick"] == 3
    env.close()


def test_truncation_and_episode_summary():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=25)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for step in range(25):
        obs, _, term, trunc, infos = env.step(masked_random(env, obs, rng))
        assert not any(term.values())
        assert all(trunc.values()) == (step == 24)
    assert env.agents == []
    episode = infos[env.possible_agents[0]]["episode"]
    assert episode["ticks"] == 26 and "run" not in episode  # the reset tick, then 25 epochs of one tick
    t = episode["totals"]
    assert t["generated"] == t["completed"] + t["dropped"]["total"] + t["in_system"]
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    env.close()


def test_sparse_reward_and_potential_shaping():
    def potential(obs):
        return -float(obs["own"][1])  # fewer tasks in the buffer is better

    plain = ZenohEdgeEnv("aot1", transport="inproc", reward="sparse", max_steps=40)
    shaped = ZenohEdgeEnv("aot1", transport="inproc", reward="sparse", shaping=potential, gamma=0.9, max_steps=40)
    plain.reset(seed=8)
    obs_s, _ = shaped.reset(seed=8)
    for _ in range(40):
        actions = dict.fromkeys(plain.agents, 0)
        _, r_p, *_ = plain.step(actions)
        next_s, r_s, _, _, infos = shaped.step(actions)
        for agent in plain.possible_agents:
            expected = r_p[agent] + 0.9 * potential(next_s[agent]) - potential(obs_s[agent])
            assert r_s[agent] == pytest.approx(expected)
            node = infos[agent]["node"]
            assert node["completed"] >= 0 and node["dropped"] >= 0
        obs_s = next_s
    plain.close()
    shaped.close()


def test_custom_reward_callable_sees_the_context():
    seen = []

    def reward(ctx):
        seen.append(ctx)
        return paper_reward(ctx) + sparse_reward(ctx)

    env = ZenohEdgeEnv("aot1", transport="inproc", reward=reward, max_steps=20)
    env.reset(seed=1)
    for _ in range(20):
        env.step(dict.fromkeys(env.agents, 0))
    assert len(seen) == 20 * len(env.possible_agents)
    with_tasks = [c for c in seen if c.terms]
    assert with_tasks and all(c.obs is not None and c.obs.tasks for c in with_tasks)
    env.close()


def test_agents_subset_leaves_other_controllers_to_their_policy():
    env = ZenohEdgeEnv("aot1", transport="inproc", agents=["nuc_0", "server_0"], max_steps=10)
    assert env.possible_agents == ["ctrl_nuc_0", "ctrl_server_0"]
    env.reset(seed=0, options={"policy": "least_queue"})
    for _ in range(10):
        env.step(dict.fromkeys(env.agents, 0))
    assert env.summary()["totals"]["decisions"] > 0  # the rpi3 controllers decided on their own
    env.close()
    with pytest.raises(ValueError, match="not controllers of aot1: tx2_0"):
        ZenohEdgeEnv("aot1", transport="inproc", agents=["tx2_0"])


@pytest.mark.zenoh
def test_node_death_during_steps_is_reported_with_its_name():
    env = ZenohEdgeEnv("aot1", transport="zenoh", layout="per-node", max_steps=100000)
    env.reset(seed=0)
    pids = list(env.sim.supervisor.pids)
    victim = next(p for p in pids if psutil.Process(p).name() == "zn-nuc_0")
    psutil.Process(victim).kill()
    with pytest.raises(ProcessFailed, match="nuc_0"):
        for _ in range(100000):
            env.step(dict.fromkeys(env.agents, 0))
    env.close()
    _, alive = psutil.wait_procs([psutil.Process(p) for p in pids if psutil.pid_exists(p)], timeout=10)
    assert not alive
