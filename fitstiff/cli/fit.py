"""``fitstiff fit``: least-squares fit of a model to one or more logs (joint)."""

from __future__ import annotations

import argparse
import json

from fitstiff.cli.common import (add_log_arguments, add_out_argument, input_paths, logs_from_args,
                                  model_spec, reading_options)
from fitstiff.errors import InputError
from fitstiff.inference.comparison import compare
from fitstiff.inference.fitting import SOLVERS, fit
from fitstiff.inference.nuisances import OPTIONAL_NUISANCES
from fitstiff.io.output import OutputDir, to_jsonable
from fitstiff.io.validation import parse_decimal
from fitstiff.physics.model import DEFAULT_MODEL, parse_fix
from fitstiff.segments.segmentation import REGIONS

__all__ = ["add_parser", "run", "fit_options", "add_data_arguments",
           "problem_options", "FIT", "COMPARE"]

FIT = "fit.json"
COMPARE = "compare.json"
_MAX_WEIGHT = 1e6     # relative region weights beyond this are a typo, not a choice


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "fit", help="least-squares fit, joint over several logs",
        description="Fit a model (sum of terms) jointly to the logs with optimistix least "
                    "squares. Seal and chamber parameters are shared; each log has its own "
                    "force offset and initial friction state. Writes fit.json and a manifest.")
    add_log_arguments(parser)
    add_fit_arguments(parser)
    parser.add_argument("--compare", metavar="SPEC,SPEC,...",
                        help="fit several models to the same logs and rank them (held-out "
                             "error over logs with two logs or more, else BIC); writes "
                             "compare.json (every model's estimates) and the winner's "
                             "fit.json; --model, when given, joins the comparison")
    parser.add_argument("--json", action="store_true", help="print fit.json to stdout")
    add_out_argument(parser)
    # no default here: with --compare an explicit --model joins the comparison
    parser.set_defaults(func=run, model=None)
    return parser


def add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """Model and solver options shared by ``fit``, ``posterior`` and ``diagnose``."""
    group = parser.add_argument_group("model and solver")
    group.add_argument("--model", default=DEFAULT_MODEL, metavar="SPEC", type=model_spec,
                       help="terms joined by '+' (default chamber+dahl)")
    group.add_argument("--fix", action="append", default=[], metavar="NAME[=VALUE]",
                       help="hold a parameter (value in its display unit, e.g. n=1.4 or "
                            "sigma0=40); 'offset' / 'friction_state0' fix those nuisances")
    group.add_argument("--free", action="append", default=[], choices=OPTIONAL_NUISANCES,
                       help="also fit this per-log nuisance: closing_pressure (each log's "
                            "closing pressure of its closed chambers; supply_bar then only "
                            "starts it)")
    group.add_argument("--solver", choices=sorted(SOLVERS), default="lm",
                       help="least-squares solver (default lm, optimistix's "
                            "Levenberg-Marquardt)")
    group.add_argument("--starts", type=int, default=1, metavar="N",
                       help="random restarts around the data-driven start (default 1)")
    group.add_argument("--seed", type=int, default=0,
                       help="seed of the random restarts of --starts (default 0)")
    group.add_argument("--max-steps", type=int, default=400, metavar="N",
                       help="solver steps per start before it gives up (default 400)")
    add_data_arguments(group)


def _range(text):
    if not text:
        return None
    start, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return (int(start) if start else None, int(stop) if stop else None)
    except ValueError:
        raise InputError(None, f"--range {text}", "is not START:STOP",
                         "write e.g. 100:4000 or 100:") from None


def _weights(items):
    out = {}
    for item in items:
        region, sep, value = item.partition("=")
        weight = parse_decimal(value)
        if not sep or weight is None:
            raise InputError(None, f"--weight {item}", "is not REGION=W",
                             "write e.g. presliding=4")
        if not 0 <= weight <= _MAX_WEIGHT:
            raise InputError(None, f"--weight {item}", f"weight {weight:g} is outside "
                             f"0..{_MAX_WEIGHT:g}", "give a relative weight such as 4")
        out[region] = weight
    return out


def add_data_arguments(group) -> None:
    """Options that choose and prepare the data of a
    :class:`~fitstiff.inference.problem.Problem`."""
    group.add_argument("--denoise", choices=("auto", "on", "off"), default="auto",
                       help="reversal-preserving displacement denoising (default: auto, when "
                            "the displacement noise is above 0.05 um)")
    group.add_argument("--range", metavar="START:STOP",
                       help="sample range used in every log (Python slice, e.g. 100:)")
    group.add_argument("--skip", type=int, default=0, metavar="N",
                       help="warm-up samples that drive the model but weigh 0")
    group.add_argument("--weight", action="append", default=[], metavar="REGION=W",
                       help=f"extra weight of a region ({', '.join(REGIONS[:4])})")


def problem_options(args) -> dict[str, object]:
    """Keyword arguments of :class:`~fitstiff.inference.problem.Problem` given by
    :func:`add_data_arguments`."""
    return {"denoise": {"auto": "auto", "on": True, "off": False}[args.denoise],
            "sample_range": _range(args.range), "skip": args.skip,
            "weights": _weights(args.weight)}


def fit_options(args) -> dict[str, object]:
    """Keyword arguments of :func:`fitstiff.inference.fitting.fit` from the parsed options."""
    for flag, value, least in (("--max-steps", args.max_steps, 1), ("--skip", args.skip, 0)):
        if value < least:
            raise InputError(None, f"{flag} {value}", f"must be at least {least}",
                             f"give {least} or more")
    return {"solver": args.solver, "starts": args.starts, "seed": args.seed,
            "max_steps": args.max_steps, **problem_options(args), "free": args.free}


def run(args) -> int:
    options = fit_options(args)
    specs = [s for s in (args.compare or "").split(",") if s]
    if args.compare is not None and args.fix:
        raise InputError(None, "--fix with --compare", "would hold the parameter in one "
                         "model only", "compare without --fix, or fit each model on its own")
    if args.compare is not None and args.model and args.model not in specs:
        specs.append(args.model)
    model = args.model or DEFAULT_MODEL
    fix = parse_fix(args.fix, model)
    planned = [FIT] + ([COMPARE] if args.compare is not None else [])
    with OutputDir(args.out, inputs=input_paths(args), planned=planned, seed=args.seed,
                   options={"model": model if args.compare is None else args.model,
                            "fix": args.fix, **options, "compare": specs,
                            "reading": reading_options(args)}) as out:
        logs = logs_from_args(args)
        if args.compare is not None:
            comparison, results = compare(logs, specs, **options)
            print(comparison.table())
            result = results[0]
            print(f"fit.json holds the winner, {comparison.rows[0]['spec']}")
            out.write_json(COMPARE, comparison.to_dict())
        else:
            result = fit(logs, model, fix=fix, **options)
        out.write_json(FIT, result.to_dict())
        out.finish()
    if args.json:
        print(json.dumps(to_jsonable(result.to_dict()), indent=2))
    else:
        print(result.table())
        print(f"wrote {out.path / FIT}")
    return 0
