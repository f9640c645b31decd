"""MkDocs hooks (mkdocs.yml's ``hooks:``): the README as the site's home page, and the repository files the
pages link to brought into the site.

MkDocs builds only what is under ``docs/``, and its strict build fails on a link to anything else. The
pages are read on GitHub too, where ``../deploy/README.md`` or ``../topologies/examples/ring.yaml`` is the
natural link, so the sources keep those links and these hooks resolve them: each linked repository file
joins the site under ``repo/`` (a Markdown file as a page, any other file as a download), and every link
is rewritten to where its target is in the site. A link to a file that does not exist is left as written,
so MkDocs' own validation still reports it and the strict build fails.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent
HOME = "README.md"  # the repository's front page is the site's index.md
OUTSIDE = "repo/"  # where files from outside docs/ are placed in the site
LINK = re.compile(r"(\]\()([^)\s#]+)")  # an inline link or image: ](path — its anchor, if any, follows
FENCE = re.compile(r"^ *```.*?^ *```", re.S | re.M)


def real_path(src_uri: str) -> str:
    """The repository path of a site file."""
    if src_uri == "index.md":
        return HOME
    if src_uri.startswith(OUTSIDE):
        return src_uri.removeprefix(OUTSIDE)
    return f"docs/{src_uri}"


def site_path(real: str) -> str:
    """The site path of a repository file."""
    if real == HOME:
        return "index.md"
    if real.startswith("docs/"):
        return real.removeprefix("docs/")
    return OUTSIDE + real


def targets(markdown: str, real: str) -> list[tuple[str, str]]:
    """(link as written, repository path it points to) for every relative link outside code blocks."""
    out = []
    for m in LINK.finditer(FENCE.sub("", markdown)):
        link = m[2]
        if re.match(r"[a-z][a-z0-9+.-]*:", link) or link.startswith("/"):
            continue  # a URL, or an absolute path (MkDocs warns about those)
        resolved = posixpath.normpath(posixpath.join(posixpath.dirname(real), link))
        if not resolved.startswith("../"):
            out.append((link, resolved))
    return out


def on_files(files: Files, config: Any) -> Files:
    """Add the README as index.md, then every repository file a page links to, and the files those link to."""
    files.append(File.generated(config, "index.md", abs_src_path=str(ROOT / HOME)))
    queue = list(files.documentation_pages())
    while queue:
        page = queue.pop()
        real = real_path(page.src_uri)
        for _, target in targets(Path(page.abs_src_path).read_text(encoding="utf-8"), real):
            if target.startswith("docs/") or target == HOME or not (ROOT / target).is_file():
                continue
            if files.get_file_from_path(site_path(target)) is None:
                added = File.generated(config, site_path(target), abs_src_path=str(ROOT / target))
                files.append(added)
                if added.is_documentation_page():
                    queue.append(added)
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Point each link that resolves to a file of the site at that file, relative to this page."""
    here = page.file.src_uri
    rewrite = {link: posixpath.relpath(site_path(target), posixpath.dirname(here) or ".")
               for link, target in targets(markdown, real_path(here))
               if files.get_file_from_path(site_path(target)) is not None}
    return LINK.sub(lambda m: m[1] + rewrite.get(m[2], m[2]), markdown)
