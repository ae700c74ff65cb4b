"""The model's view of one log: a :class:`Drive` (JAX pytree) of input arrays and rig scalars.

A drive holds what the terms need from the data (time, measured displacement, measured
pressures, standstill flags), the rig constants of that log (areas, effective chamber lengths,
closing pressures) and the log's nuisance values (initial friction state, force offset). The
measured force is *not* in the drive: the model predicts it.

Each chamber has a static mode decided from the log:

``closed``    closed at the start with the supply pressure (the rig gives ``supply_bar``):
              modelled with the polytropic law. If its pressure is also logged, the log is an
              *observation* the fit compares with the modelled pressure (``observed``), which
              is what identifies ``n``.
``measured``  its pressure is logged and the rig does not say it was closed (no
              ``supply_bar``, e.g. a regulated supply): the chamber force uses the logged
              pressure as an input;
``vented``    open to ambient (declared, or the unlogged side of a one-pressure log).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import equinox as eqx

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.io.log import Log, Rig
from fitstiff.signal.monotone import Runs, find_runs

__all__ = ["Drive", "make_drive", "drive_from_log", "chamber_log_ratios", "log_volume_span",
           "CHAMBER_MODES", "log_volume_ratios"]

CHAMBER_MODES = ("measured", "vented", "closed")


class Drive(eqx.Module):
    """Inputs of one log for the model (SI, absolute pressures)."""

    time: jnp.ndarray            # (n,) s; sample index when the log has no time
    displacement: jnp.ndarray    # (n,) m, measured, relative to the start
    pressure_a: jnp.ndarray      # (n,) Pa abs, 0 where not measured
    pressure_b: jnp.ndarray
    still: jnp.ndarray           # (n,) 1.0 while standing still
    area_a: jnp.ndarray          # m^2 (nan where the model does not need it)
    area_b: jnp.ndarray
    l_a0: jnp.ndarray            # m, effective chamber lengths at the start
    l_b0: jnp.ndarray
    p_a0: jnp.ndarray            # Pa abs, chamber pressures at the start
    p_b0: jnp.ndarray
    p_amb: jnp.ndarray           # Pa abs
    friction_state0: jnp.ndarray  # initial friction state, fraction of saturation in (-1, 1)
    force_offset: jnp.ndarray    # N, added to the predicted force
    #: smoothed velocity (m/s) for rate-dependent terms; None: the difference quotient
    velocity: jnp.ndarray | None = None
    #: smoothed acceleration (m/s^2) for the inertia term; None: the velocity's difference
    acceleration: jnp.ndarray | None = None
    #: the measured force (N) where a term takes it as an input (``rig_compliance:measured``)
    measured_force: jnp.ndarray | None = None
    #: the monotone runs of ``displacement`` (:mod:`fitstiff.signal.monotone`): friction terms
    #: with a closed form over a run step run by run; None: sample by sample. Whoever replaces the
    #: displacement finds them again (:meth:`with_displacement`)
    runs: Runs | None = None
    #: a bound (a power of two) on ``|log(V(x[0]) / V(x))|`` of a closed chamber over the
    #: samples of ``displacement`` (:func:`log_volume_span`): the chamber evaluates its
    #: polytropic powers over all samples as a short series when it is small. None: unknown
    #: (``exp``). Whoever replaces the displacement finds it again (:meth:`with_displacement`)
    log_volume_span: float | None = eqx.field(static=True, default=None)
    #: ``log(V(x[0]) / V(x))`` of chambers A and B over the samples of ``displacement``
    #: (:func:`log_volume_ratios`), given with :attr:`log_volume_span`: the chamber's closed
    #: form reads them instead of taking two logs per sample and call. Whoever replaces the
    #: displacement drops or finds them again (:meth:`moved`, :meth:`with_displacement`)
    log_volume_ratios: tuple[jnp.ndarray, jnp.ndarray] | None = None
    modes: tuple[str, str] = eqx.field(static=True, default=("closed", "closed"))
    #: per chamber: the logged pressure is an observation of a closed (modelled) chamber
    observed: tuple[bool, bool] = eqx.field(static=True, default=(False, False))
    has_time: bool = eqx.field(static=True, default=True)
    name: str = eqx.field(static=True, default="")

    def __len__(self) -> int:
        return int(self.displacement.shape[0])

    def with_displacement(self, x) -> Drive:
        """This drive moved by the displacement ``x`` (NumPy, ``(n,)``), with the runs, the
        chamber span and the log volume ratios of ``x``."""
        x = np.asarray(x, dtype=float)
        span = log_volume_span(x, float(self.l_a0), float(self.l_b0), self.modes)
        return dataclasses.replace(
            self, displacement=jnp.asarray(x), runs=find_runs(x), log_volume_span=span,
            log_volume_ratios=log_volume_ratios(x, float(self.l_a0), float(self.l_b0), span))

    def moved(self, x) -> Drive:
        """This drive with the displacement ``x`` (traced: a small change of it, such as the
        turning points' errors), its log volume ratios dropped (the chamber takes them from
        ``x``); the runs and the span stay, and their closed forms give NaN where ``x``
        leaves them."""
        return dataclasses.replace(self, displacement=x, log_volume_ratios=None)

    def window(self, start: int, stop: int | None = None) -> Drive:
        """The samples ``[start, stop)`` of this drive (the rig values and nuisances kept),
        without the runs and the log volume ratios, which are the whole displacement's."""
        def cut(a):
            return None if a is None else a[start:stop]

        return dataclasses.replace(
            self, time=cut(self.time), displacement=cut(self.displacement),
            pressure_a=cut(self.pressure_a), pressure_b=cut(self.pressure_b),
            still=cut(self.still), velocity=cut(self.velocity),
            acceleration=cut(self.acceleration), measured_force=cut(self.measured_force),
            runs=None, log_volume_span=None, log_volume_ratios=None)

    @property
    def seal_pressure(self):
        """Per-sample mean gauge pressure of the two chambers (Pa): the seal's normal load.

        Measured chambers use the log, closed ones their closing pressure, vented ones 0.
        """
        def gauge(mode, measured, p0):
            if mode == "measured":
                return measured - self.p_amb
            if mode == "closed":
                return jnp.broadcast_to(p0 - self.p_amb, measured.shape)
            return jnp.zeros_like(measured)

        return 0.5 * (gauge(self.modes[0], self.pressure_a, self.p_a0)
                      + gauge(self.modes[1], self.pressure_b, self.p_b0))


def make_drive(*, displacement, time=None, rig: Rig | None = None, pressure_a=None,
               pressure_b=None, vented=(), still=None, name: str = "",
               needs_chamber: bool = False, needs_supply: bool = True,
               friction_state0: float = 0.0, force_offset: float = 0.0,
               what: str = "the chamber term", host: bool = False) -> Drive:
    """Build a drive from arrays (SI; pressures absolute).

    ``needs_chamber``: require the rig values the chamber force needs (bore; and stroke,
    start position and supply pressure for a closed chamber); a missing one is an
    :class:`~fitstiff.errors.InputError` naming the sidecar key and the flag.
    ``needs_supply=False``: the closing pressure will be fitted, so a missing
    ``supply_bar`` is no error and logged pressures are observations of closed chambers
    (closed chambers start at ambient until the fit sets the closing pressure).
    ``host=True``: the per-sample arrays stay NumPy arrays (views of the inputs where they
    are float64 already: no copy), without the runs and the log volume ratios, for a long
    log run in windows (:meth:`Drive.window`, :mod:`fitstiff.inference.chunks`).
    """
    rig = rig or Rig()
    x = np.asarray(displacement, dtype=float)
    n = x.shape[0]
    has_time = time is not None
    t = np.asarray(time, dtype=float) if has_time else np.arange(n, dtype=float)
    closed_by_rig = rig.supply_pressure is not None or not needs_supply
    modes, observed = [], []
    for chamber, p in (("a", pressure_a), ("b", pressure_b)):
        if chamber in vented:
            modes.append("vented")
        elif p is not None and not closed_by_rig:
            modes.append("measured")
        else:
            modes.append("closed")
        observed.append(p is not None and modes[-1] == "closed")
    nan = float("nan")
    area_a = area_b = l_a0 = l_b0 = nan
    p_amb = rig.ambient_pressure
    supply = rig.supply_pressure
    if needs_chamber:
        area_a, area_b = rig.area_a, rig.area_b
        if "closed" in modes:
            stroke = rig.require("stroke", needed_for=f"{what} (closed chamber)")
            x0 = rig.require("start_position", needed_for=f"{what} (closed chamber)")
            if needs_supply:
                supply = rig.require("supply_pressure",
                                     needed_for=f"{what} (closed chamber)")
            l_a0 = x0 + (rig.dead_length_a or 0.0)
            l_b0 = stroke - x0 + (rig.dead_length_b or 0.0)
            _check_chamber_lengths(x, l_a0, l_b0, modes, rig=rig, name=name)
    p0 = (supply if supply is not None else 0.0) + p_amb
    span = None if host else log_volume_span(x, l_a0, l_b0, modes)
    array = np.asarray if host else jnp.asarray
    zeros = np.zeros(n)
    return Drive(
        time=array(t), displacement=array(x),
        pressure_a=array(zeros if pressure_a is None else np.asarray(pressure_a, float)),
        pressure_b=array(zeros if pressure_b is None else np.asarray(pressure_b, float)),
        still=array(zeros if still is None else np.asarray(still, dtype=float)),
        area_a=jnp.asarray(area_a), area_b=jnp.asarray(area_b),
        l_a0=jnp.asarray(l_a0), l_b0=jnp.asarray(l_b0),
        p_a0=jnp.asarray(p0), p_b0=jnp.asarray(p0), p_amb=jnp.asarray(p_amb),
        friction_state0=jnp.asarray(float(friction_state0)),
        force_offset=jnp.asarray(float(force_offset)),
        modes=(modes[0], modes[1]), observed=(observed[0], observed[1]), has_time=has_time,
        name=name, runs=None if host else find_runs(x), log_volume_span=span,
        log_volume_ratios=log_volume_ratios(x, l_a0, l_b0, span))


#: shortest closed-chamber length (m) the polytropic law is evaluated at; shorter is
#: metal on metal, and the law's pressure would overflow
MIN_CHAMBER_LENGTH = 1e-6


def log_volume_span(x: np.ndarray, l_a0: float, l_b0: float, modes) -> float | None:
    """The largest ``|log(V(x[0]) / V(x))|`` of a closed chamber over the samples of ``x`` (the
    closed form's powers are taken from the first sample), rounded up to a power of two
    (drives of one stack share one, and each value is a compilation); None without a closed
    chamber of finite length (or samples)."""
    x = np.asarray(x, dtype=float)
    lengths = [np.array([l0 + sign * x[0], l0 + sign * x.min(), l0 + sign * x.max()])
               for mode, l0, sign in zip(modes, (l_a0, l_b0), (1.0, -1.0))
               if mode == "closed" and x.size]
    if not lengths or not all(np.all(np.isfinite(v)) and np.all(v > 0) for v in lengths):
        return None
    span = max(abs(math.log(v[k] / v[0])) for v in lengths for k in (1, 2))
    return 2.0 ** math.ceil(math.log2(max(span, 2.0 ** -40)))


def chamber_log_ratios(x, l_a0, l_b0):
    """``log(V(x[0]) / V(x))`` of chambers A and B (effective lengths ``l_a0 + x`` and
    ``l_b0 - x``) over the last axis of ``x``: one drive's samples, or a stack's (leading log
    axis, one length per log). Traced or concrete."""
    x0 = x[..., :1]
    l_a, l_b = (jnp.asarray(length)[..., None] for length in (l_a0, l_b0))
    return jnp.log((l_a + x0) / (l_a + x)), jnp.log((l_b - x0) / (l_b - x))


#: :func:`chamber_log_ratios` of concrete samples: one compilation per log length, where its
#: operations one by one compiled five
_chamber_log_ratios = jax.jit(chamber_log_ratios)


def log_volume_ratios(x: np.ndarray, l_a0: float, l_b0: float,
                      span: float | None) -> tuple[jnp.ndarray, jnp.ndarray] | None:
    """:func:`chamber_log_ratios` of ``x``, when the drive has a chamber ``span``
    (:func:`log_volume_span`; None: None)."""
    return None if span is None else _chamber_log_ratios(jnp.asarray(x, dtype=float), l_a0,
                                                         l_b0)


def _check_chamber_lengths(x: np.ndarray, l_a0: float, l_b0: float, modes, *, rig: Rig,
                           name: str) -> None:
    """A closed chamber keeps a positive length over the whole log."""
    for chamber, mode, length, key in (("A", modes[0], l_a0 + x, "dead_length_a_mm"),
                                       ("B", modes[1], l_b0 - x, "dead_length_b_mm")):
        if mode != "closed" or not length.size:
            continue
        i = int(np.argmin(length))
        if not length[i] >= MIN_CHAMBER_LENGTH:
            raise InputError(rig.source or name, f"log '{name}', closed chamber {chamber}",
                             f"its length (start_position_mm, stroke_mm and {key} with the "
                             f"displacement) falls to {length[i] * 1e3:.4g} mm at sample {i}, "
                             "where the gas-spring law is singular",
                             f"give {key} (the chamber's dead volume / piston area, "
                             f"--{key.replace('_', '-')}) or check start_position_mm and the "
                             "displacement sign")


def drive_from_log(log: Log, *, needs_chamber: bool = False, needs_supply: bool = True,
                   still=None, what: str = "the chamber term", host: bool = False) -> Drive:
    """The drive of a :class:`~fitstiff.io.log.Log` (``host``: see :func:`make_drive`)."""
    drive = make_drive(displacement=log.displacement, time=log.time, rig=log.rig,
                       pressure_a=log.pressure_a, pressure_b=log.pressure_b,
                       vented=log.vented, still=still, name=log.name,
                       needs_chamber=needs_chamber, needs_supply=needs_supply, what=what,
                       host=host)
    force = np.asarray(log.force, dtype=float) if host else jnp.asarray(log.force)
    return eqx.tree_at(lambda d: d.measured_force, drive, force, is_leaf=lambda v: v is None)
