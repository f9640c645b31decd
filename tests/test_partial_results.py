"""An episode that does not finish keeps what it measured: summary.json marked incomplete (why, last
tick) and the CSV rows so far, whether a node dies or the orchestrator is interrupted."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.conftest import ROOT, write_scenario
from tests.launcher import TIMEOUT, Launch

WORKERS = '''
import sys

from node_runtime import Worker


class FailingWorker(Worker):
    """Dies in tick ``fail_at``: its node process exits and the clock reports it."""

    def tick(self, t, inbox, out):
        if t == int(self.node.param("fail_at")):
            raise RuntimeError(f"battery flat at tick {t}")
        super().tick(t, inbox, out)


class MarkingWorker(Worker):
    """Says on stderr that tick ``mark_at`` ran: an event a test can wait for (in-process runs only)."""

    def tick(self, t, inbox, out):
        if t == int(self.node.param("mark_at")):
            print(f"mark {t}", file=sys.stderr, flush=True)
        super().tick(t, inbox, out)
'''


def scenario(tmp_path: Path, worker: str, **params: object) -> Path:
    (tmp_path / "partial_workers.py").write_text(textwrap.dedent(WORKERS))
    return write_scenario(tmp_path, {
        "simulation": {"steps": 100000},
        "topology": {"nodes": [{"id": "a", "client": True, "controller": True,
                                "roles": {"worker": f"partial_workers:{worker}"}, "params": params},
                               {"id": "b"}], "links": [["a", "b"]]}})


def read(out: Path) -> tuple[dict, list[dict]]:
    summary = json.loads((out / "summary.json").read_text())
    with (out / "ticks.csv").open() as fh:
        return summary, list(csv.DictReader(fh))


@pytest.mark.zenoh
def test_a_dead_node_keeps_the_ticks_before_it_died(tmp_path):
    path = scenario(tmp_path, "FailingWorker", fail_at=40)
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", str(path), "--out",
                           str(tmp_path / "out"), "-q"], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 1, proc.stderr
    summary, ticks = read(tmp_path / "out")
    assert summary["incomplete"]["last_tick"] == 39
    assert "worker-a" in summary["incomplete"]["reason"]
    assert summary["ticks"] == len(ticks) == 40
    assert [int(r["tick"]) for r in ticks] == list(range(40))


@pytest.mark.parametrize(("signum", "reason"), [(signal.SIGINT, "interrupted (Ctrl-C)"),
                                                 (signal.SIGTERM, "terminated (SIGTERM)")])
def test_an_interrupted_run_keeps_its_ticks(tmp_path, signum, reason):
    path = scenario(tmp_path, "MarkingWorker", mark_at=30)
    run = Launch(str(path), "--transport", "inproc", "--tick-rate", "200", "--out", str(tmp_path / "out"), "-q")
    run.wait_for("mark 30", timeout=TIMEOUT)
    run.proc.send_signal(signum)
    assert run.finish(TIMEOUT) == 130
    summary, ticks = read(tmp_path / "out")
    assert summary["incomplete"]["reason"] == reason
    assert summary["ticks"] == len(ticks) == summary["incomplete"]["last_tick"] + 1 >= 30  # tick 30 was running


def test_a_run_that_fails_before_its_first_tick_still_says_why(tmp_path):
    from rich.console import Console

    from orchestrator.cli import keep_partial
    from orchestrator.clock import ClockError
    from orchestrator.scenario import load_scenario
    from orchestrator.session import Simulation

    with Simulation.inproc(load_scenario("aot1")) as sim:
        keep_partial(sim, tmp_path / "run", ClockError("tick 0: worker-rpi3_1 hung"), 0.0, Console(quiet=True))
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary == {"scenario": "aot1", "ticks": 0,
                       "incomplete": {"reason": "ClockError: tick 0: worker-rpi3_1 hung", "last_tick": None}}


def test_streamed_tables_equal_the_tables_built_at_the_end_and_memory_stays_bounded(tmp_path):
    """The CLI streams ticks.csv and nodes.csv (memory flat in the run length); what it writes is byte for
    byte what the in-memory history gives."""
    from orchestrator.metrics import STREAM_BLOCK
    from orchestrator.scenario import load_scenario
    from orchestrator.session import Simulation

    ticks = 2 * STREAM_BLOCK + 37
    for name in ("streamed", "history"):
        with Simulation.inproc(load_scenario("aot1")) as sim:
            if name == "streamed":
                sim.metrics.stream(tmp_path / name)
            summary = sim.run(ticks, seed=5, policy="least_queue")
            if name == "streamed":
                assert len(sim.metrics._rows.ticks) < STREAM_BLOCK  # older rows are on disk, not in memory
                assert len((tmp_path / name / "ticks.csv").read_text().splitlines()) > STREAM_BLOCK
            sim.metrics.write(tmp_path / name, summary)
    for table in ("ticks.csv", "nodes.csv"):
        assert (tmp_path / "streamed" / table).read_bytes() == (tmp_path / "history" / table).read_bytes(), table
    streamed, history = (json.loads((tmp_path / name / "summary.json").read_text()) for name in ("streamed", "history"))
    streamed.pop("run"), history.pop("run")  # wall-clock times
    assert streamed == history
