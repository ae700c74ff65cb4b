"""``fitstiff report``: the report page of a fit, posterior or diagnose directory."""

from __future__ import annotations

import argparse

from fitstiff.cli.common import directory
from fitstiff.errors import InputError
from fitstiff.present.report import FIGURES, REPORT, REPORT_MANIFEST, RESULT_FILES, write_report

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "report", help="the report page of a fit, posterior, diagnose or fleet directory",
        description="Write a self-contained report.html (images embedded, opens offline) and "
                    f"every figure as PNG and SVG in {FIGURES}/ for the --out directory of "
                    "fitstiff fit, posterior, diagnose or fleet (which one: the "
                    f"{' or '.join(RESULT_FILES.values())} or fleet.parquet it holds). The "
                    "logs are re-read "
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
    parser.add_argument("--cylinder", metavar="NAME",
                        help="for a fitstiff fleet directory: fit this cylinder again as the "
                             "fleet did and write its report to DIR/cylinders/NAME[/RUN]/ "
                             "(the fleet page links to it)")
    parser.add_argument("--run", metavar="RUN", help="with --cylinder: which of its runs")
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    if args.run is not None and args.cylinder is None:
        raise InputError(None, "--run", "needs --cylinder", "name the cylinder too")
    if args.cylinder is not None:
        from fitstiff.present.fleet_page import cylinder_report

        if args.out is not None:
            raise InputError(None, "--out with --cylinder", "the cylinder's report goes "
                             "beside the fleet page", "leave --out out")
        path = cylinder_report(args.directory, args.cylinder, run=args.run)
        print(f"wrote {path}; run fitstiff report {args.directory} again to link it")
        return 0
    path = write_report(args.directory, out=args.out, draws=args.draws)
    print(f"wrote {path} (figures in {path.parent / FIGURES})")
    return 0
