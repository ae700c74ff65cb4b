"""Withheld-effect benchmark of the diagnosis (DESIGN §6 step 5, issue 12).

Datasets (:mod:`fitstiff._testing.withheld`) are generated blind to the diagnosis by an
independent NumPy rig simulator (:mod:`fitstiff._testing.rig_sim`), three logs each; the
families (``single``, ``null``, ``ool``, ``pair``, ``missing``, ``law``) and their right
answers are described there. Each dataset is diagnosed with :func:`fitstiff.diagnosis.diagnose`
(``chamber+dahl``, or ``dahl`` when the chamber is withheld; all candidates) and scored by
:mod:`fitstiff._testing.withheld_scoring` (the pairs run are its ``PAIRS``).

Scores: top-1 identification (the first accepted effect, else the best-ranked
candidate), accepted-set exact match, false-alarm rate on nulls with its Wilson 95 % interval,
median shrink ``(before - after) / (before - noise)`` of the held-out RMS, "unexplained" rate on
out-of-library data, both-found rate on pairs, not-testable rate on missing excitation, the
law's candidate accepted (alone) on seals whose whole friction is another law, detectability calibration (found rate of effects at or above the size the diagnosis reports
as detectable at 80 % power) and the confusion matrix (true x first named effect), written to
``benchmarks/results/withheld.json`` and ``withheld_confusion.png``.

``--plan`` runs the closed loop of issue 33 instead (:mod:`fitstiff._testing.plan_loop`): each
dataset is diagnosed, given the planned experiment of :func:`fitstiff.planning.plan` when its
diagnosis ends with a tie, an untestable candidate, a wrong or missing name or an unexplained
structure (a null always, for its strongest candidate), the programs are run on the dataset's
rig and the logs diagnosed again; the same with the naive experiment (the longest log
replayed). Written to ``benchmarks/results/plan_loop.json`` (:func:`score_loop`'s table).

Resumable (finished datasets are kept in the JSON and skipped); one line per dataset.

    python benchmarks/withheld.py --quick                  # 3 effects, 3 nulls, 1 ool, 1 missing
    python benchmarks/withheld.py --workers 2              # the full run (~210 datasets)
    python benchmarks/withheld.py --family single --seeds 5 --nulls 0
    python benchmarks/withheld.py --effects dwell_stiction --nulls 5   # what withholds it
    python benchmarks/withheld.py --plan --family missing --seeds 4 --nulls 0
    python benchmarks/withheld.py --family single null --seeds 3 --one-log 0 --json F  # log 0 alone
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from fitstiff._testing.plan_loop import run_closed_loop, score_loop
from fitstiff._testing.withheld import FAMILIES
from fitstiff._testing.withheld_scoring import (dataset_ids, describe, plot_confusion,
                                                run_dataset, score, screened)

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
JSON_PATH = RESULTS / "withheld.json"
LOOP_PATH = RESULTS / "plan_loop.json"
FIGURE_PATH = RESULTS / "withheld_confusion.png"
#: ``--rerun-screened``: a stored screen below this p may have led to a refit (the rule
#: refits below 0.05 / the number of candidates, 0.0038 with 13)
RERUN_LEVEL = 0.01


def save_figure(summary: Mapping[str, object], path: Path = FIGURE_PATH) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = summary["confusion"]
    if not c["rows"]:
        return
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    plot_confusion(ax, c["rows"], c["cols"], np.array(c["counts"]))
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)


# ----------------------------------------------------------------------------------- runs

def _save(path: Path, records: Mapping[str, Mapping[str, object]], figure: bool,
          loop: bool = False) -> None:
    from fitstiff.io.output import to_jsonable, write_atomic

    if loop:
        write_atomic(path, json.dumps(to_jsonable({"summary": score_loop(list(records.values())),
                                                   "datasets": records}), indent=1))
        return
    summary = score(records)
    write_atomic(path, json.dumps(to_jsonable({"summary": summary, "datasets": records}),
                                  indent=1))
    if figure:
        save_figure(summary, path.with_name(path.stem + "_confusion.png"))


def run_many(ids: Sequence[str], *, workers: int = 2, rate_scale: float = 1.0,
             max_crashes: int = 2, residuals: Path | None = None, loop: bool = False,
             one_log: int | None = None) -> Iterable[dict[str, object]]:
    """Diagnose ``ids`` in a pool of ``workers`` processes, a fresh process per dataset
    (compiled code does not pile up; a crash loses one dataset, not the run). A dataset
    whose worker died ``max_crashes`` times is recorded as an error."""
    ctx = multiprocessing.get_context("spawn")
    pending = list(ids)
    crashes: dict[str, int] = {}
    while pending:
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                    max_tasks_per_child=1) as pool:
            futures = {(pool.submit(run_closed_loop, d, rate_scale) if loop else
                        pool.submit(run_dataset, d, rate_scale, residuals=residuals,
                                    one_log=one_log)): d
                       for d in pending}
            try:
                for f in cf.as_completed(futures):
                    r = f.result()
                    pending.remove(futures[f])
                    yield r
            except cf.process.BrokenProcessPool:
                # the oldest unfinished datasets were running when a worker died
                for d in pending[:workers]:
                    crashes[d] = crashes.get(d, 0) + 1
                    if crashes[d] >= max_crashes:
                        pending.remove(d)
                        yield {"id": d, "error": f"worker crashed {crashes[d]} times",
                               "wall_s": 0.0}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a small version (8 datasets)")
    parser.add_argument("--family", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    parser.add_argument("--seeds", type=int, default=5, help="seeds per effect (default 5)")
    parser.add_argument("--nulls", type=int, default=100, help="null datasets (default 100)")
    parser.add_argument("--pair-seeds", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rate-scale", type=float, default=1.0,
                        help="factor on the sample rates (smaller logs; default 1)")
    parser.add_argument("--limit", type=int, default=None, help="run at most this many")
    parser.add_argument("--effects", nargs="+", default=None, metavar="EFFECT",
                        help="only the datasets that withhold one of these (nulls are kept)")
    parser.add_argument("--ids", nargs="+", default=None, metavar="ID",
                        help="these dataset ids instead (e.g. missing/inertia/0 null/3)")
    parser.add_argument("--json", type=Path, default=JSON_PATH)
    parser.add_argument("--rerun-screened", default=None, metavar="EFFECT",
                        help="run again the stored datasets whose diagnosis may have refitted "
                             "EFFECT (anything accepted; else screened at p < 0.01, refitted, "
                             "or hidden below the ranked ones): after a change to that "
                             "candidate alone, the others' stored records stand")
    parser.add_argument("--one-log", type=int, default=None, metavar="K",
                        help="diagnose log K of each dataset alone (leave-one-block-out "
                             "folds); keep its records in their own --json")
    parser.add_argument("--no-figure", action="store_true")
    parser.add_argument("--residuals", type=Path, default=None, metavar="DIR",
                        help="keep each dataset's held-out residuals in DIR (one .npz each)")
    parser.add_argument("--plan", action="store_true",
                        help="the closed loop of the planned experiment (issue 33) instead; "
                             f"default --json {LOOP_PATH.relative_to(REPO)}")
    args = parser.parse_args(argv)
    if args.plan and args.json == JSON_PATH:
        args.json = LOOP_PATH
    records: dict[str, dict] = {}
    if args.json.exists():
        records = json.loads(args.json.read_text()).get("datasets", {})
    ids = dataset_ids(families=args.family, seeds=args.seeds, nulls=args.nulls,
                      pair_seeds=args.pair_seeds, quick=args.quick)
    if args.ids:
        ids = list(args.ids)
    if args.effects:
        ids = [d for d in ids if d.startswith("null/")
               or set(d.split("/")[1].split("+")) & set(args.effects)]
    if args.rerun_screened:
        again = [d for d in ids if d in records
                 and screened(records[d], args.rerun_screened, level=RERUN_LEVEL)]
        print(f"{len(again)} stored datasets may have refitted {args.rerun_screened}: "
              "run again", flush=True)
        for d in again:
            del records[d]
    todo = [d for d in ids if d not in records]
    if args.limit is not None:
        todo = todo[: args.limit]
    print(f"{len(ids)} datasets, {len(ids) - len(todo)} done, {len(todo)} to run "
          f"with {args.workers} worker(s)", flush=True)
    start = time.perf_counter()
    for r in run_many(todo, workers=args.workers, rate_scale=args.rate_scale,
                      residuals=args.residuals, loop=args.plan, one_log=args.one_log):
        records[r["id"]] = r
        print(_loop_line(r) if args.plan else describe(r), flush=True)
        _save(args.json, records, not args.no_figure, args.plan)
    if not todo and records:
        _save(args.json, records, not args.no_figure, args.plan)
    if args.plan:
        print(json.dumps(score_loop([v for k, v in records.items() if k in set(ids)]),
                         default=float))
        return
    summary = score({k: v for k, v in records.items() if k in set(ids)})
    print(f"wall {time.perf_counter() - start:.0f} s for {len(todo)} datasets")
    print(json.dumps({k: summary[k] for k in ("single", "null", "ool", "pair", "missing",
                                               "law", "detectability", "wall_s")},
                     default=float)[:4000])


def _loop_line(r: Mapping[str, object]) -> str:
    if "error" in r:
        return f"{r['id']}: ERROR {r['error']}"
    if r.get("reason") is None:
        return f"{r['id']}: no plan needed ({r['before']['accepted']}) {r['wall_s']:.0f} s"
    plans = "; ".join(" vs ".join(p["separates"]) for p in r.get("plan", [])) or "none"
    return (f"{r['id']}: {r['reason']}; before {r['before']['accepted']}, plan [{plans}] "
            f"({r.get('plan_s', 0):.0f} s), naive {r['after_naive']['accepted']}, planned "
            f"{r['after_planned']['accepted']} (target {r['target']}) {r['wall_s']:.0f} s")


if __name__ == "__main__":
    main()
