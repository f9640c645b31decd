"""Spreading a simulation over several hosts, with Linux network namespaces as the hosts.

deploy/netns.sh makes two namespaces linked to this one by veth pairs; the orchestrator listens on
all addresses here, and ``zenohedge-node`` runs one placement group inside each namespace.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import psutil
import pytest

from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, model_part, run_summary
from tests.launcher import Launch, assert_all_gone

pytestmark = pytest.mark.zenoh
NETNS = ROOT / "deploy" / "netns.sh"


@pytest.fixture
def hosts():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    subprocess.run([NETNS, "down"], check=True, capture_output=True)
    made = subprocess.run([NETNS, "up", "2"], capture_output=True, text=True)
    if made.returncode != 0:
        subprocess.run([NETNS, "down"], capture_output=True)
        pytest.skip(f"cannot create network namespaces here: {made.stderr.strip()}")
    yield ["zedge-host1", "zedge-host2"]
    subprocess.run([NETNS, "down"], check=True, capture_output=True)


def net_namespace(pid: int) -> str:
    return os.readlink(f"/proc/{pid}/ns/net")


def test_two_hosts_give_the_same_emulation(tmp_path, hosts):
    from orchestrator.session import free_port

    port = free_port("0.0.0.0")
    run = Launch("aot2", "--layout", "per-node", "--listen", f"0.0.0.0:{port}", "--sim-id", "deploytest",
                 "--placement", str(ROOT / "deploy" / "examples" / "aot2-two-hosts.yaml"), "--steps", "150",
                 "--seed", "4", "--policy", "random", "--out", str(tmp_path / "run"))
    run.wait_for("waiting for 18 processes on other hosts")
    groups = []
    for i, (ns, group) in enumerate(zip(hosts, ["cluster-a", "cluster-b"], strict=True), start=1):
        groups.append(subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "node_runtime.runtime.remote", "--connect",
             f"tcp/10.77.{i}.1:{port}", "--sim", "deploytest", "--group", group],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    run.wait_for("processes ready")
    here = net_namespace(os.getpid())
    remote = [p for g in groups for p in psutil.Process(g.pid).children(recursive=True) if p.name().startswith("zn-")]
    assert len(remote) == 18
    assert all(net_namespace(p.pid) != here for p in remote)  # they really run on the other "hosts"
    local = [p for p in run.descendants() if p.name().startswith("zn-")]
    assert [p.name() for p in local] == ["zn-server_0"]

    assert run.finish(120) == 0
    for g in groups:
        assert g.wait(30) == 0, g.stderr.read()
    assert_all_gone(remote + local)

    deployed = json.loads((tmp_path / "run" / "summary.json").read_text())
    alone = run_summary(load_scenario("aot2"), ticks=150, seed=4, policy="random")
    assert model_part(deployed) == model_part(alone)


def test_bad_placement_is_a_clear_error(tmp_path):
    bad = tmp_path / "placement.yaml"
    bad.write_text("groups:\n  a: [rpi3_0, nope]\n  b: [rpi3_0]\n")
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", "aot2", "--placement", str(bad)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        f"{bad}: groups.a[1]: unknown node 'nope' in scenario aot2",
        f"{bad}: groups.b[0]: node 'rpi3_0' is already placed in group 'a'",
    ]
