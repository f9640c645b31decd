"""A study's grid on a local Ray (2 CPUs): the same files, with the same content, as a local run, and no Ray
process left once the command has returned. Needs Ray (the "sweep" extra, also in "test")."""

from __future__ import annotations

import csv
import os
import queue
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import psutil
import ray

from experiments import evaluate, rq1, train
from tests.launcher import TIMEOUT, assert_all_gone

GRID = ["--quick", "--train-episodes", "1", "--eval-episodes", "2", "--max-steps", "25", "--no-progress",
        "--scenario", "aot1", "--lambdas", "0.1", "0.3", "--seed", "0", "1", "--agents", "ddqn", "ppo", "random"]
RUNS = 2 * (2 * 2 + 1)  # lambdas x (seeds x learners + the baseline, evaluated once)
WALL_CLOCK = {"wall_s"}  # the only columns that may differ between two runs of the same seeds


def processes_with(marker: str) -> list[psutil.Process]:
    """Processes whose environment holds ``marker``: the command's and everything Ray started for it."""
    found = []
    for p in psutil.process_iter():
        try:
            if p.environ().get("ZENOHEDGE_TEST_RAY") == marker:
                found.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    return found


def csv_without_wall_clock(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in WALL_CLOCK} for row in csv.DictReader(f)]


def test_rq1_on_a_local_ray_writes_what_a_local_run_writes_and_leaves_no_process(tmp_path):
    rq1.main([*GRID, "--out", str(tmp_path / "local")])

    marker = uuid.uuid4().hex
    proc = subprocess.Popen([sys.executable, "-m", "experiments.rq1", *GRID, "--ray", "--ray-cpus", "2",
                             "--out", str(tmp_path / "ray")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "ZENOHEDGE_TEST_RAY": marker, "COLUMNS": "200"})
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()
    out: list[str] = []
    err: list[str] = []

    def read_stdout() -> None:
        for line in proc.stdout:
            out.append(line)
            lines.put(line)

    threading.Thread(target=read_stdout, daemon=True).start()
    threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True).start()
    try:
        deadline = time.monotonic() + TIMEOUT
        while not (line := lines.get(timeout=max(0.0, deadline - time.monotonic()))).startswith(f"[1/{RUNS}]"):
            pass
        # Ray is running: its processes (GCS, raylet, workers) carry the command's environment
        during = processes_with(marker)
        assert len(during) > 2, (line, [p.name() for p in during])
        assert proc.wait(timeout=TIMEOUT) == 0, "".join(err)
    except queue.Empty:
        raise AssertionError(f"no run finished within {TIMEOUT} s; stdout {''.join(out)}\n"
                             f"stderr {''.join(err)}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
    assert_all_gone(during + processes_with(marker), timeout=TIMEOUT)
    assert not processes_with(marker)
    assert sum(line.endswith(" done\n") for line in out) == RUNS

    local = sorted(p.relative_to(tmp_path / "local") for p in (tmp_path / "local").rglob("*") if p.is_file())
    remote = sorted(p.relative_to(tmp_path / "ray") for p in (tmp_path / "ray").rglob("*") if p.is_file())
    assert local == remote
    assert len([p for p in local if p.suffix == ".pt"]) == 2 * 2 * 2  # lambdas x seeds x learners
    for name in local:
        if name.name == "timings.csv":  # nothing but wall-clock times
            continue
        a, b = tmp_path / "local" / name, tmp_path / "ray" / name
        if name.suffix == ".csv":
            assert csv_without_wall_clock(a) == csv_without_wall_clock(b), name
        else:  # checkpoints, config.json, marl_eval.json, the figure
            assert a.read_bytes() == b.read_bytes(), name
    rows = csv_without_wall_clock(tmp_path / "ray" / "results.csv")
    assert {(r["train_seed"], r["lambda"], r["agent"]) for r in rows} == {
        (s, lam, a) for s in ("0", "1") for lam in ("0.1", "0.3") for a in ("ddqn", "ppo", "random")
        if a != "random" or s == "0"}  # a baseline is evaluated once
    ddqn0, ddqn1 = ((tmp_path / "ray" / "checkpoints" / "aot1-lam0.1" / f"seed{s}" / "ddqn.pt").read_bytes()
                    for s in (0, 1))
    assert ddqn0 != ddqn1  # the seeds are different runs


def test_evaluate_on_ray_gives_the_episodes_of_a_local_evaluation(tmp_path):
    train.main(["ppo", "--scenario", "aot1", "--episodes", "1", "--max-steps", "25", "--out", str(tmp_path),
                "--no-progress"])
    common = [str(tmp_path / "ppo.pt"), "--scenario", "aot1", "--lam", "0.3", "--episodes", "3", "--max-steps", "25",
              "--no-progress"]
    evaluate.main([*common, "--csv", str(tmp_path / "local.csv")])
    evaluate.main([*common, "--csv", str(tmp_path / "ray.csv"), "--ray", "--ray-cpus", "2"])
    local, remote = csv_without_wall_clock(tmp_path / "local.csv"), csv_without_wall_clock(tmp_path / "ray.csv")
    assert [r["episode"] for r in remote] == ["0", "1", "2"] and remote == local
    assert not ray.is_initialized()
