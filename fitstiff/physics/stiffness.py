"""Chamber gas-spring calculator: stiffness and restoring force from geometry (DESIGN §1.1).

The library behind ``fitstiff stiffness``. For a cylinder described by a
:class:`~fitstiff.io.log.Rig` (bore, rod, stroke, dead lengths, supply and ambient pressure) whose
chambers were closed at position ``x0``, :func:`chamber_stiffness` gives

- the linearised stiffness ``k = n (p_A0 A_A / l_A0 + p_B0 A_B / l_B0)`` (the paper's eq. 15
  generalised to unequal pressures, areas and dead lengths);
- the restoring force of a displacement ``u`` by the linearised law (``k u``) and by the exact
  polytropic law (``F(u) - F(0)``), and their relative gap;
- the relative return pressure (eq. 14) and the chamber pressures before and after ``u``.

:func:`stiffness_table` does the same over the stroke. The physics lives in
:mod:`fitstiff.physics.gas_spring`; this module adds the input checks (every problem is an
:class:`~fitstiff.errors.InputError` naming the command-line flag) and the result record.

Units: SI inside (m, Pa, N). Pressures are given as **gauge** (as users and logs speak) and
used **absolute** (gauge + ambient) in every law. ``u`` is positive toward the B cap
(chamber A grows, chamber B is compressed); forces are positive toward the B cap.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.log import Rig
from fitstiff.physics import gas_spring
from fitstiff.units import BAR, MM

__all__ = [
    "ADIABATIC_AIR",
    "BAR",
    "JSON_KEYS",
    "MM",
    "POLYTROPIC_RANGE",
    "StiffnessResult",
    "chamber_stiffness",
    "stiffness_table",
    "table_positions",
]


ADIABATIC_AIR = 1.4
"""Polytropic exponent of air under fast (adiabatic) compression; the paper's value."""

POLYTROPIC_RANGE = (1.0, 1.67)
"""Accepted polytropic exponents: isothermal (1) up to a monatomic gas's adiabatic (5/3)."""

JSON_KEYS: Mapping[str, str] = MappingProxyType({
    "bore_mm": "piston bore diameter",
    "rod_mm": "rod diameter on the B side (0 = rodless)",
    "stroke_mm": "stroke length L",
    "dead_length_a_mm": "dead volume of chamber A divided by its area",
    "dead_length_b_mm": "dead volume of chamber B divided by its area",
    "position_mm": "x0: length of chamber A when the valves closed",
    "displacement_mm": "u: displacement from x0, + toward the B cap",
    "n": "polytropic exponent",
    "ambient_bar": "ambient pressure, absolute",
    "pressure_a_bar": "closing pressure of chamber A, gauge",
    "pressure_b_bar": "closing pressure of chamber B, gauge",
    "area_a_mm2": "piston area on the A side",
    "area_b_mm2": "piston area on the B side (smaller by the rod area when rodded)",
    "effective_length_a_mm": "l_A0 = x0 + dead_length_a",
    "effective_length_b_mm": "l_B0 = L - x0 + dead_length_b",
    "stiffness_N_per_mm": "linearised chamber stiffness dF/du at x0",
    "preload_N": "force that holds the piston at x0 (non-zero for unequal pressures or areas)",
    "force_linear_N": "restoring force of u, linearised law: stiffness * u",
    "force_exact_N": "restoring force of u, exact polytropic law: F(u) - F(0)",
    "relative_gap": "force_exact_N / force_linear_N - 1 (> 0: the exact law is stiffer)",
    "relative_return_pressure": "eq. 14 (linearised, a fraction): n u (1/l_A0 + 1/l_B0), the "
                                "sum of both chambers' relative pressure changes; for equal "
                                "closing pressures the pressure difference it builds across the "
                                "piston relative to the closing pressure",
    "pressure_a_displaced_bar_abs": "chamber A pressure after u (exact law), absolute",
    "pressure_b_displaced_bar_abs": "chamber B pressure after u (exact law), absolute",
})
"""Keys of :meth:`StiffnessResult.to_dict` (``fitstiff stiffness --json``) and their meaning."""


@dataclasses.dataclass(frozen=True)
class StiffnessResult:
    """Chamber stiffness and restoring force at one closing position (SI units).

    Attributes:
        rig: the geometry used (rod and dead lengths filled in with 0 where unset,
            ``start_position`` set to ``position``).
        position: ``x0``, m.
        displacement: ``u``, m, + toward the B cap.
        n: polytropic exponent.
        pressure_a0, pressure_b0: closing pressures, Pa **absolute**.
        length_a0, length_b0: effective chamber lengths at ``x0`` (dead volume included), m.
        stiffness: linearised stiffness at ``x0``, N/m.
        preload: force that holds the piston at ``x0``, N.
        force_linear: restoring force of ``u`` by the linearised law, N.
        force_exact: restoring force of ``u`` by the exact polytropic law, N.
        pressure_a, pressure_b: chamber pressures after ``u`` (exact law), Pa absolute.
        relative_return_pressure: eq. 14 generalised, ``n u (1/l_A0 + 1/l_B0)`` (a fraction).
    """

    rig: Rig
    position: float
    displacement: float
    n: float
    pressure_a0: float
    pressure_b0: float
    length_a0: float
    length_b0: float
    stiffness: float
    preload: float
    force_linear: float
    force_exact: float
    pressure_a: float
    pressure_b: float
    relative_return_pressure: float

    @property
    def relative_gap(self) -> float:
        """``force_exact / force_linear - 1``: how far the linearisation is off at ``u``."""
        return self.force_exact / self.force_linear - 1.0

    def to_dict(self) -> dict[str, float]:
        """Engineering units, keys as documented in :data:`JSON_KEYS`."""
        rig = self.rig
        ambient = rig.ambient_pressure
        return {
            "bore_mm": rig.bore / MM,
            "rod_mm": rig.rod / MM,
            "stroke_mm": rig.stroke / MM,
            "dead_length_a_mm": rig.dead_length_a / MM,
            "dead_length_b_mm": rig.dead_length_b / MM,
            "position_mm": self.position / MM,
            "displacement_mm": self.displacement / MM,
            "n": self.n,
            "ambient_bar": ambient / BAR,
            "pressure_a_bar": (self.pressure_a0 - ambient) / BAR,
            "pressure_b_bar": (self.pressure_b0 - ambient) / BAR,
            "area_a_mm2": rig.area_a / MM**2,
            "area_b_mm2": rig.area_b / MM**2,
            "effective_length_a_mm": self.length_a0 / MM,
            "effective_length_b_mm": self.length_b0 / MM,
            "stiffness_N_per_mm": self.stiffness * MM,
            "preload_N": self.preload,
            "force_linear_N": self.force_linear,
            "force_exact_N": self.force_exact,
            "relative_gap": self.relative_gap,
            "relative_return_pressure": self.relative_return_pressure,
            "pressure_a_displaced_bar_abs": self.pressure_a / BAR,
            "pressure_b_displaced_bar_abs": self.pressure_b / BAR,
        }


def chamber_stiffness(rig: Rig, *, position: float | None = None, displacement: float,
                      n: float = ADIABATIC_AIR, pressure_a_gauge: float | None = None,
                      pressure_b_gauge: float | None = None) -> StiffnessResult:
    """Chamber stiffness and restoring force of the closed cylinder at one position.

    Args:
        rig: geometry and pressures: ``bore`` and ``stroke`` are needed; ``rod`` and the dead
            lengths default to 0; ``supply_pressure`` (gauge) is needed unless both chamber
            pressures are given; ``ambient_pressure`` is absolute.
        position: ``x0``, the length of chamber A when the valves closed (m); defaults to
            ``rig.start_position``.
        displacement: ``u`` (m, non-zero, + toward the B cap) at which the restoring force
            is evaluated; the piston must stay within the stroke.
        n: polytropic exponent, within :data:`POLYTROPIC_RANGE`.
        pressure_a_gauge, pressure_b_gauge: closing pressures of chambers A and B (Pa gauge);
            each defaults to ``rig.supply_pressure``.

    Raises:
        InputError: a missing or impossible input, naming the ``fitstiff stiffness`` flag.
    """
    setup = _Setup.checked(rig, pressure_a_gauge=pressure_a_gauge,
                           pressure_b_gauge=pressure_b_gauge, n=n, displacement=displacement)
    if position is None:
        if rig.start_position is None:
            raise InputError(rig.source, "closing position (--position-mm)", "is missing",
                             "give the length of chamber A when the valves closed")
        position = rig.start_position
    return setup.evaluate(position)


def stiffness_table(rig: Rig, *, count: int, displacement: float, n: float = ADIABATIC_AIR,
                    pressure_a_gauge: float | None = None,
                    pressure_b_gauge: float | None = None) -> tuple[StiffnessResult, ...]:
    """:func:`chamber_stiffness` at ``count`` positions over the stroke (:func:`table_positions`).

    The other arguments are those of :func:`chamber_stiffness`.
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise InputError(rig.source, "number of table positions (--table)", f"found {count!r}",
                         "give a whole number >= 1")
    setup = _Setup.checked(rig, pressure_a_gauge=pressure_a_gauge,
                           pressure_b_gauge=pressure_b_gauge, n=n, displacement=displacement)
    return tuple(setup.evaluate(float(x)) for x in table_positions(setup.rig.stroke, count))


def table_positions(stroke: float, count: int) -> np.ndarray:
    """The centres of ``count`` equal slices of the stroke: ``L (i + 1/2) / count``.

    They avoid the caps, where a chamber without dead volume is empty and the stiffness
    infinite; an odd ``count`` includes mid-stroke.
    """
    return stroke * (np.arange(count) + 0.5) / count


@dataclasses.dataclass(frozen=True)
class _Setup:
    """Checked inputs shared by every position: complete rig, absolute pressures, n, u."""

    rig: Rig
    pressure_a0: float
    pressure_b0: float
    n: float
    displacement: float

    @classmethod
    def checked(cls, rig: Rig, *, pressure_a_gauge: float | None,
                pressure_b_gauge: float | None, n: float, displacement: float) -> _Setup:
        where = rig.source
        bore = _finite(rig.require("bore", needed_for="the chamber stiffness"),
                       where, "bore (--bore-mm)", MM, "mm")
        stroke = _finite(rig.require("stroke", needed_for="the chamber stiffness"),
                         where, "stroke (--stroke-mm)", MM, "mm")
        rod = _finite(rig.rod or 0.0, where, "rod diameter (--rod-mm)", MM, "mm")
        dead_a = _finite(rig.dead_length_a or 0.0, where,
                         "dead length of chamber A (--dead-length-a-mm)", MM, "mm")
        dead_b = _finite(rig.dead_length_b or 0.0, where,
                         "dead length of chamber B (--dead-length-b-mm)", MM, "mm")
        ambient = _finite(rig.ambient_pressure, where, "ambient pressure (--ambient-bar)",
                          BAR, "bar")
        n = _finite(n, where, "polytropic exponent (--n)", 1.0, "")
        displacement = _finite(displacement, where, "displacement (--displacement-mm)",
                               MM, "mm")
        if bore <= 0:
            raise InputError(where, "bore (--bore-mm)", f"found {bore / MM:g} mm",
                             "give a positive piston diameter")
        if stroke <= 0:
            raise InputError(where, "stroke (--stroke-mm)", f"found {stroke / MM:g} mm",
                             "give a positive stroke length")
        if not 0 <= rod < bore:
            raise InputError(where, "rod diameter (--rod-mm)",
                             f"found {rod / MM:g} mm with a {bore / MM:g} mm bore",
                             "give 0 for a rodless cylinder or a rod thinner than the bore")
        for dead, chamber in ((dead_a, "a"), (dead_b, "b")):
            if dead < 0:
                raise InputError(where, f"dead length of chamber {chamber.upper()} "
                                 f"(--dead-length-{chamber}-mm)", f"found {dead / MM:g} mm",
                                 "give a length >= 0 (dead volume divided by the piston area)")
        if ambient <= 0:
            raise InputError(where, "ambient pressure (--ambient-bar)",
                             f"found {ambient / BAR:g} bar",
                             "give the absolute ambient pressure (about 1.013 bar)")
        lo, hi = POLYTROPIC_RANGE
        if not lo <= n <= hi:
            raise InputError(where, "polytropic exponent (--n)", f"found {n:g}",
                             f"give a value from {lo:g} (isothermal) to {hi:g} "
                             f"(adiabatic; {ADIABATIC_AIR:g} for air)")
        if displacement == 0:
            raise InputError(where, "displacement (--displacement-mm)", "found 0",
                             "give a non-zero displacement to evaluate the restoring force at")
        p_a0 = _absolute(pressure_a_gauge, rig, ambient, "a")
        p_b0 = _absolute(pressure_b_gauge, rig, ambient, "b")
        full = dataclasses.replace(rig, bore=bore, rod=rod, stroke=stroke, dead_length_a=dead_a,
                                   dead_length_b=dead_b, ambient_pressure=ambient)
        return cls(rig=full, pressure_a0=p_a0, pressure_b0=p_b0, n=n, displacement=displacement)

    def evaluate(self, position: float) -> StiffnessResult:
        """Check ``position`` (and ``position + u``) against the stroke, then compute."""
        rig, u, where = self.rig, self.displacement, self.rig.source
        position = _finite(position, where, "closing position (--position-mm)", MM, "mm")
        stroke_mm = f"the stroke 0..{rig.stroke / MM:g} mm"
        if not 0 <= position <= rig.stroke:
            raise InputError(where, "closing position (--position-mm)",
                             f"found {position / MM:g} mm, outside {stroke_mm}",
                             "give the length of chamber A within the stroke")
        l_a0, l_b0 = gas_spring.effective_lengths(position, stroke=rig.stroke,
                                                  dead_length_a=rig.dead_length_a,
                                                  dead_length_b=rig.dead_length_b)
        for length, chamber in ((l_a0, "A"), (l_b0, "B")):
            if length <= 0:
                raise InputError(where, "closing position (--position-mm)",
                                 f"{position / MM:g} mm leaves chamber {chamber} with no volume "
                                 f"(dead length 0)", f"give a position inside {stroke_mm} or "
                                 f"the dead length of chamber {chamber}")
        end = position + u
        if not 0 <= end <= rig.stroke or l_a0 + u <= 0 or l_b0 - u <= 0:
            raise InputError(where, "displacement (--displacement-mm)",
                             f"{u / MM:g} mm from {position / MM:g} mm moves the piston to "
                             f"{end / MM:g} mm, onto a cap or outside {stroke_mm}",
                             "give a smaller displacement")
        law = dict(p_a0=self.pressure_a0, p_b0=self.pressure_b0, l_a0=l_a0, l_b0=l_b0,
                   n=self.n)
        areas = dict(area_a=rig.area_a, area_b=rig.area_b)
        ambient = rig.ambient_pressure
        stiffness = gas_spring.linear_stiffness(**law, **areas)
        preload = gas_spring.chamber_force(0.0, **law, **areas, p_amb=ambient)
        force_exact = gas_spring.chamber_force(u, **law, **areas, p_amb=ambient) - preload
        p_a, p_b = gas_spring.chamber_pressures(u, **law)
        return StiffnessResult(
            rig=dataclasses.replace(rig, start_position=position), position=position,
            displacement=u, n=self.n, pressure_a0=self.pressure_a0,
            pressure_b0=self.pressure_b0, length_a0=l_a0, length_b0=l_b0,
            stiffness=stiffness, preload=preload, force_linear=stiffness * u,
            force_exact=force_exact, pressure_a=p_a, pressure_b=p_b,
            relative_return_pressure=gas_spring.relative_return_pressure(
                u, x=position, stroke=rig.stroke, n=self.n, dead_length_a=rig.dead_length_a,
                dead_length_b=rig.dead_length_b),
        )


def _finite(value: float, where: str | None, what: str, per: float, unit: str) -> float:
    """``value`` as a float; an InputError (shown as ``value / per`` ``unit``) if not finite."""
    value = float(value)
    if not math.isfinite(value):
        raise InputError(where, what, f"found {value / per:g} {unit}".rstrip(),
                         "give a finite number")
    return value


def _absolute(gauge: float | None, rig: Rig, ambient: float, chamber: str) -> float:
    """Absolute closing pressure of ``chamber`` from its gauge value or the supply pressure."""
    flag = f"--pressure-{chamber}-bar"
    if gauge is None:
        if rig.supply_pressure is None:
            raise InputError(rig.source, f"closing pressure of chamber {chamber.upper()} "
                             f"(--supply-bar or {flag})", "is missing",
                             "give --supply-bar (gauge), or both --pressure-a-bar and "
                             "--pressure-b-bar")
        gauge, flag = rig.supply_pressure, "--supply-bar"
    what = f"closing pressure of chamber {chamber.upper()} ({flag})"
    gauge = _finite(gauge, rig.source, what, BAR, "bar")
    if gauge + ambient <= 0:
        raise InputError(rig.source, what,
                         f"found {gauge / BAR:g} bar gauge, at or below vacuum "
                         f"(ambient {ambient / BAR:g} bar)",
                         f"give a gauge pressure above {-ambient / BAR:g} bar")
    return gauge + ambient
