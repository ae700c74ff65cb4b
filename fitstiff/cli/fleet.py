"""``fitstiff fleet``: fit every cylinder and run of a fleet, estimate the population, flag
outliers and drift (on Dask workers)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fitstiff.cli.common import add_out_argument, add_reading_arguments, reading_options
from fitstiff.cli.fit import add_fit_arguments, fit_options
from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir
from fitstiff.physics.model import parse_fix

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "fleet", help="fit a fleet of cylinders: one row per cylinder and run, the "
                      "population, outliers and drift",
        description="Fit each cylinder (and each of its runs) of SOURCE as 'fitstiff fit' "
                    "would, on Dask workers, then estimate the population of each derived "
                    "quantity (random effects, from every estimate and its standard error), "
                    "flag outlying cylinders and cylinders that drift from run to run "
                    "(Benjamini-Hochberg at --q). Writes fleet.parquet, population.json and "
                    "a manifest; finished cylinders are kept in DIR/.fleet-cache and not "
                    "refitted by a later run on DIR unless their logs or the options changed.")
    parser.add_argument("source", metavar="SOURCE",
                        help="a folder laid out <cylinder>/[<run>/]*.csv (sidecars beside "
                             "the logs), or a manifest CSV with columns cylinder, run "
                             "(optional), file")
    add_fit_arguments(parser)
    where = parser.add_argument_group("where it runs")
    place = where.add_mutually_exclusive_group()
    place.add_argument("--workers", type=int, metavar="N",
                       help="local worker processes (default: one per core; 1: in this "
                            "process, without Dask)")
    place.add_argument("--scheduler", metavar="ADDRESS",
                       help="submit to an existing Dask scheduler, e.g. tcp://host:8786 "
                            "(its workers need fitstiff and the files)")
    where.add_argument("--lanes", type=int, default=1, metavar="N",
                       help="cylinders per vmap-ed solve (default 1: one at a time, on "
                            "the CPU; N > 1 goes to a GPU where JAX sees one, e.g. with "
                            "JAX_PLATFORMS=cuda,cpu, and takes hundreds)")
    where.add_argument("--chunk", type=int, default=8, metavar="N",
                       help="cylinders per task (default 8)")
    parser.add_argument("--diagnose", action="store_true",
                        help="also diagnose each cylinder (accepted effects, held-out RMS; "
                             "about a minute per cylinder)")
    parser.add_argument("--q", type=float, default=0.01, metavar="Q",
                        help="false-discovery rate of the outlier and drift flags "
                             "(default 0.01)")
    add_reading_arguments(parser)
    add_out_argument(parser)
    parser.set_defaults(func=run)
    return parser


def _inputs(units, fmt) -> list[Path]:
    files = []
    for unit in units:
        for path in unit.files:
            files.append(path)
            if path.with_suffix(".json").is_file():
                files.append(path.with_suffix(".json"))
    if fmt and Path(fmt).is_file():
        files.append(Path(fmt))
    return files


def run(args) -> int:
    from fitstiff.fleet import FLEET, POPULATION, discover, fit_fleet
    from fitstiff.fleet.engine import CACHE_DIR

    if not 0 < args.q < 1:
        raise InputError(None, f"--q {args.q}", "must lie strictly between 0 and 1",
                         "give e.g. 0.01")
    options = fit_options(args)
    fix = parse_fix(args.fix, args.model)
    units = discover(args.source)
    source = Path(args.source)
    manifest = [source] if source.is_file() else []
    with OutputDir(args.out, inputs=manifest + _inputs(units, args.format),
                   planned=[FLEET, POPULATION], seed=args.seed,
                   options={"model": args.model, "fix": args.fix, **options,
                            "workers": args.workers, "scheduler": args.scheduler,
                            "lanes": args.lanes, "chunk": args.chunk,
                            "diagnose": args.diagnose, "q": args.q,
                            "reading": reading_options(args)}) as out:
        shown = [0]

        def progress(done: int, total: int) -> None:
            if done == total or done - shown[0] >= max(total // 20, 1):
                shown[0] = done
                print(f"fleet: {done}/{total} cylinder-runs done", file=sys.stderr,
                      flush=True)

        table = fit_fleet(units, model=args.model, fix=fix, reading=reading_options(args),
                          workers=args.workers, scheduler=args.scheduler, lanes=args.lanes,
                          chunk=args.chunk, diagnose=args.diagnose, q=args.q,
                          cache=out.path / CACHE_DIR, progress=progress, **options)
        population = table.attrs.pop("population")
        table.to_parquet(out.temp_path(FLEET), index=False)
        out.commit(FLEET)
        out.write_json(POPULATION, population)
        out.finish()
    print(_summary(table, population))
    print(f"wrote {out.path / FLEET} and {out.path / POPULATION}")
    return 0


def _summary(table, population) -> str:
    failed = table[table["error"] != ""]
    unconverged = table[(table["error"] == "") & ~table["converged"].astype(bool)]
    lines = [f"fleet: {len(table)} cylinder-runs of {table['cylinder'].nunique()} cylinders; "
             f"{len(failed)} with an error, {len(unconverged)} not converged"]
    for name, q in population["quantities"].items():
        spread = q["spread_sd_log"]
        lines.append(f"  {name:<30} population mean {q['mean']:.4g} "
                     f"[{q['mean_interval_95'][0]:.4g}, {q['mean_interval_95'][1]:.4g}], "
                     f"spread {'n/a' if spread is None else f'{100 * spread:.1f} %'} "
                     f"({q['cylinders']} cylinders)")
    outliers, drift = population["outliers"], population["drift"]
    lines.append(f"  outliers at q = {population['q']:g}: {len(outliers)}"
                 + (": " + ", ".join(o["cylinder"] for o in outliers[:8])
                    + (" ..." if len(outliers) > 8 else "") if outliers else ""))
    lines.append(f"  drifting: {len(drift)}"
                 + (": " + ", ".join(d["cylinder"] for d in drift[:8])
                    + (" ..." if len(drift) > 8 else "") if drift else ""))
    for _, row in failed.head(5).iterrows():
        lines.append(f"  error: {row['cylinder']}{'/' + row['run'] if row['run'] else ''}: "
                     f"{row['error']}")
    return "\n".join(lines)

