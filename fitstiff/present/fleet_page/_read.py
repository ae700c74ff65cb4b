"""Reading a ``fitstiff fleet`` directory (``fleet.parquet``, ``population.json``,
``manifest.json``), and where a unit's logs and on-demand report are."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import pandas as pd

from fitstiff.errors import InputError

_MANIFEST = "manifest.json"
_NEEDED_COLUMNS = ("cylinder", "run", "run_index", "files", "converged", "identifiable",
                   "error")


class _FleetDir(NamedTuple):
    """What :func:`_read` finds in a fleet directory."""

    table: pd.DataFrame     # fleet.parquet, its text and flag columns cleaned
    population: dict        # population.json
    manifest: dict          # manifest.json


def _read(directory: Path) -> _FleetDir:
    """The fleet directory's files, read and checked (InputError naming what is wrong)."""
    from fitstiff.fleet import FLEET, POPULATION

    fix = "give the --out directory of a finished fitstiff fleet run (or run it again there)"
    missing = [name for name in (FLEET, POPULATION, _MANIFEST)
               if not (directory / name).is_file()]
    if missing:
        raise InputError(str(directory), "fleet directory", f"has no {missing[0]}", fix)
    try:
        table = pd.read_parquet(directory / FLEET)
    except Exception as exc:           # noqa: BLE001  - pyarrow raises many kinds
        raise InputError(str(directory / FLEET), "fleet table", "cannot be read ("
                         + " ".join(str(exc).split())[:120] + ")", fix) from None
    texts = {}
    for name in (POPULATION, _MANIFEST):
        try:
            texts[name] = json.loads((directory / name).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputError(str(directory / name), name, f"cannot be read ({exc})",
                             fix) from None
    absent = [c for c in _NEEDED_COLUMNS if c not in table]
    if absent:
        raise InputError(str(directory / FLEET), f"column {absent[0]!r}", "is missing", fix)
    population = texts[POPULATION]
    if not (isinstance(population, dict)
            and all(k in population for k in ("q", "quantities", "outliers", "drift"))):
        raise InputError(str(directory / POPULATION), "population", "is not a fitstiff fleet "
                         "population (q, quantities, outliers, drift)", fix)
    table = table.copy()
    table["error"] = table["error"].fillna("").astype(str)
    table["run"] = table["run"].fillna("").astype(str)
    table["cylinder"] = table["cylinder"].astype(str)
    for flag in ("converged", "identifiable"):
        table[flag] = table[flag].fillna(False).astype(bool)
    return _FleetDir(table, population, texts[_MANIFEST])


def cylinder_dir(cylinder: str, run: str = "") -> Path:
    """Where a unit's on-demand report lives, relative to the fleet directory."""
    return Path("cylinders") / cylinder / run if run else Path("cylinders") / cylinder


def _files(files: str, manifest: Mapping) -> list[Path]:
    """A row's ``files`` as paths; relative ones from where the fleet was run."""
    cwd = Path(manifest.get("cwd") or ".")
    return [p if p.is_absolute() else cwd / p
            for p in (Path(f) for f in str(files).split(";") if f)]
