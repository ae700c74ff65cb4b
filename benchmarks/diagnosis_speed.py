"""Speed of a full diagnosis against the whole library, cold.

Two sizes, both ``chamber+dahl+viscous`` logs at 0/2/4/6 bar and 1/3/10/30 mm/s (so one
effect is found and the greedy loop runs two screens):

- ``--size small``: 4 logs x 5 000 samples; issue 11's target <= 60 s on 2 cores, cold.
- ``--size real``: 32 000 + 3 x 6 400 samples, the size of real seal logs; issue 31's target
  <= 90 s on 2 cores, cold.

Cold means a fresh process and an empty compilation cache. Reported: the wall time of
``diagnose`` split as ``Diagnosis.timing_s`` splits it (set-up, baseline fit, held-out folds,
screens, refits, the rest), the time JAX spent tracing and compiling (summed from JAX's own
compile events, so it overlaps the phases it happened in), and a second identical call in the
same process, warm (the persistent compilation cache serves its compilations). With
``--solves``, every least-squares solve of the diagnosis is also timed and its trial steps
counted, grouped by the candidates it frees (where the refits' time goes).

    python benchmarks/diagnosis_speed.py --size real --json benchmarks/results/diagnosis_speed_real.json
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

LOGS = ((0.0, 1.0), (2.0, 3.0), (4.0, 10.0), (6.0, 30.0))   # (supply bar, rate mm/s)
SIZES = {"small": (5000, 5000, 5000, 5000), "real": (32000, 6400, 6400, 6400)}
TARGETS = {"small": 60.0, "real": 90.0}
#: JAX's compile events (jax._src.dispatch): tracing, lowering and XLA's compilation
_COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
                   "/jax/core/compile/jaxpr_to_mlir_module_duration",
                   "/jax/core/compile/backend_compile_duration")


def make_logs(samples=SIZES["small"]):
    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate

    out = []
    for k, ((bar, rate), size) in enumerate(zip(LOGS, samples)):
        rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35,
                  supply_pressure=bar * 1e5)
        program = TriangleCycles(amplitudes_mm=(0.2, 0.5, 1.0, 2.0), rate_mm_s=rate,
                                 cycles=1)
        duration = program.sample(1000.0)[0][-1]
        rate_hz = size / duration
        sim = simulate("chamber+dahl+viscous", program, rig=rig,
                       params={"n": 1.4, "sigma0": 40, "Fc": 18, "c": 100}, seed=k,
                       rate_hz=rate_hz, name=f"log{k}",
                       noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0))
        out.append(sim.log)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=sorted(SIZES), default="small")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--solves", action="store_true",
                        help="time every solve and count its steps, by the candidates it frees")
    args = parser.parse_args()
    # cold: no persistent compilation cache for the first call
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        cache = tempfile.mkdtemp(prefix="fitstiff-speed-cache-")
        atexit.register(shutil.rmtree, cache, ignore_errors=True)
        os.environ["JAX_COMPILATION_CACHE_DIR"] = cache
    import jax

    from fitstiff.diagnosis import diagnose

    compiling = {event: 0.0 for event in _COMPILE_EVENTS}

    def listen(event, duration, **_):
        if event in compiling:
            compiling[event] += duration

    jax.monitoring.register_event_duration_secs_listener(listen)
    solves = _count_solves() if args.solves else None
    logs = make_logs(SIZES[args.size])
    runs = []
    for label in ("cold", "second"):
        compiling.update({event: 0.0 for event in compiling})
        start = time.perf_counter()
        d = diagnose(logs, baseline="chamber+dahl", candidates="all")
        wall = time.perf_counter() - start
        compile_s = {event.rsplit("/", 1)[1]: round(v, 2) for event, v in compiling.items()}
        runs.append({"run": label, "wall_s": wall, "timing_s": dict(d.timing_s),
                     "compile_s": compile_s, "compile_total_s": sum(compiling.values()),
                     "accepted": list(d.accepted)})
        if solves is not None:
            runs[-1]["solves"] = sorted(solves.values(), key=lambda v: -v["seconds"])
            for v in runs[-1]["solves"]:
                print(f"  {v['frees'] or '(current model)':40s} {v['solves']:3d} solves "
                      f"{v['steps']:4d} steps {v['seconds']:6.1f} s", flush=True)
            solves.clear()
        print(f"{label}: {wall:.1f} s {d.timing_s} compile {compile_s} "
              f"accepted {d.accepted}", flush=True)
    result = {"size": args.size, "logs": len(logs), "samples": [len(log) for log in logs],
              "cpu_count": os.cpu_count(), "runs": runs,
              "compilation_estimate_s": runs[0]["wall_s"] - runs[1]["wall_s"],
              "target_s": TARGETS[args.size]}
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


def _count_solves() -> dict:
    """Wrap :meth:`SuperProblem.solve` to time each solve and count its trial steps, keyed
    by the candidates it frees beyond the baseline (seconds are summed over the two fold
    threads, so they can exceed the wall time)."""
    import threading

    import numpy as np

    from fitstiff.diagnosis import supermodel

    found: dict[str, dict] = {}
    lock = threading.Lock()          # the held-out folds solve from two threads
    solve = supermodel.SuperProblem.solve

    def timed(self, theta0, hold, free_model, free_nuisance, weights, **options):
        start = time.perf_counter()
        out = solve(self, theta0, hold, free_model, free_nuisance, weights, **options)
        frees = ",".join(sorted({self.owners[k].term for k in np.flatnonzero(free_model)}
                                - set(self.baseline_terms)))
        with lock:
            entry = found.setdefault(frees, {"frees": frees, "solves": 0, "steps": 0,
                                             "seconds": 0.0})
            entry["solves"] += 1
            entry["steps"] += out[2]
            entry["seconds"] += time.perf_counter() - start
        return out

    supermodel.SuperProblem.solve = timed
    return found


if __name__ == "__main__":
    main()
