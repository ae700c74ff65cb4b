"""Derived quantities engineers quote (DESIGN §1.2), from any composed model.

=============================== ==============================================================
``presliding_slope_N_per_mm``   slope of the friction force right after a reversal: sum over
                                friction bases (``sigma0`` for Dahl / LuGre, ``sum k_i`` for
                                Maxwell-slip). For Dahl / LuGre this is the tangent at zero
                                friction force; right after a reversal *from saturation* their
                                tangent is ``sigma0 (1 + |F|/Fc)``, about ``2 sigma0``, while
                                Maxwell-slip's is ``sum k_i`` from any state
``breakaway_N``                 largest friction force before gross sliding: sum over bases
                                (``Fc`` Dahl, ``Fs`` LuGre, ``sum W_i`` Maxwell-slip) times the
                                modifiers' reference level (e.g. the Stribeck ratio at low speed)
``presliding_range_mm``         travel after a reversal until the friction force has made 95 %
                                of its swing (simulated quasi-statically from saturation)
``chamber_stiffness_N_per_mm``  linearised stiffness of the closed chambers at the log's start
                                (measured or vented chambers add none: their pressure is held)
``total_stiffness_N_per_mm``    the sum of the two
=============================== ==============================================================

All are JAX expressions of the model's fields, so standard errors can be propagated by
autodiff. Their display units are fixed by their names' suffixes (one table here:
:func:`split_unit`, :func:`to_display`).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from fitstiff._jax import jnp
from fitstiff.physics.drive import make_drive
from fitstiff.physics.terms.base import FrictionBase, Modifier, Modulation

__all__ = ["DERIVED", "derived_quantities", "presliding_curve", "split_unit", "to_display"]

DERIVED = ("presliding_slope_N_per_mm", "breakaway_N", "presliding_range_mm",
           "chamber_stiffness_N_per_mm", "total_stiffness_N_per_mm")

#: name suffix -> (display unit, display per SI: ``display = SI * factor``)
_UNIT_SUFFIXES = (("_N_per_mm", "N/mm", 1e-3), ("_mm", "mm", 1e3), ("_N", "N", 1.0))
_SWING = 0.95
_SAMPLES = 4001
_QUASI_STATIC_SPEED = 1e-6  # m/s


class _Level(Modifier):
    """A constant friction level factor (the modifiers' reference condition)."""

    name = "reference_level"
    targets = FrictionBase
    level: float = 1.0

    def modulate(self, state, s, drive):
        return state, Modulation(level=self.level)


def split_unit(name: str) -> tuple[str, str]:
    """A derived quantity's label and display unit from its name's unit suffix:
    ``"breakaway_N"`` -> ``("breakaway", "N")``; ``("name", "")`` without a known suffix."""
    for suffix, unit, _ in _UNIT_SUFFIXES:
        if name.endswith(suffix):
            return name[: -len(suffix)], unit
    return name, ""


def to_display(name: str, si):
    """The SI value(s) of the derived quantity ``name`` in its display unit (the unit its
    name ends in: ``_N_per_mm``, ``_mm``, ``_N``); ``KeyError`` for a name without one."""
    for suffix, _, factor in _UNIT_SUFFIXES:
        if name.endswith(suffix):
            return si * factor
    raise KeyError(name)


def _reference(model):
    from fitstiff.physics.model import Model

    bases = model.terms_of(FrictionBase)
    level = jnp.asarray(1.0)
    for m in model.terms_of(Modifier):
        if m.targets is FrictionBase:
            level = level * m.reference_level()
    sub = Model(tuple(bases) + (_Level(level=level),)) if bases else None
    return bases, level, sub


def presliding_curve(model, *, travel=None):
    """Friction force after a reversal from negative saturation, quasi-static.

    Returns ``(travel_m, force_N)`` over the positive-going branch (``travel`` from the
    reversal). The default span saturates every base (20 x breakaway / slope, at least twice
    the largest Maxwell-slip slip displacement).
    """
    bases, level, sub = _reference(model)
    slope = sum(b.presliding_slope() for b in bases)
    breakaway = sum(b.breakaway() for b in bases) * level
    if travel is None:
        travel = 20.0 * breakaway / jnp.where(jnp.isfinite(slope), slope, 1e9)
        for b in bases:
            if hasattr(b, "delta"):
                travel = jnp.maximum(travel, 2.0 * jnp.max(b.delta) * level)
    # the curve's shape (down, then up) gives the drive its runs: the travel scales it
    u = np.linspace(0.0, 1.0, _SAMPLES)
    shape = np.concatenate([-u, -1.0 + 2.0 * u[1:]])
    x = jnp.asarray(shape) * travel
    time = jnp.concatenate([jnp.zeros(1), jnp.cumsum(jnp.abs(jnp.diff(x)))]) / _QUASI_STATIC_SPEED
    template = make_drive(displacement=shape, time=np.arange(shape.size, dtype=float))
    drive = eqx.tree_at(lambda d: d.time, template.moved(x), time)
    force = sub.run(drive).force
    branch = slice(_SAMPLES - 1, None)
    return x[branch] - x[_SAMPLES - 1], force[branch]


def _presliding_range(model):
    travel, force = presliding_curve(model)
    target = force[0] + _SWING * (force[-1] - force[0])
    above = force >= target
    i = jnp.argmax(above)            # first sample at or past the target
    i = jnp.clip(i, 1, force.shape[0] - 1)
    f0, f1 = force[i - 1], force[i]
    frac = jnp.clip((target - f0) / jnp.where(f1 == f0, 1.0, f1 - f0), 0.0, 1.0)
    return travel[i - 1] + frac * (travel[i] - travel[i - 1])


def derived_quantities(model, drive=None) -> dict[str, jnp.ndarray]:
    """The DESIGN §1.2 quantities of ``model`` (engineering units; NaN where undefined).

    ``drive`` gives the operating point of the chamber stiffness; without it (or without a
    chamber) that entry is NaN (no chamber: 0).
    """
    bases, level, _ = _reference(model)
    nan = jnp.asarray(jnp.nan)
    if bases:
        slope = sum(b.presliding_slope() for b in bases)
        breakaway = sum(b.breakaway() for b in bases) * level
        prange = _presliding_range(model)
    else:
        slope = breakaway = prange = nan
    if model.has("chamber"):
        k_ch = model.term("chamber").stiffness(drive) if drive is not None else nan
    else:
        k_ch = jnp.asarray(0.0)
    si = {"presliding_slope_N_per_mm": slope, "breakaway_N": breakaway,
          "presliding_range_mm": prange, "chamber_stiffness_N_per_mm": k_ch}
    out = {name: to_display(name, jnp.asarray(value)) for name, value in si.items()}
    out["total_stiffness_N_per_mm"] = (out["presliding_slope_N_per_mm"]
                                       + out["chamber_stiffness_N_per_mm"])
    return out
