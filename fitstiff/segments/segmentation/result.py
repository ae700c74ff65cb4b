"""What :func:`~fitstiff.segments.segmentation.segment` returns: the immutable
:class:`Segmentation` of one log, and the names of its region and speed-band codes."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from fitstiff.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["REGIONS", "SPEED_BANDS", "Segmentation"]

REGIONS = ("presliding", "sliding", "dwell", "standstill", "stroke_end")
"""Region names. ``Segmentation.region`` holds codes into this tuple for the first four (a
partition of the samples); ``stroke_end`` is the separate, overlapping flag."""

SPEED_BANDS = ("slow", "medium", "fast", "standstill", "unknown")
"""Speed-band names; ``Segmentation.speed_band`` holds codes into this tuple. ``standstill``
tags pause samples, ``unknown`` every sample of a log without time."""

_PRESLIDING, _SLIDING, _DWELL, _STANDSTILL = range(4)
_SLOW, _MEDIUM, _FAST, _BAND_STANDSTILL, _BAND_UNKNOWN = range(5)


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
        true displacement with :func:`~fitstiff.segments.segmentation.standstill`, and the
        diagnosis reads the ``dwell`` and ``standstill`` regions from the same pauses.
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
