"""ZenohEdgeEnv: PettingZoo's own tests, transport agreement, overrides, rewards, failures.

The rules for actions have their own tests (test_env_actions.py), and so do the wrappers (test_env_wrappers.py).
"""

from __future__ import annotations

import os
import re

import numpy as np
import psutil
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, render_test
from pettingzoo.utils.conversions import parallel_to_aec

from env import NeighbourField, ScenarioOverrides, TaskField, ZenohEdgeEnv
from env.reward import paper_reward, sparse_reward
from orchestrator.clock import ProcessFailed
from tests.conftest import same, write_scenario

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


# ----- PettingZoo's own tests, with the defaults (only the episode is shortened), on both transports -----

TRANSPORTS = ["inproc", pytest.param("zenoh", marks=pytest.mark.zenoh)]


def default_env(transport: str, **kwargs) -> ZenohEdgeEnv:
    """``ZenohEdgeEnv()`` (aot1 over Zenoh) or its in-process twin, with a short episode."""
    if transport == "zenoh":
        return ZenohEdgeEnv(max_steps=12, **kwargs)
    return ZenohEdgeEnv(transport="inproc", max_steps=12, **kwargs)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_parallel_api_test_with_the_defaults(transport):
    env = default_env(transport)
    parallel_api_test(env, num_cycles=20)
    env.close()


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_parallel_seed_test_with_the_defaults(transport):
    """It samples from action_space(agent) without the mask: every such action must be accepted."""
    parallel_seed_test(lambda: default_env(transport))


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_aec_api_test_with_the_defaults(transport):
    env = parallel_to_aec(default_env(transport))
    api_test(env, num_cycles=20)
    env.close()


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_render_test_with_the_defaults(transport):
    render_test(lambda render_mode=None: parallel_to_aec(default_env(transport, render_mode=render_mode)))


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_unmasked_random_episode_with_the_defaults(transport):
    """A whole episode of actions sampled from the space alone: nothing raises, and with every
    neighbour a worker (aot1) no choice is masked, so nothing counts as invalid."""
    env = default_env(transport)
    env.reset(seed=3)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(i)
    while env.agents:
        _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert not any(info["invalid_action"] for info in infos.values())
    assert env.summary()["invalid_actions"]["total"] == 0
    assert infos[env.possible_agents[0]]["episode"]["invalid_actions"]["total"] == 0
    env.close()


@pytest.mark.parametrize("scenario", ["aot1", "n_tier"])
def test_parallel_api_inproc(scenario, request):
    source = request.getfixturevalue("n_tier") if scenario == "n_tier" else scenario
    env = ZenohEdgeEnv(source, transport="inproc", max_steps=60)
    parallel_api_test(env, num_cycles=80)
    env.close()


def test_parallel_api_batch_mode_and_uniform_spaces():
    env = ZenohEdgeEnv("aot1", transport="inproc", overrides=ScenarioOverrides(mode="batch", batch_size=3),
                       uniform_spaces=True, max_steps=40)
    agent = env.possible_agents[0]
    masks = env.observation_space(agent)["action_mask"]
    assert len(masks) == 3 and masks[0].shape == (1 + 11,)  # padded to the largest degree
    assert env.action_space(agent).nvec.tolist() == [12, 12, 12]
    parallel_api_test(env, num_cycles=50)
    env.close()


def test_neighbour_slots_pad_every_agent_to_k_and_are_checked():
    env = ZenohEdgeEnv("aot1", transport="inproc", neighbour_slots=15, max_steps=30)
    assert {str(env.action_space(a)) for a in env.possible_agents} == {"Discrete(16)"}  # largest degree: 11
    assert {env.observation_space(a)["neighbours"].shape for a in env.possible_agents} == {(15, len(NeighbourField))}
    parallel_api_test(env, num_cycles=40)
    env.close()
    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match="neighbour_slots must be an integer >= 1"):
            ZenohEdgeEnv("aot1", transport="inproc", neighbour_slots=bad)
    with pytest.raises(ValueError, match=r"neighbour_slots=10 is below the largest degree of an agent of aot1 \(11\)"):
        ZenohEdgeEnv("aot1", transport="inproc", neighbour_slots=10)


def test_render_modes_on_an_n_tier_network(n_tier):
    render_test(lambda render_mode=None: parallel_to_aec(
        ZenohEdgeEnv(n_tier, transport="inproc", render_mode=render_mode, max_steps=20)))


def test_ansi_render_shows_queues_and_decisions():
    env = ZenohEdgeEnv("aot1", transport="inproc", render_mode="ansi", max_steps=30)
    obs, _ = env.reset(seed=3)
    agent = "ctrl_rpi3_0"
    while not obs[agent]["task"][TaskField.PRESENT]:
        obs, *_ = env.step(dict.fromkeys(env.agents, 0))
    actions = dict.fromkeys(env.agents, 0)
    actions[agent] = 1  # to nuc_0
    env.step(actions)
    rows = {line.split()[0]: line for line in env.render().splitlines()[2:]}
    assert "occ/buf" in env.render() and "server_0" in rows
    assert rows["rpi3_0"].endswith("-> nuc_0")  # the last step's decision
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
    assert any(info["credits"] for step in got[1:] for info in step[4].values())  # the ledger crossed the bus
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


def test_observations_match_their_spaces_exactly():
    for mode in ("binary", "batch"):
        env = ZenohEdgeEnv("aot2", transport="inproc", overrides=ScenarioOverrides(mode=mode), max_steps=200)
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
    env = ZenohEdgeEnv("aot1", transport="inproc", overrides=ScenarioOverrides(decision_interval=3), max_steps=10)
    _, infos = env.reset(seed=0)
    assert infos[env.possible_agents[0]]["tick"] == 0
    _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
    assert infos[env.possible_agents[0]]["tick"] == 3
    env.close()


def test_overrides_change_the_scenario_and_keep_the_episode_length():
    base = ZenohEdgeEnv("aot2", transport="inproc").scenario
    sc = ZenohEdgeEnv("aot2", transport="inproc", overrides=ScenarioOverrides(
        mode="batch", decision_interval=2, batch_size=5, arrival_rate=0.4)).scenario
    assert (sc.mode, sc.decision_interval, sc.batch_size) == ("batch", 2, 5)
    assert sc.steps == base.steps and sc.episode_ticks == sc.steps * sc.decision_interval
    assert sc.workload.arrival.kind == "constant" and sc.workload.arrival.rate == 0.4
    assert ZenohEdgeEnv("aot2", transport="inproc", overrides=ScenarioOverrides()).scenario == base


def test_an_arrival_rate_override_keeps_the_scenarios_arrival_process():
    sc = ZenohEdgeEnv("aot2_reference", transport="inproc", overrides=ScenarioOverrides(arrival_rate=0.3)).scenario
    assert (sc.workload.arrival.rate, sc.workload.arrival.process) == (0.3, "exponential_gaps")


@pytest.mark.parametrize("kwargs,message", [
    ({"mode": "batched"}, "mode must be 'binary' or 'batch', not 'batched'"),
    ({"decision_interval": 0}, "decision_interval must be an integer >= 1, not 0"),
    ({"batch_size": 2.5}, "batch_size must be an integer >= 1, not 2.5"),
    ({"arrival_rate": -1.0}, r"arrival_rate must be a number >= 0 \(tasks/s per source\), not -1.0"),
])
def test_bad_overrides_say_what_was_expected(kwargs, message):
    with pytest.raises(ValueError, match=f"^ScenarioOverrides: {message}$"):
        ScenarioOverrides(**kwargs)


def test_bad_environment_arguments_say_what_was_expected():
    with pytest.raises(TypeError, match=r"^overrides must be a ScenarioOverrides, not a dict$"):
        ZenohEdgeEnv("aot1", transport="inproc", overrides={"mode": "batch"})
    with pytest.raises(ValueError, match=r"^max_steps must be an integer >= 1, not 0$"):
        ZenohEdgeEnv("aot1", transport="inproc", max_steps=0)
    with pytest.raises(ValueError, match=r"^max_steps=2147483649: expected at most 2\^31 \(2147483648\) ticks an "
                                         r"episode, but 2147483649 steps of 1 tick\(s\) are 2147483649$"):
        ZenohEdgeEnv("aot1", transport="inproc", max_steps=2**31 + 1)  # it ran for ever
    with pytest.raises(ValueError, match=r"^invalid_action must be 'local' .* or 'raise', not 'penalty'$"):
        ZenohEdgeEnv("aot1", transport="inproc", invalid_action="penalty")
    # at construction, not at the first reset
    with pytest.raises(ValueError, match=r"^transport must be 'zenoh' or 'inproc', not 'tcp'$"):
        ZenohEdgeEnv("aot1", transport="tcp")
    with pytest.raises(ValueError, match=r"^unknown layout 'per-x': expected per-role, per-node, single or groups:K"):
        ZenohEdgeEnv("aot1", transport="inproc", layout="per-x")
    with pytest.raises(ValueError, match=r"^connect= needs sim_id="):
        ZenohEdgeEnv(connect="tcp/127.0.0.1:7447")


def test_the_arguments_are_sorted_into_settings_checked_before_the_scenario_is_read():
    """Each group of settings checks its own arguments as it is made: a bad one is refused before the scenario
    file is even looked for, and the good ones land in their group."""
    from env.reward import PaperWeights, RewardSettings

    with pytest.raises(ValueError, match=r"^congestion_price must be a finite number >= 0, not nan$"):
        ZenohEdgeEnv("no/such/scenario.yaml", transport="inproc", congestion_price=float("nan"))
    weights = PaperWeights(utility=3.0)
    env = ZenohEdgeEnv("aot1", transport="inproc", layout="groups:2", max_steps=7, agents=["rpi3_0"], seed=4,
                       observation="flat", info_numbers=False, reward_weights=weights, congestion_price=1)
    assert (env.episode.max_steps, env.episode.agents, env.episode.seed) == (7, ("rpi3_0",), 4)
    assert (env.flat, env.observing.info_numbers, env.observing.uniform_spaces) == (True, False, False)
    assert (env.connection.transport, env.connection.layout, env.connection.connect) == ("inproc", "groups:2", None)
    assert env.reward_settings == RewardSettings(weights=weights, congestion_price=1.0)
    assert env.credit.settings is env.reward_settings  # one object, held once
    assert ZenohEdgeEnv("aot1", transport="inproc").reward_settings == RewardSettings()


@pytest.mark.parametrize("seed", [-1, 1.5, True, "3", 2**62])
def test_a_seed_that_is_no_non_negative_62_bit_integer_is_refused_by_reset(seed):
    """A seed travels in the reset tick as a msgpack integer: 2^70 crashed the clock over Zenoh."""
    env = ZenohEdgeEnv("aot1", transport="inproc")
    with pytest.raises(ValueError, match=rf"^reset\(seed={re.escape(repr(seed))}\): expected an integer from 0 to "):
        env.reset(seed=seed)
    env.reset(seed=2**62 - 1)  # the largest
    env.close()
    with pytest.raises(ValueError, match=rf"^ZenohEdgeEnv\(seed={re.escape(repr(seed))}\): expected an integer"):
        ZenohEdgeEnv("aot1", transport="inproc", seed=seed)


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
    assert episode["invalid_actions"] == {"total": 0, "by_agent": dict.fromkeys(env.possible_agents, 0)}
    env.close()


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
