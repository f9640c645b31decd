"""Running the real CLI in a subprocess, synchronised on what it prints (never on sleeps)."""

from __future__ import annotations

import os
import queue
import re
import subprocess
import sys
import threading
import time

import psutil

TIMEOUT = 120.0  # seconds any single wait may take on a loaded machine before the test fails


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


def served(run: Launch) -> tuple[str, str]:
    """(endpoint, sim id) from what ``launch`` printed."""
    text = "".join(run.err)
    endpoint = re.search(r"router (tcp/[0-9.]+:[0-9]+)", text)
    sim = re.search(r"simulation id (\w+)", text)
    assert endpoint and sim, text
    return endpoint.group(1), sim.group(1)
