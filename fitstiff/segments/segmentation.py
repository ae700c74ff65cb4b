"""Segmentation of a log: direction reversals, loops, pauses and per-sample regions (DESIGN §2).

:func:`segment` turns a :class:`~fitstiff.io.log.Log` into an immutable :class:`Segmentation`.
Everything is computed on the displacement after a short running median (``median_window``
samples, default 3), which removes isolated sensor spikes without moving monotone edges.

**Reversals** use a hysteresis (zig-zag) rule, not sign changes of a noisy derivative: while
the piston moves up, track the running maximum since the last reversal; once the signal has
come back by more than ``threshold`` from it, the reversal is confirmed and placed at that
maximum (its last sample on a plateau); then the same downwards. Noise smaller than the
threshold and any standstill, however long, never create a reversal.

**Default threshold**: ``max(10 * noise, 4 * resolution, 1 um)`` where ``noise`` is the
Gaussian-equivalent standard deviation of the displacement noise estimated from the second
differences, ``1.4826 * MAD(diff(x, 2)) / sqrt(6)`` (white noise of standard deviation s has
second differences of standard deviation ``s * sqrt(6)``; smooth motion contributes almost
nothing to them, so the estimate holds on ramps, sines and pauses alike), and ``resolution`` is
the sensor's quantisation step: the smallest step between two plateaus (a non-zero difference
with a zero difference on either side), the staircase a quantised sensor leaves when it is
still or creeping, and the flicker it may show at rest; 0 when there is no such step, as in
noise-free simulated data. The MAD of the second differences is 0 for a signal that is mostly
flat, so flicker needs this term. Ten standard deviations exceed the peak-to-peak excursion of
Gaussian noise over a million samples (about 10.5 s before the median, 7 s after it).

**Pauses** (needs time) are spans of at least ``min_pause`` seconds in which every window of
that duration stays within a band of ``pause_band`` (default: the threshold). Motion slower
than ``pause_band / min_pause`` is therefore indistinguishable from standing still. The ends of
each span are trimmed to the samples within a third of the band of its median level.

**Regions**: every sample has one motion region,

- ``standstill``: inside a pause;
- ``dwell``: just after a pause, until the piston has travelled ``presliding_range`` from
  where it stood;
- ``presliding``: within ``presliding_range`` of travel after a reversal (or after the start
  of the log, where the seal state is unknown);
- ``sliding``: everything else;

and, where the rig's stroke and start position are known, the location flag ``stroke_end``
(within ``stroke_end_margin`` of either cap), which overlaps the motion regions.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from fitstiff.errors import InputError
from fitstiff.io.log import Log

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "REGIONS",
    "SPEED_BANDS",
    "Segmentation",
    "estimate_noise",
    "segment",
    "standstill",
]

REGIONS = ("presliding", "sliding", "dwell", "standstill", "stroke_end")
"""Region names. ``Segmentation.region`` holds codes into this tuple for the first four (a
partition of the samples); ``stroke_end`` is the separate, overlapping flag."""

SPEED_BANDS = ("slow", "medium", "fast", "standstill", "unknown")
"""Speed-band names; ``Segmentation.speed_band`` holds codes into this tuple. ``standstill``
tags pause samples, ``unknown`` every sample of a log without time."""

_PRESLIDING, _SLIDING, _DWELL, _STANDSTILL = range(4)
_SLOW, _MEDIUM, _FAST, _BAND_STANDSTILL, _BAND_UNKNOWN = range(5)

NOISE_MULTIPLE = 10.0
RESOLUTION_MULTIPLE = 4.0
THRESHOLD_FLOOR = 1e-6  # m
DEFAULT_PRESLIDING_RANGE = 0.5e-3  # m, DESIGN §1.2
DEFAULT_MIN_PAUSE = 0.2  # s
DEFAULT_SPEED_EDGES = (2e-3, 20e-3)  # m/s: slow < 2 mm/s <= medium < 20 mm/s <= fast
DEFAULT_SPEED_WINDOW = 0.1  # s
DEFAULT_STROKE_END_FRACTION = 0.1  # of the stroke


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


@dataclasses.dataclass(frozen=True, eq=False)
class Segmentation:
    """The segmentation of one log (immutable; arrays are read-only). SI units.

    Attributes:
        name: the log's name (file stem).
        n_samples: number of samples.
        noise: estimated displacement noise, Gaussian-equivalent standard deviation (m).
        threshold: hysteresis threshold used for the reversals (m).
        presliding_range: travel after a reversal or pause counted as presliding / dwell (m).
        reversals: sample indices of the direction reversals (the turning extrema), ascending.
        loops: ``(n_loops, 2)`` half-open sample ranges ``[start, stop)`` of full cycles, from
            every second reversal to the next-but-one (``start = reversals[2k]``,
            ``stop = reversals[2k + 2] + 1``), so ``log.slice(*loops[k])`` is loop ``k``.
        pauses: ``(n_pauses, 2)`` half-open sample ranges ``[start, stop)`` of standstills.
        pause_durations: dwell time of each pause, ``time[stop - 1] - time[start]`` (s).
        direction: per sample, +1 moving toward the B cap, -1 toward the A cap, 0 standing
            still (in a pause, or before the first leg starts: the wiggle within the noise
            band before the displacement first leaves it).
        velocity: per sample, smoothed velocity (m/s); ``None`` without time.
        speed_band: per sample, codes into :data:`SPEED_BANDS`.
        speed_edges: ``(slow/medium, medium/fast)`` speed edges used (m/s).
        region: per sample, codes into :data:`REGIONS` (``presliding``, ``sliding``,
            ``dwell`` or ``standstill``; a partition of the samples).
        stroke_end: per sample, within ``stroke_end_margin`` of either cap; ``None`` when the
            rig's stroke or start position is unknown.
        stroke_end_margin: the margin used (m), ``None`` when ``stroke_end`` is.
        pressure_level: the log's pressure level, gauge (Pa): the rig's supply pressure, else
            the mean logged chamber pressure; ``None`` when neither is known.
        has_time: whether the log has time (otherwise it is quasi-static).
        notes: what could not be determined, and why.
    """

    name: str
    n_samples: int
    noise: float
    threshold: float
    presliding_range: float
    reversals: np.ndarray
    loops: np.ndarray
    pauses: np.ndarray
    pause_durations: np.ndarray
    direction: np.ndarray
    velocity: np.ndarray | None
    speed_band: np.ndarray
    speed_edges: tuple[float, float]
    region: np.ndarray
    stroke_end: np.ndarray | None
    stroke_end_margin: float | None
    pressure_level: float | None
    has_time: bool
    notes: tuple[str, ...] = ()

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                object.__setattr__(self, f.name, _readonly(value))
        object.__setattr__(self, "notes", tuple(self.notes))

    @property
    def available_regions(self) -> tuple[str, ...]:
        """Region names that could be determined for this log (see :meth:`mask`)."""
        return tuple(r for r in REGIONS if self._unavailable(r) is None)

    def _unavailable(self, region: str) -> str | None:
        if region in ("dwell", "standstill") and not self.has_time:
            return "the log has no time column (quasi-static), so it has no pauses"
        if region == "stroke_end" and self.stroke_end is None:
            return "the rig's stroke_mm or start_position_mm is unknown"
        return None

    def mask(self, region: str) -> np.ndarray:
        """Boolean per-sample mask of ``region`` (one of :data:`REGIONS`).

        Raises :class:`InputError` for an unknown name, or for a region this log cannot
        have (``stroke_end`` without stroke and start position; ``dwell`` and ``standstill``
        without time).
        """
        if region not in REGIONS:
            raise InputError(self.name, f"region '{region}'", "is not a region",
                             f"use one of: {', '.join(REGIONS)}")
        reason = self._unavailable(region)
        if reason is not None:
            raise InputError(self.name, f"region '{region}'", f"cannot be determined: {reason}")
        if region == "stroke_end":
            return self.stroke_end.copy()
        return self.region == REGIONS.index(region)

    def shares(self) -> dict[str, float]:
        """Fraction of samples in each available region (motion regions sum to 1)."""
        n = max(self.n_samples, 1)
        return {r: float(np.count_nonzero(self.mask(r))) / n for r in self.available_regions}

    @property
    def still(self) -> np.ndarray:
        """Per sample 1.0 while the piston stands still (the ``standstill`` region), else 0.0.

        The one definition of standing still: the model's dwell-dependent terms are driven
        by it (:class:`~fitstiff.physics.drive.Drive` ``still``), the simulator derives it from the
        true displacement with :func:`standstill`, and the diagnosis reads the ``dwell`` and
        ``standstill`` regions from the same pauses.
        """
        return (self.region == _STANDSTILL).astype(np.float64)

    def to_frame(self) -> pd.DataFrame:
        """Tidy per-sample tags, one row per sample.

        Columns: ``file``, ``sample``, ``region`` (categorical over the motion regions),
        ``stroke_end`` (nullable boolean; ``<NA>`` when unknown), ``direction`` (+1/-1/0),
        ``speed_band`` (categorical), ``pressure_bar`` (pressure level, bar gauge; NaN when
        unknown), ``loop`` (index of the loop holding the sample, -1 outside every loop).
        """
        import pandas as pd  # here, not at module level: most callers never need it

        n = self.n_samples
        loop = np.full(n, -1, dtype=np.int64)
        for k, (start, stop) in enumerate(self.loops):
            loop[start:stop] = k  # a closing reversal is the next loop's first sample
        stroke_end = (pd.array(self.stroke_end, dtype="boolean") if self.stroke_end is not None
                      else pd.array([pd.NA] * n, dtype="boolean"))
        pressure = np.nan if self.pressure_level is None else self.pressure_level / 1e5
        return pd.DataFrame({
            "file": pd.Categorical.from_codes(np.zeros(n, dtype=np.int8), categories=[self.name]),
            "sample": np.arange(n),
            "region": pd.Categorical.from_codes(self.region, categories=REGIONS[:4]),
            "stroke_end": stroke_end,
            "direction": self.direction,
            "speed_band": pd.Categorical.from_codes(self.speed_band, categories=SPEED_BANDS),
            "pressure_bar": np.full(n, pressure),
            "loop": loop,
        })


def estimate_noise(displacement: np.ndarray) -> float:
    """Gaussian-equivalent standard deviation of the noise on ``displacement``.

    ``1.4826 * MAD(diff(x, 2)) / sqrt(6)``: robust to spikes and to the motion itself (a ramp
    has zero second difference, a turning point affects a handful of samples).
    """
    x = np.asarray(displacement, dtype=np.float64)
    if x.size < 3:
        return 0.0
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


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


def _hysteresis_reversals(x: np.ndarray, threshold: float) -> tuple[np.ndarray, int, int]:
    """Reversal indices, the first leg's direction and start (0, n if ``x`` never moves).

    Loops over reversals, not samples: each leg is found with vectorised running extrema over
    a window that doubles until the confirming sample is inside it.
    """
    departure = _first_departure(x, threshold)
    if departure is None:
        return np.empty(0, dtype=np.int64), 0, x.size
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
    return np.asarray(reversals, dtype=np.int64), first_direction, first_start


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


def _segment_ids(starts: np.ndarray, n: int) -> np.ndarray:
    """For each sample, the index of the last of the sorted ``starts`` at or before it."""
    return np.searchsorted(starts, np.arange(n), side="right") - 1


def _running_max_per_segment(values: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Cumulative maximum of non-negative ``values`` restarted at each new ``seg`` id."""
    offset = (float(values.max()) + 1.0) * (seg - seg.min()) if values.size else 0.0
    return np.maximum.accumulate(values + offset) - offset


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


def _pressure_level(log: Log) -> float | None:
    if log.rig.supply_pressure is not None:
        return float(log.rig.supply_pressure)
    logged = [p for p in (log.pressure_a, log.pressure_b) if p is not None]
    if not logged:
        return None
    return float(np.mean([p.mean() for p in logged]) - log.rig.ambient_pressure)


def _positive(name: str, value: float | None, where: str) -> None:
    if value is not None and not (np.isfinite(value) and value > 0):
        raise InputError(where, f"segmentation option '{name}'", f"found {value!r}",
                         "give a positive number")


def standstill(displacement: np.ndarray, time: np.ndarray, *,
               threshold: float | None = None, min_pause: float = DEFAULT_MIN_PAUSE,
               pause_band: float | None = None, median_window: int = 3) -> np.ndarray:
    """Per sample 1.0 inside a pause, else 0.0: :attr:`Segmentation.still` from arrays.

    The same rule as :func:`segment` (a span of at least ``min_pause`` within ``pause_band``),
    for callers that have a displacement and time but no :class:`~fitstiff.io.log.Log` (the
    simulator, on the true displacement).
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


def _legs(x: np.ndarray, reversals: np.ndarray, first_start: int) -> np.ndarray:
    """Travel of every leg (between reversals, from the first motion to the end), > 0 (m)."""
    if not x.size:
        return np.empty(0)
    ends = np.clip(np.concatenate([[first_start], reversals, [x.size - 1]]).astype(int),
                   0, x.size - 1)
    travel = np.abs(np.diff(x[ends]))
    return travel[travel > 0]


def _presliding_range(legs: np.ndarray, given: float | None) -> tuple[float, list[str]]:
    """The presliding range to use, and a note when it cannot leave a sliding sample.

    Given: used as it is, with a note when every leg is shorter (no sample can count as
    sliding; issue 17: a 0.23 mm microtribometer stroke against the 0.5 mm default had no
    presliding or sliding sample at all). Default: :data:`DEFAULT_PRESLIDING_RANGE`, or a
    third of the median leg when every leg is shorter than that, said in a note.
    """
    if not legs.size:
        return (DEFAULT_PRESLIDING_RANGE if given is None else given), []
    longest, median = float(legs.max()), float(np.median(legs))
    if given is None:
        if longest >= DEFAULT_PRESLIDING_RANGE:
            return DEFAULT_PRESLIDING_RANGE, []
        derived = median / 3.0
        return derived, [
            f"every travel between reversals (median {median * 1e3:.3g} mm, longest "
            f"{longest * 1e3:.3g} mm) is shorter than the default presliding range "
            f"({DEFAULT_PRESLIDING_RANGE * 1e3:g} mm): the presliding range is a third of the "
            f"median travel, {derived * 1e3:.2g} mm; give --presliding-range-mm to set it"]
    if longest >= given:      # minor loops inside pre-sliding are by design
        return given, []
    return given, [
        f"the presliding range ({given * 1e3:.3g} mm) exceeds every travel between reversals "
        f"(median {median * 1e3:.3g} mm, longest {longest * 1e3:.3g} mm): no sample can be "
        f"sliding, and after a pause every sample is dwell; give a shorter "
        f"--presliding-range-mm (e.g. {median * 1e3 / 3:.2g}) for these logs"]


def _default_threshold(raw: np.ndarray) -> float:
    return max(NOISE_MULTIPLE * estimate_noise(raw), RESOLUTION_MULTIPLE * _resolution(raw),
               THRESHOLD_FLOOR)


def segment(
    log: Log,
    *,
    threshold: float | None = None,
    presliding_range: float | None = None,
    min_pause: float = DEFAULT_MIN_PAUSE,
    pause_band: float | None = None,
    speed_edges: tuple[float, float] = DEFAULT_SPEED_EDGES,
    speed_window: float = DEFAULT_SPEED_WINDOW,
    stroke_end_margin: float | None = None,
    median_window: int = 3,
) -> Segmentation:
    """Segment ``log`` into reversals, loops, pauses and per-sample regions.

    Args:
        log: the log.
        threshold: hysteresis threshold for reversals (m); default from the noise (module
            docstring: ``max(10 * noise, 4 * resolution, 1 um)``).
        presliding_range: travel after a reversal (``presliding``) or a pause (``dwell``)
            before the motion counts as ``sliding`` (m); default 0.5 mm (DESIGN §1.2), or a
            third of the median travel between reversals when every travel is shorter (a
            short-stroke rig; :attr:`Segmentation.notes` says so).
        min_pause: shortest standstill reported as a pause (s).
        pause_band: displacement band a standstill stays within (m); default ``threshold``.
        speed_edges: ``(slow/medium, medium/fast)`` edges of ``|velocity|`` (m/s); default
            2 and 20 mm/s (below 2 mm/s seal friction is in its stiction / Stribeck regime),
            fixed so that a band means the same in every log.
        speed_window: time span of the central difference giving the smoothed velocity (s).
        stroke_end_margin: distance from either cap counted as ``stroke_end`` (m); default
            10 % of the stroke. Needs the rig's stroke and start position.
        median_window: odd length of the running median applied first (1 disables it).

    Returns:
        The :class:`Segmentation`.
    """
    where = log.name
    for name, value in (("threshold", threshold), ("presliding_range", presliding_range),
                        ("min_pause", min_pause), ("pause_band", pause_band),
                        ("speed_window", speed_window),
                        ("stroke_end_margin", stroke_end_margin)):
        _positive(name, value, where)
    lo_edge, hi_edge = speed_edges
    if not (np.isfinite(lo_edge) and np.isfinite(hi_edge) and 0 < lo_edge < hi_edge):
        raise InputError(where, "segmentation option 'speed_edges'", f"found {speed_edges!r}",
                         "give two increasing positive speeds")
    if not (isinstance(median_window, (int, np.integer)) and median_window >= 1
            and median_window % 2 == 1):
        raise InputError(where, "segmentation option 'median_window'",
                         f"found {median_window!r}", "give an odd positive integer")

    n = len(log)
    raw = np.asarray(log.displacement, dtype=np.float64)
    x = _running_median(raw, int(median_window))
    noise = estimate_noise(raw)
    if threshold is None:
        threshold = _default_threshold(raw)
    notes: list[str] = []

    reversals, first_direction, first_start = _hysteresis_reversals(x, threshold)
    if first_direction == 0:
        notes.append(f"the displacement never moved by more than the threshold "
                     f"({threshold * 1e3:.3g} mm): no motion, no reversals")
    loops = np.column_stack([reversals[:-2:2], reversals[2::2] + 1]).astype(np.int64)

    # direction: constant on each leg between reversals, the reversal sample opens a leg
    legs = np.searchsorted(reversals, np.arange(n), side="right")
    direction = np.where(legs % 2 == 0, first_direction, -first_direction).astype(np.int8)
    direction[:first_start] = 0

    time = log.time
    if time is not None:
        pauses = _pauses(x, time, band=pause_band or threshold, min_pause=min_pause)
        pause_durations = time[pauses[:, 1] - 1] - time[pauses[:, 0]]
        velocity = _velocity(x, time, window=speed_window)
    else:
        notes.append("no time column: quasi-static log, so no velocity, speed bands, pauses "
                     "or dwell")
        pauses = np.empty((0, 2), dtype=np.int64)
        pause_durations = np.empty(0)
        velocity = None
    in_pause = np.zeros(n, dtype=bool)
    for start, stop in pauses:
        in_pause[start:stop] = True
    direction[in_pause] = 0

    presliding_range, more = _presliding_range(_legs(x, reversals, first_start),
                                               presliding_range)
    notes += more
    region = _regions(x, reversals, pauses, in_pause, threshold=threshold,
                      presliding_range=presliding_range)

    if velocity is None:
        speed_band = np.full(n, _BAND_UNKNOWN, dtype=np.int8)
    else:
        speed_band = np.digitize(np.abs(velocity), [lo_edge, hi_edge]).astype(np.int8)
        speed_band[in_pause] = _BAND_STANDSTILL

    stroke_end = None
    rig = log.rig
    if rig.stroke is None or rig.start_position is None:
        missing = [k for k, v in (("stroke_mm", rig.stroke),
                                  ("start_position_mm", rig.start_position)) if v is None]
        notes.append(f"stroke_end region skipped: rig metadata {' and '.join(missing)} "
                     "missing")
        stroke_end_margin = None
    else:
        if stroke_end_margin is None:
            stroke_end_margin = DEFAULT_STROKE_END_FRACTION * rig.stroke
        position = rig.start_position + raw
        stroke_end = (position < stroke_end_margin) | (position > rig.stroke - stroke_end_margin)

    pressure_level = _pressure_level(log)
    if pressure_level is None:
        notes.append("pressure level unknown: no supply_bar in the rig metadata and no "
                     "logged chamber pressure")

    return Segmentation(
        name=log.name, n_samples=n, noise=noise, threshold=float(threshold),
        presliding_range=float(presliding_range), reversals=reversals, loops=loops,
        pauses=pauses, pause_durations=pause_durations, direction=direction,
        velocity=velocity, speed_band=speed_band,
        speed_edges=(float(lo_edge), float(hi_edge)), region=region, stroke_end=stroke_end,
        stroke_end_margin=stroke_end_margin, pressure_level=pressure_level,
        has_time=time is not None, notes=tuple(notes))


def _regions(x: np.ndarray, reversals: np.ndarray, pauses: np.ndarray, in_pause: np.ndarray,
             *, threshold: float, presliding_range: float) -> np.ndarray:
    """Motion region codes: standstill > dwell > presliding > sliding.

    Travel is measured from the last *origin*: the log start, a reversal, or the end of a
    pause (the position the piston stood at). A reversal inside a pause, or one that the
    signal reaches without having left the pause's noise band (the turning extremum of a
    pause at a turning point, found just after it by the noise), is the same turning as the
    pause and opens no origin of its own: what follows is ``dwell``.
    """
    n = x.size
    pause_stops = pauses[:, 1]
    if reversals.size and pauses.size:
        # travel since the end of the last pause, running maximum until the next pause
        seg = _segment_ids(pause_stops, n)
        after = seg >= 0
        ref = np.where(after, x[pause_stops[np.maximum(seg, 0)] - 1], x)
        exit_travel = _running_max_per_segment(np.abs(x - ref), seg)
        exit_travel[~after] = np.inf
        keep = ~in_pause[reversals] & (exit_travel[reversals] > threshold)
        reversals = reversals[keep]

    # origins: (first sample of the segment, sample the travel is measured from, is_pause)
    starts = np.concatenate([[0], reversals, pause_stops])
    refs = np.concatenate([[0], reversals, pause_stops - 1])
    from_pause = np.concatenate([[False], np.zeros(reversals.size, bool),
                                 np.ones(pause_stops.size, bool)])
    order = np.lexsort((from_pause, starts))  # at equal start, the pause end wins (last)
    starts, refs, from_pause = starts[order], refs[order], from_pause[order]
    seg = _segment_ids(starts, n)
    travel = _running_max_per_segment(np.abs(x - x[refs[seg]]), seg)
    near = travel < presliding_range

    region = np.full(n, _SLIDING, dtype=np.int8)
    region[near] = _PRESLIDING
    region[near & from_pause[seg]] = _DWELL
    region[in_pause] = _STANDSTILL
    return region
