"""``fitstiff inspect LOGS...``: what is in each log, before fitting anything.

A thin layer over :func:`fitstiff.segments.inspection.inspect_log` and
:func:`fitstiff.segments.segmentation.segment`: readable text per log, or ``--json`` (one object
``{"logs": [summary, ...]}``); ``--out DIR`` also writes it as ``inspect.json`` with a
manifest.
"""

from __future__ import annotations

import argparse
import contextlib
import json

from fitstiff.cli.common import add_log_arguments, directory, input_paths, logs_from_args
from fitstiff.io.output import OutputDir, to_jsonable
from fitstiff.io.validation import cli_number
from fitstiff.segments.inspection import format_summary, inspect_log
from fitstiff.segments.segmentation import DEFAULT_MIN_PAUSE, DEFAULT_PRESLIDING_RANGE, segment

__all__ = ["add_parser", "run", "INSPECT"]

INSPECT = "inspect.json"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``fitstiff inspect``."""
    parser = subparsers.add_parser(
        "inspect",
        help="summarise logs: sampling, ranges, reversals, loops, pauses, regions, metadata",
        description=(
            "Per log: samples, duration, sample rate and jitter, displacement / force / "
            "pressure ranges (mm, N, bar gauge), the segmentation (reversals, loops, pauses, "
            "share of samples per region and speed band), which rig metadata is present or "
            "missing, and what the loader assumed."),
    )
    add_log_arguments(parser)
    seg = parser.add_argument_group("segmentation")
    seg.add_argument("--threshold-mm", type=cli_number, metavar="H",
                     help="hysteresis threshold for direction reversals (default: 10 x the "
                          "estimated displacement noise, at least 4 x the sensor resolution "
                          "and 0.001 mm)")
    seg.add_argument("--presliding-range-mm", type=cli_number, metavar="D",
                     help="travel after a reversal or pause counted as presliding / dwell "
                          f"(default {DEFAULT_PRESLIDING_RANGE * 1e3:g}, or a third of the "
                          "median travel between reversals when every travel is shorter)")
    seg.add_argument("--min-pause-s", type=cli_number, metavar="T", default=DEFAULT_MIN_PAUSE,
                     help=f"shortest standstill reported as a pause (default {DEFAULT_MIN_PAUSE:g})")
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument("--out", metavar="DIR", type=directory,
                        help="also write inspect.json and manifest.json to DIR")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Load, segment and summarise every log; print text or JSON; optionally write it."""
    options = {"presliding_range": (None if args.presliding_range_mm is None
                                    else args.presliding_range_mm * 1e-3),
               "min_pause": args.min_pause_s}
    if args.threshold_mm is not None:
        options["threshold"] = args.threshold_mm * 1e-3
    out = (OutputDir(args.out, inputs=input_paths(args), planned=[INSPECT],
                     options={k: v for k, v in vars(args).items() if k != "func"})
           if args.out else None)
    with out or contextlib.nullcontext():
        logs = logs_from_args(args)
        summaries = [inspect_log(log, segmentation=segment(log, **options)) for log in logs]
        document = {"logs": summaries}
        if out:
            out.write_json(INSPECT, document)
            out.finish()
    if args.json:
        print(json.dumps(to_jsonable(document), indent=2, allow_nan=False))
    else:
        print("\n\n".join(format_summary(summary) for summary in summaries))
    return 0
