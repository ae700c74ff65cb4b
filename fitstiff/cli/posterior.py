"""``fitstiff posterior``: emcee posterior of a model given logs, resumable.

Writes into ``--out``: ``posterior.json`` (DESIGN §5), ``chain.h5`` (the emcee chain),
``posterior.nc`` (ArviZ InferenceData), ``predictive.npz`` (model-force draws for the report)
and ``manifest.json``. While sampling, the chain grows in ``.chain.h5.partial.h5``; an interrupted
or failed run keeps it (and nothing else), and ``--resume`` continues from its last step.
``--out`` is claimed and locked before anything is loaded (:class:`fitstiff.io.output.OutputDir`).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path
from signal import SIGINT

import numpy as np

from fitstiff.interrupts import Interrupted, pending
from fitstiff.cli.common import (add_log_arguments, add_out_argument, input_paths, logs_from_args,
                                  reading_options)
from fitstiff.cli.fit import add_fit_arguments, fit_options
from fitstiff.errors import InputError
from fitstiff.inference.likelihood import NOISE_MODELS
from fitstiff.inference.posterior import (CHAIN, DEFAULT_MOVES, DEFAULT_NOISE_MODEL, INFERENCE_DATA,
                                          MOVES, PREDICTIVE, sample_posterior)
from fitstiff.io.output import NO_ROOM, OutputDir, ensure_room, to_jsonable
from fitstiff.io.validation import cli_number
from fitstiff.physics.model import parse_fix

__all__ = ["add_parser", "run", "POSTERIOR", "PLANNED"]

POSTERIOR = "posterior.json"
PLANNED = (POSTERIOR, CHAIN, INFERENCE_DATA, PREDICTIVE)
"""The files ``fitstiff posterior`` writes into ``--out`` (besides ``manifest.json``)."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "posterior", help="emcee posterior, resumable",
        description="Sample the posterior of a model given the logs with emcee, starting "
                    "from the least-squares fit. Runs until the chain is longer than "
                    "--tau-multiple autocorrelation times (or --steps), writes "
                    "posterior.json, the chain (chain.h5), ArviZ InferenceData "
                    "(posterior.nc), model-force draws (predictive.npz) and a manifest.")
    add_log_arguments(parser)
    add_fit_arguments(parser)
    group = parser.add_argument_group("sampler")
    group.add_argument("--walkers", type=int, default=32, metavar="N",
                       help="ensemble size, at least twice the sampled coordinates (default 32)")
    group.add_argument("--steps", type=int, default=20_000, metavar="N",
                       help="step cap, including the steps of a resumed run (default 20000)")
    group.add_argument("--tau-multiple", type=cli_number, default=50.0, metavar="K",
                       help="converged when the chain is K autocorrelation times long "
                            "(default 50)")
    group.add_argument("--check-every", type=int, default=500, metavar="N",
                       help="steps between convergence checks (default 500)")
    group.add_argument("--noise-model", choices=sorted(NOISE_MODELS), default=DEFAULT_NOISE_MODEL,
                       help="ar1: autocorrelated residuals (default); gaussian: white; "
                            "student_t: outliers")
    group.add_argument("--priors", metavar="FILE",
                       help='JSON priors in display units, e.g. {"sigma0": {"dist": "normal", '
                            '"mean": 40, "sd": 10, "unit": "N/mm"}}')
    group.add_argument("--thin", type=int, metavar="N",
                       help="keep every N-th step (default: half the autocorrelation time)")
    group.add_argument("--draws", type=int, default=200, metavar="N",
                       help="posterior draws of the model force kept for the report "
                            "(default 200)")
    group.add_argument("--moves", choices=list(MOVES), default=DEFAULT_MOVES,
                       help="emcee proposal: de (differential evolution, default), de+snooker, "
                            "stretch (emcee's default)")
    group.add_argument("--sample-offsets", action="store_true",
                       help="sample the per-log force offsets instead of integrating them out "
                            "analytically (automatic for student_t noise or offset priors)")
    group.add_argument("--resume", action="store_true",
                       help="continue the chain in --out (interrupted, or to more --steps)")
    parser.add_argument("--json", action="store_true", help="print posterior.json to stdout")
    add_out_argument(parser)
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    options = fit_options(args)
    fix = parse_fix(args.fix, args.model)
    inputs = input_paths(args) + ([Path(args.priors)] if args.priors else [])
    with OutputDir(args.out, inputs=inputs, planned=PLANNED, seed=args.seed,
                   options={"model": args.model, "fix": args.fix, **options,
                            "reading": reading_options(args),
                            "noise_model": args.noise_model, "walkers": args.walkers,
                            "steps": args.steps, "tau_multiple": args.tau_multiple,
                            "priors": args.priors, "resume": args.resume,
                            "moves": args.moves,
                            "sample_offsets": args.sample_offsets}) as out:
        logs = logs_from_args(args)
        partial = out.partial_path(CHAIN)
        if args.resume and not partial.exists():
            if not (out.path / CHAIN).exists():
                raise InputError(str(out.path), "--resume", f"holds no {CHAIN} to continue",
                                 "run without --resume first")
            shutil.copyfile(out.path / CHAIN, partial)   # the finished chain stays until replaced
        elif not args.resume:
            partial.unlink(missing_ok=True)
        try:
            posterior = sample_posterior(
                logs, args.model, fix=fix, fit_options=options,
                noise_model=args.noise_model, priors=args.priors, walkers=args.walkers,
                steps=args.steps, tau_multiple=args.tau_multiple,
                check_every=args.check_every, thin=args.thin, seed=args.seed,
                backend=partial, resume=args.resume, draws=args.draws, moves=args.moves,
                integrate_offsets=not args.sample_offsets, release=True,
                interrupted=lambda: pending() is not None)
        except KeyboardInterrupt as exc:
            stop = exc if isinstance(exc, Interrupted) else Interrupted(pending() or SIGINT)
            if partial.exists():
                stop.kept = (f"the chain so far is kept in {partial}; continue it with "
                             "--resume")
            raise stop from None
        except OSError as exc:
            if exc.errno not in NO_ROOM or not partial.exists():
                raise
            raise InputError(str(partial), "chain", f"stopped: {exc.strerror}",
                             "the chain so far is kept there: free some space and continue "
                             "it with --resume") from None
        out.commit_partial(CHAIN)
        data = posterior.to_inference_data()
        ensure_room(out.path, 2 * data.posterior.nbytes, what=INFERENCE_DATA)   # HDF5 too
        data.to_netcdf(str(out.temp_path(INFERENCE_DATA)))
        out.commit(INFERENCE_DATA)
        with open(out.temp_path(PREDICTIVE), "wb") as fh:
            np.savez_compressed(fh, **posterior.predictive)
        out.commit(PREDICTIVE)
        content = posterior.to_dict() | {"outputs": {"chain": CHAIN,
                                                     "inference_data": INFERENCE_DATA,
                                                     "predictive": PREDICTIVE}}
        out.write_json(POSTERIOR, content)
        out.finish()
    if args.json:
        print(json.dumps(to_jsonable(content), indent=2))
    else:
        print(posterior.table())
        print(f"wrote {out.path / POSTERIOR}")
    return 0
