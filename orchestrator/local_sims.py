"""The simulations launched on this host, so that ``orchestrator monitor`` finds them without --connect.

``orchestrator launch`` (over Zenoh) writes one small JSON file per simulation while it runs, in a
directory that only this user can write: ``$XDG_RUNTIME_DIR/zenohedge/``, or
``<temp dir>/zenohedge-<uid>/`` where XDG_RUNTIME_DIR is unset. The file goes when the launch ends
(normally, on an error, Ctrl-C or SIGTERM); one left by a killed launch is ignored, and deleted, by
the next reader, since its process is gone. Other users' simulations are never seen, so a monitor on
a shared host cannot attach to someone else's run by mistake.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import stat
import tempfile
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields
from pathlib import Path

SUFFIX = ".json"


class LocalSimsError(Exception):
    """The directory of local simulations cannot be trusted or written (one line, naming it)."""


@dataclass(frozen=True)
class Entry:
    sim: str  # simulation id
    endpoint: str  # where a client on this host reaches its router
    scenario: str  # scenario name
    pid: int  # the orchestrator's process
    started: str  # ISO 8601, local time with offset

    def describe(self) -> str:
        return f"{self.sim} ({self.scenario}) at {self.endpoint}, pid {self.pid}, started {self.started}"


def directory() -> Path:
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isabs(runtime):
        return Path(runtime) / "zenohedge"
    return Path(tempfile.gettempdir()) / f"zenohedge-{os.getuid()}"


def _private(path: Path, create: bool) -> bool:
    """Whether ``path`` is a directory of ours that nobody else can write (creating it if asked)."""
    if create:
        try:
            path.mkdir(mode=0o700, parents=True)
        except FileExistsError:
            pass
        except OSError as exc:
            raise LocalSimsError(f"{path}: cannot create: {exc.strerror}") from None
    try:
        st = path.lstat()
    except FileNotFoundError:
        return False
    if not stat.S_ISDIR(st.st_mode):
        raise LocalSimsError(f"{path}: expected a directory of simulations, found something else")
    if st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise LocalSimsError(f"{path}: owned or writable by another user; remove it to monitor local simulations")
    return True


def local_endpoint(endpoint: str) -> str:
    """The endpoint a client on this host connects to: a router listening on every interface
    (tcp/0.0.0.0:7447) is reached on loopback."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    loopback = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(host)
    return f"{proto}/{loopback}:{port}" if loopback else endpoint


@contextlib.contextmanager
def registered(sim: str, endpoint: str, scenario: str) -> Iterator[Entry]:
    """List this process's simulation for the duration of the block."""
    folder = directory()
    _private(folder, create=True)
    entry = Entry(sim, local_endpoint(endpoint), scenario, os.getpid(),
                  dt.datetime.now().astimezone().isoformat(timespec="seconds"))
    path = folder / f"{sim}.{entry.pid}{SUFFIX}"
    partial = path.with_suffix(".tmp")  # written whole, then renamed: a reader never sees half a file
    try:
        partial.write_text(json.dumps(asdict(entry)))
        partial.replace(path)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise LocalSimsError(f"{folder}: cannot write: {exc.strerror}") from None
    try:
        yield entry
    finally:
        path.unlink(missing_ok=True)


def running() -> list[Entry]:
    """The simulations launched on this host by this user that still run, oldest first."""
    folder = directory()
    if not _private(folder, create=False):
        return []
    entries = []
    for path in folder.glob(f"*{SUFFIX}"):
        try:
            data = json.loads(path.read_text())
            entry = Entry(**{f.name: data[f.name] for f in fields(Entry)})  # later versions may add fields
        except OSError:  # its launch just ended, or it is not ours to read
            continue
        except (ValueError, TypeError, KeyError):  # not a listing
            path.unlink(missing_ok=True)
            continue
        if _alive(entry.pid):
            entries.append(entry)
        else:
            path.unlink(missing_ok=True)
    return sorted(entries, key=lambda e: (e.started, e.sim))


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a running process of this user (not gone, not a zombie awaiting its parent)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):  # gone, or the number now belongs to another user
        return False
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return True
    return state != "Z"
