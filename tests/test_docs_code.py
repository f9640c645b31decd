"""Every code block of the README and of docs/ is checked, so that what a reader copies works:

- ``python``: compiled; run in a fresh interpreter from a scratch directory unless marked;
- ``yaml``: parsed; a whole scenario (it has ``name`` or ``extends``) goes through the scenario loader, and
  a block headed ``# file: PATH`` is that file, word for word;
- ``bash`` and ``console`` (its ``$`` lines): every command of this project (``orchestrator``,
  ``zenohedge-node``, ``python -m <module>``, ``python <script>.py``) is parsed by that command's own
  argparse parser, so an unknown flag, choice or subcommand fails; the repository files it names exist
  (a script that reads ``sys.argv`` without argparse is only checked to exist);
- ``json``: parsed;
- plain, ``text``, ``csv`` and ``json5`` blocks (diagrams, formulas, shown output) are not checked.

Markers, an HTML comment on the line before a block (invisible once rendered):
``<!-- no-run -->`` compiles a python block without running it (it needs a network, a long run or a
package outside the test extra, or it is a fragment of a larger file); ``<!-- run: "A" -> "B" -->``
runs it with every A replaced by B (a shorter episode, in one process); several pairs are separated
by ``;``.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import runpy
import shlex
import subprocess
import sys
import textwrap
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from orchestrator.scenario import load_scenario
from tests.conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), ROOT / "deploy" / "README.md"]
FENCE = re.compile(r"^(?P<indent> *)```(?P<lang>[\w+-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)```[ \t]*$", re.S | re.M)
MARKER = re.compile(r"<!--\s*(no-run|run:.*?)\s*-->")
STRING = r'"(?:[^"\\]|\\.)*"'
REPLACE = re.compile(rf"({STRING})\s*->\s*({STRING})")
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
# Commands of other tools that the docs show; they are not ours to parse.
FOREIGN = {"pip", "pytest", "git", "cd", "source", "export", "mkdir", "cp", "ls", "cat", "kill", "ssh", "scp",
           "docker", "zenohd", "openssl", "ip", "mkdocs", "echo", "for", "do", "done", "then", "fi", "if", "sudo",
           "env", "ray", "tar", "curl", "wget", "diff", "py-spy", "nice", "time", "timeout", "watch", "python3", "jq"}


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    code: str
    marker: str | None  # "no-run", or 'run: "A" -> "B"'

    def __str__(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks() -> list[Block]:
    found = []
    for page in PAGES:
        text = page.read_text()
        for m in FENCE.finditer(text):
            before = text[:m.start()].rstrip().rsplit("\n", 1)[-1]
            marker = MARKER.search(before)
            found.append(Block(page, text.count("\n", 0, m.start()) + 1, m["lang"],
                               textwrap.dedent(m["body"]), marker[1] if marker else None))
    return found


BLOCKS = blocks()


def of(*langs: str) -> list[Block]:
    return [b for b in BLOCKS if b.lang in langs]


def test_every_block_has_a_known_language():
    """A block in a language that no test below reads would go unchecked: name its language, or add a check.
    Plain, ``text``, ``csv`` and ``json5`` blocks are diagrams, formulas and shown output: read, not run."""
    read = {"python", "yaml", "bash", "console", "json", "text", "csv", "json5", ""}
    assert not [f"{b} ({b.lang or 'no language'})" for b in BLOCKS if b.lang not in read]


# ----- python -----

@pytest.mark.parametrize("block", of("python"), ids=str)
def test_python_block_compiles(block):
    ast.parse(block.code, str(block))


RUN = [b for b in of("python") if b.marker != "no-run"]
# Runs the blocks one after the other, each in a namespace of its own, and names the first that fails.
DRIVER = """
import json, sys, traceback
for label, code in json.load(sys.stdin):
    try:
        exec(compile(code, label, "exec"), {"__name__": "__doc_block__"})
    except BaseException:
        print(label, "failed:", traceback.format_exc(), file=sys.stderr)
        sys.exit(1)
"""


def runnable(block: Block) -> str:
    if not block.marker:
        return block.code
    code = block.code
    for m in REPLACE.finditer(block.marker):
        old, new = ast.literal_eval(m[1]), ast.literal_eval(m[2])
        assert old in code, f"{block}: its marker replaces {old!r}, which the block does not contain"
        code = code.replace(old, new)
    return code


def test_python_blocks_run(tmp_path):
    """In a fresh interpreter (a block may register a role kind or start processes), one for all blocks so that
    torch is imported once, from a scratch directory (blocks write runs/...), with examples/ importable as the
    pages say."""
    todo = [(str(b), runnable(b)) for b in RUN]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "examples")])}
    done = subprocess.run([sys.executable, "-c", DRIVER], input=json.dumps(todo), cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-4000:]


# ----- yaml -----

@pytest.mark.parametrize("block", of("yaml"), ids=str)
def test_yaml_block(block, monkeypatch):
    data = yaml.safe_load(block.code)
    named = re.match(r"# file: (\S+)", block.code)
    if named:
        path = ROOT / named[1]
        assert path.is_file(), f"{block} shows {named[1]}, which does not exist"
        assert path.read_text() == block.code, f"{block} is not {named[1]} as it is: copy the file into the page"
        load_scenario(path)
    elif isinstance(data, dict) and ("name" in data or "extends" in data):
        monkeypatch.chdir(ROOT / "topologies")  # where a scenario's relative paths (ether/...) are read from
        load_scenario(data, name_hint="docs")


# ----- json -----

@pytest.mark.parametrize("block", of("json"), ids=str)
def test_json_block(block):
    if block.marker == "no-run":
        return
    try:
        json.loads(block.code)
    except json.JSONDecodeError:
        json.loads("{" + block.code + "}")  # a fragment of an object: its members


# ----- bash and console -----

class Parsed(Exception):
    """Raised by the patched parse_args once a command line parsed."""


def command_lines(block: Block) -> list[str]:
    text = block.code
    if block.lang == "console":
        text = "\n".join(line[2:] for line in text.splitlines() if line.startswith("$ "))
    return [line for line in text.replace("\\\n", " ").splitlines() if line.strip()]


def commands(line: str) -> list[list[str]]:
    """The simple commands of a line, split at ; && || |, with a for loop's variable set to its first value."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lexer.whitespace_split = True
    lexer.commenters = "#"
    words, out, current = list(lexer), [], []
    for w in words:
        if set(w) <= set(";&|"):
            out.append(current)
            current = []
        else:
            current.append(w)
    out.append(current)
    loops = {c[1]: c[3] for c in out if len(c) > 3 and c[0] == "for" and c[2] == "in"}
    expanded = []
    for c in out:
        if c and c[0] == "do":
            c = c[1:]
        expanded.append([re.sub(r"\$(\w+)", lambda m: loops.get(m[1], m[0]), w) for w in c])
    return [c for c in expanded if c]


def entry(words: list[str]) -> tuple[str, list[str]] | None:
    """(what to run, its arguments) for a command of this project; None for any other."""
    if words[0] == "sudo":
        words = words[1:]
    if words[0] in SCRIPTS:
        return f"script:{SCRIPTS[words[0]]}", words[1:]
    if words[0] != "python":
        assert words[0] in FOREIGN or words[0].startswith(("./", "deploy/", ".ci/")), f"unknown command {words[0]}"
        return None
    if words[1] == "-m":
        if words[2].split(".")[0] in ("pip", "pytest", "venv"):
            return None
        return f"module:{words[2]}", words[3:]
    if words[1].endswith(".py"):
        return f"path:{words[1]}", words[2:]
    return None


def parse(target: str, argv: list[str]) -> None:
    """Run the command's own argument parsing and stop there: parse_args raises Parsed once it returned."""
    original = argparse.ArgumentParser.parse_args

    def parse_only(self, args=None, namespace=None):
        original(self, args, namespace)
        raise Parsed

    kind, name = target.split(":", 1)
    argparse.ArgumentParser.parse_args = parse_only
    saved, sys.argv = sys.argv, [name, *argv]
    try:
        if kind == "script":
            module, func = name.rsplit(":", 1)
            getattr(__import__(module, fromlist=[func]), func)(argv)
        elif kind == "module":
            runpy.run_module(name, run_name="__main__", alter_sys=False)
        else:
            runpy.run_path(str(ROOT / name), run_name="__main__")
    except Parsed:
        return
    except SystemExit as exc:
        if exc.code not in (0, None):
            raise AssertionError(f"{target} {shlex.join(argv)}: the parser refused it (exit status {exc.code})") \
                from None
        return
    finally:
        argparse.ArgumentParser.parse_args = original
        sys.argv = saved
    raise AssertionError(f"{target} did not parse its arguments")


TOP = {p.name for p in ROOT.iterdir() if not p.name.startswith(".")} - {"runs"}


def repo_paths(argv: list[str]) -> list[str]:
    """Words that name a file of the repository (an existing top-level folder, then more)."""
    return [w for w in argv if "/" in w and not w.startswith(("-", "/", "$")) and w.split("/")[0] in TOP
            and "*" not in w]


@pytest.mark.parametrize("block", of("bash", "console"), ids=str)
def test_commands_parse(block, monkeypatch):
    monkeypatch.chdir(ROOT)
    for line in command_lines(block):
        for words in commands(line):
            found = entry(words)
            if found is None:
                continue
            target, argv = found
            if target.startswith("path:"):
                script = ROOT / target[5:]
                assert script.is_file(), f"{block}: {target[5:]} does not exist"
                if "parse_args" not in script.read_text():  # it reads sys.argv itself: running it is the only check
                    continue
            missing = [w for w in repo_paths(argv) if not (ROOT / w).exists()
                       and not w.startswith(("runs/", "docs/figures/"))]
            assert not missing, f"{block}: {' '.join(missing)} do not exist"
            parse(target, argv)
