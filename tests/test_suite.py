"""The scenario generator (experiments.suite): suites drawn by seed, byte for byte, from disjoint seed sets;
every regime a valid scenario that runs; overloaded regimes among them; cards for every regime."""

from __future__ import annotations

import csv

import pytest

from agents import BASELINES
from experiments import regimes, suite
from experiments.protocol import EPISODES, REGIMES, SPLITS
from orchestrator.cli import main as orchestrator
from orchestrator.scenario import load_scenario
from orchestrator.scenario.costs import load_ratio
from orchestrator.session import Simulation


def test_the_same_seed_writes_the_same_files(tmp_path):
    suite.main(["--suites", "test", "--count", "4", "--out", str(tmp_path / "a")])
    suite.main(["--suites", "test", "--count", "4", "--out", str(tmp_path / "b")])
    files = sorted(p.name for p in (tmp_path / "a" / "test").iterdir())
    assert len(files) == 5 and "manifest.csv" in files
    for name in files:
        assert (tmp_path / "a" / "test" / name).read_bytes() == (tmp_path / "b" / "test" / name).read_bytes(), name
    assert suite.draw(3_000_001, "test", 1).text() != suite.draw(3_000_002, "test", 1).text()


def test_the_suites_share_no_regime_seed():
    seeds = {split: {r.seed for r in suite.suite(split, 3)} for split in SPLITS}
    for split, drawn in seeds.items():
        assert drawn == set(REGIMES[split].seeds(3))  # regime k is seed k of its split: nothing hand-picked
    assert not (seeds["train"] & seeds["validation"] or seeds["train"] & seeds["test"]
                or seeds["validation"] & seeds["test"])


@pytest.fixture(scope="module")
def test_suite(tmp_path_factory):
    folder = tmp_path_factory.mktemp("suites") / "test"
    drawn = suite.suite("test", suite.SUITES["test"], steps=20)
    return drawn, suite.write(drawn, folder)


@pytest.mark.parametrize("split", ["test", "validation"])
def test_every_regime_of_a_suite_validates_and_runs(split, test_suite, tmp_path, capsys):
    """The whole test suite and the whole validation suite, as the commands draw them by default."""
    drawn, paths = test_suite
    if split == "validation":
        drawn = suite.suite("validation", suite.SUITES["validation"], steps=20)
        paths = suite.write(drawn, tmp_path)
    for regime, path in zip(drawn, paths, strict=True):
        assert orchestrator(["validate", str(path)]) == 0, capsys.readouterr().err
        sc = load_scenario(path)
        assert sc.name == regime.name and len(sc.nodes) == regime.about["nodes"]
        assert load_ratio(sc) == pytest.approx(regime.about["load_ratio"], rel=5e-3)  # 3 digits in the manifest
        with Simulation.inproc(sc) as sim:
            summary = sim.run(5, seed=EPISODES[split].seeds(1)[0])
        assert summary["ticks"] == 5


def test_the_manifest_describes_every_regime(test_suite):
    drawn, paths = test_suite
    with open(paths[0].parent / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["name"] for r in rows] == [p.stem for p in paths] == [r.name for r in drawn]
    # overloaded regimes, where a policy must choose which tasks to lose, and every family
    assert {r["load_class"] for r in rows} == {"overloaded", "busy", "light"}
    assert {r["family"] for r in rows} == set(suite.DISTRIBUTION.families)
    for r in rows:
        assert suite.load_class(float(r["load_ratio"])) == r["load_class"]
        assert float(r["peak_rate"]) <= suite.DISTRIBUTION.peak_rate + 1e-9


def test_the_distribution_covers_what_it_says():
    """Over the first 40 train regimes: every family, every arrival kind, every task kind, drawn and fixed
    deadlines, and every load class."""
    drawn = suite.suite("train", 40, steps=20)
    assert {r.about["family"] for r in drawn} == set(suite.DISTRIBUTION.families)
    assert {r.about["arrival"] for r in drawn} == set(suite.DISTRIBUTION.arrivals)
    kinds = {t["name"] for r in drawn for t in r.scenario["workload"]["tasks"]}
    assert kinds == {k.name for k in suite.DISTRIBUTION.kinds}
    deadlines = [t["deadline"] for r in drawn for t in r.scenario["workload"]["tasks"]]
    assert any(isinstance(d, dict) for d in deadlines) and any(isinstance(d, float) for d in deadlines)
    assert {r.about["load_class"] for r in drawn} == {"light", "busy", "overloaded"}


def test_the_strata_pair_every_family_with_every_load_class():
    d = suite.DISTRIBUTION
    assert {suite.strata(k) for k in range(18)} == {(f, load) for f in d.families for load in d.loads}
    assert [suite.strata(k)[0] for k in range(7)] == [*d.families, d.families[0]]


def test_a_load_beyond_the_rate_cap_scales_the_tasks_up():
    drawn = suite.suite("train", 30, steps=20)
    scaled = [r for r in drawn if r.about["task_scale"] > 1]
    assert scaled  # light tasks on a large network: a rate under the cap cannot load it
    for r in scaled:
        assert r.about["peak_rate"] == pytest.approx(suite.DISTRIBUTION.peak_rate, rel=1e-3)
        assert r.about["load_class"] == suite.load_class(r.about["load_ratio"])


def test_load_classes():
    assert [suite.load_class(x) for x in (0.3, 0.7, 0.71, 1.0, 1.01)] == [
        "light", "light", "busy", "busy", "overloaded"]


def test_cards_for_a_suite(tmp_path):
    suite.main(["--suites", "validation", "--count", "1", "--steps", "20", "--out", str(tmp_path), "--cards",
                "--episodes", "2", "--no-progress"])
    cards = tmp_path / "validation" / "cards"
    rows = regimes.read_rows(next(cards.glob("*.csv")))
    assert len(rows) == 2 * len(BASELINES) and {r["seed"] for r in rows} == {100_000.0, 100_001.0}
    text = (cards / "README.md").read_text()
    assert "## validation-000-" in text and text.count("| own | greedy |") == 1 and "Regime seed 2000000" in text


def test_a_bad_option_is_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        suite.main(["--suites", "dev"])
    assert e.value.code == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_load_ratio_by_hand():
    """Two sources at 0.5 and 0.25 tasks/s of 2e6 cycles (weights 3:1 with 4e6 cycles: 2.5e6 on average) into
    workers of 1e6 + 3e6 + 1e6 cycles/s: (0.5 + 0.25) x 2.5e6 / 5e6 = 0.375."""
    sc = load_scenario({"workload": {"arrival": {"kind": "constant", "rate": 0.5}, "rates": {"b": 0.25},
                                     "tasks": [{"name": "s", "weight": 3, "instructions": 2e6},
                                               {"name": "l", "weight": 1, "instructions": 4e6}]},
                        "topology": {"nodes": [{"id": "a", "client": True, "frequency": 1e6},
                                               {"id": "b", "client": True, "frequency": 3e6},
                                               {"id": "c", "frequency": 1e6}],
                                     "links": [["a", "b"], ["b", "c"]]}})
    assert load_ratio(sc) == pytest.approx(0.375)
