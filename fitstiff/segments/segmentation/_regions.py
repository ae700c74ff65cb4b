"""Per-sample motion regions (standstill > dwell > presliding > sliding) and the presliding
range they use (see :mod:`fitstiff.segments.segmentation`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitstiff.segments.segmentation.result import _DWELL, _PRESLIDING, _SLIDING, _STANDSTILL

DEFAULT_PRESLIDING_RANGE = 0.5e-3  # m, DESIGN §1.2


def _segment_ids(starts: np.ndarray, n: int) -> np.ndarray:
    """For each sample, the index of the last of the sorted ``starts`` at or before it."""
    return np.searchsorted(starts, np.arange(n), side="right") - 1


def _running_max_per_segment(values: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Cumulative maximum of non-negative ``values`` restarted at each new ``seg`` id."""
    offset = (float(values.max()) + 1.0) * (seg - seg.min()) if values.size else 0.0
    return np.maximum.accumulate(values + offset) - offset


def _legs(x: np.ndarray, reversals: np.ndarray, first_start: int) -> np.ndarray:
    """Travel of every leg (between reversals, from the first motion to the end), > 0 (m)."""
    if not x.size:
        return np.empty(0)
    ends = np.clip(np.concatenate([[first_start], reversals, [x.size - 1]]).astype(int),
                   0, x.size - 1)
    travel = np.abs(np.diff(x[ends]))
    return travel[travel > 0]


class _PreslidingRange(NamedTuple):
    """What :func:`_presliding_range` chooses."""

    value: float             # m
    notes: list[str]         # why it was derived, or why it leaves no sample sliding


def _presliding_range(legs: np.ndarray, given: float | None) -> _PreslidingRange:
    """The presliding range to use, and a note when it cannot leave a sliding sample.

    Given: used as it is, with a note when every leg is shorter (no sample can count as
    sliding; issue 17: a 0.23 mm microtribometer stroke against the 0.5 mm default had no
    presliding or sliding sample at all). Default: :data:`DEFAULT_PRESLIDING_RANGE`, or a
    third of the median leg when every leg is shorter than that, said in a note.
    """
    if not legs.size:
        return _PreslidingRange(DEFAULT_PRESLIDING_RANGE if given is None else given, [])
    longest, median = float(legs.max()), float(np.median(legs))
    if given is None:
        if longest >= DEFAULT_PRESLIDING_RANGE:
            return _PreslidingRange(DEFAULT_PRESLIDING_RANGE, [])
        derived = median / 3.0
        return _PreslidingRange(derived, [
            f"every travel between reversals (median {median * 1e3:.3g} mm, longest "
            f"{longest * 1e3:.3g} mm) is shorter than the default presliding range "
            f"({DEFAULT_PRESLIDING_RANGE * 1e3:g} mm): the presliding range is a third of the "
            f"median travel, {derived * 1e3:.2g} mm; give --presliding-range-mm to set it"])
    if longest >= given:      # minor loops inside pre-sliding are by design
        return _PreslidingRange(given, [])
    return _PreslidingRange(given, [
        f"the presliding range ({given * 1e3:.3g} mm) exceeds every travel between reversals "
        f"(median {median * 1e3:.3g} mm, longest {longest * 1e3:.3g} mm): no sample can be "
        f"sliding, and after a pause every sample is dwell; give a shorter "
        f"--presliding-range-mm (e.g. {median * 1e3 / 3:.2g}) for these logs"])


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
