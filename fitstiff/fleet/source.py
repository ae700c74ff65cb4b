"""Where a fleet's logs are: a folder ``<cylinder>/[<run>/]*.csv`` or a manifest CSV.

:func:`discover` turns either into :class:`Unit` s, one per cylinder and run, sorted by
cylinder and run order. A bad *layout* (no such folder, a log at the top level, a cylinder
folder that mixes logs and run folders, a manifest without its columns) is an
:class:`~fitstiff.errors.InputError` (exit 2, one line): nothing can be fitted until it is
fixed. A bad *cylinder* (an unreadable log, a missing file, a sidecar without a key) is not a
layout error: it becomes that cylinder's row with its one-line error (:mod:`fitstiff.fleet.work`).

Runs are ordered by their names read as numbers when every run of the fleet is a number, else
as ISO dates when every one is a date, else as text; a cylinder's runs are indexed 0, 1, ...
in that order (the drift test's run axis, :mod:`fitstiff.fleet.population`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from collections.abc import Iterable
from datetime import date
from pathlib import Path

import pandas as pd

from fitstiff.errors import InputError
from fitstiff.io.output import LOG_SUFFIXES

__all__ = ["Unit", "discover", "MANIFEST_COLUMNS", "input_hash"]

#: a manifest CSV's columns (``run`` may be left out: one run per cylinder)
MANIFEST_COLUMNS = ("cylinder", "run", "file")


@dataclasses.dataclass(frozen=True)
class Unit:
    """One cylinder's logs of one run: what one row of ``fleet.parquet`` fits.

    Attributes:
        cylinder: the cylinder's name (its folder, or the manifest's ``cylinder``).
        run: the run's name (its folder, the manifest's ``run``; ``""``: a single run).
        run_index: the run's position among the cylinder's runs (0, 1, ...).
        files: the logs, sorted (a sidecar ``<stem>.json`` beside each is read with it).
    """

    cylinder: str
    run: str
    run_index: int
    files: tuple[Path, ...]


def _is_log(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in LOG_SUFFIXES and not path.name.startswith(".")


def _visible_dirs(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


def _from_folder(root: Path) -> list[tuple[str, str, tuple[Path, ...]]]:
    loose = sorted(p.name for p in root.iterdir() if _is_log(p))
    if loose:
        raise InputError(str(root), "fleet folder", f"holds logs at its top level "
                         f"({', '.join(loose[:3])}{' ...' if len(loose) > 3 else ''})",
                         "put each cylinder's logs in a folder of its own: "
                         "SOURCE/<cylinder>/[<run>/]*.csv")
    cylinders = _visible_dirs(root)
    if not cylinders:
        raise InputError(str(root), "fleet folder", "has no cylinder folders",
                         "lay the logs out as SOURCE/<cylinder>/[<run>/]*.csv, or give a "
                         "manifest CSV with columns cylinder, run, file")
    out = []
    for cylinder in cylinders:
        logs = tuple(sorted(p for p in cylinder.iterdir() if _is_log(p)))
        runs = _visible_dirs(cylinder)
        if logs and runs:
            raise InputError(str(cylinder), "cylinder folder", "holds both logs and run "
                             f"folders ({runs[0].name}/)", "put every log of a cylinder "
                             "with runs into its run's folder")
        if not runs:
            out.append((cylinder.name, "", logs))     # no logs: that cylinder's row says so
        for run in runs:
            out.append((cylinder.name, run.name, tuple(sorted(p for p in run.iterdir()
                                                              if _is_log(p)))))
    return out


def _from_manifest(path: Path) -> list[tuple[str, str, tuple[Path, ...]]]:
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise InputError(str(path), "fleet manifest", f"cannot be read ({exc})",
                         "give a CSV with columns cylinder, run (optional), file") from None
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in ("cylinder", "file") if c not in table.columns]
    if missing:
        raise InputError(str(path), f"column {missing[0]!r}", "is missing (found "
                         f"{', '.join(map(repr, table.columns)) or 'no columns'})",
                         "give a header row with cylinder, run (optional), file")
    if table.empty:
        raise InputError(str(path), "fleet manifest", "lists no logs",
                         "give one row per log: cylinder, run, file")
    groups: dict[tuple[str, str], list[Path]] = {}
    for row, record in enumerate(table.to_dict("records"), start=2):
        cylinder = record["cylinder"].strip()
        if not cylinder:
            raise InputError(str(path), f"row {row}, column 'cylinder'", "is empty",
                             "name the cylinder of every log")
        file = record["file"].strip()
        if not file:
            raise InputError(str(path), f"row {row}, column 'file'", "is empty",
                             "give the log's path (relative to the manifest's folder)")
        run = str(record.get("run", "")).strip()
        groups.setdefault((cylinder, run), []).append(path.parent / file)
    return [(c, r, tuple(sorted(files))) for (c, r), files in groups.items()]


def _run_order(names: Iterable[str]):
    """The sort key of run names: numbers, else ISO dates, else text (one rule per fleet)."""
    names = [n for n in set(names) if n]

    def number(text):
        value = float(text)
        if not math.isfinite(value):
            raise ValueError(text)
        return value

    for parse in (number, date.fromisoformat):
        try:
            for n in names:
                parse(n)
        except ValueError:
            continue
        return lambda n, parse=parse: (0, parse(n)) if n else (-1, 0)
    return lambda n: (0, n)


def discover(source: str | os.PathLike) -> list[Unit]:
    """The units (cylinder, run, logs) of ``source``: a folder laid out
    ``<cylinder>/[<run>/]*.csv`` or a manifest CSV (columns ``cylinder``, ``run`` optional,
    ``file`` relative to the manifest's folder). Sorted by cylinder, then run order.

    Raises:
        InputError: ``source`` is missing, or its layout is not one of the two.
    """
    path = Path(source)
    if path.is_dir():
        found = _from_folder(path)
    elif path.is_file():
        found = _from_manifest(path)
    else:
        raise InputError(str(path), "fleet source", "does not exist",
                         "give a folder <cylinder>/[<run>/]*.csv or a manifest CSV")
    order = _run_order(run for _, run, _ in found)
    found.sort(key=lambda item: (item[0], order(item[1])))
    units, index = [], {}
    for cylinder, run, files in found:
        k = index.get(cylinder, 0)
        index[cylinder] = k + 1
        units.append(Unit(cylinder, run, k, files))
    return units


def input_hash(unit: Unit, settings: str) -> str:
    """SHA-256 of what a unit's row depends on: its logs' and sidecars' bytes (a missing
    file counts as missing) and ``settings`` (model and options, as text)."""
    digest = hashlib.sha256(settings.encode())
    digest.update(f"{unit.cylinder}\0{unit.run}\0".encode())
    for file in unit.files:
        for part in (file, file.with_suffix(".json")):
            digest.update(part.name.encode() + b"\0")
            try:
                digest.update(part.read_bytes())
            except OSError:
                digest.update(b"<missing>")
    return digest.hexdigest()
