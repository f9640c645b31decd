"""The experiment scripts, end to end on a tiny budget: the same code paths as --quick, fewer episodes."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from agents import LEARNERS, DDQNConfig, PPOConfig
from experiments import evaluate, raw, rq1, rq2, train
from experiments.common import learner_config
from experiments.plot import mean_ci
from experiments.sweep import AGENTS

TINY = ["--quick", "--train-episodes", "1", "--eval-episodes", "2", "--max-steps", "25", "--no-progress"]


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def check_outputs(out: Path, study: str, key: str, values: list[str]) -> None:
    rows = read_csv(out / "results.csv")
    assert len(rows) == len(AGENTS) * len(values) * 2  # one row per agent x sweep value x episode
    assert {(r["agent"], r[key], r["episode"]) for r in rows} == {
        (a, v, e) for a in AGENTS for v in values for e in ("0", "1")}
    assert all(not float(r["response_time_mean"]) < 0 and int(r["dropped"]) >= 0 for r in rows)  # NaN: none done
    assert len(read_csv(out / "summary.csv")) == len(AGENTS) * len(values)
    png = (out / f"{study}.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 20_000
    for agent in ("ddqn", "a2c", "ppo"):
        point = f"aot1-lam{values[0] if key == 'lambda' else '0.17'}"
        assert (out / "checkpoints" / point / "seed0" / f"{agent}.pt").is_file()


def check_marl_eval(data: dict[str, Any], tasks: set[str], algorithms: set[str], seeds: set[int]) -> None:
    """marl-eval's documented raw-data format (its README, "Data Structure for Raw Experiment data"), and the
    conditions its DiagnoseData checks: the same algorithms in every task, the same runs for every algorithm,
    the same steps in every run, the same metrics in every step, no comma in an algorithm's name."""
    assert list(data) == ["zenohedge"]
    assert set(data["zenohedge"]) == tasks
    metrics: set[str] | None = None
    for algos in data["zenohedge"].values():
        assert set(algos) == algorithms and not any("," in a for a in algos)
        for runs in algos.values():
            assert set(runs) == {f"seed_{k}" for k in seeds}
            for run in runs.values():
                assert set(run) == {"step_0", "absolute_metrics"}
                step, absolute = run["step_0"], run["absolute_metrics"]
                assert isinstance(step["step_count"], int) and step["step_count"] >= 0
                metrics = metrics or set(step) - {"step_count"}
                assert set(step) - {"step_count"} == metrics == set(absolute)
                lengths = {len(v) for v in [*absolute.values(), *(step[m] for m in metrics)]}
                assert len(lengths) == 1
                assert all(isinstance(x, float) for m in metrics for x in step[m])
    assert metrics and {"return", "response_time_mean", "dropped", "overloaded_node_ticks"} <= metrics
    assert not metrics & {"episode", "seed", "wall_s"}


def same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def test_rq1_quick_writes_csv_and_figure(tmp_path):
    rq1.main([*TINY, "--scenario", "aot1", "--lambdas", "0.1", "0.3", "--out", str(tmp_path)])
    check_outputs(tmp_path, "rq1", "lambda", ["0.1", "0.3"])
    marl = json.loads((tmp_path / "marl_eval.json").read_text())
    check_marl_eval(marl, {"aot1-lam0.1", "aot1-lam0.3"}, set(AGENTS), {0})
    for r in read_csv(tmp_path / "results.csv"):
        step = marl["zenohedge"][f"aot1-lam{r['lambda']}"][r["agent"]]["seed_0"]["step_0"]
        assert same(step["response_time_mean"][int(r["episode"])], float(r["response_time_mean"]))
        assert step["dropped"][int(r["episode"])] == float(r["dropped"])
        assert step["step_count"] == (25 if r["agent"] in LEARNERS else 0)  # 1 training episode of 25 steps
    train_log = read_csv(tmp_path / "train" / "aot1-lam0.1" / "seed0" / "ddqn.csv")
    assert len(train_log) == 1 and {"return", "epsilon", "response_time_mean"} <= set(train_log[0])


def test_several_seeds_give_intervals_over_seeds_and_evaluate_a_baseline_once(tmp_path):
    """Identical copies of a baseline's episodes (evaluation reseeds it from the episode's seed, random too)
    would narrow its interval by the root of the number of seeds; a learner's interval is over its seeds'
    means, what another training run would give."""
    rq1.main([*TINY, "--scenario", "aot1", "--lambdas", "0.3", "--agents", "ppo", "random", "greedy",
              "--seed", "0", "1", "2", "--set", "rollout_steps=10", "--out", str(tmp_path)])
    rows = read_csv(tmp_path / "results.csv")
    seeds = {a: sorted({r["train_seed"] for r in rows if r["agent"] == a}) for a in ("ppo", "random", "greedy")}
    assert seeds == {"ppo": ["0", "1", "2"], "random": ["0"], "greedy": ["0"]}
    summary = {r["agent"]: r for r in read_csv(tmp_path / "summary.csv")}
    assert {a: (r["ci_over"], r["seeds"], r["episodes"]) for a, r in summary.items()} == {
        "ppo": ("seeds", "3", "6"), "random": ("episodes", "1", "2"), "greedy": ("episodes", "1", "2")}
    for agent, r in summary.items():
        by_seed = {}
        for row in rows:
            if row["agent"] == agent:
                by_seed.setdefault(row["train_seed"], []).append(float(row["dropped"]))
        values = [sum(v) / len(v) for v in by_seed.values()] if len(by_seed) > 1 else by_seed["0"]
        mean, half = mean_ci(values)
        assert (float(r["dropped"]), float(r["dropped_ci95"])) == pytest.approx((mean, half))


def test_rq2_counts_the_clusters_of_the_paper_networks_and_their_variants():
    names = ("aot1", "aot4_urgent", "aot3_reference", "ring", "aot2x")
    assert [rq2.clusters(s) for s in names] == [1, 4, 3, None, None]


def test_rq2_quick_writes_csv_and_figure(tmp_path):
    rq2.main([*TINY, "--scenarios", "aot1", "aot2", "--out", str(tmp_path), "--set", "ppo.rollout_steps=10"])
    check_outputs(tmp_path, "rq2", "clusters", ["1.0", "2.0"])


def test_train_then_evaluate_command_lines(tmp_path, capsys):
    train.main(["a2c", "--scenario", "aot1", "--episodes", "1", "--max-steps", "20", "--out", str(tmp_path),
                "--no-progress"])
    evaluate.main([str(tmp_path / "a2c.pt"), "--scenario", "aot1", "--episodes", "2", "--max-steps", "20",
                   "--csv", str(tmp_path / "eval.csv"), "--no-progress"])
    assert "response_time_mean" in capsys.readouterr().out
    assert len(read_csv(tmp_path / "eval.csv")) == 2
    rows = raw.read([tmp_path / "eval.csv"])  # the raw schema experiments.report reads
    assert [(r["policy"], r["train_seed"], r["suite"], r["split"], r["regime"], r["seed"]) for r in rows] == [
        ("a2c", 0, "bundled", "validation", "aot1", 100_000 + k) for k in range(2)]
    # the default reward is the learner's: the paper's for the learners tuned on it, marginal for PPO
    assert json.loads((tmp_path / "config.json").read_text())["reward"] == "paper"
    train.main(["ppo", "--scenario", "aot1", "--episodes", "1", "--max-steps", "20", "--out", str(tmp_path / "ppo"),
                "--no-progress", "--price", "1.5"])
    config = json.loads((tmp_path / "ppo" / "config.json").read_text())
    assert (config["reward"], config["congestion_price"]) == ("marginal", 1.5)
    with pytest.raises(SystemExit):
        train.main(["ppo", "--price", "-1"])
    assert "--price: congestion_price must be a finite number >= 0, not -1.0" in capsys.readouterr().err


def test_evaluate_takes_a_rule_of_your_own_by_import_path(tmp_path, monkeypatch, capsys):
    """A Baseline subclass named module:Class, from the working directory, plays the same episodes."""
    (tmp_path / "myrules.py").write_text(
        "from agents.baselines import Baseline\nfrom node_runtime.model.policies import GreedyBacklog\n\n"
        "class Mine(Baseline):\n    rule = GreedyBacklog\n    name = 'mine'\n")
    monkeypatch.chdir(tmp_path)
    common = ["--scenario", "aot1", "--lam", "0.3", "--episodes", "2", "--max-steps", "40", "--no-progress"]
    evaluate.main(["myrules:Mine", *common, "--csv", "mine.csv"])
    evaluate.main(["greedy_backlog", *common, "--csv", "builtin.csv"])
    mine, builtin = read_csv(tmp_path / "mine.csv"), read_csv(tmp_path / "builtin.csv")
    assert [r["completed"] for r in mine] == [r["completed"] for r in builtin] and int(mine[0]["decisions"]) > 0
    with pytest.raises(SystemExit):
        evaluate.main(["myrules:Nope", *common])
    assert "myrules:Nope: module 'myrules' has no 'Nope'" in capsys.readouterr().err
    # and in a study, beside the built-ins, on the same episodes
    rq1.main(["--agents", "greedy_backlog", "myrules:Mine", "--lambdas", "0.3", "--eval-episodes", "2",
              "--max-steps", "40", "--out", "study", "--no-progress"])
    rows = read_csv(tmp_path / "study" / "results.csv")
    by_agent = {a: [r["completed"] for r in rows if r["agent"] == a] for a in ("greedy_backlog", "myrules:Mine")}
    assert by_agent["myrules:Mine"] == by_agent["greedy_backlog"] and len(by_agent["greedy_backlog"]) == 2


def test_evaluate_adds_its_runs_to_a_marl_eval_file(tmp_path):
    train.main(["a2c", "--scenario", "aot1", "--episodes", "1", "--max-steps", "20", "--seed", "3",
                "--out", str(tmp_path), "--no-progress"])
    common = ["--scenario", "aot1", "--lam", "0.2", "--episodes", "2", "--max-steps", "20", "--no-progress",
              "--marl-eval", str(tmp_path / "marl.json")]
    evaluate.main([str(tmp_path / "a2c.pt"), *common])
    for seed in ("0", "1"):
        evaluate.main(["random", "--seed", seed, *common])
    data = json.loads((tmp_path / "marl.json").read_text())
    assert set(data["zenohedge"]["aot1-lam0.2"]) == {"a2c", "random"}
    assert set(data["zenohedge"]["aot1-lam0.2"]["a2c"]) == {"seed_3"}  # the checkpoint's training seed
    assert data["zenohedge"]["aot1-lam0.2"]["a2c"]["seed_3"]["step_0"]["step_count"] == 20
    assert set(data["zenohedge"]["aot1-lam0.2"]["random"]) == {"seed_0", "seed_1"}
    check_marl_eval({"zenohedge": {"t": {"random": data["zenohedge"]["aot1-lam0.2"]["random"]}}},
                    {"t"}, {"random"}, {0, 1})


@pytest.mark.parametrize(("cli", "argv", "message"), [
    (train, ["ddqn", "--set", "clip_coef=0.1"],
     "--set 'clip_coef=0.1': ddqn has no field 'clip_coef' (it is a field of ppo)"),
    (train, ["ppo", "--set", "clip=0.1"], "--set 'clip=0.1': ppo has no field 'clip' (did you mean 'clip_coef'?)"),
    (train, ["ddqn", "--set", "ppo.clip_coef=0.1"], "--set 'ppo.clip_coef=0.1': ppo is not trained in this run"),
    (rq1, ["--set", "epsilon=1"], "--set 'epsilon=1': none of a2c, ddqn, ppo has a field 'epsilon'"),
    (rq1, ["--agents", "ddqn", "--set", "clip_coef=0.1"], "ddqn has no field 'clip_coef' (it is a field of ppo)"),
    (rq1, ["--agents", "local", "--set", "lr=1"], "--set 'lr=1': no learner among --agents"),
    (train, ["ppo", "--set", "teacher=oracle"], "ppo: teacher must be one of local, random, round_robin,"),
    (rq1, ["--agents", "a2c", "--set", "actor=cnn"], "a2c: actor must be one of targets, mlp, not 'cnn'"),
    (train, ["a2c", "--scenario", "aot9"], "aot9: no such file or bundled scenario (did you mean 'aot4'?); "
                                           "bundled: aot1, aot1_compute, aot1_reference, aot1_urgent, "),
    (rq2, ["--scenarios", "aot1", "nowhere.yaml"], "nowhere.yaml: no such file or bundled scenario"),
    (rq1, ["--agents", "ppo", "best"], "argument --agents: expected one of ddqn, a2c, ppo, local, random, round_robin, "
                                       "least_queue, greedy, greedy_backlog, local_first, threshold, "
                                       "drift_plus_penalty or an import path 'module:Class' (got 'best')"),
    (rq2, ["--agents", "agents.baselines:Nothing"], "argument --agents: module 'agents.baselines' has no 'Nothing'"),
    (evaluate, ["greedy", "--scenario", "aot5"], "aot5: no such file or bundled scenario"),
    (evaluate, ["nothing.pt"], "'nothing.pt' is neither a baseline (local, random,"),
    (rq1, ["--lambdas", "0.1", "-1"], "argument --lambdas: expected an arrival rate >= 0 (tasks/s per source), "
                                      "not '-1'"),
    (rq2, ["--lam", "-1"], "argument --lam: expected an arrival rate >= 0"),
    (evaluate, ["greedy", "--lam", "fast"], "argument --lam: expected an arrival rate >= 0"),
    (train, ["a2c", "--episodes", "0"], "argument --episodes: expected an integer >= 1, not '0'"),
    (rq1, ["--eval-episodes", "-2"], "argument --eval-episodes: expected an integer >= 1, not '-2'"),
    (rq1, ["--max-steps", "1.5"], "argument --max-steps: expected an integer >= 1, not '1.5'"),
    (rq1, ["--seed", "0", "-1"], "argument --seed: expected an integer from 0 to 4611686018427387903, not '-1'"),
    (rq1, ["--cpus-per-run", "0"], "argument --cpus-per-run: expected a number > 0, not '0'"),
    (rq1, ["--seed", "1", "2", "1"], "--seed 1 2 1: a seed is given more than once"),
    (rq1, ["--ray-cpus", "2"], "--ray-cpus sizes the local Ray of --ray"),
    (rq2, ["--ray", "--ray-address", "auto"], "--ray starts a local Ray, --ray-address joins a running one"),
])
def test_user_errors_are_one_line_and_exit_2(cli, argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # where the default output directories would go
    with pytest.raises(SystemExit) as e:
        cli.main([*argv, "--no-progress"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"experiments.{cli.__name__.rpartition('.')[2]}: error: " in err
    assert message in err
    assert not list(tmp_path.iterdir())


def test_a_user_error_prints_no_traceback():
    proc = subprocess.run([sys.executable, "-m", "experiments.train", "ppo", "--set", "ppo.clip=0.1"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == ("python -m experiments.train: error: --set 'ppo.clip=0.1': ppo has no field 'clip' "
                           "(did you mean 'clip_coef'?)\n")


def test_overrides_reach_the_right_learner():
    every = list(LEARNERS)
    ppo = learner_config("ppo", seed=3, reward="paper", hidden=[16], chosen=every,
                         overrides=["ppo.clip_coef=0.1", "lr=1e-3", "ddqn.tau=0.5", "centralised_critic=true",
                                    "target_kl=none"])
    assert isinstance(ppo, PPOConfig) and ppo.hidden == (16,) and ppo.seed == 3 and ppo.clip_coef == 0.1
    assert ppo.lr == 1e-3 and ppo.centralised_critic is True and ppo.target_kl is None
    ddqn = learner_config("ddqn", seed=0, reward="paper", base={"learning_starts": 7}, chosen=every,
                          overrides=["ddqn.tau=0.5", "hidden=8,8", "clip_coef=0.3"])
    assert isinstance(ddqn, DDQNConfig) and ddqn.tau == 0.5 and ddqn.learning_starts == 7 and ddqn.hidden == (8, 8)


@pytest.mark.parametrize(("algo", "chosen", "item", "message"), [
    ("ppo", (), "ppo.clip=0.1", "--set 'ppo.clip=0.1': ppo has no field 'clip' (did you mean 'clip_coef'?)"),
    ("ppo", (), "nonsense=1", "--set 'nonsense=1': ppo has no field 'nonsense'"),
    ("ddqn", (), "clip_coef=0.1", "--set 'clip_coef=0.1': ddqn has no field 'clip_coef' (it is a field of ppo)"),
    ("ddqn", (), "ppo.lr=0.1", "--set 'ppo.lr=0.1': ppo is not trained in this run (ddqn)"),
    ("ddqn", ("ddqn", "a2c"), "dqn.tau=1", "unknown algorithm 'dqn' (did you mean 'ddqn'?)"),
    ("ddqn", (), "tau=fast", "--set 'tau=fast': expected a number or none, not 'fast'"),
    ("ddqn", (), "tau", "--set 'tau': expected [ALGO.]FIELD=VALUE"),
])
def test_overrides_that_reach_no_learner_are_errors(algo, chosen, item, message):
    with pytest.raises(ValueError) as e:
        learner_config(algo, seed=0, reward="paper", chosen=chosen, overrides=[item])
    assert message in str(e.value)


def test_on_the_marginal_reward_the_learners_take_credit_per_task():
    for algo in ("ppo", "a2c", "ddqn"):
        config = learner_config(algo, seed=0, reward="marginal")
        assert (config.credit, config.gamma, config.normalize_reward) == ("task", 0.0, True)
        config = learner_config(algo, seed=0, reward="marginal", overrides=["credit=step", "gamma=0.99"])
        assert (config.credit, config.gamma) == ("step", 0.99)
        assert learner_config(algo, seed=0, reward="paper").credit == "step"
    with pytest.raises(ValueError, match="ppo: credit=task learns from the marginal reward's credits per task, not "
                                         "from 'paper'"):
        learner_config("ppo", seed=0, reward="paper", overrides=["credit=task"])


def test_confidence_interval_uses_student_t():
    mean, half = mean_ci([1.0, 2.0, 3.0])
    assert mean == 2.0 and half == pytest.approx(4.303 * 1.0 / 3**0.5)
    assert mean_ci([5.0]) == (5.0, 0.0)


def test_the_studies_accept_every_learner_and_every_baseline():
    """The studies' agent list is the registries', not a copy of them (greedy_backlog was once refused)."""
    from agents import BASELINES, LEARNERS
    from experiments.sweep import parser

    args = parser("rq1", "test").parse_args(["--agents", *LEARNERS, *BASELINES])
    assert args.agents == [*LEARNERS, *BASELINES]
