"""``fitstiff report``: the report page of a fit, posterior or diagnose directory."""

from __future__ import annotations

import argparse

from fitstiff.cli._common import directory
from fitstiff.report import FIGURES, REPORT, REPORT_MANIFEST, RESULT_FILES, write_report

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "report", help="the report page of a fit, posterior or diagnose directory",
        description="Write a self-contained report.html (images embedded, opens offline) and "
                    f"every figure as PNG and SVG in {FIGURES}/ for the --out directory of "
                    "fitstiff fit, posterior or diagnose (which one: the "
                    f"{' or '.join(RESULT_FILES.values())} it holds). The logs are re-read "
                    "from the run's manifest (their SHA-256 checked), so run it where the run "
                    "was started when the manifest has relative paths.")
    parser.add_argument("directory", metavar="DIR", type=directory,
                        help="the run's --out directory")
    parser.add_argument("--out", metavar="OUT", type=directory,
                        help=f"where to write {REPORT}, {FIGURES}/ and {REPORT_MANIFEST} "
                             "(default: DIR)")
    parser.add_argument("--draws", type=int, default=100, metavar="N",
                        help="posterior draws for the median curve and the predictive band "
                             "(default 100)")
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    path = write_report(args.directory, out=args.out, draws=args.draws)
    print(f"wrote {path} (figures in {path.parent / FIGURES})")
    return 0
