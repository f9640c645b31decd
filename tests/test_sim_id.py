"""Simulation ids on joined routers: an id already in use on the network is refused at start."""

from __future__ import annotations

import signal

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
