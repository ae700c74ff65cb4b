"""The unexplained-structure step (issue 32) scored on kept held-out residuals.

``benchmarks/withheld.py --residuals DIR`` keeps every dataset's held-out residuals. This
script runs :func:`fitstiff.diagnosis.structure.describe_structure` on them with the inputs
the diagnosis gives it (:func:`fitstiff._testing.withheld_scoring.structure_from_residuals`;
``tests/test_structure.py`` checks the two paths agree), writes each record's ``structure``
into the benchmark JSON(s) and prints the structure scores: descriptions accepted on nulls,
none after an accepted in-library effect, and per out-of-library kind the right variable and
the shrink. The step is cheap (about a second a dataset), so thresholds can be studied
without diagnosing the datasets again.

    python benchmarks/structure.py --residuals DIR RESULTS.json [MORE.json ...] [--out F]
        [--alpha A] [--min-shrink S]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fitstiff._testing.withheld_scoring import score, structure_from_residuals
from fitstiff.diagnosis.structure import STRUCTURE_ALPHA, STRUCTURE_MIN_SHRINK


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="+", help="withheld.py JSON files")
    parser.add_argument("--residuals", type=Path, required=True, metavar="DIR")
    parser.add_argument("--alpha", type=float, default=STRUCTURE_ALPHA,
                        help=f"the descriptions' level (default {STRUCTURE_ALPHA})")
    parser.add_argument("--min-shrink", type=float, default=STRUCTURE_MIN_SHRINK,
                        help=f"share of the gap a description must remove (default "
                             f"{STRUCTURE_MIN_SHRINK})")
    parser.add_argument("--out", type=Path, default=None,
                        help="write the merged records and scores here (JSON)")
    args = parser.parse_args(argv)
    records = {}
    for path in args.results:
        records.update(json.loads(path.read_text())["datasets"])
    seconds = []
    for did, r in sorted(records.items()):
        if "error" in r or not (args.residuals / (did.replace("/", "__") + ".npz")).exists():
            continue
        start = time.perf_counter()
        r["structure"] = structure_from_residuals(did, args.residuals, alpha=args.alpha,
                                                  min_shrink=args.min_shrink)
        seconds.append(time.perf_counter() - start)
        found = [f"{u['variable']} {u['form']} shrink {u['shrink']:.2f}"
                 for u in r["structure"] if u["accepted"]]
        print(f"{did:<36} {r['accepted']} -> {found or 'nothing'}", flush=True)
    summary = score(records)["structure"]
    summary["seconds_per_dataset"] = sum(seconds) / max(len(seconds), 1)
    for key, v in summary.items():
        if isinstance(v, dict) and "k" in v:
            print(f"{key:<26} {v['k']}/{v['n']}  (Wilson 95 % {v['wilson95'][0]:.2f}-"
                  f"{v['wilson95'][1]:.2f})")
        elif key != "per_kind":
            print(f"{key:<26} {v}")
    for kind, v in summary["per_kind"].items():
        print(f"  {kind:<22} n {v['n']} never named {v['never_named']} right "
              f"{v['right_variable']} (or confounded {v['right_or_confounded']}) "
              f"described {v['described']} shrink "
              f"{[round(s, 2) if s is not None else None for s in v['shrink']]}")
    if args.out:
        from fitstiff.io.output import to_jsonable, write_atomic
        write_atomic(args.out, json.dumps(to_jsonable({"summary": summary,
                                                       "datasets": records}), indent=1))


if __name__ == "__main__":
    main()
