"""examples/mappo_torchrl.py trains (briefly, on 2 simulations stepped together): it runs, its losses are finite,
its rows time collection and updates, and its policy respects the masks; its plot draws several curves against
frames and wall-clock."""

from __future__ import annotations

import csv
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
    curve = tmp_path / "curve.csv"
    args = mappo.parse(["--frames", "3000", "--max-steps", "50", "--envs", "2", "--frames-per-batch", "600",
                        "--minibatch", "300", "--epochs", "2", "--eval-every", "0", "--eval-episodes", "1",
                        "--csv", str(curve)])
    row, actor = mappo.train(args)
    assert row["frames"] == 3000
    # (the mean response time is NaN when nothing completed in so short an episode: the score is defined)
    for key in ("loss_objective", "loss_critic", "loss_entropy", "eval_return", "eval_completed",
                "eval_completion_ratio", "eval_penalised_response_time"):
        assert math.isfinite(row[key]), key
    with open(curve) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5  # one row per batch
    # each batch's time splits into collecting and updating; what is left of the wall-clock is the evaluations
    timed = sum(float(r["collect_s"]) + float(r["update_s"]) for r in rows)
    assert 0 < timed <= float(rows[-1]["wall_s"]) + 0.1  # wall_s is rounded to 0.1 s
    assert all(float(r["collect_s"]) > 0 and float(r["update_s"]) > 0 for r in rows)

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


def write_curve(path, wall_per_batch: float) -> None:
    """A learning curve as train writes it: evaluations every second batch, none in between."""
    mappo = load_example()
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["batch", "frames", "wall_s", *(f"eval_{k}" for k in mappo.EVAL_METRICS)])
        for i in range(4):
            evaluated = [0.5 + i / 10] * len(mappo.EVAL_METRICS) if i % 2 else [""] * len(mappo.EVAL_METRICS)
            writer.writerow([i, 1200 * (i + 1), wall_per_batch * (i + 1), *evaluated])


def test_plot_draws_several_curves_against_frames_and_wall_clock(tmp_path):
    mappo = load_example()
    write_curve(tmp_path / "slow.csv", 10.0)
    write_curve(tmp_path / "fast.csv", 2.0)
    baseline = tmp_path / "local.csv"
    baseline.write_text("completion_ratio,penalised_response_time,return\n0.4,40,100\n0.6,50,300\n")
    png = tmp_path / "curves.png"
    args = mappo.parse(["--plot", f"K = 4={tmp_path / 'slow.csv'}", "--plot", str(tmp_path / "fast.csv"),
                        "--baseline", f"local={baseline}", "--png", str(png)])
    fig = mappo.plot(args.plot, args.png, args.baseline)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    by_frames, by_wall = fig.axes[0], fig.axes[3]  # completion against frames, then against wall-clock
    curves = {line.get_label(): line for line in by_frames.get_lines()}
    assert list(curves) == ["K = 4 (greedy)", "fast (greedy)", "local"]  # "=" inside a label is kept
    assert list(curves["fast (greedy)"].get_xdata()) == [2400.0, 4800.0]  # the evaluated rows only
    assert list(curves["fast (greedy)"].get_ydata()) == [0.6, 0.8]
    assert list(curves["local"].get_ydata()) == [0.5, 0.5]  # the baseline's mean
    walls = {line.get_label(): list(line.get_xdata()) for line in by_wall.get_lines()[:2]}
    assert walls == {"K = 4 (greedy)": [20.0, 40.0], "fast (greedy)": [4.0, 8.0]}


def test_plot_of_a_missing_csv_is_one_line(tmp_path, capsys):
    mappo = load_example()
    with pytest.raises(SystemExit) as exit_info:
        mappo.parse(["--plot", f"K = 4={tmp_path / 'none.csv'}"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(f"{tmp_path / 'none.csv'}: no such CSV file")
