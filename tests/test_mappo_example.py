"""examples/mappo_torchrl.py trains (briefly, on 2 simulations stepped together): it runs, its losses are finite,
and its policy respects the masks."""

from __future__ import annotations

import importlib.util
import math

import pytest
import torch

pytest.importorskip("torchrl")

from torchrl.envs import PettingZooWrapper

from env import ZenohEdgeEnv
from tests.conftest import ROOT


def load_example():
    spec = importlib.util.spec_from_file_location("mappo_torchrl", ROOT / "examples" / "mappo_torchrl.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_mappo_trains_with_finite_losses_and_masked_actions(tmp_path):
    mappo = load_example()
    csv = tmp_path / "curve.csv"
    args = mappo.parse(["--frames", "3000", "--max-steps", "50", "--envs", "2", "--frames-per-batch", "600",
                        "--minibatch", "300", "--epochs", "2", "--eval-every", "0", "--eval-episodes", "1",
                        "--csv", str(csv)])
    row, actor = mappo.train(args)
    assert row["frames"] == 3000
    # (the mean response time is NaN when nothing completed in so short an episode: the score is defined)
    for key in ("loss_objective", "loss_critic", "loss_entropy", "eval_return", "eval_completed",
                "eval_completion_ratio", "eval_penalised_response_time"):
        assert math.isfinite(row[key]), key
    assert len(csv.read_text().splitlines()) == 1 + 5  # header and one row per batch

    base = ZenohEdgeEnv("aot2", transport="inproc", observation="flat", max_steps=50)
    env = PettingZooWrapper(base, use_mask=True, categorical_actions=True, group_map={"agents": base.possible_agents})
    td = env.rollout(60, actor, break_when_any_done=False)  # sampled actions, across an episode end
    mask, action = td["agents", "action_mask"], td["agents", "action"]
    assert (~mask).any()  # some choices were forbidden ...
    assert mask.gather(-1, action.unsqueeze(-1)).all()  # ... and none was taken
    assert (td["next", "agents", "info", "invalid_action"] == 0).all()
    observations, _ = base.reset(seed=1)
    for _ in range(30):  # the greedy policy the evaluation uses
        actions = mappo.greedy_actions(actor, observations, base.possible_agents)
        assert all(observations[a]["action_mask"][i] for a, i in actions.items())
        observations, *_ = base.step(actions)
    assert torch.isfinite(td["next", "agents", "reward"]).all()
    env.close()


def test_envs_must_divide_the_batch():
    mappo = load_example()
    with pytest.raises(SystemExit):
        mappo.parse(["--envs", "4", "--frames-per-batch", "1001"])
    with pytest.raises(SystemExit):
        mappo.parse(["--envs", "0"])
