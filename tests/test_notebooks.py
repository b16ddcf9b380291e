"""Notebooks: each py:percent source runs as a script in smoke mode, and its .ipynb is in step."""

from __future__ import annotations

import importlib.util
import json
import os
import pathlib
import subprocess
import sys

import pytest

NOTEBOOKS = pathlib.Path(__file__).parent.parent / "notebooks"
SOURCES = sorted(p.name for p in NOTEBOOKS.glob("[0-9][0-9]_*.py"))
# CI runs the regularizer-on-any-policy notebook (every notebook's pairing is checked above);
# the others train programs other tests compile (quickstart, meta-RL, a report, a population)
# and are extended tests (pytest -m extended).
IN_CI = ("02_min_attention_any_policy.py",)
RUNS = [n if n in IN_CI else pytest.param(n, marks=pytest.mark.extended) for n in SOURCES]


def _pair_module():
    spec = importlib.util.spec_from_file_location("pair", NOTEBOOKS / "pair.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_notebook_is_paired_without_outputs_and_has_its_setup_cells():
    assert len(SOURCES) == 5
    assert _pair_module().main(["--check"]) == 0  # each .ipynb is its .py, regenerated
    for name in SOURCES:
        notebook = json.loads((NOTEBOOKS / name).with_suffix(".ipynb").read_text())
        code = [c for c in notebook["cells"] if c["cell_type"] == "code"]
        assert all(c["outputs"] == [] and c["execution_count"] is None for c in code), name
        assert "pip" in "".join(code[0]["source"]), name  # the Colab install cell comes first
        assert "SMOKE" in "".join(code[1]["source"]), name  # then the parameters


@pytest.mark.slow
@pytest.mark.parametrize("name", RUNS)
def test_notebook_runs_in_smoke_mode(name, tmp_path):
    env = {**os.environ, "MINATT_SMOKE": "1", "MINATT_OUT": str(tmp_path / "runs"),
           "MPLBACKEND": "Agg"}  # fmt: skip
    proc = subprocess.run([sys.executable, str(NOTEBOOKS / name)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=1200)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
