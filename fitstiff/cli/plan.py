"""``fitstiff plan``: the next rig run that settles what a diagnosis could not (issue 33)."""

from __future__ import annotations

import argparse
import json

from fitstiff.cli.common import directory
from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir, to_jsonable
from fitstiff.planning import PLAN_DIR

__all__ = ["add_parser", "run", "add_limit_arguments", "limits_from_args", "write_plan"]



def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "plan", help="programs for the next rig run that settle what a diagnosis could not",
        description="Read a fitstiff diagnose directory, fit the rival explanations it could "
                    "not tell apart (ties, an accepted effect and the candidate it silenced, "
                    "candidates the logs cannot test) and search programs within the rig's "
                    "limits for the one that separates each pair best after both refit. "
                    "Writes program_<k>.csv (time_s,displacement_mm, relative to the start "
                    "position), plan.json and predicted.npz. Limits default to what the logs "
                    "and their sidecars show.")
    parser.add_argument("directory", metavar="DIAGNOSIS_DIR", type=directory,
                        help="the --out directory of fitstiff diagnose")
    parser.add_argument("--out", metavar="DIR", type=directory, default=None,
                        help=f"output directory (default DIAGNOSIS_DIR/{PLAN_DIR}, where the "
                             "diagnosis report finds it)")
    add_limit_arguments(parser)
    parser.add_argument("--separate", metavar="A[,B]", default=None,
                        help="plan for these effects instead of the diagnosis' confusions: "
                             "one (against its absence) or two (against each other)")
    parser.add_argument("--seed", type=int, default=0,
                        help="recorded with the plan (planning is deterministic)")
    parser.add_argument("--json", action="store_true", help="print plan.json to stdout")
    parser.set_defaults(func=run)
    return parser


def add_limit_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("the rig's limits on the next run")
    group.add_argument("--max-duration", type=float, metavar="S", default=None,
                       help="length of each program (default: the longest log's)")
    group.add_argument("--max-speed", type=float, metavar="MM_S", default=None,
                       help="fastest piston speed (default: the fastest logged)")
    group.add_argument("--stroke-range", type=float, nargs=2, metavar=("LOW", "HIGH"),
                       default=None, help="absolute piston positions (mm, chamber A length) "
                                          "the motion stays within (default: 5-95 %% of the "
                                          "sidecars' stroke)")
    group.add_argument("--pressures", type=float, nargs="+", metavar="BAR", default=None,
                       help="supply pressures (gauge) a program may use (default: the logged "
                            "ones)")
    group.add_argument("--rate", type=float, metavar="HZ", default=None,
                       help="sample rate of the programs (default: the logs' median)")
    group.add_argument("--max-programs", type=int, default=None, metavar="N",
                       help="at most this many programs, one per confusion (default 4)")


def limits_from_args(args, logs):
    from fitstiff.planning import Limits

    return Limits.from_logs(
        logs, max_duration_s=args.max_duration, max_speed_mm_s=args.max_speed,
        stroke_range_mm=tuple(args.stroke_range) if args.stroke_range else None,
        pressures_bar=tuple(args.pressures) if args.pressures else None,
        rate_hz=args.rate)


def write_plan(out: OutputDir, result) -> None:
    """``plan.json``, the program CSVs and ``predicted.npz`` into ``out``."""
    from fitstiff.planning import PLAN

    out.write_json(PLAN, result.to_dict())
    for name, data in result.files().items():
        out.write_bytes(name, data)


def planned_names(max_programs: int) -> list[str]:
    from fitstiff.planning import PLAN
    from fitstiff.planning.plan import PREDICTED

    return [PLAN, PREDICTED] + [f"program_{k}.csv" for k in range(1, max_programs + 1)]


def run(args) -> int:
    from fitstiff.diagnosis import RESULT, Diagnosis
    from fitstiff.inference.selection import Selection
    from fitstiff.planning import plan
    from fitstiff.planning.plan import MAX_PROGRAMS
    from fitstiff.present.reopen import open_run

    if args.max_programs is not None and args.max_programs < 1:
        raise InputError(None, f"--max-programs {args.max_programs}", "must be at least 1",
                         "give 1 or more")
    source = open_run(args.directory)
    if source.kind != "diagnosis":
        raise InputError(str(args.directory), "plan directory",
                         f"holds a {source.kind} run, not a diagnosis",
                         "give the --out directory of fitstiff diagnose")
    diagnosis = Diagnosis.from_dict(source.result)
    options = source.manifest.get("options", {})
    selection, _ = Selection.pick(options)
    limits = limits_from_args(args, source.logs)
    count = args.max_programs or MAX_PROGRAMS
    separate = [s for s in (args.separate or "").split(",") if s] or None
    out_path = args.out if args.out is not None else args.directory / PLAN_DIR
    inputs = [args.directory / RESULT] + [p for p, _ in source.inputs]
    with OutputDir(out_path, inputs=inputs, planned=planned_names(count),
                   options={"diagnosis": str(args.directory), "limits": limits.to_dict(),
                            "separate": separate, "seed": args.seed,
                            "max_programs": count}) as out:
        result = plan(diagnosis, list(source.logs), limits=limits, separate=separate,
                      max_programs=count, seed=args.seed, selection=selection)
        write_plan(out, result)
        out.finish()
    if args.json:
        print(json.dumps(to_jsonable(result.to_dict()), indent=2))
    else:
        print(result.summary())
        print(f"wrote {out.path / 'plan.json'}")
    return 0
