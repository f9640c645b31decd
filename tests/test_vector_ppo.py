"""``agents.vector_ppo``: PPO over K copies of the array backend learns from what the serial learner would.

The comparison runs K serial environments (Dict observations, ``ZenohEdgeEnv(backend="array")``, each its own
seed) and the vectorised loop's ``BatchedSteps`` over K copies with the same seeds, giving both the same actions
(drawn among those the masks allow): at every step the learner's features of every deciding agent must be the
same arrays, and the per-task credits that come (``ArrayCredit`` against the environments' ``TaskCredit``,
``infos[agent]["credits"]``) the same decisions with the same floats, at the same step. Then the loop itself:
deterministic for a seed, every decision either learnt from or counted as uncredited, and its checkpoint an
ordinary PPO checkpoint that acts on the emulator.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import torch

from agents import PPO
from agents.common import AgentSpec
from agents.ppo import PPOConfig
from agents.training import evaluate, run_episode
from agents.vector_ppo import Regime, VectorPPO
from env import ZenohEdgeEnv
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT
from tests.test_array_env import draw

SLOTS = 20


def learner(**settings: Any) -> PPO:
    config = PPOConfig(**{"shared": True, "agent_id": False, "credit": "task", "gamma": 0.0, "seed": 3,
                          "hidden": (16, 16), **settings})
    return PPO({"agent": AgentSpec(slots=SLOTS, n_actions=1 + SLOTS)}, config)


def flat_env(scenario: Any, steps: int, **kwargs: Any) -> ZenohEdgeEnv:
    return ZenohEdgeEnv(scenario, observation="flat", backend="array", transport="inproc", neighbour_slots=SLOTS,
                        max_steps=steps, reward="marginal", info_numbers=False, **kwargs)


def serial(scenario: Any, seed: int, steps: int, ppo: PPO, **kwargs: Any) -> list[dict[str, Any]]:
    """One serial episode with random valid actions: per step, the actions, the deciding agents' features and
    the credits the step's infos carry (agent -> [(step, credit)])."""
    env = ZenohEdgeEnv(scenario, seed=seed, backend="array", transport="inproc", neighbour_slots=SLOTS,
                       max_steps=steps, reward="marginal", **kwargs)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset()
    out = []
    while env.agents:
        actions = draw(rng, obs)
        features = {a: ppo.features(a, o) for a, o in obs.items() if o["task"][0] == 1}
        obs, _, _, _, infos = env.step(actions)
        out.append({"actions": actions, "features": features,
                    "credits": {a: sorted(i["credits"]) for a, i in infos.items() if i["credits"]}})
    env.close()
    return out


@pytest.mark.parametrize("scenario", ["aot2", load_scenario("aot2").replace(max_hops=2)], ids=["aot2", "max_hops2"])
def test_features_and_credits_are_the_serial_learners_step_for_step(scenario):
    steps, seeds = 120, [11, 12]
    ppo = learner()
    runs = [serial(scenario, s, steps, ppo) for s in seeds]
    regime = Regime(ppo, flat_env(scenario, steps), len(seeds))
    batched, credit = regime.steps, regime.credit
    observation, mask, _ = batched.reset(seeds)
    credit.reset(len(seeds), batched.sim.m)
    agents = batched.agents
    waiting: list[tuple[int, int, int, int]] = []  # (copy, agent, step, task) of decisions without credit
    compared = 0
    for step in range(steps):
        dc, da = np.nonzero(batched.present[:, :, 0])
        x = regime.features(observation[dc, da], da)
        for row, (c, a) in enumerate(zip(dc.tolist(), da.tolist(), strict=True)):
            assert np.array_equal(x[row], runs[c][step]["features"][agents[a]]), (step, c, agents[a])
        assert len(dc) == sum(len(r[step]["features"]) for r in runs)
        actions = np.array([[r[step]["actions"][a] for a in agents] for r in runs])
        task = batched.shown[dc, da, 0]
        came: list[dict[str, list]] = [{} for _ in seeds]
        for c, a, i, gone in zip(dc.tolist(), da.tolist(), task.tolist(), credit.place(dc, task).tolist(),
                                 strict=True):
            if gone:
                came[c].setdefault(agents[a], []).append((step, 0.0))
            else:
                waiting.append((c, a, step, i))
        observation, mask, _, _, _ = batched.step(actions, mask)
        for ledger in batched.ledgers:
            credit.settle(ledger)
        still = []
        for c, a, s, i in waiting:
            value = credit.credit[c, i]
            if np.isnan(value):
                still.append((c, a, s, i))
            else:
                came[c].setdefault(agents[a], []).append((s, float(value)))
        waiting = still
        for c, run in enumerate(runs):
            assert {a: sorted(v) for a, v in came[c].items()} == run[step]["credits"], (step, c)
            compared += sum(map(len, run[step]["credits"].values()))
    assert compared > 100  # the comparison saw credits come, not an empty episode


def train(seed: int, episodes: int = 2, k: int = 3, scenarios: tuple[str, ...] = ("aot1",),
          **settings: Any) -> tuple[VectorPPO, list[dict]]:
    """``episodes`` rounds of K copies of each scenario stepped together."""
    ppo = learner(seed=seed, rollout_steps=8 * k * len(scenarios), **settings)
    regimes = [Regime(ppo, flat_env(s, 40), k) for s in scenarios]
    trainer = VectorPPO(ppo)
    ppo.start_training(episodes * k * len(scenarios) * 40)
    rows = []
    for e in range(episodes):
        seeds = [[seed * 100 + (e * len(scenarios) + g) * k + c for c in range(k)] for g in range(len(scenarios))]
        rows += [row for out in trainer.episode(regimes, seeds) for row in out]
    return trainer, rows


def test_training_is_deterministic_and_loses_no_decision():
    a, rows = train(seed=1)
    b, _ = train(seed=1)
    c, _ = train(seed=2)
    for name, tensor in a.learner.nets["shared"].state_dict().items():
        assert torch.equal(tensor, b.learner.nets["shared"].state_dict()[name]), name
    assert any(not torch.equal(t, c.learner.nets["shared"].state_dict()[n])
               for n, t in a.learner.nets["shared"].state_dict().items())
    assert len(rows) == 6 and a.learner.updates >= 4
    assert a.table.rows == 0  # every episode ends with its decisions learnt from or dropped
    decided = sum(r["decisions"] for r in rows)  # each row: its episode's decisions over all copies, per copy
    assert a.learnt + a.learner.uncredited == pytest.approx(decided)
    assert all(np.isfinite(r["policy_loss"]) for r in rows[3:])


def test_step_credit_and_discounting_train_too():
    trainer, rows = train(seed=4, credit="step", gamma=0.9, gae_lambda=0.95)
    assert trainer.learner.uncredited == 0 and trainer.table.rows == 0
    assert trainer.learnt == pytest.approx(sum(r["decisions"] for r in rows))


def test_regimes_of_different_sizes_train_together():
    trainer, rows = train(seed=6, scenarios=("aot1", "aot2"))
    assert len(rows) == 12 and trainer.learner.updates >= 4 and trainer.table.rows == 0
    assert trainer.learnt + trainer.learner.uncredited == pytest.approx(sum(r["decisions"] for r in rows))
    assert {r["generated"] > 0 for r in rows} == {True}


def test_its_checkpoint_acts_on_the_emulator(tmp_path):
    trainer, _ = train(seed=5, episodes=1)
    trainer.learner.save(tmp_path / "ppo.pt")
    loaded = PPO.load(tmp_path / "ppo.pt")
    env = ZenohEdgeEnv("aot1", backend="emulator", transport="inproc", neighbour_slots=SLOTS, max_steps=30)
    rows = evaluate(env, loaded, 1)
    env.close()
    assert rows[0]["generated"] > 0 and rows[0]["steps"] == 30


def test_playing_greedy_is_the_serial_greedy_policy_episode_for_episode():
    trainer, _ = train(seed=7, episodes=1)  # a policy that is not uniform
    ppo = trainer.learner
    ppo.config.sample_eval = False  # the serial evaluation's greedy policy
    steps, seeds = 60, [[21, 22], [23]]
    regimes = [Regime(ppo, flat_env(name, steps), len(s)) for name, s in zip(("aot1", "aot2"), seeds, strict=True)]
    before = (ppo.env_steps, ppo.updates, {k: v.clone() for k, v in ppo.nets["shared"].state_dict().items()})
    played = trainer.play(regimes, seeds, greedy=True)
    for name, rows, regime_seeds in zip(("aot1", "aot2"), played, seeds, strict=True):
        env = ZenohEdgeEnv(name, backend="emulator", transport="inproc", neighbour_slots=SLOTS, max_steps=steps,
                           reward="marginal")
        for row, seed in zip(rows, regime_seeds, strict=True):
            expected = run_episode(env, ppo, seed)
            for key in ("steps", "decisions", "generated", "completed", "dropped", "completion_ratio",
                        "penalised_response_time"):
                assert row[key] == pytest.approx(expected[key], rel=1e-12), (name, seed, key)
            assert row["return"] == pytest.approx(expected["return"], rel=1e-9)
        env.close()
    assert trainer.table.rows == 0 and (ppo.env_steps, ppo.updates) == before[:2]  # nothing learnt, nothing kept
    assert all(torch.equal(v, before[2][k]) for k, v in ppo.nets["shared"].state_dict().items())

    def completed(greedy: bool) -> list[float]:
        return [row["completed"] for rows in trainer.play(regimes, seeds, greedy) for row in rows]

    assert completed(False) == completed(False)  # sampled: one stream from the first seed, the same episodes
    assert completed(False) != completed(True)  # ... and not the most likely actions
    for regime in regimes:
        regime.close()


@pytest.mark.parametrize("settings, scenario, why", [
    ({"centralised_critic": True, "agent_id": True}, "aot1", "centralised_critic"),
    ({"teacher": "greedy"}, "aot1", "teacher"),
    ({}, load_scenario("aot1").replace(mode="batch", batch_size=2), "binary mode"),
])
def test_what_it_cannot_train_is_refused_in_one_line(settings, scenario, why):
    with pytest.raises(ValueError, match=why):
        Regime(learner(**settings), flat_env(scenario, 20), 2)


def test_experiments_train_takes_envs(tmp_path, capsys):
    from experiments import train as train_command

    out = tmp_path / "ppo"
    train_command.main(["ppo", "--scenario", "aot1", "--episodes", "4", "--envs", "2", "--max-steps", "60",
                        "--set", "rollout_steps=20", "--out", str(out), "--no-progress"])
    rows = (out / "train.csv").read_text().splitlines()
    assert len(rows) == 5 and rows[0].startswith("episode,seed,steps,decisions,return")
    assert [int(r.split(",")[1]) for r in rows[1:]] == [0, 1, 2, 3]  # the serial loop's episode seeds
    assert PPO.load(out / "ppo.pt").updates >= 1
    with pytest.raises(SystemExit):
        train_command.main(["ddqn", "--scenario", "aot1", "--episodes", "4", "--envs", "2", "--out", str(out),
                            "--no-progress"])
    assert "--envs 2 trains ppo on the array backend" in capsys.readouterr().err


def test_the_training_benchmark_times_both_loops(tmp_path):
    out = tmp_path / "speed.csv"
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "training.py"), "--episodes", "1", "--ks", "2",
                    "--max-steps", "20", "--csv", str(out)], check=True, cwd=ROOT, timeout=300, capture_output=True)
    rows = list(csv.DictReader(out.open()))
    assert [r["loop"] for r in rows] == ["serial", "vector 2"]
    assert [int(r["steps"]) for r in rows] == [20, 40] and all(float(r["steps_per_s"]) > 0 for r in rows)
