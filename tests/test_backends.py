"""Training and evaluation on either backend: a policy trained on one scores the same on the other, and
``--backend auto`` (training's default) says in one line which backend it chose and why.

The array backend gives the emulator's observations, rewards and infos step for step (tests/test_array_env.py),
so the scores are not close but identical: the same seeds, the same greedy actions, the same episodes.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from experiments import evaluate, train

TINY = ["--scenario", "aot1", "--max-steps", "20", "--no-progress"]


def trained(out: Path, backend: str, capsys: pytest.CaptureFixture) -> Path:
    """A tiny PPO trained on ``backend`` (2 episodes), acting greedily when evaluated."""
    train.main(["ppo", *TINY, "--hidden", "16", "--episodes", "2", "--set", "sample_eval=false",
                "--set", "rollout_steps=10", "--backend", backend, "--out", str(out)])
    capsys.readouterr()
    assert json.loads((out / "config.json").read_text())["backend"] == backend
    return out / "ppo.pt"


def scores(checkpoint: Path, backend: str, csv_path: Path) -> list[dict[str, str]]:
    """experiments.evaluate's rows of ``checkpoint`` on ``backend`` (2 validation episodes), the backend column
    checked and left out."""
    evaluate.main([str(checkpoint), *TINY, "--episodes", "2", "--backend", backend, "--csv", str(csv_path)])
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r.pop("backend") for r in rows] == [backend, backend]
    return rows


@pytest.mark.parametrize("trained_on", ["array", "emulator"])
def test_a_policy_trained_on_one_backend_scores_the_same_on_the_other(tmp_path, capsys, trained_on):
    checkpoint = trained(tmp_path / trained_on, trained_on, capsys)
    on_array = scores(checkpoint, "array", tmp_path / "array.csv")
    on_emulator = scores(checkpoint, "emulator", tmp_path / "emulator.csv")
    assert on_array == on_emulator
    assert len(on_array) == 2 and all(int(r["generated"]) > 0 for r in on_array)  # real episodes, not empty ones


def test_training_on_either_backend_learns_the_same_weights(tmp_path, capsys):
    """Same seed, same episodes: the learner sees the same steps, so its log and its network come out the same."""
    logs = {}
    for backend in ("array", "emulator"):
        trained(tmp_path / backend, backend, capsys)
        with open(tmp_path / backend / "train.csv", newline="") as f:
            logs[backend] = [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]
    assert logs["array"] == logs["emulator"]
    assert (tmp_path / "array" / "ppo.pt").read_bytes() == (tmp_path / "emulator" / "ppo.pt").read_bytes()


def test_auto_trains_on_the_array_backend_where_it_models_the_scenario(tmp_path, capsys):
    train.main(["ppo", *TINY, "--hidden", "16", "--episodes", "1", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m experiments.train: --backend auto: the array backend (it models this scenario: the "
                   "emulator's results, step for step)"]
    assert json.loads((tmp_path / "config.json").read_text())["backend"] == "array"


def test_auto_falls_back_to_the_emulator_for_a_refused_scenario_in_one_line(tmp_path, capsys):
    args = ["ppo", "--scenario", "examples/zigzag_workload", "--max-steps", "5", "--hidden", "16", "--no-progress",
            "--episodes", "1", "--out", str(tmp_path)]
    train.main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m experiments.train: --backend auto: the emulator (scenario zigzag_workload: the array "
                   "backend does not support client sensor has no worker of its own (its tasks would cross the radio))"]
    assert json.loads((tmp_path / "config.json").read_text())["backend"] == "emulator"
    with pytest.raises(SystemExit) as e:  # asked for by name, the array backend's refusal is the user's error
        train.main([*args, "--backend", "array"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not support client sensor has no worker of its own" in err[0]
