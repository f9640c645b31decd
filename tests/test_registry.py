"""Role kinds come from a registry: a new kind is one module that registers it, and then runs like
the built-in ones, in process and over Zenoh, in every layout, named from Python or from YAML."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
import textwrap

import pytest

from node_runtime.model.registry import ROLE_KINDS, RoleKind, register
from node_runtime.model.role import Role
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.process import short_name
from orchestrator.cli import main
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, model_part, run_summary, write_scenario

# The whole of a new role kind: one module, one register call.
SENSOR = '''
"""A battery monitor: samples its node's state broadcasts; every sample costs energy."""
import math

from node_runtime.model.messages import Kind
from node_runtime.model.registry import RoleKind, register
from node_runtime.model.rng import stream
from node_runtime.model.role import Role, state_topic


class Sensor(Role):
    kind = "sensor"

    def reset(self, seed):
        super().reset(seed)
        self.rng = stream(seed, self.index, SENSOR.stream)
        self.sample_j = float(self.node.param("sample_j", 0.5))
        self.sample_p = float(self.node.param("sample_p", 0.7))

    def tick(self, t, inbox, out):
        for env in inbox:
            if env.kind == Kind.STATE and self.rng.random() < self.sample_p:
                self.stats.energy_idle += self.sample_j

    def wake(self, t):
        return math.inf  # only a broadcast wakes it


def own_state(node, scenario):
    return (state_topic(node.id),)


SENSOR = register(RoleKind(Sensor, order=3, stream=3, subscribes=own_state))
'''
SAMPLE_J = 0.5


@pytest.fixture
def sensor_kind(tmp_path, monkeypatch):
    """The sensor kind, registered in this process the way a user's module registers it; gone afterwards."""
    (tmp_path / "mylab_sensor.py").write_text(textwrap.dedent(SENSOR))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield importlib.import_module("mylab_sensor").SENSOR
    del ROLE_KINDS["sensor"]
    del sys.modules["mylab_sensor"]


def network(sensors: bool = True, **top) -> dict:
    """Three nodes; a and c carry a sensor (c samples less often)."""
    nodes = [{"id": "a", "frequency": 1e6, "buffer": 6, "client": True, "controller": True},
             {"id": "b", "frequency": 1e6, "buffer": 6, "client": True, "controller": True},
             {"id": "c", "frequency": 2e6, "buffer": 10, "controller": True, "params": {"sample_p": 0.3}}]
    if sensors:
        nodes[0]["sensor"] = nodes[2]["sensor"] = True
    data = {
        "simulation": {"steps": 150, "policy": "least_queue"},
        "workload": {"arrival": {"rate": 0.3}, "tasks": [{"instructions": 2e6, "input_bytes": 1e5,
                                                          "output_bytes": 1e5, "deadline": 60}]},
        "topology": {"nodes": nodes, "links": [["a", "b"], ["b", "c"], ["a", "c"]]},
    }
    data.update(top)
    return data


def counts(summary: dict) -> dict:
    """What the tasks did, per node and in total: integers, unaffected by float summation order."""
    per_node = {n: {k: v for k, v in row.items() if isinstance(v, int)} for n, row in summary["nodes"].items()}
    return {"totals": summary["totals"], "nodes": per_node}


def test_built_in_kinds_keep_their_order_and_streams():
    assert [(k.name, k.order, k.stream) for k in ROLE_KINDS.values()] == [
        ("worker", 0, 0), ("client", 1, 1), ("controller", 2, 2)]


@pytest.mark.zenoh
def test_a_new_role_kind_runs_alike_in_process_and_over_zenoh(tmp_path, sensor_kind):
    sc = load_scenario(write_scenario(tmp_path, network()))
    plain = load_scenario(write_scenario(tmp_path, network(sensors=False), "plain.yaml"))
    assert [n.roles for n in sc.nodes] == [("worker", "client", "controller", "sensor"),
                                           ("worker", "client", "controller"), ("worker", "controller", "sensor")]
    assert dict(sc.kinds)["sensor"] == "mylab_sensor:Sensor"  # where a node process imports it from
    per_role = ProcessLayout(sc, "per-role")
    assert per_role.roles[:5] == ("worker:a", "client:a", "controller:a", "sensor:a", "worker:b")
    assert per_role.subscriptions["sensor:c"] == ("state/c",)
    assert "sensor-a" in per_role.procs
    assert [short_name(p, per_role) for p in ("controller-a", "sensor-a")] == ["zk-a", "zs-a"]  # in ps and top

    inproc = run_summary(sc)
    # it ran: it heard its nodes' broadcasts and its samples cost energy ...
    samples = inproc["energy_j"]["idle"] / SAMPLE_J
    assert samples > 0 and samples == int(samples)
    # ... it only watched: the tasks did exactly what they do without it ...
    assert counts(inproc) == counts(run_summary(plain))
    # ... and its own processes (sensor-a, sensor-c) or its nodes' processes give the same run
    assert model_part(run_summary(sc, transport="zenoh", layout="per-role")) == model_part(inproc)
    assert model_part(run_summary(sc, transport="zenoh", layout="per-node")) == model_part(inproc)


@pytest.mark.zenoh
def test_a_new_role_kind_from_yaml_in_a_fresh_interpreter(tmp_path, sensor_kind):
    """The file names the kind's class under ``roles`` (which imports and registers it) and gives it
    to nodes through a profile; ``orchestrator launch`` in a new interpreter knows nothing else."""
    data = network(sensors=False, roles={"sensor": "mylab_sensor:Sensor"},
                   profiles={"watched": {"sensor": True, "params": {"sample_j": SAMPLE_J}}})
    data["topology"]["nodes"][0]["profile"] = "watched"
    path = write_scenario(tmp_path, data)
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", str(path), "--transport", "zenoh",
                           "--layout", "per-role", "--out", str(tmp_path / "out"), "-q"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    over_zenoh = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert over_zenoh["energy_j"]["idle"] > 0
    assert model_part(over_zenoh) == model_part(run_summary(load_scenario(path)))


def test_a_kind_nobody_registered_is_an_unknown_key(tmp_path, capsys):
    path = write_scenario(tmp_path, network())
    assert main(["validate", str(path)]) == 2
    assert f"{path}: topology.nodes[0].sensor: unknown key" in capsys.readouterr().err


@pytest.mark.parametrize(("module", "expected"), [
    ("json:JSONDecoder", "roles.sensor: json:JSONDecoder is not a subclass of node_runtime.model.role.Role"),
    ("mylab_unregistered:Sensor", "roles.sensor: unknown role kind 'sensor': importing mylab_unregistered:Sensor "
                                  "did not register it"),
])
def test_a_kind_named_in_roles_must_register(tmp_path, capsys, module, expected):
    (tmp_path / "mylab_unregistered.py").write_text(SENSOR.split("\n\ndef own_state")[0])
    path = write_scenario(tmp_path, network(roles={"sensor": module}))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: {expected}" in err, err
    assert "Traceback" not in err and "sensor" not in ROLE_KINDS
    sys.modules.pop("mylab_unregistered", None)


def test_register_refuses_a_taken_order_or_stream():
    class Clash(Role):
        kind = "clash"

    with pytest.raises(ValueError, match="stream 2 is taken by 'controller'"):
        register(RoleKind(Clash, order=9, stream=2))
    with pytest.raises(ValueError, match="order 0 is taken by 'worker'"):
        register(RoleKind(Clash, order=0, stream=9))
    assert "clash" not in ROLE_KINDS
