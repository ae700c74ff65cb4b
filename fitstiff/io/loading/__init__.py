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

A clean file (plain ASCII rows of one width, a single-character delimiter, no quotes) is
checked and parsed a block of rows at a time, without holding its text: a long log costs its
arrays, not its lines. Any other file is read whole and line by line, which is also how a bad
cell anywhere is found and named; both give the numbers of ``float`` on each cell.
"""

from __future__ import annotations

from fitstiff.io.loading._read import load_log, load_logs
from fitstiff.io.loading._text import MIN_SAMPLES

__all__ = ["MIN_SAMPLES", "load_log", "load_logs"]
