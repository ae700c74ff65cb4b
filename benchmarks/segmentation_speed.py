"""Segmentation speed on a 1e6-sample noisy log, against NumPy's own cost of touching the data.

The reference measured in the same run is a plain vectorised pass over the samples
(``np.diff`` + ``np.median`` of the second differences, what the noise estimate alone costs),
so the figure is a ratio that does not depend on the machine's speed.

    python benchmarks/segmentation_speed.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fitstiff.io.log import Log
from fitstiff.segments.segmentation import segment


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000,
                        help="samples of the log (default 1 000 000)")
    n, cycles = parser.parse_args(argv).samples, 200
    phase = (np.arange(n) % (n / cycles)) / (n / cycles)
    x = 2e-3 * (2 * np.abs(2 * phase - 1) - 1) + np.random.default_rng(0).normal(0, 1e-6, n)
    log = Log(name="big", displacement=x, force=np.zeros(n), time=np.arange(n) / 1000.0)
    t0 = time.perf_counter()
    seg = segment(log)
    seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    d2 = np.diff(x, 2)
    np.median(np.abs(d2 - np.median(d2)))
    reference = time.perf_counter() - t0
    print(f"samples {n}, reversals {seg.reversals.size}")
    print(f"segment: {seconds:.3f} s; reference pass: {reference:.3f} s; "
          f"ratio {seconds / reference:.1f}")


if __name__ == "__main__":
    main()
