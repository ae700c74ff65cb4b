"""Command-line options shared by the subcommands that read logs or write results.

A subcommand's ``add_parser`` calls :func:`add_log_arguments` (and :func:`add_out_argument` if
it writes); its ``func`` calls :func:`logs_from_args`::

    def add_parser(subparsers):
        parser = subparsers.add_parser("inspect", help="...")
        add_log_arguments(parser)
        parser.set_defaults(func=run)

    def run(args):
        logs = logs_from_args(args)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fitstiff.io.columns import CHAMBERS, ENTRY_FORM, bundled_formats
from fitstiff.io.loading import load_logs
from fitstiff.io.log import RIG_KEYS, Log
from fitstiff.io.output import LOG_SUFFIXES
from fitstiff.io.validation import cli_number

__all__ = ["add_log_arguments", "add_out_argument", "add_reading_arguments", "directory", "input_files", "input_paths",
           "logs_from_args", "model_spec", "reading_options"]


def directory(text: str) -> Path:
    """An argparse type for an output directory: an empty one is refused (``Path('')`` is
    the current directory, where ``--out ''`` used to write)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: give a directory path, e.g. results")
    return Path(text)


def model_spec(text: str) -> str:
    """An argparse type for a model spec: an empty one is refused (it used to fit the
    default model without a word)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: give terms joined by '+', e.g. "
                                         "chamber+dahl")
    return text


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """``LOG...`` plus the options that say how to read them and override rig metadata."""
    parser.add_argument("logs", nargs="+", metavar="LOG",
                        help="CSV log files (rig metadata from <stem>.json beside each)")
    add_reading_arguments(parser)


def add_reading_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that say how to read logs and override rig metadata (without ``LOG...``:
    ``fitstiff fleet`` finds its logs in a folder or a manifest)."""
    reading = parser.add_argument_group("reading foreign files")
    reading.add_argument("--columns", nargs="+", metavar="ENTRY", action=_ColumnEntries,
                         help="column mapping, one entry per quantity (time, displacement, "
                              f"force, p_a, p_b): {ENTRY_FORM}; put the LOG files first")
    reading.add_argument("--format", metavar="FILE|NAME",
                         help="format JSON file (column mapping, header, delimiter, vented "
                              "chambers, rig defaults) or a bundled format: "
                              + ", ".join(bundled_formats()))
    reading.add_argument("--no-header", action="store_true", default=None,
                         help="the files have no header row (map the columns by number)")
    reading.add_argument("--delimiter", metavar="D",
                         help="one character or comma, semicolon, tab, whitespace "
                              "(default: detected from the first line)")
    rig = parser.add_argument_group("rig metadata (overrides the sidecar JSON and --format)")
    for key in RIG_KEYS:
        unit = key.key.rsplit("_", 1)[1].upper()
        rig.add_argument(key.flag, dest=key.key, type=cli_number, metavar=unit, help=key.help)
    rig.add_argument("--vented", action="append", choices=CHAMBERS,
                     help="a chamber open to ambient (repeat for both)")


class _ColumnEntries(argparse.Action):
    """``--columns`` entries, each ``QUANTITY=COLUMN[:UNIT]``: a LOG file written after them
    is taken as one more entry (argparse cannot tell), and the command then only said "the
    following arguments are required: LOG"; now the entry is named."""

    def __call__(self, parser, namespace, values, option_string=None):
        for value in values:
            if "=" not in value:
                hint = ("; it looks like a LOG file: put the LOG files before --columns"
                        if Path(value).suffix.lower() in LOG_SUFFIXES or Path(value).exists()
                        else "")
                parser.error(f"argument --columns: entry {value!r} is not "
                             f"QUANTITY=COLUMN[:UNIT]{hint}")
        setattr(namespace, self.dest, values)


def add_out_argument(parser: argparse.ArgumentParser, *, default: str | None = None) -> None:
    """``--out DIR`` (required unless ``default`` is given)."""
    parser.add_argument("--out", metavar="DIR", type=directory, default=default,
                        required=default is None,
                        help="output directory (written atomically, with a manifest.json)")


def logs_from_args(args: argparse.Namespace) -> list[Log]:
    """Load the logs named by the options of :func:`add_log_arguments`."""
    return load_logs(args.logs, **reading_options(args))


def reading_options(args: argparse.Namespace) -> dict[str, object]:
    """Keyword arguments of :func:`~fitstiff.io.loading.load_logs` given by the options (for a
    manifest, so a report can read the logs again the same way)."""
    overrides: dict[str, object] = {k.key: getattr(args, k.key) for k in RIG_KEYS
                                    if getattr(args, k.key) is not None}
    if args.vented:
        overrides["vented"] = sorted(set(args.vented))
    return {"columns": args.columns, "no_header": args.no_header, "delimiter": args.delimiter,
            "rig_overrides": overrides, "fmt": args.format}


def input_paths(args: argparse.Namespace) -> list[Path]:
    """Every file a run will read, known from the options alone (so the output directory can
    be checked before anything is loaded): the logs, their sidecar JSONs and a format file
    (not a bundled format name), for the manifest's hashes."""
    files: list[Path] = []
    for name in args.logs:
        path = Path(name)
        files.append(path)
        sidecar = path.with_suffix(".json")
        if sidecar.is_file():
            files.append(sidecar)
    if args.format and Path(args.format).is_file():
        files.append(Path(args.format))
    return files


def input_files(logs: list[Log], args: argparse.Namespace) -> list[Path]:
    """:func:`input_paths` (kept for callers that have the logs already)."""
    del logs
    return input_paths(args)
