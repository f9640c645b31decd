"""The experiment scripts, end to end on a tiny budget: the same code paths as --quick, fewer episodes."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from agents import LEARNERS, DDQNConfig, PPOConfig
from experiments import evaluate, rq1, rq2, train
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


def test_rq1_quick_writes_csv_and_figure(tmp_path):
    rq1.main([*TINY, "--scenario", "aot1", "--lambdas", "0.1", "0.3", "--out", str(tmp_path)])
    check_outputs(tmp_path, "rq1", "lambda", ["0.1", "0.3"])
    train_log = read_csv(tmp_path / "train" / "aot1-lam0.1" / "seed0" / "ddqn.csv")
    assert len(train_log) == 1 and {"return", "epsilon", "response_time_mean"} <= set(train_log[0])


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


def test_overrides_reach_the_right_learner():
    every = list(LEARNERS)
    ppo = learner_config("ppo", seed=3, hidden=[16], chosen=every,
                         overrides=["ppo.clip_coef=0.1", "lr=1e-3", "ddqn.tau=0.5", "centralised_critic=true",
                                    "target_kl=none"])
    assert isinstance(ppo, PPOConfig) and ppo.hidden == (16,) and ppo.seed == 3 and ppo.clip_coef == 0.1
    assert ppo.lr == 1e-3 and ppo.centralised_critic is True and ppo.target_kl is None
    ddqn = learner_config("ddqn", seed=0, base={"learning_starts": 7}, chosen=every,
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
        learner_config(algo, seed=0, chosen=chosen, overrides=[item])
    assert message in str(e.value)


def test_confidence_interval_uses_student_t():
    mean, half = mean_ci([1.0, 2.0, 3.0])
    assert mean == 2.0 and half == pytest.approx(4.303 * 1.0 / 3**0.5)
    assert mean_ci([5.0]) == (5.0, 0.0)
