"""Jobs as DAGs: readiness at the origin, transfers of outputs, job counters, sources and bad input.

The rule (docs/model.md, "Jobs as DAGs"): the origin client holds a job; a task of it is released, as a
new task of that client, when the results of all its predecessors are back at the origin; it is then a
decision of the origin's controller like any task, and its input (its in-edges' bytes) travels with it
when it is offloaded, its result (its out-edges' bytes, and an exit task's output) back to the origin.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from node_runtime.model.array import refusal
from node_runtime.model.client import CLIENT, COUNTS, TYPES, arrivals
from node_runtime.model.dag import JobSpec, LayeredDag, Shape
from node_runtime.model.payload import read_record, run_log
from node_runtime.model.rng import stream
from node_runtime.model.spec import Scenario
from node_runtime.model.workload import TaskSource, nominal_arrivals
from orchestrator.scenario import ScenarioError, costs, load_scenario
from orchestrator.viewers.summary import rows
from tests.conftest import ROOT, model_part, run_summary, write_scenario
from tests.test_payload import LAB
from topologies.alibaba import Conversion, TraceError
from topologies.alibaba_dag import dependencies, read_dags

SAMPLE = ROOT / "topologies" / "traces" / "alibaba_dag_sample.csv"
DIAMOND = {"name": "diamond", "deadline": 40,
           "tasks": [{"instructions": 2.0e6, "input_bytes": 1.0e5}, {"instructions": 4.0e6},
                     {"instructions": 2.0e6}, {"instructions": 1.0e6, "output_bytes": 1.0e4}],
           "edges": [[0, 1, 2.0e5], [0, 2, 2.0e5], [1, 3, 1.0e5], [2, 3, 1.0e5]]}
SEED = 22  # the Poisson draws of a's client at 0.05 jobs/s give one job, at tick 0, in the 20 ticks (asserted)


def diamond(tmp_path: Path, **workload) -> Path:
    """a (client, controller, worker, 1e6 cycles/s), b (worker, 2e6) and c (worker, 1e6); links a-b and a-c
    of 8e5 bit/s (1e5 bytes a second); round robin with co-located control."""
    return write_scenario(tmp_path, {
        "name": "diamond",
        "simulation": {"dt": 1.0, "steps": 20, "seed": SEED, "policy": "round_robin", "control_latency": 0},
        "topology": {"nodes": [
            {"id": "a", "frequency": 1.0e6, "buffer": 8, "client": True, "controller": True},
            {"id": "b", "frequency": 2.0e6, "buffer": 8},
            {"id": "c", "frequency": 1.0e6, "buffer": 8},
        ], "links": [{"between": ["a", "b"], "rate_bps": 8.0e5}, {"between": ["a", "c"], "rate_bps": 8.0e5}]},
        "workload": {"arrival": {"kind": "constant", "rate": 0.05}, "jobs": {"dags": [DIAMOND]}, **workload},
    })


def diamond_done(s: dict, mean: float, longest: float, makespan: float, cycles_b: float, cycles_c: float) -> None:
    """The diamond's summary once its job completed: 4 tasks, 2 offloaded; the response times, the makespan and
    each node's energy (radio on air 4 s at a, 1 s at b and c, at 0.1 W; a computes 3e6 cycles at 1 GHz, b at 2 GHz,
    c at 1 GHz)."""
    assert s["totals"]["generated"] == s["totals"]["completed"] == 4 and s["totals"]["offloaded"] == 2
    assert s["response_time"]["mean"] == pytest.approx(mean) and s["response_time"]["max"] == pytest.approx(longest)
    assert s["jobs"] == {"generated": 1, "completed": 1, "missed": 0, "completion_ratio": 1.0,
                         "makespan_mean": makespan, "penalised_makespan": makespan, "active": 0}
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(0.4 + 1e-27 * 3e6 * 1e12)
    assert s["nodes"]["b"]["energy_j"] == pytest.approx(0.1 + 1e-27 * cycles_b * 4e12)
    assert s["nodes"]["c"]["energy_j"] == pytest.approx(0.1 + 1e-27 * cycles_c * 1e12)


def check_hand_trace(s: dict, ticks: list[dict[str, str]]) -> None:
    """The diamond 0 -> {1, 2} -> 3, created at tick 0 on a (deadline 40 s). Task sizes from the edges:
    α_in = own input + in-edges, α_out = own output + out-edges: task 0 (2e6 cycles) 1e5 in, 4e5 out;
    task 1 (4e6) 2e5 in, 1e5 out; task 2 (2e6) 2e5 in, 1e5 out; task 3 (1e6) 2e5 in, 1e4 out.
    Round robin at a places its decisions on a, b, c, a, … With control_latency 0 a task handed to a's
    worker at t is observed at the end of t and placed at the start of t + 1; one decision a tick.

    - tick 0: the job is created; task 0 is ready (no predecessor) and released: at a's worker at 1.
    - task 0: placed locally at 2; 2e6 cycles at 1e6 a tick: ticks 2, 3; result to a's client at 4 (4 s).
    - tick 4: task 0's result is back at the origin: tasks 1 and 2 are ready, released at 4 (due in
      40 - 4 = 36 s), at a's worker at 5, observed at the end of 5 (task 1) and 6 (task 2).
    - task 1 -> b at 6: its 2e5 input bytes (task 0's output for it) on a->b 6.0 -> 8.0, at b at 8; 4e6
      cycles at 2e6: ticks 8, 9; its 1e5-byte result on b->a 9.0 -> 10.0: back at 10 (6 s).
    - task 2 -> c at 7: 2e5 bytes on a->c 7.0 -> 9.0, at c at 9; 2e6 cycles at 1e6: ticks 9, 10; 1e5
      bytes on c->a 10.0 -> 11.0: back at 11 (7 s).
    - tick 11: both predecessors of task 3 are back: released at 11 (due in 29 s), at a's worker at 12,
      placed locally (round robin's fourth) at 13, 1e6 cycles in tick 13, result at 14 (3 s).
    - tick 14: the job's last result is back: it completes, makespan 14 s.

    Response times 4, 6, 7, 3 (mean 5); offloads at 6 and 7; a's radio is on air 4 s, b's and c's 1 s each
    (20 dBm: 0.1 W).
    """
    diamond_done(s, mean=5.0, longest=7.0, makespan=14.0, cycles_b=4e6, cycles_c=2e6)
    by_tick = {int(r["tick"]): r for r in ticks}
    released = {t: int(r["generated"]) for t, r in by_tick.items() if int(r["generated"])}
    back = {t: int(r["completed"]) for t, r in by_tick.items() if int(r["completed"])}
    offloads = [t for t, r in by_tick.items() if int(r["offloaded"])]
    assert (released, back, offloads) == ({0: 1, 4: 2, 11: 1}, {4: 1, 10: 1, 11: 1, 14: 1}, [6, 7])
    assert [int(by_tick[t]["jobs_active"]) for t in (0, 13, 14)] == [1, 1, 0]
    assert [by_tick[t]["makespan_mean"] for t in (13, 14)] == ["", "14.0"]
    # in flight: the inputs of tasks 1 and 2 on their links, then their results
    assert [int(by_tick[t]["in_flight"]) for t in range(6, 11)] == [1, 2, 1, 1, 1]


def run(scenario, tmp_path: Path, name: str, **kwargs) -> tuple[dict, list[dict[str, str]]]:
    out = tmp_path / name
    s = run_summary(scenario, ticks=20, out=out, **kwargs)
    with (out / "ticks.csv").open() as fh:
        return s, list(csv.DictReader(fh))


def test_one_job_arrives_in_the_hand_trace(tmp_path):
    sc = load_scenario(diamond(tmp_path))
    source = TaskSource(sc, "a", stream(SEED, 0, CLIENT.stream, COUNTS), stream(SEED, 0, CLIENT.stream, TYPES))
    assert [t for t in range(20) if source.count(t)] == [0] and source.count(0) == 1


def test_hand_trace_of_a_diamond_on_three_nodes(tmp_path):
    s, ticks = run(load_scenario(diamond(tmp_path)), tmp_path, "inproc")
    check_hand_trace(s, ticks)
    labels = [label for label, _ in rows(s)]  # the launch table
    assert labels[-6:] == ["jobs", "jobs completed", "jobs missed", "job completion ratio", "makespan (mean)",
                           "penalised makespan"]


def test_validate_describes_a_jobs_workload(tmp_path):
    assert costs.report(load_scenario(diamond(tmp_path))) == [
        "jobs workload: every arrival is a job, one of 1 listed DAG(s), 4 tasks in all, due in at most 40 s "
        "(no task types to cost)"]


@pytest.mark.zenoh
def test_hand_trace_of_a_diamond_over_zenoh(tmp_path):
    scenario = load_scenario(diamond(tmp_path))
    inproc, inproc_ticks = run(scenario, tmp_path, "inproc")
    for layout in ("per-role", "per-node"):
        over, over_ticks = run(scenario, tmp_path, layout, transport="zenoh", layout=layout)
        check_hand_trace(over, over_ticks)
        assert model_part(over) == model_part(inproc) and over_ticks == inproc_ticks


def payload_diamond(tmp_path: Path) -> Scenario:
    """The diamond whose tasks 1 and 2 are of type infer, which runs a payload, replayed from a record: task 1
    (task id 3, on b) 2.5 CPU-s, task 2 (id 4, on c) 3 CPU-s; payload_hz: each node's capacity."""
    (tmp_path / "lab_payloads.py").write_text(LAB)
    typed = [{**t, "type": "infer"} if i in (1, 2) else t for i, t in enumerate(DIAMOND["tasks"])]
    path = diamond(tmp_path, jobs={"dags": [{**DIAMOND, "tasks": typed}]},
                   tasks=[{"name": "infer", "payload": {"call": "lab_payloads:spin"}}])
    record = tmp_path / "times.jsonl"
    record.write_text(f'{{"seed": {SEED}, "task": 3, "node": "b", "cpu_s": 2.5}}\n'
                      f'{{"seed": {SEED}, "task": 4, "node": "c", "cpu_s": 3.0}}\n')
    return load_scenario(path).replace(payload_log=run_log(replay=str(record)))


def check_payload_hand_trace(s: dict) -> None:
    """As the diamond's hand trace (``check_hand_trace``) until task 1 reaches b at 8 and task 2 c at 9; then:

    - task 1: 2.5 CPU-s x 2e6 = 5e6 cycles, not its nominal 4e6: ticks 8, 9 and 1e6 in 10; its result on
      b->a 10.0 -> 11.0: back at 11 (7 s).
    - task 2: 3 CPU-s x 1e6 = 3e6 cycles, not 2e6: ticks 9, 10, 11; result on c->a 11.0 -> 12.0: back at 12 (8 s).
    - task 3: released at 12, at a's worker at 13, placed locally at 14, run in 14, result at 15 (3 s): the
      job completes at 15, makespan 15 s.

    Response times 4, 7, 8, 3 (mean 5.5); b computes 5e6 cycles, c 3e6, a 3e6."""
    diamond_done(s, mean=5.5, longest=8.0, makespan=15.0, cycles_b=5e6, cycles_c=3e6)


def test_a_jobs_tasks_run_the_payload_of_the_type_they_name(tmp_path):
    scenario = payload_diamond(tmp_path)
    check_payload_hand_trace(run_summary(scenario, ticks=20))
    assert costs.report(scenario)[0].endswith("(no task types to cost); the tasks of type(s) infer run a payload")


@pytest.mark.zenoh
def test_a_jobs_payload_tasks_replay_over_zenoh_per_node(tmp_path):
    scenario = payload_diamond(tmp_path)
    inproc, inproc_ticks = run(scenario, tmp_path, "inproc")
    over, over_ticks = run(scenario, tmp_path, "per-node", transport="zenoh", layout="per-node")
    check_payload_hand_trace(over)
    assert model_part(over) == model_part(inproc) and over_ticks == inproc_ticks


def test_generated_jobs_of_a_payload_type_record_and_replay(tmp_path):
    """generator.type: every task of a generated job runs the payload; the measured times, recorded, replay
    to the same results in another layout."""
    (tmp_path / "lab_payloads.py").write_text(LAB)
    path = diamond(tmp_path, jobs={"generator": {"type": "infer", "deadline": 40}},
                   tasks=[{"name": "infer", "payload": {"call": "lab_payloads:spin"}}],
                   arrival={"kind": "constant", "rate": 0.3})
    record = tmp_path / "times.jsonl"
    scenario = load_scenario(path)
    measured = run_summary(scenario.replace(payload_log=run_log(record=str(record))), ticks=20, seed=1)
    times = read_record(str(record))
    assert measured["jobs"]["generated"] >= 1 and 0 < len(times) <= measured["totals"]["generated"]
    assert 0 < measured["totals"]["completed"] <= len(times)  # every task served ran the payload
    replayed = run_summary(scenario.replace(payload_log=run_log(replay=str(record))), ticks=20, seed=1,
                           layout="per-node")
    assert model_part(replayed) == model_part(measured)


def test_a_lost_task_makes_its_job_miss_at_its_deadline(tmp_path):
    """The diamond with a 1-tick failure of c while task 2's input is on its way (c down at tick 9, when it
    arrives): task 2 is dropped (node_failure), task 3 is never released, and the job misses its deadline
    at tick 41, the first at which it is older than 40 s. Tasks and jobs are conserved at every tick (the
    run checks both)."""
    data = yaml.safe_load(diamond(tmp_path).read_text())
    data["failures"] = [{"node": "c", "at": 9, "duration": 1}]
    data["simulation"]["steps"] = 45
    sc = load_scenario(write_scenario(tmp_path, data, "failing.yaml"))
    out = tmp_path / "failing"
    s = run_summary(sc, ticks=45, out=out)
    assert s["totals"]["generated"] == 3 and s["totals"]["completed"] == 2
    assert s["totals"]["dropped"]["node_failure"] == 1
    assert s["jobs"] == {"generated": 1, "completed": 0, "missed": 1, "completion_ratio": 0.0, "makespan_mean": None,
                         "penalised_makespan": 40.0, "active": 0}
    with (out / "ticks.csv").open() as fh:
        missed = [int(r["tick"]) for r in csv.DictReader(fh) if int(r["jobs_missed"])]
    assert missed == [41]


def test_generated_jobs_are_deterministic_layered_dags():
    """Every task after the first layer has 1..fan_in predecessors (here widths never exceed fan_in times the
    next), every task before the last layer a successor; entry tasks bring the input, exit tasks the output."""
    gen = LayeredDag(layers={"low": 2, "high": 6}, width={"low": 1, "high": 3}, fan_in=3, deadline=50.0)
    jobs = [gen.draw(np.random.default_rng(seed)) for seed in range(200)]
    assert jobs[7] == gen.draw(np.random.default_rng(7))  # the same seed, the same DAG
    assert len({(len(j.tasks), j.edges) for j in jobs}) > 50  # and others differ
    for job in jobs:
        shape = Shape.of(job)
        entries = [i for i, p in enumerate(shape.preds) if not p]
        exits = [i for i, s in enumerate(shape.succs) if not s]
        assert all(a < b for a, b, _ in job.edges)  # acyclic: listed in an order the edges respect
        assert entries == list(range(len(entries))) and exits == list(range(len(job.tasks) - len(exits),
                                                                              len(job.tasks)))
        assert all(len(p) <= 3 for p in shape.preds)
        assert all(job.tasks[i].input_bytes == 1.0e5 for i in entries)
        assert all(job.tasks[i].output_bytes == 1.0e4 for i in exits)
        assert all(1.0e5 <= b <= 1.0e6 for *_, b in job.edges)
        assert 2 <= len(job.tasks) <= 18 and job.deadline == 50.0


def test_a_jobs_mean_task_count_sets_the_nominal_arrivals(tmp_path):
    """What a worker expects to receive (rewards and validate read it): jobs/s x tasks per job on average."""
    sc = load_scenario(diamond(tmp_path))
    assert nominal_arrivals(sc) == {"a": pytest.approx(0.05 * 4)}
    gen = LayeredDag(layers={"low": 3, "high": 5}, width={"low": 1, "high": 3})
    assert sc.workload.jobs.model_copy(update={"dags": (), "generator": gen}).mean_tasks == 4 * 2


def test_critical_path_and_sizes_of_a_job():
    shape = Shape.of(JobSpec.model_validate(DIAMOND))
    assert shape.preds == ((), (0,), (0,), (1, 2)) and shape.succs == ((1, 2), (3,), (3,), ())
    assert shape.input_bytes == (1.0e5, 2.0e5, 2.0e5, 2.0e5)
    assert shape.output_bytes == (4.0e5, 1.0e5, 1.0e5, 1.0e4)
    assert shape.critical_cycles == (7.0e6, 5.0e6, 3.0e6, 1.0e6)


def test_alibaba_task_names_keep_their_dependencies():
    assert dependencies("M1") == (1, ()) and dependencies("R2_1") == (2, (1,))
    assert dependencies("J3_1_2") == (3, (1, 2)) and dependencies("task_Nzg3ODA=") is None
    dags = read_dags(SAMPLE)
    assert [d.name for d in dags] == ["j_200001", "j_200002", "j_200003", "j_200005", "j_200007"]
    first = dags[0]  # M1 (2 instances), M2, J3_1_2, R4_3
    assert first.edges == ((0, 2, 5.0e6), (1, 2, 3.0e6), (2, 3, 8.0e6))
    assert [t.instructions for t in first.tasks] == [2 * 1.0 * 10 * 4.0e6, 0.5 * 8 * 4.0e6, 2.0 * 10 * 4.0e6,
                                                     1.0 * 5 * 4.0e6]
    assert first.tasks[0].input_bytes == 5.0e6 and first.tasks[3].output_bytes == 2.0e6
    assert first.deadline == 3.0 * 25
    last = dags[-1]
    assert len(last.tasks) == 7 and Shape.of(last).preds[6] == (4, 5)
    assert len(read_dags(SAMPLE, Conversion(limit=2))) == 2


def test_the_importer_refuses_what_is_not_a_batch_task_file(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("M1,1,j_1,1,Terminated,0,10\n")
    with pytest.raises(TraceError, match=r"bad.csv:1: expected 9 columns"):
        read_dags(bad)
    bad.write_text("M1,1,j_1,1,Terminated,0,x,100,0.5\n")
    with pytest.raises(TraceError, match=r"bad.csv:1: instance_num, start_time, end_time, plan_cpu and plan_mem"):
        read_dags(bad)
    bad.write_text("R2_3,1,j_1,1,Terminated,0,10,100,0.5\n")
    with pytest.raises(TraceError, match="no job whose every task finished"):
        read_dags(bad)


def test_a_scenario_imports_the_sample_and_runs_its_jobs(tmp_path):
    path = write_scenario(tmp_path, {
        "simulation": {"steps": 200, "policy": "least_queue"},
        "topology": {"nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b", "controller": True}],
                     "links": [{"between": ["a", "b"], "rate_bps": 1.0e8}]},
        "workload": {"arrival": {"kind": "constant", "rate": 0.05},
                     "jobs": {"alibaba": {"file": "traces/alibaba_dag_sample.csv", "frequency": 4.0e7}}}})
    sc = load_scenario(path)
    assert len(sc.workload.jobs.dags) == 5
    s = run_summary(sc, ticks=200)
    assert s["jobs"]["generated"] > 0 and s["jobs"]["completed"] > 0
    assert s["penalty_s"] == 75.0  # the longest job deadline


@pytest.mark.parametrize(("jobs", "extra", "message"), [
    ({"dags": [{**DIAMOND, "edges": [[1, 0, 5.0]]}]}, {},
     "workload.jobs.dags[0]: edges[0]: expected [from, to, bytes] with 0 <= from < to < 4"),
    ({"dags": [{**DIAMOND, "edges": [[0, 1, 5.0], [0, 1, 6.0]]}]}, {},
     "workload.jobs.dags[0]: edges[1]: a second edge from task 0 to task 1"),
    ({"dags": [DIAMOND], "generator": {}}, {},
     "expected exactly one of dags, generator, alibaba (got dags, generator)"),
    ({"generator": {"layers": {"low": 4, "high": 2}}}, {}, "workload.jobs.generator.layers: high must be >= low"),
    ({"generator": {"instructions": {"low": 0, "high": 5}}}, {},
     "workload.jobs.generator: instructions: expected low > 0 (every task has work to do)"),
    ({"alibaba": {"file": "none.csv"}}, {}, "workload.jobs.alibaba.file: "),
    ({"dags": [DIAMOND]}, {"source": "x.y:Z"}, "jobs come from the arrival process: remove trace and source, or jobs"),
    ({"dags": [DIAMOND]}, {"tasks": [{"payload": {"call": "x.y:f"}}]},
     "workload.tasks[0].payload: no task of workload.jobs is of type 'task'; with jobs a task runs a payload when it "
     "names its type (dags[].tasks[].type or generator.type; an Alibaba job's tasks have none)"),
    ({"dags": [{**DIAMOND, "tasks": [{"instructions": 1.0e6, "type": "nope"}], "edges": []}]}, {},
     "workload.jobs.dags[0].tasks[0].type: expected the name of a task type of workload.tasks ('task'), got 'nope'"),
    ({"generator": {"type": "infer"}}, {"tasks": [{"name": "infer"}, {"name": "infer"}]},
     "workload.jobs.generator.type: 2 task types of workload.tasks are named 'infer'; give each a name of its own"),
])
def test_bad_job_settings_name_the_key(tmp_path, jobs, extra, message):
    path = write_scenario(tmp_path, {"workload": {"jobs": jobs, **extra},
                                     "topology": {"nodes": [{"id": "a", "client": True}]}})
    with pytest.raises(ScenarioError) as e:
        load_scenario(path)
    lines = str(e.value).splitlines()
    assert len(lines) == 1 and message in lines[0] and str(path) in lines[0], str(e.value)


def test_the_array_backend_and_the_arrival_trace_refuse_jobs(tmp_path):
    sc = load_scenario(diamond(tmp_path))
    assert refusal(sc) == ("scenario diamond: the array backend does not support jobs (workload.jobs: DAGs of "
                           "tasks); run it with the in-process or Zenoh backend (Simulation.inproc / .over_zenoh)")
    with pytest.raises(ValueError, match="no arrival trace of its tasks"):
        arrivals(sc, 0, 10)


def test_a_scenario_without_jobs_shows_no_job_metric(aot1):
    s = run_summary(aot1, ticks=20)
    assert "jobs" not in s and "jobs" not in s["nodes"][aot1.nodes[0].id]


def test_agents_observe_each_tasks_critical_path_and_successor_data(tmp_path):
    """In a scenario of jobs the Dict observation has a ``job`` block beside ``task`` (and the flat one those
    3 numbers after the task's 7): the diamond's task 0 is in a job, its remaining critical path is
    2e6 + max(4e6 + 1e6, 2e6 + 1e6) = 7e6 cycles and its successors need 2 x 2e5 bytes of its output."""
    from env import JobField, ZenohEdgeEnv

    sc = load_scenario(diamond(tmp_path))
    env = ZenohEdgeEnv(sc, transport="inproc", max_steps=20)
    flat = ZenohEdgeEnv(sc, transport="inproc", observation="flat", max_steps=20)
    try:
        obs, _ = env.reset(seed=SEED)
        flat_obs, _ = flat.reset(seed=SEED)
        agent = env.agents[0]
        while not obs[agent]["task"][0]:
            obs, *_ = env.step({agent: 0})
            flat_obs, *_ = flat.step({agent: 0})
        job = obs[agent]["job"]
        assert job[JobField.IN_JOB] == 1.0
        assert (job[JobField.CRITICAL_GCYCLES], job[JobField.SUCCESSOR_MB]) == pytest.approx((7e-3, 0.4))
        assert flat_obs[agent]["observation"].shape == (7 + 7 + 3 + 2 * 10 + 1,)
        assert flat_obs[agent]["observation"][14:17] == pytest.approx(job)
    finally:
        env.close()
        flat.close()


def test_generated_jobs_give_the_same_run_in_every_in_process_layout():
    """The example (aot2 with generated jobs) under random placements: tasks and jobs conserved at every tick
    (the run checks both), and the same results whatever the layout."""
    sc = load_scenario("examples/dag_jobs")
    runs = [model_part(run_summary(sc, ticks=300, seed=3, policy="random", layout=layout))
            for layout in ("single", "per-node", "groups:3")]
    assert runs[0]["jobs"]["generated"] > 10 and runs[0]["jobs"]["completed"] > 0
    assert runs[0]["totals"]["offloaded"] > 0
    assert runs[1] == runs[0] and runs[2] == runs[0]
