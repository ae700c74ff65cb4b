"""A log file as text: read, decoded (UTF-8; UTF-16 named as such), split into lines and cells
at its delimiter (detected, or given), with its header; the shape checked (one column that looks
like another delimiter, duplicate names, ragged rows). Every refusal names the file and line."""

from __future__ import annotations

import codecs
import csv
import dataclasses
import functools
import hashlib
import io
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

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

    A clean file (:func:`_clean_table`: one single-character delimiter, every row as wide as
    the header, plain ASCII without quotes) is not held: its rows are the bytes ``start`` to
    ``end`` of ``path``, :meth:`numbers` parses the used columns from them a block at a time,
    and the lines are made only if a message needs a cell. Any other file keeps its data
    lines (``text``), split when a column is read (:meth:`cells`), one column at a time:
    holding a million-row log as a list of cell strings per row cost 270 MB more (issue 16).
    A file with quotes, NUL bytes or overlong lines keeps the rows ``csv`` parsed
    (``parsed``), which a line split would not reproduce.
    """

    where: str
    header: list[str] | None
    first_line: int
    delimiter: str
    n_rows: int
    sha256: str                                # of the file's bytes
    text: list[str] | None = None              # the data lines (not a clean file)
    parsed: list[list[str]] | None = None      # csv's rows of a quoted file, else None
    path: Path | None = None                   # a clean file ...
    start: int = 0                             # ... and where its data rows are
    end: int = 0

    @functools.cached_property
    def lines(self) -> list[str]:
        """The data lines (of a clean file: read when first asked for)."""
        if self.text is not None:
            return self.text
        with open(self.path, "rb") as file:
            file.seek(self.start)
            body = file.read(self.end - self.start).decode("ascii")
        return body.replace("\r\n", "\n").split("\n")

    @functools.cached_property
    def width(self) -> int:
        if self.header is not None:
            return len(self.header)
        if self.path is not None:       # a clean file's first row, without making the lines
            with open(self.path, "rb") as file:
                file.seek(self.start)
                return file.readline().count(self.delimiter.encode()) + 1
        return len(self.row(0))

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

    def numbers(self, indices: Sequence[int]) -> dict[int, np.ndarray] | None:
        """Columns ``indices`` (0-based) as numbers, parsed from a clean file a block of rows
        at a time (no text line is made); ``None`` when the file is not clean, a cell of these
        columns is not a finite plain decimal, or the file changed since it was recognised:
        then :func:`~fitstiff.io.loading._cells._values` reads the cells and names the first
        bad one.

        ``numpy.loadtxt`` converts a cell as ``float`` does (correctly rounded). On a clean
        file's cells (printable ASCII and blanks) it takes the plain decimals
        (:func:`~fitstiff.io.validation.is_decimal`) and, besides them, only ``nan``,
        ``inf`` and ``infinity`` in any case and sign, which are not finite: refused here. A
        row of another width is an error, and a blank line one row fewer: refused too."""
        if self.path is None or not indices:
            return None
        used = tuple(sorted(set(indices)))
        out = {i: np.empty(self.n_rows) for i in used}
        row, digest = 0, hashlib.sha256()
        try:
            for block in _blocks(self.path, self.start, self.end, digest):
                values = np.loadtxt(io.StringIO(block.decode("ascii"), newline=None),
                                    delimiter=self.delimiter, comments=None, usecols=used,
                                    dtype=np.float64, ndmin=2)
                if row + len(values) > self.n_rows:
                    return None
                for k, i in enumerate(used):
                    out[i][row:row + len(values)] = values[:, k]
                row += len(values)
        except (ValueError, OSError):
            return None
        if (row != self.n_rows or digest.hexdigest() != self.sha256
                or not all(np.isfinite(v).all() for v in out.values())):
            return None
        return out

    def line(self, i: int) -> int:
        return self.first_line + i

    def label(self, index: int) -> str:
        """``column 3 'force_N'`` (``index`` is 0-based)."""
        name = f" '{self.header[index]}'" if self.header is not None else ""
        return f"column {index + 1}{name}"


#: bytes of a clean file parsed at a time (:meth:`_Table.numbers`)
_BLOCK_BYTES = 16 * 2**20
#: the ASCII blanks a clean file's cell may hold (those of
#: :func:`~fitstiff.io.validation.is_decimal` but the line ends, which end a row)
_CELL_BLANKS = " \t\x0b\x0c"


def _cell_pattern(delimiter: str) -> bytes:
    """A regular expression (bytes) of any cell of a clean file: printable ASCII and the
    blanks of :data:`_CELL_BLANKS`, neither the delimiter nor a quote."""
    d = re.escape(delimiter.encode())
    return rb'[^' + d + rb'"\x00-\x08\x0a\x0d-\x1f\x7f-\xff]*'


@functools.lru_cache(maxsize=64)
def _rows_pattern(delimiter: str, width: int, limit: int) -> re.Pattern:
    """Finds the first row of a clean file that is not ``width`` cells of printable ASCII,
    or is longer than ``limit`` characters (``csv``'s field limit: such a file is read by
    ``csv``, which names the line); one lookahead per line, no backtracking state kept across
    lines."""
    cell = _cell_pattern(delimiter)
    d = re.escape(delimiter.encode())
    return re.compile(rb"^(?!(?=[^\n]{0,%d}+(?:\n|\Z))" % limit + cell
                      + (rb"(?:" + d + cell + rb")" + b"{%d}" % (width - 1)) + rb"\r?$)",
                      re.MULTILINE)


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


def _blocks(path: Path, start: int, end: int, digest):
    """The rows of ``path`` between bytes ``start`` and ``end`` in blocks of about
    :data:`_BLOCK_BYTES`, each whole rows without its last line end; ``digest`` is updated
    with every byte of the file (from its first)."""
    with open(path, "rb") as file:
        head = file.read(start)
        digest.update(head)
        carry, at = b"", start
        while True:
            chunk = file.read(_BLOCK_BYTES)
            digest.update(chunk)
            at += len(chunk)
            data = carry + chunk
            if at >= end or not chunk:
                tail = data[:len(data) - (at - end)] if at > end else data
                digest.update(file.read())
                if tail:
                    yield tail
                return
            cut = data.rfind(b"\n")
            if cut < 0:
                carry = data
                continue
            yield data[:cut]
            carry = data[cut + 1:]


def _clean_table(path: Path, *, where: str, delimiter: str | None, header: bool
                 ) -> _Table | None:
    """The table of a clean file, read a block at a time and not held, else ``None`` (then
    :func:`_table` reads it whole, line by line, and names what is wrong).

    Clean: UTF-8 (a byte-order mark allowed), LF or CRLF line ends, a single-character
    delimiter (given, or detected on the first line), a header row (when one is expected)
    that is not all numbers, then rows of exactly as many cells as the header, each of
    printable ASCII and blanks without a quote, and trailing blank lines at most. Such a file
    reads the same either way; neither held nor split into lines, a 10 M-row log (546 MB)
    loads with a peak of 910 MB against 2 935 MB, in 24 s against 44 s (issue 36)."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as file:
            opening = file.read(min(size, 1 << 20))
            last = max(size - 4096, 0)
            file.seek(last)
            ending = file.read()
    except OSError:
        return None
    if _utf16(opening):
        return None
    begin = len(codecs.BOM_UTF8) if opening.startswith(codecs.BOM_UTF8) else 0
    newline = opening.find(b"\n", begin)
    if newline < 0 or (begin and not header):     # a data row must start at a line start
        return None
    try:
        first = opening[begin:newline].decode("utf-8").removesuffix("\r")
    except UnicodeDecodeError:
        return None
    if not first.strip() or any(c in first for c in '"\x00\r'):
        return None
    if delimiter is None:
        delimiter = next((d for d in _DETECTED if d in first), WHITESPACE)
    if delimiter == WHITESPACE or len(delimiter) != 1 or delimiter in " \x0b\x0c":
        return None
    names = None
    if header:
        names = [name.strip() for name in first.split(delimiter)]
        if all(_is_number(name) for name in names):
            return None
    start = newline + 1 if header else begin
    stripped = ending.rstrip(b" \t\r\n\x0b\x0c")
    if not stripped and last > start:     # more than 4 kB of trailing blanks: read it whole
        return None
    end = last + len(stripped)
    width = len(names) if names is not None else first.count(delimiter) + 1
    if end <= start or width < 2:
        return None
    rows, digest = 0, hashlib.sha256()
    pattern = _rows_pattern(delimiter, width, csv.field_size_limit())
    for block in _blocks(path, start, end, digest):
        if pattern.search(block) is not None:
            return None
        rows += block.count(b"\n") + 1
    return _Table(where, names, 2 if header else 1, delimiter, n_rows=rows,
                  sha256=digest.hexdigest(), path=path, start=start, end=end)


def _open_table(path: Path, *, where: str, delimiter: str | None, header: bool) -> _Table:
    """The table of the file at ``path`` (clean: read a block at a time; else whole)."""
    regular_file(path)      # a named pipe or a device would block the read
    clean = _clean_table(path, where=where, delimiter=delimiter, header=header)
    if clean is not None:
        _check_shape(clean, first="", rows=False)
        return clean
    return _table(_read(path), where=where, delimiter=delimiter, header=header)


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
    parsed = _split(lines, delimiter, where=where, first_line=first_line) if whole else None
    table = _Table(where, names, first_line, delimiter,
                   n_rows=len(parsed) if parsed is not None else len(lines),
                   sha256=hashlib.sha256(raw).hexdigest(), text=lines, parsed=parsed)
    _check_shape(table, first=first)
    return table


def _check_shape(table: _Table, *, first: str, rows: bool = True) -> None:
    """One column that looks like another delimiter, duplicate names, ragged rows (``rows``:
    a clean file's rows were checked as it was recognised)."""
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
    for i, width in enumerate(table.row_widths() if rows else ()):
        if width != table.width:
            raise InputError(table.where, f"line {table.line(i)}",
                             f"has {width} fields, expected {table.width} (as on line 1)",
                             f"check the delimiter ({_show(table.delimiter)} used) and fill in "
                             "or remove the missing or extra cells")
