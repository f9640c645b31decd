"""experiments.report rebuilds its tables from the raw per-episode CSVs: the whole pipeline on a small test
suite (suite, bound and baselines, report), a table that follows an edited row, a learner against every
baseline and regime by regime, the learning curves of real training runs, the wall-clock table, and bad input
in one line."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from experiments import bound, curves, evaluate, generalist, raw, report, suite
from tests.conftest import ROOT

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    """2 test regimes, every baseline and the bound on 2 test episodes of 30 steps each."""
    folder = tmp_path_factory.mktemp("pipeline")
    suite.write(suite.suite("test", 2, steps=30), folder / "test")
    bound.main(["--suite", str(folder / "test"), "--episodes", "2", "--out", str(folder / "raw.csv"),
                "--no-progress"])
    return folder


def rows_of(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write(path: Path, rows: list[dict[str, str]]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def cell(text: str, policy: str, column: int) -> str:
    """A cell of the aggregate table: the row of ``policy``, the ``column``-th (0: the policy)."""
    line = next(line for line in text.splitlines() if line.startswith(f"| `{policy}` | ") and "[" in line)
    return line.strip("|").split("|")[column].strip()


def expected_completion(rows: list[dict[str, str]], policy: str) -> float:
    """The mean over regimes of each regime's mean completion, in %: what the table must say."""
    regimes = sorted({r["regime"] for r in rows})
    return 100 * float(np.mean([np.mean([float(r["completion_ratio"]) for r in rows
                                         if r["policy"] == policy and r["regime"] == g]) for g in regimes]))


def build(folder: Path, *csvs: Path, reps: str = "200") -> str:
    out = folder / "page" / "results.md"
    report.main([*map(str, csvs), "--out", str(out), "--reps", reps, "--no-progress"])
    return out.read_text()


def test_the_tables_are_rebuilt_from_the_csv_and_follow_an_edited_row(pipeline, tmp_path):
    rows = rows_of(pipeline / "raw.csv")
    assert {r["split"] for r in rows} == {"test"} and {r["suite"] for r in rows} == {"test"}
    text = build(tmp_path, pipeline / "raw.csv")
    assert "## `test` suite, test episodes, 30 steps" in text and "(200000–200001)" in text
    for policy in ("local", "greedy", "threshold", "drift_plus_penalty"):
        got = float(cell(text, policy, 5).split()[0])
        assert got == pytest.approx(expected_completion(rows, policy), abs=0.05), policy
    assert cell(text, "local", 2).startswith("0.000")  # local is 0 on the normalised score, by definition
    for name in ("profile", "aggregates", "improvement"):
        assert (tmp_path / "page" / "figures" / f"benchmark-test-test-30-{name}.png").stat().st_size > 1000
    assert text == build(tmp_path, pipeline / "raw.csv")  # the same rows give the same page

    # greedy completes every task of one episode more: its completion cell moves to the new mean
    edited = [dict(r) for r in rows]
    target = next(r for r in edited if r["policy"] == "greedy" and int(r["generated"]) > 0)
    target["completed"], target["completion_ratio"] = target["generated"], "1.0"
    write(tmp_path / "edited.csv", edited)
    changed = build(tmp_path, tmp_path / "edited.csv")
    assert cell(changed, "greedy", 5) != cell(text, "greedy", 5)
    assert float(cell(changed, "greedy", 5).split()[0]) == pytest.approx(expected_completion(edited, "greedy"),
                                                                         abs=0.05)
    assert cell(changed, "local", 5) == cell(text, "local", 5)


def test_a_learner_with_several_runs_joins_the_bound_of_its_episodes(pipeline, tmp_path):
    rows = rows_of(pipeline / "raw.csv")
    learner = [{**r, "policy": "learner", "train_seed": str(s), "local": "", "bound": "", "bound_kind": "",
                "normalised_score": ""} for s in (0, 1) for r in rows if r["policy"] == "greedy"]
    write(tmp_path / "learner.csv", learner)
    text = build(tmp_path, pipeline / "raw.csv", tmp_path / "learner.csv")
    assert cell(text, "learner", 1) == "2"  # two runs
    # the normalised score from the joined bound: greedy's episodes, so greedy's IQM
    assert cell(text, "learner", 2).split()[0] == cell(text, "greedy", 2).split()[0]
    # a copy of greedy against every baseline: P = 1/2 against greedy, no paired difference, every episode a tie
    against = text.split("### `learner` against every baseline")[1].split("###")[0]
    line = next(line for line in against.splitlines() if line.startswith("| `greedy` |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    episodes = len({(r["regime"], r["seed"]) for r in rows})
    assert cells[1].startswith("0.500") and cells[2] == "overlap"
    assert cells[3] == "0.0 [0.0, 0.0]" and cells[4] == f"0/{episodes}/0"
    assert sum(line.startswith("| `") for line in against.splitlines()) == len({r["policy"] for r in rows})
    # regime by regime: the best baseline's completion there, from the rows
    by_regime = text.split("### `learner` regime by regime")[1].split("###")[0]
    for regime in sorted({r["regime"] for r in rows}):
        best = max(np.mean([float(r["completion_ratio"]) for r in rows if r["regime"] == regime
                            and r["policy"] == p]) for p in {r["policy"] for r in rows})
        line = next(line for line in by_regime.splitlines() if line.startswith(f"| {regime} |"))
        assert float(line.split("|")[4].split()[-1]) == pytest.approx(100 * best, abs=0.05)
    scored = report.with_scores(raw.read([pipeline / "raw.csv", tmp_path / "learner.csv"]))
    for r in scored:
        if r["policy"] == "learner" and r["bound"] > r["local"]:
            assert r["normalised_score"] == pytest.approx(
                (r["completed"] - r["local"]) / (r["bound"] - r["local"]))


def test_bad_input_is_one_line(pipeline, tmp_path, capsys):
    rows = rows_of(pipeline / "raw.csv")
    cases = {
        "no_column.csv": [{k: v for k, v in r.items() if k != "completed"} for r in rows],
        "not_a_number.csv": [{**r, "completed": "many" if i == 3 else r["completed"]} for i, r in enumerate(rows)],
        "missing_episode.csv": [r for i, r in enumerate(rows) if not (r["policy"] == "random" and i > 20)],
    }
    expected = {"no_column.csv": "no column completed", "not_a_number.csv": "not_a_number.csv:5: column completed",
                "missing_episode.csv": "random (training seed None) lacks"}
    for name, bad in cases.items():
        write(tmp_path / name, bad)
        with pytest.raises(SystemExit) as e:
            build(tmp_path, tmp_path / name)
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1 and expected[name] in err, err
    with pytest.raises(SystemExit):
        build(tmp_path, tmp_path / "nowhere.csv")
    assert re.search(r"nowhere.csv: No such file", capsys.readouterr().err)


def test_evaluate_writes_the_rows_the_bound_writes(pipeline, tmp_path):
    """experiments.evaluate on a suite's regime and seed set gives the bound command's rows for that policy:
    one schema, the same episodes."""
    regime = sorted((pipeline / "test").glob("*.yaml"))[0]
    evaluate.main(["greedy", "--scenario", str(regime), "--split", "test", "--episodes", "2",
                   "--csv", str(tmp_path / "greedy.csv"), "--no-progress"])
    columns = (*raw.KEYS, *raw.METRICS)
    mine = [{k: r[k] for k in columns} for r in raw.read([tmp_path / "greedy.csv"])]
    theirs = [{k: r[k] for k in columns} for r in raw.read([pipeline / "raw.csv"])
              if r["policy"] == "greedy" and r["regime"] == regime.stem]
    assert len(mine) == 2 and [r["seed"] for r in mine] == [200_000, 200_001]
    assert str(mine) == str(theirs)  # str: NaN equals NaN


def test_the_committed_page_is_what_the_committed_rows_give(tmp_path, monkeypatch):
    """docs/benchmark-results.md is python -m experiments.report's output on docs/benchmark-data/, unedited."""
    monkeypatch.chdir(ROOT)
    report.main(["--out", str(tmp_path / "benchmark-results.md"), "--no-progress"])
    assert (tmp_path / "benchmark-results.md").read_text() == (ROOT / report.OUT).read_text()


@pytest.fixture(scope="module")
def training(tmp_path_factory) -> list[Path]:
    """Two real generalist training runs (seeds 0 and 1) of 4 episodes of 20 steps, 2 at a time, a checkpoint
    every 2."""
    folder = tmp_path_factory.mktemp("training")
    suite.write(suite.suite("train", 2, steps=20), folder / "train")
    suite.write(suite.suite("validation", 1, steps=20), folder / "validation")
    runs = []
    for seed in (0, 1):
        runs.append(folder / f"seed-{seed}")
        generalist.main(["train", "--suite", str(folder / "train"), "--validation", str(folder / "validation"),
                         "--episodes", "4", "--checkpoint-every", "2", "--envs", "2", "--set", "rollout_steps=16",
                         "--seed", str(seed), "--out", str(runs[-1]), "--no-progress"])
    return runs


def test_the_settings_table_chooses_the_best_validation_candidate(pipeline, training, tmp_path, capsys):
    """Candidates are folders of training runs; the table says what each changed from default/ (read from the
    runs' config.json), and chooses the highest mean best.pt validation completion."""
    settings = tmp_path / "settings"
    shifts = {"default": 0.0, "price": 0.1, "wider": -0.1}  # completions moved so that "price" must win
    for name, shift in shifts.items():
        for run in training:
            folder = settings / name / run.name
            folder.mkdir(parents=True)
            config = json.loads((run / "config.json").read_text())
            config["congestion_price"] += 1.0 if name == "price" else 0.0
            config["config"]["hidden"] = [256, 256] if name == "wider" else config["config"]["hidden"]
            (folder / "config.json").write_text(json.dumps(config))
            rows = rows_of(run / "validation.csv")
            write(folder / "validation.csv", [{**r, "completion_ratio": str(float(r["completion_ratio"]) + shift)}
                                              for r in rows])
    out = tmp_path / "page.md"
    report.main([str(pipeline / "raw.csv"), "--settings", str(settings), "--out", str(out), "--reps", "50",
                 "--no-progress"])
    table = out.read_text().split("## Settings chosen on validation")[1].split("##")[0]
    assert "Chosen: **price**." in table
    lines = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert [line.split("|")[1].strip() for line in lines] == ["**price**", "default", "wider"]
    base = json.loads((training[0] / "config.json").read_text())["congestion_price"]
    assert f"`congestion_price` {base + 1.0} ({base})" in lines[0]
    assert "`config.hidden` [256, 256]" in lines[2] and lines[1].split("|")[2].strip() == "—"
    best = np.mean([max(float(r["completion_ratio"]) for r in rows_of(run / "validation.csv")) for run in training])
    assert float(lines[1].split("|")[4]) == pytest.approx(100 * best, abs=0.005)
    mixed = settings / "wider" / training[0].name / "config.json"
    config = json.loads(mixed.read_text())
    mixed.write_text(json.dumps({**config, "congestion_price": config["congestion_price"] + 2.0}))
    with pytest.raises(SystemExit):
        report.main([str(pipeline / "raw.csv"), "--settings", str(settings), "--out", str(out), "--no-progress"])
    assert "its runs differ in more than the training seed" in capsys.readouterr().err
    (settings / "wider").rename(tmp_path / "wider")
    (settings / "default").rename(settings / "start")
    with pytest.raises(SystemExit):
        report.main([str(pipeline / "raw.csv"), "--settings", str(settings), "--out", str(out), "--no-progress"])
    assert "expected default/ and every candidate with seed-*/ training runs" in capsys.readouterr().err


def test_learning_curves_and_wall_clock_follow_their_csv(pipeline, training, tmp_path, capsys):
    timing = tmp_path / "protocol.csv"
    write(timing, [{"step": "suites", "command": "python -m experiments.suite", "processes": "1", "wall_s": "90",
                    "cpu_s": "", "note": "all three"},
                   {"step": "train seed 0", "command": "python -m experiments.generalist train", "processes": "2",
                    "wall_s": "600", "cpu_s": "330", "note": ""}])
    out = tmp_path / "page" / "results.md"
    report.main([str(pipeline / "raw.csv"), "--training", *map(str, training), "--wall-clock", str(timing),
                 "--out", str(out), "--reps", "200", "--no-progress"])
    text = out.read_text()
    assert (tmp_path / "page" / "figures" / "generalist-learning-curves.png").stat().st_size > 1000
    assert "2 training runs (seeds 0, 1)" in text and "4 training episodes each" in text
    checks = [rows_of(run / "validation.csv") for run in training]
    table = text.split("## Learning curves of the generalist")[1].split("##")[0]
    lines = [line for line in table.splitlines() if re.match(r"\| \d+ \|", line)]
    assert [int(line.split("|")[1]) for line in lines] == [2, 4]
    chosen = 0
    for k, line in enumerate(lines):
        cells = [c.strip() for c in line.strip("|").split("|")]
        frames = np.mean([float(c[k]["frames"]) for c in checks])
        completion = np.mean([float(c[k]["completion_ratio"]) for c in checks])
        assert cells[1] == f"{frames:,.0f}" and float(cells[2].split()[0]) == pytest.approx(100 * completion, abs=0.05)
        chosen += int(cells[5])
    assert chosen == 2  # one best.pt per run
    assert "| suites | `python -m experiments.suite` | 1 | 1.5 | — | all three |" in text
    assert "| train seed 0 | `python -m experiments.generalist train` | 2 | 10.0 | 5.5 |  |" in text

    # the training curve: the seeds' means of their episodes binned by frames, the first bin from the logs
    runs = curves.read(training)
    x, cis = curves.binned(runs, "completion_ratio", reps=50, bins=1)
    last = min(float(rows_of(run / "train.csv")[-1]["frames"]) for run in training)
    assert x.tolist() == [last / 2] and cis[0].point == pytest.approx(np.mean(
        [np.mean([float(r["completion_ratio"]) for r in rows_of(run / "train.csv") if float(r["frames"]) <= last])
         for run in training]))

    bad = {"no_frames": ("train.csv", "frames", "no column frames"),
           "not_a_number": ("validation.csv", "completion_ratio", "validation.csv:2: column completion_ratio")}
    for name, (file, column, expected) in bad.items():
        run = tmp_path / name / "seed-0"
        run.mkdir(parents=True)
        (run / "config.json").write_text((training[0] / "config.json").read_text())
        for f in ("train.csv", "validation.csv"):
            rows = rows_of(training[0] / f)
            if f == file:
                rows = ([{k: v for k, v in r.items() if k != column} for r in rows] if name == "no_frames"
                        else [{**r, column: "high"} for r in rows])
            write(run / f, rows)
        with pytest.raises(SystemExit) as e:
            report.main([str(pipeline / "raw.csv"), "--training", str(run), "--out", str(out), "--no-progress"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1 and expected in err, err
    write(timing, [{"step": "suites", "command": "x", "processes": "1", "wall_s": "soon", "cpu_s": "", "note": ""}])
    with pytest.raises(SystemExit) as e:
        report.main([str(pipeline / "raw.csv"), "--wall-clock", str(timing), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "protocol.csv:2: wall_s and cpu_s: expected numbers" in err


def test_rows_with_jobs_add_the_job_columns_over_their_regimes_alone(tmp_path):
    """The committed cards' rows of dag (jobs) and compute (none) in one group: the aggregate and paired tables
    gain jobs done and the penalised makespan, computed over dag's regimes alone; compute alone has no job column."""
    compute = rows_of(ROOT / "docs" / "regimes" / "compute.csv")
    policies = {r["policy"] for r in compute}
    dag = [r for r in rows_of(ROOT / "docs" / "regimes" / "dag.csv") if r["policy"] in policies]
    learner = [{**r, "policy": "learner", "train_seed": str(s)} for s in (0, 1) for r in dag + compute
               if r["policy"] == "greedy"]
    for name, rows in (("compute.csv", compute), ("dag.csv", dag), ("learner.csv", learner)):
        write(tmp_path / name, rows)
    assert "jobs done" not in build(tmp_path, tmp_path / "compute.csv")
    text = build(tmp_path, tmp_path / "compute.csv", tmp_path / "dag.csv", tmp_path / "learner.csv")
    assert "| completion % | penalised response [s] | jobs done % | penalised makespan [s] | interval over |" in text
    assert "the same over the regimes of jobs alone." in text
    for policy in policies:
        for column, metric, scale in ((7, "job_completion_ratio", 100), (8, "penalised_makespan", 1)):
            regimes = sorted({r["regime"] for r in dag})
            expected = scale * np.mean([np.mean([float(r[metric]) for r in dag if r["policy"] == policy
                                                 and r["regime"] == g]) for g in regimes])
            assert float(cell(text, policy, column).split()[0]) == pytest.approx(expected, abs=0.05), policy
        assert float(cell(text, policy, 5).split()[0]) == pytest.approx(
            expected_completion(compute + dag, policy), abs=0.05)  # the tasks over every regime
    episodes = len({(r["regime"], r["seed"]) for r in compute + dag})
    jobs = len({(r["regime"], r["seed"]) for r in dag})
    for title in ("### Every policy against", "### `learner` against every baseline"):
        table = text.split(title)[1].split("###")[0]
        assert "| Δ jobs done [points] | W/T/L | Δ penalised makespan [s] | W/T/L |" in table
        for line in (line for line in table.splitlines() if line.startswith("| `")):
            cells = [c.strip() for c in line.strip("|").split("|")]
            counts = [sum(map(int, c.split("/"))) for c in cells if re.fullmatch(r"\d+/\d+/\d+", c)]
            assert counts == [episodes, episodes, jobs, jobs], line
    against = text.split("### `learner` against every baseline")[1].split("###")[0]
    greedy = [c.strip() for c in next(line for line in against.splitlines()
                                      if line.startswith("| `greedy` |")).strip("|").split("|")]
    assert greedy[7:11] == ["0.0 [0.0, 0.0]", f"0/{jobs}/0", "0.0 [0.0, 0.0]", f"0/{jobs}/0"]
    # regime by regime: the job columns on the regimes of jobs (the best baseline's mean there), — elsewhere
    by_regime = text.split("### `learner` regime by regime")[1].split("###")[0]
    assert "| jobs done % | best baseline | Δ [points] | penalised makespan [s] | best baseline | Δ [s] |" in by_regime
    for regime in sorted({r["regime"] for r in compute + dag}):
        cells = [c.strip() for c in next(line for line in by_regime.splitlines()
                                         if line.startswith(f"| {regime} |")).strip("|").split("|")]
        if regime not in {r["regime"] for r in dag}:
            assert cells[8:] == ["—"] * 6, regime
            continue
        best = max(np.mean([float(r["job_completion_ratio"]) for r in dag if r["regime"] == regime
                            and r["policy"] == q]) for q in policies)
        assert float(cells[9].split()[-1]) == pytest.approx(100 * best, abs=0.05), regime
        assert float(cells[8]) <= float(cells[9].split()[-1]) + 0.05  # a copy of greedy: never above the best
    assert f"On the {len({r['regime'] for r in dag})} regimes of jobs it finishes fewer jobs on" in by_regime
