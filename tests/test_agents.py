"""Agents: masks respected, double-DQN targets, semi-MDP transitions, GAE, learning, checkpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agents import BASELINES, DDQN, PPO, A2CConfig, DDQNConfig, PPOConfig, evaluate, load_learner, make_policy, train
from agents.a2c import A2C
from agents.common import (
    NEIGHBOUR_DIM,
    OWN_DIM,
    TASK_DIM,
    TIE,
    AgentSpec,
    MaskedCategorical,
    TargetScorer,
    flat_dim,
    flatten_one,
    masked_argmax,
)
from agents.ddqn import td_target
from agents.learner import ReturnScale
from agents.onpolicy import Record
from env import ScenarioOverrides, TaskField, ZenohEdgeEnv
from env.observations import DictObservation, ObservationLayout
from node_runtime.model.messages import TaskSize
from node_runtime.model.policies import make_policy as make_node_policy
from node_runtime.model.view import NodeView, TaskView
from node_runtime.model.view import Observation as View

# A slow task source beside a fast idle worker over a fast link: offloading is clearly the better choice.
SLOW_FAST = {
    "name": "slow_fast",
    "simulation": {"steps": 100},
    "workload": {"arrival": {"rate": 0.3},
                 "tasks": [{"instructions": 5.0e6, "input_bytes": 1.0e5, "output_bytes": 1.0e5, "deadline": 60.0}]},
    "topology": {"nodes": [{"id": "slow", "client": True, "controller": True, "frequency": 1.0e6, "buffer": 10},
                           {"id": "fast", "frequency": 2.0e7, "buffer": 20}],
                 "links": [{"between": ["slow", "fast"], "rate_bps": 1.0e9}]},
}


def mean_response(rows: list[dict]) -> float:
    return float(np.mean([r["response_time_mean"] for r in rows]))


def check_valid(obs: dict, actions: dict) -> int:
    """Assert every action is allowed by its mask; return how many real choices (>1 valid action) there were."""
    choices = 0
    for agent, o in obs.items():
        mask = o["action_mask"]
        masks, acts = ([mask], [actions[agent]]) if isinstance(mask, np.ndarray) else (list(mask), actions[agent])
        assert len(acts) == len(masks), agent
        for m, a in zip(masks, acts, strict=True):
            assert m[int(a)] == 1, (agent, a, m)
        choices += sum(int(m.sum() > 1) for m in masks)
    return choices


# ----- baselines -----

@pytest.mark.parametrize("scenario", ["aot1", "aot2", "aot3", "aot4", "batch"])
def test_baselines_pick_only_valid_actions(scenario):
    mode = {"mode": "batch", "batch_size": 3} if scenario == "batch" else {}
    env = ZenohEdgeEnv("aot2" if scenario == "batch" else scenario, transport="inproc", max_steps=25,
                       overrides=ScenarioOverrides(arrival_rate=0.6, **mode), invalid_action="raise")
    for name, cls in BASELINES.items():
        policy = cls(seed=1)
        obs, _ = env.reset(seed=3)
        policy.reset(3)
        choices, offloads = 0, 0
        while env.agents:
            actions = policy.act(obs)
            choices += check_valid(obs, actions)
            offloads += sum(np.count_nonzero(a) for a in actions.values())
            obs, *_ = env.step(actions)  # invalid_action="raise": the env checks the masks too
        assert choices > 0, name
        if name == "local":
            assert offloads == 0
        elif name not in ("greedy", "greedy_backlog", "local_first", "drift_plus_penalty"):  # AoT tasks stay
            # local: 80 s of transfer (drift-plus-penalty counts it in its drift and its penalty)
            assert offloads > 0, name
    env.close()


def test_least_queue_and_greedy_choose_as_documented():
    obs = {"own": np.array([2, 3, 10, 0.004, 0, 1], np.float32),
           "task": np.array([1, 0.08, 1.0, 1.0, 1, 50, 0], np.float32),
           # present, queue, occupancy, buffer, capacity, tier, rate, age, backlog
           "neighbours": np.array([[1, 2, 2, 10, 0.1, 1, 8.0, 1, 0],  # same queue as local: tie -> local
                                   [1, 4, 10, 10, 1.0, 2, 800.0, 1, 0],  # fastest but full
                                   [1, 5, 5, 20, 0.1, 1, 800.0, 1, 0]], np.float32),
           "action_mask": np.array([1, 1, 1, 1], np.int8)}
    assert BASELINES["least_queue"]().act({"a": obs}) == {"a": 0}
    # greedy: local (2 + 1) * 0.08e9 / 4e6 = 60 s; n1: 2 s transfer + 3 * 0.8 s; n2 full; n3: 0.02 s + 6 * 0.8 s
    assert BASELINES["greedy"]().act({"a": obs}) == {"a": 1}
    obs["neighbours"][0, 8] = 1.0  # 1 s of transfers queued on the link to n1: 5.4 s against n3's 4.82 s
    assert BASELINES["greedy"]().act({"a": obs}) == {"a": 1}
    assert BASELINES["greedy_backlog"]().act({"a": obs}) == {"a": 3}
    # local_first: 60 s at home against 50 s left, so greedy_backlog's choice; with 60 s left, home
    assert BASELINES["local_first"]().act({"a": obs}) == {"a": 3}
    obs["task"][TaskField.TIME_LEFT_S] = 60.0
    assert BASELINES["local_first"]().act({"a": obs}) == {"a": 0}
    obs["neighbours"][0, 0] = 0
    obs["action_mask"] = np.array([1, 0, 1, 1], np.int8)
    assert BASELINES["greedy"]().act({"a": obs}) == {"a": 3}
    rr = BASELINES["round_robin"]()
    assert [rr.act({"a": obs})["a"] for _ in range(4)] == [0, 2, 3, 0]


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_a_baseline_reads_back_the_view_its_rule_decides_on(data):
    # A baseline runs the node-side rule of its name on the view it reads back from the encoded arrays;
    # on the controller's raw view the rule must place the task alike (seconds-scale values, so float32
    # encoding cannot flip a choice): units, columns, masks and the random stream all come back.
    def node(name: str, worker: bool = True) -> NodeView:
        return NodeView(name, data.draw(st.integers(0, 8)), data.draw(st.integers(0, 12)), 12,
                        data.draw(st.sampled_from([1e8, 4e8, 1e9, 4e9])), 1,
                        data.draw(st.sampled_from([1e6, 1e7, 1e8])), 1, worker,
                        data.draw(st.sampled_from([0.0, 0.5, 3.0, 20.0])))
    degree = data.draw(st.integers(1, 4))
    neighbours = [node(f"n{i}", data.draw(st.booleans())) for i in range(degree)]
    task = TaskView(7, TaskSize(data.draw(st.sampled_from([1e8, 1e9])), 1e6, 1e5, 1.0, 60.0), 30.0, 0, "me")
    view = View(5, "me", node("me"), 1, [task], neighbours)
    # Exact ties between estimates are a matter of rounding: the raw view holds float64 numbers, the
    # arrays float32 ones, so either target may win (e.g. 0.88 s + 2 x 1e9 / 1e8 against
    # 0.88 s + 8 x 1e9 / 4e8). Such views test nothing about the reading, and are left out.
    valid = [i for i, ok in enumerate(view.valid_actions()) if ok]
    for name in ("greedy", "greedy_backlog"):
        costs = sorted(make_node_policy(name).estimate(view, task, a, 0) for a in valid)
        assume(len(costs) < 2 or not math.isclose(costs[0], costs[1], rel_tol=1e-5))
    assume(not math.isclose(make_node_policy("local_first").estimate(view, task, 0, 0), task.time_left, rel_tol=1e-5))
    encoded = DictObservation(ObservationLayout(degree, degree + 1, None)).encode(view)  # one padding slot
    seed = data.draw(st.integers(0, 2**32 - 1))
    for name in BASELINES:
        rule = make_node_policy(name)
        rule.reset(np.random.default_rng(seed))
        assert BASELINES[name](seed).act({"a": encoded})["a"] == rule.decide(view)[0], name


@pytest.mark.parametrize("scenario, mode", [("aot3_compute", None), ("examples/n_tier_cloud", None),
                                            ("aot4_wired", "batch")])
def test_baselines_choose_as_their_rules_on_the_controllers_views(scenario, mode):
    """Over real episodes: at every step, each agent's action is what its rule decides on the controller's
    raw view (the deterministic rules; a baseline's random stream is shared by its agents)."""
    overrides = ScenarioOverrides(mode=mode, batch_size=3 if mode else None, arrival_rate=0.5)
    env = ZenohEdgeEnv(scenario, transport="inproc", max_steps=60, overrides=overrides, uniform_spaces=True)
    offloads = 0
    try:
        for name in ("least_queue", "greedy", "greedy_backlog", "local_first"):
            baseline, rule = BASELINES[name](0), make_node_policy(name)
            obs, _ = env.reset(seed=4)
            decisions = 0
            while env.agents:
                actions = baseline.act(obs)
                for agent in env.agents:
                    raw = env._raw[agent]
                    if raw is not None and raw.tasks:
                        expected = rule.decide(raw)
                        assert (actions[agent] if mode else [actions[agent]])[:len(expected)] == expected, name
                        decisions += 1
                        offloads += sum(a > 0 for a in expected)
                obs, *_ = env.step(actions)
            assert decisions > 0, name
    finally:
        env.close()
    assert offloads > 0  # the rules did send tasks away: not only "keep it" was compared


def test_the_tie_that_the_twin_test_leaves_out_is_one():
    """The view hypothesis found: n0 and n1 tie at 20.88 s, and the two sides may pick either."""
    n0 = NodeView("n0", 1, 0, 12, 1e8, 1, 1e7, 1, True, 0.0)
    n1 = NodeView("n1", 7, 0, 12, 4e8, 1, 1e7, 1, True, 0.0)
    task = TaskView(7, TaskSize(1e9, 1e6, 1e5, 1.0, 60.0), 30.0, 0, "me")
    view = View(5, "me", NodeView("me", 0, 0, 12, 1e8, 1, 1e6, 1, True, 0.0), 1, [task], [n0, n1])
    greedy = make_node_policy("greedy")
    assert greedy.estimate(view, task, 1, 0) == pytest.approx(20.88) == greedy.estimate(view, task, 2, 0)


# ----- common pieces -----

def test_masked_distribution_and_argmax_never_pick_masked_actions():
    logits = torch.tensor([[5.0, 9.0, 1.0], [0.0, 0.0, 0.0]])
    mask = torch.tensor([[True, False, True], [False, True, False]])
    assert masked_argmax(logits, mask).tolist() == [0, 1]
    # near-ties (a forward pass's rounding, ~1e-6) go to the first: the greedy action is the batch's any way
    near = torch.tensor([[1.0, 1.0 + 1e-6, 0.5], [-3.0, 200.0 + 1e-4, 200.0], [0.0, 0.1, 0.1 - 1e-3]])
    assert masked_argmax(near, torch.ones(3, 3, dtype=torch.bool)).tolist() == [0, 1, 1]
    dist = MaskedCategorical(logits, mask)
    draws = torch.stack([dist.sample(torch.Generator().manual_seed(s)) for s in range(50)])
    assert mask.gather(1, draws.T).all()
    assert torch.isfinite(dist.entropy()).all() and dist.entropy()[1] == 0
    e4 = float(np.exp(4))
    assert dist.probs[0].tolist() == pytest.approx([e4 / (1 + e4), 0.0, 1 / (1 + e4)])


def test_flatten_has_the_documented_size_and_finite_values():
    env = ZenohEdgeEnv("aot2", transport="inproc", max_steps=30, uniform_spaces=True,
                       overrides=ScenarioOverrides(arrival_rate=0.5))
    obs, _ = env.reset(seed=0)
    slots = env.observation_space(env.possible_agents[0])["neighbours"].shape[0]
    for _ in range(30):
        for o in obs.values():
            x = flatten_one(o)
            assert x.shape == (flat_dim(slots),) and np.isfinite(x).all() and np.abs(x).max() < 20
        obs, *_ = env.step(BASELINES["random"](0).act(obs))
    env.close()


def test_estimates_and_slack_match_a_hand_computed_example():
    # own: queue 2 holding 25 s of work, capacity 0.004 Gcycles/s; task: 0.08 G instructions, 1 MB in, 1 MB out,
    # 50 s left
    obs = {"own": np.array([2, 3, 10, 0.004, 1, 0, 25.0], np.float32),
           "task": np.array([1, 0.08, 1.0, 1.0, 1, 50, 0], np.float32),
           # present, queue, occupancy, buffer, capacity, tier, rate, age, backlog, work
           "neighbours": np.array([[1, 1, 1, 10, 0.1, 1, 8.0, 1, 0.5, 0.3], [0] * 10], np.float32),
           "action_mask": np.array([1, 1, 0], np.int8)}
    est = flatten_one(obs)[8 + 7 + 11 * 2:].reshape(3, 4)
    # local: wait 25 s (its work left, not 2 x 20 s), execution 20 s, no transfer, slack 50 - 45 = 5 s
    # neighbour: wait 0.3 s, execution 0.8 s, transfer 16 Mbit / 8 Mbit/s = 2 s, slack 50 - 3.1 - 0.5 s of backlog
    expected = np.array([[25, 20, 0, 5], [0.3, 0.8, 2, 46.4], [0, 0, 0, 0]])
    np.testing.assert_allclose(est, np.sign(expected) * np.log1p(np.abs(expected)), rtol=1e-5)


def test_target_scorer_follows_its_targets_not_their_slots():
    torch.manual_seed(0)
    slots = 4
    scorer = TargetScorer(slots, (16,), out_gain=1.0)
    x = torch.randn(3, flat_dim(slots) + 5)  # 5 trailing columns (an agent id) that it ignores
    logits = scorer(x)
    assert logits.shape == (3, 1 + slots)
    start, width = OWN_DIM + TASK_DIM, NEIGHBOUR_DIM * slots
    nb = x[:, start:start + width].reshape(3, slots, NEIGHBOUR_DIM)
    est = x[:, start + width:start + width + 4 * (1 + slots)].reshape(3, 1 + slots, 4)
    order = torch.tensor([2, 0, 3, 1])  # permute the neighbour slots, with their estimates
    y = x.clone()
    y[:, start:start + width] = nb[:, order].reshape(3, -1)
    targets = torch.cat([torch.tensor([0]), order + 1])
    y[:, start + width:start + width + 4 * (1 + slots)] = est[:, targets].reshape(3, -1)
    y[:, flat_dim(slots):] = torch.randn(3, 5)
    permuted = scorer(y)
    torch.testing.assert_close(permuted[:, 0], logits[:, 0])
    torch.testing.assert_close(permuted[:, 1:], logits[:, 1:][:, order])
    # a scorer for another degree uses the same weights
    wider = TargetScorer(slots + 2, (16,), out_gain=1.0)
    wider.load_state_dict(scorer.state_dict())


def test_unknown_actor_is_refused():
    with pytest.raises(ValueError, match="actor must be one of"):
        PPOConfig(actor="cnn")


# ----- DDQN -----

def constant_q(net: torch.nn.Sequential, values: list[float]) -> None:
    """Make a Q-network output ``values`` whatever its input."""
    with torch.no_grad():
        net[-1].weight.zero_()
        net[-1].bias.copy_(torch.tensor(values))


def test_ddqn_target_is_double_dqn():
    ddqn = DDQN({"a": AgentSpec(slots=2, n_actions=3)}, DDQNConfig(hidden=(8,), gamma=0.9, lr=0.0, batch_size=2,
                                                                  learning_starts=1))
    net = ddqn.nets["a"]
    constant_q(net.online, [1.0, 5.0, 3.0])  # the online network prefers action 1, then 2
    constant_q(net.target, [10.0, 2.0, 7.0])  # the target network values action 0 highest
    x = torch.zeros(2, flat_dim(2))
    reward, discount = torch.tensor([1.0, 1.0]), torch.tensor([0.9, 0.9])
    next_mask = torch.tensor([[True, True, True], [True, False, True]])
    double = td_target(net.online, net.target, reward, discount, x, next_mask, double=True)
    vanilla = td_target(net.online, net.target, reward, discount, x, next_mask, double=False)
    # double: online argmax -> 1 (all valid) and 2 (1 masked); the target network values them 2 and 7
    assert double.tolist() == pytest.approx([1 + 0.9 * 2.0, 1 + 0.9 * 7.0])
    # vanilla: max of the target network over the valid actions -> 10 for both
    assert vanilla.tolist() == pytest.approx([1 + 0.9 * 10.0, 1 + 0.9 * 10.0])
    # and the learner's update uses the double target: Huber(Q_online(s, a) = 5, y) with lr = 0
    for m in next_mask.numpy():
        net.buffer.add(np.zeros(flat_dim(2), np.float32), np.ones(3, bool), 1, 1.0, 0.9, np.zeros(flat_dim(2)), m)
    ddqn.rng = np.random.default_rng(0)
    idx = np.random.default_rng(0).integers(2, size=2)
    expected = F.smooth_l1_loss(torch.full((2,), 5.0), double[torch.as_tensor(idx)]).item()
    ddqn.update(net)
    assert ddqn.last_loss == pytest.approx(expected)


def obs_of(task: bool, queue: float = 0.0) -> dict:
    return {"own": np.array([queue, queue, 5, 0.01, 0, 0, queue], np.float32),
            "task": np.array([1, 0.01, 0.1, 0.1, 1, 30, 0] if task else [0] * 7, np.float32),
            "neighbours": np.array([[1, 0, 0, 5, 0.02, 1, 100, 1, 0, 0]], np.float32),
            "action_mask": np.array([1, 1] if task else [1, 0], np.int8)}


def test_transitions_span_from_one_decision_to_the_next():
    """Steps without a task are no-ops: their rewards accrue (discounted) to the open transition."""
    ddqn = DDQN({"a": AgentSpec(1, 2)}, DDQNConfig(hidden=(8,), gamma=0.5, reward_scale=1.0, learning_starts=100))
    buf = ddqn.nets["a"].buffer
    ddqn.explore({"a": obs_of(True)})
    ddqn.observe({"a": 1.0}, {"a": obs_of(False)}, {"a": False}, {"a": False})
    assert ddqn.explore({"a": obs_of(False)}) == {"a": 0} and len(buf) == 0
    ddqn.observe({"a": 2.0}, {"a": obs_of(True, queue=3)}, {"a": False}, {"a": False})
    assert len(buf) == 1
    assert buf.reward[0] == pytest.approx(1.0 + 0.5 * 2.0) and buf.discount[0] == pytest.approx(0.25)
    assert np.array_equal(buf.next_obs[0], flatten_one(obs_of(True, queue=3)))
    ddqn.explore({"a": obs_of(True, queue=3)})  # truncated with a task in the final observation: bootstrap
    ddqn.observe({"a": 4.0}, {"a": obs_of(True)}, {"a": False}, {"a": True})
    assert buf.reward[1] == pytest.approx(4.0) and buf.discount[1] == pytest.approx(0.5)
    ddqn.explore({"a": obs_of(True)})  # terminated: no bootstrap
    ddqn.observe({"a": 8.0}, {"a": obs_of(True)}, {"a": True}, {"a": False})
    assert buf.reward[2] == pytest.approx(8.0) and buf.discount[2] == 0.0 and not ddqn.pending


def test_return_scale_divides_by_the_std_of_every_discounted_return_seen():
    """Hand-computed: gamma 0.5, two agents; the running variance covers every agent's return so far."""
    scale = ReturnScale(gamma=0.5)
    # returns 1 and 3: mean 2, variance 1
    assert scale.normalize({"a": 1.0, "b": 3.0}, set()) == pytest.approx({"a": 1.0, "b": 3.0}, rel=1e-3)
    # returns 0.5 * 1 + 2 = 2.5 and 0.5 * 3 + 0 = 1.5; over [1, 3, 2.5, 1.5] the variance is 0.625
    out = scale.normalize({"a": 2.0, "b": 0.0}, {"a"})  # a's episode ends: its next return starts afresh
    assert out == pytest.approx({"a": 2.0 / math.sqrt(0.625), "b": 0.0}, rel=1e-3)
    # a's return restarts at 1 (not 0.5 * 2.5 + 1): over [1, 3, 2.5, 1.5, 1] the variance is 0.66
    assert scale.normalize({"a": 1.0}, set()) == pytest.approx({"a": 1.0 / math.sqrt(0.66)}, rel=1e-3)


def test_return_scale_makes_rewards_independent_of_their_unit():
    rng = np.random.default_rng(0)
    small, large = ReturnScale(gamma=0.9), ReturnScale(gamma=0.9)
    for step in range(200):
        rewards = {a: float(rng.normal()) for a in "abc"}
        ended = {"a"} if step % 40 == 39 else set()
        out = small.normalize(rewards, ended)
        assert large.normalize({a: 1000.0 * r for a, r in rewards.items()}, ended) == pytest.approx(out, rel=1e-3)
    # the first rewards, before any variance is known, are clipped rather than blown up
    assert ReturnScale(gamma=0.9).normalize({"a": 1e6, "b": 1e6}, set()) == {"a": 10.0, "b": 10.0}


def test_gae_follows_each_agents_own_decisions():
    a2c = A2C({"a": AgentSpec(1, 2), "b": AgentSpec(1, 2)}, A2CConfig(hidden=(8,), gae_lambda=0.5))
    z = np.zeros(1, np.float32)

    def rec(agent, value, reward, discount, next_value, last=False):
        return Record(agent, z, z, np.ones(2, bool), 0, 0.0, value, reward, discount, next_value, last)

    records = [rec("a", 1.0, 1.0, 0.9, 2.0), rec("b", 0.0, 5.0, 0.8, 1.0, last=True), rec("a", 2.0, 0.5, 0.9, 3.0),
               rec("b", 1.0, 1.0, 0.8, 0.0)]
    adv = a2c.batch(records)["advantage"].numpy()
    d_a2 = 0.5 + 0.9 * 3.0 - 2.0
    d_b2 = 1.0 + 0.8 * 0.0 - 1.0
    d_b1 = 5.0 + 0.8 * 1.0 - 0.0  # last of its episode: does not continue into b's next record
    d_a1 = 1.0 + 0.9 * 2.0 - 1.0
    assert adv.tolist() == pytest.approx([d_a1 + 0.9 * 0.5 * d_a2, d_b1, d_a2, d_b2])


def test_shared_parameters_need_uniform_spaces():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=5)
    with pytest.raises(ValueError, match="uniform_spaces=True"):
        PPO.for_env(env)
    env.close()


# ----- learning on a scenario whose best action is known -----

@pytest.fixture(scope="module")
def slow_fast():
    env = ZenohEdgeEnv(SLOW_FAST, transport="inproc")
    yield env
    env.close()


def test_offloading_is_the_better_action_on_slow_fast(slow_fast):
    local = mean_response(evaluate(slow_fast, BASELINES["local"](), 2))
    offload = mean_response(evaluate(slow_fast, BASELINES["least_queue"](), 2))  # the idle fast node
    assert offload < 0.5 * local


@pytest.mark.parametrize("algo", ["ddqn", "ppo"])
def test_learners_beat_random_where_offloading_is_best(slow_fast, algo):
    torch.set_num_threads(1)
    common = {"hidden": (32,), "gamma": 0.9, "reward_scale": 1e-2, "seed": 0}
    config = (DDQNConfig(lr=1e-3, learning_starts=16, batch_size=16, target_update_interval=50, **common)
              if algo == "ddqn" else PPOConfig(lr=3e-3, rollout_steps=25, **common))
    learner = make_policy(algo, slow_fast, config)
    train(slow_fast, learner, 3)  # 300 steps, about 90 decisions
    random = mean_response(evaluate(slow_fast, BASELINES["random"](0), 3))
    learnt = mean_response(evaluate(slow_fast, learner, 3))
    assert learnt < 0.8 * random, (learnt, random)


def test_a_teacher_keeps_the_learner_on_its_choices_where_reward_alone_would_not(slow_fast):
    """Kickstarting: with the imitation loss weighted up throughout, PPO keeps tasks local as its teacher
    does, although offloading to the fast node is what the reward teaches without a teacher (the test above)."""
    torch.set_num_threads(1)
    config = PPOConfig(hidden=(32,), gamma=0.9, lr=3e-3, rollout_steps=25, seed=0, teacher="local",
                       teacher_coef=5.0, teacher_fraction=100.0)
    learner = make_policy("ppo", slow_fast, config)
    train(slow_fast, learner, 3)
    rows = evaluate(slow_fast, learner, 3)
    assert sum(r["offloaded"] for r in rows) <= 0.1 * sum(r["generated"] for r in rows), rows


def test_the_teachers_weight_falls_linearly_to_zero():
    ppo = PPO({"a": AgentSpec(1, 2)}, PPOConfig(hidden=(8,), teacher="greedy", teacher_coef=2.0,
                                                teacher_fraction=0.5))
    ppo.start_training(100)
    weights = []
    for steps in (0, 25, 50, 80):
        ppo.env_steps = steps
        weights.append(ppo.teacher_weight())
    assert weights == pytest.approx([2.0, 1.0, 0.0, 0.0])
    assert PPO({"a": AgentSpec(1, 2)}, PPOConfig(hidden=(8,))).teacher_weight() == 0.0
    with pytest.raises(ValueError, match="teacher must be one of local, random"):
        PPOConfig(teacher="oracle")


def test_evaluation_temperature_goes_from_sampling_to_the_most_likely_action():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=30, overrides=ScenarioOverrides(arrival_rate=0.5),
                       uniform_spaces=True)
    policies = {name: make_policy("ppo", env, PPOConfig(hidden=(16,), seed=3, **changes)) for name, changes in {
        "sampled": {}, "T=1": {"eval_temperature": 1.0}, "cold": {"eval_temperature": 1e-6},
        "mode": {"sample_eval": False}}.items()}
    obs, _ = env.reset(seed=5)
    chosen: dict[str, list] = {name: [] for name in policies}
    mode = policies["mode"]
    parted = 0
    while env.agents:
        for name, policy in policies.items():
            policy.reset(9)  # the same random stream for every policy
            chosen[name].append(policy.act(obs))
        for agent, action in chosen["cold"][-1].items():  # cold samples the mode, or one of targets that tie with it
            if action != chosen["mode"][-1][agent]:
                parted += 1
                with torch.no_grad():
                    logits = mode.nets[mode.group(agent)].actor(torch.as_tensor(mode.features(agent, obs[agent])))
                assert logits[action] == pytest.approx(logits[chosen["mode"][-1][agent]], abs=TIE)
        obs, *_ = env.step(chosen["sampled"][-1])
    env.close()
    assert chosen["T=1"] == chosen["sampled"]
    assert chosen["mode"] != chosen["sampled"]
    assert parted < sum(len(step) for step in chosen["mode"]) / 20  # identical neighbours only
    with pytest.raises(ValueError, match="eval_temperature must be > 0"):
        PPOConfig(eval_temperature=0.0)


# ----- checkpoints -----

@pytest.mark.parametrize("algo,config", [("ddqn", DDQNConfig(learning_starts=8, batch_size=8)),
                                         ("a2c", A2CConfig(rollout_steps=8)),
                                         ("ppo", PPOConfig(rollout_steps=16, centralised_critic=True))])
def test_checkpoint_round_trip_gives_the_same_actions(tmp_path, algo, config):
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=40, overrides=ScenarioOverrides(arrival_rate=0.5),
                       uniform_spaces=config.shared)
    learner = make_policy(algo, env, config)
    train(env, learner, 1)
    learner.save(tmp_path / "ckpt.pt")
    loaded = load_learner(tmp_path / "ckpt.pt")
    assert type(loaded) is type(learner) and loaded.config == learner.config and loaded.env_steps == 40
    assert loaded.returns.stats() == learner.returns.stats()  # reward normalisation goes on where it was
    obs, _ = env.reset(seed=7)
    compared = 0
    while env.agents:
        learner.reset(11)
        loaded.reset(11)
        actions = learner.act(obs)
        assert loaded.act(obs) == actions
        compared += sum(int(o["task"][TaskField.PRESENT]) for o in obs.values())
        obs, *_ = env.step(actions)
    assert compared > 10
    env.close()
