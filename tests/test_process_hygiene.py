"""No process of a run outlives it: after a normal end, a killed node, Ctrl-C, SIGTERM, or a killed
orchestrator. Runs the real CLI as a subprocess; waits on its output and on process exits, never on sleeps.
"""

from __future__ import annotations

import signal
import time

import pytest

from tests.launcher import Launch, assert_all_gone

pytestmark = pytest.mark.zenoh


def test_normal_run_leaves_nothing(tmp_path):
    run = Launch("aot1", "--steps", "60", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    assert len([p for p in children if p.name().startswith(("zw-", "zc-", "zk-"))]) == 30
    assert run.finish(60) == 0
    assert_all_gone(children)
    assert (tmp_path / "summary.json").exists()


def test_killed_node_ends_the_run_with_its_name(tmp_path):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    victim = run.node("zw-rpi3_1")
    killed_at = time.monotonic()
    victim.kill()
    code = run.finish(30)
    elapsed = time.monotonic() - killed_at
    assert code == 1
    message = [ln for ln in run.err if ln.startswith("error:")]
    assert message and "worker-rpi3_1" in message[0] and "node rpi3_1" in message[0], run.err[-5:]
    assert elapsed < 10, f"took {elapsed:.1f} s to notice"
    assert_all_gone(children)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_stops_everything(tmp_path, sig):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    run.proc.send_signal(sig)
    assert run.finish(30) == 130
    assert any("interrupted" in ln for ln in run.err)
    assert_all_gone(children)


def test_killed_orchestrator_takes_its_processes_with_it(tmp_path):
    run = Launch("aot1", "--steps", "100000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    run.proc.kill()
    run.finish(10)
    assert_all_gone(children)
