"""Speed of a full diagnosis: 4 logs x 5 000 samples against the whole library, cold.

Issue 11's target: <= 60 s on 2 cores, cold (a fresh process, no compilation cache). The
logs are ``chamber+dahl+viscous`` at 0/2/4/6 bar and 1/3/10/30 mm/s (so one effect is found
and the greedy loop runs two screens). Reported: the wall time of ``diagnose`` split into set-up,
baseline (fit, compilations, held-out folds) and selection (screens and refits), and the
share that is compilation, measured as the cold minus the warm time of a second identical call
in the same process (the compiled functions belong to the problem, so the second call builds
its own; the persistent compilation cache makes it warm).

    python benchmarks/diagnosis_speed.py --json benchmarks/results/diagnosis_speed.json
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

SAMPLES = 5000
LOGS = ((0.0, 1.0), (2.0, 3.0), (4.0, 10.0), (6.0, 30.0))   # (supply bar, rate mm/s)


def make_logs():
    from fitstiff.log import Rig
    from fitstiff.programs import TriangleCycles
    from fitstiff.simulate import Noise, simulate

    out = []
    for k, (bar, rate) in enumerate(LOGS):
        rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35,
                  supply_pressure=bar * 1e5)
        program = TriangleCycles(amplitudes_mm=(0.2, 0.5, 1.0, 2.0), rate_mm_s=rate,
                                 cycles=1)
        duration = program.sample(1000.0)[0][-1]
        rate_hz = SAMPLES / duration
        sim = simulate("chamber+dahl+viscous", program, rig=rig,
                       params={"n": 1.4, "sigma0": 40, "Fc": 18, "c": 100}, seed=k,
                       rate_hz=rate_hz, name=f"log{k}",
                       noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0))
        out.append(sim.log)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    # cold: no persistent compilation cache for the first call
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", tempfile.mkdtemp())
    from fitstiff.diagnosis import diagnose

    logs = make_logs()
    runs = []
    for label in ("cold", "second"):
        start = time.perf_counter()
        d = diagnose(logs, baseline="chamber+dahl", candidates="all")
        wall = time.perf_counter() - start
        runs.append({"run": label, "wall_s": wall, "timing_s": dict(d.timing_s),
                     "accepted": list(d.accepted)})
        print(f"{label}: {wall:.1f} s {d.timing_s} accepted {d.accepted}", flush=True)
    result = {"logs": len(logs), "samples": [len(log) for log in logs],
              "cpu_count": os.cpu_count(), "runs": runs,
              "compilation_estimate_s": runs[0]["wall_s"] - runs[1]["wall_s"],
              "target_s": 60.0}
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
