"""MkDocs hooks: README sections in pages, and equations typeset at build time.

README sections: a page line ``TEXT <!-- include-readme: NAME -->`` is replaced by the
part of README.md between ``<!-- docs:NAME -->`` and ``<!-- /docs:NAME -->``, so the
README stays the single source of the quickstart, the Python example and the library
table; ``TEXT`` (a link to that README section) is what a reader of the page on GitHub
sees instead.
README links into ``docs/`` are rewritten relative to the including page; any other
relative link would point outside the site and fails ``mkdocs build --strict`` (as does an
unknown section name).

Equations: the site loads nothing from another host, so no MathJax from a CDN. Formulas
are written in LaTeX (``\\( .. \\)`` and ``\\[ .. \\]`` through pymdownx.arithmatex in the
pages, ``$ .. $`` and ``$$ .. $$`` in the notebooks' markdown cells) and converted to MathML
while the site is built, by latex2mathml (a PyPI package); browsers render MathML
themselves. A formula latex2mathml cannot convert fails the build and names the page. The
notebook pages also lose nbconvert's MathJax and Mermaid loaders (both would fetch scripts
from a CDN); a notebook with a Mermaid diagram fails the build instead.
"""

from __future__ import annotations

import html
import posixpath
import re
from pathlib import Path

from latex2mathml.converter import convert as latex_to_mathml
from mkdocs.exceptions import PluginError

README = Path(__file__).resolve().parent.parent / "README.md"
# What GitHub shows (a link to the README's section; it hides the comment), then the
# marker, on one line: the whole line is replaced on the site.
INCLUDE = re.compile(r"^.*<!-- include-readme: ([\w-]+) -->$", re.MULTILINE)
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


# pymdownx.arithmatex (generic): <span class="arithmatex">\(..\)</span> and
# <div class="arithmatex">\[..\]</div>, the LaTeX HTML-escaped.
ARITHMATEX = re.compile(r'<(span|div) class="arithmatex">\s*(.*?)\s*</\1>', re.DOTALL)
# Parts of a page whose text is not prose: scripts, styles, code, the title, and tags.
NOT_TEXT = re.compile(
    r"(<(script|style|pre|code|title|textarea)\b.*?</\2\s*>|<[^>]*>)", re.DOTALL | re.IGNORECASE
)
# $$..$$, and $..$ that opens before a non-space and closes after one (not "$5 and $10").
DOLLARS = re.compile(r"\$\$(.+?)\$\$|(?<![\\$\w])\$(?=\S)([^$\n]+?)(?<=\S)\$(?![\w$])", re.DOTALL)
NBCONVERT_MATHJAX = re.compile(
    r"<!-- Load mathjax -->.*?<!-- End of mathjax configuration -->", re.DOTALL
)
NBCONVERT_MERMAID = re.compile(
    r'<script type="module">(?:(?!</script>).)*?jp-Mermaid.*?</script>', re.DOTALL
)


def mathml(tex: str, display: bool, where: str) -> str:
    """``tex`` as a MathML ``<math>`` element (``display``: a block formula)."""
    depth = 0
    for brace in re.findall(r"\\.|[{}]", tex):  # \{ and \} are literal braces
        depth += {"{": 1, "}": -1}.get(brace, 0)
        if depth < 0:
            break
    if depth != 0:  # latex2mathml would silently drop or print the odd brace
        raise PluginError(f"{where}: unbalanced braces in {tex!r}")
    try:
        out = latex_to_mathml(tex, display="block" if display else "inline")
    except Exception as error:  # latex2mathml raises several types for bad input
        raise PluginError(f"{where}: latex2mathml cannot convert {tex!r}: {error}") from error
    if "\\" in out:  # an unknown command passed through as text
        raise PluginError(f"{where}: latex2mathml left a LaTeX command in {tex!r}: {out}")
    return out


def _arithmatex(match: re.Match, where: str) -> str:
    tag, source = match.group(1), html.unescape(match.group(2))
    if not (source[:2] in ("\\(", "\\[") and source[-2:] in ("\\)", "\\]")):
        raise PluginError(f"{where}: unexpected arithmatex content {source!r}")
    return f'<{tag} class="arithmatex">{mathml(source[2:-2].strip(), tag == "div", where)}</{tag}>'


def _dollars(text: str, where: str) -> str:
    def one(match: re.Match) -> str:
        block = match.group(1) is not None
        tex = html.unescape(match.group(1) if block else match.group(2)).strip()
        return mathml(tex, block, where)

    return DOLLARS.sub(one, text)


def on_post_page(output: str, page, config) -> str:
    """Replace every formula of the page by MathML; strip nbconvert's CDN loaders."""
    where = page.file.src_uri
    output = ARITHMATEX.sub(lambda m: _arithmatex(m, where), output)
    if not where.endswith((".py", ".ipynb")):  # notebooks (mkdocs-jupyter)
        return output
    output = NBCONVERT_MATHJAX.sub("", output)
    output = NBCONVERT_MERMAID.sub("", output)
    if re.search(r'class="[^"]*jp-Mermaid', output):
        raise PluginError(f"{where}: Mermaid diagrams need a script from a CDN; not supported")
    parts = NOT_TEXT.split(output)
    # split() with two groups returns text, whole match, inner group, text, ...
    out = []
    for i in range(0, len(parts), 3):
        out.append(_dollars(parts[i], where))
        if i + 1 < len(parts):
            out.append(parts[i + 1])
    return "".join(out)
