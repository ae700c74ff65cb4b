"""Time to plan (issue 33: <= 30 s on 2 cores for the benchmark's sets), cold.

For each withheld-effect dataset named, its diagnosis is taken from ``--diagnoses DIR``
(``<id with / as _>.json``, a ``Diagnosis.to_dict()``) or made and stored there first. Then
each plan runs in a fresh process with an empty compilation cache: ``plan(diagnosis, logs)``
with the closed loop's limits (:data:`fitstiff._testing.plan_loop.LOOP_LIMITS`: 20 s
programs, the rig's three supplies and its speed; the logs' stroke and rate), timed as ``Plan.timing_s`` splits
it (rivals, search). Run with another tree on ``PYTHONPATH`` for a before figure on the same
stored diagnoses.

    python benchmarks/plan_speed.py --diagnoses benchmarks/results/plan_speed_diagnoses \\
        --ids single/maxwell_slip/1 [--json F]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_ONE = """
import json, sys, time
import fitstiff
from fitstiff._testing.plan_loop import LOOP_LIMITS
from fitstiff._testing.withheld import make_dataset
from fitstiff.diagnosis.result import Diagnosis
from fitstiff.planning.families import Limits
from fitstiff.planning.plan import plan
logs, _ = make_dataset(sys.argv[1])
d = Diagnosis.from_dict(json.loads(open(sys.argv[2]).read()))
limits = Limits.from_logs(logs, **LOOP_LIMITS)
t = time.perf_counter()
p = plan(d, logs, limits=limits)
wall = time.perf_counter() - t
print(json.dumps({"fitstiff": fitstiff.__file__, "wall_s": wall, "timing_s": p.timing_s,
                  "planned": [[list(x.separates), x.program, x.expected] for x in p.programs],
                  "unplanned": [[u["separates"], u["why"]] for u in p.unplanned]},
                 default=float))
"""


def _diagnosis(dataset: str, store: Path) -> Path:
    path = store / (dataset.replace("/", "_") + ".json")
    if not path.exists():
        from fitstiff._testing.withheld import make_dataset
        from fitstiff.diagnosis import diagnose

        logs, truth = make_dataset(dataset)
        store.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(diagnose(logs, baseline=truth["baseline"]).to_dict(),
                                   default=float))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="+", required=True)
    parser.add_argument("--diagnoses", type=Path, required=True,
                        help="folder of stored diagnoses (made where missing)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    out = {"python_path": os.environ.get("PYTHONPATH", ""), "plans": {}}
    for dataset in args.ids:
        stored = _diagnosis(dataset, args.diagnoses)
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=cache,
                       JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
            # run outside the working directory: its fitstiff would shadow PYTHONPATH's
            run = subprocess.run([sys.executable, "-c", _ONE, dataset, str(stored.resolve())],
                                 env=env, cwd=cache, check=True, capture_output=True,
                                 text=True)
        result = json.loads(run.stdout.strip().splitlines()[-1])
        out["plans"][dataset] = result
        timing = {k: round(v, 1) for k, v in result["timing_s"].items()}
        print(f"{result['fitstiff']} {dataset}: plan {result['wall_s']:.1f} s {timing}; planned "
              f"{[p[0] for p in result['planned']]}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
