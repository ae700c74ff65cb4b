"""What a held-out residual can be described by (:mod:`fitstiff.diagnosis.structure`): the
variables per sample (:func:`structure_variables`) and the candidate descriptions of each,
a variable in one form (:func:`candidates`: linear, curved, smooth, periodic, step, or the
force's hysteresis; even or sign-dependent).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff.io.log import Log
from fitstiff.segments.segmentation import Segmentation

__all__ = ["VARIABLES", "UNITS", "Candidate", "candidates", "disjoint", "one_level_per_log",
           "periods", "phase_per_log", "stretches", "structure_variables"]

#: what a residual can follow, in the order ties are broken (physical variables first)
VARIABLES = ("position", "time", "pressure", "velocity", "since_reversal", "direction",
             "acceleration", "force", "log")
UNITS = {"position": "mm", "time": "s", "pressure": "bar", "velocity": "mm/s",
         "since_reversal": "mm", "direction": "", "acceleration": "mm/s^2", "force": "N",
         "log": ""}
#: periods scanned for a periodic description (:func:`periods`)
_PERIODS = 40


def structure_variables(log: Log, seg: Segmentation, model_force: np.ndarray
                        ) -> dict[str, np.ndarray]:
    """Per-sample values of every variable this log has (display units), and the two signs:
    ``_motion`` (direction of motion, 0 standing still) and ``_force`` (direction of the
    model force's change). ``model_force``: the final model's held-out prediction (N)."""
    n = len(log)
    out: dict[str, np.ndarray] = {}
    x0 = log.rig.start_position
    out["position"] = 1e3 * ((x0 or 0.0) + np.asarray(log.displacement))
    # whether the position is along the stroke (the rig gives the start) or from the start
    out["_absolute"] = np.full(n, float(x0 is not None))
    if log.time is not None:
        out["time"] = np.asarray(log.time) - float(log.time[0])
    if seg.pressure_level is not None:
        out["pressure"] = np.full(n, seg.pressure_level / 1e5)
    if seg.velocity is not None:
        v = np.asarray(seg.velocity)
        out["velocity"] = 1e3 * v
        if log.time is not None and n > 4:
            out["acceleration"] = 1e3 * _smooth(np.gradient(v, np.asarray(log.time)), 5)
    out["since_reversal"] = 1e3 * _since_reversal(np.asarray(log.displacement), seg.reversals)
    if seg.velocity is not None:
        out["_leg_speed"] = leg_speed(1e3 * np.asarray(seg.velocity), seg.reversals)
    out["direction"] = np.asarray(seg.direction, float)
    out["force"] = np.asarray(model_force, float)
    out["_motion"] = held_direction(np.asarray(seg.direction, float))
    # the model force has no noise: the sign of its change marks its reversals
    f = np.asarray(model_force, float)
    change = np.sign(np.gradient(f))
    out["_force"] = change
    turn = np.flatnonzero((change[1:] != change[:-1]) & (change[1:] != 0)) + 1
    out["_force_since_reversal"] = _since_reversal(f, turn)
    return out


def held_direction(direction: np.ndarray) -> np.ndarray:
    """The direction of the last motion, held while the piston stands (0 before it first
    moves): the sign of the friction, which keeps its last sliding sign through a pause or
    a hold, where a change of its level shows as much as in the motion before it."""
    moving = direction != 0
    if not moving.any():
        return direction
    last = np.maximum.accumulate(np.where(moving, np.arange(direction.size), -1))
    return np.where(last >= 0, direction[np.maximum(last, 0)], 0.0)


def leg_speed(v: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """Per sample, the speed of its leg (the motion between two reversals): the median speed
    of the leg's moving samples (where ``|v|`` exceeds a tenth of the leg's largest), the
    rate the seal's transition after the reversal runs at."""
    cuts = np.unique(np.concatenate([[0], np.asarray(reversals, dtype=np.int64), [v.size]]))
    out = np.zeros(v.size)
    for a, b in zip(cuts[:-1], cuts[1:]):
        speed = np.abs(v[a:b])
        if speed.size == 0 or speed.max() <= 0:
            continue
        out[a:b] = float(np.median(speed[speed > 0.1 * speed.max()]))
    return out


def _smooth(a: np.ndarray, width: int) -> np.ndarray:
    if a.size < width:
        return a
    kernel = np.ones(width) / width
    padded = np.pad(a, width // 2, mode="edge")
    return np.convolve(padded, kernel, mode="valid")[: a.size]


def _since_reversal(x: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """Travel since the last reversal (or since the start), m."""
    anchor = np.zeros(x.size, dtype=np.int64)
    for r in np.asarray(reversals, dtype=np.int64):
        anchor[r:] = r
    return np.abs(x - x[anchor])


@dataclasses.dataclass(frozen=True, eq=False)
class Candidate:
    """A candidate description: ``variable`` in one ``form``, even or ``signed`` (times the
    direction of motion, or of the force's change for its hysteresis)."""

    variable: str
    form: str              # linear / curved / smooth / gated / periodic / step / transition
    signed: bool
    values: np.ndarray     # the variable, all samples (concatenated logs)
    sign: np.ndarray       # the sign multiplying the columns (ones when even)
    #: per sample, the group of logs that share a periodic description's phase and
    #: amplitude (:func:`stretches`); None for the other forms
    groups: np.ndarray | None = None
    #: per sample, what a ``transition`` description's shape is scaled by (the time, the
    #: supply pressure, or the log of the leg's speed), or a ``gated`` one's travel since
    #: the last reversal (mm); None for the other forms
    scale: np.ndarray | None = None

    @property
    def label(self) -> str:
        if self.form == "transition":
            return "sign-dependent transition after each reversal, scaled by it"
        if self.form == "gated":
            return "sign-dependent friction level (grows in after each reversal)"
        if self.form == "hysteresis":
            return "hysteresis (smooth in the force's change since it last turned)"
        return ("sign-dependent " if self.signed else "") + self.form


def candidates(per_log: Sequence[Mapping[str, np.ndarray]], log_id: np.ndarray
               ) -> list[Candidate]:
    """Every candidate description of the logs' variables (``per_log``: each log's
    :func:`structure_variables`), in the order of :data:`VARIABLES`: the forms each variable
    can take, those its values allow (two pressures for a line, three for a curve, a travel
    long enough for a period)."""
    n_logs = len(per_log)
    out: list[Candidate] = []

    def cat(name):
        if any(name not in v for v in per_log):
            return None
        return np.concatenate([v[name] for v in per_log])

    motion, force_sign = cat("_motion"), cat("_force")
    ones = np.ones_like(motion)
    travel = cat("since_reversal")
    scales = {"time": cat("time"), "pressure": cat("pressure"), "velocity": (
        None if cat("_leg_speed") is None else np.log(np.maximum(cat("_leg_speed"), 1e-9)))}
    for name in VARIABLES:
        z = scales.get(name)
        if travel is not None and z is not None and np.all(np.isfinite(z)) and np.ptp(z) > 0:
            # a friction (level or stiffness) that follows the variable: the transition
            # after a reversal, smooth in the travel since it, scaled linearly in the variable
            out.append(Candidate(name, "transition", True, travel, motion, scale=z))
        if name == "log":
            if n_logs >= 2:
                out.append(Candidate("log", "step", True, log_id.astype(float), motion))
            continue
        v = cat(name)
        if v is None or not np.all(np.isfinite(v)):
            continue
        if name == "direction":
            out.append(Candidate(name, "step", False, v, ones))
            continue
        if name == "pressure":
            levels = np.unique(np.round(v, 3))
            if levels.size >= 2:
                out.append(Candidate(name, "linear", True, v, motion))
            if levels.size >= 3:
                out.append(Candidate(name, "curved", True, v, motion))
            continue
        if np.ptp(v) <= 0:
            continue
        sign = force_sign if name == "force" else motion
        if name == "force":         # a nonlinearity of F, a hysteresis in F
            out.append(Candidate(name, "smooth", False, v, ones))
            travel = cat("_force_since_reversal")
            if travel is not None and np.ptp(travel) > 0:
                out.append(Candidate(name, "hysteresis", True, travel, sign))
            continue
        if name == "velocity":      # a friction-like law of the speed, or any law of v
            out.append(Candidate(name, "smooth", True, np.abs(v), sign))
            out.append(Candidate(name, "smooth", False, v, ones))
            continue
        if name == "acceleration":
            out.append(Candidate(name, "linear", False, v, ones))
            out.append(Candidate(name, "smooth", False, v, ones))
            continue
        if name in ("time",):
            out.append(Candidate(name, "linear", False, v, ones))
            out.append(Candidate(name, "linear", True, v, sign))
        for signed in (False, True):
            out.append(Candidate(name, "smooth", signed, v, sign if signed else ones))
        if name == "position" and travel is not None:
            # a friction level along the bore (a tight spot): it acts once the seal slides,
            # so the curve grows in over the transition after each reversal
            out.append(Candidate(name, "gated", True, v, sign, scale=travel))
        if name == "position" and periods(v, log_id).size:
            absolute = cat("_absolute")
            groups = stretches(v, log_id, absolute is not None and bool(np.all(absolute)))
            for signed in (False, True):
                out.append(Candidate(name, "periodic", signed, v, sign if signed else ones,
                                     groups))
    return out


def stretches(v: np.ndarray, log_id: np.ndarray, absolute: bool) -> np.ndarray:
    """Per sample, its stretch of the stroke: logs whose ranges of the position ``v``
    overlap (directly or through another log) form one, and a periodic description shares
    its phase and amplitude within it: a ripple of the bore or the guide is where it is,
    whichever log travels it. Logs apart keep a phase each (sharing one across a gap would
    need the period to a part in 10^5), and so does every log when the positions are
    relative to each log's start (``absolute`` False: where the logs lie is not known)."""
    logs = np.unique(log_id)
    group = {int(k): i for i, k in enumerate(logs)}
    if absolute:
        ranges = sorted((float(v[log_id == k].min()), float(v[log_id == k].max()), int(k))
                        for k in logs)
        end, current = -np.inf, -1
        for lo, hi, k in ranges:
            if lo > end:
                current += 1
            group[k] = current
            end = max(end, hi)
    lookup = np.zeros(int(logs.max()) + 1, dtype=np.int64)
    for k, g in group.items():
        lookup[k] = g
    return lookup[log_id]


def periods(v: np.ndarray, log_id: np.ndarray) -> np.ndarray:
    """The periods scanned: from 20 sample steps (at least 0.2 of the unit) to half the
    widest log's span (a period is only claimed where two of them were travelled; a
    longer one is a smooth curve); empty when the logs are too short for that."""
    spans = [np.ptp(v[log_id == k]) for k in np.unique(log_id)]
    step = np.median(np.abs(np.diff(v)))
    low = max(0.2, 20 * step)
    high = 0.5 * max(spans)
    return np.geomspace(low, high, _PERIODS) if high > 1.5 * low else np.zeros(0)


def disjoint(v: np.ndarray, log_id: np.ndarray, counted: np.ndarray) -> bool:
    """Whether no two logs share a range of ``v`` (two logs or more): a curve of ``v`` is
    then as well a shape of its own per log."""
    ranges = sorted((float(v[m].min()), float(v[m].max()))
                    for k in np.unique(log_id) if (m := (log_id == k) & counted).any())
    return len(ranges) >= 2 and all(a[1] < b[0] for a, b in zip(ranges, ranges[1:]))


def phase_per_log(cand: Candidate, log_id: np.ndarray, counted: np.ndarray) -> bool:
    """Whether a periodic description has a phase and an amplitude of its own in every log
    (two logs or more, none sharing a stretch of the stroke): it is then as well a shape of
    each log's own, as a curve over ranges that do not overlap is (:func:`disjoint`)."""
    if cand.form != "periodic" or cand.groups is None:
        return False
    seen = [int(k) for k in np.unique(log_id[counted])]
    groups = {int(cand.groups[np.flatnonzero((log_id == k) & counted)[0]]) for k in seen}
    return len(seen) >= 2 and len(groups) == len(seen)


def one_level_per_log(v: np.ndarray, log_id: np.ndarray, counted: np.ndarray) -> bool:
    """Whether ``v`` is one value per log and no two logs share it (two logs or more, such
    as one supply pressure each): anything that differs between the logs is then as well a
    function of ``v``."""
    levels = []
    for k in np.unique(log_id):
        m = (log_id == k) & counted
        if not m.any():
            continue
        values = np.unique(np.round(v[m], 9))
        if values.size != 1:
            return False
        levels.append(float(values[0]))
    return len(levels) >= 2 and np.unique(levels).size == len(levels)
