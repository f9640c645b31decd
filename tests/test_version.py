"""summary.json says which code produced it, so a seed and a scenario hash can replay the run."""

from __future__ import annotations

import re
import subprocess
from importlib import metadata

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
