"""``fitstiff diagnose``: where a baseline misses the logs, which effect explains it, how far
the gap shrinks (DESIGN §6)."""

from __future__ import annotations

import argparse
import dataclasses
import io
import json

import numpy as np

from fitstiff.cli.common import (add_log_arguments, add_out_argument, input_paths, logs_from_args,
                                  model_spec, reading_options)
from fitstiff.cli.fit import add_data_arguments, problem_options
from fitstiff.cli.plan import planned_names, write_plan
from fitstiff.diagnosis import ALPHA, HELDOUT, MIN_SHRINK, RESULT, diagnose
from fitstiff.diagnosis.supermodel import CANDIDATES
from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir, to_jsonable
from fitstiff.physics.model import DEFAULT_MODEL
from fitstiff.planning import PLAN_DIR, Limits, plan
from fitstiff.planning.plan import MAX_PROGRAMS
from fitstiff.planning.rivals import confusions

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "diagnose", help="sim-to-real gap diagnosis against a baseline model",
        description="Fit the baseline, locate its held-out misfit by region against the noise "
                    "floor, screen every candidate effect with a score test, refit the "
                    "promising ones on held-out data and accept them greedily. Writes "
                    "diagnosis.json and a manifest.")
    add_log_arguments(parser)
    group = parser.add_argument_group("diagnosis")
    group.add_argument("--baseline", default=DEFAULT_MODEL, metavar="SPEC", type=model_spec,
                       help="the model whose gap is diagnosed (default chamber+dahl)")
    group.add_argument("--candidates", default="all", metavar="all|LIST",
                       help="'all' or a comma-separated list of: " + ", ".join(CANDIDATES))
    group.add_argument("--alpha", type=float, default=ALPHA,
                       help=f"family-wise level of the score screen (default {ALPHA})")
    group.add_argument("--min-shrink", type=float, default=MIN_SHRINK,
                       help="share of the held-out gap above the noise an effect must remove "
                            f"(default {MIN_SHRINK})")
    group.add_argument("--structure", action=argparse.BooleanOptionalAction, default=True,
                       help="describe what the unexplained held-out residual follows "
                            "(position, time, pressure, ...; default on)")
    group.add_argument("--plan", action=argparse.BooleanOptionalAction, default=True,
                       help="when the diagnosis ends with a tie, a rival, an untestable or an "
                            "undecided candidate, plan the next experiment (diagnosis.json's "
                            f"next_experiment, the programs in {PLAN_DIR}/; limits from the "
                            "logs, see fitstiff plan; default on). Logs that do not show the "
                            "limits get no plan: the verdict says so and how to make one")
    add_data_arguments(group)
    parser.add_argument("--json", action="store_true", help="print diagnosis.json to stdout")
    add_out_argument(parser)
    parser.set_defaults(func=run)
    return parser


def _npz(arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def run(args) -> int:
    options = problem_options(args)
    with OutputDir(args.out, inputs=input_paths(args), planned=[RESULT, HELDOUT],
                   options={"baseline": args.baseline, "candidates": args.candidates,
                            "alpha": args.alpha, "min_shrink": args.min_shrink,
                            "structure": args.structure, "plan": args.plan, **options,
                            "reading": reading_options(args)}) as out:
        logs = logs_from_args(args)
        result = diagnose(logs, baseline=args.baseline, candidates=args.candidates,
                          alpha=args.alpha, min_shrink=args.min_shrink,
                          structure=args.structure, **options)
        next_experiment = None
        if args.plan and confusions(result):
            # logs without a time column or sidecars do not show what the rig can do: the
            # diagnosis stands without a plan, and says how to make one
            try:
                limits = Limits.from_logs(logs)
            except InputError as exc:
                said = (f"the next experiment was not planned: {exc.found}; run "
                        f"`fitstiff plan {out.path}` and {exc.fix}")
                result = dataclasses.replace(result, verdict=(*result.verdict, said))
            else:
                next_experiment = plan(result, logs, limits=limits, **options)
        if next_experiment is not None:
            result = dataclasses.replace(result, next_experiment=next_experiment.to_dict())
        out.write_json(RESULT, result.to_dict())
        out.write_bytes(HELDOUT, _npz(result.heldout_arrays()))
        out.finish()
    if next_experiment is not None:
        # as fitstiff plan DIR would write it (its own manifest: fitstiff plan may replace it)
        with OutputDir(out.path / PLAN_DIR, inputs=[out.path / RESULT, *input_paths(args)],
                       planned=planned_names(MAX_PROGRAMS),
                       options={"diagnosis": str(out.path),
                                "limits": next_experiment.limits.to_dict()}) as planned:
            write_plan(planned, next_experiment)
            planned.finish()
    if args.json:
        print(json.dumps(to_jsonable(result.to_dict()), indent=2))
    else:
        print(result.summary())
        print(f"wrote {out.path / RESULT}")
    return 0
