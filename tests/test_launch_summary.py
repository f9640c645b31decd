"""What `orchestrator launch` prints: the node-side policy in the header and the table, energy in units
that read (split into compute, idle and radio), and why nothing is offloaded under policy local."""

from __future__ import annotations

import json

import pytest

from orchestrator.cli import main
from orchestrator.units import si


def launch(tmp_path, capsys, *args: str) -> tuple[str, str, dict]:
    out = tmp_path / "run"
    assert main(["launch", "aot1", "--transport", "inproc", "--steps", "120", "--out", str(out), *args]) == 0
    printed = capsys.readouterr()
    return printed.out, printed.err, json.loads((out / "summary.json").read_text())


def row(text: str, label: str) -> str:
    """The value column of the table row whose label is ``label``."""
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("│ ").split("│")]
        if len(cells) == 2 and cells[0] == label:
            return cells[1]
    raise AssertionError(f"no row {label!r} in:\n{text}")


def test_policy_local_is_named_and_explained(tmp_path, capsys):
    out, err, summary = launch(tmp_path, capsys)
    assert summary["policy"] == ["local"] and summary["totals"]["offloaded"] == 0
    assert "; seed 0; policy local" in " ".join(err.split())  # the header (wrapped at the terminal's width)
    assert "aot1 — 120 ticks, seed 0, policy local" in out
    assert out.splitlines()[-1] == ("policy local keeps every task on its own node: pass --policy least_queue to "
                                    "offload")
    energy = summary["energy_j"]
    assert energy["total"] < 1e-3  # compute alone: microjoules, which used to read 2.234e-05 J
    assert row(out, "energy") == si(energy["total"], "J") and row(out, "energy").endswith(" µJ")
    assert row(out, "compute") == si(energy["compute"], "J")
    assert row(out, "radio") == "0 J" and row(out, "idle") == "0 J"
    assert "e-0" not in out


def test_an_offloading_policy_is_named_and_its_energy_split(tmp_path, capsys):
    out, err, summary = launch(tmp_path, capsys, "--policy", "least_queue")
    assert "; seed 0; policy least_queue" in " ".join(err.split())
    assert "seed 0, policy least_queue" in out and "keeps every task" not in out
    energy = summary["energy_j"]
    assert row(out, "energy") == si(energy["total"], "J")
    assert row(out, "radio") == si(energy["transmit"], "J")
    assert row(out, "compute") == si(energy["compute"], "J") and row(out, "compute").endswith(" mJ")
    dropped = summary["totals"]["dropped"]
    assert row(out, "dropped").startswith(f"{dropped['total']}  (")
    assert row(out, "expired") == str(dropped["expired"]) and row(out, "queue full") == str(dropped["queue_full"])


def test_json_output_stays_json(tmp_path, capsys):
    out, _, summary = launch(tmp_path, capsys, "--json")
    printed = json.loads(out)
    printed.pop("run")
    summary.pop("run")
    assert printed == summary


@pytest.mark.parametrize(("policy", "text"), [("local", "policy local"), (["greedy", "local"],
                                                                          "policies greedy, local")])
def test_policy_text(policy, text):
    from orchestrator.viewers.summary import policy_text

    assert policy_text(policy) == text
