"""The diagnosis on the bundled synthetic sets: each effect withheld from ``chamber+dahl``, and
the null set (DESIGN §6 step 5, issue 11's "must show").

For every folder of ``data/synthetic/effects/`` (one effect added to ``chamber+dahl`` in the
data) and ``data/synthetic/null/`` (no effect), run :func:`fitstiff.diagnose` with the
``chamber+dahl`` baseline and all candidates, and record: the effect ranked first (by score
p-value), the accepted set, held-out RMS before/after, shrink, noise floor and wall time.
These sets come from the same simulator as the fit (the blind, differently integrated
benchmark is ``benchmarks/withheld.py``, issue 12); they check that every effect can be named
at all. Resumable: finished sets are kept in the JSON and skipped.

    python benchmarks/diagnosis_sets.py --json benchmarks/results/diagnosis_sets.json
    python benchmarks/diagnosis_sets.py --only viscous null
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fitstiff.diagnosis import diagnose
from fitstiff.io.loading import load_logs
from fitstiff.io.output import to_jsonable, write_atomic

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"


def sets() -> dict[str, Path]:
    out = {p.name: p for p in sorted((DATA / "effects").iterdir()) if p.is_dir()}
    out["null"] = DATA / "null"
    return out


def run_set(name: str, folder: Path) -> dict[str, object]:
    logs = load_logs(sorted(str(p) for p in folder.glob("*.csv")))
    start = time.perf_counter()
    d = diagnose(logs, baseline="chamber+dahl", candidates="all")
    wall = time.perf_counter() - start
    ranked = sorted(d.candidates, key=lambda c: (c.p_value, -c.score))
    expected = [] if name == "null" else [name]
    return {"set": name, "logs": len(logs), "samples": sum(len(log) for log in logs),
            "expected": expected, "top1": ranked[0].effect if ranked else None,
            "top1_p": ranked[0].p_value if ranked else None,
            "accepted": list(d.accepted), "correct": list(d.accepted) == expected,
            "heldout_rms_before_N": d.gap["heldout_rms_N"],
            "heldout_rms_after_N": d.gap["final_heldout_rms_N"],
            "noise_N": d.gap["noise_N"],
            "shrink": (d.candidate(name).shrink if name != "null" and name in
                       [c.effect for c in d.candidates] else None),
            "verdict": list(d.verdict), "wall_s": wall, "timing_s": dict(d.timing_s)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="SET")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    results = {}
    if args.json and args.json.exists():
        results = json.loads(args.json.read_text()).get("sets", {})
    for name, folder in sets().items():
        if args.only and name not in args.only:
            continue
        if name in results:
            continue
        results[name] = run_set(name, folder)
        r = results[name]
        print(f"{name:<18} top1 {r['top1']:<18} accepted {r['accepted']} "
              f"{r['heldout_rms_before_N']:.3g} -> {r['heldout_rms_after_N']:.3g} N "
              f"(noise {r['noise_N']:.3g}) {r['wall_s']:.0f} s", flush=True)
        if args.json:
            save_sets(args.json, results)


def save_sets(path: Path, results: dict[str, dict]) -> None:
    """The resumable results file of a set benchmark: a summary (sets right) and every set."""
    summary = {"correct": sum(v["correct"] for v in results.values()), "sets": len(results)}
    write_atomic(path, json.dumps(to_jsonable({"summary": summary, "sets": results}), indent=1))


if __name__ == "__main__":
    main()
