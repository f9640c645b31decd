"""Regime cards (experiments.regimes) and the bundled variants in which offloading pays."""

from __future__ import annotations

import math

import pytest

from agents import BASELINES, evaluate
from agents.training import write_csv
from experiments import raw, regimes
from experiments.common import make_env
from orchestrator.scenario import load_scenario
from tests.conftest import ROOT


def _stats(completion: dict[str, float], score: dict[str, float], dropped: dict[str, float]) -> dict:
    out = {}
    for b in BASELINES:
        out[b, "completion_ratio"] = (completion[b], 0.0)
        out[b, "penalised_response_time"] = (score[b], 0.0)
        out[b, "dropped"] = (dropped[b], 0.0)
    return out


def test_the_verdict_names_the_dominant_heuristic_or_the_split():
    names = list(BASELINES)
    completion = dict.fromkeys(names, 50.0) | {"local": 20.0, "greedy": 90.0}
    score = dict.fromkeys(names, 40.0) | {"greedy": 10.0}
    dropped = dict.fromkeys(names, 100.0) | {"greedy": 5.0}
    best = {"completion_ratio": "greedy", "penalised_response_time": "greedy", "dropped": "greedy"}
    assert regimes.verdict(_stats(completion, score, dropped), best) == (
        "*offloading pays (+70.0 points over local); greedy dominates*")
    best["penalised_response_time"] = "random"
    assert regimes.verdict(_stats(completion, score, dropped), best) == (
        "*offloading pays (+70.0 points over local); no heuristic dominates: most completed greedy, best score "
        "random, fewest dropped greedy*")
    best = dict.fromkeys(best, "local")
    assert regimes.verdict(_stats(completion, score, dropped), best).startswith("*keeping tasks local is best")


def test_in_a_scenario_of_jobs_the_verdict_judges_the_jobs_beside_the_tasks():
    """Jobs done and the job score decide the second half: here greedy completes most tasks, but round_robin
    completes most jobs (beyond the CIs) and drift_plus_penalty has the best job score."""
    names = list(BASELINES)
    stats = _stats(dict.fromkeys(names, 50.0) | {"local": 20.0, "greedy": 90.0}, dict.fromkeys(names, 40.0),
                   dict.fromkeys(names, 100.0))
    jobs = dict.fromkeys(names, 40.0) | {"local": 30.0, "round_robin": 60.0}
    for b in names:
        stats[b, "job_completion_ratio"] = (jobs[b], 5.0)
    best = {"completion_ratio": "greedy", "penalised_response_time": "greedy", "dropped": "greedy",
            "job_completion_ratio": "round_robin", "penalised_makespan": "drift_plus_penalty",
            "jobs_missed": "round_robin"}
    assert regimes.verdict(stats, best) == (
        "*tasks: offloading pays (+70.0 points over local); greedy dominates. Jobs: offloading pays (+30.0 points "
        "over local); no heuristic dominates: most jobs done round_robin, best job score drift_plus_penalty*")
    stats["round_robin", "job_completion_ratio"] = (40.0, 5.0)  # +10 points, within the two CIs of 5
    best["penalised_makespan"] = "round_robin"
    assert regimes.verdict(stats, best).endswith(
        "Jobs: offloading barely matters (+10.0 points over local, within the 95% CIs); round_robin dominates*")
    best["job_completion_ratio"] = "local"
    assert "Jobs: keeping tasks local is best; no heuristic dominates" in regimes.verdict(stats, best)


def test_the_command_writes_one_csv_per_family_and_the_cards(tmp_path):
    regimes.main(["--families", "compute", "--episodes", "2", "--max-steps", "30", "--out", str(tmp_path),
                  "--no-progress"])
    rows = regimes.read_rows(tmp_path / "compute.csv")
    assert len(rows) == 2 * len(BASELINES) * 2  # two rates, every baseline, two episodes
    assert {r["lambda"] for r in rows} == {0.03, 0.06} and {r["episode"] for r in rows} == {0, 1}
    typed = raw.read([tmp_path / "compute.csv"])  # the raw schema experiments.report reads
    assert {(r["suite"], r["split"], r["train_seed"]) for r in typed} == {("bundled", "validation", None)}
    assert {r["regime"] for r in typed} == {"aot3_compute-lam0.03", "aot3_compute-lam0.06"}
    card = (tmp_path / "README.md").read_text()
    assert "## compute: `aot3_compute`" in card and card.count("| 0.06 | greedy |") == 1
    (tmp_path / "README.md").unlink()
    regimes.main(["--families", "compute", "--out", str(tmp_path), "--cards-only"])
    assert (tmp_path / "README.md").read_text() == card  # the cards are a function of the CSV alone


def test_cards_only_without_the_csv_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        regimes.main(["--families", "wired", "--out", str(tmp_path), "--cards-only"])
    assert e.value.code == 2
    assert capsys.readouterr().err.strip().endswith("wired.csv: not found; run without --cards-only first")


def test_every_family_is_a_bundled_scenario_with_two_rates():
    """The paper's families on aot3's 28 nodes; a feature's family on its example, its card showing its metrics."""
    features = {"dag": (19, regimes.JOB_COLUMNS), "mobile": (9, regimes.DROP_COLUMNS)}
    for family in regimes.FAMILIES:
        env = make_env(family.scenario, None, 5)
        assert (len(env.scenario.nodes), family.columns) == features.get(family.name, (28, ()))
        assert len(family.lambdas) == 2
        env.close()


@pytest.mark.parametrize("family", ["compute", "urgent", "wired"])
def test_each_variant_family_comes_at_every_size_of_the_paper(family):
    """RQ2 adds clusters: aot1..aot4's networks with the family's tasks and links, and nothing else changed."""
    three = load_scenario(f"aot3_{family}")
    for k, nodes in ((1, 12), (2, 19), (4, 31)):
        sc = load_scenario(f"aot{k}_{family}")
        assert len(sc.nodes) == nodes == len(load_scenario(f"aot{k}").nodes)
        assert sc.name == f"aot{k}_{family}"
        own = dict.fromkeys(("name", "source", "extra", "nodes", "links", "workload"))
        assert sc.to_dict() | own == three.to_dict() | own
        assert sc.workload.task_types == three.workload.task_types and sc.workload.arrival == three.workload.arrival


@pytest.mark.parametrize("scenario,lam", [("aot3_compute", 0.03), ("aot3_wired", 0.1), ("aot3_urgent", 0.04)])
def test_in_the_variants_offloading_pays(scenario, lam):
    """The variants' reason to exist: a heuristic that offloads completes far more than keeping tasks local."""
    env = make_env(scenario, lam, 300)
    local, greedy = (evaluate(env, BASELINES[b](0), 1)[0]["completion_ratio"] for b in ("local", "greedy"))
    env.close()
    assert greedy > local + 0.2, (local, greedy)


def test_in_aot3_urgent_the_rule_that_completes_most_is_not_the_fastest():
    """aot3_urgent's reason to exist: keeping batch work at home (local_first) completes more tasks than
    greedy, which answers faster and has the better score (its card: 87.2 against 80.5 %, 58.5 against
    49.4 s at lambda 0.04, 3 episodes; here one episode of the card's)."""
    env = make_env("aot3_urgent", 0.04, None)
    first, greedy = (evaluate(env, BASELINES[b](0), 1)[0] for b in ("local_first", "greedy"))
    env.close()
    assert first["completion_ratio"] > greedy["completion_ratio"]
    assert greedy["penalised_response_time"] < first["penalised_response_time"]


def test_a_feature_family_card_shows_its_own_columns_and_is_rebuilt_from_its_csv(tmp_path):
    """dag's card has the job columns, mobile's the drops by cause (link broken among them); both CSVs keep
    the raw schema, the job columns empty where the scenario has no jobs."""
    regimes.main(["--families", "dag", "mobile", "--episodes", "1", "--max-steps", "60", "--out", str(tmp_path),
                  "--no-progress"])
    card = (tmp_path / "README.md").read_text()
    for family in ("dag", "mobile"):
        columns = next(f for f in regimes.FAMILIES if f.name == family).columns
        header = next(line for line in card.splitlines() if line.startswith("| λ |") and columns[0][1] in line)
        assert header.endswith(" | ".join(title for _, title, _, _ in columns) + " |")
    verdicts = [line for line in card.splitlines() if line.startswith("| 0.0") and "| | *" in line]
    assert len(verdicts) == 2 and all("*tasks: " in v and ". Jobs: " in v for v in verdicts)  # dag's two rates
    assert sum(". Jobs: " in line for line in card.splitlines()) == 2  # mobile's verdicts judge tasks alone
    dag, mobile = (raw.read([tmp_path / f"{name}.csv"]) for name in ("dag", "mobile"))
    assert all(r["jobs"] > 0 and 0 <= r["job_completion_ratio"] <= 1 and r["jobs_completed"] + r["jobs_missed"]
               <= r["jobs"] for r in dag)
    assert all(math.isnan(r[c]) for r in mobile for c in raw.JOBS)
    assert all(r["dropped_link_broken"] >= 0 for r in regimes.read_rows(tmp_path / "mobile.csv"))
    (tmp_path / "README.md").unlink()
    regimes.main(["--families", "dag", "mobile", "--out", str(tmp_path), "--cards-only"])
    assert (tmp_path / "README.md").read_text() == card


def test_the_raw_rows_of_scenarios_with_and_without_jobs_share_one_file(tmp_path):
    """One CSV may hold both (a suite, a report's inputs): the job columns are in every row, empty where the
    scenario has no jobs; a file written before them reads as if they were empty."""
    rows = []
    for scenario in ("aot1", "examples/dag_jobs"):
        env = make_env(scenario, None, 40)
        rows += [raw.row("local", None, scenario, scenario, r) for r in evaluate(env, BASELINES["local"](0), 1)]
        env.close()
    assert rows[0]["jobs"] == "" and rows[1]["jobs"] > 0
    write_csv(tmp_path / "both.csv", rows)
    plain, jobs = raw.read([tmp_path / "both.csv"])
    assert all(math.isnan(plain[c]) for c in raw.JOBS) and jobs["jobs"] == rows[1]["jobs"]
    assert jobs["penalised_makespan"] == rows[1]["penalised_makespan"]
    committed = raw.read([ROOT / "docs" / "regimes" / "compute.csv"])
    assert committed and all(math.isnan(r[c]) for r in committed for c in raw.JOBS)
