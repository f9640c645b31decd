"""Shared helpers: small scenarios written on the fly, and runs over both transports."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import fcntl
import json
import os
import select
import shutil
import signal
import subprocess
import sys
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
        for ns in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split():
            if ns.startswith("zedge-wire"):  # a wire (``wire``) a killed test session left, with a host's address
                subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        subprocess.run([NETNS, "down"], check=True, capture_output=True)
        made = subprocess.run([NETNS, "up", "2"], capture_output=True, text=True)
        if made.returncode != 0:
            subprocess.run([NETNS, "down"], capture_output=True)
            pytest.skip(f"cannot create network namespaces here: {made.stderr.strip()}")
        yield ["zedge-host1", "zedge-host2"]
        subprocess.run([NETNS, "down"], check=True, capture_output=True)
        left = [ns for ns in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split()
                if ns.startswith("zedge-")]
        assert not left, f"namespaces left behind: {left}"


def shape(host: int, rule: str) -> None:
    """A tc qdisc on both ends of host ``host``'s link (deploy/netns.sh numbers them from 1), e.g. "tbf rate
    1mbit ..." or "netem delay 20ms"; empty: remove it. The ``hosts`` fixture deletes the links, qdiscs included."""
    if shutil.which("tc") is None:
        pytest.skip("tc (iproute2) is needed for link faults")
    ns = f"zedge-host{host}"
    for cmd in (["tc", "qdisc", "del", "dev", f"zedge{host}-o", "root"],
                ["ip", "netns", "exec", ns, "tc", "qdisc", "del", "dev", f"zedge{host}-h", "root"]):
        subprocess.run(cmd, capture_output=True)  # nothing to delete is fine
    if not rule:
        return
    for cmd in (["tc", "qdisc", "add", "dev", f"zedge{host}-o", "root", *rule.split()],
                ["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", f"zedge{host}-h", "root", *rule.split()]):
        made = subprocess.run(cmd, capture_output=True, text=True)
        if made.returncode != 0:
            pytest.skip(f"tc {rule.split()[0]} is not available here: {made.stderr.strip()}")


def cut(host: int, down: bool) -> None:
    """Take host ``host``'s link down (a partition: no packet passes, no connection is reset) or up again."""
    subprocess.run(["ip", "link", "set", f"zedge{host}-o", "down" if down else "up"], check=True, capture_output=True)


@dataclasses.dataclass
class Wire:
    """A wire's process, made faulty by ``strike``; ``counts``, once its block is over: how many frames it
    forwarded, dropped and reordered since."""

    relay: subprocess.Popen
    counts: dict[str, int] = dataclasses.field(default_factory=dict)

    def strike(self) -> None:
        self.relay.send_signal(signal.SIGUSR1)


@contextlib.contextmanager
def wire(host: int, loss: float, delay: float, jitter: float) -> Any:
    """Host ``host``'s link through a wire that can turn lossy, slow and reordering (tests/wire.py, netem in user
    space): its veth's end here moves to a namespace zedge-wire<host> of its own, where the wire forwards its
    frames to a new veth pair that takes its address. Undone after, whatever happened: that namespace, the
    wire's process and the veths go (the host's end of its link with them). Yields a ``Wire``."""
    ns, here, there = f"zedge-wire{host}", f"zedge{host}-w", f"zedge{host}-x"
    subprocess.run(["ip", "netns", "delete", ns], capture_output=True)  # one a killed test left
    relay = None
    try:
        for cmd in (["ip", "netns", "add", ns], ["ip", "link", "set", f"zedge{host}-o", "netns", ns],
                    ["ip", "link", "add", here, "type", "veth", "peer", "name", there],
                    ["ip", "link", "set", there, "netns", ns],
                    ["ip", "addr", "add", f"10.77.{host}.1/24", "dev", here], ["ip", "link", "set", here, "up"],
                    ["ip", "netns", "exec", ns, "ip", "link", "set", f"zedge{host}-o", "up", "promisc", "on"],
                    ["ip", "netns", "exec", ns, "ip", "link", "set", there, "up", "promisc", "on"],
                    [sys.executable, "-m", "tests.wire", "--software", here],
                    ["ip", "netns", "exec", f"zedge-host{host}", sys.executable, "-m", "tests.wire", "--software",
                     f"zedge{host}-h"]):
            subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT, timeout=60)
        relay = subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, "-m", "tests.wire", f"zedge{host}-o",
                                  there, "--loss", str(loss), "--delay", str(delay), "--jitter", str(jitter)],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        ready, _, _ = select.select([relay.stdout], [], [], 60)
        assert ready and relay.stdout.readline() == "ready\n", relay.stderr.read() if relay.poll() else "no answer"
        handle = Wire(relay)
        yield handle
        relay.terminate()
        said = relay.communicate(timeout=60)[0].split()
        handle.counts.update(zip(said[::2], map(int, said[1::2]), strict=True))
    finally:
        if relay is not None and relay.poll() is None:
            relay.kill()
            relay.wait()
        subprocess.run(["ip", "netns", "delete", ns], capture_output=True)


def check_outputs(out: Path, nodes: int) -> dict[str, Any]:
    """A run's outputs are whole, however it ended: the tables hold ticks 0 .. last once each (every node once
    a tick) and summary.json counts exactly those ticks; returns the summary."""
    summary = json.loads((out / "summary.json").read_text())
    if summary["ticks"] == 0:  # interrupted before the first tick: the summary says why, tables may be missing
        assert summary["incomplete"]["last_tick"] is None
        return summary
    with (out / "ticks.csv").open() as fh:
        ticks = [int(row["tick"]) for row in csv.DictReader(fh)]
    with (out / "nodes.csv").open() as fh:
        node_rows = [(int(row["tick"]), row["node"]) for row in csv.DictReader(fh)]
    assert ticks == list(range(len(ticks))), f"ticks.csv: {len(ticks)} rows, {len(set(ticks))} distinct ticks"
    assert len(node_rows) == len(set(node_rows)) == nodes * len(ticks), "nodes.csv repeats or misses rows"
    assert sorted({t for t, _ in node_rows}) == ticks
    assert summary["ticks"] == len(ticks)
    if "incomplete" in summary:
        assert summary["incomplete"]["last_tick"] == (ticks[-1] if ticks else None)
    return summary
