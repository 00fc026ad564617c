"""The documentation site builds with warnings as errors (``mkdocs build --strict``): a
broken link, a missing page or a docstring that names a parameter the signature lacks fails
here, and so does a public module without an API page. Needs the ``docs`` extra
(``pip install ".[test]"`` pulls it in).

The built site loads nothing from another host: no script, stylesheet, font or icon from
a CDN (the equations are MathML, typeset at build time by docs/_hooks.py)."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from tiny import public_modules

ROOT = Path(__file__).resolve().parent.parent


# An element that makes the browser fetch something: its tag and the attribute holding the URL.
LOADS = re.compile(
    r"<(script|link|img|iframe|source|embed|object)\b[^>]*?\b(src|href|data)\s*=\s*"
    r"[\"']?([^\"'\s>]+)",
    re.IGNORECASE,
)
# Links that only navigate (the browser fetches nothing until one is followed).
NAVIGATION = re.compile(r"\brel\s*=\s*[\"']?(prev|next|canonical|alternate)\b", re.IGNORECASE)
# Material's bundle fetches mermaid from unpkg when a page has a mermaid element.
FETCHES = re.compile(
    r"import\(\s*[\"'](?:https?:)?//|@import\s+(?:url\()?[\"']?(?:https?:)?//"
    r"|url\(\s*[\"']?(?:https?:)?//|class=\"[^\"]*\bmermaid\b",
    re.IGNORECASE,
)


def external_loads(html: str) -> list[str]:
    """What a page would fetch from another host: absolute or protocol-relative URLs in
    elements that load (scripts, stylesheets, icons, images, frames), module imports, CSS
    imports and ``url()``s, and mermaid diagrams."""
    found = []
    for element in re.finditer(r"<[a-zA-Z][^>]*>", html):
        tag = element.group(0)
        load = LOADS.match(tag)
        if load and re.match(r"(?:[a-z][a-z0-9+.-]*:)?//", load.group(3), re.IGNORECASE):
            if not (load.group(1).lower() == "link" and NAVIGATION.search(tag)):
                found.append(tag)
    found += [m.group(0) for m in FETCHES.finditer(html)]
    return found


def build(root: Path, site: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    env.pop("CFM_JAX_DOCS_EXECUTE", None)  # render the notebooks, do not run them here
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_every_public_module_has_an_api_page_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text()
    missing = []
    for name in public_modules():
        # A module's page is its own (docs/api/sim/robots.md), else its package's (the
        # tasks' modules are on docs/api/tasks.md).
        own = f"{name.replace('.', '/')}.md"
        top = own if (ROOT / "docs" / "api" / own).is_file() else f"{name.split('.')[0]}.md"
        page = ROOT / "docs" / "api" / top
        if not page.is_file() or f"::: cfm_jax.{name}\n" not in page.read_text() + "\n":
            missing.append(f"docs/api/{top} (with '::: cfm_jax.{name}')")
        elif f"api/{top}" not in nav:
            missing.append(f"api/{top} in the nav of mkdocs.yml")
    assert not missing, "public modules without an API page: " + ", ".join(missing)


def test_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    done = build(ROOT, site)
    assert done.returncode == 0, done.stdout + done.stderr
    # The API pages hold the docstrings, the notebooks are pages, README sections and
    # figures are where the pages link them.
    training = (site / "api" / "runs" / "training" / "index.html").read_text()
    assert "Run Algorithm 1 for every seed" in training
    assert "cfm_jax.runs.training.train" in training
    for name in ("train_iiwa", "compare_losses", "own_robot", "theory_1d"):
        page = (site / "notebooks" / name / "index.html").read_text()
        assert "CFM_JAX_DOCS_QUICK" in page  # the intro says what the tests run
        # What the notebook produces is on the page: its stored outputs, a figure at least;
        # the cell that sets the tests' reduced size is not.
        assert re.search(r'<img[^>]+src="data:image/(png|gif)', page), name
        assert "QUICK = os.environ" not in page, name
    results = (site / "results" / "index.html").read_text()
    assert "Operational-space control (paper Fig. 3b)" in results
    # The page results/ and the data folder results/ are one folder of the site.
    curves = "robustness/cells/opspace/home-default/curves.png"
    assert f'src="{curves}"' in results
    assert (site / "results" / curves).is_file()
    # Every equation is MathML, none is left as LaTeX for a script to typeset.
    losses = (site / "concepts" / "losses" / "index.html").read_text()
    assert "<math" in losses and "<mi>&#x02112;</mi>" in losses  # \mathcal{L}
    theory = (site / "notebooks" / "theory_1d" / "index.html").read_text()
    assert "<math" in theory  # the notebook's $..$ formulas
    offline = {}
    for page in site.rglob("*.html"):
        text = page.read_text()
        assert 'class="arithmatex">\\(' not in text and 'class="arithmatex">\\[' not in text
        if external_loads(text):
            offline[str(page.relative_to(site))] = external_loads(text)
    assert not offline, f"pages that load from another host: {offline}"


def test_external_loads_finds_what_a_browser_would_fetch_from_another_host():
    """The checker against hand-written pages: every kind of remote load is found, local
    files and plain links are not."""
    remote = [
        '<script src="https://cdn.jsdelivr.net/npm/mathjax@3/es5/tex-mml-chtml.js"></script>',
        "<script src='//unpkg.com/mermaid'></script>",
        '<link rel="stylesheet" href="https://fonts.googleapis.com/css?family=Roboto">',
        '<link href="https://fonts.gstatic.com" rel="preconnect">',
        '<link rel="icon" href=http://example.org/favicon.png>',
        '<img alt="" src="https://example.org/plot.png">',
        '<script type="module">import("https://cdnjs.cloudflare.com/x.js")</script>',
        '<style>@import url("https://fonts.googleapis.com/css2?family=Inter");</style>',
        '<div class="mermaid">graph LR; a-->b</div>',
    ]
    for html in remote:
        assert external_loads(html), html
    local = [
        '<script src="../assets/javascripts/bundle.js"></script>',
        '<link rel="stylesheet" href="/assets/stylesheets/main.css">',
        '<a href="https://arxiv.org/abs/2011.03859">the paper</a>',
        '<link rel="canonical" href="https://example.org/cfm_jax/">',
        '<img src="robustness/jump.png">',
        "<p>a price of $5 and //comments</p>",
    ]
    for html in local:
        assert not external_loads(html), html


def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "_hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_equations_become_mathml_and_a_bad_one_fails_the_build():
    from mkdocs.exceptions import PluginError

    hooks = _hooks()
    out = hooks.mathml(r"\frac{\partial \mathcal{L}}{\partial \theta}", True, "page.md")
    assert out.startswith("<math") and 'display="block"' in out
    assert "<mfrac>" in out and "<mi>&#x003B8;</mi>" in out and "\\" not in out  # theta
    for bad in (r"\frac{a", "x}", "x^", r"\left( x", r"\nosuchcommand{x}"):
        try:
            hooks.mathml(bad, False, "page.md")
        except PluginError as error:
            assert "page.md" in str(error)
        else:
            raise AssertionError(f"{bad!r} converted without an error")


def test_a_broken_link_fails_the_build(tmp_path):
    """Negative control: the same site with one broken link must not build."""
    copy = tmp_path / "repo"
    copy.mkdir()
    for name in ("mkdocs.yml", "README.md"):
        shutil.copy(ROOT / name, copy / name)
    shutil.copytree(ROOT / "cfm_jax", copy / "cfm_jax", ignore=shutil.ignore_patterns("__py*"))
    shutil.copytree(ROOT / "docs", copy / "docs")
    page = copy / "docs" / "how-to" / "resume.md"
    page.write_text(page.read_text() + "\nSee [the missing page](no-such-page.md).\n")
    done = build(copy, tmp_path / "site")
    assert done.returncode != 0
    assert "no-such-page.md" in done.stdout + done.stderr


def test_pages_that_include_the_readme_point_to_it_on_github():
    # GitHub shows a page as written, the comment hidden: each line that the site replaces
    # by a README section must itself link to that section, by a heading README.md has.
    readme = (ROOT / "README.md").read_text()
    slugs = {
        re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
        for line in readme.splitlines()
        if line.startswith("## ")
    }
    marked = [
        (page, line)
        for page in (ROOT / "docs").rglob("*.md")
        for line in page.read_text().splitlines()
        if "<!-- include-readme:" in line
    ]
    assert len(marked) >= 3
    for page, line in marked:
        link = re.search(r"\]\((?:\.\./)+README\.md#([\w-]+)\)", line)
        assert link and link.group(1) in slugs, (page.name, line)
