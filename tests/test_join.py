"""Hosts that join a run: ``zenohedge-node`` on loopback, started with the very commands ``launch`` prints.

Unlike tests/test_deploy.py (network namespaces, root), these run wherever the suite does. They check
that the printed commands work as printed, that the run equals one process, and that the processes of
other hosts get the orchestrator's timing: they wait for late hosts as long as the orchestrator does,
and a paused one is reported hung after ``--timeout``, not dropped as dead by Zenoh's default 10 s lease.
"""

from __future__ import annotations

import json
import signal
import sys

import numpy as np
import psutil
import pytest

from env import ZenohEdgeEnv
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.remote import group_info
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, model_part, run_summary
from tests.launcher import Launch, Output, assert_all_gone, paused_run
from tests.test_serve import play

pytestmark = pytest.mark.zenoh

PLACEMENT = str(ROOT / "deploy" / "examples" / "aot2-two-hosts.yaml")
GROUPS = ("cluster-a", "cluster-b")


def launch_placed(tmp_path, *args: str) -> tuple[Launch, dict[str, list[str]]]:
    """``launch`` with the two-host placement, and the command it prints for each group (as argv)."""
    run = Launch("aot2", "--layout", "per-node", "--placement", PLACEMENT, "--out", str(tmp_path), *args)
    run.wait_for("waiting for 18 processes on other hosts")
    for _ in GROUPS:
        run.wait_for("zenohedge-node --connect")
    lines = [line.split() for line in run.err if "zenohedge-node --connect" in line]
    commands = {argv[argv.index("--group") + 1]: argv for argv in lines}
    assert sorted(commands) == list(GROUPS)
    return run, commands


def join(argv: list[str]) -> Output:
    """Run a printed ``zenohedge-node …`` command with this interpreter."""
    assert argv[0] == "zenohedge-node"
    return Output(sys.executable, "-m", "node_runtime.runtime.remote", *argv[1:])


def test_hosts_join_with_the_printed_commands_and_get_the_orchestrators_timing(tmp_path):
    run, commands = launch_placed(tmp_path, "--steps", "40", "--timeout", "45", "--serve")
    argv = commands["cluster-a"]
    endpoint, sim = argv[argv.index("--connect") + 1], argv[argv.index("--sim") + 1]
    asker = ZenohTransport.client(endpoint)
    try:
        info = group_info(asker, endpoint, Keys(sim), "cluster-a", timeout=30)
    finally:
        asker.close()
    assert (info.ready_timeout, info.lease_s) == (600.0, 50.0)  # the groups' wait; --timeout + 5 s

    # cluster-a forwards its processes' reports of a tick as one message (the default); cluster-b's report alone
    hosts = [join(commands["cluster-a"]), join([*commands["cluster-b"], "--no-aggregate"])]
    run.wait_for("serving until Ctrl-C")
    # a driver attached from elsewhere takes the forwarded reports too: it learns the hosts from the session
    env = ZenohEdgeEnv(connect=endpoint, sim_id=sim, max_steps=20)
    obs, rewards, _ = play(env, seed=3, steps=20)
    forwarded = env.sim.clock.reports["host_messages"]
    env.close()
    local = ZenohEdgeEnv("aot2", transport="inproc", max_steps=20)
    local_obs, local_rewards, _ = play(local, seed=3, steps=20)
    local.close()
    assert forwarded > 0 and rewards == local_rewards
    assert all(np.array_equal(obs[a][k], local_obs[a][k]) for a in obs for k in obs[a])
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(120) == 130, "".join(run.err)
    for host in hosts:
        status, _, err = host.finish(timeout=60)
        assert status == 0, err
    placed = json.loads((tmp_path / "summary.json").read_text())
    alone = run_summary(load_scenario("aot2"), ticks=40)
    assert model_part(placed) == model_part(alone)
    reports = placed["run"]["reports"]
    assert reports["alone"] > 0  # cluster-b's and the orchestrator's own process (the server)
    # messages that carry several reports (one each, without forwarding): about two a message here, where most of
    # cluster-a's processes sleep or coast through most ticks
    assert reports["from_hosts"] > 1.5 * reports["host_messages"] > 0, reports


def test_a_paused_process_on_another_host_is_reported_hung_after_the_timeout(tmp_path):
    run, commands = launch_placed(tmp_path, "--steps", "100000", "--timeout", "15")
    hosts = [join(commands[g]) for g in GROUPS]
    run.wait_for("processes ready")
    children = [p for host in hosts for p in psutil.Process(host.proc.pid).children(recursive=True)]
    code, elapsed, error = paused_run(run, next(p for p in children if p.name() == "zn-rpi3_1"), 60)
    assert code == 1
    # its host forwards the others' reports of that tick: only the paused process is blamed
    assert ": node-rpi3_1 (nodes rpi3_1) hung: no report within 15 s" in error, error
    assert elapsed >= 15, f"took {elapsed:.1f} s"  # Zenoh's default lease would have said "died" after about 10
    for host in hosts:  # they end with the run: the orchestrator's token vanished
        host.finish(timeout=60)
    assert_all_gone(children)
