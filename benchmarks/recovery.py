"""Parameter recovery and robustness on random synthetic datasets (issue: fitting).

For each dataset (:func:`fitstiff._testing.recovery.dataset`: a true seal, slope 30-50 N/mm
and breakaway 14-21 N, and n 1.0-1.4; 4 logs of the paper's cylinder at 0, 2, 4, 6 bar gauge,
driven at 0.2, 1, 5 and 20 mm/s, with realistic noise), fit ``chamber+<friction>`` from the
default, data-driven starts, and score: converged, slope and breakaway within 2 % and within
3 standard errors, n within 0.05.

    python benchmarks/recovery.py --datasets 20 --friction dahl
    python benchmarks/recovery.py --datasets 5 --friction lugre --json out.json
"""

from __future__ import annotations

import argparse
import json
import time

from fitstiff._testing.recovery import dataset
from fitstiff.inference.fitting import fit

def score(friction: str, seed: int) -> dict[str, object]:
    logs, derived, n_true = dataset(friction, seed)
    t0 = time.perf_counter()
    result = fit(logs, f"chamber+{friction}")
    row = {"seed": seed, "converged": result.converged, "seconds": time.perf_counter() - t0,
           "n_true": n_true, "n_fit": result.value("n")}
    ok = result.converged and abs(row["n_fit"] - n_true) <= 0.05
    for key in ("presliding_slope_N_per_mm", "breakaway_N"):
        value, err = result.derived[key]
        true = derived[key]
        rel = (value - true) / true
        z = (value - true) / err if err > 0 else float("inf")
        row[key] = {"true": true, "fit": value, "stderr": err, "rel_error": rel, "z": z}
        ok = ok and abs(rel) <= 0.02 and abs(z) <= 3
    row["recovered"] = bool(ok)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=20)
    parser.add_argument("--friction", default="dahl")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    rows = []
    for seed in range(args.datasets):
        row = score(args.friction, seed)
        rows.append(row)
        s, b = row["presliding_slope_N_per_mm"], row["breakaway_N"]
        print(f"seed {seed:3d} conv {row['converged']!s:5} n {row['n_fit']:.3f}/{row['n_true']:.3f}"
              f"  slope {s['fit']:7.3f}/{s['true']:7.3f} z {s['z']:+6.2f}"
              f"  breakaway {b['fit']:7.3f}/{b['true']:7.3f} z {b['z']:+6.2f}"
              f"  {'ok' if row['recovered'] else 'MISS'}  {row['seconds']:.1f}s", flush=True)
    ok = sum(r["recovered"] for r in rows)
    print(f"recovered {ok} of {len(rows)} ({args.friction})")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
