"""A fork server for node processes: fast starts, no user ``__main__`` re-import, no orphans.

``ForkServer`` (the orchestrator's handle) starts ``python -m node_runtime.runtime.forkserver`` once. That
clean interpreter imports zenoh, numpy, msgpack and the node code, then forks one child per
``start(spec)`` (~0.75 s for 70 processes, against ~7 s with spawn). Unlike the stdlib
forkserver it never runs the caller's main module, so a training script needs no
``if __name__ == "__main__"`` guard.

Hygiene: the server exits, killing its children, when its stdin reaches EOF — which happens however
the orchestrator ends, even by SIGKILL. Children also get PR_SET_PDEATHSIG from the server.

A child that fails says why: when ``target`` raises, the child writes its account (``failure.account``:
the exception, then the traceback) to a pipe its server reads when it exits, and the exit notice carries
it. The orchestrator's error then shows the node's own reason, not just a status.

Wire format on the pipes: 4-byte big-endian length, then a pickle. Requests: ("start", name, job)
where ``job`` pickles (target, args) and ``target`` is an importable module-level function that ends
the child with os._exit (or raises); replies and notices: ("started", name, pid), ("failed", name, why)
and ("exited", name, pid, status, account), ``account`` empty unless the child raised.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pickle
import selectors
import signal
import struct
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from node_runtime.runtime.failure import account

HEADER = struct.Struct(">I")
ACCOUNT_BYTES = 8192  # at most this much of a child's account: it must fit the pipe, which is read after the exit


def _write(fd: int, obj: Any) -> None:
    data = pickle.dumps(obj)
    os.write(fd, HEADER.pack(len(data)) + data)


def _read_exact(fd: int, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = os.read(fd, n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def _read(fd: int) -> Any | None:
    head = _read_exact(fd, HEADER.size)
    if head is None:
        return None
    body = _read_exact(fd, HEADER.unpack(head)[0])
    return None if body is None else pickle.loads(body)


def _report(fd: int, text: str) -> None:
    data = text.encode(errors="replace")
    if len(data) > ACCOUNT_BYTES:  # keep the first line (the summary) and the end of the traceback
        head = data.split(b"\n", 1)[0][:1024] + b"\n...\n"
        data = head + data[len(head) - ACCOUNT_BYTES:]
    with contextlib.suppress(OSError):
        while data:
            data = data[os.write(fd, data):]


def _drain(fd: int) -> str:
    """All a dead child wrote on its account pipe."""
    chunks = []
    with contextlib.suppress(OSError):
        while chunk := os.read(fd, 65536):
            chunks.append(chunk)
    os.close(fd)
    return b"".join(chunks).decode(errors="replace")


# ----- the server process -----

def serve() -> None:
    from node_runtime.runtime import process  # noqa: F401  the preload: zenoh, numpy, msgpack and all node code

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    requests, replies = sys.stdin.fileno(), os.dup(sys.stdout.fileno())
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # children's prints go to the orchestrator's stderr
    children: dict[int, str] = {}
    accounts: dict[int, int] = {}  # pid -> read end of the pipe its account comes on
    sel = selectors.DefaultSelector()
    sel.register(requests, selectors.EVENT_READ)
    try:
        while True:
            for _ in sel.select(timeout=0.05):
                msg = _read(requests)
                if msg is None:  # the orchestrator is gone
                    return
                _, name, job = msg
                try:
                    target, args = pickle.loads(job)
                except Exception as exc:  # e.g. a target defined in the caller's __main__
                    _write(replies, ("failed", name, f"{type(exc).__name__}: {exc}"))
                    continue
                readable, writable = os.pipe()
                pid = os.fork()
                if pid == 0:
                    for fd in (requests, replies, readable, *accounts.values()):
                        os.close(fd)
                    try:
                        target(*args)
                    except BaseException as exc:
                        _report(writable, account(exc))
                    finally:
                        with contextlib.suppress(Exception):
                            sys.stdout.flush()
                            sys.stderr.flush()
                        os._exit(1)  # a target that returns or raises instead of exiting
                os.close(writable)
                children[pid] = name
                accounts[pid] = readable
                _write(replies, ("started", name, pid))
            while children:
                pid, status = os.waitpid(-1, os.WNOHANG)
                if pid == 0:
                    break
                why = _drain(accounts.pop(pid)) if pid in accounts else ""
                _write(replies, ("exited", children.pop(pid, "?"), pid, os.waitstatus_to_exitcode(status), why))
    finally:
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


# ----- the orchestrator's handle -----

def same_code_environment() -> dict[str, str]:
    """The environment of a server that runs the very code this process imported: this package's tree
    first on its path, and (``python -P``) not the working directory, which may hold another checkout."""
    tree = str(Path(__file__).resolve().parents[2])
    return {**os.environ, "PYTHONPATH": os.pathsep.join([tree, *filter(None, [os.environ.get("PYTHONPATH")])])}


class ForkServer:
    """Starts node processes through one long-lived server process (shared by this interpreter)."""

    _shared: ForkServer | None = None
    _lock = threading.Lock()

    def __init__(self) -> None:
        self.server = subprocess.Popen([sys.executable, "-P", "-m", "node_runtime.runtime.forkserver"],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True,
                                       env=same_code_environment())
        self.exits: dict[int, int] = {}  # pid -> exit status
        self.accounts: dict[int, str] = {}  # pid -> what it said when it failed ("" if nothing)
        self._started: dict[str, list[int]] = {}
        self._failed: dict[str, str] = {}
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._listen, name="forkserver-listener", daemon=True)
        self._reader.start()

    @classmethod
    def shared(cls) -> ForkServer:
        with cls._lock:
            if cls._shared is None or cls._shared.server.poll() is not None:
                cls._shared = cls()
                atexit.register(cls._shared.close)
            return cls._shared

    def _listen(self) -> None:
        fd = self.server.stdout.fileno()
        while (msg := _read(fd)) is not None:
            with self._cond:
                self._note(msg)
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def _note(self, msg: tuple) -> None:
        """Record one of the server's replies or notices (the caller holds ``_cond``)."""
        if msg[0] == "started":
            name, pid = msg[1], msg[2]
            # Linux reuses pids once the counter wraps (32768 by default; every thread takes one too), and
            # the server reaps a child before it can fork another with its pid: an exit recorded for
            # this pid was a former child's, and must not read as this one's.
            self.exits.pop(pid, None)
            self.accounts.pop(pid, None)
            self._started.setdefault(name, []).append(pid)
        elif msg[0] == "failed":
            self._failed[msg[1]] = msg[2]
        else:
            self.exits[msg[2]] = msg[3]
            self.accounts[msg[2]] = msg[4]

    def start(self, name: str, target: Callable[..., None], *args: Any, timeout: float = 30.0) -> int:
        """Fork a child running ``target(*args)``; returns its pid."""
        with self._cond:
            if self.server.poll() is not None:
                raise RuntimeError(f"the node fork server exited (status {self.server.returncode})")
            _write(self.server.stdin.fileno(), ("start", name, pickle.dumps((target, args))))
            self._cond.wait_for(lambda: self._started.get(name) or name in self._failed
                                or self.server.poll() is not None, timeout)
            if self._started.get(name):
                return self._started[name].pop(0)
            if name in self._failed:
                raise RuntimeError(f"the node fork server cannot start {name}: {self._failed.pop(name)}")
            if self.server.poll() is not None:
                raise RuntimeError(f"the node fork server exited (status {self.server.returncode})")
            raise RuntimeError(f"the node fork server did not start {name} within {timeout:.0f} s")

    def exit_status(self, pid: int) -> int | None:
        with self._cond:
            return self.exits.get(pid)

    def account(self, pid: int) -> str:
        """What an exited child said about its failure: 'Type: message' then the traceback, or ""."""
        with self._cond:
            return self.accounts.get(pid, "")

    def wait(self, pids: list[int], timeout: float | None) -> list[int]:
        """Wait until these processes have exited (``timeout`` None: however long); returns those still running."""
        with self._cond:
            self._cond.wait_for(lambda: all(p in self.exits for p in pids), timeout)
            return [p for p in pids if p not in self.exits]

    def close(self) -> None:
        if self.server.poll() is None:
            self.server.stdin.close()
            try:
                self.server.wait(5.0)
            except subprocess.TimeoutExpired:
                self.server.kill()
                self.server.wait()
        self._reader.join(2.0)


if __name__ == "__main__":
    serve()
