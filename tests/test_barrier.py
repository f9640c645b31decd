"""The bare Zenoh barrier that every benchmark ratio divides by: on loopback, and spread over host routers
laid out as `zenohedge-node` lays out a host (benchmarks/hosts.py)."""

from __future__ import annotations

import subprocess
import sys

import psutil
import pytest

from orchestrator.viewers.bench import BareBarrier
from tests.conftest import ROOT
from tests.launcher import TIMEOUT

sys.path.insert(0, str(ROOT / "benchmarks"))  # hosts.py imports its sibling scale.py as a script does
import hosts as hosts_script

pytestmark = pytest.mark.zenoh


def participants() -> list[str]:
    """Barrier participants still running anywhere on this machine (they name themselves zb-<index>)."""
    found = []
    for proc in psutil.process_iter(["name"]):
        if (proc.info["name"] or "").startswith("zb-"):
            found.append(proc.info["name"])
    return found


def test_a_local_barrier_runs_rounds_and_its_participants_end():
    barrier = BareBarrier(3)
    try:
        assert barrier.rate(20) > 0
    finally:
        barrier.close()
    assert barrier.forks.wait(barrier.pids, TIMEOUT) == []


def test_participants_behind_two_host_routers_answer_every_round():
    """Two `--barrier-host` processes on loopback, each a router joined to the barrier's with its share of
    the five participants behind it on a unix socket: the rounds complete, and close ends them all."""
    members: list[subprocess.Popen] = []

    def spawn(endpoint: str, root: str) -> None:
        for first, count in ((0, 3), (3, 2)):
            members.append(subprocess.Popen([sys.executable, "benchmarks/hosts.py", "--barrier-host", endpoint, root,
                                             str(first), str(count)], cwd=ROOT))

    barrier = BareBarrier(5, spawn=spawn, timeout=TIMEOUT)
    try:
        assert barrier.rate(20) > 0
    finally:
        barrier.close()
    assert [m.wait(TIMEOUT) for m in members] == [0, 0]
    assert participants() == []


def test_host_shares_cover_every_process_once():
    assert hosts_script.shares(16, 4) == [range(0, 4), range(4, 8), range(8, 12), range(12, 16)]
    assert hosts_script.shares(5, 2) == [range(0, 3), range(3, 5)]
    assert hosts_script.shares(2, 4) == [range(0, 1), range(1, 2)]  # fewer processes than hosts: no empty host


def test_a_barrier_spread_over_network_namespaces(hosts):
    """benchmarks/hosts.py's barrier column: participants in two namespaces behind their own routers."""
    assert hosts_script.barrier(procs=4, hosts=2, ticks=20, rounds=2) > 0
    assert participants() == []
