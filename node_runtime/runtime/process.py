"""Entry point of a node process: wire a host of roles to a Zenoh session and run the protocol.

Started by the orchestrator's launcher (local processes) or by ``zenohedge-node`` on another host.
A node process never decides to stop on its own: it stops when the orchestrator says so, when the
orchestrator's liveliness token vanishes (it crashed or was killed), or when its parent dies. When it
fails, it raises: the fork server hands its account (exception and traceback) to the orchestrator.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
from dataclasses import dataclass
from typing import Any

from node_runtime.model.plugins import extend_path
from node_runtime.model.spec import Scenario
from node_runtime.runtime.driver import HostDriver
from node_runtime.runtime.failure import ChildFailed
from node_runtime.runtime.host import Host
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import Layout, ProcessLayout
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.security import Security
from node_runtime.runtime.zenoh_bus import ZenohTransport, use_lean_runtime

ORCHESTRATOR = "orchestrator"  # liveliness name of the clock's owner
READY_TIMEOUT = 60.0
EXIT_OK, EXIT_ORPHANED = 0, 3  # a failed process exits with status 1 (the fork server)


@dataclass(frozen=True)
class ProcSpec:
    proc: str
    scenario: Scenario
    layout: Layout
    endpoint: str  # the router to connect to
    keys: Keys
    keyring: Keyring  # the clock's key and this process's own (origin.py): handed over here, never on the bus
    paths: tuple[str, ...] = ()  # the orchestrator's sys.path, where user extensions may live
    security: Security | None = None  # TLS and login for the session (deploy/README.md)
    settings: dict[str, Any] | None = None  # a user's Zenoh configuration (zenohedge-node --zenoh-config)
    lease_s: float | None = None  # how long the router keeps a silent session (default: Zenoh's 10 s)
    ready_timeout: float = READY_TIMEOUT  # how long to wait for the peers' subscriptions before giving up
    done_key: str | None = None  # where to publish Done: the host's aggregator (zenohedge-node), else the clock


PR_SET_PDEATHSIG, PR_SET_NAME = 1, 15
GROUPS = {"node": "zn", "all": "za", "group": "zg"}  # per-node, single, groups:K; per-role: named for the kind


def short_name(proc: str, plan: ProcessLayout) -> str:
    """What ``ps``/``top`` show for a node process (15 bytes at most): zw-<node> for a worker, etc."""
    kind, _, node = proc.partition("-")
    prefix = plan.kinds[kind].process_prefix if kind in plan.kinds else GROUPS.get(kind, "z")
    return f"{prefix}-{node}"[:15]


def _prctl(option: int, arg: object) -> None:
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(option, arg)


def die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent exits (no orphans after a crash)."""
    _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def run(spec: ProcSpec) -> int:
    """Run one node process to completion; returns its exit status, or raises what made it fail."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the orchestrator handles it
    use_lean_runtime()
    extend_path(spec.paths)
    settings = dict(spec.settings or {})
    if spec.lease_s is not None:  # a paused process must stay "hung", not "died", until the clock's timeout
        settings.setdefault("transport/link/tx/lease", round(spec.lease_s * 1000))
    transport = ZenohTransport.client(spec.endpoint, spec.security, settings or None)
    transport.rejections.who = spec.proc
    try:
        plan = ProcessLayout(spec.scenario, spec.layout)
        _prctl(PR_SET_NAME, short_name(spec.proc, plan).encode())
        host = Host(spec.proc, plan)
        driver = HostDriver(host, transport, spec.keys, spec.keyring, spec.done_key)
        orchestrator = {"seen": False, "gone": False}

        def on_orchestrator(key: str, alive: bool) -> None:
            orchestrator["seen" if alive else "gone"] = True

        transport.watch_tokens(spec.keys.alive(ORCHESTRATOR), on_orchestrator)
        publishes = [*driver.inbox_keys.values(), driver.done_key]
        if driver.broadcast_key is not None:
            publishes.append(driver.broadcast_key)
        transport.wait_matching(publishes, spec.ready_timeout)
        transport.declare_token(spec.keys.alive(spec.proc))
        transport.dispatch(until=lambda: driver.stopped or driver.failed is not None or orchestrator["gone"])
        if driver.failed is not None:  # already reported in its Done; the exit notice says it again
            raise ChildFailed(driver.failed)
        return EXIT_ORPHANED if orchestrator["gone"] and not driver.stopped else EXIT_OK
    finally:
        transport.rejections.log_total()
        transport.close()  # a close that hangs raises TransportError: the fork server reports it


def main(spec: ProcSpec) -> None:
    """Body of a forked node process."""
    die_with_parent()
    code = run(spec)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
