"""The segmentation of one log: :func:`segment` puts the reversals, pauses, regions, speed
bands and stroke ends of a :class:`~fitstiff.io.log.Log` into a :class:`Segmentation` (see
:mod:`fitstiff.segments.segmentation`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.segments.segmentation._regions import _legs, _presliding_range, _regions
from fitstiff.segments.segmentation._reversals import (_default_threshold, _hysteresis_reversals,
                                                       _running_median)
from fitstiff.segments.segmentation._time import DEFAULT_MIN_PAUSE, _pauses, _velocity
from fitstiff.segments.segmentation.result import _BAND_STANDSTILL, _BAND_UNKNOWN, Segmentation
from fitstiff.signal.noise import estimate_noise

DEFAULT_SPEED_EDGES = (2e-3, 20e-3)  # m/s: slow < 2 mm/s <= medium < 20 mm/s <= fast
DEFAULT_SPEED_WINDOW = 0.1  # s
DEFAULT_STROKE_END_FRACTION = 0.1  # of the stroke


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
    _check_options(where, threshold=threshold, presliding_range=presliding_range,
                   min_pause=min_pause, pause_band=pause_band, speed_edges=speed_edges,
                   speed_window=speed_window, stroke_end_margin=stroke_end_margin,
                   median_window=median_window)
    lo_edge, hi_edge = speed_edges
    n = len(log)
    raw = np.asarray(log.displacement, dtype=np.float64)
    x = _running_median(raw, int(median_window))
    noise = estimate_noise(raw)
    if threshold is None:
        threshold = _default_threshold(raw)
    legs = _legs_of(x, threshold, n)
    time = log.time
    timed = _timed(x, time, n, band=pause_band or threshold, min_pause=min_pause,
                   speed_window=speed_window)
    legs.direction[timed.in_pause] = 0
    presliding = _presliding_range(_legs(x, legs.reversals, legs.first_start), presliding_range)
    region = _regions(x, legs.reversals, timed.pauses, timed.in_pause, threshold=threshold,
                      presliding_range=presliding.value)
    speed_band = _speed_bands(timed.velocity, timed.in_pause, lo_edge, hi_edge, n)
    stroke = _stroke_end(log.rig, raw, stroke_end_margin)
    pressure_level = _pressure_level(log)
    notes = legs.notes + timed.notes + presliding.notes + stroke.notes
    if pressure_level is None:
        notes.append("pressure level unknown: no supply_bar in the rig metadata and no "
                     "logged chamber pressure")

    return Segmentation(
        name=log.name, n_samples=n, noise=noise, threshold=float(threshold),
        presliding_range=float(presliding.value), reversals=legs.reversals, loops=legs.loops,
        pauses=timed.pauses, pause_durations=timed.pause_durations, direction=legs.direction,
        velocity=timed.velocity, speed_band=speed_band,
        speed_edges=(float(lo_edge), float(hi_edge)), region=region, stroke_end=stroke.mask,
        stroke_end_margin=stroke.margin, pressure_level=pressure_level,
        has_time=time is not None, notes=tuple(notes))


def _check_options(where: str, *, threshold, presliding_range, min_pause, pause_band,
                   speed_edges, speed_window, stroke_end_margin, median_window) -> None:
    """An InputError for the first option of :func:`segment` out of its range."""
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


def _positive(name: str, value: float | None, where: str) -> None:
    if value is not None and not (np.isfinite(value) and value > 0):
        raise InputError(where, f"segmentation option '{name}'", f"found {value!r}",
                         "give a positive number")


class _Legs(NamedTuple):
    """The legs between the reversals."""

    reversals: np.ndarray    # sample indices, ascending
    loops: np.ndarray        # (n_loops, 2) half-open sample ranges of full cycles
    direction: np.ndarray    # per sample +1 / -1, 0 before the first leg (pauses not yet 0)
    first_start: int         # first sample of the first leg
    notes: list[str]


def _legs_of(x: np.ndarray, threshold: float, n: int) -> _Legs:
    """The reversals of ``x`` (``n`` samples; hysteresis ``threshold``), its loops and
    direction."""
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
    return _Legs(reversals, loops, direction, first_start, notes)


class _Timed(NamedTuple):
    """What needs time (empty without it)."""

    pauses: np.ndarray            # (n_pauses, 2) half-open sample ranges
    pause_durations: np.ndarray   # s
    velocity: np.ndarray | None   # m/s per sample; None without time
    in_pause: np.ndarray          # per sample
    notes: list[str]


def _timed(x: np.ndarray, time: np.ndarray | None, n: int, *, band: float, min_pause: float,
           speed_window: float) -> _Timed:
    """The pauses and velocity of ``x`` (``n`` samples) over ``time`` (none without time,
    said in a note)."""
    notes: list[str] = []
    if time is not None:
        pauses = _pauses(x, time, band=band, min_pause=min_pause)
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
    return _Timed(pauses, pause_durations, velocity, in_pause, notes)


def _speed_bands(velocity: np.ndarray | None, in_pause: np.ndarray, lo_edge: float,
                 hi_edge: float, n: int) -> np.ndarray:
    """Per sample the speed-band code (``unknown`` without velocity, ``standstill`` in a
    pause)."""
    if velocity is None:
        return np.full(n, _BAND_UNKNOWN, dtype=np.int8)
    speed_band = np.digitize(np.abs(velocity), [lo_edge, hi_edge]).astype(np.int8)
    speed_band[in_pause] = _BAND_STANDSTILL
    return speed_band


class _StrokeEnd(NamedTuple):
    """The ``stroke_end`` flag, where the rig's stroke and start position are known."""

    mask: np.ndarray | None
    margin: float | None     # m
    notes: list[str]


def _stroke_end(rig, raw: np.ndarray, margin: float | None) -> _StrokeEnd:
    """Per sample within ``margin`` (default 10 % of the stroke) of either cap."""
    if rig.stroke is None or rig.start_position is None:
        missing = [k for k, v in (("stroke_mm", rig.stroke),
                                  ("start_position_mm", rig.start_position)) if v is None]
        return _StrokeEnd(None, None, [f"stroke_end region skipped: rig metadata "
                                       f"{' and '.join(missing)} missing"])
    if margin is None:
        margin = DEFAULT_STROKE_END_FRACTION * rig.stroke
    position = rig.start_position + raw
    return _StrokeEnd((position < margin) | (position > rig.stroke - margin), margin, [])


def _pressure_level(log: Log) -> float | None:
    if log.rig.supply_pressure is not None:
        return float(log.rig.supply_pressure)
    logged = [p for p in (log.pressure_a, log.pressure_b) if p is not None]
    if not logged:
        return None
    return float(np.mean([p.mean() for p in logged]) - log.rig.ambient_pressure)

