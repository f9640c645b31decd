"""The documentation site builds with `mkdocs build --strict`, and its settings keep that strict: a broken link
or anchor, a page left out of the nav or a docstring the API reference cannot read fails the build."""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys

import pytest

from tests.conftest import ROOT

pytest.importorskip("mkdocs", reason="the test and docs extras install it: pip install -e '.[test]'")
pytest.importorskip("mkdocstrings", reason="the test and docs extras install it: pip install -e '.[test]'")


def test_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"}, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "WARNING" not in done.stderr, done.stderr[-4000:]
    home = (site / "index.html").read_text()
    assert "figures/rq2-urgent.png" in home and 'href="results/"' in home  # the README, its links made the site's
    assert "congestion_price" in (site / "api" / "index.html").read_text()  # ZenohEdgeEnv's arguments, documented
    assert (site / "repo" / "deploy" / "index.html").is_file()  # deploy/README.md, linked from the pages


def test_broken_links_and_pages_left_out_fail_the_build(tmp_path, caplog):
    from mkdocs.commands.build import build
    from mkdocs.config import load_config
    from mkdocs.exceptions import Abort

    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    page = docs / "contributing.md"
    page.write_text(page.read_text() + "\n[gone](nowhere.md), [no such part](bus.md#no-such-part), "
                    "[no such file](../topologies/nowhere.yaml)\n")
    (docs / "orphan.md").write_text("# A page no nav names\n")
    config = load_config(str(ROOT / "mkdocs.yml"), site_dir=str(tmp_path / "site"), strict=True)
    config.docs_dir = str(docs)
    with caplog.at_level(logging.WARNING), pytest.raises(Abort):
        build(config)
    warned = "\n".join(r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    for expected in ("'nowhere.md'", "'#no-such-part'", "'../topologies/nowhere.yaml'", "orphan.md"):
        assert expected in warned, f"no warning names {expected}:\n{warned}"
