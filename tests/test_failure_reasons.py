"""A node process that fails says why: the orchestrator's error names the process and carries the
node's own reason (its exception, and the end of its traceback), however the node failed."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap

import pytest

from node_runtime.runtime.zenoh_bus import ZenohTransport, free_port
from tests.conftest import ROOT
from tests.launcher import Launch, assert_all_gone

pytestmark = pytest.mark.zenoh

FAILING_WORKERS = '''
from node_runtime.model.worker import Worker

class FailsInTick(Worker):
    def tick(self, t, inbox, out):
        if t == 7 and self.node.id == "rpi3_1":
            raise ValueError("the flux capacitor overheated")
        super().tick(t, inbox, out)

class FailsAtStart(Worker):
    def reset(self, seed):
        if self.node.id == "rpi3_1":
            raise RuntimeError("no battery at start")
        super().reset(seed)
'''


@pytest.mark.parametrize(("worker", "how", "message"), [
    # reported in its Done, and in its exit notice, whichever reaches the orchestrator first
    ("FailsInTick", r"(failed in tick 7|exited unexpectedly \(status 1\))",
     "ValueError: the flux capacitor overheated"),
    ("FailsAtStart", r"exited unexpectedly \(status 1\)", "RuntimeError: no battery at start"),  # before any tick
])
def test_the_error_names_the_process_and_its_reason(tmp_path, worker, how, message):
    (tmp_path / "failing_workers.py").write_text(textwrap.dedent(FAILING_WORKERS))
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text((ROOT / "topologies" / "aot1.yaml").read_text()
                        + f'roles: {{worker: "failing_workers:{worker}"}}\n')
    run = Launch(str(scenario), "--steps", "40", "--out", str(tmp_path / "out"))
    run.wait_for("error: ", timeout=120)
    children = run.descendants()
    assert run.finish(60) == 1
    error = next(line for line in run.err if line.startswith("error: "))
    assert re.match(rf"error: process worker-rpi3_1 \(node rpi3_1\) {how}: {message}$", error), error
    trace = run.err[run.err.index(error) + 1:]
    assert any("failing_workers.py" in line for line in trace), "".join(run.err)
    assert_all_gone(children)


def test_a_node_process_waits_for_its_peers_as_long_as_it_was_told():
    """Readiness follows the orchestrator's timeout (ProcSpec.ready_timeout), not a fixed 60 s: a node
    whose peers never subscribe gives up after it, naming what it waited for."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = ZenohTransport.router(endpoint)
    code = textwrap.dedent(f"""
        import time
        from node_runtime.runtime.keys import Keys
        from node_runtime.runtime.origin import Keyring
        from node_runtime.runtime.process import ProcSpec, run
        from orchestrator.scenario import load_scenario
        spec = ProcSpec("node-rpi3_0", load_scenario("aot1"), "per-node", {endpoint!r}, Keys("lonely"),
                        Keyring.new(["node-rpi3_0"]), ready_timeout=2.0)
        start = time.monotonic()
        try:
            run(spec)
        except Exception as exc:
            print(type(exc).__name__, round(time.monotonic() - start, 1), exc)
    """)
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    finally:
        router.close()
    name, elapsed, message = out.stdout.strip().split(" ", 2)
    assert name == "TransportError", out.stdout + out.stderr
    assert "no subscriber appeared within 2 s" in message and "lonely/proc/" in message
    assert 2.0 <= float(elapsed) < 30
