"""Outputs are crash-consistent: whatever point an interrupt lands on, every tick's rows are in ticks.csv and
nodes.csv once and only once, and summary.json is whole JSON that counts exactly the ticks the tables hold.
A run killed outright leaves a summary.json that says it is incomplete.

Interrupts used to repeat a block of 256 ticks (one between ``writerows`` and clearing the buffer), and to
leave summary.json one tick behind the tables."""

from __future__ import annotations

import csv
import json
import signal
import sys
import time
from pathlib import Path

import pytest
from rich.console import Console

from orchestrator import metrics
from orchestrator.cli import keep_partial
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from tests.conftest import check_outputs, write_scenario
from tests.launcher import TIMEOUT, Launch

BLOCK = 4  # rows written every 4 ticks here, so that a short run crosses several blocks
TICKS = 9
# what records a tick and writes rows; the rest of metrics.py computes values and changes nothing
WRITE_PATH = {"add", "settle", "_flush", "close_stream", "complete", "_csv", "keep", "write", "reset", "_open_tables",
              "__init__", "write_summary", "stream", "close"}
SCENARIO = {"simulation": {"steps": 100000},
            "topology": {"nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b"}, {"id": "c"}],
                         "links": [["a", "b"], ["b", "c"]]},
            "workload": {"arrival": {"rate": 0.5}}}


def interrupted_at(n: int, tmp_path: Path, scenario_path: Path, where: str) -> bool:
    """Run TICKS ticks with a KeyboardInterrupt raised at the ``n``-th line that the write path of
    orchestrator/metrics.py runs (0: none), then close as the CLI does; whether the interrupt came."""
    out = tmp_path / where
    count = [0]
    fired = [False]

    def local(frame, event, arg):
        if event == "line":
            count[0] += 1
            if count[0] == n:
                fired[0] = True
                raise KeyboardInterrupt
        return local

    def tracer(frame, event, arg):
        code = frame.f_code
        return local if code.co_filename == metrics.__file__ and code.co_name in WRITE_PATH and not fired[0] else None

    with Simulation.inproc(load_scenario(scenario_path)) as sim:
        sim.metrics.stream(out)
        try:
            sys.settrace(tracer)
            try:
                summary = sim.run(TICKS, seed=3, policy="least_queue")
            finally:
                sys.settrace(None)
            sim.metrics.write(out, summary)
        except KeyboardInterrupt as exc:
            keep_partial(sim, out, exc, 0.0, Console(quiet=True))
    return fired[0]


def test_an_interrupt_at_any_line_of_the_metrics_keeps_every_row_once(tmp_path, monkeypatch):
    """An interrupt at each line of the write path in a whole run of 9 ticks (two blocks written while it
    runs, the last at the end), closed as `orchestrator launch` closes an interrupted run."""
    monkeypatch.setattr(metrics, "STREAM_BLOCK", BLOCK)
    path = write_scenario(tmp_path, SCENARIO)
    assert not interrupted_at(0, tmp_path, path, "whole")
    whole = check_outputs(tmp_path / "whole", 3)
    assert "incomplete" not in whole and whole["ticks"] == TICKS
    n, seen = 1, set()
    while interrupted_at(n, tmp_path, path, f"at-{n}"):
        summary = check_outputs(tmp_path / f"at-{n}", 3)
        assert summary["incomplete"]["reason"] == "interrupted (Ctrl-C)"
        seen.add(summary["ticks"])
        n += 1
    assert n > 100 and seen == set(range(TICKS + 1))  # interrupts before the first tick, and in every tick


class HalfWriter:
    """A file that writes half of what the ``n``-th write to any of the files sharing ``left`` is given, then
    is interrupted."""

    def __init__(self, file, left: list[int]) -> None:
        self.file, self.left = file, left

    def write(self, data: bytes) -> int:
        self.left[0] -= 1
        if self.left[0] == 0:
            self.file.write(data[:len(data) // 2])
            raise KeyboardInterrupt
        return self.file.write(data)

    def __getattr__(self, name: str):
        return getattr(self.file, name)


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_rows_half_written_when_the_interrupt_comes_are_completed_not_repeated(tmp_path, monkeypatch, n):
    monkeypatch.setattr(metrics, "STREAM_BLOCK", BLOCK)
    out = tmp_path / "out"
    with Simulation.inproc(load_scenario(write_scenario(tmp_path, SCENARIO))) as sim:
        sim.metrics.stream(out)
        sim.reset(seed=3)  # opens the tables
        left = [n]
        for table in sim.metrics._tables:
            table.file = HalfWriter(table.file, left)
        with pytest.raises(KeyboardInterrupt) as exc:
            for _ in range(TICKS):
                sim.step()
        keep_partial(sim, out, exc.value, 0.0, Console(quiet=True))
    assert check_outputs(out, 3)["ticks"] == BLOCK * ((n + 1) // 2)  # the n-th write: the tables' (n + 1) // 2-th block


def rows(path: Path) -> int:
    try:
        return len(path.read_text().splitlines()) - 1
    except FileNotFoundError:
        return 0


def wait_rows(path: Path, at_least: int, run: Launch) -> None:
    deadline = time.monotonic() + TIMEOUT
    while rows(path) < at_least:
        assert run.proc.poll() is None, "".join(run.err)
        assert time.monotonic() < deadline, f"{path} has {rows(path)} rows, not {at_least}, after {TIMEOUT} s"
        time.sleep(0.01)  # polling the file: the event is its length


@pytest.mark.parametrize("after", [1, 256, 257, 700])
def test_a_real_ctrl_c_keeps_every_row_once(tmp_path, after):
    """`orchestrator launch` sent SIGINT once ticks.csv has ``after`` rows (blocks are 256 ticks)."""
    path = write_scenario(tmp_path, SCENARIO)
    out = tmp_path / "out"
    run = Launch(str(path), "--transport", "inproc", "--out", str(out), "-q")
    wait_rows(out / "ticks.csv", after, run)
    run.proc.send_signal(signal.SIGINT)
    assert run.finish(TIMEOUT) == 130, "".join(run.err)
    assert check_outputs(out, 3)["incomplete"]["reason"] == "interrupted (Ctrl-C)"


def test_a_killed_run_leaves_a_summary_that_says_it_is_incomplete(tmp_path):
    path = write_scenario(tmp_path, SCENARIO)
    out = tmp_path / "out"
    run = Launch(str(path), "--transport", "inproc", "--out", str(out), "-q")
    wait_rows(out / "ticks.csv", 300, run)
    run.proc.kill()
    run.finish(TIMEOUT)
    summary = json.loads((out / "summary.json").read_text())
    assert summary == {"scenario": "scenario", "ticks": None,
                       "incomplete": {"reason": metrics.UNFINISHED, "last_tick": None}}
    with (out / "ticks.csv").open() as fh:
        ticks = [int(row["tick"]) for row in csv.DictReader(fh)]
    assert ticks == list(range(len(ticks))) and len(ticks) % 256 == 0  # whole blocks, each once
