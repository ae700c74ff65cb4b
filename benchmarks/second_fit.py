"""A second fit in one process: other data of the same structure (issue 34).

Before 406e437 every ``Problem`` compiled its solve and covariance summary anew; since then
problems of one structure share them (:meth:`fitstiff.inference.problem.Problem.compiled`). Two
cylinders of :func:`fitstiff._testing.fleet.make_fleet` (two 3 700-sample logs each) are
fitted one after the other; the second fit's time is what a loop over a fleet pays per
cylinder. Run it with another tree on ``PYTHONPATH`` for the before figure (the data are
written on the first run into ROOT).

    python benchmarks/second_fit.py ROOT
"""
import sys, time
from pathlib import Path
import fitstiff

from fitstiff.io.loading import load_logs
root = Path(sys.argv[1])
if not root.exists():
    from fitstiff._testing.fleet import make_fleet
    make_fleet(root, cylinders=2, outliers=0.0, samples=3700)
logs = [load_logs(sorted((root / f"cyl000{c}").glob("*.csv"))) for c in (0, 1)]
t = time.perf_counter()
a = fitstiff.fit(logs[0], "chamber+dahl")
first = time.perf_counter() - t
t = time.perf_counter()
b = fitstiff.fit(logs[1], "chamber+dahl")
second = time.perf_counter() - t
print(f"first fit {first:.2f} s, second fit (other data, one structure) {second:.2f} s; "
      f"breakaway {b.derived['breakaway_N'][0]:.6f} N")
