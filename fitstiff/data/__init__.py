"""Data shipped inside the package, so ``fitstiff demo`` runs from any directory after
``pip install .``.

``fig4/`` holds copies of the four mid-stroke logs of ``data/synthetic/fig4/`` (the paper's
32 mm rodless cylinder at 0, 2, 4 and 6 bar, closed at 350 mm; each with its sidecar and
``.truth.json``). ``tests/test_report.py`` checks that they equal the generated set.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["fig4_logs"]


def fig4_logs() -> list[Path]:
    """The bundled Fig. 4-like logs (CSV paths, sidecars and truth files beside them), by
    supply pressure."""
    folder = Path(str(files(__name__) / "fig4"))
    logs = sorted(folder.glob("p*bar_x350mm.csv"))
    if not logs:   # an install that left the package data out
        raise FileNotFoundError(f"no bundled logs in {folder}: reinstall fitstiff "
                                "(pip install .) so that its package data is included")
    return logs
