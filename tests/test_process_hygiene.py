"""No process of a run outlives it: after a normal end, a killed node, Ctrl-C, SIGTERM, or a killed
orchestrator. Runs the real CLI as a subprocess; waits on its output and on process exits, never on sleeps.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time

import psutil
import pytest

pytestmark = pytest.mark.zenoh


class Launch:
    """``orchestrator launch`` in a subprocess, with its stderr read line by line in the background."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "orchestrator.cli", "launch", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "COLUMNS": "200"})
        self.lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.err: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        self.out_thread = threading.Thread(target=self.proc.stdout.read, daemon=True)
        self.out_thread.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.err.append(line)
            self.lines.put(line)

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{text!r} not seen within {timeout} s; stderr so far:\n{''.join(self.err)}")
            try:
                if text in self.lines.get(timeout=left):
                    return
            except queue.Empty:
                continue

    def descendants(self) -> list[psutil.Process]:
        return psutil.Process(self.proc.pid).children(recursive=True)

    def node(self, name: str) -> psutil.Process:
        for p in self.descendants():
            if p.name() == name:
                return p
        raise AssertionError(f"no process named {name}")

    def finish(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()


def assert_all_gone(procs: list[psutil.Process], timeout: float = 10.0) -> None:
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    assert not alive, f"left behind: {[(p.pid, p.name()) for p in alive]}"


def test_normal_run_leaves_nothing(tmp_path):
    run = Launch("aot1", "--steps", "60", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    assert len([p for p in children if p.name().startswith(("zw-", "zc-", "zk-"))]) == 30
    assert run.finish(60) == 0
    assert_all_gone(children)
    assert (tmp_path / "summary.json").exists()


def test_killed_node_ends_the_run_with_its_name(tmp_path):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    victim = run.node("zw-rpi3_1")
    killed_at = time.monotonic()
    victim.kill()
    code = run.finish(30)
    elapsed = time.monotonic() - killed_at
    assert code == 1
    message = [ln for ln in run.err if ln.startswith("error:")]
    assert message and "worker-rpi3_1" in message[0] and "node rpi3_1" in message[0], run.err[-5:]
    assert elapsed < 10, f"took {elapsed:.1f} s to notice"
    assert_all_gone(children)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_stops_everything(tmp_path, sig):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    run.proc.send_signal(sig)
    assert run.finish(30) == 130
    assert any("interrupted" in ln for ln in run.err)
    assert_all_gone(children)


def test_killed_orchestrator_takes_its_processes_with_it(tmp_path):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    run.proc.kill()
    run.finish(10)
    assert_all_gone(children)
