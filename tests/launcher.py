"""Running the real CLI in a subprocess, synchronised on what it prints (never on sleeps)."""

from __future__ import annotations

import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, ClassVar

import psutil

from tests.conftest import ROOT

TIMEOUT = 120.0  # seconds any single wait may take on a loaded machine before the test fails


class Launch:
    """``orchestrator launch`` in a subprocess, with its stderr read line by line in the background."""

    running: ClassVar[list[Launch]] = []  # every launch not yet stopped by ``end_all``

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "orchestrator.cli", "launch", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "COLUMNS": "200"})
        Launch.running.append(self)
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


def end_all(keep: list[Launch], grace: float = 30.0) -> None:
    """SIGTERM every launch still running but those in ``keep`` (the orchestrator then stops its node
    processes), SIGKILL one that does not end within ``grace`` seconds."""
    for run in [r for r in Launch.running if r not in keep]:
        if run.proc.poll() is None:
            run.proc.terminate()
            try:
                run.proc.wait(grace)
            except subprocess.TimeoutExpired:
                run.proc.kill()
                run.proc.wait()
    Launch.running[:] = keep


def paused_run(run: Launch, victim: psutil.Process, timeout: float) -> tuple[int, float, str]:
    """SIGSTOP ``victim`` and wait for ``run`` to end: (exit status, seconds from the pause, first error line).
    The victim is resumed afterwards, whatever happened, so that nothing stays stopped."""
    paused_at = time.monotonic()
    victim.suspend()
    try:
        code = run.finish(timeout)
    finally:
        if victim.is_running():
            victim.resume()
    errors = [line for line in run.err if line.startswith("error:")]
    assert errors, f"no error line; stderr ends:\n{''.join(run.err[-5:])}"
    return code, time.monotonic() - paused_at, errors[0]


def assert_all_gone(procs: list[psutil.Process], timeout: float = 10.0) -> None:
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    assert not alive, f"left behind: {[(p.pid, p.name()) for p in alive]}"


def served(run: Launch) -> tuple[str, str]:
    """(endpoint, sim id) from what ``launch`` printed."""
    text = "".join(run.err)
    endpoint = re.search(r"router ((?:tcp|tls)/[0-9.]+:[0-9]+)", text)
    sim = re.search(r"simulation id (\w+)", text)
    assert endpoint and sim, text
    return endpoint.group(1), sim.group(1)


class Output:
    """A subprocess whose stdout and stderr lines are read in the background and waited for by content."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     env={**os.environ, "COLUMNS": "120"})
        self.out: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.err: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.readers = [threading.Thread(target=self._pump, args=(stream, q.put), daemon=True)
                        for stream, q in ((self.proc.stdout, self.out), (self.proc.stderr, self.err))]
        for reader in self.readers:
            reader.start()

    @staticmethod
    def _pump(stream: Any, put: Any) -> None:
        for line in stream:
            put(line.rstrip("\n"))

    @staticmethod
    def _next(q: queue.SimpleQueue[str], what: str, timeout: float) -> str:
        try:
            return q.get(timeout=timeout)
        except queue.Empty:
            raise AssertionError(f"no {what} line within {timeout} s") from None

    def line(self, timeout: float = TIMEOUT) -> str:
        """The next line on stdout."""
        return self._next(self.out, "stdout", timeout)

    def wait_err(self, text: str, timeout: float = TIMEOUT) -> list[str]:
        """stderr lines up to the first that contains ``text``."""
        seen = [self._next(self.err, "stderr", timeout)]
        while text not in seen[-1]:
            seen.append(self._next(self.err, "stderr", timeout))
        return seen

    def finish(self, sig: int | None = None, timeout: float = 60.0) -> tuple[int, list[str], list[str]]:
        """Signal (optionally) and wait for the exit: (status, unread stdout lines, unread stderr lines)."""
        if sig is not None:
            self.proc.send_signal(sig)
        try:
            status = self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        for reader in self.readers:
            reader.join(timeout)
        return status, drain(self.out), drain(self.err)


def drain(q: queue.SimpleQueue[str]) -> list[str]:
    lines = []
    while not q.empty():
        lines.append(q.get())
    return lines


DRIVER = """
import sys, threading
from orchestrator.session import Simulation
from node_runtime.runtime.security import Security
security = Security.from_dir(sys.argv[4]) if len(sys.argv) > 4 else None
sim = Simulation.attach(sys.argv[1], sys.argv[2], timeout=30, security=security)
print(sim.attached, flush=True)
if sys.argv[3] == "hold":
    threading.Event().wait()  # until it is killed
sys.exit(0)  # without sim.close(): the clock is never released
"""


def claiming_driver(endpoint: str, sim: str, how: str, security: Path | None = None) -> tuple[Output, str]:
    """A driver in its own process that claims the clock of a served simulation, then holds it until killed
    (``how`` "hold") or exits without releasing it ("exit"); and the name it claimed as."""
    proc = Output(sys.executable, "-c", DRIVER, endpoint, sim, how, *([str(security)] if security else []))
    return proc, proc.line()
