"""The diagnosis on the independent seal sets of issue 31 (:mod:`fitstiff._testing.independent`):
an aged junction after pauses, a seal whose friction is a Maxwell-slip law, leaky chambers
with the pressures not logged; each also without its effect (the same programs and noise:
nothing may be accepted there). Full size (the suite runs small versions in
``tests/test_diagnosis.py``), ``chamber+dahl`` baseline, every candidate. Resumable.

    python benchmarks/independent_sets.py --json benchmarks/results/independent_sets.json
    python benchmarks/independent_sets.py --only junction_dwell junction_dwell/null
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from diagnosis_sets import save_sets

from fitstiff._testing import independent
from fitstiff.diagnosis import diagnose

#: set name -> (logs, the effect that must be accepted, or None)
SETS = {
    "junction_dwell": (lambda: independent.junction_dwell(), "dwell_stiction"),
    "junction_dwell/null": (lambda: independent.junction_dwell(gain=0.0), None),
    "maxwell_seal": (lambda: independent.maxwell_seal(), "maxwell_slip"),
    "leaky_chambers": (lambda: independent.leaky_chambers(), "leakage"),
    "leaky_chambers/null": (lambda: independent.leaky_chambers(rate=0.0), None),
}


def run_set(name: str) -> dict[str, object]:
    make, effect = SETS[name]
    logs = make()
    start = time.perf_counter()
    d = diagnose(logs, baseline="chamber+dahl", candidates="all")
    wall = time.perf_counter() - start
    expected = [effect] if effect else []
    named = d.candidate(effect) if effect else None
    return {"set": name, "logs": len(logs), "samples": sum(len(log) for log in logs),
            "expected": expected, "accepted": list(d.accepted),
            "correct": list(d.accepted) == expected,
            "heldout_rms_before_N": d.gap["heldout_rms_N"],
            "heldout_rms_after_N": d.gap["final_heldout_rms_N"],
            "noise_N": d.gap["noise_N"],
            "shrink": named.shrink if named else None,
            "parameters": ({k: v["value"] for k, v in named.parameters.items()}
                           if named else None),
            "verdict": list(d.verdict), "wall_s": wall, "timing_s": dict(d.timing_s)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=list(SETS), metavar="SET")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    results = {}
    if args.json and args.json.exists():
        results = json.loads(args.json.read_text()).get("sets", {})
    for name in SETS:
        if (args.only and name not in args.only) or name in results:
            continue
        results[name] = r = run_set(name)
        print(f"{name:<20} accepted {r['accepted']} (expected {r['expected']}) "
              f"{r['heldout_rms_before_N']:.3g} -> {r['heldout_rms_after_N']:.3g} N "
              f"(noise {r['noise_N']:.3g}) {r['wall_s']:.0f} s", flush=True)
        if args.json:
            save_sets(args.json, results)


if __name__ == "__main__":
    main()
