"""Every notebook in notebooks/ runs top to bottom without a cell error.

Notebooks are committed without outputs and built by a generator script ``make_<stem>.py``
beside them (where there is one); the committed file must match what the script writes.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
PATHS = sorted(NOTEBOOKS.glob("*.ipynb"))


def _generator(notebook: Path):
    script = notebook.with_name(f"make_{notebook.stem.split('_')[0]}.py")
    if not script.is_file():
        return None
    spec = importlib.util.spec_from_file_location(script.stem, script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_there_are_notebooks():
    assert PATHS, f"no notebooks in {NOTEBOOKS}"


@pytest.mark.parametrize("path", PATHS, ids=[p.name for p in PATHS])
def test_notebook_is_committed_without_outputs_and_matches_its_generator(path):
    nb = nbformat.read(path, as_version=4)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    assert all(not cell.outputs and cell.execution_count is None for cell in code)
    generator = _generator(path)
    if generator is not None:
        assert path.read_text(encoding="utf-8") == generator.render(), (
            f"{path.name} is out of date: run python notebooks/{generator.__name__}.py")


@pytest.mark.parametrize("path", PATHS, ids=[p.name for p in PATHS])
def test_notebook_executes(path, monkeypatch):
    # the kernel shares the suite's persistent compilation cache (tests/conftest.py): the
    # notebooks compile the functions the tests compile (notebook 03: 152 s -> 50 s)
    cache = os.environ.get("FITSTIFF_CACHE_DIR",
                           os.path.join(os.path.expanduser("~"), ".cache", "fitstiff", "jax"))
    if cache:
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", cache)
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()  # raises CellExecutionError, naming the cell, on any error
