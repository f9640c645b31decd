"""What step() does with each action (docs/env.md "Actions"): every rule and every message.

In one process: every rule is applied before anything reaches the emulation, whatever the transport
(test_env.py runs PettingZoo's own tests over Zenoh too).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from env import InvalidActionError, InvalidActionPenalty, ScenarioOverrides, TaskField, ZenohEdgeEnv
from env.reward import paper_reward
from tests.conftest import same, write_scenario

# Node a decides for its own tasks; of its neighbours b is a worker, d (a task source) is not.
SENSOR = {
    "name": "sensor",
    "simulation": {"steps": 40},
    "workload": {"arrival": {"rate": 0.5},
                 "tasks": [{"instructions": 3e6, "input_bytes": 2e5, "output_bytes": 2e5, "deadline": 30}]},
    "topology": {"nodes": [{"id": "a", "frequency": 1e6, "buffer": 6, "client": True, "controller": True},
                           {"id": "b", "frequency": 4e6, "buffer": 6},
                           {"id": "d", "client": True, "worker": False}],
                 "links": [["a", "b"], ["a", "d"]]},
}
BATCH = ScenarioOverrides(mode="batch", batch_size=3)


@pytest.fixture
def sensor(tmp_path):
    return write_scenario(tmp_path, SENSOR)


def has_task(obs: dict, agent: str, slot: int = 0) -> bool:
    return bool(np.asarray(obs[agent]["task"]).reshape(-1, len(TaskField))[slot, TaskField.PRESENT])


def twins(source, seed: int = 1, **kwargs) -> tuple[ZenohEdgeEnv, ZenohEdgeEnv, dict]:
    """Two environments at the same point of the same episode, and its first observations."""
    a = ZenohEdgeEnv(source, transport="inproc", max_steps=40, **kwargs)
    b = ZenohEdgeEnv(source, transport="inproc", max_steps=40, **kwargs)
    obs, _ = a.reset(seed=seed)
    b.reset(seed=seed)
    return a, b, obs


def stay(env: ZenohEdgeEnv) -> dict:
    """Action 0 (local) for every live agent, in every task slot."""
    return {a: 0 if env.scenario.mode == "binary" else [0] * env.scenario.batch_size for a in env.agents}


def advance_until(envs, obs: dict, ready) -> dict:
    """Step every env with ``stay`` until ``ready(obs)``; fails if the episode ends first."""
    while not ready(obs):
        assert envs[0].agents, "the episode ended before the awaited observation"
        for env in envs:
            obs, *_ = env.step(stay(env))
    return obs


def close_all(*envs) -> None:
    for env in envs:
        env.close()


# ----- an agent with nothing to decide: ignored -----

def test_an_agent_with_nothing_to_decide_has_its_action_ignored():
    """Any in-space action of an agent without a task does what 0 does: not invalid, not penalised."""
    ref, env, obs = twins("aot1")
    penalised = InvalidActionPenalty(env, penalty=-10.0)
    idle = [a for a in ref.agents if not has_task(obs, a)]
    assert idle
    for _ in range(5):
        chosen = {a: env.action_space(a).n - 1 if a in idle else 0 for a in env.agents}
        got = penalised.step(chosen)
        want = ref.step(stay(ref))
        assert same(got, want)
        assert not any(info["invalid_action"] for info in got[4].values())
        idle = [a for a in ref.agents if not has_task(got[0], a)]
    assert env.summary()["invalid_actions"]["total"] == 0
    close_all(ref, env)


def test_empty_task_slots_are_ignored_in_batch_mode():
    ref, env, obs = twins("aot2", overrides=BATCH, uniform_spaces=True)
    agent = "ctrl_rpi3_0"
    obs = advance_until((ref, env), obs, lambda o: has_task(o, agent) and not has_task(o, agent, 1))
    n = env.action_space(agent).nvec[0]
    chosen = stay(env) | {agent: [0, n - 1, n - 1]}  # slots 1 and 2 hold no task
    got = env.step(chosen)
    assert same(got, ref.step(stay(ref)))
    assert got[4][agent]["invalid_action"] is False
    close_all(ref, env)


# ----- a choice the mask forbids: the task stays local, and it is counted -----

@pytest.mark.parametrize("case", ["not a worker", "padding slot", "batch slot"])
def test_a_masked_choice_keeps_the_task_local_and_is_counted(case, sensor):
    source, kwargs, agent, action = {
        "not a worker": (sensor, {}, "ctrl_a", 2),  # neighbour d has no worker
        "padding slot": ("aot1", {"uniform_spaces": True}, "ctrl_rpi3_0", 7),  # rpi3_0 has 2 neighbours of 11 slots
        "batch slot": ("aot1", {"uniform_spaces": True, "overrides": BATCH}, "ctrl_rpi3_0", [7, 0, 0]),
    }[case]
    ref, env, obs = twins(source, **kwargs)
    obs = advance_until((ref, env), obs, lambda o: has_task(o, agent))
    counts = []
    for _ in range(2):
        obs, rewards, _, _, infos = env.step(stay(env) | {agent: action})
        r_obs, r_rewards, _, _, r_infos = ref.step(stay(ref))
        assert same(obs, r_obs) and rewards == r_rewards  # the emulation did what action 0 does
        assert infos[agent]["invalid_action"] is True and r_infos[agent]["invalid_action"] is False
        assert infos[agent]["reward_terms"] == r_infos[agent]["reward_terms"]  # the terms of keeping it local
        counts.append(infos[agent]["invalid_action_count"])
        obs = advance_until((ref, env), obs, lambda o: has_task(o, agent))
    assert counts == [1, 2]
    summary = env.summary()["invalid_actions"]
    assert summary["total"] == 2 and summary["by_agent"][agent] == 2
    while env.agents:
        *_, infos = env.step(stay(env))
    assert infos[agent]["episode"]["invalid_actions"] == summary
    env.reset(seed=2)
    assert env.summary()["invalid_actions"]["total"] == 0  # counts are per episode
    close_all(ref, env)


def test_invalid_action_raise_names_the_allowed_targets_and_changes_nothing(sensor):
    ref, env, obs = twins(sensor, invalid_action="raise")
    obs = advance_until((ref, env), obs, lambda o: has_task(o, "ctrl_a"))
    message = ("ctrl_a: action 2 (d) is masked; allowed now: 0 (local), 1 (b) "
               "(invalid_action='raise'; the default, 'local', keeps the task local)")
    with pytest.raises(InvalidActionError, match=f"^{re.escape(message)}$"):
        env.step({"ctrl_a": 2})
    assert same(env.step({"ctrl_a": 1}), ref.step({"ctrl_a": 1}))  # the failed step changed nothing
    close_all(ref, env)


# ----- what counts as an integer -----

@pytest.mark.parametrize("action", [np.int64(1), np.int8(1), np.array(1), 1.0, np.float32(1.0), np.array(1.0)],
                         ids=["np.int64", "np.int8", "0-d array", "1.0", "np.float32", "0-d float array"])
def test_integers_of_other_types_are_the_same_action(action):
    seen = []

    def reward(ctx):
        seen.append(ctx.action)
        return paper_reward(ctx)

    ref, env, obs = twins("aot1", reward=reward)
    agent = "ctrl_rpi3_0"
    obs = advance_until((ref, env), obs, lambda o: has_task(o, agent))
    seen.clear()
    got = env.step(stay(env) | {agent: action})
    assert same(got, ref.step(stay(ref) | {agent: 1}))
    assert got[4][agent]["reward_terms"][0]["t_comm"] > 0  # offloaded, not kept local
    assert type(seen[0]) is int and seen[0] == 1  # the reward sees a plain int, as documented
    close_all(ref, env)


# ----- each mistake, its own message -----

SPACE = re.escape("expected an integer action of Discrete(3) (0 = local, i = neighbour i)")


@pytest.mark.parametrize("action,error,message", [
    ("left", TypeError, rf"ctrl_rpi3_0: action 'left' is a str, not an integer; {SPACE}"),
    (None, TypeError, rf"ctrl_rpi3_0: action None is a NoneType, not an integer; {SPACE}"),
    ([1], TypeError, rf"ctrl_rpi3_0: action \[1\] is a list, not an integer; {SPACE}"),
    (1.7, ValueError, rf"ctrl_rpi3_0: action 1.7 is not a whole number; {SPACE}"),
    (float("nan"), ValueError, rf"ctrl_rpi3_0: action nan is not a whole number; {SPACE}"),
    (np.array(0.5), ValueError, rf"ctrl_rpi3_0: action 0.5 is not a whole number; {SPACE}"),
    (3, ValueError, r"ctrl_rpi3_0: action 3 is outside the action space Discrete\(3\): expected 0 \(local\) to 2"),
    (-1, ValueError, r"ctrl_rpi3_0: action -1 is outside the action space Discrete\(3\): expected 0 \(local\) to 2"),
    (np.int64(9), ValueError, r"ctrl_rpi3_0: action 9 is outside the action space Discrete\(3\)"),
], ids=["str", "None", "list", "1.7", "nan", "0-d 0.5", "too large", "negative", "np.int64 too large"])
def test_an_action_outside_the_space_is_refused_with_its_own_message(action, error, message):
    ref, env, _ = twins("aot1")
    with pytest.raises(error, match=f"^{message}"):
        env.step(stay(env) | {"ctrl_rpi3_0": action})
    assert same(env.step(stay(env)), ref.step(stay(ref)))  # nothing happened
    close_all(ref, env)


@pytest.mark.parametrize("action,error,message", [
    (0, TypeError, r"ctrl_rpi3_0: action 0 is not a sequence; expected 3 integers, one per task slot, "
                   r"in MultiDiscrete\(\[3 3 3\]\) \(batch mode\)"),
    ([0, 0], ValueError, r"ctrl_rpi3_0: 2 actions; expected 3, one per task slot, in MultiDiscrete\(\[3 3 3\]\) "
                         r"\(batch mode\)"),
    ([0, 7, 0], ValueError, r"ctrl_rpi3_0: action 7 \(task slot 1\) is outside the action space "
                            r"MultiDiscrete\(\[3 3 3\]\): expected 0 \(local\) to 2"),
    ([0, "x", 0], TypeError, r"ctrl_rpi3_0: action 'x' \(task slot 1\) is a str, not an integer"),
    (np.array([[0, 0, 0]]), TypeError, r"ctrl_rpi3_0: action \[\[0 0 0\]\] is not a sequence"),
], ids=["scalar", "too short", "slot out of range", "slot str", "2-d array"])
def test_batch_mode_messages(action, error, message):
    env = ZenohEdgeEnv("aot2", transport="inproc", overrides=BATCH, max_steps=5)
    env.reset(seed=0)
    with pytest.raises(error, match=f"^{message}"):
        env.step(stay(env) | {"ctrl_rpi3_0": action})
    env.step(dict.fromkeys(env.agents, np.zeros(3, dtype=np.int64)))  # MultiDiscrete.sample()'s type is fine
    env.close()


def test_the_actions_dict_must_name_exactly_the_live_agents():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=5)
    env.reset(seed=0)
    zeros = stay(env)
    live = re.escape("the live agents (env.agents) are ctrl_rpi3_0, ctrl_rpi3_1, ctrl_rpi3_2, …, ctrl_server_0 (10)")
    with pytest.raises(ValueError, match=rf"^step\(\): actions for 'ctrl_rpi3_9', not a live agent of this "
                                         rf"environment; {live}$"):
        env.step(zeros | {"ctrl_rpi3_9": 0})
    with pytest.raises(ValueError, match=r"^step\(\): actions for 'rpi3_0', 'nuc_0', not live agents"):
        env.step(zeros | {"rpi3_0": 0, "nuc_0": 0})
    missing = {a: 0 for a in env.agents if a != "ctrl_nuc_0"}
    with pytest.raises(ValueError, match=r"^step\(\): no action for ctrl_nuc_0; every live agent \(env.agents\) "
                                         r"needs one$"):
        env.step(missing)
    with pytest.raises(TypeError, match=r"^step\(\) takes a dict \{agent: action\} for the live agents "
                                        r"\(env.agents\), not a list$"):
        env.step([0] * 10)
    env.close()


def test_step_outside_an_episode_says_what_happened_and_what_to_call():
    env = ZenohEdgeEnv("aot1", transport="inproc", max_steps=2)
    with pytest.raises(RuntimeError, match=r"^step\(\) before reset\(\): call reset\(\) to start an episode$"):
        env.step({})
    env.reset(seed=0)
    env.step(stay(env))
    env.step(stay(env))
    with pytest.raises(RuntimeError, match=r"^step\(\) after the episode ended \(every agent truncated at step 2\): "
                                           r"call reset\(\) to start a new one$"):
        env.step(dict.fromkeys(env.possible_agents, 0))
    env.close()
    with pytest.raises(RuntimeError, match=r"^step\(\) after close\(\): call reset\(\) to start the environment "
                                           r"again$"):
        env.step(dict.fromkeys(env.possible_agents, 0))
    env.reset(seed=0)  # as the message says
    env.step(stay(env))
    env.close()
