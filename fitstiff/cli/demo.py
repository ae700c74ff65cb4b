"""``fitstiff demo``: the whole pipeline on the bundled synthetic logs, ending in a report.

Runs, as a user would, ``fitstiff fit`` and ``fitstiff posterior`` on the four Fig. 4-like
logs shipped with the package (:func:`fitstiff.data.fig4_logs`) and writes the posterior's
report: ``OUT/fit/``, ``OUT/posterior/`` with ``OUT/posterior/report.html``.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Sequence

from fitstiff.cli.common import add_out_argument
from fitstiff.cli.fit import FIT
from fitstiff.cli.posterior import PLANNED
from fitstiff.data import fig4_logs
from fitstiff.io.output import OutputDir
from fitstiff.physics.model import DEFAULT_MODEL
from fitstiff.present.report import PLANNED as REPORT_PLANNED
from fitstiff.present.report import REPORT, REPORT_MANIFEST, write_report

__all__ = ["add_parser", "run", "MODEL", "CHAINS"]

MODEL = DEFAULT_MODEL
CHAINS: dict[str, dict[str, int]] = {
    "default": {"steps": 6000, "check_every": 250, "draws": 100},
    "quick": {"steps": 120, "check_every": 60, "draws": 20},
}
"""emcee settings of the demo. The default chain runs until fitstiff's convergence rule holds
(50 autocorrelation times, stable between checks); the step cap is a safety net. With the
differential-evolution proposal and the force offsets integrated out, the autocorrelation time
on these logs is about 20 steps, so the chain converges after some 1 500-2 500 steps.
``--quick`` is a smoke test (does not converge)."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "demo", help="the whole pipeline on bundled synthetic data",
        description="Fit chamber+dahl to the bundled Fig. 4-like synthetic logs (the paper's "
                    "32 mm rodless cylinder at 0, 2, 4 and 6 bar, true sigma0 = 40 N/mm, "
                    "Fc = 18 N, n = 1.4), sample its posterior with emcee until it converges and "
                    f"write the report: OUT/fit/, OUT/posterior/ and OUT/posterior/{REPORT}.")
    add_out_argument(parser, default="fitstiff-demo")
    parser.add_argument("--quick", action="store_true",
                        help=f"a {CHAINS['quick']['steps']}-step chain instead of "
                             f"{CHAINS['default']['steps']} (a smoke test: seconds, not minutes)")
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    chain = CHAINS["quick" if args.quick else "default"]
    logs = [str(path) for path in fig4_logs()]
    fit_dir, posterior_dir = args.out / "fit", args.out / "posterior"
    # claim every directory the steps write before the first step runs (the steps' own
    # claims nest inside these): a clash or a busy directory stops the demo before any work
    claims = [OutputDir(args.out, manifest_name=None),
              OutputDir(fit_dir, inputs=logs, planned=[FIT]),
              OutputDir(posterior_dir, inputs=logs, planned=PLANNED),
              OutputDir(posterior_dir, planned=REPORT_PLANNED, manifest_name=REPORT_MANIFEST)]
    with contextlib.ExitStack() as stack:
        for claim in claims:
            stack.enter_context(claim)
        _subcommand(["fit", *logs, "--model", MODEL, "--out", str(fit_dir)])
        _subcommand(["posterior", *logs, "--model", MODEL, "--steps", str(chain["steps"]),
                     "--check-every", str(chain["check_every"]), "--draws", str(chain["draws"]),
                     "--out", str(posterior_dir)])
        print(f"\n$ fitstiff report {posterior_dir}")
        report = write_report(posterior_dir, draws=chain["draws"])
    print(f"\nThe report: {report}\n(open it in a browser; the least-squares fit's own report: "
          f"fitstiff report {fit_dir})")
    return 0


def _subcommand(argv: Sequence[str]) -> None:
    """Run one fitstiff subcommand in this process, echoing its command line."""
    from fitstiff.cli import build_parser

    print(f"\n$ fitstiff {' '.join(argv)}", flush=True)
    args = build_parser().parse_args(list(argv))
    args.func(args)
