"""Where a fleet's wall time goes: start-up against steady throughput (issue 34).

Runs :func:`fitstiff.fit_fleet` on SOURCE with ``--workers N`` in this process and reads the
phases off its ``progress`` callback: when the first chunk of units is done (imports, the
cluster's start, the workers' compilation), the steady throughput after it, and the whole
call; also this process's own CPU time. ``--cache DIR`` is the persistent compilation cache
the workers inherit (emptied first unless ``--warm``).

    python benchmarks/fleet_timeline.py SOURCE --workers 2 --cache /tmp/fleet-jax [--warm]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", required=True)
    parser.add_argument("--warm", action="store_true", help="keep the cache's contents")
    args = parser.parse_args()
    if not args.warm:
        shutil.rmtree(args.cache, ignore_errors=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = args.cache
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    t0 = time.perf_counter()
    from fitstiff.fleet.engine import fit_fleet

    imported = time.perf_counter() - t0
    marks: list[tuple[float, int]] = []
    table = fit_fleet(args.source, workers=args.workers,
                      progress=lambda done, total: marks.append((time.perf_counter() - t0,
                                                                 done)))
    end = time.perf_counter() - t0
    (t_first, n_first), (t_last, n_last) = next(m for m in marks if m[1] > 0), marks[-1]
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({
        "workers": args.workers, "warm": args.warm, "units": len(table),
        "import_s": round(imported, 2), "first_chunk_s": round(t_first, 2),
        "last_chunk_s": round(t_last, 2), "whole_s": round(end, 2),
        "steady_units_per_s": round((n_last - n_first) / (t_last - t_first), 2),
        "this_process_cpu_s": round(usage.ru_utime + usage.ru_stime, 2)}))


if __name__ == "__main__":
    main()
