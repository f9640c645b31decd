"""Node processes: start them, wait until all are ready, notice a death at once, leave none behind.

Processes come from the node fork server, which has already imported zenoh, numpy and msgpack
(70 processes start in under a second that way; docs/protocol.md, "Process life"). Readiness is each
process's liveliness token; death is the token vanishing (any host) or the process's exit (local ones, checked when
idle). The error names the process and, for a local one, gives its own account of the failure; when every
process of another host vanishes at once, it names that host's group instead.
Every child also dies with the fork server and when the orchestrator's token goes.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping

import psutil

from node_runtime.model.spec import Scenario
from node_runtime.runtime import process as node_process
from node_runtime.runtime.forkserver import ForkServer
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import Layout, ProcessLayout
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.process import ORCHESTRATOR, ProcSpec
from node_runtime.runtime.security import Security
from node_runtime.runtime.transport import Transport
from orchestrator.clock import ClockError, ProcessFailed

EXIT_NOTICE_S = 2.0  # how long a vanished token waits for its local process's exit notice, which says why
# A process drops the router once it heard nothing for a lease; Zenoh sends keep-alives every quarter lease,
# so its count may start that much before the orchestrator stood still
LEASE_SLACK = 0.75


BEAT_S = 0.25  # how often ``StallWatch`` looks at the time


class StallWatch:
    """Measures how long this process stood still (SIGSTOP, a starved machine): a thread that looks at the
    monotonic clock every ``BEAT_S``, which goes on while the process is stopped."""

    def __init__(self) -> None:
        self.last = (0.0, 0.0)  # the latest stall: (its length, when it ended)
        self._beat = time.monotonic()
        self._stop = threading.Event()
        threading.Thread(target=self._run, daemon=True, name="stall-watch").start()

    def _run(self) -> None:
        while not self._stop.wait(BEAT_S):
            now = time.monotonic()
            if (gap := now - self._beat - BEAT_S) > BEAT_S:
                self.last = (gap, now)
            self._beat = now

    def stalled_s(self, within: float) -> float:
        """How long the stall under way, or one that ended less than ``within`` seconds ago, lasted (the thread
        may not have run since a stall ended); 0 if none."""
        now = time.monotonic()
        gap, ended = self.last
        return max(gap if now - ended < within else 0.0, now - self._beat - BEAT_S)

    def stop(self) -> None:
        self._stop.set()


class Stalled(ClockError):
    """The orchestrator itself stood still (stopped, starved of CPU) past its processes' Zenoh lease: they
    took it for gone and left, and none of them is to blame."""


class HostLost(ClockError):
    """Every process of a host (``zenohedge-node``) vanished at once: the host, or the network to it, is gone;
    none of its processes is to blame on its own."""


def how(status: int) -> str:
    """An exit status as a person reads it: 'status 1', 'killed by SIGKILL'."""
    if status >= 0:
        return f"status {status}"
    try:
        return f"killed by {signal.Signals(-status).name}"
    except ValueError:
        return f"killed by signal {-status}"


def paused(pid: int) -> str:
    """How a live process is stopped ("stopped by a signal", ...), or "" if it runs or is gone. A stopped
    process cannot act on anything, a stop included."""
    try:
        status = psutil.Process(pid).status()
    except psutil.Error:
        return ""
    return {psutil.STATUS_STOPPED: "stopped by a signal (SIGSTOP?)",
            psutil.STATUS_TRACING_STOP: "stopped by a tracer"}.get(status, "")


class Supervisor:
    """Watches the processes of a simulation; starts the local ones when asked.

    ``token`` is this side's own liveliness: the orchestrator's (node processes exit when it
    vanishes); None for a remote driver, which declared its own as it claimed the clock. ``placement``
    (group -> processes): the processes each other host runs, for naming a host that is gone.
    """

    def __init__(self, transport: Transport, keys: Keys, plan: ProcessLayout, token: str | None = ORCHESTRATOR,
                 placement: Mapping[str, list[str]] | None = None) -> None:
        self.transport = transport
        self.keys = keys
        self.plan = plan
        self.placement = dict(placement or {})  # group -> the processes its host runs
        self.vanished: list[str] = []  # processes on other hosts whose token vanished, in order (``check``)
        self.children: dict[str, int] = {}  # process name -> pid
        self.forks: ForkServer | None = None
        self.ready: set[str] = set()
        self.stopping = False
        self.lease_s: float | None = None  # the lease the local processes announce (``start``)
        self.watch: StallWatch | None = None  # how long we stood still (``start``)
        if token is not None:
            transport.declare_token(keys.alive(token))
        transport.watch_tokens(keys.alive(), self.on_token)

    def nodes(self, proc: str) -> tuple[str, ...]:
        return self.plan.node_of_proc(proc)

    def on_token(self, key: str, alive: bool) -> None:
        proc = key.rsplit("/", 1)[-1]
        if proc not in self.plan.roles_of:  # the orchestrator, a driver, a monitor
            return
        if alive:
            self.ready.add(proc)
        elif proc in self.ready and not self.stopping:
            self.ready.discard(proc)
            pid = self.children.get(proc)
            if pid is not None and self.forks is not None:
                if not self.forks.wait([pid], EXIT_NOTICE_S):
                    self._exited(proc, pid)  # a local child: its exit notice says why
                if state := paused(pid):
                    raise ProcessFailed(proc, self.nodes(proc), f"hung: {state}; its Zenoh session lapsed")
            if pid is None:  # on another host: the others of that host may be vanishing with it (``check``)
                self.vanished.append(proc)
                return
            self._unless_we_stalled(proc)
            raise ProcessFailed(proc, self.nodes(proc), "died: its liveliness token vanished")

    def _lost(self) -> None:
        """Raise for processes on other hosts whose tokens vanished: a host all of whose processes vanished
        (their tokens go together when its router's session closes) is named; otherwise the first process."""
        proc = self.vanished[0]
        self._unless_we_stalled(proc)
        group = next((g for g, procs in self.placement.items() if proc in procs), None)
        if group is None:
            raise ProcessFailed(proc, self.nodes(proc), "died: its liveliness token vanished")
        procs = self.placement[group]
        if len(procs) > 1 and set(procs) <= set(self.vanished):
            raise HostLost(f"the host of group {group} is gone: the liveliness tokens of all its {len(procs)} "
                           f"processes ({', '.join(procs[:6])}{' ...' if len(procs) > 6 else ''}) vanished at once; "
                           "its zenohedge-node was stopped or killed, or the network to it failed")
        raise ProcessFailed(proc, self.nodes(proc), f"on the host of group {group} died: its liveliness token vanished")

    def _unless_we_stalled(self, proc: str) -> None:
        """Raise ``Stalled`` if this process stood still for about a lease: ``proc`` left because of that."""
        if self.lease_s is None or self.watch is None:
            return
        stalled = self.watch.stalled_s(within=self.lease_s)  # they left during it: we hear of it once we run again
        if stalled >= LEASE_SLACK * self.lease_s:
            raise Stalled(f"the orchestrator itself stood still for {stalled:.0f} s (stopped, or starved of CPU), "
                          f"about the {self.lease_s:g} s Zenoh lease of its processes: they took it for gone and left "
                          f"({proc} first); none of them failed")

    def hung(self, procs: list[str]) -> str:
        """Why these processes sent no report: what their OS state says, for the local ones."""
        states = [f"{p} {state}" for p in procs if (pid := self.children.get(p)) is not None and (state := paused(pid))]
        return f" ({'; '.join(states)})" if states else ""

    def check(self) -> None:
        """Raise if a local child has exited while it should be running, or a process on another host vanished
        (called when the bus is idle: a host's tokens have all vanished by then)."""
        if self.stopping:
            return
        if self.vanished:
            self._lost()
        if self.forks is None:
            return
        for proc, pid in self.children.items():
            if self.forks.exit_status(pid) is not None:
                self._exited(proc, pid)

    def _exited(self, proc: str, pid: int) -> None:
        """Raise the error for a local child that exited: its status, and its own reason when it gave one."""
        status = self.forks.exit_status(pid)
        if status == node_process.EXIT_ORPHANED:
            self._unless_we_stalled(proc)
        why = self.forks.account(pid)
        first = f": {why.strip().splitlines()[0]}" if why.strip() else ""
        raise ProcessFailed(proc, self.nodes(proc), f"exited unexpectedly ({how(status)}){first}", why)

    def start(self, scenario: Scenario, layout: Layout, endpoint: str, procs: tuple[str, ...], keyring: Keyring,
              timeout: float = 60.0, security: Security | None = None, lease_s: float | None = None) -> float:
        """Start the local processes and wait for every process of the layout to be ready.

        ``procs``: the ones to start here; others are expected to join from other hosts. ``keyring``: each gets
        its own key and the clock's in its start request (origin.py), never over the bus.
        ``lease_s``: how long the router keeps the session of a process that went silent.
        Returns the seconds it took.
        """
        t0 = time.perf_counter()
        self.lease_s = lease_s
        self.watch = StallWatch()
        self.forks = ForkServer.shared()
        for proc in procs:
            spec = ProcSpec(proc, scenario, layout, endpoint, self.keys, keyring.of([proc]), tuple(sys.path), security,
                            lease_s=lease_s, ready_timeout=timeout)
            self.children[proc] = self.forks.start(proc, node_process.main, spec)
        self.wait_ready(timeout)
        return time.perf_counter() - t0

    def wait_ready(self, timeout: float) -> None:
        """Wait until every process of the layout has announced itself."""
        want = set(self.plan.procs)
        try:
            self.transport.dispatch(until=lambda: want <= self.ready, timeout=timeout, idle=self.check)
        except TimeoutError:
            missing = sorted(want - self.ready)
            raise ProcessFailed(missing[0], self.nodes(missing[0]),
                                f"was not ready within {timeout:.0f} s ({len(missing)} process(es) missing: "
                                f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''})") from None

    def shutdown(self, grace: float = 5.0) -> list[str]:
        """Wait for the children to exit after a stop; terminate, then kill, what remains.

        Returns the names of processes that had to be forced.
        """
        self.stopping = True
        if self.watch is not None:
            self.watch.stop()
        if self.forks is None:
            return []
        pids = list(self.children.values())
        for pid in pids:  # a stopped process cannot act on the stop: no grace for it
            if paused(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        left = self.forks.wait(pids, grace)
        forced = [p for p, pid in self.children.items() if pid in left]
        for sig, wait in ((signal.SIGTERM, 2.0), (signal.SIGKILL, 5.0)):
            if not left:
                break
            for pid in left:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, sig)
            left = self.forks.wait(left, wait)
        return forced

    @property
    def pids(self) -> list[int]:
        return list(self.children.values())
