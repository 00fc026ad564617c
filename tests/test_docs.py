"""The documentation site builds with warnings as errors (``mkdocs build --strict``): a
broken link, a missing page or a docstring that names a parameter the signature lacks fails
here, and so does a public module without an API page. Needs the ``docs`` extra
(``pip install ".[test]"`` pulls it in)."""

from __future__ import annotations

import os
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

import cfm_jax

ROOT = Path(__file__).resolve().parent.parent


def public_modules() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(cfm_jax.__path__) if m.name[0] != "_")


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
        page = ROOT / "docs" / "api" / f"{name}.md"
        if not page.is_file() or f"::: cfm_jax.{name}" not in page.read_text():
            missing.append(f"docs/api/{name}.md (with '::: cfm_jax.{name}')")
        elif f"api/{name}.md" not in nav:
            missing.append(f"api/{name}.md in the nav of mkdocs.yml")
    assert not missing, "public modules without an API page: " + ", ".join(missing)


def test_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    done = build(ROOT, site)
    assert done.returncode == 0, done.stdout + done.stderr
    # The API pages hold the docstrings, the notebooks are pages, README sections and
    # figures are where the pages link them.
    training = (site / "api" / "training" / "index.html").read_text()
    assert "Run Algorithm 1 for every seed" in training
    assert "cfm_jax.training.train" in training
    for name in ("train_iiwa", "compare_losses", "own_robot", "theory_1d"):
        assert "CFM_JAX_DOCS_QUICK" in (site / "notebooks" / name / "index.html").read_text()
    results = (site / "results" / "index.html").read_text()
    assert "Operational-space control (paper Fig. 3b)" in results  # from README.md
    # The page results/ and the data folder results/ are one folder of the site.
    curves = "robustness/cells/opspace/home-default/curves.png"
    assert f'src="{curves}"' in results
    assert (site / "results" / curves).is_file()
    losses = (site / "concepts" / "losses" / "index.html").read_text()
    assert "\\mathcal{L}_{joint}" in losses  # the equations are there for MathJax


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
