"""The paper reward (Eq. 1–5 as read in docs/reward.md), term by term, against hand computation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from env.reward import PaperWeights, paper_terms, reference_terms, shaped
from node_runtime.model.messages import TaskSize
from node_runtime.model.view import NodeView, Observation, TaskView
from node_runtime.model.workload import nominal_arrivals

# An rpi3-like node (1 core at 4e6 cycles/s, buffer 3, holding 3 tasks of which 2 queued) next to a
# nuc-like one (3.2e7 cycles/s, buffer 54, 5 tasks queued) over a 30 Mbit/s link.
OWN = NodeView("a", queue=2, occupancy=3, buffer=3, capacity=4e6, tier=0, rate_bps=0.0, age=1, worker=True)
NUC = NodeView("b", queue=5, occupancy=5, buffer=54, capacity=3.2e7, tier=1, rate_bps=3e7, age=1, worker=True)
TASK = TaskView(1, TaskSize(instructions=8e7, input_bytes=1e7, output_bytes=5e6, cpi=1.0, deadline=100.0),
                time_left=97.0, waited=1, origin="a")
OBS = Observation(10, "a", OWN, 1, [TASK], [NUC])


def test_keeping_the_task_local():
    t = paper_terms(OBS, TASK, 0, dt=1.0)
    assert t.t_wait == pytest.approx(40.0)  # 2 queued * 8e7 cycles / 4e6 cycles/s
    assert t.t_comm == 0.0
    assert t.t_exc == 0.0
    assert t.delay == pytest.approx(800.0)  # 20 * 40
    # Q = 3 - 1 (the task itself) = 2; phi = 4e6 / 8e7 = 0.05 tasks per tick; Q' = min(2 - 0.05 + 1, 3) = 2.95
    # p = (3 - 2.95) / 3 = 0.016667; O = -ln(p) / 3 = 1.364781
    assert t.overload == pytest.approx(-math.log(0.05 / 3) / 3)
    assert t.overload == pytest.approx(1.3647815, rel=1e-6)
    assert t.reward == pytest.approx(2 - (800 + 150 * 1.3647815), rel=1e-7)  # -1002.717


def test_offloading_to_a_faster_neighbour():
    t = paper_terms(OBS, TASK, 1, dt=1.0)
    assert t.t_wait == pytest.approx(12.5)  # 5 * 8e7 / 3.2e7
    assert t.t_comm == pytest.approx(4.0)  # 8 * (1e7 + 5e6) bits / 3e7 bit/s
    assert t.t_exc == pytest.approx(-17.5)  # 8e7/3.2e7 - 8e7/4e6 = 2.5 - 20
    assert t.delay == pytest.approx(-20.0)  # 20 * (12.5 + 4 - 17.5)
    # Q = 5; phi = 3.2e7 / 8e7 = 0.4; Q' = 5.6; p = (54 - 5.6) / 54 = 0.896296; O = 0.0364947
    assert t.overload == pytest.approx(0.0364947, rel=1e-5)
    assert t.reward == pytest.approx(2 - (-20 + 150 * 0.0364947), rel=1e-5)  # 16.526


def test_a_full_target_hits_the_floor():
    full = NodeView("b", queue=54, occupancy=54, buffer=54, capacity=3.2e7, tier=1, rate_bps=3e7, age=1, worker=True)
    t = paper_terms(Observation(10, "a", OWN, 1, [TASK], [full]), TASK, 1, dt=1.0)
    # Q' = min(54 - 0.4 + 1, 54) = 54 -> p = max(1e-3, 0) = 1e-3 -> O = -ln(1e-3) / 3 = 2.302585
    assert t.overload == pytest.approx(math.log(1000) / 3)


def test_weights_are_configurable():
    w = PaperWeights(utility=1.0, wait=1.0, comm=0.0, exc=0.0, overload=0.0)
    assert paper_terms(OBS, TASK, 1, dt=1.0, w=w).reward == pytest.approx(1.0 - 12.5)


def test_shaping_formula():
    assert shaped(1.0, potential_before=2.0, potential_after=3.0, gamma=0.5) == pytest.approx(1.0 + 1.5 - 2.0)


# ----- the reference implementation's reward (docs/reward.md, "The reference implementation") -----
# Same situation; nominal arrivals 0.5 task/s at a and 1 task/s at b. Default weights: U = 2, so the
# caps are U * chi = 40 s and the overload scale U * chi_O = 300.
ARRIVALS = {"a": 0.5, "b": 1.0}


def test_reference_keeping_the_task_local():
    t = reference_terms(OBS, TASK, 0, dt=1.0, arrivals=ARRIVALS)
    assert t.t_wait == pytest.approx(7.5e-7)  # 3 tasks / 4e6 cycles/s: the reference's units, near 0
    assert (t.t_comm, t.t_exc) == (0.0, 0.0)
    # Q' = 3 (the task is in the buffer already) + 0.5 arrivals - 4e6/8e7 = 3.45 -> capped at Qmax = 3
    # p = max(1e-3, 0) = 1e-3; O = -log10(1e-3) / 3 * 300 = 300
    assert t.overload == pytest.approx(300.0)
    assert t.reward == pytest.approx(2 - (7.5e-7 + 300))  # -298.00000075


def test_reference_offloading_to_a_faster_neighbour():
    t = reference_terms(OBS, TASK, 1, dt=1.0, arrivals=ARRIVALS)
    assert t.t_wait == pytest.approx(3 / 4e6 + 5 / 3.2e7)  # own queue, then the target's: 9.0625e-7 s
    assert t.t_comm == pytest.approx(8e7 / 3e7)  # one way, the input only: 2.6667 s
    assert t.t_exc == pytest.approx(-17.5)  # 2.5 - 20, inside [-40, 40]
    assert t.delay == pytest.approx(9.0625e-7 + 8 / 3 - 17.5)  # unweighted sum: -14.833332
    # Q' = 5 + 1 (this task) + 1.0 arrivals - 3.2e7/8e7 = 6.6; p = (54 - 6.6)/54 = 0.877778
    # O = -log10(0.877778) / 3 * 300 = 0.0566150 * 100 = 5.66150
    assert t.overload == pytest.approx(5.66150, rel=1e-5)
    assert t.reward == pytest.approx(2 - (-14.833332 + 5.66150), rel=1e-5)  # 11.17183


def test_reference_caps_the_times_at_utility_times_chi():
    slow = NodeView("b", queue=5, occupancy=5, buffer=54, capacity=4e5, tier=1, rate_bps=1e6, age=1, worker=True)
    t = reference_terms(Observation(10, "a", OWN, 1, [TASK], [slow]), TASK, 1, dt=1.0, arrivals=ARRIVALS)
    assert t.t_comm == pytest.approx(40.0)  # 8e7 bits / 1e6 bit/s = 80 s, capped at 2 * 20
    assert t.t_exc == pytest.approx(40.0)  # 8e7/4e5 - 8e7/4e6 = 200 - 20 = 180 s, capped at 40


def test_reference_offloading_from_a_near_empty_buffer_earns_the_utility():
    alone = NodeView("a", queue=0, occupancy=1, buffer=3, capacity=4e6, tier=0, rate_bps=0.0, age=1, worker=True)
    t = reference_terms(Observation(10, "a", alone, 0, [TASK], [NUC]), TASK, 1, dt=1.0, arrivals=ARRIVALS)
    assert t.reward == 2.0  # +U, whatever the target


def test_nominal_arrivals_split_a_clients_rate_over_its_targets():
    from orchestrator.scenario import load_scenario

    sc = load_scenario("aot2")
    arrivals = nominal_arrivals(sc)
    assert sum(arrivals.values()) == pytest.approx(sc.workload.arrival.rate * len(sc.clients))


def test_a_scenario_may_name_every_built_in_reward():
    from env import ZenohEdgeEnv
    from env.reward import REWARDS
    from orchestrator.scenario import load_scenario
    from orchestrator.scenario.schema import REWARD_NAMES

    assert tuple(REWARDS) == REWARD_NAMES  # the names the scenario format accepts are the env's
    for name, fn in REWARDS.items():
        scenario = load_scenario({"reward": name, "topology": {
            "nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b"}],
            "links": [{"between": ["a", "b"], "rate_bps": 1.0e8}]}}, name_hint="two")
        env = ZenohEdgeEnv(scenario, transport="inproc")
        assert env.reward_fn is fn, name
        env.close()


def test_the_env_selects_the_reference_reward_by_name():
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv("aot1", transport="inproc", reward="reference", max_steps=30, seed=3)
    try:
        env.reset(seed=3)
        placed = []
        for _ in range(30):
            _, rewards, *_ = env.step({a: 0 for a in env.agents})
            placed.extend(r for r in rewards.values() if r != 0.0)
            if not env.agents:
                break
        assert placed, "no task was placed in 30 steps"
        assert all(r <= 2.0 for r in placed)  # U - (D + O) with D, O >= 0 when kept local
    finally:
        env.close()


@pytest.mark.parametrize("reward", ["paper", "reference"])
def test_the_infos_terms_are_those_of_the_reward_in_use(reward):
    """Under either built-in reward, each agent's reward is the sum of the terms its infos list."""
    import numpy as np

    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv("aot1", transport="inproc", reward=reward, max_steps=40, seed=4)
    rng = np.random.default_rng(0)
    try:
        observations, _ = env.reset(seed=4)
        checked = 0
        while env.agents:  # random valid actions, so that offloads are placed too
            actions = {a: int(rng.choice(np.flatnonzero(observations[a]["action_mask"]))) for a in env.agents}
            observations, rewards, _, _, infos = env.step(actions)
            for agent, r in rewards.items():
                if terms := infos[agent]["reward_terms"]:
                    assert r == pytest.approx(sum(t["reward"] for t in terms))
                    checked += 1
        assert checked > 0
    finally:
        env.close()


def shared_episode(scenario: str, reward: str, seed: int) -> tuple[float, dict, float]:
    """One inproc episode of 150 steps in which every agent offloads where it can; checks that every agent
    gets the same reward in each step, and returns their sum over the episode, the episode's summary
    (from the last infos) and the env's penalty P."""
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv(scenario, transport="inproc", reward=reward, max_steps=150, seed=seed)
    try:
        env.reset(seed=seed)
        total = 0.0
        while env.agents:
            _, rewards, _, _, infos = env.step({a: 1 for a in env.agents})
            assert len(set(rewards.values())) == 1
            total += next(iter(rewards.values()))
        return total, next(iter(infos.values()))["episode"], env.penalty
    finally:
        env.close()


def test_the_team_reward_is_the_networks_completions_minus_drops_for_every_agent():
    """Checked against the episode's own counters: the team rewards of all steps add up to the episode's
    completed - dropped."""
    total, episode, _ = shared_episode("aot1", "team", seed=2)
    totals = episode["totals"]
    assert totals["completed"] > 0 and totals["dropped"]["total"] > 0
    assert total == totals["completed"] - totals["dropped"]["total"]


def test_the_score_reward_weighs_each_completion_by_its_timeliness():
    """Two of the node's tasks came back in 10 s and 30 s, with P = 100 s: (1 - 0.1) + (1 - 0.3) = 1.6; the
    team version reads the network's changes (3 completions summing 90 s: 3 - 0.9 = 2.1)."""
    from env.reward import RewardContext, score_reward, team_score_reward

    ctx = RewardContext(agent="ctrl_a", node="a", obs=OBS, action=0, next_obs=OBS, terms=(),
                        node_delta={"completed": 2, "response_time_total": 40.0},
                        network_delta={"completed": 3, "response_time_total": 90.0}, dt=1.0, arrivals={},
                        penalty=100.0)
    assert score_reward(ctx) == pytest.approx(1.6)
    assert team_score_reward(ctx) == pytest.approx(2.1)


def test_the_marginal_reward_charges_the_delay_imposed_at_the_congestion_price():
    """The score reward of the node's completions (1.6, above) minus 2 x 0.2 deadlines of delay imposed."""
    from env.reward import CONGESTION_PRICE, RewardContext, RewardSettings, marginal_reward

    assert CONGESTION_PRICE == RewardSettings().congestion_price == 2.0
    ctx = RewardContext(agent="ctrl_a", node="a", obs=OBS, action=0, next_obs=OBS, terms=(),
                        node_delta={"completed": 2, "response_time_total": 40.0, "delay_imposed": 0.2},
                        network_delta={"completed": 3, "response_time_total": 90.0, "delay_imposed": 0.5}, dt=1.0,
                        arrivals={}, penalty=100.0)
    assert (ctx.price, ctx.weights) == (2.0, PaperWeights())  # the names a user's reward reads
    assert marginal_reward(ctx) == pytest.approx(1.6 - 0.4)
    ctx.settings = RewardSettings(congestion_price=1.0)  # the environment's congestion_price
    assert ctx.price == 1.0
    assert marginal_reward(ctx) == pytest.approx(1.6 - 0.2)


def test_reward_context_takes_keywords_only():
    from env.reward import RewardContext

    with pytest.raises(TypeError):
        RewardContext("ctrl_a", "a", OBS, 0, OBS, (), {}, {}, 1.0, {}, 100.0)  # the positionals of old


def test_at_price_zero_marginal_is_the_score_reward_and_credits_are_timeliness_alone():
    """The environment's congestion_price reaches both the marginal reward and the credits per task."""
    from env import ZenohEdgeEnv

    runs = {}
    for reward, price in (("score", 3.0), ("marginal", 0.0), ("marginal", 3.0)):
        env = ZenohEdgeEnv("aot1_wired", transport="inproc", reward=reward, congestion_price=price, max_steps=120)
        obs, _ = env.reset(seed=6)
        rng = np.random.default_rng(6)
        rewards, credits = [], []
        while env.agents:
            obs, r, _, _, infos = env.step({a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"])))
                                            for a in env.agents})
            rewards.append(r)
            credits.append({a: i["credits"] for a, i in infos.items()})
        runs[(reward, price)] = rewards, credits
        env.close()
    assert runs[("score", 3.0)][0] == runs[("marginal", 0.0)][0]
    assert runs[("marginal", 3.0)][0] != runs[("marginal", 0.0)][0]
    free, priced = runs[("marginal", 0.0)][1], runs[("marginal", 3.0)][1]
    pairs = [(c0, c3) for s0, s3 in zip(free, priced, strict=True) for a in s0
             for (_, c0), (_, c3) in zip(s0[a], s3[a], strict=True)]
    assert pairs and all(0.0 <= c0 <= 1.0 and c3 <= c0 for c0, c3 in pairs) and any(c3 < c0 for c0, c3 in pairs)
    with pytest.raises(ValueError, match="congestion_price must be a finite number >= 0"):
        ZenohEdgeEnv("aot1", transport="inproc", congestion_price=-1.0)


@pytest.mark.parametrize("scenario", ["aot1", "aot3_compute"])
def test_the_team_score_rewards_of_an_episode_add_up_to_the_headline_score(scenario):
    """Over an episode, the team-score rewards add up to generated - penalised response time x generated / P
    (read from the episode's own summary), so maximising them minimises the headline score; on aot3_compute
    the deadlines are drawn, so P is the range's high end."""
    total, episode, penalty = shared_episode(scenario, "team_score", seed=4)
    generated = episode["totals"]["generated"]
    assert episode["totals"]["completed"] > 0
    expected = generated - episode["penalised_response_time"] * generated / penalty
    assert total == pytest.approx(expected, rel=1e-9, abs=1e-9)
