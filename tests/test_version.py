"""summary.json says which code produced it, so a seed and a scenario hash can replay the run."""

from __future__ import annotations

import re
import subprocess
from importlib import metadata

from orchestrator.cli import main
from orchestrator.version import version_line
from tests.conftest import ROOT, run_summary


def test_summary_records_package_version_and_commit(aot1):
    code = run_summary(aot1, ticks=3)["code"]
    assert code["version"] == metadata.version("zenohedge")
    if (ROOT / ".git").exists():
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        assert re.fullmatch(r"[0-9a-f]{40}", code["commit"])
        assert code["commit"] == head
        assert isinstance(code["dirty"], bool)
    else:
        assert code["commit"] is None


def test_version_line_names_the_commit_and_uncommitted_changes():
    sha = "e8dab53" + "0" * 33
    assert version_line({"version": "0.1.0", "commit": sha, "dirty": True}) == \
        "zenohedge 0.1.0, commit e8dab53 (uncommitted changes)"
    assert version_line({"version": "0.1.0", "commit": sha, "dirty": False}) == "zenohedge 0.1.0, commit e8dab53"
    assert version_line({"version": None, "commit": None, "dirty": None}) == "zenohedge (not installed)"


def test_bench_stamps_its_table_with_the_code(capsys):
    """A table pasted into docs/benchmarks.md then says which code it measured."""
    assert main(["bench", "aot1", "--transports", "inproc", "--ticks", "20", "--rounds", "1"]) == 0
    assert f"measured with {version_line()}" in " ".join(capsys.readouterr().out.split())
