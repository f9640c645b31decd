"""The same scenario and seed give the same emulation, bit for bit, whatever the transport or layout."""

from __future__ import annotations

import pytest

from tests.conftest import model_part, run_summary


def outputs(tmp_path, scenario, name, **kw):
    out = tmp_path / name
    summary = run_summary(scenario, out=out, **kw)
    return model_part(summary), (out / "ticks.csv").read_text(), (out / "nodes.csv").read_text()


def test_same_seed_same_run_inproc(tmp_path, aot2):
    a = outputs(tmp_path, aot2, "a", ticks=600, seed=7, policy="random")
    b = outputs(tmp_path, aot2, "b", ticks=600, seed=7, policy="random")
    assert a == b


def test_other_seed_other_run(tmp_path, aot2):
    a = outputs(tmp_path, aot2, "a", ticks=300, seed=1, policy="random")
    b = outputs(tmp_path, aot2, "b", ticks=300, seed=2, policy="random")
    assert a[0]["totals"] != b[0]["totals"]


def test_inproc_layouts_agree(tmp_path, aot1):
    ref = outputs(tmp_path, aot1, "single", ticks=400, seed=3, policy="least_queue")
    for layout in ("per-role", "per-node", "groups:5"):
        assert outputs(tmp_path, aot1, layout, ticks=400, seed=3, policy="least_queue", layout=layout) == ref


@pytest.mark.zenoh
@pytest.mark.parametrize("scenario_name", ["aot1", "aot2"])
def test_zenoh_agrees_with_inproc(tmp_path, request, scenario_name):
    scenario = request.getfixturevalue(scenario_name)
    ref = outputs(tmp_path, scenario, "inproc", ticks=300, seed=11, policy="random")
    for layout in ("per-role", "per-node", "groups:3"):
        got = outputs(tmp_path, scenario, layout, ticks=300, seed=11, policy="random", transport="zenoh", layout=layout)
        assert got == ref, f"zenoh {layout} differs from inproc"


def test_a_policy_override_lasts_one_episode(aot1):
    from orchestrator.session import Simulation

    with Simulation.inproc(aot1) as sim:
        first = model_part(sim.run(200))
        overridden = sim.run(200, policy="random")
        again = model_part(sim.run(200))
    assert overridden["totals"]["offloaded"] > 0 and overridden["policy"] == "random"
    assert again == first  # the scenario's own policy (local) is back
