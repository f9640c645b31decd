"""Payloads: real work run by the serving worker, its CPU time turned into cycles, recorded and replayed.

The rule (docs/model.md, "Payloads"): when a task of a type with a payload (the index the task carries)
starts service, its worker runs the payload (or, replaying, reads its recorded CPU seconds) and the task takes
cycles = seconds x payload_hz of the serving node (default cores x frequency) instead of ρ·ξ.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from node_runtime.model.calibrate import main
from node_runtime.model.client import arrivals
from node_runtime.model.payload import PayloadError, read_record, run_log
from orchestrator.clock import ProcessFailed
from orchestrator.scenario import ScenarioError, costs, load_scenario
from tests.conftest import ROOT, model_part, run_summary, write_scenario
from tests.golden import Case, _launch
from tests.launcher import TIMEOUT

LAB = '''
import time


def spin(task_id, cpu_s=0.005):
    """Burn about cpu_s seconds of this thread's CPU."""
    end = time.thread_time() + cpu_s
    while time.thread_time() < end:
        pass


def boom(task_id):
    raise ValueError(f"bad input for task {task_id}")
'''
HEADER = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n"
INFER = {"name": "infer", "instructions": 1.0e6, "input_bytes": 1.0e6, "output_bytes": 1.0e6,
         "payload": {"call": "lab_payloads:spin"}}
PLAIN = {"name": "plain", "instructions": 2.0e6, "input_bytes": 1.0e6, "output_bytes": 1.0e6}


def pair(tmp_path: Path, workload: dict, steps: int, policy: str = "round_robin", call: str = "lab_payloads:spin",
         hz: tuple[float | None, float] = (None, 8.0e6)):
    """a (1e6 cycles/s; payload_hz: by default its capacity) places its tasks over itself and b (2e6 cycles/s,
    payload_hz by default 8e6: a payload's CPU second is 8e6 cycles there, 4 s), over an 8e6 bit/s link.
    ``hz=SLOW`` makes the payload's 5 ms of CPU a service of 1.5 ticks on either node, so that measured times
    move the results."""
    (tmp_path / "lab_payloads.py").write_text(LAB)
    tasks = [{**INFER, "payload": {"call": call}}, PLAIN]
    a_hz = {} if hz[0] is None else {"payload_hz": hz[0]}
    return write_scenario(tmp_path, {
        "simulation": {"dt": 1.0, "steps": steps, "policy": policy},
        "workload": {**workload, "tasks": tasks},
        "topology": {"nodes": [
            {"id": "a", "frequency": 1.0e6, "buffer": 4, "controller": True, "client": True, **a_hz},
            {"id": "b", "frequency": 2.0e6, "buffer": 4, "payload_hz": hz[1]},
        ], "links": [{"between": ["a", "b"], "rate_bps": 8.0e6}]},
    })


SLOW = (3.0e8, 6.0e8)


def replaying(path: Path, record: Path):
    return load_scenario(path).replace(payload_log=run_log(replay=str(record)))


def hand_trace(tmp_path: Path):
    (tmp_path / "trace.csv").write_text(HEADER.replace("\n", ",type\n") + "0,a,1e6,1e6,1e6,1,100,infer\n"
                                        "0,a,1e6,1e6,1e6,1,100,infer\n0,a,2e6,1e6,1e6,1,100,\n")
    record = tmp_path / "times.jsonl"
    record.write_text('{"seed": 0, "task": 1, "node": "a", "cpu_s": 2.5}\n'
                      '{"seed": 0, "task": 2, "node": "b", "cpu_s": 0.75}\n')
    return replaying(pair(tmp_path, {"trace": "trace.csv"}, steps=14), record)


def check_hand_trace(s: dict) -> None:
    """Tasks 1 and 2 are of type infer (the trace's type column), task 3 has no type. Round robin over [local, b], one
    decision a tick reaching a at 4, 5, 6: tasks 1 and 3 stay, task 2 goes to b.

    - task 1 (recorded 2.5 CPU-s on a, payload_hz 1e6): 2.5e6 cycles, not its nominal 1e6. It starts in
      tick 4 and runs 1e6 in 4, 1e6 in 5 and its last 0.5e6 in 6 -> result at a's client at 7: 7 s.
    - task 3 (plain, 2e6 cycles) joins the queue at 6, behind task 1, and takes the 0.5e6 left of tick 6,
      1e6 in 7 and 0.5e6 in 8 -> 9 s. It waited behind task 1 in tick 6 for 0.5 s of a's CPU
      (0.5e6 / 1e6): task 1 imposed 0.5 s / 100 s = 0.005 of a deadline.
    - task 2: its decision reaches a at 5; 1e6 bytes = 8e6 bits at 8e6 bit/s: on air 5.0 -> 6.0, at b at 6,
      queued at once (b has no controller). Recorded 0.75 CPU-s on b x payload_hz 8e6 = 6e6 cycles at
      2e6 a tick: ticks 6, 7, 8. Its 1e6-byte result is on air 8.0 -> 9.0 -> a's client at 9: 9 s.

    Busy cycles: a 2.5e6 + 2e6 = 4.5e6 of 14 ticks x 1e6; b 6e6 of 14 x 2e6. Compute energy
    κ·cycles·f² with κ = 1e-27: a 1e-27 x 4.5e6 x 1e12, b 1e-27 x 6e6 x 4e12; radio at 20 dBm (0.1 W):
    a 1 s on air, b 1 s.
    """
    assert s["totals"]["generated"] == s["totals"]["completed"] == 3
    assert s["totals"]["offloaded"] == 1
    assert s["response_time"]["mean"] == pytest.approx(25.0 / 3)
    assert (s["response_time"]["p50"], s["response_time"]["max"]) == (pytest.approx(9.0), pytest.approx(9.0))
    assert s["nodes"]["a"]["utilisation"] == pytest.approx(4.5e6 / 14e6)
    assert s["nodes"]["b"]["utilisation"] == pytest.approx(6e6 / 28e6)
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(0.1 + 1e-27 * 4.5e6 * 1e12)
    assert s["nodes"]["b"]["energy_j"] == pytest.approx(0.1 + 1e-27 * 6e6 * 4e12)
    assert s["delay_imposed"] == pytest.approx(0.005)


def test_hand_trace_with_recorded_payload_times(tmp_path):
    check_hand_trace(run_summary(hand_trace(tmp_path), ticks=14))


@pytest.mark.zenoh
def test_hand_trace_with_recorded_payload_times_over_zenoh(tmp_path):
    scenario = hand_trace(tmp_path)
    inproc = run_summary(scenario, ticks=14)
    for layout in ("per-role", "per-node"):
        over = run_summary(scenario, ticks=14, transport="zenoh", layout=layout)
        check_hand_trace(over)
        assert model_part(over) == model_part(inproc)


def fingerprint(scenario, transport: str, layout: str, ticks: int) -> dict:
    """The golden master's fingerprint of a launch: its summary's model part and its two tables, hashed."""
    return _launch(Case("payload", ticks, seed=0, layout=layout), scenario, transport)


@pytest.mark.zenoh
def test_a_recorded_run_replays_bit_for_bit_in_every_layout(tmp_path):
    path = pair(tmp_path, {"arrival": {"rate": 0.4}}, steps=40, policy="least_queue", hz=SLOW)
    record = tmp_path / "times.jsonl"
    recording = load_scenario(path).replace(payload_log=run_log(record=str(record)))
    recorded = fingerprint(recording, "zenoh", "per-node", 40)  # each worker's process appends its own lines
    rows = [json.loads(line) for line in record.read_text().splitlines()]
    assert recorded["totals"]["completed"] > 10 and {r["node"] for r in rows} == {"a", "b"}
    assert all(r["type"] == "infer" and r["seed"] == 0 and r["cpu_s"] >= 0.004 for r in rows)
    scenario = replaying(path, record)
    for transport, layout in (("inproc", "single"), ("zenoh", "per-role"), ("zenoh", "single")):
        assert fingerprint(scenario, transport, layout, 40) == recorded, (transport, layout)


SOURCES = """
import numpy as np

from node_runtime.model.workload import TaskSource

KINDS = (np.int64(0), 1, None)  # infer (a numpy integer will do), plain, none


class Typed(TaskSource):
    \"\"\"A task every other tick until tick 24, of type infer, plain and none in turn: tasks 1, 4, 7, 10 of
    the 12 are of type infer, and only they run its payload.\"\"\"

    def typed(self, tick):
        if tick % 2 or tick >= 24:
            return []
        return [((1.0e6, 1.0e6, 1.0e6, 1.0, 100.0), KINDS[tick // 2 % 3])]
"""


def typed_source(tmp_path: Path) -> Path:
    """``pair`` fed by ``lab_sources:Typed``, round robin over a and b: its tasks alternate between them."""
    (tmp_path / "lab_sources.py").write_text(SOURCES)
    return pair(tmp_path, {"source": "lab_sources:Typed"}, steps=40)


def check_typed_record(summary: dict, record: Path) -> None:
    """Every task completed, and the record holds exactly the four of type infer, served on both nodes."""
    assert summary["totals"]["generated"] == summary["totals"]["completed"] == 12
    rows = [json.loads(line) for line in record.read_text().splitlines()]
    assert sorted(r["task"] & 0xFFFFFFFF for r in rows) == [1, 4, 7, 10]
    assert all(r["type"] == "infer" for r in rows) and {r["node"] for r in rows} == {"a", "b"}


def test_a_user_sources_typed_tasks_run_their_payload_the_same_in_every_layout(tmp_path):
    path, record = typed_source(tmp_path), tmp_path / "times.jsonl"
    recorded = fingerprint(load_scenario(path).replace(payload_log=run_log(record=str(record))), "inproc", "single",
                           40)
    check_typed_record(recorded, record)
    for layout in ("per-node", "groups:2"):
        assert fingerprint(replaying(path, record), "inproc", layout, 40) == recorded, layout


@pytest.mark.zenoh
def test_a_user_sources_typed_tasks_run_their_payload_over_zenoh(tmp_path):
    """The types cross the bus with the tasks: b's process runs the payload of the two it serves."""
    path, record = typed_source(tmp_path), tmp_path / "times.jsonl"
    recorded = fingerprint(load_scenario(path).replace(payload_log=run_log(record=str(record))), "zenoh", "per-node",
                           40)
    check_typed_record(recorded, record)
    for transport, layout in (("inproc", "single"), ("zenoh", "per-role")):
        assert fingerprint(replaying(path, record), transport, layout, 40) == recorded, (transport, layout)


def test_the_motion_camera_example_classifies_only_frames_with_motion(tmp_path):
    """Its source makes a frame of the first 5 s of every 20 a classify, any other a check: over 7 s, every
    recorded payload is of a classify frame (its size says which; a task's id is its client's index and
    sequence number)."""
    scenario = load_scenario(ROOT / "topologies" / "examples" / "motion_camera.yaml")
    created: dict[int, list[tuple[int, float]]] = {}  # client index -> (tick, instructions) of its tasks, in order
    for t, client, size in arrivals(scenario, 0, 70):
        created.setdefault(client, []).append((t, size.instructions))
    kinds = {(c << 32) | seq: ("classify" if t < 50 else "check", instructions)
             for c, tasks in created.items() for seq, (t, instructions) in enumerate(tasks, start=1)}
    assert {kind: {i for k, i in kinds.values() if k == kind} for kind in ("classify", "check")} == \
        {"classify": {3.0e7}, "check": {2.0e6}}  # each frame has its type's size, and there are both
    record = tmp_path / "times.jsonl"
    summary = run_summary(scenario.replace(payload_log=run_log(record=str(record))), ticks=70)
    rows = [json.loads(line) for line in record.read_text().splitlines()]
    assert summary["totals"]["generated"] == len(kinds) and len(rows) > 10
    assert all(r["type"] == "classify" and kinds[r["task"]][0] == "classify" for r in rows)


def test_measured_times_become_cycles_by_the_rule(tmp_path):
    """Measure and record: each task's cycles are its recorded CPU seconds x the serving node's payload_hz,
    which a replay of the record reproduces exactly."""
    path = pair(tmp_path, {"arrival": {"rate": 0.3}}, steps=30, hz=SLOW)
    record = tmp_path / "times.jsonl"
    measured = run_summary(load_scenario(path).replace(payload_log=run_log(record=str(record))), ticks=30)
    rows = read_record(str(record))
    assert rows and all(0.004 <= s < 1.0 for s in rows.values())
    assert model_part(run_summary(replaying(path, record), ticks=30)) == model_part(measured)


def test_a_replay_refuses_a_task_it_has_no_time_for(tmp_path):
    scenario = hand_trace(tmp_path)
    record = tmp_path / "times.jsonl"
    record.write_text(record.read_text().splitlines()[0] + "\n")  # task 2 on b is missing
    with pytest.raises(ProcessFailed, match=r"node b: task type 'infer': .*times.jsonl has no time for task 2 "
                                            r"with seed 0"):
        run_summary(scenario.replace(payload_log=run_log(replay=str(record))), ticks=14)


def test_a_payload_that_raises_fails_the_run_naming_node_type_and_payload(tmp_path):
    path = pair(tmp_path, {"arrival": {"rate": 0.5}}, steps=30, policy="local", call="lab_payloads:boom")
    with pytest.raises(ProcessFailed, match=r"node a: task type 'infer': payload lab_payloads:boom raised "
                                            r"ValueError: bad input for task"):
        run_summary(load_scenario(path), ticks=30)


@pytest.mark.zenoh
def test_a_payload_that_raises_over_zenoh_keeps_the_ticks_before(tmp_path):
    path = pair(tmp_path, {"arrival": {"rate": 0.5}}, steps=30, policy="local", call="lab_payloads:boom")
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", str(path), "--out", str(out), "-q"],
                          cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 1, proc.stderr
    assert "task type 'infer': payload lab_payloads:boom raised ValueError: bad input for task" in proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ticks"] == summary["incomplete"]["last_tick"] + 1 > 0
    assert len((out / "ticks.csv").read_text().splitlines()) == summary["ticks"] + 1  # the header, then each tick


def test_a_payload_is_part_of_the_scenario_hash_and_its_times_are_not(tmp_path):
    """(A scenario without payloads keeps its hash: the golden master checks the bundled ones'.)"""
    (tmp_path / "lab_payloads.py").write_text(LAB)
    (tmp_path / "plain").mkdir()
    base = {"topology": {"nodes": [{"id": "a", "client": True}]}}
    plain = load_scenario(write_scenario(tmp_path / "plain", {**base, "workload": {"tasks": [{}]}}))
    with_payload = load_scenario(write_scenario(tmp_path, {**base, "workload": {"tasks": [
        {"payload": {"call": "lab_payloads:spin"}}]}}))
    assert with_payload.name == plain.name and with_payload.digest() != plain.digest()
    replay = with_payload.replace(payload_log={"mode": "replay", "path": "x"})
    assert replay.digest() == with_payload.digest()  # how the times are obtained is no part of the scenario


@pytest.mark.parametrize(("task", "node", "message"), [
    ({"payload": {"call": "lab_payloads:nope"}}, {},
     "workload.tasks[0].payload.call: module 'lab_payloads' has no 'nope'"),
    ({"payload": {"call": "spin"}}, {},
     "workload.tasks[0].payload.call: expected an import path like 'package.module:function' (got 'spin')"),
    ({"payload": {"cal": "lab_payloads:spin"}}, {}, "workload.tasks[0].payload.cal: unknown key"),
    ({"payload": {"call": "lab_payloads:spin"}}, {"payload_hz": 0},
     "topology.nodes[0].payload_hz: expected a number > 0 (got 0)"),
])
def test_bad_payload_settings_name_the_key(tmp_path, task, node, message):
    (tmp_path / "lab_payloads.py").write_text(LAB)
    path = write_scenario(tmp_path, {"workload": {"tasks": [task, PLAIN]},
                                     "topology": {"nodes": [{"id": "a", "client": True, **node}]}})
    with pytest.raises(ScenarioError) as e:
        load_scenario(path)
    assert any(message in line for line in str(e.value).splitlines()), str(e.value)


def test_a_worker_knows_a_payload_task_by_its_type_not_its_size(tmp_path):
    """infer and plain of one size: the trace's rows 1 and 3 name infer and run its payload, rows 2 (plain)
    and 4 (no type) keep their nominal cycles, and only 1 and 3 are in the record."""
    path = pair(tmp_path, {"trace": "trace.csv"}, steps=20, policy="local")
    data = yaml.safe_load(path.read_text())
    data["workload"]["tasks"][1]["instructions"] = INFER["instructions"]
    write_scenario(tmp_path, data)
    (tmp_path / "trace.csv").write_text(HEADER.replace("\n", ",type\n") + "".join(
        f"{t},a,1e6,1e6,1e6,1,100,{kind}\n" for t, kind in enumerate(("infer", "plain", "infer", ""))))
    scenario = load_scenario(path)
    assert scenario.workload.task_types[0].size(1.0) == scenario.workload.task_types[1].size(1.0)
    assert [r.type for r in scenario.workload.trace] == [0, 1, 0, None]
    record = tmp_path / "times.jsonl"
    summary = run_summary(scenario.replace(payload_log=run_log(record=str(record))), ticks=20)
    assert summary["totals"]["completed"] == 4
    assert sorted(task & 0xFFFFFFFF for _, task, _ in read_record(str(record))) == [1, 3]


@pytest.mark.parametrize(("rows", "message"), [
    ("0,a,1e6,1e6,1e6,1,100,nope\n", "workload.trace: {trace}:2: type: expected the name of a task type of "
                                     "workload.tasks ('infer', 'plain'), got 'nope'"),
    ("0,a,1e6,1e6,1e6,1,100,plain\n", "workload.tasks[0].payload: no row of trace.csv is of type 'infer'; a "
                                      "trace's task runs a payload when its type column names it"),
])
def test_a_trace_names_task_types_or_is_refused_in_one_line(tmp_path, rows, message):
    path = pair(tmp_path, {"trace": "trace.csv"}, steps=5)
    (tmp_path / "trace.csv").write_text(HEADER.replace("\n", ",type\n") + rows)
    with pytest.raises(ScenarioError) as e:
        load_scenario(path)
    assert str(e.value).splitlines() == [f"{path}: {message.format(trace=tmp_path / 'trace.csv')}"]


def test_record_files_keep_whole_lines_and_refuse_what_is_not_one(tmp_path):
    record = tmp_path / "r.jsonl"
    record.write_text('{"seed": 0, "task": 1, "node": "a", "cpu_s": 0.5}\n{"seed": 0, "task": 2, "no')
    assert read_record(str(record)) == {(0, 1, "a"): 0.5}  # a line cut by a crash is left out
    record.write_text('{"seed": 0, "task": 1, "node": "a", "cpu_s": 0.5}\n' * 2)
    with pytest.raises(PayloadError, match=r"r.jsonl:2: task 1 on node 'a' with seed 0 is recorded twice"):
        read_record(str(record))
    record.write_text('{"seed": 0, "task": 1, "node": "a", "cpu_s": -1}\n')
    with pytest.raises(PayloadError, match=r"r.jsonl:1: cpu_s must be a number >= 0"):
        read_record(str(record))
    with pytest.raises(PayloadError, match="cannot read the payload record"):
        read_record(str(tmp_path / "none.jsonl"))


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "orchestrator.cli", "launch", *args, "--transport", "inproc", "-q"],
                          cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)


def test_launch_options_refuse_what_cannot_work_in_one_line(tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text("not json\n")
    proc = run_cli("topologies/examples/payload_classifier.yaml", "--payload-replay", str(bad))
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"orchestrator: --payload-replay: {bad}:1: expected a JSON object with seed, task, node and cpu_s "
        "(got 'not json')"]
    proc = run_cli("topologies/examples/minimal.yaml", "--payload-record", str(tmp_path / "r.jsonl"))
    assert proc.returncode == 2
    assert proc.stderr.strip() == "orchestrator: --payload-record: minimal has no task type with a payload"


def test_the_example_records_and_replays_from_the_command_line(tmp_path):
    record, first, second = tmp_path / "times.jsonl", tmp_path / "first", tmp_path / "second"
    example = "topologies/examples/payload_classifier.yaml"
    assert run_cli(example, "--steps", "60", "--payload-record", str(record), "--out", str(first)).returncode == 0
    assert run_cli(example, "--steps", "60", "--payload-replay", str(record), "--out", str(second)).returncode == 0
    summaries = [json.loads((d / "summary.json").read_text()) for d in (first, second)]
    assert summaries[0]["totals"]["completed"] > 0 and model_part(summaries[0]) == model_part(summaries[1])
    assert [s["run"]["payloads"] for s in summaries] == [{"mode": "record", "path": str(record)},
                                                         {"mode": "replay", "path": str(record)}]
    for table in ("ticks.csv", "nodes.csv"):
        assert (first / table).read_bytes() == (second / table).read_bytes()


def test_calibration_prints_the_reference_rate_and_a_devices_payload_hz(capsys):
    assert main(["--host-rate", "1000", "--cores", "2", "--frequency", "1e8"]) == 0
    rate_line, hz_line = capsys.readouterr().out.splitlines()
    rate = float(rate_line.split()[2])
    assert rate > 0 and float(hz_line.split()[1]) == pytest.approx(2 * 1e8 * 1000 / rate, rel=1e-5)


def test_calibration_times_a_payload_of_its_own(tmp_path, monkeypatch, capsys):
    (tmp_path / "lab_payloads.py").write_text(LAB)
    monkeypatch.chdir(tmp_path)
    assert main(["--call", "lab_payloads:spin", "--args", '{"cpu_s": 0.01}']) == 0
    line = capsys.readouterr().out.strip()
    assert line.endswith("per CPU-second (calls of lab_payloads:spin, median of 5)")
    assert 50 < float(line.split()[2]) <= 100  # each call spins at least 0.01 CPU-s



def test_validate_says_which_types_run_a_payload():
    intro = costs.report(load_scenario("topologies/examples/payload_classifier.yaml"))[0]
    assert intro.endswith("task type(s) classify run a payload: their service is its measured CPU time x the "
                          "node's payload_hz, the nominal one above until they run")


def test_the_environment_replays_a_record_made_by_a_launch(tmp_path):
    """An agent that keeps every task local makes the decisions the node-side policy `local` made while
    recording (docs/model.md: the timing is the same either way), so its episode replays that record."""
    from env import ZenohEdgeEnv

    path = pair(tmp_path, {"arrival": {"rate": 0.3}}, steps=60, policy="local", hz=SLOW)
    record = tmp_path / "times.jsonl"
    # an episode of 60 steps runs 61 ticks: its reset runs tick 0
    recorded = run_summary(load_scenario(path).replace(payload_log=run_log(record=str(record))), ticks=61)
    env = ZenohEdgeEnv(replaying(path, record), transport="inproc", max_steps=60)
    env.reset(seed=0)
    while env.agents:
        env.step(dict.fromkeys(env.agents, 0))
    replayed = env.summary()
    assert replayed["totals"] == recorded["totals"] and recorded["totals"]["completed"] > 5
    assert replayed["nodes"] == recorded["nodes"] and replayed["response_time"] == recorded["response_time"]
    env.close()
