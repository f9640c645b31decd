"""Malformed scenarios: exit status 2 and one line per problem naming the file, key path and expectation."""

from __future__ import annotations

import statistics
import subprocess
import sys

import pytest
import yaml

from orchestrator.cli import main
from orchestrator.scenario import load_scenario

NODES = [{"id": "a", "client": True, "controller": True}, {"id": "b"}]
LINKS = [["a", "b"]]
HEADER = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n"
# an Ether file with a device whose name is no profile and whose type label implies no part
ETHER_GPU = """{"nodes": {
  "rpi3_0": {"id": 1, "coordinates": [0, 0], "capacity": {"cpu_milis": 4000, "memory": 1e9},
             "labels": {"ether.edgerun.io/type": "sbc"}},
  "gpu_0": {"id": 2, "coordinates": [10, 0], "capacity": {"cpu_milis": 9000, "memory": 8e9},
            "labels": {"ether.edgerun.io/type": "gpgpu"}}},
 "links": {"neighbours": {"1": [2], "2": [1]}}}"""


def good(**top):
    data = {"topology": {"nodes": [dict(n) for n in NODES], "links": [list(lk) for lk in LINKS]}}
    data.update(top)
    return data


def with_nodes(*nodes, links=LINKS):
    return {"topology": {"nodes": list(nodes), "links": links}}


# (name, file content (dict or raw text), extra files, expected fragment of the error line)
CASES = [
    ("empty_file", "", {}, "the file is empty"),
    ("invalid_yaml", "topology: {nodes: [a, b\n", {}, ":2:1: invalid YAML"),
    ("top_level_list", "- a\n- b\n", {}, "expected a mapping at the top level"),
    ("missing_topology", {"simulation": {"steps": 5}}, {}, "topology: required key is missing"),
    ("unknown_key_typo", {**good(), "simulaton": {"steps": 3}}, {},
     "simulaton: unknown key (did you mean 'simulation'?)"),
    ("unknown_nested_key", good(simulation={"step": 3}), {}, "simulation.step: unknown key (did you mean 'steps'?)"),
    ("wrong_type_cores", with_nodes({"id": "a", "client": True, "cores": "four"}, {"id": "b"}), {},
     "topology.nodes[0].cores: expected an integer (got 'four')"),
    ("float_cores", with_nodes({"id": "a", "client": True}, {"id": "b", "cores": 1.5}), {},
     "topology.nodes[1].cores: expected an integer"),
    ("negative_rate", good(workload={"arrival": {"rate": -0.1}}), {},
     "workload.arrival.rate: expected a number >= 0"),
    ("zero_frequency", with_nodes({"id": "a", "client": True, "frequency": 0}, {"id": "b"}), {},
     "topology.nodes[0].frequency: expected a number > 0"),
    ("bad_mode", good(simulation={"mode": "greedy"}), {}, "simulation.mode: expected 'binary' or 'batch'"),
    ("unknown_policy", good(simulation={"policy": "best"}), {}, "simulation.policy: expected one of local"),
    ("link_to_unknown_node", with_nodes(*NODES, links=[["a", "zz"]]), {},
     "topology.links[0].between: unknown node 'zz'"),
    ("link_to_itself", with_nodes(*NODES, links=[["a", "b"], ["a", "a"]]), {}, "cannot link to itself"),
    ("duplicate_node", with_nodes(*NODES, {"id": "a"}), {}, "duplicate node id 'a'"),
    ("disconnected", with_nodes(*NODES, {"id": "c"}), {}, "topology: the network is disconnected"),
    ("failure_unknown_node", good(failures=[{"node": "x", "at": 3, "duration": 2}]), {},
     "failures[0].node: unknown node 'x'"),
    ("negative_failure_tick", good(failures=[{"node": "a", "at": -3, "duration": 2}]), {},
     "failures[0].at: expected a number >= 0"),
    ("unknown_profile", with_nodes({"id": "a", "profile": "raspberry", "client": True}, {"id": "b"}), {},
     "topology.nodes[0].profile: unknown profile 'raspberry'"),
    ("unknown_generator", {"topology": {"generator": {"kind": "star", "n": 4}}}, {},
     "topology.generator.kind: expected one of ring"),
    ("generator_missing_param", {"topology": {"generator": {"kind": "ring", "profile": "tier0"}}}, {},
     "topology.generator.n: ring needs this parameter"),
    ("generator_bad_param_type", {"topology": {"generator": {"kind": "ring", "n": "six", "profile": "tier0"}}}, {},
     "topology.generator.n: expected an integer"),
    ("ether_file_missing", {"topology": {"ether": "nowhere.json"}}, {}, "topology.ether: file not found"),
    ("trace_bad_header", good(workload={"trace": "t.csv"}), {"t.csv": "when,who\n1,a\n"},
     "workload.trace: "),
    ("trace_unknown_client", good(workload={"trace": "t.csv"}), {"t.csv": HEADER + "0,b,1e6,1,1,1,10\n"},
     "t.csv:2: 'b' is not a task source node"),
    ("controller_without_worker", with_nodes({"id": "a", "client": True, "controller": True, "worker": False},
                                             {"id": "b"}), {}, "a controller needs a worker"),
    ("no_task_source", with_nodes({"id": "a"}, {"id": "b"}), {}, "topology: no node is a task source"),
    ("loss_above_one", good(network={"loss": 1.5}), {}, "network.loss: expected a number <= 1"),
    ("zero_steps", good(simulation={"steps": 0}), {}, "simulation.steps: expected a number >= 1"),
    # an episode ends within 2^31 ticks: 1.0e+12 steps (YAML reads a float) ran for ever, its CSVs growing 2 MB/s
    ("steps_past_2_31", yaml.safe_dump(good()) + "simulation: {steps: 1.0e+12}\n", {},
     "simulation.steps: expected a number <= 2147483648 (got 1000000000000.0)"),
    ("steps_past_int64", good(simulation={"steps": 10**22}), {},
     "simulation.steps: expected a number <= 2147483648 (got 10000000000000000000000)"),
    ("episode_ticks_past_2_31", good(simulation={"steps": 2**30, "decision_interval": 4}), {},
     "simulation: steps x decision_interval: expected at most 2^31 (2147483648) ticks an episode, but 1073741824 "
     "steps of 4 tick(s) are 4294967296"),
    ("bad_node_id", with_nodes({"id": "a/b", "client": True}, {"id": "b"}, links=[["a/b", "b"]]), {},
     "topology.nodes[0].id: expected a name of letters"),
    ("both_sources", {"topology": {"ether": "x.json", "generator": {"kind": "ring", "n": 3}}}, {},
     "topology: give either 'ether' or 'generator'"),
    ("duplicate_link", with_nodes(*NODES, links=[["a", "b"], {"between": ["b", "a"], "rate_bps": 1e6}]), {},
     "topology.links[1].between: duplicate link (also topology.links[0])"),
    ("arrival_key_of_another_kind", good(workload={"arrival": {"kind": "linear", "rate": 0.3}}), {},
     "workload.arrival: rate is not used by kind 'linear', which takes end, start"),
    ("arrival_missing_keys", good(workload={"arrival": {"kind": "zigzag", "low": 0.1}}), {},
     "workload.arrival: kind 'zigzag' needs high, period"),
    ("arrival_unknown_kind", good(workload={"arrival": {"kind": "poisson"}}), {},
     "workload.arrival.kind: expected 'constant', 'linear', 'zigzag' or 'uniform' (got 'poisson')"),
    ("arrival_misspelt_key_of_its_kind", good(workload={"arrival": {"kind": "linear", "strat": 0.1, "end": 1}}), {},
     "workload.arrival.strat: unknown key (did you mean 'start'?)"),
    ("arrival_not_a_mapping", good(workload={"arrival": 7}), {}, "workload.arrival: expected a mapping (got 7)"),
    ("failure_zero_duration", good(failures=[{"node": "a", "at": 3, "duration": 0}]), {},
     "failures[0].duration: expected a number >= 1 (got 0)"),
    ("link_rates_without_ether", {"topology": {"nodes": NODES, "links": LINKS, "link_rates": "ether"}}, {},
     "topology: link_rates only applies to an Ether import"),
    ("trace_and_arrival", good(workload={"trace": "t.csv", "arrival": {"rate": 0.2}}), {"t.csv": HEADER},
     "workload: a trace gives every task itself: remove arrival"),
    ("generator_profile_typo", {"topology": {"generator": {"kind": "ring", "n": 5, "profile": "tierO"}}}, {},
     "topology.generator: unknown profile 'tierO'"),
    # the reference implementation's semantics (docs/scenario.md, "Scenario families")
    ("bad_admission", good(simulation={"admission": "queue"}), {},
     "simulation.admission: expected 'decide_first' or 'queue_first' (got 'queue')"),
    ("bad_control_latency", good(simulation={"control_latency": 1}), {},
     "simulation.control_latency: expected 0 or 2 (got 1)"),
    ("bad_arrival_process", good(workload={"arrival": {"process": "gaps"}}), {},
     "workload.arrival.process: expected 'poisson' or 'exponential_gaps' (got 'gaps')"),
    ("deadline_range_reversed", good(workload={"tasks": [{"deadline": {"low": 200, "high": 100}}]}), {},
     "workload.tasks[0].deadline: high must be > low (for a fixed deadline, give a number)"),
    ("deadline_range_without_high", good(workload={"tasks": [{"deadline": {"low": 100, "grace": 5}}]}), {},
     "workload.tasks[0].deadline.high: required key is missing"),
    ("deadline_range_typo", good(workload={"tasks": [{"deadline": {"low": 1, "high": 2, "grase": 5}}]}), {},
     "workload.tasks[0].deadline.grase: unknown key (did you mean 'grace'?)"),
    ("deadline_negative_grace", good(workload={"tasks": [{"deadline": {"low": 1, "high": 2, "grace": -5}}]}), {},
     "workload.tasks[0].deadline.grace: expected a number >= 0 (got -5)"),
    ("deadline_list", good(workload={"tasks": [{"deadline": [100, 200]}]}), {},
     "workload.tasks[0].deadline: expected a number, or a range {low, high, grace} (got [100, 200])"),
    ("deadline_zero", good(workload={"tasks": [{"deadline": 0}]}), {},
     "workload.tasks[0].deadline: expected a number > 0 (got 0)"),
    ("buffer_bytes_without_ether", {"topology": {"nodes": NODES, "links": LINKS, "buffer_bytes": 3.2e8}}, {},
     "topology: buffer_bytes only applies to an Ether import"),
    ("zero_buffer_bytes", {"topology": {"ether": "ether/network_2_clusters.json", "buffer_bytes": 0}}, {},
     "topology.buffer_bytes: expected a number > 0 (got 0)"),
    ("path_loss_two_references", good(network={"path_loss": {"frequency_hz": 2.4e9, "ref_loss_db": 40}}), {},
     "network.path_loss: give either ref_loss_db or frequency_hz"),
    ("ether_device_of_unknown_type", {"topology": {"ether": "e.json"}}, {"e.json": ETHER_GPU},
     "node 'gpu_0'.profile: unknown profile 'gpu'"),
    ("negative_seed", good(simulation={"seed": -5}), {}, "simulation.seed: expected a number >= 0 (got -5)"),
    # a seed travels in every reset tick as a msgpack integer: 2^70 ended the run in an OverflowError
    ("seed_past_62_bits", good(simulation={"seed": 2**70}), {},
     "simulation.seed: expected a number <= 4611686018427387903 (got 1180591620717411303424)"),
    # inf and nan are refused everywhere: as YAML writes them (.nan, .inf), and as strings
    ("nan_tx_power", "network: {tx_power_dbm: .nan}\ntopology: {nodes: [{id: a, client: true}, {id: b}], "
                     "links: [[a, b]]}\n", {}, "network.tx_power_dbm: expected a finite number (got nan)"),
    ("infinite_dt", good(simulation={"dt": "inf"}), {}, "simulation.dt: expected a finite number"),
    ("infinite_instructions", good(workload={"tasks": [{"instructions": float("inf")}]}), {},
     "workload.tasks[0].instructions: expected a finite number (got inf)"),
    ("nan_position", with_nodes({"id": "a", "client": True, "position": [0, float("nan")]}, {"id": "b"}), {},
     "topology.nodes[0].position[1]: expected a finite number"),
    # a level in dB whose power form is no float
    ("huge_tx_power", with_nodes({"id": "a", "client": True, "tx_power_dbm": 1e20}, {"id": "b"}), {},
     "topology.nodes[0].tx_power_dbm: expected a number <= 3000"),
    ("huge_link_gain", with_nodes(*NODES, links=[{"between": ["a", "b"], "gain_db": -1e9}]), {},
     "topology.links[0].gain_db: expected a number >= -3000"),
    # more tasks a tick than any run could hold: a clear line, not numpy's "lam value too large"
    ("arrivals_beyond_a_million_a_tick", good(simulation={"dt": 1e7}), {},
     "workload.arrival.rate: 0.17 tasks/s with dt = 1e+07 s is 1.7e+06 tasks a tick per source; expected at most"),
    # Python's json reads NaN; a negative capacity was taken as a negative clock rate
    ("ether_nan_coordinates", {"topology": {"ether": "e.json"}},
     {"e.json": ETHER_GPU.replace('"coordinates": [10, 0]', '"coordinates": [NaN, 0]')},
     "node 'gpu_0' lacks coordinates, or capacity.cpu_milis and memory as positive numbers"),
    ("ether_negative_capacity", {"topology": {"ether": "e.json"}},
     {"e.json": ETHER_GPU.replace('"cpu_milis": 9000', '"cpu_milis": -9000')},
     "node 'gpu_0' lacks coordinates, or capacity.cpu_milis and memory as positive numbers"),
    # a clock rate past a float's range: the hardware a topology source gives is held to the model's own ranges
    ("ether_endless_frequency", {"topology": {"ether": "e.json"}},
     {"e.json": ETHER_GPU.replace('"cpu_milis": 4000', '"cpu_milis": 1e307')},
     "node 'rpi3_0'.frequency: expected a finite number (got inf), as the topology source gives it"),
    ("ether_buffer_bytes_too_small", {"topology": {"ether": "ether/network_2_clusters.json", "buffer_bytes": 1e-300}},
     {}, "of memory hold inf tasks of 1e-300 bytes (topology.buffer_bytes, or the task size)"),
    ("ether_is_a_directory", {"topology": {"ether": "."}}, {}, ": cannot read it: Is a directory"),
    ("trace_is_a_directory", good(workload={"trace": "."}), {}, ": cannot read it: Is a directory"),
    ("yaml_nested_too_deeply", "topology: " + "[" * 5000 + "]" * 5000 + "\n", {}, "invalid YAML: nested too deeply"),
    # a generator asked for more than any machine builds: said at once, not after exhausting memory
    ("generator_too_many_nodes", {"topology": {"generator": {"kind": "grid", "rows": 100000, "cols": 100000,
                                                             "profile": "tier0"}}}, {},
     "topology.generator: grid: 10,000,000,000 nodes; expected at most 1,000,000"),
    ("generator_too_many_links", {"topology": {"generator": {"kind": "fully_connected", "n": 100000,
                                                             "profile": "tier0"}}}, {},
     "topology.generator: fully_connected: 4,999,950,000 links; expected at most 10,000,000"),
    # a deadline whose expiry tick floats cannot compute (the search for it looped for ever)
    ("deadline_past_two_to_the_fifty_ticks", good(workload={"tasks": [{"deadline": {"low": 1, "high": 1e300}}]}),
     {}, "workload.tasks[0].deadline: a deadline of 1e+300 s is 1e+300 ticks of dt = 1 s; expected at most 2^50"),
    ("trace_with_nan", good(workload={"trace": "t.csv"}), {"t.csv": HEADER + "0,a,1e6,1e3,1e3,1,nan\n"},
     "t.csv:2: expected finite numbers in every column but 'client'"),
    ("trace_with_endless_deadline", good(workload={"trace": "t.csv"}),
     {"t.csv": HEADER + "0,a,1e6,1e3,1e3,1,1e300\n"},
     "t.csv:2: a deadline of 1e+300 s is 1e+300 ticks"),
    ("client_rate_beyond_a_million_a_tick", good(workload={"rates": {"a": 1e12}}), {},
     "workload.rates.a: 1e+12 tasks/s with dt = 1 s is 1e+12 tasks a tick"),
]


def write_case(tmp_path, name, content, files):
    path = tmp_path / f"{name}.yaml"
    path.write_text(content if isinstance(content, str) else yaml.safe_dump(content, sort_keys=False))
    for fname, text in files.items():
        (tmp_path / fname).write_text(text)
    return path


def test_there_are_at_least_fifteen_cases():
    assert len(CASES) >= 15


@pytest.mark.parametrize(("name", "content", "files", "expected"), CASES, ids=[c[0] for c in CASES])
def test_bad_scenario_is_rejected_with_a_key_path(tmp_path, capsys, name, content, files, expected):
    path = write_case(tmp_path, name, content, files)
    assert main(["validate", str(path)]) == 2
    captured = capsys.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert captured.out == ""
    assert lines, "no error printed"
    assert all(ln.startswith(str(path)) for ln in lines), lines
    assert any(expected in ln for ln in lines), f"expected {expected!r} in {lines}"
    assert "Traceback" not in captured.err


def test_missing_file(tmp_path, capsys):
    assert main(["validate", str(tmp_path / "nope.yaml")]) == 2
    assert capsys.readouterr().err.strip() == f"{tmp_path / 'nope.yaml'}: file not found"


def test_unknown_bundled_name_lists_the_bundled_scenarios_and_suggests_one(capsys):
    assert main(["validate", "aot5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aot5: no such file or bundled scenario (did you mean 'aot4'?); "
                          "bundled: aot1, aot1_compute, aot1_reference, aot1_urgent, aot1_wired, aot2,")
    assert "examples/minimal" in err and len(err.splitlines()) == 1


def test_an_outside_scenario_names_a_bundled_ether_file_by_its_relative_path(tmp_path, capsys):
    path = write_case(tmp_path, "outside", {"topology": {"ether": "ether/network_2_clusters.json"}}, {})
    assert main(["validate", str(path)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "19 nodes, 34 links, 15 controllers, 12 task sources"


def test_cli_process_exit_status_and_no_traceback(tmp_path):
    path = write_case(tmp_path, "bad", with_nodes({"id": "a", "client": True, "cores": -2}, {"id": "b"}), {})
    for command in ("validate", "launch"):
        proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", command, str(path)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2
        assert proc.stderr.strip() == f"{path}: topology.nodes[0].cores: expected a number >= 1 (got -2)"


def test_validate_prints_the_counts_then_what_a_task_costs(capsys):
    assert main(["validate", "topologies/aot2.yaml"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "19 nodes, 34 links, 15 controllers, 12 task sources"
    # 8e7 instructions x cpi 1 on one core of 4 MHz; 150 MiB at the median rate of the links into the rpi3s
    aot2 = load_scenario("aot2")
    rate = statistics.median(link.rate_bps for link in aot2.links if link.dst.startswith("rpi3"))
    row = next(line.split() for line in lines if line.split()[:2] == ["sensing", "rpi3"])
    assert row[2:5] == ["12", "20", "s"] and row[5] == f"{150 * 2**20 * 8 / rate:.3g}" and row[-2:] == ["100", "s"]
    assert [line for line in lines if line.startswith("warning:")] == [
        "warning: 12 rpi3 node(s) (rpi3_0, rpi3_1, rpi3_2 ...) receive more work than they serve, up to 3.4 times "
        "(0.17 tasks/s of 20 s of service at rpi3_0): what they do not offload queues, and is dropped when the "
        "buffer is full or the deadline passes"]


def test_validate_warns_of_a_task_that_cannot_meet_its_deadline_alone(tmp_path, capsys):
    """150 MiB tasks of 8e7 instructions on rpi3s (4 MHz: 20 s of service) with a 10 s deadline: served where
    they arrive or offloaded, no task can make it; the file is still valid (exit 0)."""
    data = {"workload": {"tasks": [{"name": "big", "deadline": 10}]},
            "topology": {"nodes": [{"id": "a", "profile": "rpi3"}, {"id": "b", "profile": "rpi3"}],
                         "links": [["a", "b"]]}}
    path = write_case(tmp_path, "big", data, {})
    assert main(["validate", str(path)]) == 0
    warnings = [line for line in capsys.readouterr().out.splitlines() if line.startswith("warning:")]
    assert warnings == ["warning: task type 'big' cannot meet its deadline (10 s) even alone on rpi3: 20 s of service",
                        "warning: 2 rpi3 node(s) (a, b) receive more work than they serve, up to 3.4 times (0.17 "
                        "tasks/s of 20 s of service at a): what they do not offload queues, and is dropped when the "
                        "buffer is full or the deadline passes"]


def test_a_generator_profile_typo_is_reported_once(tmp_path, capsys):
    path = write_case(tmp_path, "typo", {"topology": {"generator": {"kind": "ring", "n": 6, "profile": "tierO"}}}, {})
    assert main(["validate", str(path)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_validate_warns_when_tasks_reach_a_controller_faster_than_it_places_them(tmp_path, capsys):
    """1.5 tasks a tick at one node whose controller places one a step (binary mode): the rest wait undecided
    (a launch of this file drops about 70 % of its tasks); batch mode with two slots, or queue_first admission,
    places them all (about 99 % completed), and then there is nothing to warn of."""
    base = {"workload": {"arrival": {"rate": 1.5}, "tasks": [{"instructions": 4e6, "input_bytes": 1e5,
                                                              "output_bytes": 1e4, "deadline": 20}]},
            "topology": {"nodes": [{"id": "edge", "profile": "tier0"}, {"id": "fog", "profile": "tier1",
                                                                       "position": [30, 0]}],
                         "links": [["edge", "fog"]]}}
    cases = {"binary": {}, "batch": {"mode": "batch", "batch_size": 2}, "queue_first": {"admission": "queue_first"},
             "slower": {"decision_interval": 2, "mode": "batch", "batch_size": 2}}
    warned = {}
    for name, simulation in cases.items():
        path = write_case(tmp_path, name, {**base, "simulation": simulation}, {})
        assert main(["validate", str(path)]) == 0
        warned[name] = [line for line in capsys.readouterr().out.splitlines() if "reach the controllers" in line]
    assert warned["binary"] == [
        "warning: tasks reach the controllers of 1 node(s) (edge) faster than they place them, up to 1.5 a step at "
        "edge where a controller places 1 a step (binary mode): the rest wait undecided, fill the buffer and expire "
        "(batch mode with batch_size >= 2, or admission: queue_first, places them all)"]
    assert warned["batch"] == warned["queue_first"] == []
    # two ticks a step: 3 tasks reach edge's controller every step, which places 2
    assert "up to 3 a step at edge where a controller places 2 a step (batch mode)" in warned["slower"][0]
