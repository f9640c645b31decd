"""The fork server's bookkeeping: a pid the kernel hands out again belongs to its new child only.

Linux reuses pids once its counter wraps (32768 by default, and every thread of every process takes
one), which a long training run that creates and closes Zenoh environments reaches: a new node process
with a former one's pid was taken for exited ("exited unexpectedly (status 0)") as it started.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from node_runtime.runtime.forkserver import ForkServer
from tests.conftest import ROOT
from tests.launcher import TIMEOUT

NEXT_PID = Path("/proc/sys/kernel/ns_last_pid")


def exit_at_once() -> None:
    os._exit(0)


def wait_for_a_signal() -> None:
    signal.pause()
    os._exit(0)


def test_the_exit_of_a_former_child_is_forgotten_when_its_pid_starts_again():
    forks = ForkServer.shared()
    pid = 2**31 - 1  # no real process: only the server's messages are replayed
    with forks._cond:
        forks._note(("exited", "former", pid, 0, "Error: the former child's account"))
        forks._note(("started", "reused-pid", pid))
    assert forks.exit_status(pid) is None
    assert forks.account(pid) == ""
    assert forks.wait([pid], 0.0) == [pid]  # running, as far as anyone can tell


def test_a_child_given_a_former_childs_pid_runs():
    forks = ForkServer.shared()
    first = forks.start("first", exit_at_once)
    assert forks.wait([first], TIMEOUT) == []
    try:
        NEXT_PID.write_text(str(first - 1))  # the next fork in this pid namespace gets ``first`` again
    except OSError:
        pytest.skip("choosing the next pid needs root (/proc/sys/kernel/ns_last_pid)")
    second = forks.start("second", wait_for_a_signal)
    try:
        if second != first:
            pytest.skip(f"another process took pid {first} first")
        assert forks.exit_status(second) is None
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:  # still running, not the former child's exit
            assert forks.wait([second], 0.05) == [second]
    finally:
        os.kill(second, signal.SIGKILL)
    assert forks.wait([second], TIMEOUT) == []
    assert forks.exit_status(second) == -signal.SIGKILL


def test_the_server_runs_the_code_its_caller_runs_whatever_the_working_directory_holds(tmp_path):
    """Started from a directory with another checkout in it (here a decoy that cannot be imported), the server
    still imports the caller's tree: node processes run the very code of the orchestrator that starts them."""
    decoy = tmp_path / "node_runtime"
    decoy.mkdir()
    (decoy / "__init__.py").write_text('raise ImportError("the decoy in the working directory")\n')
    script = ("from node_runtime.runtime.forkserver import ForkServer\n"
              "from tests.test_forkserver import exit_at_once\n"
              "forks = ForkServer.shared()\n"
              f"pid = forks.start('child', exit_at_once)\n"
              f"assert forks.wait([pid], {TIMEOUT}) == []\n"
              "print(forks.exit_status(pid))\n")
    done = subprocess.run([sys.executable, "-P", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=2 * TIMEOUT)
    assert (done.returncode, done.stdout.strip()) == (0, "0"), done.stderr
