"""The Alibaba cluster-trace importer: jobs become tasks as the paper describes, by hand."""

from __future__ import annotations

import csv

import pytest

from orchestrator.cli import main
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, run_summary, write_scenario
from topologies.alibaba import Conversion, TraceError, convert

# task_name, instance_num, job_name, task_type, status, start_time, end_time, plan_cpu, plan_mem
BATCH = """M1,1,j_1,1,Terminated,100,110,100,0.5
R2_1,1,j_1,1,Terminated,105,120,200,0.25
M1,2,j_2,1,Terminated,130,134,50,1.0
M1,1,j_3,1,Running,140,0,100,1.0
"""


def test_jobs_become_tasks(tmp_path):
    src = tmp_path / "batch_task.csv"
    src.write_text(BATCH)
    rows = convert(src, ["a", "b"], Conversion(frequency=1e6, memory_bytes=1e9))
    assert len(rows) == 2  # j_3 never finished
    j1, j2 = rows
    # j_1: starts at 100 (the origin), runs 100..120 = 20 s, peak 2 cores, peak 0.5 % of 1e9 bytes
    assert j1 == {"time": 0.0, "client": "a", "instructions": 2 * 20 * 1e6, "input_bytes": 5e6, "output_bytes": 5e6,
                  "cpi": 1.0, "deadline": 60.0}
    # j_2: starts 30 s later, 4 s at half a core, 1 % of memory; deadline max(10, 3 x 4)
    assert j2["time"] == 30.0 and j2["client"] == "b"
    assert j2["instructions"] == pytest.approx(0.5 * 4 * 1e6)
    assert j2["input_bytes"] == pytest.approx(1e7) and j2["deadline"] == 12.0


def test_cli_writes_a_trace_the_emulator_runs(tmp_path, capsys):
    src = tmp_path / "batch_task.csv"
    src.write_text(BATCH)
    scenario = write_scenario(tmp_path, {"simulation": {"steps": 60, "policy": "least_queue"},
                                         "workload": {"trace": "trace.csv"},
                                         "topology": {"nodes": [{"id": "a", "client": True, "controller": True,
                                                                 "frequency": 1e6},
                                                                {"id": "b", "client": True, "frequency": 1e6}],
                                                      "links": [["a", "b"]]}})
    (tmp_path / "trace.csv").write_text("time,client,instructions,input_bytes,output_bytes,cpi,deadline\n")
    out = tmp_path / "trace.csv"
    assert main(["trace", "alibaba", str(src), "--scenario", str(scenario), "--out", str(out),
                 "--frequency", "1e6"]) == 0
    assert "2 tasks over 30 s for 2 task sources" in capsys.readouterr().out
    assert len(list(csv.DictReader(out.open()))) == 2
    summary = run_summary(load_scenario(scenario))
    assert summary["totals"]["generated"] == 2


def test_bad_input(tmp_path, capsys):
    src = tmp_path / "bad.csv"
    src.write_text("a,b,c\n")
    with pytest.raises(TraceError, match=r"bad\.csv:1: expected 9 columns"):
        convert(src, ["a"])
    assert main(["trace", "alibaba", str(tmp_path / "none.csv"), "--scenario", "aot1", "--out",
                 str(tmp_path / "o.csv")]) == 2
    assert "none.csv: file not found" in capsys.readouterr().err


@pytest.mark.parametrize(("content", "expected"), [
    (b"\x7fELF\x02\x01\x01\x00\xd0\xff", r"binary\.csv: not a CSV text file \(UnicodeDecodeError\)"),
    (b"t,1,j1,1,Terminated,0,nan,50,1\n", r"binary\.csv:1: start_time, end_time, plan_cpu and plan_mem must be finite"),
    (b"t,1,j1,1,Terminated,0,10,inf,1\n", r"binary\.csv:1: start_time, end_time, plan_cpu and plan_mem must be finite"),
])
def test_a_binary_file_or_non_finite_numbers_are_refused(tmp_path, content, expected):
    """They used to end in a UnicodeDecodeError traceback, or to pass nan into the trace."""
    src = tmp_path / "binary.csv"
    src.write_bytes(content)
    with pytest.raises(TraceError, match=expected):
        convert(src, ["a"])


def test_an_output_that_cannot_be_written_is_one_line(tmp_path, capsys):
    assert main(["trace", "alibaba", str(ROOT / "topologies" / "traces" / "alibaba_batch_task_sample.csv"),
                 "--scenario", "aot1", "--out", str(tmp_path / "missing" / "o.csv")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"orchestrator trace: cannot write {tmp_path / 'missing' / 'o.csv'}: No such file or directory")


def test_the_shipped_sample_converts_and_runs(tmp_path):
    out = tmp_path / "trace.csv"
    sample = ROOT / "topologies" / "traces" / "alibaba_batch_task_sample.csv"
    assert main(["trace", "alibaba", str(sample), "--scenario", "aot2", "--out", str(out)]) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    with sample.open() as fh:
        jobs = {r[2] for r in csv.reader(fh) if r[4] == "Terminated"}
    assert 100 < len(rows) <= len(jobs)
    path = write_scenario(tmp_path, {"topology": {"ether": "ether/network_2_clusters.json"},
                                     "workload": {"trace": str(out)}, "simulation": {"steps": 50}})
    summary = run_summary(load_scenario(path))
    assert summary["totals"]["generated"] == sum(float(r["time"]) < 50 for r in rows)


def test_without_out_the_trace_goes_under_runs_not_in_the_current_directory(tmp_path, monkeypatch, capsys):
    sample = ROOT / "topologies" / "traces" / "alibaba_batch_task_sample.csv"
    monkeypatch.chdir(tmp_path)
    assert main(["trace", "alibaba", str(sample), "--scenario", "aot2", "--limit", "5"]) == 0
    said = capsys.readouterr().out
    written = [p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file()]
    assert len(written) == 1 and written[0].parts[0] == "runs" and written[0].parent.name.startswith("aot2-alibaba-")
    assert f"-> {written[0]} " in said
    with (tmp_path / written[0]).open() as fh:
        assert len(list(csv.DictReader(fh))) == 5
