"""Long commands report progress: a bar on a terminal, plain lines elsewhere."""

from __future__ import annotations

import io

from rich.console import Console

from orchestrator.viewers.progress import progress_steps


def test_plain_lines_when_not_on_a_terminal(capsys):
    with progress_steps(2, "bench", console=Console(file=io.StringIO(), force_terminal=False)) as step:
        step("aot1 inproc single")
        step("aot1 zenoh per-role")
    assert capsys.readouterr().err.splitlines() == ["bench 1/2: aot1 inproc single", "bench 2/2: aot1 zenoh per-role"]


def test_a_bar_on_a_terminal(capsys):
    screen = io.StringIO()
    with progress_steps(2, "bench", console=Console(file=screen, force_terminal=True, width=100)) as step:
        step("aot1 inproc single")
        step("aot1 zenoh per-role")
    assert capsys.readouterr().err == ""
    assert "bench" in screen.getvalue()
