"""Per-task credit: the ledger the nodes keep, the credit the environment derives from it, and the learners
that wait for it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agents.baselines import BASELINES
from agents.common import AgentSpec
from agents.ddqn import DDQN, DDQNConfig
from agents.learner import LearnerConfig, OpenTransition
from agents.onpolicy import Record, credited, uncredited_removed
from agents.ppo import PPO, PPOConfig
from env import ZenohEdgeEnv
from env.credit import TaskCredit
from env.reward import CONGESTION_PRICE, RewardSettings
from node_runtime.model.role import CHARGED, COMPLETED, LOST


def test_a_completed_task_is_credited_its_timeliness_less_its_charges():
    credit = TaskCredit(100.0, RewardSettings(congestion_price=3.0))
    assert credit.place("a", 3, [11]) == {}
    assert credit.place("b", 4, [12]) == {}
    # 11 imposed 0.1 + 0.05 deadlines of waiting; it completes in 20 s: 1 - 20/100 - 3 * 0.15 = 0.35
    assert credit.settle([(11, CHARGED, 0.1), (12, CHARGED, 0.2)]) == {}
    assert credit.settle([(11, CHARGED, 0.05), (11, COMPLETED, 20.0)]) == {"a": [(3, pytest.approx(0.35))]}
    # 12 is lost: 0 - 3 * 0.2
    assert credit.settle([(12, LOST, 0.0)]) == {"b": [(4, pytest.approx(-0.6))]}


def test_a_decision_is_credited_once_all_its_tasks_settle():
    credit = TaskCredit(50.0, RewardSettings())
    credit.place("a", 0, [1, 2])  # batch mode: one decision places two tasks
    assert credit.settle([(1, COMPLETED, 10.0)]) == {}
    assert credit.settle([(2, COMPLETED, 25.0)]) == {"a": [(0, pytest.approx(0.8 + 0.5))]}


def test_a_task_placed_twice_credits_both_decisions():
    credit = TaskCredit(100.0, RewardSettings())
    credit.place("a", 0, [7])  # offloaded by a ...
    credit.place("b", 2, [7])  # ... and placed again by b (max_hops 2)
    assert credit.settle([(7, COMPLETED, 40.0)]) == {"a": [(0, pytest.approx(0.6))], "b": [(2, pytest.approx(0.6))]}


def test_a_decision_on_a_task_already_gone_is_credited_zero_at_once():
    credit = TaskCredit(100.0, RewardSettings())
    assert credit.settle([(9, LOST, 0.0), (8, CHARGED, 1.0)]) == {}  # nobody placed them: nothing to credit
    assert credit.place("a", 1, [9]) == {"a": [(1, 0.0)]}
    credit.place("a", 2, [8])  # a charge alone does not settle a task
    assert credit.settle([(8, LOST, 0.0)]) == {"a": [(2, 0.0)]}
    assert credit.settle([(8, CHARGED, 1.0)]) == {}  # after it settled: not credited


def test_memory_of_settled_tasks_stays_flat_and_keeps_the_latest(monkeypatch):
    monkeypatch.setattr("env.credit.SETTLED_MEMORY", 4)
    credit = TaskCredit(100.0, RewardSettings())
    credit.settle([(task, LOST, 0.0) for task in range(1, 11)])
    assert len(credit._settled) + len(credit._settled_before) <= 2 * 4
    assert credit.place("a", 0, [10]) == {"a": [(0, 0.0)]}  # among the latest: gone, credited 0 at once
    assert credit.place("a", 1, [1]) == {}  # long forgotten: it waits for a credit that never comes


class Recording(TaskCredit):
    """Keeps every decision placed and every ledger entry applied, for an oracle to recompute the credits."""

    def reset(self) -> None:
        super().reset()
        self.entries, self.placed = [], []

    def place(self, agent, step, tasks):
        tasks = list(tasks)
        self.placed.append((agent, step, tasks))
        return super().place(agent, step, tasks)

    def settle(self, ledger):
        self.entries += ledger
        return super().settle(ledger)


def episode(scenario, steps, policy="greedy_backlog", seed=5):
    env = ZenohEdgeEnv(scenario, transport="inproc", reward="marginal", max_steps=steps)
    env.credit = Recording(env.penalty, env.reward_settings)
    obs, _ = env.reset(seed=seed)
    rule = BASELINES[policy](0)
    rule.reset(seed)
    credits = {}
    while env.agents:
        obs, _, _, _, infos = env.step(rule.act(obs))
        for a, i in infos.items():
            for step, value in i["credits"]:
                assert (a, step) not in credits
                credits[(a, step)] = value
    summary = env.summary()
    env.close()
    return env.credit, credits, summary


@pytest.mark.parametrize(("scenario", "policy"), [("aot1_wired", "greedy_backlog"), ("aot1_urgent", "round_robin"),
                                                  ("aot2_compute", "local_first")])
def test_each_decision_is_credited_what_its_tasks_did_once_they_all_settled(scenario, policy):
    record, credits, summary = episode(scenario, 150, policy)
    outcome, charges = {}, {}
    for task, kind, value in record.entries:
        if kind == CHARGED:
            charges[task] = charges.get(task, 0.0) + value * (task not in outcome)  # none after it settled
        else:
            outcome.setdefault(task, 1.0 - value / summary["penalty_s"] if kind == COMPLETED else 0.0)
    expected = {}
    for agent, step, tasks in record.placed:
        if all(t in outcome for t in tasks):
            expected[(agent, step)] = sum(outcome[t] - CONGESTION_PRICE * charges.get(t, 0.0) for t in tasks)
    assert credits.keys() == expected.keys()
    assert all(credits[k] == pytest.approx(v, abs=1e-12) for k, v in expected.items())
    assert any(v > 0.5 for v in credits.values()) and any(v < 0 for v in credits.values())
    # what is left uncredited is what the network still held at the end
    assert 0 < len(record.placed) - len(credits) <= summary["totals"]["in_system"]


def test_the_ledger_accounts_for_every_completion_loss_and_charge():
    record, _, s = episode("aot1_wired", 150, "round_robin", seed=3)
    entries = record.entries
    assert sum(v for _, kind, v in entries if kind == CHARGED) == pytest.approx(s["delay_imposed"], rel=1e-9)
    assert s["delay_imposed"] > 0
    assert sum(kind == COMPLETED for _, kind, _ in entries) == s["totals"]["completed"]
    assert sum(kind == LOST for _, kind, _ in entries) == s["totals"]["dropped"]["total"]
    times = sorted(v for _, kind, v in entries if kind == COMPLETED)
    assert sum(times) == pytest.approx(s["response_time"]["mean"] * len(times))


def specs(n_agents=2, slots=2):
    return {f"ctrl_{i}": AgentSpec(slots, slots + 1) for i in range(n_agents)}


class StepOnly(DDQN):
    """A user's learner that does not wait for credits."""

    name = "step_only"
    task_credit = False


def test_a_learner_that_does_not_wait_for_credits_refuses_task_credit():
    with pytest.raises(ValueError, match="credit must be one of step, task"):
        LearnerConfig(credit="tasks")
    with pytest.raises(ValueError, match="step_only learns from step rewards only"):
        StepOnly(specs(), DDQNConfig(credit="task"))


def test_ddqn_stores_a_transition_once_its_credit_comes_and_never_one_without():
    env = ZenohEdgeEnv("aot1_wired", transport="inproc", reward="marginal", max_steps=60)
    ddqn = DDQN.for_env(env, DDQNConfig(credit="task", gamma=0.0, reward_scale=1.0, learning_starts=10**6))
    ddqn.start_training(120)
    obs, _ = env.reset(seed=2)
    credits, late = {}, 0
    while env.agents:
        obs, rewards, term, trunc, infos = env.step(ddqn.explore(obs))
        waiting = {(w[0].agent, w[0].pending.step) for w in ddqn.uncredited_closed}
        ddqn.observe(rewards, obs, term, trunc, {a: i["credits"] for a, i in infos.items()})
        for agent, info in infos.items():
            for step, value in info["credits"]:
                credits[(agent, step)] = value
                late += (agent, step) in waiting  # closed before its credit came: it waited for it
    stored = sorted(float(r) for net in ddqn.nets.values() for r in net.buffer.reward[:len(net.buffer)])
    assert late > 0
    assert stored == pytest.approx(sorted(credits.values()), abs=1e-6)  # the credits, each once, and nothing else
    assert any(v < 0 for v in stored) and any(v > 0.5 for v in stored)
    left = len(ddqn.uncredited_closed)  # every decision closed at the end; these tasks outlive the episode
    assert left and all(w[0].pending.credit is None for w in ddqn.uncredited_closed)
    ddqn.reset(3)
    assert not ddqn.uncredited_closed and ddqn.uncredited == left
    env.close()


def record(agent, credit):
    return Record(agent, np.zeros(1), np.zeros(1), np.ones(2, bool), 0, 0.0, 0.0, 0.0, 1.0, 0.0, False,
                  source=OpenTransition(np.zeros(1), np.ones(2, bool), 0, credit=credit))


def test_an_agents_records_wait_from_its_first_decision_without_credit():
    rs = [record("a", 1.0), record("b", None), record("a", None), record("b", 2.0), record("a", 3.0), record("c", 0.0)]
    ready, waiting = credited(rs)
    assert ready == [rs[0], rs[5]] and waiting == [rs[1], rs[2], rs[3], rs[4]]


def test_task_credit_trains_on_the_environments_credits():
    env = ZenohEdgeEnv("aot1_wired", transport="inproc", reward="marginal", max_steps=44, uniform_spaces=True)
    ppo = PPO.for_env(env, PPOConfig(credit="task", rollout_steps=8, normalize_reward=False, reward_scale=1.0))
    ppo.start_training(80)
    obs, _ = env.reset(seed=2)
    while not any(o["task"][0] for o in obs.values()):
        obs, *_ = env.step(dict.fromkeys(env.agents, 0))
    ppo.explore(obs)
    opened = len(ppo.awaiting)
    with pytest.raises(ValueError, match="pass them to observe"):
        ppo.observe(dict.fromkeys(env.agents, 0.0), obs, {}, {})
    obs, _ = env.reset(seed=2)
    ppo.reset(2)  # the decisions above never get their credit: they are learnt as 0, and counted
    assert opened and ppo.uncredited == opened
    seen, held = {}, []
    while env.agents:
        obs, rewards, term, trunc, infos = env.step(ppo.explore(obs))
        ppo.observe(rewards, obs, term, trunc, {a: i["credits"] for a, i in infos.items()})
        seen.update({(a, step): value for a, i in infos.items() for step, value in i["credits"]})
        if ppo.env_steps % 8 == 0:  # just updated: what was held back waits for its credit
            held.append(sum(len(records) for records in ppo.rollout.values()))
    assert max(held) > 0
    assert ppo.updates > 0 and ppo.uncredited == opened
    left = set(ppo.awaiting)  # decisions whose tasks outlive the episode
    assert left
    waiting = [r for records in ppo.rollout.values() for r in records]
    assert all(r.source.credit == pytest.approx(seen[(r.agent, r.source.step)]) for r in waiting
               if r.source.credit is not None)
    ppo.reset(3)  # the next episode: what will never be credited is not learnt
    assert ppo.uncredited == opened + len(left) and not ppo.awaiting
    kept = [r for records in ppo.rollout.values() for r in records]
    assert kept and all(r.source.credit is not None for r in kept)
    batch = ppo.batch(kept)
    assert np.isfinite(batch["advantage"].numpy()).all()
    env.close()


def test_a_chain_ends_where_a_decision_without_credit_is_removed():
    rs = [record("a", 1.0), record("a", None), record("b", 2.0), record("a", 3.0)]
    kept = uncredited_removed(rs)
    assert kept == [rs[0], rs[2], rs[3]] and rs[0].last and not rs[2].last and not rs[3].last


def test_the_example_of_docs_env_md_runs_and_prints_credits(capsys):
    text = (Path(__file__).resolve().parents[1] / "docs" / "env.md").read_text()
    section = text[text.index("## Credit per task"):]
    block = section[section.index("```python\n") + len("```python\n"):]
    block = block[:block.index("```")]
    exec(compile(block.replace("max_steps=400", "max_steps=150"), "docs/env.md", "exec"), {})
    lines = capsys.readouterr().out.splitlines()
    assert lines and all("'s decision at step " in line for line in lines)
