"""Security on one host (loopback): a served simulation behind TLS, logins and access control
(deploy/README.md). The identities decide what a session may do: the driver drives, the monitor only
reads, a node group cannot take the clock, the driver identity cannot tick without a claim; a bad security
directory is one clear line."""

from __future__ import annotations

import signal
import subprocess
import sys

import numpy as np
import pytest

from env import ZenohEdgeEnv
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.protocol import Tick
from node_runtime.runtime.security import Security
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator.clock import ClockError
from orchestrator.serve import describe, session_of
from orchestrator.session import Simulation
from tests.conftest import ROOT
from tests.launcher import Launch, claiming_driver, served


@pytest.fixture(scope="module")
def secrets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("security") / "secrets"
    subprocess.run([ROOT / "deploy" / "make-certs.sh", folder, "127.0.0.1", "edge"], check=True, capture_output=True)
    return folder


@pytest.mark.zenoh
def test_identities_decide_who_drives(tmp_path, secrets):
    run = Launch("aot1", "--serve", "--episodes", "0", "--layout", "per-node", "--out", str(tmp_path),
                 "--security", str(secrets / "orchestrator"))
    run.wait_for("serving until Ctrl-C")
    endpoint, sim = served(run)
    assert endpoint.startswith("tls/127.0.0.1:")

    # a monitor reads the session description but gets no answer from …/control
    assert describe(endpoint, sim, security=Security.from_dir(secrets / "monitor"))["sim"] == sim
    for reader in ("monitor", "edge"):
        with pytest.raises(ClockError):
            ZenohEdgeEnv(connect=endpoint, sim_id=sim, security=secrets / reader, timeout=3.0).reset(seed=1)

    # the driver identity may publish ticks, but without holding the clock it has no key to seal them: a stop and
    # a run tick change nothing (a stop ended the run, blaming a node); the processes count them, and the claim
    # that follows on the same session, after them in order, drives them as before
    keys = Keys(sim)
    rogue = ZenohTransport.client(endpoint, Security.from_dir(secrets / "driver"))
    rogue.publish(keys.tick(), Tick(0, 1, "stop"))
    rogue.publish(keys.tick(), Tick(0, 1, "run"))
    attached = Simulation.attach(rogue, sim)
    attached.run(5, seed=2)
    assert attached.clock.node_rejected() == {"bad_mac": 2 * len(attached.plan.procs)}
    attached.close()

    env = ZenohEdgeEnv(connect=endpoint, sim_id=sim, security=secrets / "driver", max_steps=5)
    obs, _ = env.reset(seed=3)
    for _ in range(4):
        obs, *_ = env.step({a: int(np.flatnonzero(obs[a]["action_mask"])[0]) for a in env.agents})
    assert env.sim.clock.tick == 4
    env.close()  # the release carries the driver's token: the clock is free again
    watcher = ZenohTransport.client(endpoint, Security.from_dir(secrets / "monitor"))
    assert session_of(watcher, Keys(sim), 5.0)["driver"] is None

    # a driver killed while it holds the clock frees it: the claim lasts while its liveliness token does
    killed, name = claiming_driver(endpoint, sim, "hold", secrets / "driver")
    assert session_of(watcher, Keys(sim), 5.0)["driver"] == name
    killed.proc.send_signal(signal.SIGKILL)
    run.wait_for(f"driver {name} left without releasing the clock")
    assert session_of(watcher, Keys(sim), 5.0)["driver"] is None
    watcher.close()

    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130


@pytest.mark.zenoh
def test_only_the_orchestrator_answers_session_and_control(tmp_path, secrets):
    """With --security, the router drops a queryable declared by any identity but the orchestrator's: a group's,
    the monitor's or the driver's own rogue answers on …/session and …/control never reach the driver, which
    attaches and drives as if they were not there (in plain mode it would refuse: test_serve.py)."""
    run = Launch("aot1", "--serve", "--episodes", "0", "--out", str(tmp_path),
                 "--security", str(secrets / "orchestrator"))
    run.wait_for("serving until Ctrl-C")
    endpoint, sim = served(run)
    keys = Keys(sim)
    rogues = []
    for who in ("edge", "monitor", "driver"):
        rogue = ZenohTransport.client(endpoint, Security.from_dir(secrets / who))
        rogue.serve(keys.session(), lambda message: {"type": "session", "sim": sim, "scenario": {}})
        rogue.serve(keys.control(), lambda message: {"type": "control", "granted": False, "reason": "rogue"})
        rogues.append(rogue)
    try:
        with Simulation.attach(endpoint, sim, timeout=10, security=Security.from_dir(secrets / "driver")) as driver:
            driver.run(3, seed=1)
            assert driver.clock.episode == 0 and not driver.transport.rejections.counts
    finally:
        for rogue in rogues:
            rogue.close()
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130


def test_a_bad_security_directory_is_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", "aot1", "--security", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        f"orchestrator: {tmp_path}: missing ca.pem, cert.pem, key.pem, credentials (expected ca.pem, cert.pem, "
        "key.pem, credentials; deploy/make-certs.sh writes them)"]


def test_zenoh_config_file_merges_what_differs_from_the_defaults(tmp_path):
    from node_runtime.runtime.security import file_overrides
    from node_runtime.runtime.zenoh_bus import zenoh_config

    given = tmp_path / "zenoh.json5"
    given.write_text('{ transport: { link: { tx: { lease: 20000 } } }, // a comment, as JSON5 allows\n}\n')
    assert file_overrides(given) == {"transport/link/tx/lease": 20000}
    cfg = zenoh_config("client", connect=["tcp/127.0.0.1:7447"], settings=file_overrides(given))
    assert cfg.get_json("transport/link/tx/lease") == "20000"

    given.write_text("{ nonsense: 1 }")
    proc = subprocess.run([sys.executable, "-m", "node_runtime.runtime.remote", "--connect", "tcp/127.0.0.1:1",
                           "--sim", "x", "--group", "g", "--zenoh-config", str(given)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    [line] = proc.stderr.splitlines()
    assert line.startswith(f"zenohedge-node: {given}: not a usable Zenoh configuration: ")
