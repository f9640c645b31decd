"""Spreading a simulation over several hosts, with Linux network namespaces as the hosts.

deploy/netns.sh makes two namespaces linked to this one by veth pairs; the orchestrator listens on
all addresses here, and ``zenohedge-node`` runs one placement group inside each namespace.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys

import psutil
import pytest

from node_runtime.runtime.layout import ProcessLayout
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, model_part, run_summary
from tests.launcher import Launch, assert_all_gone

pytestmark = pytest.mark.zenoh


def net_namespace(pid: int) -> str:
    return os.readlink(f"/proc/{pid}/ns/net")


def tcp_peers(pid: int) -> list[tuple[str, int]]:
    """The remote (address, port) of each TCP connection the process holds, read in its own network namespace."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):  # closed meanwhile
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
            if link.startswith("socket:["):
                inodes.add(link[8:-1])
    peers = []
    for table in ("tcp", "tcp6"):
        with open(f"/proc/{pid}/net/{table}") as f:
            for line in list(f)[1:]:
                cols = line.split()
                address, port = cols[2].split(":")
                if cols[9] in inodes and cols[3] == "01" and len(address) == 8:  # ESTABLISHED, IPv4
                    peers.append((socket.inet_ntoa(bytes.fromhex(address)[::-1]), int(port, 16)))
    return peers


def test_two_hosts_give_the_same_emulation(tmp_path, hosts):
    """Host 1 runs its processes behind its own router (the default), host 2 connects each process to the
    orchestrator's router (``--direct``): the same emulation as one host either way."""
    from orchestrator.session import free_port

    port = free_port("0.0.0.0")
    run = Launch("aot2", "--layout", "per-node", "--listen", f"0.0.0.0:{port}", "--insecure", "--sim-id", "deploytest",
                 "--placement", str(ROOT / "deploy" / "examples" / "aot2-two-hosts.yaml"), "--steps", "150",
                 "--seed", "4", "--policy", "random", "--out", str(tmp_path / "run"), "--serve")
    run.wait_for("waiting for 18 processes on other hosts")
    groups = []
    for i, (ns, group, how) in enumerate(zip(hosts, ["cluster-a", "cluster-b"], [[], ["--direct"]], strict=True),
                                         start=1):
        groups.append(subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "node_runtime.runtime.remote", "--connect",
             f"tcp/10.77.{i}.1:{port}", "--sim", "deploytest", "--group", group, *how],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    run.wait_for("serving until Ctrl-C")  # the episode is over; every process is still connected
    here = net_namespace(os.getpid())
    remote = [[p for p in psutil.Process(g.pid).children(recursive=True) if p.name().startswith("zn-")]
              for g in groups]
    assert [len(r) for r in remote] == [9, 9]
    assert all(net_namespace(p.pid) != here for r in remote for p in r)  # they really run on the other "hosts"
    local = [p for p in run.descendants() if p.name().startswith("zn-")]
    assert [p.name() for p in local] == ["zn-server_0"]
    # host 1: one session crosses the network, its router's; host 2: one per process
    assert tcp_peers(groups[0].pid) == [("10.77.1.1", port)]  # `ip netns exec` became zenohedge-node
    assert all(tcp_peers(p.pid) == [] for p in remote[0])
    assert all(tcp_peers(p.pid) == [("10.77.2.1", port)] for p in remote[1])

    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(120) == 130
    for g in groups:
        assert g.wait(30) == 0, g.stderr.read()
    assert_all_gone([p for r in remote for p in r] + local)

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



def test_a_process_split_between_hosts_is_refused(tmp_path):
    """With groups:K a process holds a block of nodes: a placement that puts them on different hosts (or
    some on none) is refused, and each process of a group is started once, however many nodes it holds."""
    from orchestrator.placement import load_placement
    from orchestrator.scenario import ScenarioError

    two_hosts = ROOT / "deploy" / "examples" / "aot2-two-hosts.yaml"
    with pytest.raises(ScenarioError) as refused:
        load_placement(two_hosts, ProcessLayout(load_scenario("aot2"), "groups:4"))
    assert refused.value.errors == [
        f"{two_hosts}: process group-1 of layout groups:4 holds nodes of different groups: rpi3_5 (cluster-a), "
        "nuc_0 (cluster-a), tx2_0 (cluster-a), tx2_1 (cluster-a), rpi3_6 (cluster-b); place all of its nodes in "
        "one group",
        f"{two_hosts}: process group-3 of layout groups:4 holds nodes of different groups: nuc_1 (cluster-b), "
        "tx2_2 (cluster-b), tx2_3 (cluster-b), server_0 (unplaced); place all of its nodes in one group"]
    plan = ProcessLayout(load_scenario("aot2"), "groups:2")
    whole = tmp_path / "whole.yaml"
    whole.write_text(f"groups:\n  a: [{', '.join(plan.node_of_proc('group-0'))}]\n")
    assert load_placement(whole, plan) == {"a": ["group-0"]}  # once, not once per node


@pytest.fixture
def intruder():
    """Start ``python -m tests.intruder`` in a namespace; whatever a failing test leaves running is killed."""
    started: list[subprocess.Popen] = []

    def start(ns: str, endpoint: str, *args: str) -> subprocess.Popen:
        started.append(subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, "-m", "tests.intruder", endpoint,
                                         "securetest", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True))
        return started[-1]

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_secure_two_hosts_refuse_outsiders(tmp_path, hosts, intruder):
    """The deploy/README.md default: TLS with client certificates, logins and access control. Outsiders
    without a certificate or the right password cannot connect; a host with a valid identity cannot
    publish on keys that are not its own, nor forge its own processes' reports (it lacks their keys); the run
    is the same emulation as a clean one."""
    from orchestrator.session import free_port

    secrets = tmp_path / "secrets"
    subprocess.run([ROOT / "deploy" / "make-certs.sh", secrets, "10.77.1.1,10.77.2.1", "cluster-a", "cluster-b"],
                   check=True, capture_output=True)
    port = free_port("0.0.0.0")
    run = Launch("aot2", "--layout", "per-node", "--listen", f"0.0.0.0:{port}", "--sim-id", "securetest",
                 "--placement", str(ROOT / "deploy" / "examples" / "aot2-two-hosts.yaml"), "--steps", "150",
                 "--seed", "4", "--policy", "random", "--out", str(tmp_path / "run"),
                 "--security", str(secrets / "orchestrator"))
    run.wait_for("waiting for 18 processes on other hosts")
    tls, victim = f"tls/10.77.1.1:{port}", "node-rpi3_6"  # a process of cluster-b, on the other host
    refused = [intruder("zedge-host1", f"tcp/10.77.1.1:{port}", victim),  # plain TCP
               intruder("zedge-host1", tls, victim, "--ca", str(secrets / "ca" / "ca.pem")),  # no client cert
               intruder("zedge-host1", tls, victim, "--security", str(secrets / "cluster-a"), "--password", "x")]
    for attempt in refused:
        out, err = attempt.communicate(timeout=60)
        assert (attempt.returncode, out) == (3, "refused\n"), err
    inside = intruder("zedge-host1", tls, victim, "--security", str(secrets / "cluster-a"))  # a compromised host
    own = intruder("zedge-host1", tls, "node-rpi3_0", "--victim-group", "cluster-a", "--security",
                   str(secrets / "cluster-a"))  # the same, forging the reports of its own group's process
    for forger in (inside, own):
        assert forger.stdout.readline() == "connected\n"
        assert forger.stdout.readline() == "forging\n"

    def group(i: int, name: str) -> subprocess.Popen:
        return subprocess.Popen(
            ["ip", "netns", "exec", f"zedge-host{i}", sys.executable, "-m", "node_runtime.runtime.remote", "--connect",
             f"tls/10.77.{i}.1:{port}", "--sim", "securetest", "--group", name, "--security", str(secrets / name)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    # The same identity on host 1's own router: its access control is the orchestrator's, so forged ticks
    # and Done reach neither the orchestrator nor the processes beside it. The run cannot start before
    # host 2's processes are ready, so both intruders forge while it runs.
    groups = [group(1, "cluster-a")]
    local = groups[0].stderr.readline().rstrip().rpartition("connected to ")[2]
    assert local.startswith("unixsock-stream/"), local
    beside = intruder("zedge-host1", local, victim, "--security", str(secrets / "cluster-a"))
    own_beside = intruder("zedge-host1", local, "node-rpi3_0", "--victim-group", "cluster-a", "--security",
                          str(secrets / "cluster-a"))
    for forger in (beside, own_beside):
        assert forger.stdout.readline() == "connected\n"
        assert forger.stdout.readline() == "forging\n"
    groups.append(group(2, "cluster-b"))
    assert run.finish(120) == 0, "".join(run.err)
    for g in groups:
        assert g.wait(30) == 0, g.stderr.read()
    for forger in (inside, beside, own, own_beside):
        out, err = forger.communicate(timeout=60)
        assert forger.returncode == 0 and out.split()[-2] == "forged" and int(out.split()[-1]) > 0, err

    deployed = json.loads((tmp_path / "run" / "summary.json").read_text())
    alone = run_summary(load_scenario("aot2"), ticks=150, seed=4, policy="random")
    assert model_part(deployed) == model_part(alone)
    assert deployed["run"]["rejected_messages"]["orchestrator"]["bad_mac"] > 0  # its own process's, without the key
