"""Shared by the notebook generators ``make_<stem>.py``: a list of ``(kind, source)`` cells ->
a notebook without outputs, with stable cell ids."""

from __future__ import annotations

import nbformat


def build(cells: list[tuple[str, str]]) -> nbformat.NotebookNode:
    """The notebook, without outputs, with stable cell ids."""
    nb = nbformat.v4.new_notebook(metadata={
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    })
    makers = {"markdown": nbformat.v4.new_markdown_cell, "code": nbformat.v4.new_code_cell}
    nb.cells = [makers[kind](source.strip("\n"), id=f"cell-{i:02d}")
                for i, (kind, source) in enumerate(cells)]
    nbformat.validate(nb)
    return nb


def render(cells: list[tuple[str, str]]) -> str:
    """The notebook file's text."""
    return nbformat.writes(build(cells))
