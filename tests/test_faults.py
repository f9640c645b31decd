"""Faults between node processes and the router: a short pause, a slow and lossy link to a host, and a
partition. Each checks what the run says and what output survives. Remote hosts are network
namespaces (deploy/netns.sh); tc shapes their link, and taking it down partitions them."""

from __future__ import annotations

import json
import subprocess
import time

import psutil
import pytest

from orchestrator.scenario import load_scenario
from tests.conftest import cut, model_part, run_summary, shape
from tests.launcher import Launch, assert_all_gone, spread

pytestmark = pytest.mark.zenoh

GROUP = ["rpi3_0", "rpi3_1", "rpi3_2", "nuc_0"]  # the nodes of aot1 placed on the remote host


def remote_run(tmp_path, *args: str) -> tuple[Launch, subprocess.Popen]:
    """aot1 with GROUP's processes on host 1 (per-node layout), the rest here; started and ready."""
    run, hosts = spread(tmp_path / "run", "aot1", {"edge": GROUP}, *args, sim="faulttest")
    return run, hosts[0]


def test_a_slow_lossy_link_to_a_host_changes_nothing(tmp_path, hosts):
    """1 Mbit/s with at most 50 ms of queue each way (tbf): packets wait and overflowing ones are dropped.
    Zenoh over TCP retransmits, the clock waits, and the emulation is the same as in one process."""
    shape(1, "tbf rate 1mbit burst 16kbit latency 50ms")
    try:
        run, group = remote_run(tmp_path, "--steps", "60", "--seed", "2", "--policy", "random")
        assert run.finish(180) == 0, "".join(run.err)
        assert group.wait(60) == 0, group.stderr.read()
    finally:
        shape(1, "")
    deployed = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert "incomplete" not in deployed
    assert model_part(deployed) == model_part(run_summary(load_scenario("aot1"), ticks=60, seed=2, policy="random"))


def test_a_partition_ends_the_run_as_hung_and_keeps_what_was_measured(tmp_path, hosts):
    run, group = remote_run(tmp_path, "--steps", "100000", "--timeout", "5")
    remote = psutil.Process(group.pid).children(recursive=True)
    cut(1, down=True)
    try:
        cut_at = time.monotonic()
        assert run.finish(60) == 1
        elapsed = time.monotonic() - cut_at
        message = [ln for ln in run.err if ln.startswith("error:")]
        assert message and "the host of group edge hung or was cut off" in message[0], "".join(run.err)
        assert "no report within 5 s" in message[0], message[0]
        assert any(f"node-{n}" in message[0] for n in GROUP), message[0]
        assert elapsed < 5 + 20, f"took {elapsed:.1f} s"  # the timeout, plus shutdown on a loaded machine
        summary = json.loads((tmp_path / "run" / "summary.json").read_text())
        assert "hung" in summary["incomplete"]["reason"]
        # cut off from the orchestrator, the remote processes leave once their session lapses
        group.wait(60)
        assert_all_gone(remote, timeout=30)
    finally:
        cut(1, down=False)
        if group.poll() is None:
            group.kill()


def test_a_pause_shorter_than_the_timeout_changes_nothing(tmp_path):
    """SIGSTOP then SIGCONT within --timeout: the clock waits for the late report; same emulation."""
    run = Launch("aot1", "--steps", "2000", "--seed", "6", "--policy", "least_queue", "--timeout", "20",
                 "--out", str(tmp_path))
    run.wait_for("processes ready")
    victim = run.node("zw-rpi3_2")
    victim.suspend()
    assert run.proc.poll() is None  # paused while the episode runs
    time.sleep(1.5)  # the fault itself: how long the process stays stopped
    victim.resume()
    assert run.finish(120) == 0, "".join(run.err)
    paused = json.loads((tmp_path / "summary.json").read_text())
    alone = run_summary(load_scenario("aot1"), ticks=2000, seed=6, policy="least_queue")
    assert model_part(paused) == model_part(alone)
