"""MkDocs hook: include sections of the repository's README.md in documentation pages.

A page line ``<!-- include-readme: NAME -->`` is replaced by the part of README.md between
``<!-- docs:NAME -->`` and ``<!-- /docs:NAME -->``, so the README stays the single source of
the quickstart, the metrics table, the results and the library table. README links into
``docs/`` are rewritten relative to the including page; any other relative link would point
outside the site and fails ``mkdocs build --strict`` (as does an unknown section name).
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.exceptions import PluginError

README = Path(__file__).resolve().parent.parent / "README.md"
INCLUDE = re.compile(r"^<!-- include-readme: ([\w-]+) -->$", re.MULTILINE)
LINK = re.compile(r"\]\(docs/([^)]*)\)")


def readme_section(name: str) -> str:
    """The README text between the markers of section ``name``."""
    text = README.read_text(encoding="utf-8")
    match = re.search(rf"<!-- docs:{name} -->\n(.*?)<!-- /docs:{name} -->", text, re.DOTALL)
    if match is None:
        raise PluginError(
            f"README.md has no section <!-- docs:{name} --> ... <!-- /docs:{name} -->"
        )
    return match.group(1)


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Expand ``<!-- include-readme: NAME -->`` lines of a page."""
    page_dir = posixpath.dirname(page.file.src_uri)

    def relink(match: re.Match) -> str:
        target = match.group(1)
        path, hash_, anchor = target.partition("#")
        rel = posixpath.relpath(path or ".", page_dir or ".")
        if path.endswith("/"):
            rel += "/"
        return f"]({rel}{hash_}{anchor})"

    def expand(match: re.Match) -> str:
        return LINK.sub(relink, readme_section(match.group(1)))

    return INCLUDE.sub(expand, markdown)
