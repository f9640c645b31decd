"""The default layout over Zenoh fits the machine: per-role while its processes fit, else groups:K, said
in one line; an explicit layout is obeyed; and the chosen layout gives the results of one process."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import subprocess
import sys
from collections.abc import Iterator

import pytest

from node_runtime.runtime.layout import Choice, Machine, ProcessLayout, default_layout, layout_for
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from tests.conftest import ROOT, model_part, run_summary, write_scenario

GB = 2**30
# 300 sensing nodes in a grid: 900 roles, each a process per-role
GRID = {"name": "grid300", "simulation": {"steps": 10**6, "seed": 5, "policy": "least_queue"},
        "topology": {"generator": {"kind": "grid", "rows": 15, "cols": 20, "profile": "tier0"}}}
STEPS = 12


@pytest.mark.parametrize(("processes", "nodes", "cpus", "memory", "expected"), [
    (46, 19, 2, 24 * GB, "per-role"),  # aot2 on the development machine
    (72, 31, 2, 24 * GB, "per-role"),  # aot4, the largest bundled scenario
    (100, 34, 2, 24 * GB, "per-role"),  # 50 a core: the last that fits 2 cores
    (101, 34, 2, 24 * GB, "groups:4"),
    (3000, 1000, 2, 24 * GB, "groups:4"),  # the 1,000-node scenario that never became ready per-role
    (3000, 1000, 64, 256 * GB, "per-role"),  # 50 a core fits it on 64 cores with the memory
    (3000, 1000, 64, 100 * GB, "groups:128"),  # ... but not in 100 GB: 1,600 processes of 32 MB at most
    (72, 31, 1, 24 * GB, "groups:2"),
    (46, 19, 16, 1 * GB, "groups:19"),  # 16 processes fit half a GB; never more groups than nodes
])
def test_the_rule(processes, nodes, cpus, memory, expected):
    choice = default_layout(processes, nodes, Machine(cpus, memory))
    assert choice.layout == expected
    if expected == "per-role":
        assert choice.note is None
    else:
        assert f"{processes} processes (per-role) would not fit {cpus} core" in choice.note
        assert choice.note.endswith("--layout per-role forces a process per role")
        assert "\n" not in choice.note


def test_what_the_rule_counts(aot2):
    """Processes of the per-role layout (co-located controllers share their worker's), nodes for K; in-process
    it is single, and nodes placed on other hosts keep per-role."""
    small = Machine(1, 1 * GB)  # 16 processes fit
    assert len(ProcessLayout(aot2, "per-role").procs) == 46
    assert layout_for(aot2, "zenoh", small).layout == "groups:2"
    assert layout_for(aot2, "zenoh", Machine(1, 8 * GB)) == Choice("per-role")  # 46 of 50 a core
    assert layout_for(aot2, "inproc", small) == Choice("single")
    assert layout_for(aot2, "zenoh", small, placed=True) == Choice("per-role")


@contextlib.contextmanager
def two_cores() -> Iterator[None]:
    """This process (and the processes it starts) on at most 2 cores, as on the development machine,
    so that the rule decides the same on any machine."""
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, sorted(before)[:2])
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    path = write_scenario(tmp_path_factory.mktemp("grid"), GRID)
    sc = load_scenario(path)
    return path, sc, model_part(run_summary(sc, ticks=STEPS * sc.decision_interval))


@pytest.mark.zenoh
def test_launch_of_a_large_scenario_chooses_groups_and_says_so(grid, tmp_path):
    path, _, inproc = grid
    cores = min(2, len(os.sched_getaffinity(0)))
    with two_cores():
        run = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", str(path), "--steps", str(STEPS),
                              "--out", str(tmp_path / "out"), "--timeout", "60"],
                             cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    notes = [line for line in run.stderr.splitlines() if line.startswith("layout groups:")]
    assert notes == [f"layout groups:{2 * cores}: 900 processes (per-role) would not fit {cores} core"
                     f"{'s' if cores > 1 else ''} and " + notes[0].split(" and ", 1)[1]]
    assert notes[0].endswith("; --layout per-role forces a process per role")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert (summary["run"]["layout"], summary["run"]["processes"]) == (f"groups:{2 * cores}", 2 * cores)
    assert model_part(summary) == inproc


@pytest.mark.zenoh
def test_simulation_and_environment_default_is_the_same_rule(grid, caplog):
    """Simulation.over_zenoh(layout=None) and ZenohEdgeEnv(layout=None) choose by the same rule and log the same line;
    an explicit layout is obeyed however large the scenario."""
    from env import ZenohEdgeEnv

    _, sc, inproc = grid
    with two_cores(), caplog.at_level(logging.WARNING, logger="orchestrator.session"):
        expected = layout_for(sc, "zenoh")
        with Simulation.over_zenoh(sc) as sim:
            assert sim.layout == expected.layout != "per-role"
            summary = sim.run(STEPS * sc.decision_interval)
        env = ZenohEdgeEnv(sc, transport="zenoh", max_steps=2)
        try:
            env.reset(seed=1)
            assert (env.sim.layout, len(env.sim.plan.procs)) == (expected.layout, int(expected.layout[7:]))
        finally:
            env.close()
    # the memory available moves between two looks: the line is the same up to it
    said = [r.getMessage().split(" and ")[0] for r in caplog.records]
    assert said == [expected.note.split(" and ")[0]] * 2
    assert expected.note.startswith(f"layout {expected.layout}: 900 processes (per-role) would not fit ")
    assert model_part(summary) == inproc
    with Simulation.inproc(sc, layout="per-node") as sim:
        assert len(sim.plan.procs) == 300
