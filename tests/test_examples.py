"""The example scenarios under topologies/examples/ load, run, and match what docs/scenario.md shows."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "topologies" / "examples"
DOC = ROOT / "docs" / "scenario.md"
YAMLS = sorted(EXAMPLES.glob("*.yaml"))

# A fenced block: the opening fence with its language, the body, the closing fence.
FENCE = re.compile(r"^```(?P<lang>[\w-]*)\n(?P<body>.*?)^```$", re.MULTILINE | re.DOTALL)
FILE_LINE = re.compile(r"# file: (topologies/examples/[\w.-]+\.yaml)\n")
# A block that is not YAML (a CSV file) names its file in an HTML comment on the line before it.
FILE_COMMENT = re.compile(r"<!-- file: (topologies/examples/[\w./-]+) -->")


def doc_blocks() -> list[tuple[str, str]]:
    """(file path, block text) of every block in the doc that names its file."""
    text = DOC.read_text()
    out = []
    for m in FENCE.finditer(text):
        body = m.group("body")
        named = FILE_LINE.match(body) if m.group("lang") == "yaml" else None
        if named:
            out.append((named.group(1), body))
            continue
        previous = text[:m.start()].splitlines()[-1:]
        comment = FILE_COMMENT.fullmatch(previous[0]) if previous else None
        if comment:
            out.append((comment.group(1), body))
    return out


def test_there_are_examples():
    assert len(YAMLS) >= 10


@pytest.mark.parametrize("path", YAMLS, ids=[p.name for p in YAMLS])
def test_example_loads_and_runs(path):
    scenario = load_scenario(path)
    assert scenario.name == path.stem
    with Simulation.inproc(scenario) as sim:
        summary = sim.run(50)
    totals = summary["totals"]
    assert totals["generated"] > 0
    assert totals["generated"] == totals["completed"] + totals["dropped"]["total"] + totals["in_system"]


@pytest.mark.parametrize("path", YAMLS, ids=[p.name for p in YAMLS])
def test_example_names_itself_on_its_first_line(path):
    assert path.read_text().startswith(f"# file: topologies/examples/{path.name}\n")


def test_doc_blocks_are_the_files_byte_for_byte():
    blocks = doc_blocks()
    assert blocks, "no example blocks found in docs/scenario.md"
    for rel, body in blocks:
        path = ROOT / rel
        assert path.exists(), f"docs/scenario.md shows {rel}, which does not exist"
        assert body.encode() == path.read_bytes(), f"docs/scenario.md and {rel} differ"


def test_every_example_is_shown_in_the_doc():
    shown = {rel for rel, _ in doc_blocks()}
    files = {str(p.relative_to(ROOT)) for p in [*YAMLS, *EXAMPLES.glob("*.csv")]}
    assert files <= shown, f"not shown in docs/scenario.md: {sorted(files - shown)}"


def test_the_first_scenario_in_the_doc_validates_as_shown_and_drops_nothing(tmp_path, capsys):
    """docs/scenario.md's minimal scenario: `validate` prints what the doc shows, without a warning, and a run
    completes what the doc says."""
    from orchestrator.cli import main

    section = DOC.read_text().split("## A minimal scenario\n", 1)[1].split("\n## ", 1)[0]
    blocks = {m.group("lang"): m.group("body") for m in FENCE.finditer(section) if not FILE_LINE.match(m.group("body"))}
    path = tmp_path / "my.yaml"
    path.write_text(blocks["yaml"])
    shown = blocks["console"].split("$ orchestrator validate my.yaml\n", 1)[1].split("$ ")[0]
    assert main(["validate", str(path)]) == 0
    assert capsys.readouterr().out == shown
    with Simulation.inproc(load_scenario(path)) as sim:
        totals = sim.run()["totals"]
    assert (totals["completed"], totals["generated"], totals["dropped"]["total"]) == (492, 494, 0)
    assert "It completes 492 of 494 tasks (2 still in the system at the end)" in section
