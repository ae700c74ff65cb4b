"""Data shipped inside the package, so ``fitstiff demo`` runs from any directory after
``pip install .``.

``fig4/`` holds copies of the four mid-stroke logs of ``data/synthetic/fig4/`` (the paper's
32 mm rodless cylinder at 0, 2, 4 and 6 bar, closed at 350 mm; each with its sidecar and
``.truth.json``). ``tests/test_report.py`` checks that they equal the generated set.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib.resources import files
from pathlib import Path
from types import MappingProxyType

__all__ = ["fig4_logs", "PAPER_RIG", "paper_rig"]

#: the paper's cylinder (Festo OSP-P 32, rodless, 700 mm stroke), closed at mid-stroke at
#: 6 bar, as sidecar keys (read-only; :func:`paper_rig` gives a copy with changes)
PAPER_RIG: Mapping[str, float | None] = MappingProxyType({
    "bore_mm": 32.0, "rod_mm": 0.0, "stroke_mm": 700.0, "start_position_mm": 350.0,
    "supply_bar": 6.0, "dead_length_a_mm": 0.0, "dead_length_b_mm": 0.0,
    "ambient_bar": 1.01325, "load_kg": None})


def paper_rig(**changes: float | None) -> dict[str, float | None]:
    """The paper's rig (:data:`PAPER_RIG`) as sidecar keys, with ``changes`` (e.g.
    ``supply_bar=4``; ``None`` leaves a key unknown), for ``Rig.from_mapping`` or a sidecar."""
    unknown = set(changes) - set(PAPER_RIG)
    if unknown:
        raise KeyError(f"not a key of the paper rig: {', '.join(sorted(unknown))} (use one "
                       f"of: {', '.join(PAPER_RIG)})")
    return {**PAPER_RIG, **changes}


def fig4_logs() -> list[Path]:
    """The bundled Fig. 4-like logs (CSV paths, sidecars and truth files beside them), by
    supply pressure."""
    folder = Path(str(files(__name__) / "fig4"))
    logs = sorted(folder.glob("p*bar_x350mm.csv"))
    if not logs:   # an install that left the package data out
        raise FileNotFoundError(f"no bundled logs in {folder}: reinstall fitstiff "
                                "(pip install .) so that its package data is included")
    return logs
