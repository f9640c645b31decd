"""A bare `orchestrator monitor` finds what `orchestrator launch` runs on this host (orchestrator.local_sims).

Each test has a list of its own (XDG_RUNTIME_DIR in its temporary directory), so simulations
that others run on this host cannot interfere. Real launches and monitors in subprocesses; every wait
is on a printed line, with a timeout that fails loudly.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from node_runtime.runtime.zenoh_bus import free_port
from orchestrator import local_sims
from tests.launcher import Launch, Output, assert_all_gone, served

NONE_HERE = ("monitor: no simulation running on this host; start one with `orchestrator launch SCENARIO --serve`, "
             "or give --connect ENDPOINT to watch one on another host")


@pytest.fixture
def runtime_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """This test's XDG_RUNTIME_DIR, here and in the processes it starts."""
    path = tmp_path / "xdg"
    path.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(path))
    return path


def monitor(*args: str) -> Output:
    return Output(sys.executable, "-m", "orchestrator.cli", "monitor", *args)


def listed(runtime_dir: Path) -> list[dict]:
    return sorted((json.loads(p.read_text()) for p in (runtime_dir / "zenohedge").glob("*.json")),
                  key=lambda e: e["sim"])


def started_line(entry: dict) -> str:
    return f"{entry['sim']} (aot1) at {entry['endpoint']}, pid {entry['pid']}, started {entry['started']}"


@pytest.mark.zenoh
def test_a_bare_monitor_attaches_to_the_simulation_launched_here(runtime_dir, tmp_path):
    port = free_port()  # a fixed port, as for other hosts (--listen) — its listing says where it is
    run = Launch("aot1", "--serve", "--tick-rate", "20", "--steps", "100000", "--layout", "single",
                 "--listen", f"127.0.0.1:{port}", "--out", str(tmp_path / "run"))
    run.wait_for("processes ready")
    children = run.descendants()
    endpoint, sim = served(run)
    assert endpoint == f"tcp/127.0.0.1:{port}"
    [entry] = listed(runtime_dir)
    assert {k: entry[k] for k in ("sim", "endpoint", "scenario", "pid")} == {
        "sim": sim, "endpoint": endpoint, "scenario": "aot1", "pid": run.proc.pid}

    status, out, err = monitor("--once").finish()
    assert status == 0, err
    assert err == [f"monitor: found on this host: {started_line(entry)}",
                   f"monitor: attached to {sim} (aot1) at {endpoint} (Ctrl-C to detach)"]
    assert f"sim {sim} · aot1" in out[0]  # the snapshot's title

    run.proc.send_signal(signal.SIGINT)
    assert run.finish(30) == 130
    assert_all_gone(children)
    assert list((runtime_dir / "zenohedge").iterdir()) == []


@pytest.mark.zenoh
def test_several_are_listed_none_is_said_and_nothing_is_left_behind(runtime_dir, tmp_path):
    status, _, err = monitor().finish()
    assert (status, err) == (2, [NONE_HERE])

    runs = [Launch("aot1", "--serve", "--episodes", "0", "--layout", "single", "--out", str(tmp_path / n))
            for n in "ab"]
    for run in runs:
        run.wait_for("serving until Ctrl-C")
    children = [c for run in runs for c in run.descendants()]
    entries = listed(runtime_dir)
    assert sorted(e["sim"] for e in entries) == sorted(served(run)[1] for run in runs)
    status, _, err = monitor().finish()
    assert status == 2
    assert err[0] == ("monitor: 2 simulations running on this host; choose one with --sim ID (or --connect "
                      "ENDPOINT):")
    assert sorted(err[1:]) == sorted(f"  {started_line(e)}" for e in entries)

    (end_b, sim_b) = served(runs[1])
    chosen = monitor("--sim", sim_b)
    chosen.wait_err(f"monitor: attached to {sim_b} (aot1) at {end_b}")
    assert chosen.finish(signal.SIGINT)[::2] == (0, [f"monitor: detached from {sim_b}"])
    status, _, err = monitor("--sim", "nope").finish()
    assert status == 2 and err[0].startswith("monitor: no simulation 'nope' launched on this host")

    runs[0].proc.send_signal(signal.SIGTERM)
    assert runs[0].finish(30) == 130
    runs[1].proc.kill()  # no chance to clean up: its file stays, and readers must see through it
    runs[1].finish(30)
    assert_all_gone(children)
    assert [e["sim"] for e in listed(runtime_dir)] == [sim_b]
    status, _, err = monitor().finish()
    assert (status, err) == (2, [NONE_HERE])
    assert list((runtime_dir / "zenohedge").iterdir()) == []  # the stale file is gone too


def test_registered_for_the_block_and_stale_entries_dropped(runtime_dir):
    gone = subprocess.Popen(["true"])  # a process that has come and gone: its pid is free
    gone.wait()
    folder = runtime_dir / "zenohedge"
    with local_sims.registered("lab1", "tcp/0.0.0.0:7447", "aot2") as entry:
        assert entry.endpoint == "tcp/127.0.0.1:7447"  # all interfaces: reached on loopback from here
        (folder / f"old.{gone.pid}.json").write_text(json.dumps(
            {"sim": "old", "endpoint": "tcp/127.0.0.1:1", "scenario": "aot1", "pid": gone.pid, "started": "-"}))
        assert local_sims.running() == [entry]
        assert sorted(p.name for p in folder.iterdir()) == [f"lab1.{entry.pid}.json"]
    assert local_sims.running() == [] and list(folder.iterdir()) == []
    assert local_sims.local_endpoint("tcp/[::]:7447") == "tcp/[::1]:7447"
    assert local_sims.local_endpoint("tcp/10.0.0.1:7447") == "tcp/10.0.0.1:7447"


def test_a_directory_others_can_write_is_refused(runtime_dir, capsys):
    from orchestrator.viewers.monitor import main

    folder = runtime_dir / "zenohedge"
    folder.mkdir(mode=0o700)
    folder.chmod(0o777)
    with pytest.raises(local_sims.LocalSimsError, match="writable by another user"), \
            local_sims.registered("lab1", "tcp/127.0.0.1:7447", "aot2"):
        pass
    assert main([]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"monitor: {folder}: owned or writable by another user; remove it to monitor local simulations"]
