"""Notebooks: each .ipynb is its py:percent source (jupytext pairs them), and every notebook
executes cell by cell in a Jupyter kernel (nbclient) in smoke mode; a failing cell fails the test
with that cell's traceback."""

from __future__ import annotations

import os
import pathlib

import jupytext
import nbformat
import pytest

NOTEBOOKS = pathlib.Path(__file__).parent.parent / "notebooks"
SOURCES = sorted(p.name for p in NOTEBOOKS.glob("[0-9][0-9]_*.py"))


def cells(notebook: nbformat.NotebookNode) -> list[tuple[str, str]]:
    return [(c.cell_type, c.source) for c in notebook.cells]


def test_every_notebook_is_a_jupytext_pair_without_outputs_and_has_its_setup_cells():
    assert len(SOURCES) == 5
    for name in SOURCES:
        source = jupytext.read(NOTEBOOKS / name)
        paired_path = (NOTEBOOKS / name).with_suffix(".ipynb")
        paired = nbformat.read(paired_path, as_version=4)
        nbformat.validate(paired)  # nbformat 4.5: every cell has an id
        assert all("id" in c for c in paired.cells), name
        assert cells(paired) == cells(source), f"{paired_path} differs: jupytext --sync {name}"
        code = [c for c in paired.cells if c.cell_type == "code"]
        assert all(c.outputs == [] and c.execution_count is None for c in code), name
        assert "pip" in code[0].source, name  # the Colab install cell comes first
        assert "SMOKE" in code[1].source, name  # then the parameters


@pytest.mark.slow
@pytest.mark.parametrize("name", SOURCES)
def test_notebook_executes_in_a_kernel_in_smoke_mode(name, tmp_path, monkeypatch):
    from nbclient import NotebookClient

    # The kernel inherits this environment: smoke settings, outputs under tmp_path, and the test
    # run's compilation cache (tests/conftest.py), so programs other tests compiled load from it.
    monkeypatch.setenv("MINATT_SMOKE", "1")
    monkeypatch.setenv("MINATT_OUT", str(tmp_path / "runs"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read((NOTEBOOKS / name).with_suffix(".ipynb"), as_version=4)
    client = NotebookClient(notebook, timeout=1200, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})  # fmt: skip
    client.execute()
    outputs = [o for c in notebook.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"], name
    assert outputs, f"{name} printed nothing"
    assert os.environ["JAX_COMPILATION_CACHE_DIR"]
