"""Conservation: generated = completed + dropped + in the system, at every tick.

The metrics layer raises at the first tick where it fails; these runs also recompute it from the
per-tick CSV written at the end, so the check itself is checked.
"""

from __future__ import annotations

import csv
import dataclasses

from node_runtime.model.arrival import Constant
from node_runtime.model.spec import Failure
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, run_summary


def recompute_from_csv(path):
    generated = completed = dropped = 0
    rows = 0
    with open(path) as fh:
        for row in csv.DictReader(fh):
            generated += int(row["generated"])
            completed += int(row["completed"])
            dropped += int(row["dropped"])
            assert generated == completed + dropped + int(row["in_system"]), f"tick {row['tick']}"
            assert int(row["in_system"]) == int(row["queued"]) + int(row["undecided"]) + int(row["in_flight"])
            rows += 1
    return rows, generated


def test_aot4_high_load_5000_ticks(tmp_path):
    base = load_scenario(ROOT / "topologies" / "aot4.yaml")
    wl = base.workload.model_copy(update={"arrival": Constant(rate=0.6)})
    scenario = base.replace(workload=wl, failures=(Failure(node="nuc_1", at=1000, duration=300),
                                                   Failure(node="server_0", at=3000, duration=100)))
    summary = run_summary(scenario, ticks=5000, policy="random", out=tmp_path)
    rows, generated = recompute_from_csv(tmp_path / "ticks.csv")
    assert rows == 5000
    assert generated == summary["totals"]["generated"] > 40_000
    t = summary["totals"]
    assert t["dropped"]["node_failure"] > 0 and t["dropped"]["queue_full"] > 0 and t["dropped"]["expired"] > 0
    assert t["offloaded"] > 0


def test_lossy_links_account_for_every_task(tmp_path):
    base = load_scenario(ROOT / "topologies" / "aot1.yaml")
    lossy = tuple(dataclasses.replace(lk, loss=0.2) for lk in base.links)
    summary = run_summary(base.replace(links=lossy), ticks=1500, policy="least_queue", out=tmp_path)
    recompute_from_csv(tmp_path / "ticks.csv")
    assert summary["totals"]["dropped"]["link_loss"] > 0
