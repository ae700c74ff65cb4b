"""The in-memory measurement log: one immutable object in SI units.

A :class:`Log` is what every model consumes. It is made by :func:`fitstiff.io.loading.load_log`
(or by the simulator) and never changes afterwards: its arrays are read-only.

Sign convention (DESIGN §1-2): ``x`` is the length of chamber A measured from the A cap;
``displacement`` is ``x - x0`` (relative to the start); ``force`` is the external force on the
piston, positive toward the B cap. Pressures are stored **absolute** (Pa).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io import validation

__all__ = ["Log", "Rig", "RIG_KEYS", "RigKey", "STANDARD_AMBIENT_PA"]

STANDARD_AMBIENT_PA = 101_325.0


@dataclasses.dataclass(frozen=True)
class RigKey:
    """One rig-metadata key: sidecar name, field on :class:`Rig`, SI scale, CLI flag, and the
    physically plausible range of its value (in ``unit``, the key's own unit).

    The range is checked wherever the value comes from (sidecar, format file, command line,
    a Python mapping), by :func:`fitstiff.io.validation.number`. It is wide - every real cylinder
    fits - and its point is to refuse what no cylinder has (a 1e300 mm bore, a bore given in
    metres) before a computation overflows on it.
    """

    key: str          # sidecar / JSON name, engineering units (e.g. "bore_mm")
    field: str        # Rig field, SI
    scale: float      # SI value = sidecar value * scale
    flag: str         # command-line override
    help: str
    unit: str = ""    # the unit of the sidecar value ("mm", "bar", "kg")
    low: float | None = None     # plausible range in ``unit``
    high: float | None = None
    low_open: bool = False       # ``low`` itself is excluded (a stroke > 0)
    example: float = 1.0         # a typical value, shown in messages

    @property
    def meaning(self) -> str:
        """``the piston bore diameter``: the help as a noun phrase, for messages."""
        return "the " + self.help.split(",")[0].removeprefix("x0: ")


RIG_KEYS: tuple[RigKey, ...] = (
    RigKey("bore_mm", "bore", 1e-3, "--bore-mm", "piston bore diameter",
           "mm", 1.0, 1000.0, example=32.0),
    RigKey("rod_mm", "rod", 1e-3, "--rod-mm", "rod diameter on the B side (0 = rodless)",
           "mm", 0.0, 1000.0, example=0.0),
    RigKey("stroke_mm", "stroke", 1e-3, "--stroke-mm", "stroke length",
           "mm", 0.0, 50_000.0, low_open=True, example=700.0),
    RigKey("dead_length_a_mm", "dead_length_a", 1e-3, "--dead-length-a-mm",
           "dead volume of chamber A divided by its area", "mm", 0.0, 100_000.0, example=0.0),
    RigKey("dead_length_b_mm", "dead_length_b", 1e-3, "--dead-length-b-mm",
           "dead volume of chamber B divided by its area", "mm", 0.0, 100_000.0, example=0.0),
    RigKey("start_position_mm", "start_position", 1e-3, "--start-position-mm",
           "x0: length of chamber A at the start of the log", "mm", 0.0, 50_000.0,
           example=350.0),
    # gauge: the lower limit is vacuum, -ambient_bar, checked with the ambient pressure
    RigKey("supply_bar", "supply_pressure", 1e5, "--supply-bar",
           "gauge pressure at which both chambers were closed", "bar", None, 1000.0,
           example=6.0),
    RigKey("ambient_bar", "ambient_pressure", 1e5, "--ambient-bar",
           "ambient (absolute) pressure, default 1.01325", "bar", 0.01, 10.0,
           example=1.01325),
    RigKey("load_kg", "load_mass", 1.0, "--load-kg", "moving mass carried by the piston",
           "kg", 0.0, 100_000.0, example=2.0),
)
_BY_FIELD = {k.field: k for k in RIG_KEYS}
_BY_KEY = {k.key: k for k in RIG_KEYS}


@dataclasses.dataclass(frozen=True)
class Rig:
    """Rig metadata in SI units; ``None`` where nobody gave the value.

    Use :meth:`require` to get a value a model needs: a missing value is an
    :class:`InputError` naming the sidecar key and the command-line flag that set it.
    """

    bore: float | None = None              # m
    rod: float | None = None               # m (0 = rodless)
    stroke: float | None = None            # m
    dead_length_a: float | None = None     # m
    dead_length_b: float | None = None     # m
    start_position: float | None = None    # m, x0
    supply_pressure: float | None = None   # Pa, gauge
    ambient_pressure: float = STANDARD_AMBIENT_PA  # Pa, absolute
    load_mass: float | None = None         # kg
    source: str | None = None              # where the metadata came from (for messages)

    @classmethod
    def from_mapping(cls, values: Mapping[str, object], *, source: str | None = None) -> Rig:
        """Build from sidecar-style keys (``bore_mm``, ``supply_bar`` ...); unknown keys fail."""
        kwargs: dict[str, object] = {"source": source}
        for key, value in values.items():
            if key not in _BY_KEY:
                known = ", ".join(k.key for k in RIG_KEYS)
                raise InputError(source, f"key '{key}'", "is not a rig metadata key",
                                 f"use one of: {known}")
            if value is None:
                continue
            spec = _BY_KEY[key]
            number = validation.number(value, where=source, what=f"key '{key}' ({spec.flag})",
                                       unit=spec.unit, low=spec.low, high=spec.high,
                                       low_open=spec.low_open, example=spec.example,
                                       meaning=spec.meaning)
            kwargs[spec.field] = number * spec.scale
        rig = cls(**kwargs)  # type: ignore[arg-type]
        rig._check(source)
        return rig

    def merged(self, overrides: Mapping[str, object], *, source: str | None = None) -> Rig:
        """A copy with sidecar-style ``overrides`` (e.g. from the command line) applied."""
        base = self.to_mapping()
        base.update({k: v for k, v in overrides.items() if v is not None})
        return Rig.from_mapping(base, source=source or self.source)

    def to_mapping(self) -> dict[str, float]:
        """Sidecar-style dict (engineering units) of the values that are set."""
        out = {}
        for k in RIG_KEYS:
            value = getattr(self, k.field)
            if value is not None:
                out[k.key] = value / k.scale
        return out

    def require(self, field: str, *, needed_for: str) -> float:
        """The SI value of ``field``; an :class:`InputError` naming key and flag if missing."""
        value = getattr(self, field)
        if value is None:
            key = _BY_FIELD[field]
            raise InputError(self.source, f"rig metadata '{key.key}' ({key.help})",
                             f"is missing but {needed_for} needs it",
                             f"add \"{key.key}\" to the sidecar JSON or pass {key.flag}")
        return float(value)

    @property
    def rodless(self) -> bool:
        return not self.rod

    @property
    def area_a(self) -> float:
        """Piston area on the A side (m^2)."""
        bore = self.require("bore", needed_for="the chamber area")
        return float(np.pi / 4 * bore**2)

    @property
    def area_b(self) -> float:
        """Piston area on the B side (m^2): smaller by the rod area for a rodded cylinder."""
        bore = self.require("bore", needed_for="the chamber area")
        rod = self.rod or 0.0
        return float(np.pi / 4 * (bore**2 - rod**2))

    def missing(self) -> list[str]:
        """Sidecar keys with no value."""
        return [k.key for k in RIG_KEYS if getattr(self, k.field) is None]

    def _check(self, source: str | None) -> None:
        def bad(field, found, fix):
            key = _BY_FIELD[field]
            raise InputError(source, f"rig metadata '{key.key}'", found, fix)

        for field in ("bore", "stroke"):
            v = getattr(self, field)
            if v is not None and v <= 0:
                bad(field, f"found {v / _BY_FIELD[field].scale:g}", "give a positive value")
        for field in ("rod", "dead_length_a", "dead_length_b", "load_mass"):
            v = getattr(self, field)
            if v is not None and v < 0:
                bad(field, f"found {v / _BY_FIELD[field].scale:g}", "give a value >= 0")
        if self.rod and self.bore and self.rod >= self.bore:
            bad("rod", f"found rod {self.rod * 1e3:g} mm >= bore {self.bore * 1e3:g} mm",
                "the rod must be thinner than the bore (0 = rodless)")
        if self.ambient_pressure <= 0:
            bad("ambient_pressure", f"found {self.ambient_pressure / 1e5:g}",
                "give the absolute ambient pressure in bar (about 1.013)")
        if self.supply_pressure is not None and self.supply_pressure + self.ambient_pressure < 0:
            bad("supply_pressure", f"found {self.supply_pressure / 1e5:g} bar gauge (below vacuum)",
                "give the gauge pressure (absolute minus ambient)")
        if (self.start_position is not None and self.stroke is not None
                and not 0 <= self.start_position <= self.stroke):
            bad("start_position", f"found {self.start_position * 1e3:g} mm outside the "
                f"stroke 0..{self.stroke * 1e3:g} mm", "give x0 within the stroke")


def _frozen(a: np.ndarray | None) -> np.ndarray | None:
    """A read-only float64 copy of ``a``; an array that is one already (read-only, float64,
    owning its data: what the loader hands over) is taken as it is, not copied (a long log's
    channels are hundreds of MB)."""
    if a is None:
        return None
    if (isinstance(a, np.ndarray) and a.dtype == np.float64 and not a.flags.writeable
            and a.flags.owndata and a.flags.c_contiguous):
        return a
    a = np.array(a, dtype=np.float64, copy=True)
    a.flags.writeable = False
    return a


@dataclasses.dataclass(frozen=True, eq=False)
class Log:
    """One measurement (or simulated) log in SI units. Immutable; arrays are read-only.

    Attributes:
        name: short name (file stem).
        displacement: m, relative to the start, positive toward the B cap.
        force: N, external force on the piston, positive toward the B cap.
        time: s, strictly increasing, or ``None`` (quasi-static log).
        pressure_a, pressure_b: Pa **absolute**, or ``None`` where not logged.
        vented: chambers known to be open to ambient (``{"a"}``, ``{"b"}``...).
        rig: rig metadata.
        path: the file it came from (``None`` when made in memory).
        notes: things the loader assumed and the user should know.
        source: how it was read (columns, units, sha256 ...), for manifests.
    """

    name: str
    displacement: np.ndarray
    force: np.ndarray
    time: np.ndarray | None = None
    pressure_a: np.ndarray | None = None
    pressure_b: np.ndarray | None = None
    rig: Rig = dataclasses.field(default_factory=Rig)
    vented: frozenset[str] = frozenset()
    path: Path | None = None
    notes: tuple[str, ...] = ()
    source: Mapping[str, object] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        set_ = object.__setattr__
        for f in ("displacement", "force", "time", "pressure_a", "pressure_b"):
            set_(self, f, _frozen(getattr(self, f)))
        set_(self, "vented", frozenset(self.vented))
        set_(self, "notes", tuple(self.notes))
        set_(self, "source", MappingProxyType(dict(self.source)))
        n = self.displacement.shape[0]
        for f in ("force", "time", "pressure_a", "pressure_b"):
            a = getattr(self, f)
            if a is not None and a.shape != (n,):
                raise ValueError(f"Log {self.name!r}: {f} has shape {a.shape}, expected ({n},)")

    def __len__(self) -> int:
        return int(self.displacement.shape[0])

    @property
    def has_time(self) -> bool:
        return self.time is not None

    @property
    def duration(self) -> float | None:
        return None if self.time is None else float(self.time[-1] - self.time[0])

    def position(self) -> np.ndarray:
        """Absolute piston position ``x = x0 + displacement`` (needs ``start_position``)."""
        x0 = self.rig.require("start_position", needed_for="the absolute piston position")
        return x0 + self.displacement

    def gauge(self, chamber: str) -> np.ndarray | None:
        """Gauge pressure (Pa) of chamber ``'a'`` or ``'b'``: logged, or 0 if vented, else None."""
        p = self.pressure_a if chamber == "a" else self.pressure_b
        if p is not None:
            return p - self.rig.ambient_pressure
        if chamber in self.vented:
            return np.zeros(len(self))
        return None

    def replace(self, **changes) -> Log:
        """A new log with some fields changed (the original is untouched)."""
        return dataclasses.replace(self, **changes)

    def slice(self, start: int | None = None, stop: int | None = None) -> Log:
        """Samples ``start:stop`` as a new log (displacement stays relative to the log start)."""
        sl = slice(start, stop)
        pick = lambda a: None if a is None else a[sl]  # noqa: E731
        return self.replace(displacement=self.displacement[sl], force=self.force[sl],
                            time=pick(self.time), pressure_a=pick(self.pressure_a),
                            pressure_b=pick(self.pressure_b))
