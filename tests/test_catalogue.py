"""The metric catalogue: every output shows exactly the metrics it declares, and a metric added to the
catalogue alone reaches summary.json, ticks.csv, nodes.csv, the bus record, the monitor, the launch
table and the environment's infos, with the same numbers everywhere."""

from __future__ import annotations

import csv
import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from env import ZenohEdgeEnv
from env.reward import sparse_reward
from orchestrator import catalogue
from orchestrator.catalogue import Agg, Form, Metric, Out, columns, shown
from orchestrator.metrics import FIELDS
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from orchestrator.units import quantity, si
from orchestrator.viewers.monitor import DashboardState, render
from orchestrator.viewers.summary import MISSING, at, rows
from tests.conftest import ROOT

SCENARIO = ROOT / "topologies" / "examples" / "failures.yaml"  # offloads, drops by two causes, spends energy
TICKS = 60
EVERYWHERE = (Out.SUMMARY | Out.SUMMARY_NODES | Out.TICKS | Out.NODES | Out.BUS | Out.BUS_DELTA | Out.BUS_NODES
              | Out.MONITOR | Out.TABLE | Out.ENV | Out.ENV_DELTA)
CYCLES = Metric("cycles", "cycles", Agg.COUNT, "CPU cycles", "cyc", EVERYWHERE, fields=("busy_cycles",), dtype=float)


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def run(tmp_path: Path) -> dict[str, Any]:
    """One short in-process run, with every output it writes or publishes."""
    records: list[dict] = []
    with Simulation.inproc(load_scenario(SCENARIO)) as sim:
        sim.transport.subscribe(sim.keys.metrics(), lambda key, m: records.append(m))
        summary = sim.run(TICKS)
        sim.metrics.write(tmp_path, summary)
    state = DashboardState("sim", "failures")
    for i, rec in enumerate(records):
        state.add_metrics(rec, now=i / 20.0)
    console = Console(record=True, width=200, file=open(os.devnull, "w"))  # noqa: SIM115 (closed below)
    console.print(render(state, now=len(records) / 20.0))
    console.file.close()

    deltas: list[dict[str, float]] = []

    def reward(ctx: Any) -> float:
        deltas.append(ctx.node_delta)
        return sparse_reward(ctx)

    env = ZenohEdgeEnv(SCENARIO, transport="inproc", reward=reward, max_steps=5)
    env.reset(seed=1)
    while env.agents:
        _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
    env.close()
    return {"summary": summary, "ticks": read_csv(tmp_path / "ticks.csv"), "nodes": read_csv(tmp_path / "nodes.csv"),
            "records": records, "screen": console.export_text(), "infos": infos, "deltas": deltas}


def keys(m: Metric, out: Out) -> list[str]:
    """The keys ``m`` takes in a flat output (the parts beside the total only in the FLAT form)."""
    return m.columns(out)


def test_every_counter_a_metric_reads_exists():
    for m in catalogue.CATALOGUE:
        assert set(m.fields) <= set(FIELDS), m.name
        assert {p.field for p in m.parts} <= set(m.fields), m.name


def test_every_output_shows_exactly_what_the_catalogue_declares(tmp_path):
    out = run(tmp_path)
    s = out["summary"]
    for m in shown(Out.SUMMARY):
        value = at(s, m.key(Out.SUMMARY))
        assert value is not MISSING, m.name
        if m.form(Out.SUMMARY) is Form.PARTS_TOTAL:
            assert list(value) == [*(p.key for p in m.parts_of(moving=False)), "total"]  # no node moves
            assert value["total"] == pytest.approx(sum(value[p.key] for p in m.parts_of(moving=False)))
    assert list(s) == ["scenario", "scenario_hash", "source", "seed", "ticks", "dt", "penalty_s",
                       *dict.fromkeys(m.key(Out.SUMMARY).partition(".")[0] for m in shown(Out.SUMMARY)),
                       "nodes", "policy", "code", "run"]
    for node in s["nodes"].values():
        assert list(node) == [m.key(Out.SUMMARY_NODES) for m in shown(Out.SUMMARY_NODES)]

    assert out["ticks"][0] == ["tick", "time_s", *columns(Out.TICKS)]
    assert out["nodes"][0] == ["tick", "node", *columns(Out.NODES)]
    assert "dropped_queue_full" in out["ticks"][0]

    last = out["records"][-1]
    assert list(last["totals"]) == [k for m in shown(Out.BUS) if m.agg is not Agg.SAMPLES for k in keys(m, Out.BUS)]
    assert all(m.key(Out.BUS) in last for m in shown(Out.BUS) if m.agg is Agg.SAMPLES)
    assert list(last["delta"]) == [k for m in shown(Out.BUS_DELTA) for k in keys(m, Out.BUS_DELTA)]
    assert list(last["nodes"]) == ["id", "buffer", *(k for m in shown(Out.BUS_NODES) for k in keys(m, Out.BUS_NODES))]
    assert set(last["totals"]["dropped"]) == {p.key for p in catalogue.METRIC["dropped"].parts_of(moving=False)}

    for m in shown(Out.MONITOR):
        assert m.label in out["screen"] or m.short in out["screen"], m.name
    labels = [label.strip() for label, _ in rows(s)]
    for m in shown(Out.TABLE):
        assert any(label.startswith(m.label) for label in labels), m.name

    for info in out["infos"].values():
        assert list(info["node"]) == [m.key(Out.ENV) for m in shown(Out.ENV)]
    assert out["deltas"] and all(list(d) == [m.key(Out.ENV_DELTA) for m in shown(Out.ENV_DELTA)]
                                 for d in out["deltas"])


def test_a_metric_added_to_the_catalogue_alone_reaches_every_output(tmp_path, monkeypatch):
    """The worked example of docs/extending.md, "Adding a metric": one entry, no other change."""
    monkeypatch.setattr(catalogue, "CATALOGUE", (*catalogue.CATALOGUE, CYCLES))
    out = run(tmp_path)
    s = out["summary"]
    header, ticks = out["ticks"]
    ratios = [m.key(Out.TICKS) for m in shown(Out.TICKS) if m.agg is Agg.RATIO]
    # a row still ends with its samples, then its ratios
    assert header[-len(ratios) - 2:] == ["cycles", "response_time_mean", *ratios]
    per_tick = np.array([float(r["cycles"]) for r in ticks])
    assert per_tick.sum() > 0
    assert s["cycles"] == pytest.approx(per_tick.sum())  # the summary's total is the sum of the ticks' changes
    assert out["records"][-1]["totals"]["cycles"] == pytest.approx(s["cycles"])
    assert out["records"][-1]["delta"]["cycles"] == pytest.approx(per_tick[-1])
    _, nodes = out["nodes"]
    last = [r for r in nodes if r["tick"] == str(TICKS - 1)]
    assert sum(float(r["cycles"]) for r in last) == pytest.approx(per_tick[-1])
    assert sum(n["cycles"] for n in s["nodes"].values()) == pytest.approx(s["cycles"])
    assert sum(out["records"][-1]["nodes"]["cycles"]) == pytest.approx(s["cycles"])
    assert all(isinstance(info["node"]["cycles"], float) for info in out["infos"].values())
    assert sum(info["node"]["cycles"] for info in out["infos"].values()) > 0
    assert all("cycles" in d for d in out["deltas"])
    assert ("CPU cycles", quantity(s["cycles"], "cycles")) in rows(s)
    assert "CPU cycles" in out["screen"] and "cyc" in out["screen"]


def test_docs_bus_md_lists_every_field_of_the_record(tmp_path):
    """docs/bus.md is the contract for subscribers: every field the record carries has its row there."""
    table = (ROOT / "docs" / "bus.md").read_text()
    last = run(tmp_path)["records"][-1]

    def fields(value: Any, path: str) -> list[str]:
        if isinstance(value, dict):
            return [f for k, v in value.items() for f in fields(v, f"{path}.{k}" if path else k)]
        return [path]

    missing = [f for f in fields(last, "") if f"| `{f}` |" not in table]
    assert not missing, f"fields of the metrics record without a row in docs/bus.md: {missing}"


def test_a_metric_that_shows_parts_where_it_is_not_shown_is_refused():
    with pytest.raises(ValueError, match="metric bad: a form for TICKS, which it does not show"):
        dataclasses.replace(catalogue.METRIC["dropped"], name="bad", show=Out.SUMMARY,
                            forms={Out.TICKS: Form.FLAT})
    with pytest.raises(ValueError, match="TABLE without SUMMARY"):
        Metric("x", "tasks", Agg.COUNT, "x", "x", Out.TABLE)


@pytest.mark.parametrize(("value", "text"), [
    (2.234e-05, "22.34 µJ"), (0.0001503360000000003, "150.3 µJ"), (709.7, "709.7 J"), (7852.4, "7.852 kJ"),
    (999.96, "1 kJ"), (0.0, "0 J"), (3.2e-10, "320 pJ"), (1.5e-3, "1.5 mJ")])
def test_energy_reads_with_an_si_prefix(value, text):
    assert si(value, "J") == text
