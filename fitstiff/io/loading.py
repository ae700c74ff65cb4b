"""Reading logs: a CSV file (+ sidecar JSON) -> one validated, immutable :class:`Log` in SI.

What is read (DESIGN §2):

- **Columns** by name, ``<quantity>_<unit>`` (``time_ms``, ``displacement_mm``, ``force_N``,
  ``p_a_bar``, ``p_b_kPa_abs`` ...), or through a column mapping / format file for foreign
  files (:mod:`fitstiff.io.columns`). Units are parsed with pint (:mod:`fitstiff.units`).
  Displacement and force are required; time and the chamber pressures are optional. Other
  columns are ignored and listed in ``Log.source["ignored_columns"]``.
- **Text**: UTF-8, with or without a byte-order mark; LF, CRLF or CR line ends. Trailing
  blank lines are allowed, blank lines between rows are not.
- **Delimiter**: given (``delimiter=`` / ``--delimiter``: one character or ``comma``,
  ``semicolon``, ``tab``, ``whitespace``), else detected from the first line: the first of tab,
  semicolon, comma that occurs in it, else runs of whitespace. A file that then reads as one
  column although its first line holds another delimiter is an error that names it.
- **Rig metadata** from the sidecar ``<stem>.json`` beside the CSV (keys of
  :data:`fitstiff.io.log.RIG_KEYS`, plus ``"vented": ["b"]`` for chambers open to ambient);
  layered: format file ``rig`` < sidecar < ``rig_overrides`` (the command line).

What is stored: time s (``None`` without a time column: the log is then quasi-static, and
``Log.notes`` says so), displacement m, force N, pressures Pa **absolute** (gauge + ambient).
If exactly one chamber pressure is logged and the other chamber is not declared vented, that
chamber is taken as vented and ``Log.notes`` says so.

Every problem is one :class:`~fitstiff.errors.InputError` naming the file, the line (1-based,
as in the file, header included), column or key, what was found and how to fix it. The loader
never modifies the file and never drops, clips or reorders rows.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.columns import (CHAMBERS, ENTRY_FORM, EXAMPLE_NAMES, QUANTITIES,
                                 REQUIRED_QUANTITIES, ColumnSpec, Format, load_format, match_header,
                                 parse_columns, parse_delimiter, parse_vented, read_json_object)
from fitstiff.io.log import Log, Rig
from fitstiff.io.validation import CHANNEL_LIMITS, MIN_TIME_STEP_S, exists, is_decimal, regular_file
from fitstiff.signal.spikes import find_spikes, force_scale_note, spike_note
from fitstiff.units import parse_unit

__all__ = ["MIN_SAMPLES", "load_log", "load_logs"]

MIN_SAMPLES = 10
WHITESPACE = "whitespace"
_DETECTED = ("\t", ";", ",")                 # tried in this order on the first line
_LOOKALIKE = ("\t", ";", ",", "|", " ")      # delimiters recognised in a one-column file
_OVERRIDE_SOURCE = "command-line overrides"

ColumnEntries = Sequence[str | Mapping[str, Any]]
#: one line that is a plain decimal: removing every such line of a whole column leaves nothing
#: when every cell is one (one pass; the cell loop then finds the culprit). A single
#: ``fullmatch`` of the repeated group kept a backtracking frame per line: 800 MB for a
#: million-row column (issue 16)
_DECIMAL_LINE = re.compile(r"^[ \t\r\f\v]*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)"
                           r"(?:[eE][+-]?[0-9]+)?[ \t\r\f\v]*\n", re.MULTILINE)


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


# ------------------------------------------------------------------------------------- text

@dataclasses.dataclass(frozen=True)
class _Table:
    """The cells of a log file as text; row ``i`` is on line ``first_line + i``.

    The data lines are kept as lines and split when a column is read (:meth:`cells`), one
    column at a time: holding a million-row log as a list of cell strings per row cost 270 MB
    more (issue 16). A file with quotes, NUL bytes or overlong lines keeps the rows ``csv``
    parsed (``parsed``), which a line split would not reproduce.
    """

    where: str
    header: list[str] | None
    lines: list[str]
    first_line: int
    delimiter: str
    parsed: list[list[str]] | None = None      # csv's rows of a quoted file, else None

    @property
    def n_rows(self) -> int:
        return len(self.parsed) if self.parsed is not None else len(self.lines)

    @property
    def width(self) -> int:
        return len(self.header) if self.header is not None else len(self.row(0))

    def row(self, i: int) -> list[str]:
        """The cells of row ``i``."""
        if self.parsed is not None:
            return self.parsed[i]
        return _split_line(self.lines[i], self.delimiter)

    def row_widths(self):
        """The number of cells of every row, in order."""
        if self.parsed is not None:
            return (len(row) for row in self.parsed)
        if self.delimiter == WHITESPACE:
            return (len(line.split()) for line in self.lines)
        return (line.count(self.delimiter) + 1 for line in self.lines)

    def cells(self, index: int) -> list[str]:
        """Column ``index`` (0-based) of every row, as written."""
        if self.parsed is not None:
            return [row[index] for row in self.parsed]
        if self.delimiter == WHITESPACE:
            return [line.split()[index] for line in self.lines]
        d = self.delimiter
        return [line.split(d)[index] for line in self.lines]

    def line(self, i: int) -> int:
        return self.first_line + i

    def label(self, index: int) -> str:
        """``column 3 'force_N'`` (``index`` is 0-based)."""
        name = f" '{self.header[index]}'" if self.header is not None else ""
        return f"column {index + 1}{name}"


def _split_line(line: str, delimiter: str) -> list[str]:
    """One unquoted line's cells (what ``csv`` gives for a line without quotes)."""
    return line.split() if delimiter == WHITESPACE else line.split(delimiter)


def _read(path: Path) -> bytes:
    regular_file(path)      # a named pipe or a device would block the read
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(str(path), "file", f"cannot be read ({exc.strerror})",
                         "check the path") from None


def _lines(raw: bytes, where: str) -> list[str]:
    """Decoded lines (BOM removed, any line end), trailing blank lines dropped."""
    utf16 = _utf16(raw)
    if utf16:
        raise InputError(where, "file", f"is not UTF-8 (it looks like {utf16})",
                         "save the file as UTF-8 (plain ASCII numbers are fine)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(where, f"line {line}", f"byte 0x{raw[exc.start]:02x} is not UTF-8",
                         "save the file as UTF-8 (plain ASCII numbers are fine)") from None
    if "\x00" in text:
        line = text[:text.index("\x00")].count("\n") + 1
        raise InputError(where, f"line {line}", "holds a NUL byte (not a text file)",
                         "give the CSV log itself, saved as UTF-8 text")
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise InputError(where, "file", "is empty",
                         "give a CSV log with a header row and at least "
                         f"{MIN_SAMPLES} data rows")
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            raise InputError(where, f"line {number}", "is blank",
                             "remove blank lines between rows (nothing is skipped silently)")
    return lines


def _utf16(raw: bytes) -> str:
    """``"UTF-16 LE"`` / ``"UTF-16 BE"`` (with "with its byte-order mark") when ``raw`` looks
    like UTF-16 text, else ``""``: a byte-order mark, or ASCII text whose every other byte is
    NUL (UTF-8 accepts NUL bytes, so such a file used to decode into columns of NULs)."""
    for bom, name in ((b"\xff\xfe", "UTF-16 LE"), (b"\xfe\xff", "UTF-16 BE")):
        if raw.startswith(bom):
            return f"{name} with its byte-order mark"
    head = raw[:4096]
    if len(head) < 4:
        return ""
    odd, even = head[1::2], head[0::2]
    if odd.count(0) > 0.9 * len(odd) and even.count(0) < 0.1 * len(even):
        return "UTF-16 LE"
    if even.count(0) > 0.9 * len(even) and odd.count(0) < 0.1 * len(odd):
        return "UTF-16 BE"
    return ""


def _q(text: str) -> str:
    """``repr`` of a cell or line for a message, shortened when long (one line stays short)."""
    return repr(text) if len(text) <= 40 else f"{text[:30]!r}... ({len(text)} characters)"


def _show(delimiter: str) -> str:
    return {"\t": "tab", " ": WHITESPACE, WHITESPACE: WHITESPACE}.get(delimiter, f"'{delimiter}'")


def _split(lines: list[str], delimiter: str, *, where: str, first_line: int) -> list[list[str]]:
    if delimiter == WHITESPACE:
        return [line.split() for line in lines]
    reader = csv.reader(lines, delimiter=delimiter, strict=True)
    rows, start = [], 1       # start: the line (of ``lines``) the next row begins on
    try:
        for row in reader:
            rows.append(row)
            start = reader.line_num + 1
    except csv.Error as exc:
        found, fix = str(exc), "fix the quoting of this line"
        if reader.line_num > start:     # a quote opened on line ``start`` runs on
            found = f"a quoted cell opened on this line is not closed ({exc})"
        elif "field limit" in found:
            found = f"a cell is longer than {csv.field_size_limit()} characters"
            fix = "check the delimiter and the quoting (no number is that long)"
        raise InputError(where, f"line {first_line + start - 1}", found, fix) from None
    return rows


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _table(raw: bytes, *, where: str, delimiter: str | None, header: bool) -> _Table:
    lines = _lines(raw, where)
    first = lines[0]
    if delimiter is None:
        delimiter = next((d for d in _DETECTED if d in lines[0]), WHITESPACE)
    names, first_line = None, 1
    if header:
        names = [name.strip() for name in _split(lines[:1], delimiter, where=where,
                                                 first_line=1)[0]]
        if all(_is_number(name) for name in names):
            raise InputError(where, "line 1", f"looks like data, not a header (found "
                             f"{', '.join(names[:3])} ...)",
                             "pass --no-header with a column mapping (--columns or --format), "
                             "or add a header row of names like "
                             + ", ".join(EXAMPLE_NAMES.values()))
        lines, first_line = lines[1:], 2
        if not lines:
            raise InputError(where, "file", "has a header row but no data rows",
                             f"give at least {MIN_SAMPLES} data rows")
    # without a quote character csv's rows are the lines split at the delimiter: keep the
    # lines and split a column at a time; a file with quotes, NUL bytes or a line beyond
    # csv's field limit is parsed by csv as a whole (its rows, or its error message)
    limit = csv.field_size_limit()
    whole = delimiter != WHITESPACE and any('"' in line or "\0" in line or len(line) > limit
                                            for line in lines)
    table = _Table(where, names, lines, first_line, delimiter,
                   parsed=_split(lines, delimiter, where=where, first_line=first_line)
                   if whole else None)
    _check_shape(table, first=first)
    return table


def _check_shape(table: _Table, *, first: str) -> None:
    """One column that looks like another delimiter, duplicate names, ragged rows."""
    if table.width == 1:
        seen = next((d for d in _LOOKALIKE if d != table.delimiter and d in first.strip()), None)
        if seen is not None:
            raise InputError(table.where, "line 1", f"reads as a single column {_q(first)} with "
                             f"delimiter {_show(table.delimiter)}",
                             f"the file looks {_show(seen)}-separated: pass --delimiter "
                             f"{_show(seen)}")
    if table.header is not None:
        for index, name in enumerate(table.header):
            if name in table.header[:index]:
                first_index = table.header.index(name)
                raise InputError(table.where, "header", f"columns {first_index + 1} and "
                                 f"{index + 1} are both named '{name}'",
                                 "rename or delete one of them")
    for i, width in enumerate(table.row_widths()):
        if width != table.width:
            raise InputError(table.where, f"line {table.line(i)}",
                             f"has {width} fields, expected {table.width} (as on line 1)",
                             f"check the delimiter ({_show(table.delimiter)} used) and fill in "
                             "or remove the missing or extra cells")


# ---------------------------------------------------------------------------------- columns

@dataclasses.dataclass(frozen=True)
class _Column:
    spec: ColumnSpec
    index: int      # 0-based


def _columns(table: _Table, mapping: Mapping[str, ColumnSpec]) -> dict[str, _Column]:
    found = _mapped(table, mapping) if mapping else _named(table)
    for quantity in REQUIRED_QUANTITIES:
        if quantity in found:
            continue
        if mapping:
            raise InputError(table.where, "column mapping", f"has no {quantity} entry",
                             f"add {quantity}=COLUMN:UNIT to --columns or the format file")
        raise InputError(table.where, "header", f"has no {quantity} column (columns: "
                         f"{', '.join(table.header or [])})",
                         f"name it {quantity}_<unit>, e.g. {EXAMPLE_NAMES[quantity]}, or map "
                         f"the columns with --columns {ENTRY_FORM}")
    return found


def _named(table: _Table) -> dict[str, _Column]:
    if table.header is None:
        raise InputError(table.where, "columns", "the file has no header and no column "
                         "mapping was given", f"map the columns with --columns {ENTRY_FORM} "
                         "or --format")
    found: dict[str, _Column] = {}
    for index, name in enumerate(table.header):
        match = match_header(name)
        if match is None:
            continue
        quantity, unit = match
        label = table.label(index)
        if not unit:
            raise InputError(table.where, label, "has no unit suffix",
                             f"name it {quantity}_<unit>, e.g. {EXAMPLE_NAMES[quantity]}")
        if quantity in found:
            raise InputError(table.where, f"{table.label(found[quantity].index)} and {label}",
                             f"both hold {quantity}",
                             "keep one (delete or rename the other) or pick one with --columns")
        spec = ColumnSpec(quantity, name, parse_unit(QUANTITIES[quantity], unit,
                                                     where=table.where, what=label))
        found[quantity] = _Column(spec, index)
    return found


def _mapped(table: _Table, mapping: Mapping[str, ColumnSpec]) -> dict[str, _Column]:
    found: dict[str, _Column] = {}
    for quantity, spec in mapping.items():
        what = f"column mapping entry '{spec.describe()}'"
        if isinstance(spec.column, int):
            if spec.column > table.width:
                raise InputError(table.where, what, f"the file has {table.width} columns",
                                 f"give a column number from 1 to {table.width}")
            index = spec.column - 1
        elif table.header is None:
            raise InputError(table.where, what, f"names column '{spec.column}' but the file "
                             "has no header", "give the column's 1-based number instead")
        elif spec.column not in table.header:
            raise InputError(table.where, what, f"there is no column '{spec.column}' "
                             f"(columns: {', '.join(table.header)})",
                             "give a header name or a 1-based column number")
        else:
            index = table.header.index(spec.column)
        clash = next((c for c in found.values() if c.index == index), None)
        if clash is not None:
            raise InputError(table.where, what, f"uses {table.label(index)}, already mapped "
                             f"by '{clash.spec.describe()}'", "map each column at most once")
        found[quantity] = _Column(spec, index)
    return found


# ----------------------------------------------------------------------------------- values

def _values(table: _Table, column: _Column, *, no_header: bool) -> np.ndarray:
    """The column's numbers as written in the file; the first bad cell is an error.

    A cell is a plain decimal number with an optional exponent (:func:`is_decimal`):
    ``float`` would also take ``1_000``, ``nan``, ``infinity`` or non-ASCII digits.
    """
    cells = table.cells(column.index)
    i = None
    if _DECIMAL_LINE.sub("", "\n".join(cells) + "\n"):
        i = next((i for i, c in enumerate(cells) if not is_decimal(c)), None)
    if i is not None:
        fix = "make every cell of this column a number"
        if not cells[i].strip():
            found = "the cell is empty"
            fix = "fill it in or remove the row"
        elif _is_number(cells[i]) and not np.isfinite(float(cells[i])):
            found = f"found {_q(cells[i])}, not a finite number"
            fix = "replace it with a measured value or remove the row"
        elif _is_number(cells[i]):
            found = f"found {_q(cells[i])}, not a plain decimal number"
            fix = ("write digits with an optional decimal point and exponent, e.g. 1000 or "
                   "1.5e3 (no digit separators, words or non-ASCII digits)")
        else:
            found = f"found {_q(cells[i])}, not a number"
            if "," in cells[i] and _is_number(cells[i].replace(",", ".")):
                fix = "use a decimal point, not a decimal comma"
            elif i == 0 and no_header:
                fix = "line 1 looks like a header: drop --no-header (no_header=False)"
        raise _at(table, column, i, found, fix)
    try:
        values = np.fromiter((float(c) for c in cells), dtype=np.float64, count=len(cells))
    except ValueError:      # cannot happen for plain decimals; never a traceback if it does
        i = next(i for i, c in enumerate(cells) if not _is_number(c))
        raise _at(table, column, i, f"found {_q(cells[i])}, not a number",
                  "make every cell of this column a number") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:            # an exponent beyond the float range: 1e999
        raise _at(table, column, bad[0], f"found {_q(cells[bad[0]])}, not a finite number",
                  "replace it with a measured value or remove the row")
    return values


#: channels screened for spikes (:mod:`fitstiff.signal.spikes`): display unit and SI per unit
_SHOWN = {"force": ("N", 1.0), "displacement": ("mm", 1e-3), "p_a": ("bar abs", 1e5),
          "p_b": ("bar abs", 1e5)}


def _check_magnitude(table: _Table, column: _Column, si: np.ndarray) -> None:
    """Every SI value within the channel's physical bound (:data:`CHANNEL_LIMITS`)."""
    limit = CHANNEL_LIMITS[column.spec.quantity]
    with np.errstate(over="ignore", invalid="ignore"):
        bad = np.flatnonzero(~(np.abs(si) <= limit.bound))
    if bad.size:
        i = int(bad[0])
        spec = column.spec
        scaled = f" (unit '{spec.unit.text}'" + (f", scale {spec.scale:g}" if spec.scale != 1
                                                 else "") + ")"
        absolute = " absolute" if spec.quantity.startswith("p_") else ""
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))}{scaled} = "
                  f"{si[i]:.4g} {limit.unit}{absolute}, beyond the plausible magnitude of a "
                  f"{spec.quantity.replace('p_', 'pressure ')} channel, {limit.describe()}",
                  "correct the cell or remove the row, and check the column's unit")


def _at(table: _Table, column: _Column, i: int, found: str, fix: str) -> InputError:
    return InputError(table.where, f"line {table.line(i)}, {table.label(column.index)}", found,
                      fix)


def _cell(table: _Table, column: _Column, i: int) -> str:
    return table.row(i)[column.index].strip()


def _check_time(table: _Table, column: _Column, time: np.ndarray) -> None:
    bad = np.flatnonzero(~(np.diff(time) > 0))
    if bad.size:
        i = int(bad[0])
        raise _at(table, column, i + 1, f"time does not increase: {_q(_cell(table, column, i))} "
                  f"on line {table.line(i)}, then {_q(_cell(table, column, i + 1))} on line "
                  f"{table.line(i + 1)}",
                  "time must increase strictly: correct or remove the offending row (the "
                  "loader never drops or reorders rows)")


def _check_time_step(table: _Table, column: _Column, time: np.ndarray) -> None:
    short = np.flatnonzero(np.diff(time) < MIN_TIME_STEP_S)
    if short.size:
        i = int(short[0])
        raise _at(table, column, i + 1, f"the time step from line {table.line(i)} is "
                  f"{time[i + 1] - time[i]:.3g} s, shorter than {MIN_TIME_STEP_S:g} s (1 GHz "
                  "sampling)", f"check the time unit ('{column.spec.unit.text}') and the "
                  "cells (a sampling that fast is not a force log)")


def _check_pressure(table: _Table, column: _Column, pressure: np.ndarray) -> None:
    bad = np.flatnonzero(pressure < 0)
    if bad.size:
        i = int(bad[0])
        unit = column.spec.unit
        kind = "absolute" if unit.absolute else "gauge"
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))} ({kind}) = "
                  f"{pressure[i] / 1e5:.4g} bar absolute, below vacuum",
                  f"check the unit ('{unit.text}') and whether the column is gauge or absolute "
                  "(absolute: unit ending in _abs), the sign (:flip) and ambient_bar "
                  "(--ambient-bar)")


def _check_stroke(table: _Table, column: _Column, displacement: np.ndarray, rig: Rig) -> None:
    if rig.stroke is None or rig.start_position is None:
        return
    x = rig.start_position + displacement
    bad = np.flatnonzero((x < 0) | (x > rig.stroke))
    if bad.size:
        i = int(bad[0])
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))}: x = x0 + displacement "
                  f"= {x[i] * 1e3:.4g} mm, outside the stroke 0..{rig.stroke * 1e3:.4g} mm",
                  "check the displacement unit and sign (:flip), start_position_mm "
                  "(--start-position-mm) and stroke_mm (--stroke-mm)")


# ------------------------------------------------------------------------------------- load

def _load(path: Path, layout: Format, overrides: dict[str, object]) -> Log:
    where = str(path)
    raw = _read(path)
    no_header = bool(layout.no_header)
    table = _table(raw, where=where, delimiter=layout.delimiter, header=not no_header)
    if table.n_rows < MIN_SAMPLES:
        raise InputError(where, "file", f"has {table.n_rows} data rows",
                         f"give at least {MIN_SAMPLES} samples")
    found = _columns(table, layout.columns)
    rig, vented, sidecar = _rig(path, layout, overrides)

    si = {}
    for quantity, column in found.items():
        with np.errstate(over="ignore"):
            si[quantity] = _values(table, column, no_header=no_header) * column.spec.factor
            if quantity.startswith("p_") and not column.spec.unit.absolute:
                si[quantity] = si[quantity] + rig.ambient_pressure      # stored absolute
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
        "sha256": hashlib.sha256(raw).hexdigest(),
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
    return Log(name=path.stem, displacement=si["displacement"], force=si["force"],
               time=si.get("time"), pressure_a=si.get("p_a"), pressure_b=si.get("p_b"),
               rig=rig, vented=vented, path=path, notes=tuple(notes), source=source)
