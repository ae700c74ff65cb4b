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

The parts, one concept a module: :mod:`~fitstiff.segments.segmentation.result` (the
:class:`Segmentation` record and its code names), ``_reversals`` (noise, threshold, the
hysteresis rule), ``_time`` (pauses, velocity), ``_regions`` (motion regions and the
presliding range) and ``_segment`` (:func:`segment`, which puts them together).
"""

from __future__ import annotations

from fitstiff.segments.segmentation._regions import DEFAULT_PRESLIDING_RANGE
from fitstiff.segments.segmentation._reversals import (NOISE_MULTIPLE, RESOLUTION_MULTIPLE,
                                                       THRESHOLD_FLOOR)
from fitstiff.segments.segmentation._segment import (DEFAULT_SPEED_EDGES, DEFAULT_SPEED_WINDOW,
                                                     DEFAULT_STROKE_END_FRACTION, segment)
from fitstiff.segments.segmentation._time import DEFAULT_MIN_PAUSE, standstill
from fitstiff.segments.segmentation.result import REGIONS, SPEED_BANDS, Segmentation
from fitstiff.signal.noise import estimate_noise   # its home; here for the segmentation's users

__all__ = [
    "REGIONS",
    "SPEED_BANDS",
    "Segmentation",
    "estimate_noise",
    "segment",
    "standstill",
    # the defaults of segment (the command line shows them)
    "DEFAULT_MIN_PAUSE",
    "DEFAULT_PRESLIDING_RANGE",
    "DEFAULT_SPEED_EDGES",
    "DEFAULT_SPEED_WINDOW",
    "DEFAULT_STROKE_END_FRACTION",
    "NOISE_MULTIPLE",
    "RESOLUTION_MULTIPLE",
    "THRESHOLD_FLOOR",
]
