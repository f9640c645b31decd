"""Refused at start, in one line: a simulation id already in use on joined routers, a port another program holds."""

from __future__ import annotations

import signal
import socket

import pytest

from tests.launcher import Launch, assert_all_gone, served

pytestmark = pytest.mark.zenoh


def test_a_taken_sim_id_on_joined_routers_is_refused(tmp_path):
    first = Launch("aot1", "--serve", "--episodes", "0", "--sim-id", "twin", "--out", str(tmp_path / "first"))
    first.wait_for("serving until Ctrl-C")
    children = first.descendants()
    endpoint, _ = served(first)

    second = Launch("aot1", "--steps", "20", "--sim-id", "twin", "--connect", endpoint, "--out", str(tmp_path / "b"))
    assert second.finish(60) == 2
    assert second.err[-1].strip() == ("orchestrator: simulation id 'twin' is already in use on this Zenoh network (an "
                                      "orchestrator with that id runs at a joined router): choose another --sim-id")
    assert not (tmp_path / "b").exists()

    # another id on the same network runs as usual
    other = Launch("aot1", "--steps", "20", "--sim-id", "other", "--connect", endpoint, "-q", "--out",
                   str(tmp_path / "c"))
    assert other.finish(120) == 0, "".join(other.err)
    assert (tmp_path / "c" / "summary.json").exists()

    first.proc.send_signal(signal.SIGTERM)
    assert first.finish(30) == 130
    assert_all_gone(children)


def test_a_port_another_program_holds_is_one_line(tmp_path):
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        run = Launch("aot1", "--steps", "5", "--listen", f"127.0.0.1:{port}", "--out", str(tmp_path / "run"))
        assert run.finish(60) == 2
    assert run.err[-1].startswith(f"orchestrator: cannot listen on 127.0.0.1:{port}: ")
    assert "Address already in use" in run.err[-1] and "Traceback" not in "".join(run.err)
    assert not (tmp_path / "run").exists()
