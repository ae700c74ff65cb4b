"""The programs a plan chooses from: a few families of motion, gridded inside the limits.

Every family is built from :mod:`fitstiff.physics.programs` (so a plan's program is a program
of the simulator), starts at rest at displacement 0 (relative to its start position, as in
the logs) and is padded with rest to the plan's duration, so that every candidate has the
same number of samples (one compilation of the rivals' predictions serves them all):

``cycles``   triangle cycles +-A at one rate, optional pauses at the reversals (presliding
             range against sliding, rate, standstill);
``holds``    a fast move to +d, a hold, a fast move back, a hold (pressure relaxation, drift);
``sweep``    a sine sweep of amplitude A up to the fastest frequency the speed limit allows
             (acceleration, lag);
``rates``    triangle cycles of amplitude A at three rates a factor 5 apart (rate laws).

Each is run at a supply pressure and start position of the limits (:class:`Limits`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.physics.programs import Concat, Pause, Program, SineSweep, Waypoints
from fitstiff.units import BAR, MM

__all__ = ["Limits", "Choice", "FAMILIES", "choices", "naive_choice"]

FAMILIES = ("cycles", "holds", "sweep", "rates")
_AMPLITUDES_MM = (0.1, 0.3, 1.0, 3.0)
_HOLDS_MM = (1.0, 5.0, 20.0)
_PAUSES_S = (0.0, 1.0, 4.0)
_SPEED_SHARES = (0.05, 0.25, 1.0)
_MAX_SWEEP_HZ = 20.0
#: the command-line flag of each limit (fitstiff plan)
_FLAGS = {"max_duration_s": "--max-duration", "max_speed_mm_s": "--max-speed",
          "stroke_range_mm": "--stroke-range", "pressures_bar": "--pressures",
          "rate_hz": "--rate"}
_SPEED_WINDOW_S = 0.05
#: samples a leg lasts at least: legs last whole sample periods (:mod:`~fitstiff.physics.programs`),
#: so a shorter one runs faster than its rate by up to half a period in its length
_MIN_LEG = 10


@dataclasses.dataclass(frozen=True, kw_only=True)
class Limits:
    """What the rig can do on the next run.

    Attributes:
        max_duration_s: length of each program.
        max_speed_mm_s: fastest piston speed.
        stroke_range_mm: ``(low, high)`` absolute piston positions (chamber A length) the
            motion must stay within.
        pressures_bar: supply pressures (gauge) a program may be run at.
        rate_hz: the sample rate the program is written and recorded at.
    """

    max_duration_s: float
    max_speed_mm_s: float
    stroke_range_mm: tuple[float, float]
    pressures_bar: tuple[float, ...]
    rate_hz: float

    def __post_init__(self):
        for name in ("max_duration_s", "max_speed_mm_s", "rate_hz"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(None, f"--{name.replace('_', '-')}", f"found {value!r}",
                                 "give a positive number")
        lo, hi = (float(v) for v in self.stroke_range_mm)
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise InputError(None, "--stroke-range", f"found {lo!r} {hi!r} mm",
                             "give LOW HIGH with HIGH > LOW (absolute piston positions, mm)")
        pressures = tuple(float(p) for p in self.pressures_bar)
        if not pressures or not all(math.isfinite(p) and p >= 0 for p in pressures):
            raise InputError(None, "--pressures", f"found {list(self.pressures_bar)!r} bar",
                             "give one or more supply pressures >= 0 bar (gauge)")
        object.__setattr__(self, "stroke_range_mm", (lo, hi))
        object.__setattr__(self, "pressures_bar", tuple(sorted(set(pressures))))

    @classmethod
    def from_logs(cls, logs: Sequence[Log], **given) -> Limits:
        """Limits from what the logs and their sidecars show, ``given`` (not None) on top:
        the longest log's duration, the fastest speed logged (99th percentile over 50 ms),
        the stroke from 5 to 95 % (the logged positions where no stroke is known), the logged
        supply pressures and the logs' median sample rate (logs with a time column)."""
        durations, speeds, rates, lows, highs, pressures = [], [], [], [], [], []
        for log in logs:
            x = np.asarray(log.displacement, float)
            t = log.time
            if t is not None and t.size > 1 and np.all(np.diff(t) > 0):
                dt = np.diff(t)
                durations.append(float(t[-1] - t[0]))
                rates.append(1.0 / float(np.median(dt)))
                # over 50 ms: a sample-to-sample difference reads the encoder's noise
                w = max(1, min(x.size - 1, int(round(_SPEED_WINDOW_S * rates[-1]))))
                v = np.abs(x[w:] - x[:-w]) / (t[w:] - t[:-w])
                speeds.append(float(np.quantile(v, 0.99)) / MM)
            rig = log.rig
            start = rig.start_position
            if rig.stroke is not None:
                lows.append(0.05 * rig.stroke / MM)
                highs.append(0.95 * rig.stroke / MM)
            elif start is not None:
                lows.append((start + x.min()) / MM)
                highs.append((start + x.max()) / MM)
            if rig.supply_pressure is not None:
                pressures.append(round(rig.supply_pressure / BAR, 3))
        found = {"max_duration_s": max(durations, default=None),
                 "max_speed_mm_s": max(speeds, default=None),
                 "stroke_range_mm": (min(lows), max(highs)) if lows else None,
                 "pressures_bar": tuple(pressures) or None,
                 "rate_hz": float(np.median(rates)) if rates else None}
        found.update({k: v for k, v in given.items() if v is not None})
        missing = [k for k, v in found.items() if v is None]
        if missing:
            raise InputError(None, "plan limits", f"the logs do not show {', '.join(missing)}",
                             "give " + ", ".join(_FLAGS[m] for m in missing)
                             + " (or logs with a time column and sidecars with stroke_mm, "
                               "start_position_mm, supply_bar)")
        return cls(**found)

    def samples(self) -> int:
        """Samples of every program: the duration at the rate."""
        return int(round(self.max_duration_s * self.rate_hz)) + 1

    def to_dict(self) -> dict[str, object]:
        out = dataclasses.asdict(self)
        out["stroke_range_mm"] = list(self.stroke_range_mm)
        out["pressures_bar"] = list(self.pressures_bar)
        return out


@dataclasses.dataclass(frozen=True)
class Choice:
    """One candidate program: a family with its options, run at ``supply_bar`` from
    ``start_position_mm``."""

    family: str
    options: Mapping[str, float]
    supply_bar: float
    start_position_mm: float

    def program(self) -> Program:
        return _build(self.family, self.options)

    def sample(self, limits: Limits) -> tuple[np.ndarray, np.ndarray]:
        """``(time_s, displacement_m)`` at the limits' rate, padded with rest to
        :meth:`Limits.samples` (a replayed log is cut there)."""
        n = limits.samples()
        if self.family == "replay":
            t = np.asarray(self.options["time_s"], float)
            x = np.asarray(self.options["displacement_m"], float)
            grid = np.arange(n) / limits.rate_hz
            x = np.interp(grid[grid <= t[-1] - t[0] + 0.5 / limits.rate_hz], t - t[0], x)
            x = x - x[0]                   # a program starts at its start position
        else:
            _, x = self.program().sample(limits.rate_hz)
            x = x[:n]
        x = np.concatenate([x, np.full(n - x.size, x[-1])])
        return np.arange(n) / limits.rate_hz, x

    def describe(self) -> dict[str, object]:
        options = ({k: v for k, v in self.options.items() if not isinstance(v, np.ndarray)}
                   if self.family == "replay" else dict(self.options))
        return {"family": self.family, **options}


def _build(family: str, o: Mapping[str, float]) -> Program:
    if family == "cycles":
        a, n = o["amplitude_mm"], int(o["cycles"])
        points = [a, -a] * n + [0.0]
        return Waypoints(points_mm=points, rate_mm_s=o["rate_mm_s"],
                         pause_s=(o["pause_s"],) if o["pause_s"] > 0 else ())
    if family == "holds":
        d, rate, hold = o["displacement_mm"], o["rate_mm_s"], o["hold_s"]
        return (Waypoints(points_mm=[d], rate_mm_s=rate) + Pause(duration_s=hold)
                + Waypoints(points_mm=[-d], rate_mm_s=rate) + Pause(duration_s=hold))
    if family == "sweep":
        return SineSweep(amplitude_mm=o["amplitude_mm"], start_hz=o["start_hz"],
                         end_hz=o["end_hz"], duration_s=o["duration_s"])
    if family == "rates":
        a, parts = o["amplitude_mm"], []
        for rate in (o["rate_mm_s"] / 25, o["rate_mm_s"] / 5, o["rate_mm_s"]):
            parts.append(Waypoints(points_mm=[a, -a] * int(o["cycles"]) + [0.0],
                                   rate_mm_s=rate))
        return Concat(parts=tuple(parts))
    raise KeyError(family)


def _sig(value: float, digits: int = 3) -> float:
    """``value`` to ``digits`` significant digits (readable options, a program a person can
    type into a rig's controller)."""
    return float(f"{value:.{digits}g}")


def _room(limits: Limits, start_mm: float) -> float:
    """How far the motion may go either way from ``start_mm`` inside the stroke range."""
    lo, hi = limits.stroke_range_mm
    return max(0.0, min(start_mm - lo, hi - start_mm))


def choices(limits: Limits, *, supply_bar: float, start_position_mm: float,
            families: Sequence[str] = FAMILIES) -> Iterator[Choice]:
    """Every gridded program of ``families`` that fits the limits at this supply and start."""
    room = _room(limits, start_position_mm)
    span = limits.max_duration_s * 0.95            # a little rest at the end
    vmax = limits.max_speed_mm_s

    def choice(family, **options):
        return Choice(family, options, supply_bar, start_position_mm)

    if "cycles" in families:
        for a in _AMPLITUDES_MM:
            if a > room:
                continue
            for share in _SPEED_SHARES:
                rate = _sig(vmax * share)
                if a / rate < _MIN_LEG * (1.0 / limits.rate_hz):
                    continue
                for pause in _PAUSES_S:
                    cycle = 4 * a / rate + 2 * pause
                    n = int((span - a / rate) // cycle)
                    if n >= 1 and pause <= span / 4:
                        yield choice("cycles", amplitude_mm=a, rate_mm_s=rate,
                                     pause_s=pause, cycles=min(n, 200))
    if "holds" in families:
        for d in sorted({min(h, room) for h in _HOLDS_MM}):
            if d <= 0:
                continue
            move = d / vmax
            hold = (span - 2 * move) / 2
            if hold > 0.5:
                for sign in (1.0, -1.0):
                    yield choice("holds", displacement_mm=_sig(sign * d), rate_mm_s=_sig(vmax),
                                 hold_s=_sig(hold))
    if "sweep" in families:
        for a in _AMPLITUDES_MM[1:]:
            top = min(_MAX_SWEEP_HZ, vmax / (2 * math.pi * a), limits.rate_hz / 20)
            if a <= room and top > 1.0:
                yield choice("sweep", amplitude_mm=a, start_hz=0.5, end_hz=_sig(top),
                             duration_s=_sig(span))
    if "rates" in families:
        for a in (0.5, 2.0):
            rate = _sig(vmax)
            per = 4 * a * (25 + 5 + 1) / rate
            n = int(span // per)
            if a <= room and n >= 1:
                yield choice("rates", amplitude_mm=a, rate_mm_s=rate, cycles=min(n, 50))


def naive_choice(log: Log) -> Choice:
    """The naive alternative of the same duration: the log's own motion replayed at its supply
    and start position (cut to the plan's duration, rest after its end)."""
    rig = log.rig
    t = log.time if log.time is not None else np.arange(len(log), dtype=float)
    return Choice("replay", {"log": log.name, "time_s": np.asarray(t, float),
                             "displacement_m": np.asarray(log.displacement, float)},
                  (rig.supply_pressure or 0.0) / BAR, (rig.start_position or 0.0) / MM)
