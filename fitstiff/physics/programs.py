"""Displacement programs: what the piston is made to do in a (simulated) experiment.

A program is a small immutable object with two methods (the :class:`Program` protocol):

``sample(rate_hz)``
    ``(time_s, displacement_m)`` on the uniform grid ``time_s[k] = k / rate_hz``, starting at
    ``time_s[0] = 0`` and ``displacement_m[0] = 0`` (displacement is relative to the start,
    + toward the B cap, SI).
``describe()``
    a JSON-able dict of what the program is (its kind and options), for the ground truth.

Programs in engineering units (mm, mm/s, s, Hz), every option keyword-only:

- :class:`Ramp`: constant-rate ramp over a distance;
- :class:`Pause`: standstill of a given duration;
- :class:`Waypoints`: constant-rate legs through given positions, optional pauses at the
  joints (at reversals, or where the motion passes a joint without reversing);
- :class:`TriangleCycles`: triangle cycles ``0 -> +A -> -A -> 0`` of growing amplitude (the
  paper's Fig. 4 experiment);
- :class:`NestedLoops`: a major cycle with nested minor loops on both branches (return-point
  memory);
- :class:`SineSweep`: sine of fixed or swept frequency, fading in and out so that it starts and
  ends at rest;
- :class:`Concat`: programs one after the other (also ``a + b``); each part continues from
  where the previous one ended. It uses the parts' displacements only, so a part of one's own
  making must follow the :class:`Program` protocol's grid.

Piecewise-linear programs put every joint (reversal, pause start and end) *on* a sample: each
leg and each pause lasts a whole number of sample periods, so a leg takes at most half a
sample period more or less than ``distance / rate``. That is what makes reversal points and
pause lengths exact in the sampled data.

>>> t, x = TriangleCycles(amplitudes_mm=(0.1, 0.5), rate_mm_s=1.0).sample(1000.0)
>>> float(x.max() * 1e3), float(x.min() * 1e3)
(0.5, -0.5)
>>> program = Ramp(distance_mm=0.2, rate_mm_s=1.0) + Pause(duration_s=2.0)
>>> program.describe()["program"]
'concat'
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Sequence
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from fitstiff.errors import InputError
from fitstiff.units import MM

__all__ = ["Program", "Ramp", "Pause", "Waypoints", "TriangleCycles", "NestedLoops",
           "SineSweep", "Concat", "PAUSE_AT"]

#: where :class:`Waypoints`-based programs may pause: at direction reversals, or at joints the
#: motion passes through without reversing (e.g. the zero crossings of triangle cycles)
PAUSE_AT = ("reversals", "passes")


@runtime_checkable
class Program(Protocol):
    """What :func:`fitstiff.physics.simulate.simulate` needs from a displacement program."""

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """``(time_s, displacement_m)``: ``time_s[k] = k / rate_hz``, displacement from 0."""
        ...

    def describe(self) -> dict[str, object]:
        """JSON-able description (kind and options)."""
        ...


def _fail(kind: str, option: str, found: object, fix: str) -> InputError:
    return InputError(None, f"{kind} program option '{option}'", f"found {found!r}", fix)


def _check_rate(rate_hz: float) -> float:
    if not (isinstance(rate_hz, numbers.Real) and math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(None, "sample rate", f"found {rate_hz!r} Hz", "give a positive rate")
    return float(rate_hz)


def _periods(seconds: float, rate_hz: float, *, at_least: int) -> int:
    """A duration as a whole number of sample periods (rounded, at least ``at_least``)."""
    return max(at_least, int(round(seconds * rate_hz)))


def _grid(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    return np.arange(x.shape[0]) / rate_hz, x


def _freeze_tuple(obj, name: str) -> None:
    """Store a sequence option as a tuple of floats (immutable, hashable)."""
    value = getattr(obj, name)
    values = (value,) if isinstance(value, numbers.Real) else value
    try:
        frozen = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise _fail(obj.kind, name, value, "give a number or a sequence of numbers") from None
    object.__setattr__(obj, name, frozen)


class _Base:
    """Shared behaviour: ``a + b`` concatenates, :meth:`describe` lists the options."""

    kind: ClassVar[str] = ""

    def __add__(self, other: Program) -> Concat:
        return Concat(parts=(self, other))

    def describe(self) -> dict[str, object]:
        options = {f.name: getattr(self, f.name)
                   for f in dataclasses.fields(self)}  # type: ignore[arg-type]
        return {"program": self.kind, **{k: list(v) if isinstance(v, tuple) else v
                                         for k, v in options.items()}}

    def _positive(self, *names: str, allow_zero: bool = False) -> None:
        for name in names:
            values = getattr(self, name)
            for v in values if isinstance(values, tuple) else (values,):
                ok = isinstance(v, numbers.Real) and math.isfinite(v) and (
                    v >= 0 if allow_zero else v > 0)
                if not ok:
                    raise _fail(self.kind, name, v, "give a finite number "
                                + (">= 0" if allow_zero else "> 0"))


@dataclasses.dataclass(frozen=True, kw_only=True)
class Ramp(_Base):
    """Move ``distance_mm`` (signed: + toward the B cap) at ``rate_mm_s``."""

    kind: ClassVar[str] = "ramp"
    distance_mm: float
    rate_mm_s: float

    def __post_init__(self):
        self._positive("rate_mm_s")
        if not (isinstance(self.distance_mm, numbers.Real) and math.isfinite(self.distance_mm)
                and self.distance_mm != 0):
            raise _fail(self.kind, "distance_mm", self.distance_mm, "give a non-zero distance")

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        rate_hz = _check_rate(rate_hz)
        return _grid(_legs(np.array([0.0, self.distance_mm * MM]), self.rate_mm_s * MM,
                           rate_hz), rate_hz)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Pause(_Base):
    """Stand still for ``duration_s`` (a whole number of sample periods, at least one)."""

    kind: ClassVar[str] = "pause"
    duration_s: float

    def __post_init__(self):
        self._positive("duration_s")

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        rate_hz = _check_rate(rate_hz)
        return _grid(np.zeros(1 + _periods(self.duration_s, rate_hz, at_least=1)), rate_hz)


@dataclasses.dataclass(frozen=True, kw_only=True)
class _Legs(_Base):
    """Constant-rate legs from 0 through :meth:`path_mm`, optional pauses at the joints
    (options as documented on :class:`Waypoints`)."""

    rate_mm_s: float
    pause_s: Sequence[float] = ()
    pause_at: str = "reversals"

    def __post_init__(self):
        _freeze_tuple(self, "pause_s")
        self._positive("rate_mm_s")
        self._positive("pause_s")
        if self.pause_at not in PAUSE_AT:
            raise _fail(self.kind, "pause_at", self.pause_at, f"use one of: {', '.join(PAUSE_AT)}")
        path = self.path_mm()
        if not path.size or not np.all(np.isfinite(path)):
            raise _fail(self.kind, "positions", path.tolist(), "give finite positions")
        if np.any(np.diff(np.concatenate([[0.0], path])) == 0):
            raise _fail(self.kind, "positions", path.tolist(),
                        "consecutive positions must differ (use pause_s to stand still)")

    def path_mm(self) -> np.ndarray:
        """The positions visited after the start (mm)."""
        raise NotImplementedError

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        rate_hz = _check_rate(rate_hz)
        speed = self.rate_mm_s * MM
        points = np.concatenate([[0.0], self.path_mm()]) * MM
        direction = np.sign(np.diff(points))
        reversal = direction[1:] != direction[:-1]          # at the joints points[1:-1]
        chosen = reversal if self.pause_at == "reversals" else ~reversal
        joints = np.flatnonzero(chosen) + 1 if self.pause_s else np.array([], dtype=int)
        pieces = []
        start = 0
        for count, joint in enumerate(joints):
            hold = Pause(duration_s=self.pause_s[count % len(self.pause_s)])
            pieces += [_legs(points[start:joint + 1], speed, rate_hz),
                       points[joint] + hold.sample(rate_hz)[1]]
            start = joint
        pieces.append(_legs(points[start:], speed, rate_hz))
        return _grid(_join(pieces, shift=False), rate_hz)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Waypoints(_Legs):
    """Constant-rate legs from 0 through ``points_mm`` (positions relative to the start).

    Args:
        points_mm: the positions visited in order; consecutive points must differ.
        rate_mm_s: speed along every leg.
        pause_s: pause durations inserted at the joints selected by ``pause_at``, used in
            turn and repeated cyclically (``(0.5, 2.0)`` pauses 0.5 s, 2 s, 0.5 s ...);
            empty (default) for none.
        pause_at: ``"reversals"`` (where the direction changes) or ``"passes"`` (joints the
            motion passes without reversing, such as the zero crossings of triangle cycles).
    """

    kind: ClassVar[str] = "waypoints"
    points_mm: Sequence[float]

    def __post_init__(self):
        _freeze_tuple(self, "points_mm")
        super().__post_init__()

    def path_mm(self) -> np.ndarray:
        return np.asarray(self.points_mm, dtype=float)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TriangleCycles(_Legs):
    """Triangle cycles ``0 -> +A -> -A -> 0`` for each amplitude in turn (the Fig. 4 test).

    Args:
        amplitudes_mm: cycle amplitudes, typically growing (``(0.05, 0.1, 0.2, 0.5, 1.0)``).
        cycles: how many cycles at each amplitude.
        rate_mm_s, pause_s, pause_at: as for :class:`Waypoints`; ``pause_at="passes"`` pauses
            at the zero crossings, i.e. mid-stroke of each cycle.
    """

    kind: ClassVar[str] = "triangle_cycles"
    amplitudes_mm: Sequence[float]
    cycles: int = 1

    def __post_init__(self):
        _freeze_tuple(self, "amplitudes_mm")
        self._positive("amplitudes_mm")
        _check_count(self)
        super().__post_init__()

    def path_mm(self) -> np.ndarray:
        return np.array([p for a in self.amplitudes_mm for _ in range(self.cycles)
                         for p in (a, 0.0, -a, 0.0)])


@dataclasses.dataclass(frozen=True, kw_only=True)
class NestedLoops(_Legs):
    """A major cycle between ``-amplitude_mm`` and ``+amplitude_mm`` with nested minor loops.

    On each branch the motion stops at ``centre_mm``, turns back by ``minor_mm[0]``, inside
    that loop turns back by ``minor_mm[1]``, and so on, then closes every minor loop in turn
    and continues the branch. With ``minor_mm = (0.4, 0.2)`` the descending branch visits
    ``0 -> 0.4 -> 0.2 -> 0.4 -> 0``: each minor loop returns to the point where it began,
    which is where friction models with return-point memory (Maxwell-slip) close their loops
    and Dahl / LuGre do not. The program starts at 0, goes to ``+amplitude_mm`` first and
    ends back at 0.

    Args:
        amplitude_mm: major cycle amplitude.
        minor_mm: minor loop sizes, strictly decreasing, ``|centre_mm| + minor_mm[0]`` inside
            the major cycle.
        centre_mm: where on each branch the minor loops start.
        cycles: number of major cycles.
        rate_mm_s, pause_s, pause_at: as for :class:`Waypoints`.
    """

    kind: ClassVar[str] = "nested_loops"
    amplitude_mm: float
    minor_mm: Sequence[float]
    centre_mm: float = 0.0
    cycles: int = 1

    def __post_init__(self):
        _freeze_tuple(self, "minor_mm")
        self._positive("amplitude_mm", "minor_mm")
        sizes = np.asarray(self.minor_mm)
        if not sizes.size or np.any(np.diff(sizes) >= 0):
            raise _fail(self.kind, "minor_mm", list(self.minor_mm),
                        "give one or more strictly decreasing loop sizes")
        if not (isinstance(self.centre_mm, numbers.Real)
                and abs(self.centre_mm) + sizes[0] < self.amplitude_mm):
            raise _fail(self.kind, "centre_mm / minor_mm", (self.centre_mm, float(sizes[0])),
                        f"keep |centre_mm| + minor_mm[0] below amplitude_mm "
                        f"({self.amplitude_mm:g})")
        _check_count(self)
        super().__post_init__()

    def path_mm(self) -> np.ndarray:
        a, c = float(self.amplitude_mm), float(self.centre_mm)
        cycle = [c, *_minor(c, self.minor_mm, +1.0), -a,          # descending branch
                 c, *_minor(c, self.minor_mm, -1.0), a]           # ascending branch
        return np.array([a, *cycle * self.cycles, 0.0])


def _check_count(program) -> None:
    if not (isinstance(program.cycles, numbers.Integral) and program.cycles >= 1):
        raise _fail(program.kind, "cycles", program.cycles, "give a whole number >= 1")


def _minor(start: float, sizes: Sequence[float], direction: float) -> list[float]:
    """Positions of nested minor loops that begin at ``start`` and turn ``direction`` first."""
    if not sizes:
        return []
    turn = start + direction * sizes[0]
    return [turn, *_minor(turn, sizes[1:], -direction), start]


@dataclasses.dataclass(frozen=True, kw_only=True)
class SineSweep(_Base):
    """``x = amplitude * envelope(t) * sin(phase(t))``, frequency from ``start_hz`` to ``end_hz``.

    Args:
        amplitude_mm: sine amplitude.
        start_hz: frequency at the start.
        end_hz: frequency at the end (``None``: a fixed-frequency sine at ``start_hz``).
        duration_s: length (a whole number of sample periods).
        spacing: ``"linear"`` or ``"log"`` frequency sweep.
        fade_cycles: the envelope rises as ``sin^2`` over this many periods of the start
            frequency and falls over as many periods of the end frequency, so the motion starts
            and ends at rest (no velocity step, hence no spurious inertia spike).
    """

    kind: ClassVar[str] = "sine_sweep"
    amplitude_mm: float
    start_hz: float
    end_hz: float | None = None
    duration_s: float
    spacing: str = "linear"
    fade_cycles: float = 1.0

    def __post_init__(self):
        self._positive("amplitude_mm", "start_hz", "duration_s")
        self._positive("fade_cycles", allow_zero=True)
        if self.end_hz is not None:
            self._positive("end_hz")
        if self.spacing not in ("linear", "log"):
            raise _fail(self.kind, "spacing", self.spacing, "use 'linear' or 'log'")
        fades = self.fade_cycles / self.start_hz + self.fade_cycles / self.final_hz
        if fades > self.duration_s:
            raise _fail(self.kind, "duration_s", self.duration_s,
                        f"give at least {fades:g} s for the fade in and out, or fewer "
                        "fade_cycles")

    @property
    def final_hz(self) -> float:
        return self.start_hz if self.end_hz is None else self.end_hz

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        rate_hz = _check_rate(rate_hz)
        n = _periods(self.duration_s, rate_hz, at_least=2)
        duration = n / rate_hz
        t = np.arange(n + 1) / rate_hz
        f0, f1 = self.start_hz, self.final_hz
        if f0 == f1:
            phase = 2 * np.pi * f0 * t
        elif self.spacing == "linear":
            phase = 2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * duration))
        else:
            k = math.log(f1 / f0)
            phase = 2 * np.pi * f0 * duration / k * np.expm1(k * t / duration)
        envelope = np.ones_like(t)
        if self.fade_cycles > 0:
            rise = np.clip(t * f0 / self.fade_cycles, 0.0, 1.0)
            fall = np.clip((duration - t) * f1 / self.fade_cycles, 0.0, 1.0)
            envelope = np.sin(np.pi / 2 * rise) ** 2 * np.sin(np.pi / 2 * fall) ** 2
        return t, self.amplitude_mm * MM * envelope * np.sin(phase)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Concat(_Base):
    """``parts`` one after the other; each continues from where the previous one ended.

    Every part's samples are shifted by the previous part's final displacement; the joint is
    one sample (the last of one part is the first of the next).
    """

    kind: ClassVar[str] = "concat"
    parts: Sequence[Program]

    def __post_init__(self):
        flat: list[Program] = []
        for part in self.parts:
            if not isinstance(part, Program):
                raise InputError(None, "concat program part", f"found {part!r}",
                                 "give objects with sample(rate_hz) and describe()")
            flat.extend(part.parts if isinstance(part, Concat) else (part,))
        if not flat:
            raise InputError(None, "concat program", "has no parts", "give at least one program")
        object.__setattr__(self, "parts", tuple(flat))

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        rate_hz = _check_rate(rate_hz)
        return _grid(_join([p.sample(rate_hz)[1] for p in self.parts], shift=True), rate_hz)

    def describe(self) -> dict[str, object]:
        return {"program": self.kind, "parts": [p.describe() for p in self.parts]}


def _legs(points: np.ndarray, speed: float, rate_hz: float) -> np.ndarray:
    """Samples of constant-speed legs through ``points`` (m), joints exactly on samples."""
    pieces = []
    for a, b in zip(points[:-1], points[1:]):
        n = _periods(abs(b - a) / speed, rate_hz, at_least=1)
        pieces.append(a + (b - a) * np.arange(n + 1) / n)
    return _join(pieces, shift=False) if pieces else points[:1].copy()


def _join(pieces: Sequence[np.ndarray], *, shift: bool) -> np.ndarray:
    """Concatenate sampled pieces that share their joint sample.

    ``shift``: each piece starts at 0 and is moved to where the previous one ended;
    otherwise pieces are already in absolute position and the duplicate joint is dropped.
    """
    out = [np.asarray(pieces[0], dtype=float)]
    end = out[0][-1]
    for piece in pieces[1:]:
        piece = np.asarray(piece, dtype=float)[1:]
        out.append(piece + end if shift else piece)
        end = out[-1][-1] if piece.size else end
    return np.concatenate(out)
