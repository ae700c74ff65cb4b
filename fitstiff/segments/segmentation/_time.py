"""What needs the log's time: pauses (standstills of at least ``min_pause`` within a band),
the standstill mask of :func:`~fitstiff.segments.segmentation.standstill`, and the smoothed
velocity (see :mod:`fitstiff.segments.segmentation`)."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from fitstiff.segments.segmentation._reversals import _default_threshold, _running_median

DEFAULT_MIN_PAUSE = 0.2  # s


def _pauses(x: np.ndarray, time: np.ndarray, *, band: float, min_pause: float) -> np.ndarray:
    """Half-open ``[start, stop)`` spans of at least ``min_pause`` within windows of ``band``."""
    n = x.size
    dt = float(np.median(np.diff(time))) if n > 1 else 0.0
    if n < 2 or dt <= 0:
        return np.empty((0, 2), dtype=np.int64)
    m = max(2, math.ceil(min_pause / dt - 1e-9) + 1)  # samples spanning min_pause
    if m > n:
        return np.empty((0, 2), dtype=np.int64)
    # range of every full window x[a : a + m], a = 0 .. n - m (centred filters, shifted)
    half = m // 2
    rng = (ndimage.maximum_filter1d(x, m, mode="nearest")
           - ndimage.minimum_filter1d(x, m, mode="nearest"))[half: half + n - m + 1]
    still_start = np.zeros(n + 1, dtype=np.int64)
    still_start[1: n - m + 2] = rng <= band
    covered_count = np.cumsum(still_start)  # covered_count[j + 1] = still windows starting <= j
    lagged = np.concatenate([np.zeros(m, dtype=np.int64), covered_count[1: n - m + 1]])
    covered = covered_count[1:] - lagged > 0
    edges = np.diff(covered.astype(np.int8), prepend=0, append=0)
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    # a window at either end may hold a few samples of the ramp in or out: trim the ends to
    # the samples within a third of the band of the span's median level
    for k, (start, stop) in enumerate(zip(starts, stops)):
        span = x[start:stop]
        inside = np.flatnonzero(np.abs(span - np.median(span)) <= band / 3)
        if inside.size:
            starts[k], stops[k] = start + inside[0], start + inside[-1] + 1
    keep = time[stops - 1] - time[starts] >= min_pause * (1 - 1e-9)
    return np.column_stack([starts[keep], stops[keep]]).astype(np.int64)


def _velocity(x: np.ndarray, time: np.ndarray, *, window: float) -> np.ndarray:
    """Central difference over ``+-k`` samples, ``2k`` intervals spanning about ``window``."""
    n = x.size
    dt = float(np.median(np.diff(time))) if n > 1 else 0.0
    if n < 2 or dt <= 0:
        return np.zeros(n)
    k = max(1, round(window / (2 * dt)))
    i = np.arange(n)
    lo, hi = np.maximum(i - k, 0), np.minimum(i + k, n - 1)
    return (x[hi] - x[lo]) / (time[hi] - time[lo])


def standstill(displacement: np.ndarray, time: np.ndarray, *,
               threshold: float | None = None, min_pause: float = DEFAULT_MIN_PAUSE,
               pause_band: float | None = None, median_window: int = 3) -> np.ndarray:
    """Per sample 1.0 inside a pause, else 0.0: the
    :attr:`~fitstiff.segments.segmentation.Segmentation.still` of a segmentation, from arrays.

    The same rule as :func:`~fitstiff.segments.segmentation.segment` (a span of at least
    ``min_pause`` within ``pause_band``), for callers that have a displacement and time but no
    :class:`~fitstiff.io.log.Log` (the simulator, on the true displacement).
    """
    raw = np.asarray(displacement, dtype=np.float64)
    x = _running_median(raw, int(median_window))
    if threshold is None:
        threshold = _default_threshold(raw)
    pauses = _pauses(x, np.asarray(time, dtype=np.float64), band=pause_band or threshold,
                     min_pause=min_pause)
    still = np.zeros(raw.size)
    for start, stop in pauses:
        still[start:stop] = 1.0
    return still
