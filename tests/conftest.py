"""Shared helpers: small scenarios written on the fly, and runs over both transports."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation

ROOT = Path(__file__).resolve().parent.parent

# A suite started in the background by a script (`pytest &`) inherits SIGINT ignored, and every process it
# starts would too: the tests that press Ctrl-C on a launch would then wait for nothing. A handled SIGINT here
# is reset to the default in every child.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--all", action="store_true", default=False,
                     help="also run the full sets of the long differential tests (tests/test_array_backend.py)")


@pytest.fixture(autouse=True, scope="session")
def own_runtime_dir(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The simulations the tests launch are listed for `orchestrator monitor` (orchestrator.local_sims) in
    a directory of this session's, not in the user's: a developer's bare monitor never sees them, and a
    launch a test kills on purpose leaves its file there."""
    path = tmp_path_factory.mktemp("xdg-runtime")
    path.chmod(0o700)
    patch = pytest.MonkeyPatch()
    patch.setenv("XDG_RUNTIME_DIR", str(path))
    yield path
    patch.undo()


@pytest.fixture(autouse=True)
def no_launch_outlives_its_test() -> Any:
    """A test whose assertion fails skips its own clean-up: a served launch would then run on for ever,
    with its node processes. What the test itself left running is stopped after it, as SIGTERM would;
    launches of fixtures that outlive one test (a module's served run) are theirs to stop."""
    from tests.launcher import Launch, end_all  # the launcher imports this module

    before = list(Launch.running)
    yield
    end_all(keep=before)


def write_scenario(tmp_path: Path, data: dict[str, Any], name: str = "scenario.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_summary(scenario, ticks: int | None = None, transport: str = "inproc", layout: str | None = None,
                seed: int | None = None, policy: str | None = None, out: Path | None = None) -> dict[str, Any]:
    with Simulation.open(scenario, transport, layout=layout) as sim:
        summary = sim.run(ticks, seed=seed, policy=policy)
        if out is not None:
            sim.metrics.write(out, summary)
    return summary


def model_part(summary: dict[str, Any]) -> dict[str, Any]:
    """Everything the emulation decides; not how fast or where it ran, nor the state of the checkout
    (``code.dirty`` may change between two runs of one test while someone edits the tree)."""
    return {k: v for k, v in summary.items() if k not in ("run", "code")}


@pytest.fixture
def aot1():
    return load_scenario(ROOT / "topologies" / "aot1.yaml")


@pytest.fixture
def aot2():
    return load_scenario(ROOT / "topologies" / "aot2.yaml")


def dump(obj: Any) -> str:
    return json.dumps(obj, indent=1, sort_keys=True)


def same(a: Any, b: Any) -> bool:
    """Exact equality of nested dicts, lists, tuples and arrays (dtype included): two environment steps agree."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    return a == b


NETNS = ROOT / "deploy" / "netns.sh"
# The namespaces have machine-wide names: two test suites on one machine (two checkouts) take turns with them
NETNS_LOCK = Path(tempfile.gettempdir()) / "zenohedge-netns.lock"
NETNS_WAIT_S = 600.0


@contextlib.contextmanager
def machine_lock(path: Path, timeout: float) -> Any:
    """Hold an exclusive lock on ``path`` (shared by every process of the machine); fail after ``timeout`` s."""
    with path.open("a") as fh:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    pytest.fail(f"{path} held by another test suite for {timeout:.0f} s")
                time.sleep(0.2)  # polling the lock: flock has no timeout of its own
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@pytest.fixture
def hosts():
    """Two network namespaces standing for two hosts (deploy/netns.sh): zedge-host1 and zedge-host2."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    with machine_lock(NETNS_LOCK, NETNS_WAIT_S):
        subprocess.run([NETNS, "down"], check=True, capture_output=True)
        made = subprocess.run([NETNS, "up", "2"], capture_output=True, text=True)
        if made.returncode != 0:
            subprocess.run([NETNS, "down"], capture_output=True)
            pytest.skip(f"cannot create network namespaces here: {made.stderr.strip()}")
        yield ["zedge-host1", "zedge-host2"]
        subprocess.run([NETNS, "down"], check=True, capture_output=True)
