"""The generalist (experiments.generalist): one shape across regimes of every family, a policy trained on two
training regimes that runs zero-shot on a test regime of another family and writes the per-episode CSV, and
seed sets that never mix."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from agents import PPOConfig, load_learner
from agents.common import flat_dim, flatten_one
from env import NeighbourField
from experiments import generalist, raw, suite
from experiments.protocol import EPISODES
from orchestrator.scenario import load_scenario

STEPS = 20  # steps of the drawn regimes' episodes: the tests only need them to run


def write_suite(folder, split, indices):
    """Regimes ``indices`` of a split's suite (family: index mod 6) written to ``folder/<split>``."""
    drawn = suite.suite(split, max(indices) + 1, steps=STEPS)
    suite.write([drawn[i] for i in indices], folder / split)
    return folder / split


@pytest.fixture(scope="module")
def suites(tmp_path_factory):
    root = tmp_path_factory.mktemp("suites")
    return {"train": write_suite(root, "train", [0, 1]),  # ring, grid
            "validation": write_suite(root, "validation", [2]),  # random geometric
            "test": write_suite(root, "test", [5])}  # an Ether AoT network: a family training never saw


def test_shapes_are_fixed_across_regimes_of_every_family(tmp_path):
    folder = write_suite(tmp_path, "train", range(6))
    regimes = generalist.read_suite(folder, "train")
    families, obs_spaces, act_spaces, features = set(), set(), set(), set()
    for regime in regimes:
        sc = load_scenario(regime.path)
        families.add(regime.name.split("-", 2)[2])
        env = generalist.regime_env(regime, generalist.SLOTS, max_steps=3)
        try:
            obs, _ = env.reset(seed=EPISODES["train"].seeds(1)[0])
            for agent in env.possible_agents:
                obs_spaces.add(str(env.observation_space(agent)))
                act_spaces.add(str(env.action_space(agent)))
                features.add(flatten_one(obs[agent]).shape)
                degree = len(sc.neighbours[env.node_of[agent]])
                assert obs[agent]["neighbours"].shape == (generalist.SLOTS, len(NeighbourField))
                assert not obs[agent]["action_mask"][1 + degree:].any()  # absent neighbours: never a target
                assert not obs[agent]["neighbours"][degree:].any()
        finally:
            env.close()
    assert families == set(suite.DISTRIBUTION.families)
    assert len(obs_spaces) == len(act_spaces) == 1 and features == {(flat_dim(generalist.SLOTS),)}
    assert act_spaces == {f"Discrete({1 + generalist.SLOTS})"}


def test_neighbour_slots_below_a_degree_and_agent_ids_are_refused(tmp_path):
    ether = generalist.read_suite(write_suite(tmp_path, "test", [5]), "test")[0]
    largest = max(len(v) for v in load_scenario(ether.path).neighbours.values())
    with pytest.raises(ValueError, match=f"neighbour_slots=1 is below the largest degree .* \\({largest}\\)"):
        generalist.regime_env(ether, 1, max_steps=3)
    with pytest.raises(ValueError, match="agent_id=false applies to a shared network"):
        PPOConfig(shared=False, agent_id=False)
    with pytest.raises(ValueError, match="centralised_critic=true needs agent_id=true"):
        PPOConfig(agent_id=False, centralised_critic=True)
    one = generalist.generalist(4, PPOConfig(agent_id=True))  # made for the agent "agent" only
    with pytest.raises(KeyError, match="needs agent_id=false"):
        one.group("ctrl_n0")
    assert generalist.generalist(4, PPOConfig(agent_id=False)).group("ctrl_n0") == "shared"


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_trained_on_two_regimes_it_runs_zero_shot_on_another_family(suites, tmp_path, capsys):
    out = tmp_path / "run"
    generalist.main(["train", "--suite", str(suites["train"]), "--validation", str(suites["validation"]),
                     "--episodes", "4", "--max-steps", str(STEPS), "--checkpoint-every", "2", "--envs", "1",
                     "--set", "rollout_steps=16", "--out", str(out), "--no-progress"])
    log = read_rows(out / "train.csv")
    assert {r["regime"] for r in log} <= {"train-000-ring", "train-001-grid"}
    assert all(int(r["episode_seed"]) in EPISODES["train"] for r in log)
    assert float(log[-1]["updates"]) >= 2  # it learnt: at least two PPO updates of the one shared network
    agents = {r.name: len(load_scenario(r.path).controllers) for r in generalist.read_suite(suites["train"])}
    frames = np.cumsum([int(r["steps"]) * agents[r["regime"]] for r in log])  # agent-steps, the curves' x axis
    assert [int(r["agents"]) for r in log] == [agents[r["regime"]] for r in log]
    assert [int(r["frames"]) for r in log] == frames.tolist()
    checks = read_rows(out / "validation.csv")
    assert [r["checkpoint"] for r in checks] == ["ckpt-00002.pt", "ckpt-00004.pt"]
    assert [int(r["frames"]) for r in checks] == [frames[1], frames[3]]
    assert all(float(r["wall_s"]) > 0 and float(r["penalised_response_time"]) > 0 for r in checks)
    best = max(checks, key=lambda r: float(r["completion_ratio"]))  # the first of equals, as training keeps it
    assert (out / "best.pt").read_bytes() == (out / best["checkpoint"]).read_bytes()
    learner = load_learner(out / "best.pt")
    assert not learner.config.agent_id and learner.config.seed == 0

    csv_path = tmp_path / "test.csv"
    generalist.main(["evaluate", str(out / "best.pt"), "--baselines", "local", "--suite", str(suites["test"]),
                     "--episodes", "2", "--max-steps", str(STEPS), "--modes", "sampled", "greedy",
                     "--csv", str(csv_path), "--no-progress"])
    rows = read_rows(csv_path)
    assert list(rows[0])[:8] == list(raw.KEYS)  # the report's schema: python -m experiments.report reads them
    assert len(raw.read([csv_path])) == len(rows)
    assert {"completion_ratio", "penalised_response_time", "response_time_mean", "dropped"} <= set(rows[0])
    assert [(r["policy"], r["regime"], r["split"], int(r["seed"])) for r in rows] == [
        (p, "test-005-ether", "test", s) for p in ("generalist", "generalist_greedy", "local")
        for s in EPISODES["test"].seeds(2)]
    ratios = np.array([float(r["completion_ratio"]) for r in rows])
    assert ((ratios >= 0) & (ratios <= 1)).all() and all(int(r["steps"]) == STEPS for r in rows)
    assert int(rows[0]["decisions"]) > 0  # the generalist decided on a topology it never saw

    batched = tmp_path / "batched.csv"  # every episode at once over copies: greedy, the same episodes
    generalist.main(["evaluate", str(out / "best.pt"), "--suite", str(suites["test"]), "--episodes", "2",
                     "--max-steps", str(STEPS), "--modes", "greedy", "sampled", "--batched", "--csv", str(batched),
                     "--no-progress"])
    together = read_rows(batched)
    assert [(r["policy"], r["seed"]) for r in together] == [
        (p, str(s)) for p in ("generalist_greedy", "generalist") for s in EPISODES["test"].seeds(2)]
    for a, b in zip([r for r in rows if r["policy"] == "generalist_greedy"], together[:2], strict=True):
        for key in ("generated", "completed", "dropped", "decisions", "steps"):
            assert float(a[key]) == float(b[key]), key
        assert float(a["penalised_response_time"]) == pytest.approx(float(b["penalised_response_time"]), rel=1e-12)

    generalist.main(["evaluate", str(out / "best.pt"), "--scenarios", "examples/n_tier_cloud", "--episodes", "1",
                     "--max-steps", str(STEPS), "--csv", str(csv_path), "--no-progress"])  # a scenario of no suite
    (row,) = read_rows(csv_path)
    assert (row["policy"], row["regime"], row["split"], int(row["seed"])) == (
        "generalist_greedy", "n_tier_cloud", "test", EPISODES["test"].start)  # the default mode


def test_with_envs_it_trains_rounds_of_episodes_of_several_regimes_at_once(suites, tmp_path, capsys):
    out = tmp_path / "vector"
    generalist.main(["train", "--suite", str(suites["train"]), "--validation", str(suites["validation"]),
                     "--episodes", "12", "--envs", "6", "--regimes", "2", "--max-steps", str(STEPS),
                     "--checkpoint-every", "6", "--set", "rollout_steps=30", "--out", str(out), "--no-progress"])
    log = read_rows(out / "train.csv")
    assert [int(r["episode"]) for r in log] == list(range(12))
    assert [int(r["episode_seed"]) for r in log] == EPISODES["train"].seeds(12)  # the serial loop's seeds
    for group in range(4):  # each round: 2 regimes drawn, 3 episodes of each
        assert len({r["regime"] for r in log[3 * group:3 * group + 3]}) == 1
    assert float(log[-1]["updates"]) >= 2 and all(int(r["steps"]) == STEPS for r in log)
    assert [r["checkpoint"] for r in read_rows(out / "validation.csv")] == ["ckpt-00006.pt", "ckpt-00012.pt"]
    assert not load_learner(out / "best.pt").config.agent_id
    for bad, why in ((["--episodes", "5", "--envs", "3"], "--envs 3 runs that many episodes at once: it must "
                      "divide --episodes (5)"), (["--episodes", "6", "--envs", "3", "--checkpoint-every", "3",
                                                  "--regimes", "2"], "--regimes 2 must divide --envs 3")):
        with pytest.raises(SystemExit):
            generalist.main(["train", "--suite", str(suites["train"]), *bad, "--out", str(tmp_path / "bad"),
                             "--no-progress"])
        assert why in capsys.readouterr().err


def test_the_seed_sets_never_mix(suites, tmp_path, capsys):
    def refused(*argv):
        with pytest.raises(SystemExit) as e:
            generalist.main(list(argv))
        assert e.value.code == 2
        return capsys.readouterr().err.strip()

    out = str(tmp_path / "run")
    err = refused("train", "--suite", str(suites["test"]), "--out", out, "--no-progress")
    assert "test-005-ether is a test regime (seed 3000005); this takes train regimes only" in err
    assert len(err.splitlines()) == 1
    err = refused("train", "--suite", str(suites["train"]), "--validation", str(suites["train"]), "--out", out)
    assert "train-000-ring is a train regime" in err and "takes validation regimes only" in err
    forged = tmp_path / "forged"  # a test regime relabelled as a training one
    forged.mkdir()
    manifest = (suites["test"] / "manifest.csv").read_text().replace(",test,", ",train,")
    (forged / "manifest.csv").write_text(manifest)
    (forged / "test-005-ether.yaml").write_text((suites["test"] / "test-005-ether.yaml").read_text())
    err = refused("train", "--suite", str(forged), "--out", out)
    assert "regime seed 3000005 is not of the 'train' regime seeds" in err
    err = refused("train", "--suite", str(suites["train"]), "--slots", "2", "--out", out)
    assert err.endswith("train-001-grid.yaml: an agent has 4 neighbours, more than --slots 2")  # a ring has 2
    assert not (tmp_path / "run").exists()  # refused before any work
    err = refused("evaluate", str(suites["test"] / "manifest.csv"), "--suite", str(suites["test"]),
                  "--csv", str(tmp_path / "x.csv"))
    assert "not a checkpoint of this project's learners" in err
    err = refused("evaluate", "--baselines", "--csv", str(tmp_path / "x.csv"))
    assert err.endswith("nothing to evaluate on: give --suite, --scenarios or both")
    err = refused("evaluate", "--baselines", "greedy", "oracle", "--suite", str(suites["test"]),
                  "--csv", str(tmp_path / "x.csv"))
    assert "--baselines oracle: not a baseline" in err and not (tmp_path / "x.csv").exists()
    err = refused("evaluate", "--baselines", "greedy", "--suite", str(suites["test"]), "--batched", "--backend",
                  "emulator", "--csv", str(tmp_path / "x.csv"))
    assert "--batched plays on the array backend, which does not run test-005-ether (--backend emulator)" in err
