"""A log file as text: read, decoded (UTF-8; UTF-16 named as such), split into lines and cells
at its delimiter (detected, or given), with its header; the shape checked (one column that looks
like another delimiter, duplicate names, ragged rows). Every refusal names the file and line."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path


from fitstiff.errors import InputError
from fitstiff.io.columns import EXAMPLE_NAMES
from fitstiff.io.validation import regular_file


__all__ = ["MIN_SAMPLES"]

MIN_SAMPLES = 10
WHITESPACE = "whitespace"
_DETECTED = ("\t", ";", ",")                 # tried in this order on the first line
_LOOKALIKE = ("\t", ";", ",", "|", " ")      # delimiters recognised in a one-column file


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
