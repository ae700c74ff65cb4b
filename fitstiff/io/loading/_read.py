""":func:`load_log` and :func:`load_logs`: a file, its sidecar and the reading options (a
format, a column mapping, rig overrides) into one validated :class:`~fitstiff.io.log.Log` in SI
units, with the spike and scale screens' notes."""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.columns import (CHAMBERS, Format, load_format, parse_columns, parse_delimiter,
                                 parse_vented, read_json_object)
from fitstiff.io.loading._cells import (_SHOWN, _check_magnitude, _check_pressure, _check_stroke,
                                        _check_time, _check_time_step, _columns, _values)
from fitstiff.io.loading._text import MIN_SAMPLES, _open_table, _show
from fitstiff.io.log import Log, Rig
from fitstiff.io.validation import exists
from fitstiff.signal.spikes import find_spikes, force_scale_note, spike_note

__all__ = ["load_log", "load_logs"]

_OVERRIDE_SOURCE = "command-line overrides"

ColumnEntries = Sequence[str | Mapping[str, Any]]


def load_log(path: str | os.PathLike[str], *, columns: ColumnEntries | None = None,
             no_header: bool | None = None, delimiter: str | None = None,
             rig_overrides: Mapping[str, object] | None = None,
             fmt: str | os.PathLike[str] | Format | None = None) -> Log:
    """Read one log file into a validated :class:`~fitstiff.io.log.Log` (SI units).

    Args:
        path: the CSV file. Its sidecar ``<stem>.json``, if present, gives rig metadata.
        columns: column mapping entries ``quantity=COLUMN:UNIT[:flip][:scale=K]``; each
            overrides the format file's entry for that quantity. Without any mapping, columns
            are found by their ``<quantity>_<unit>`` names.
        no_header: the file has no header row (``None``: as the format says, else ``False``).
        delimiter: one character or ``comma``/``semicolon``/``tab``/``whitespace``
            (``None``: as the format says, else detected).
        rig_overrides: sidecar-style keys (``{"stroke_mm": 100, "vented": ["b"]}``) that
            override the sidecar and the format file.
        fmt: a format file path or a bundled format name (``"zillen_oring"``).

    Raises:
        InputError: for any problem with the file, sidecar, mapping or metadata.

    Example::

        >>> log = load_log("run1.csv")                      # doctest: +SKIP
        >>> log.force[:3], log.rig.bore                     # doctest: +SKIP
        >>> oring = load_log("O-ring_3bar.csv", fmt="zillen_oring")        # doctest: +SKIP
        >>> raw = load_log("raw.txt", no_header=True, delimiter="tab",      # doctest: +SKIP
        ...                columns=["time=1:ms", "displacement=5:mm", "force=7:N:flip"])
    """
    layout = _layout(columns=columns, no_header=no_header, delimiter=delimiter, fmt=fmt)
    return _load(Path(path), layout, dict(rig_overrides or {}))


def load_logs(paths: Iterable[str | os.PathLike[str]], *,
              columns: ColumnEntries | None = None, no_header: bool | None = None,
              delimiter: str | None = None, rig_overrides: Mapping[str, object] | None = None,
              fmt: str | os.PathLike[str] | Format | None = None) -> list[Log]:
    """:func:`load_log` for several files with the same options (the format is read once)."""
    paths = list(paths)
    if not paths:
        raise InputError(None, "log files", "none given", "give at least one CSV log file")
    layout = _layout(columns=columns, no_header=no_header, delimiter=delimiter, fmt=fmt)
    logs = [_load(Path(p), layout, dict(rig_overrides or {})) for p in paths]
    _refuse_repeats(paths)
    return logs


def _refuse_repeats(paths: Sequence[str | os.PathLike[str]]) -> None:
    """One file, or two files of the same content, given twice would be fitted as two logs
    of independent data: every standard error shrinks by sqrt(2) without a word."""
    files: dict[str, str] = {}
    sizes: dict[int, list[str]] = {}
    for p in map(str, paths):
        real = os.path.realpath(p)
        repeat = files.get(real)
        same = "is the same file as"
        if repeat is None:
            size = os.path.getsize(real)
            same = "has the same content as"
            repeat = next((q for q in sizes.get(size, []) if _digest(q) == _digest(p)), None)
            sizes.setdefault(size, []).append(p)
        if repeat is not None:
            raise InputError(p, "log", f"{same} {repeat} (given twice)",
                             "give each log once: a repeated log counts its data twice and "
                             "shrinks every standard error by sqrt(2)")
        files[real] = p


def _digest(path: str | os.PathLike[str]) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


# ---------------------------------------------------------------------------------- options

def _layout(*, columns: ColumnEntries | None, no_header: bool | None, delimiter: str | None,
            fmt: str | os.PathLike[str] | Format | None) -> Format:
    """The format file with the explicit options laid over it."""
    base = Format() if fmt is None else load_format(fmt)
    return dataclasses.replace(
        base,
        columns={**base.columns, **parse_columns(columns or [])},
        no_header=base.no_header if no_header is None else no_header,
        delimiter=base.delimiter if delimiter is None else parse_delimiter(delimiter),
    )


def _rig(path: Path, layout: Format, overrides: Mapping[str, object]
         ) -> tuple[Rig, frozenset[str], Path | None]:
    """Rig metadata and vented chambers: format ``rig`` < sidecar < overrides."""
    sidecar = path.with_suffix(".json")
    has_sidecar = exists(sidecar)     # a pipe or directory in its place is an error, not absent
    rig_values = dict(layout.rig)
    vented = layout.vented or frozenset()
    for layer, source in ((read_json_object(sidecar) if has_sidecar else {}, str(sidecar)),
                          (overrides, _OVERRIDE_SOURCE)):
        if source != _OVERRIDE_SOURCE:
            for key, value in layer.items():
                if value is None and not key.startswith("_"):
                    raise InputError(source, f"key '{key}'", "is null",
                                     "give a number in the key's unit, or leave the key out "
                                     "to leave the value unset")
        values = {k: v for k, v in layer.items() if not k.startswith("_") and v is not None}
        if "vented" in values:
            vented = parse_vented(values.pop("vented"), where=source)
        Rig.from_mapping(values, source=source)  # a bad key or value names its own layer
        rig_values.update(values)
    # the sidecar is where a missing value belongs, so later messages name it
    rig = Rig.from_mapping(rig_values, source=str(sidecar))
    return rig, vented, sidecar if has_sidecar else None


# ------------------------------------------------------------------------------------- load

def _load(path: Path, layout: Format, overrides: dict[str, object]) -> Log:
    where = str(path)
    no_header = bool(layout.no_header)
    table = _open_table(path, where=where, delimiter=layout.delimiter, header=not no_header)
    if table.n_rows < MIN_SAMPLES:
        raise InputError(where, "file", f"has {table.n_rows} data rows",
                         f"give at least {MIN_SAMPLES} samples")
    found = _columns(table, layout.columns)
    rig, vented, sidecar = _rig(path, layout, overrides)

    si = {}
    numbers = table.numbers([c.index for c in found.values()])
    for quantity, column in found.items():
        values = (numbers.pop(column.index) if numbers is not None
                  else _values(table, column, no_header=no_header))     # a fresh array
        with np.errstate(over="ignore"):
            values *= column.spec.factor            # in place: a long log's column is large
            if quantity.startswith("p_") and not column.spec.unit.absolute:
                values += rig.ambient_pressure      # stored absolute
        si[quantity] = values
        _check_magnitude(table, column, si[quantity])
    if "time" in si:
        _check_time(table, found["time"], si["time"])
        _check_time_step(table, found["time"], si["time"])
    for chamber in CHAMBERS:
        if f"p_{chamber}" in si:
            _check_pressure(table, found[f"p_{chamber}"], si[f"p_{chamber}"])
    _check_stroke(table, found["displacement"], si["displacement"], rig)

    notes = []
    if "time" not in si:
        notes.append("no time column: treated as quasi-static")
    spiked: dict[str, list[int]] = {}
    for quantity, (unit, scale) in _SHOWN.items():
        spikes = find_spikes(si[quantity]) if quantity in si else []
        spiked[quantity] = [s.sample for s in spikes]
        if spikes:
            notes.append(spike_note(quantity.replace("p_", "pressure "), unit, scale, spikes,
                                    first_line=table.first_line))
    scale = force_scale_note(np.delete(si["force"], spiked["force"]), bore=rig.bore,
                             supply_pressure=rig.supply_pressure)
    if scale:
        notes.append(scale)
    logged = [c for c in CHAMBERS if f"p_{c}" in si]
    if len(logged) == 1:
        other = "b" if logged == ["a"] else "a"
        if other not in vented:
            vented |= {other}
            notes.append(f"only chamber {logged[0].upper()}'s pressure is logged and chamber "
                         f"{other.upper()} is not declared vented: chamber {other.upper()} is "
                         f"taken as vented (at ambient); say \"vented\": [\"{other}\"] in the "
                         "sidecar to confirm, or log its pressure")

    used = {c.index for c in found.values()}
    source = {
        "path": where,
        "sha256": table.sha256,
        "delimiter": _show(table.delimiter),
        "header": table.header is not None,
        "rows": table.n_rows,
        "columns": {q: {"column": c.index + 1,
                        "name": None if table.header is None else table.header[c.index],
                        "unit": c.spec.unit.text, "absolute": c.spec.unit.absolute,
                        "flip": c.spec.flip, "scale": c.spec.factor}
                    for q, c in found.items()},
        "ignored_columns": [table.header[i] if table.header is not None else i + 1
                            for i in range(table.width) if i not in used],
        "format": layout.source,
        "sidecar": None if sidecar is None else str(sidecar),
    }
    for values in si.values():      # handed over: the log takes them without a copy
        values.flags.writeable = False
    return Log(name=path.stem, displacement=si["displacement"], force=si["force"],
               time=si.get("time"), pressure_a=si.get("p_a"), pressure_b=si.get("p_b"),
               rig=rig, vented=vented, path=path, notes=tuple(notes), source=source)
