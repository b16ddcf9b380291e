"""Keeps each notebook's two forms in step: the jupytext ``py:percent`` source and its ``.ipynb``.

The ``.py`` file is the source of truth (diffable, ruff-clean, runnable as a script); the
``.ipynb`` beside it is generated from it without outputs, for Colab and Jupyter:

    python notebooks/pair.py          # rewrite every .ipynb from its .py
    python notebooks/pair.py --check  # exit 1 if any pair differs (the tests run this check)

Cells start at ``# %%`` lines (``# %% [markdown]`` for text cells, whose lines drop their
leading ``# ``); the jupytext header (``# ---`` ... ``# ---``) is kept as notebook metadata.
"""

from __future__ import annotations

import json
import pathlib
import sys

HERE = pathlib.Path(__file__).parent


def cells(source: str) -> list[dict]:
    """The notebook cells of a py:percent text."""
    lines = source.splitlines()
    if lines and lines[0] == "# ---":
        end = lines.index("# ---", 1)
        lines = lines[end + 1 :]
    out: list[dict] = []
    kind, body = None, []

    def flush() -> None:
        if kind is None:
            return
        while body and not body[-1].strip():
            body.pop()
        while body and not body[0].strip():
            body.pop(0)
        if kind == "markdown":
            text = [line[2:] if line.startswith("# ") else line.lstrip("#") for line in body]
        else:
            text = list(body)
        source = "\n".join(text)
        cell = {"cell_type": kind, "metadata": {}, "source": _split(source)}
        if kind == "code":
            cell.update(execution_count=None, outputs=[])
        out.append(cell)

    for line in lines:
        if line.startswith("# %%"):
            flush()
            kind, body = ("markdown" if "[markdown]" in line else "code"), []
        elif kind is not None:
            body.append(line)
    flush()
    return out


def _split(text: str) -> list[str]:
    parts = text.split("\n")
    return [p + "\n" for p in parts[:-1]] + [parts[-1]] if parts else []


def notebook(py_path: pathlib.Path) -> dict:
    """The ``.ipynb`` JSON of a py:percent file (no outputs)."""
    return {
        "cells": cells(py_path.read_text()),
        "metadata": {
            "jupytext": {"formats": "ipynb,py:percent"},
            "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
            "language_info": {"name": "python"},
        },
        "nbformat": 4,
        "nbformat_minor": 5,
    }


def render(py_path: pathlib.Path) -> str:
    return json.dumps(notebook(py_path), indent=1, ensure_ascii=False) + "\n"


def sources() -> list[pathlib.Path]:
    return sorted(p for p in HERE.glob("[0-9][0-9]_*.py"))


def main(argv: list[str]) -> int:
    stale = []
    for py in sources():
        ipynb = py.with_suffix(".ipynb")
        text = render(py)
        if "--check" in argv:
            if not ipynb.exists() or ipynb.read_text() != text:
                stale.append(ipynb.name)
        else:
            ipynb.write_text(text)
    if stale:
        print("out of date (run python notebooks/pair.py): " + ", ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
