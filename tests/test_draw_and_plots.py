"""`orchestrator topology` (network pictures) and `orchestrator plot` (time series of a finished run)."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from orchestrator.cli import build_parser
from orchestrator.cli import main as cli_main
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from orchestrator.viewers import plots
from orchestrator.viewers.draw import draw_topology
from orchestrator.viewers.plots import PlotError, load_run, plot_run
from tests.conftest import ROOT, write_scenario

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
FIGURES = ["overview.png", "queues.png", "drops.png", "response_time.png", "energy.png"]
N_TIER = {"name": "ntier", "topology": {"generator": {"kind": "n_tier", "tiers": [6, 3, 1],
                                                      "profiles": ["tier0", "tier1", "tier2"], "cloud": "tier2"}}}
NO_POSITIONS = {"name": "nopos", "topology": {
    "nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b"}, {"id": "c", "profile": "tier2"},
              {"id": "s", "worker": False, "client": True}],
    "links": [["a", "b"], ["b", "c"], ["c", "a"], ["s", "a"]]}}


def assert_png(path: Path, min_height: int = 500, min_width: int = 800) -> np.ndarray:
    assert path.is_file()
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = matplotlib.image.imread(path)
    assert image.shape[0] >= min_height and image.shape[1] >= min_width, image.shape
    assert image[..., :3].std() > 0.05  # not a blank canvas
    return image


def parser() -> argparse.ArgumentParser:
    return build_parser()


def run_command(argv: list[str]) -> int:
    """The real command line, user errors included (one line on stderr, exit 2)."""
    return cli_main(argv)


# ----- topology -----

@pytest.mark.parametrize("name", ["aot1", "aot2", "aot3", "aot4"])
def test_topology_png_for_the_aot_scenarios(tmp_path, name):
    out = draw_topology(load_scenario(ROOT / "topologies" / f"{name}.yaml"), tmp_path / f"{name}.png")
    assert out == tmp_path / f"{name}.png"
    assert_png(out)


def test_topology_png_for_a_generated_scenario(tmp_path):
    sc = load_scenario(write_scenario(tmp_path, N_TIER))
    assert_png(draw_topology(sc, tmp_path / "deep" / "folder" / "ntier.png", title="three tiers and a cloud"))


def test_coincident_positions_fall_back_to_a_deterministic_layout(tmp_path):
    sc = load_scenario(write_scenario(tmp_path, NO_POSITIONS))
    assert len({n.position for n in sc.nodes}) == 1
    first = assert_png(draw_topology(sc, tmp_path / "one.png"))
    second = assert_png(draw_topology(sc, tmp_path / "two.png"))
    assert np.array_equal(first, second)


def test_topology_command_prints_the_path(tmp_path, capsys):
    out = tmp_path / "aot1.png"
    assert run_command(["topology", str(ROOT / "topologies" / "aot1.yaml"), "--png", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert_png(out)


def test_topology_command_errors(tmp_path, capsys):
    missing = tmp_path / "missing.yaml"
    assert run_command(["topology", str(missing), "--png", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == f"{missing}: file not found\n"
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    png = blocker / "x.png"  # a folder cannot be made inside a file
    assert run_command(["topology", str(ROOT / "topologies" / "aot1.yaml"), "--png", str(png)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write" in err and "Traceback" not in err


def test_topology_without_png_writes_under_runs_not_in_the_current_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert run_command(["topology", "aot1"]) == 0
    out = Path(capsys.readouterr().out.strip())
    assert out.parent.parent == Path("runs") and out.parent.name.startswith("aot1-") and out.name == "topology.png"
    assert_png(tmp_path / out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]


# ----- plots -----

@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "aot2"
    scenario = load_scenario(ROOT / "topologies" / "aot2.yaml")
    with Simulation.inproc(scenario) as sim:
        summary = sim.run(200, policy="random")
        sim.metrics.write(out, summary)
    return out


def test_plot_run_writes_every_figure(run_dir):
    paths = plot_run(run_dir)
    assert [p.name for p in paths] == FIGURES
    assert all(p.parent == run_dir / "plots" for p in paths)
    for p in paths:
        assert_png(p)


def test_plot_run_to_another_folder_without_the_scenario(run_dir, tmp_path):
    """A run copied elsewhere whose scenario file cannot be found still plots (grouped by node, not tier)."""
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns("plots"))
    summary = json.loads((copy / "summary.json").read_text())
    assert load_run(copy).tiers is not None  # the scenario is at hand: figures group by tier
    summary.update(source="/nowhere/x.yaml", scenario="not-a-bundled-name")
    (copy / "summary.json").write_text(json.dumps(summary))
    run = load_run(copy)
    assert run.tiers is None
    assert run.nodes["queue"].shape == (19, 200)
    paths = plot_run(copy, tmp_path / "figures")
    assert [p.name for p in paths] == FIGURES and all(p.parent == tmp_path / "figures" for p in paths)
    assert_png(tmp_path / "figures" / "energy.png")


def test_rolling_response_time_is_weighted_by_completions(run_dir):
    run = load_run(run_dir)
    done = run.ticks["completed"]
    rt = np.nan_to_num(run.ticks["response_time_mean"])
    whole = plots.rolling_response(run, len(run.x))[-1]
    assert whole == pytest.approx((rt * done).sum() / done.sum())
    assert whole == pytest.approx(run.summary["response_time"]["mean"])


def test_plot_errors_name_the_missing_file(tmp_path):
    with pytest.raises(PlotError, match=r"no summary\.json, ticks\.csv, nodes\.csv \(is this a directory"):
        plot_run(tmp_path)
    assert isinstance(PlotError("x"), ValueError)
    with pytest.raises(PlotError, match="no such directory"):
        plot_run(tmp_path / "absent")


def test_plot_errors_for_malformed_files(run_dir, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad, ignore=shutil.ignore_patterns("plots"))
    ticks = (bad / "ticks.csv").read_text()
    lines = ticks.splitlines()
    (bad / "ticks.csv").write_text("\n".join([*lines[:3], "3,3.0,oops"]) + "\n")
    with pytest.raises(PlotError, match=r"ticks\.csv:4: expected \d+ values, got 3"):
        load_run(bad)
    fields = lines[3].split(",")
    fields[2] = "many"
    (bad / "ticks.csv").write_text("\n".join([*lines[:3], ",".join(fields), *lines[4:]]) + "\n")
    with pytest.raises(PlotError, match=r"ticks\.csv:4: generated: expected a number, got 'many'"):
        load_run(bad)
    (bad / "ticks.csv").write_text(lines[0] + "\n")
    with pytest.raises(PlotError, match="no ticks recorded"):
        load_run(bad)
    (bad / "ticks.csv").write_text("\n".join(lines[:101]) + "\n")  # half the run: nodes.csv does not match
    with pytest.raises(PlotError, match=r"nodes\.csv: 3800 rows, expected 19 nodes x 100 ticks"):
        load_run(bad)
    (bad / "ticks.csv").write_text(ticks)
    (bad / "summary.json").write_text("{not json")
    with pytest.raises(PlotError, match=r"summary\.json: invalid JSON at line 1"):
        load_run(bad)


def test_plot_command_exit_codes(run_dir, tmp_path, capsys):
    assert run_command(["plot", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "ticks.csv" in captured.err and "Traceback" not in captured.err
    out = tmp_path / "figures"
    assert run_command(["plot", str(run_dir), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / name) for name in FIGURES]
