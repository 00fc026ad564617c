"""The notebooks of docs/notebooks/ run top to bottom (jupytext percent-format .py files,
executed with nbclient in a fresh kernel) at their reduced size, CFM_JAX_DOCS_QUICK=1.

A cell that raises fails the test with the cell's traceback. Needs the ``docs`` extra
(``pip install ".[test]"`` pulls it in)."""

from __future__ import annotations

import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "docs" / "notebooks").glob("*.py"))
PER_NOTEBOOK_SECONDS = 600


def test_the_four_notebooks_are_there():
    names = {p.stem for p in NOTEBOOKS}
    assert {"train_iiwa", "compare_losses", "own_robot", "theory_1d"} <= names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_the_page_shows_this_source_executed(path):
    """The site shows NAME.ipynb, NAME.py executed at its default size with the outputs
    kept: the same cells (sources, kinds and tags), every code cell run in order, and
    no error among the outputs. After editing NAME.py, execute it again into NAME.ipynb."""
    import jupytext
    import nbformat

    source = jupytext.read(path)
    shown = nbformat.read(path.with_suffix(".ipynb"), as_version=4)

    def cells(notebook):
        return [(c.cell_type, c.source.strip(), c.metadata.get("tags", [])) for c in notebook.cells]

    assert cells(shown) == cells(source)
    code = [c for c in shown.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1))
    kinds = [o.get("output_type") for c in code for o in c.get("outputs", [])]
    assert "error" not in kinds and "display_data" in kinds


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs_top_to_bottom(path, tmp_path, monkeypatch):
    import jupytext
    import nbformat
    from nbclient import NotebookClient

    notebook = jupytext.read(path)
    assert any(c.cell_type == "code" for c in notebook.cells)
    # The kernel inherits this environment: reduced size, the source tree under test first
    # on the path, and no display (so MuJoCo renders offscreen with EGL).
    monkeypatch.setenv("CFM_JAX_DOCS_QUICK", "1")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.delenv("DISPLAY", raising=False)
    client = NotebookClient(
        notebook,
        timeout=PER_NOTEBOOK_SECONDS,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    )
    # One more cell: which cfm_jax did the kernel import?
    notebook.cells.append(
        nbformat.v4.new_code_cell("import cfm_jax\nprint(cfm_jax.__file__, end='')")
    )
    client.execute()
    errors = [
        output
        for cell in notebook.cells
        if cell.cell_type == "code"
        for output in cell.get("outputs", [])
        if output.get("output_type") == "error"
    ]
    assert not errors
    where = notebook.cells[-1].outputs[0]["text"]
    assert where == str(ROOT / "cfm_jax" / "__init__.py")
