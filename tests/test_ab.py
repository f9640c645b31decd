"""benchmarks/ab.py: two versions of the code stepped in turn in one window, each worker on its own tree."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.launcher import TIMEOUT


def ab(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "benchmarks/ab.py", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=TIMEOUT)


def worktrees() -> list[str]:
    return subprocess.run(["git", "worktree", "list"], cwd=ROOT, capture_output=True, text=True).stdout.splitlines()


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="compares a git revision: needs a git checkout")
def test_a_revision_and_the_working_tree_are_compared_and_the_worktree_removed():
    before = worktrees()
    done = ab("HEAD", ".", "aot1", "--transport", "inproc", "--rounds", "2", "--steps", "20")
    assert done.returncode == 0, done.stderr
    assert "A: HEAD" in done.stdout and "B: ." in done.stdout and "B / A" in done.stdout
    assert worktrees() == before  # the temporary checkout of HEAD is gone


def test_a_directory_without_the_code_is_refused_in_one_line(tmp_path):
    done = ab(".", str(tmp_path), "aot1", "--transport", "inproc", "--rounds", "1", "--steps", "5")
    assert done.returncode == 1
    assert done.stderr.strip().splitlines()[-1].startswith(f"ab.py: the worker for {tmp_path} ran the code in ")
    assert "Traceback" not in done.stderr
