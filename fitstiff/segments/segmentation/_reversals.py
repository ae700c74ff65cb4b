"""Reversals by the hysteresis (zig-zag) rule, and the noise and quantisation step of the
displacement that set its default threshold (see :mod:`fitstiff.segments.segmentation`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage

from fitstiff.signal.noise import estimate_noise

NOISE_MULTIPLE = 10.0
RESOLUTION_MULTIPLE = 4.0
THRESHOLD_FLOOR = 1e-6  # m


def _resolution(x: np.ndarray) -> float:
    """Smallest non-zero step with a zero step on either side (0 if there is none)."""
    d = np.diff(x)
    isolated = d[1:-1][(d[1:-1] != 0) & (d[:-2] == 0) & (d[2:] == 0)]
    return float(np.abs(isolated).min()) if isolated.size else 0.0


def _running_median(x: np.ndarray, window: int) -> np.ndarray:
    if window == 1 or x.size < window:
        return x.copy()
    return ndimage.median_filter(x, size=window, mode="nearest")


def _first_hit(values: np.ndarray, start: int, find, *, chunk: int) -> tuple[int, int] | None:
    """Search ``values[start:]`` in growing windows; ``find(window) -> index or -1``."""
    n = values.size
    while True:
        stop = min(n, start + chunk)
        j = find(values[start:stop])
        if j >= 0:
            return j, chunk
        if stop == n:
            return None
        chunk *= 2


def _first_departure(x: np.ndarray, threshold: float) -> tuple[int, int] | None:
    """``(start, direction)`` of the first leg: ``x`` first leaves a band of ``threshold``
    around its past at some sample; the leg starts at the last sample of the opposite extremum
    before it (what precedes is a wiggle within the noise band)."""
    def find(w):
        up = w - np.minimum.accumulate(w) > threshold
        down = np.maximum.accumulate(w) - w > threshold
        hit = np.flatnonzero(up | down)
        return int(hit[0]) if hit.size else -1

    found = _first_hit(x, 0, find, chunk=1024)
    if found is None:
        return None
    i = found[0]
    direction = 1 if x[i] - x[: i + 1].min() > threshold else -1
    past = x[: i + 1] * direction
    return i - int(np.argmin(past[::-1])), direction


class _Reversals(NamedTuple):
    """What :func:`_hysteresis_reversals` finds."""

    indices: np.ndarray      # sample indices of the reversals, ascending
    first_direction: int     # of the first leg: +1, -1, or 0 if the signal never moves
    first_start: int         # first sample of the first leg (n if it never moves)


def _hysteresis_reversals(x: np.ndarray, threshold: float) -> _Reversals:
    """Reversal indices, the first leg's direction and start (0, n if ``x`` never moves).

    Loops over reversals, not samples: each leg is found with vectorised running extrema over
    a window that doubles until the confirming sample is inside it.
    """
    departure = _first_departure(x, threshold)
    if departure is None:
        return _Reversals(np.empty(0, dtype=np.int64), 0, x.size)
    first_start, first_direction = departure
    direction = first_direction
    reversals = []
    start, chunk = 0, 1024

    def find(w):
        w = w * direction
        hit = np.flatnonzero(w < np.maximum.accumulate(w) - threshold)
        return int(hit[0]) if hit.size else -1

    while (found := _first_hit(x, start, find, chunk=chunk)) is not None:
        confirm, chunk = found
        leg = x[start: start + confirm] * direction
        r = start + confirm - 1 - int(np.argmax(leg[::-1]))  # last sample of the extremum
        reversals.append(r)
        start, direction = r, -direction
        chunk = max(1024, 2 * confirm)
    return _Reversals(np.asarray(reversals, dtype=np.int64), first_direction, first_start)


def _default_threshold(raw: np.ndarray) -> float:
    return max(NOISE_MULTIPLE * estimate_noise(raw), RESOLUTION_MULTIPLE * _resolution(raw),
               THRESHOLD_FLOOR)

