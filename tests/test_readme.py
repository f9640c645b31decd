"""The README's training snippet runs as written (in one process, to stay quick)."""

from __future__ import annotations

import re

from tests.conftest import ROOT


def test_training_snippet_runs(capsys):
    readme = (ROOT / "README.md").read_text()
    snippet = next(block for block in re.findall(r"```python\n(.*?)```", readme, re.S) if "ZenohEdgeEnv()" in block)
    exec(snippet.replace("ZenohEdgeEnv()", 'ZenohEdgeEnv(transport="inproc", max_steps=30)'), {})
    assert re.search(r"^\d+ of \d+ tasks completed, \d+ dropped$", capsys.readouterr().out, re.M)
