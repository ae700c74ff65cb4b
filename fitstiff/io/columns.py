"""Where the quantities sit in a log file: column names, column mappings and format files.

**Canonical files** name their columns ``<quantity>_<unit>`` (DESIGN §2): ``time_ms``,
``displacement_mm``, ``force_N``, ``p_a_bar``, ``p_b_kPa_abs`` ... (:func:`match_header`).

**Foreign files** are read with a *column mapping*, one entry per quantity::

    quantity=COLUMN:UNIT[:flip][:scale=K]

- ``quantity``: ``time``, ``displacement``, ``force``, ``p_a`` or ``p_b``
  (displacement and force are required);
- ``COLUMN``: a header name, or a 1-based column number (all digits = a number);
- ``UNIT``: any unit pint understands with the right dimension (``ms``, ``mm``, ``N``,
  ``bar`` ...); pressures are gauge unless the unit ends in ``_abs`` (``bar_abs``);
- ``flip``: negate the channel (for a sensor whose sign convention is the opposite of ours:
  displacement and force positive toward the B cap, see :mod:`fitstiff.io.log`);
- ``scale=K``: multiply the channel by ``K`` (a calibration factor), before the unit.

On the command line: ``--columns time=1:ms displacement=5:mm:flip force=7:N:flip p_a=6:bar``.
Columns that are not mapped are ignored (raw-volt channels, say).

**Format files** (``--format FILE`` or ``--format NAME`` for a format bundled in
``fitstiff/io/formats/``) hold the same in JSON; every key is optional and keys starting with
``_`` are comments::

    {
      "_comment": "why the mapping is what it is",
      "columns": ["time=1:ms", {"quantity": "force", "column": 7, "unit": "N", "flip": true}],
      "no_header": true,
      "delimiter": "tab",
      "vented": ["b"],
      "rig": {"bore_mm": 25}
    }

``columns`` entries are mapping strings or objects with keys ``quantity``, ``column``,
``unit`` and optionally ``flip`` (bool) and ``scale`` (number). ``delimiter`` is one
character or a name: ``comma``, ``semicolon``, ``tab``, ``whitespace`` (runs of spaces/tabs).
``vented`` lists chambers open to ambient. ``rig`` holds sidecar-style rig metadata defaults.

Precedence: command-line values override the format file (the mapping per quantity); the
sidecar ``<stem>.json`` beside a log overrides the format's ``rig`` and ``vented``; the
command line overrides both.

Bundled formats
---------------
``zillen_oring``: the O-ring friction logs in ``data/real/oring``
(tab-separated, no header; time ms, 3 raw-volt columns, position mm, chamber gauge pressure
bar, rod force N; 25 mm bore). The logged chamber is the one acting on the full bore (the
upstream analysis subtracts ``p * pi * 0.0125**2``), i.e. the cap side: our chamber A; the
rod side, B, is vented. The load cell reads about ``+p * A`` at rest, while our chamber force
``-A_A * p_A`` (gauge) is negative: the force channel is flipped. With that, friction
(external force minus chamber force) must have the sign of the velocity during gross sliding;
it does (about 98 % of sliding samples in every file) only when the position channel is
flipped too: the laser position grows as chamber A shrinks. The reasoning and numbers are in
the file's ``_comment``. Read them with::

    fitstiff inspect data/real/oring/*.csv --format zillen_oring
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from fitstiff.errors import InputError
from fitstiff.io.log import Rig
from fitstiff.io.validation import describe_type, parse_decimal, read_json, shown
from fitstiff.units import Kind, UnitSpec, parse_unit

__all__ = [
    "QUANTITIES", "REQUIRED_QUANTITIES", "EXAMPLE_NAMES", "CHAMBERS", "ColumnSpec", "Format",
    "bundled_formats", "load_format", "match_header", "parse_column_spec", "parse_columns",
    "parse_delimiter", "parse_vented", "read_json_object",
]

#: quantity -> kind of unit it takes
QUANTITIES: dict[str, Kind] = {
    "time": "time", "displacement": "length", "force": "force",
    "p_a": "pressure", "p_b": "pressure",
}
REQUIRED_QUANTITIES = ("displacement", "force")
#: a canonical column name per quantity, for messages
EXAMPLE_NAMES = {"time": "time_s", "displacement": "displacement_mm", "force": "force_N",
                 "p_a": "p_a_bar", "p_b": "p_b_bar"}
CHAMBERS = ("a", "b")

ENTRY_FORM = "quantity=COLUMN:UNIT[:flip][:scale=K], e.g. force=7:N:flip"
_HEADER = re.compile(r"(time|displacement|force|p_a|p_b)(?:_(.*))?", re.IGNORECASE)

#: delimiter names -> the character ("whitespace" = runs of blanks, not a character)
DELIMITER_NAMES = {"comma": ",", "semicolon": ";", "tab": "\t", "\\t": "\t",
                   "whitespace": "whitespace", "space": "whitespace", " ": "whitespace"}


@dataclasses.dataclass(frozen=True)
class ColumnSpec:
    """Where one quantity sits: ``column`` is a header name or a 1-based number (int)."""

    quantity: str
    column: str | int
    unit: UnitSpec
    flip: bool = False
    scale: float = 1.0

    @property
    def factor(self) -> float:
        """SI value = file value * ``factor`` (unit, calibration scale and sign)."""
        return self.unit.scale * self.scale * (-1.0 if self.flip else 1.0)

    def describe(self) -> str:
        """Back in mapping form, e.g. ``force=7:N:flip``."""
        text = f"{self.quantity}={self.column}:{self.unit.text}"
        if self.flip:
            text += ":flip"
        if self.scale != 1.0:
            text += f":scale={self.scale:g}"
        return text


def match_header(name: str) -> tuple[str, str] | None:
    """``(quantity, unit text)`` for a canonical column name, ``None`` for other columns.

    >>> match_header("p_a_bar_abs"), match_header("force"), match_header("volts")
    (('p_a', 'bar_abs'), ('force', ''), None)
    """
    m = _HEADER.fullmatch(name.strip())
    return None if m is None else (m.group(1).lower(), m.group(2) or "")


def parse_column_spec(entry: str | Mapping[str, Any], *, where: str | None = None) -> ColumnSpec:
    """One mapping entry: a string ``quantity=COLUMN:UNIT[:flip][:scale=K]`` or a dict."""
    if isinstance(entry, Mapping):
        return _spec_from_dict(entry, where=where)
    if not isinstance(entry, str):
        raise InputError(where, "column mapping entry", f"found {describe_type(entry)}",
                         f"write it as {ENTRY_FORM}, or as an object with quantity, column "
                         "and unit")
    what = f"column mapping entry '{entry}'"

    def bad(found: str) -> InputError:
        fix = f"write it as {ENTRY_FORM}"
        if "=" not in entry:
            fix += " (if it is a log file, put the log files before --columns)"
        return InputError(where, what, found, fix)

    quantity, eq, rest = str(entry).partition("=")
    if not eq:
        raise bad("has no '='")
    column, *options = rest.split(":")
    if not options:
        raise bad("has no unit")
    unit, *modifiers = options
    flip, scale = False, 1.0
    for modifier in modifiers:
        key, _, value = modifier.partition("=")
        if modifier == "flip" and not flip:
            flip = True
        elif key == "scale" and value and scale == 1.0:
            scale = _number(value, where=where, what=what)
        else:
            raise bad(f"found '{modifier}' where ':flip' or ':scale=K' (each at most once) "
                      "may stand")
    return _spec(quantity.strip(), column.strip(), unit.strip(), flip, scale,
                 where=where, what=what)


def parse_columns(entries: Iterable[str | Mapping[str, Any]], *,
                  where: str | None = None) -> dict[str, ColumnSpec]:
    """A column mapping (quantity -> :class:`ColumnSpec`); each quantity at most once."""
    out: dict[str, ColumnSpec] = {}
    for entry in entries:
        spec = parse_column_spec(entry, where=where)
        if spec.quantity in out:
            raise InputError(where, f"column mapping entry '{spec.describe()}'",
                             f"maps {spec.quantity} a second time (first: "
                             f"'{out[spec.quantity].describe()}')", "keep one entry per quantity")
        out[spec.quantity] = spec
    return out


def parse_delimiter(text: str, *, where: str | None = None) -> str:
    """A delimiter option: one character, or a name (comma, semicolon, tab, whitespace)."""
    if not isinstance(text, str):
        raise InputError(where, "delimiter", f"found {describe_type(text)}",
                         "give one character or one of: " + ", ".join(DELIMITER_NAMES))
    if text in DELIMITER_NAMES:
        return DELIMITER_NAMES[text]
    if len(text) == 1 and text not in "\r\n\"":
        return text
    raise InputError(where, "delimiter", f"found {shown(text)}",
                     "give one character or one of: " + ", ".join(DELIMITER_NAMES))


def parse_vented(value: object, *, where: str | None = None, what: str = "key 'vented'"
                 ) -> frozenset[str]:
    """Chambers open to ambient: a list of ``"a"`` / ``"b"``."""
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list | tuple) or not all(c in CHAMBERS for c in items):
        raise InputError(where, what, f"found {shown(value)}",
                         'give a list of vented chambers, e.g. ["b"] (chambers: "a", "b")')
    return frozenset(items)


@dataclasses.dataclass(frozen=True)
class Format:
    """How to read a family of files: mapping, header, delimiter, vented chambers, rig defaults.

    ``None`` (or empty) means "not said": the loader's default or another layer decides.
    """

    columns: Mapping[str, ColumnSpec] = dataclasses.field(default_factory=dict)
    no_header: bool | None = None
    delimiter: str | None = None
    vented: frozenset[str] | None = None
    rig: Mapping[str, object] = dataclasses.field(default_factory=dict)
    source: str | None = None

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, source: str | None = None) -> Format:
        """From the JSON object of a format file (see the module docstring)."""
        known = ("columns", "no_header", "delimiter", "vented", "rig")
        values = {k: v for k, v in values.items() if not k.startswith("_")}
        for key, value in values.items():
            if key not in known:
                raise InputError(source, f"key '{key}'", "is not a format key",
                                 f"use one of: {', '.join(known)} (keys starting with _ are "
                                 "comments)")
        columns = values.get("columns", [])
        if not isinstance(columns, list):
            raise InputError(source, "key 'columns'", f"found {shown(columns)}",
                             f"give a list of entries {ENTRY_FORM}")
        no_header = values.get("no_header")
        if no_header is not None and not isinstance(no_header, bool):
            raise InputError(source, "key 'no_header'", f"found {shown(no_header)}",
                             "give true or false")
        rig = values.get("rig", {})
        if not isinstance(rig, Mapping):
            raise InputError(source, "key 'rig'", f"found {shown(rig)}",
                             'give an object of rig metadata, e.g. {"bore_mm": 25}')
        rig = {k: v for k, v in rig.items() if not k.startswith("_")}
        Rig.from_mapping(rig, source=source)  # names a bad key or value in the format file
        delimiter = values.get("delimiter")
        vented = values.get("vented")
        return cls(columns=parse_columns(columns, where=source), no_header=no_header,
                   delimiter=None if delimiter is None else parse_delimiter(delimiter,
                                                                            where=source),
                   vented=None if vented is None else parse_vented(vented, where=source),
                   rig=rig, source=source)


def bundled_formats() -> list[str]:
    """Names of the formats shipped in ``fitstiff/io/formats/``."""
    return sorted(p.name.removesuffix(".json") for p in _formats_dir().iterdir()
                  if p.name.endswith(".json"))


def load_format(fmt: str | os.PathLike[str] | Format) -> Format:
    """A :class:`Format` from a JSON file path or a bundled format name (a Format passes)."""
    if isinstance(fmt, Format):
        return fmt
    path = Path(fmt)
    if not path.is_file():
        if str(fmt) not in bundled_formats():
            raise InputError(str(fmt), "--format", "is neither a file nor a bundled format",
                             "give the path of a format JSON file or one of: "
                             + ", ".join(bundled_formats()))
        path = Path(str(_formats_dir().joinpath(f"{fmt}.json")))
    return Format.from_mapping(read_json_object(path), source=str(path))


def read_json_object(path: Path) -> dict[str, Any]:
    """The JSON object in ``path`` (a sidecar or a format file), read by
    :func:`fitstiff.io.validation.read_json`: malformed JSON is an :class:`InputError` with
    line/column; a pipe or device, an oversized or deeply nested file, ``NaN`` and repeated
    keys are refused."""
    values = read_json(path)
    if not isinstance(values, dict):
        raise InputError(str(path), "file", f"holds a JSON {_json_type(values)}, not an "
                         "object", 'write an object, e.g. {"bore_mm": 25}')
    return values


def _json_type(value: object) -> str:
    return {dict: "object", list: "list", str: "string", bool: "boolean", int: "number",
            float: "number", type(None): "null"}.get(type(value), type(value).__name__)


def _formats_dir():
    return resources.files("fitstiff.io").joinpath("formats")


def _number(text: str, *, where: str | None, what: str) -> float:
    value = parse_decimal(text)
    if value is None:
        value = math.nan
    if not math.isfinite(value) or value == 0:
        raise InputError(where, what, f"scale '{text}' is not a finite non-zero number",
                         f"K must be a finite non-zero number; write it as {ENTRY_FORM}")
    return value


def _spec_from_dict(entry: Mapping[str, Any], *, where: str | None) -> ColumnSpec:
    what = f"column mapping entry {json.dumps(entry)}"
    allowed = {"quantity", "column", "unit", "flip", "scale"}
    unknown = set(entry) - allowed
    missing = {"quantity", "column", "unit"} - set(entry)
    flip, scale = entry.get("flip", False), entry.get("scale", 1.0)
    typed = (isinstance(entry.get("quantity", ""), str) and isinstance(entry.get("unit", ""), str)
             and isinstance(entry.get("column", ""), str | int)
             and not isinstance(entry.get("column"), bool))
    if (unknown or missing or not typed or not isinstance(flip, bool)
            or isinstance(scale, bool) or not isinstance(scale, int | float)):
        raise InputError(where, what, "is not a valid entry",
                         'give {"quantity": ..., "column": NAME or NUMBER, "unit": ...} with '
                         'optional "flip": true/false and "scale": number, or a string '
                         + ENTRY_FORM)
    try:
        scale = float(scale)
    except OverflowError:          # an integer with hundreds of digits
        scale = math.inf
    return _spec(entry["quantity"], str(entry["column"]), entry["unit"], flip,
                 _number(repr(scale), where=where, what=what), where=where, what=what)


def _spec(quantity: str, column: str, unit: str, flip: bool, scale: float, *,
          where: str | None, what: str) -> ColumnSpec:
    if quantity not in QUANTITIES:
        raise InputError(where, what, f"unknown quantity '{quantity}'",
                         f"use one of: {', '.join(QUANTITIES)}; write it as {ENTRY_FORM}")
    index: str | int = column
    if column.isascii() and column.isdigit():     # not int('²'), not 5000 digits
        index = int(column) if len(column) <= 9 else 10**9
    if not index:
        raise InputError(where, what, f"column '{column}' is not a column",
                         f"give a header name or a 1-based column number; {ENTRY_FORM}")
    spec = parse_unit(QUANTITIES[quantity], unit, where=where, what=what)
    return ColumnSpec(quantity, index, spec, flip, scale)

