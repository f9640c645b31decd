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

from node_runtime.runtime.keys import Keys
from node_runtime.runtime.zenoh_bus import ZenohTransport
from tests.conftest import ROOT

TIMEOUT = 120.0  # seconds any single wait may take on a loaded machine before the test fails


class Launch:
    """``orchestrator launch`` in a subprocess, with its stderr read line by line in the background."""

    running: ClassVar[list[Launch]] = []  # every launch not yet stopped by ``end_all``
    hosts: ClassVar[list[subprocess.Popen]] = []  # every ``zenohedge-node`` started by ``spread``

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
    processes), SIGKILL one that does not end within ``grace`` seconds; SIGKILL every host still running."""
    for run in [r for r in Launch.running if r not in keep]:
        if run.proc.poll() is None:
            run.proc.terminate()
            try:
                run.proc.wait(grace)
            except subprocess.TimeoutExpired:
                run.proc.kill()
                run.proc.wait()
    Launch.running[:] = keep
    for host in Launch.hosts:  # a host outlives its orchestrator by a lease at most; one stopped by a test, for ever
        if host.poll() is None:
            host.kill()
            host.wait()
    Launch.hosts.clear()


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


def spread(out: Path, scenario: str, placement: dict[str, list[str]], *args: str,
           sim: str = "spread") -> tuple[Launch, list[subprocess.Popen]]:
    """``scenario`` launched with the nodes of ``placement``'s i-th group on host i + 1 (network namespace
    zedge-host<i + 1> of deploy/netns.sh, under ``zenohedge-node``), the rest here; started and ready. The
    hosts' pids are their ``zenohedge-node``'s (``ip netns exec`` becomes it)."""
    from orchestrator.session import free_port

    out.mkdir(parents=True, exist_ok=True)
    where = out.parent / f"{out.name}-placement.yaml"
    where.write_text("groups:\n" + "".join(f"  {g}: [{', '.join(nodes)}]\n" for g, nodes in placement.items()))
    port = free_port("0.0.0.0")
    run = Launch(scenario, "--layout", "per-node", "--listen", f"0.0.0.0:{port}", "--insecure", "--sim-id", sim,
                 "--placement", str(where), "--out", str(out), *args)
    run.wait_for("processes on other hosts")
    for i, group in enumerate(placement, start=1):
        Launch.hosts.append(subprocess.Popen(
            ["ip", "netns", "exec", f"zedge-host{i}", sys.executable, "-m", "node_runtime.runtime.remote",
             "--connect", f"tcp/10.77.{i}.1:{port}", "--sim", sim, "--group", group],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    run.wait_for("processes ready")
    return run, Launch.hosts[-len(placement):]


def assert_host_empty(ns: str, timeout: float = 30.0) -> None:
    """No process is left in network namespace ``ns`` (within ``timeout`` s: the last may still be leaving)."""
    deadline = time.monotonic() + timeout
    while True:
        listed = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True, check=True)
        if not listed.stdout.split():
            return
        assert time.monotonic() < deadline, f"left behind in {ns}: pids {listed.stdout.split()}"
        time.sleep(0.1)  # polling the namespace: no event says it emptied


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


class TickWatch:
    """The ticks of a run as a monitor on its bus sees them (``…/metrics``): a test waits on the clock itself,
    never on the time. A thread dispatches the monitor's session; ``seen`` holds (monotonic time, tick) of
    each new highest tick."""

    def __init__(self, run: Launch) -> None:
        endpoint, sim = served(run)
        self.transport = ZenohTransport.client(endpoint)
        self.seen: list[tuple[float, int]] = []
        self._changed = threading.Condition()
        self._stop = threading.Event()
        self.transport.subscribe(Keys(sim).metrics(), self._on_metrics)
        self._thread = threading.Thread(target=self.transport.dispatch, args=(self._stop.is_set,), daemon=True)
        self._thread.start()

    @property
    def latest(self) -> int:
        return self.seen[-1][1] if self.seen else -1

    def _on_metrics(self, key: str, record: dict[str, Any]) -> None:
        if record["tick"] > self.latest:
            with self._changed:
                self.seen.append((time.monotonic(), record["tick"]))
                self._changed.notify_all()

    def wait(self, tick: int, run: Launch, timeout: float = TIMEOUT) -> None:
        """Until the clock has done ``tick``; fails if ``run`` ends first or the time is up."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while self.latest < tick:
                assert run.proc.poll() is None, f"the run ended before tick {tick}:\n{''.join(run.err[-5:])}"
                left = deadline - time.monotonic()
                assert left > 0, f"tick {tick} not seen within {timeout} s (latest {self.latest})"
                self._changed.wait(min(left, 0.5))  # and look at the run now and then

    def ticks_between(self, start: float, end: float) -> list[int]:
        """The new highest ticks seen from ``start`` to ``end`` (monotonic times)."""
        return [tick for at, tick in self.seen if start <= at <= end]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(TIMEOUT)
        self.transport.close()


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
