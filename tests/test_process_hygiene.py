"""No process of a run outlives it: after a normal end, a killed node, Ctrl-C, SIGTERM, or a killed
orchestrator. Runs the real CLI as a subprocess; waits on its output and on process exits, never on sleeps.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

from tests.conftest import ROOT
from tests.launcher import Launch, assert_all_gone, paused_run

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


SCRIPT = """
import psutil
from env import ZenohEdgeEnv
env = ZenohEdgeEnv("aot1", transport="zenoh", layout="per-node", max_steps=5)
env.reset(seed=0)
print(" ".join(str(p.pid) for p in psutil.Process().children(recursive=True)), flush=True)
"""


@pytest.mark.parametrize("ending", ["raises", "never closes"])
def test_a_script_that_leaves_its_environment_open_still_exits_and_takes_its_processes(tmp_path, ending):
    """zenoh-python's callback threads are not daemons: an open session once kept the interpreter from exiting,
    forever, after a user's script raised or simply ended without ``env.close()``."""
    script = tmp_path / "script.py"
    script.write_text(SCRIPT + ('raise RuntimeError("a bug in the user\'s script")\n' if ending == "raises" else ""))
    done = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == (1 if ending == "raises" else 0), done.stderr
    pids = [int(pid) for pid in done.stdout.split()]
    assert len(pids) > 12  # the fork server and the node processes
    procs = []
    for pid in pids:
        try:
            procs.append(psutil.Process(pid))
        except psutil.NoSuchProcess:
            continue
    assert_all_gone(procs)


def _shm_descriptors() -> list[str]:
    """The Zenoh shared-memory segments this process holds open."""
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:  # closed while listing
            continue
        if target.startswith("/dev/shm/") and ".zenoh" in target:  # not other libraries' (multiprocessing's)
            out.append(target)
    return out


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc")
def test_an_env_over_zenoh_holds_no_shared_memory_after_close():
    """Each create/close used to leave a /dev/shm segment open in the trainer's process (Zenoh's SHM)."""
    from env import ZenohEdgeEnv

    for seed in range(2):
        env = ZenohEdgeEnv("aot1", transport="zenoh", max_steps=3)
        env.reset(seed=seed)
        while env.agents:
            env.step(dict.fromkeys(env.agents, 0))
        env.close()
        assert _shm_descriptors() == []


def test_a_paused_node_is_reported_hung_within_the_timeout(tmp_path):
    """SIGSTOP: the process is alive but silent. The run ends after --timeout, says "hung" with the node's
    name, keeps what was measured, and kills the stopped process at once. The timeout is past where
    Zenoh's default lease (10 s) used to drop the session, ending the run early as "died"."""
    run = Launch("aot1", "--steps", "100000", "--timeout", "16", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    code, elapsed, error = paused_run(run, run.node("zw-rpi3_1"), 40)
    assert code == 1
    assert "hung" in error and "worker-rpi3_1" in error, error
    assert 16 <= elapsed < 16 + 14, f"took {elapsed:.1f} s"  # not before the timeout; shutdown may be slow under load
    assert_all_gone(children)
    summary = (tmp_path / "summary.json").read_text()
    assert '"incomplete"' in summary and "hung" in summary
