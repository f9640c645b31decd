"""env.step() steps/s of two versions of the code, measured in one window.

    python benchmarks/ab.py HEAD .                              # the last commit against the working tree
    python benchmarks/ab.py main my-branch aot3 --layout per-node --rounds 12

One run of one version cannot show a 10 % change on a shared machine: the same code measured minutes
apart differs by up to 30 % here. So both versions run at once, each in a process of its own that
starts its own node processes from its own tree, and they step in turn, chunk by chunk (who goes first
alternates); the ratio is the median of the per-chunk ratios, so a drift of the machine's speed hits
both alike. The spread of the chunk ratios is printed too: compare a version with itself to see this
machine's. A version is a git revision (checked out in a temporary worktree, removed afterwards) or a
directory holding a checkout (``.`` includes uncommitted changes). Actions are random from each agent's
mask and are not timed (``env_steps.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from rich.console import Console
from rich.table import Table

HERE = Path(__file__).resolve().parent


def worker(scenario: str, transport: str, layout: str) -> None:
    """One version's environment: a line "N" on stdin -> N steps, one line with their steps/s; "0" ends."""
    from env_steps import random_steps  # beside this file

    import env as package  # from this version's tree, first on PYTHONPATH
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv(scenario, transport=transport, layout=layout, max_steps=10**9)
    try:
        rate = random_steps(env)
        rate(50)  # warm-up
        print(f"ready {Path(package.__file__).resolve().parent.parent}", flush=True)
        for line in sys.stdin:
            if int(line) == 0:
                break
            print(rate(int(line)), flush=True)
    finally:
        env.close()


@contextlib.contextmanager
def checkout(version: str) -> Iterator[Path]:
    """The tree of ``version``: a directory as it is, or a git revision in a temporary worktree."""
    if Path(version).is_dir():
        yield Path(version).resolve()
        return
    repo = HERE.parent
    with tempfile.TemporaryDirectory(prefix="zenohedge-ab-") as parent:
        tree = Path(parent) / "tree"
        made = subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", str(tree), version],
                              capture_output=True, text=True)
        if made.returncode:
            sys.exit(f"ab.py: {version!r} is neither a directory nor a git revision of {repo}: "
                     f"{made.stderr.strip().splitlines()[-1] if made.stderr.strip() else 'git failed'}")
        try:
            yield tree
        finally:
            subprocess.run(["git", "-C", str(repo), "worktree", "remove", "--force", str(tree)], capture_output=True)


class Version:
    """A worker process stepping one version's environment."""

    def __init__(self, tree: Path, args: argparse.Namespace) -> None:
        # run from the tree itself: a version whose fork server puts the working directory first on its
        # path (before 0d1ec76) then still starts its own node code, not the code of where ab.py was run
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--worker", args.scenario, args.transport, args.layout],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=tree,
            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")])})
        self.rates: list[float] = []
        ready, _, used = self._line().partition(" ")
        if ready != "ready" or Path(used) != tree:
            self.close()
            raise RuntimeError(f"the worker for {tree} ran the code in {used or '?'}: is {tree} a checkout?")

    def _line(self) -> str:
        line = self.proc.stdout.readline().strip()
        if not line:
            raise RuntimeError("a worker ended early (see its error above)")
        return line

    def run(self, steps: int) -> None:
        self.proc.stdin.write(f"{steps}\n")
        self.proc.stdin.flush()
        self.rates.append(float(self._line()))

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.proc.stdin.write("0\n")
            self.proc.stdin.close()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def main() -> None:
    if sys.argv[1:2] == ["--worker"]:
        worker(*sys.argv[2:5])
        return
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("a", help="version A: a git revision or a checkout's directory")
    parser.add_argument("b", help="version B, compared with A")
    parser.add_argument("scenario", nargs="?", default="aot2")
    parser.add_argument("--transport", default="zenoh", choices=("zenoh", "inproc"))
    parser.add_argument("--layout", default="per-node", help="process layout (default per-node)")
    parser.add_argument("--rounds", type=int, default=8, help="chunks per version, taken in turn (default 8)")
    parser.add_argument("--steps", type=int, default=200, help="env steps per chunk (default 200)")
    args = parser.parse_args()
    from orchestrator.viewers.progress import progress_steps

    with checkout(args.a) as tree_a, checkout(args.b) as tree_b:
        versions: list[Version] = []
        try:
            for tree in (tree_a, tree_b):
                versions.append(Version(tree, args))
            with progress_steps(args.rounds, "ab") as step:
                for k in range(args.rounds):
                    step(f"chunk {k + 1}: {args.steps} steps each")
                    for v in versions if k % 2 == 0 else versions[::-1]:
                        v.run(args.steps)
        except RuntimeError as exc:
            sys.exit(f"ab.py: {exc}")
        finally:
            for v in versions:
                v.close()
    a, b = versions
    ratios = [y / x for x, y in zip(a.rates, b.rates, strict=True)]
    table = Table(title=f"{args.scenario}, {args.transport} {args.layout}: env.step() steps/s, medians of "
                        f"{args.rounds} chunks of {args.steps} steps taken in turn", title_justify="left")
    for col in ("version", "steps/s", "B / A", "B / A per chunk"):
        table.add_column(col, justify="left" if col == "version" else "right")
    table.add_row(f"A: {args.a}", f"{statistics.median(a.rates):,.0f}", "", "")
    table.add_row(f"B: {args.b}", f"{statistics.median(b.rates):,.0f}", f"{statistics.median(ratios):.3f}",
                  f"{min(ratios):.2f} to {max(ratios):.2f}")
    Console().print(table)


if __name__ == "__main__":
    main()
