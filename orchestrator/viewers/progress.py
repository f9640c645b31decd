"""Progress for long commands: a bar on a terminal, one plain line per item otherwise (logs, CI, pipes)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn


class Advance(Protocol):
    def __call__(self, label: str) -> None: ...


@contextmanager
def progress_steps(total: int, title: str, *, console: Console | None = None) -> Iterator[Advance]:
    """``with progress_steps(12, "bench") as step: step("aot2 zenoh per-role"); ...``

    Call ``step(label)`` before each of the ``total`` items: a terminal shows a bar with the item being
    worked on; anything else gets a line such as ``bench 3/12: aot2 zenoh per-role``.
    """
    console = console or Console(stderr=True, highlight=False)
    done = [0]
    if not console.is_terminal:
        def line(label: str) -> None:
            done[0] += 1
            print(f"{title} {done[0]}/{total}: {label}", file=sys.stderr, flush=True)

        yield line
        return
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("{task.fields[item]}"), TimeElapsedColumn(), console=console, transient=True)
    with bar:
        task = bar.add_task(title, total=total, item="")

        def advance(label: str) -> None:
            if done[0]:
                bar.advance(task)
            done[0] += 1
            bar.update(task, item=label)

        yield advance
