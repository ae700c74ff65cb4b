"""Effects on the measurement rather than the force (DESIGN §3): delay and rig compliance.

``time_delay`` shifts the displacement the model sees: the force channel lags the
displacement channel by ``delay`` (the model is driven by ``x(t - delay)``, linearly
interpolated). ``rig_compliance`` is a spring in series between the displacement sensor and
the piston: the piston moves ``x_sensor - compliance * F``; the composition solves that
implicit relation every step (:mod:`fitstiff.physics.model`).
"""

from __future__ import annotations

import numpy as np

from fitstiff._jax import jnp
from fitstiff.physics.params import Param
from fitstiff.physics.terms.base import InputTerm, SeriesTerm, Term
from fitstiff.signal.monotone import directions, monotone_in_runs

__all__ = ["MeasuredForceCompliance", "RigCompliance", "TimeDelay"]


class TimeDelay(InputTerm):
    name = "time_delay"
    summary = "the force channel lags the displacement channel"
    excitation = "a time column and fast reversals or a sine sweep (the lag shows where the force changes quickly)"

    delay: float = 0.0

    def params(self):
        return (Param("delay", "ms", 1e-3, -0.1, 0.1, "force lag behind displacement", null=0.0),)

    def transform_input(self, drive, x):
        if not drive.has_time:
            return x
        return jnp.interp(drive.time - self.delay, drive.time, x)

    def reach_s(self) -> float:
        """The largest delay the term can take (its bounds, or a value fixed beyond them)."""
        bound = max(abs(p) for p in (self.params()[0].lower, self.params()[0].upper))
        try:
            return max(bound, abs(float(self.delay)))
        except TypeError:          # traced
            return bound


class _Compliance(Term):
    """The rig's series spring, whichever way the model applies it."""

    name = "rig_compliance"
    summary = "a spring in series between the displacement sensor and the piston"
    excitation = "reversals in the pre-sliding range (small-amplitude loops), where the seal is stiffest"
    lookalike = ("a seal whose stiffest pre-sliding elements do not slip within the logs' "
                 "reversals softens the pre-sliding slope the same way: with the piston "
                 "blocked and the chambers vented, push on the rod and read the displacement "
                 "sensor, which a stiff rig keeps still")

    compliance: float = 1e-6

    def params(self):
        return (Param("compliance", "mm/N", 1e-3, 0.0, np.inf,
                      "series compliance of the rig (1 / rig stiffness)", null=0.0),)


class RigCompliance(_Compliance, SeriesTerm):
    @classmethod
    def from_spec(cls, arg, *, drives=()):
        if arg == "measured":
            return MeasuredForceCompliance()
        return super().from_spec(arg)


class MeasuredForceCompliance(_Compliance, InputTerm):
    """``rig_compliance:measured``: the same series spring, with the piston displacement
    taken as ``x_sensor - compliance * F_measured`` (the logged force as an input, its noise
    smoothed out by :class:`~fitstiff.inference.problem.Problem`) instead of solving
    ``x_piston = x_sensor - compliance * F_model`` every step. Equal up to the force's
    remaining error times the compliance; no Newton iteration in the scan and no coupling of
    every term to the piston motion, so the rest of the model keeps its all-samples
    evaluation. The piston position is kept moving one way within each monotone run of the
    displacement the term is given (:func:`~fitstiff.signal.monotone.monotone_in_runs`), as
    the series form's piston does. The diagnosis screens and refits the effect this way; the
    simulator uses the series form.
    """

    needs_measured_force = True

    @property
    def token(self) -> str:
        return "rig_compliance:measured"

    def transform_input(self, drive, x):
        if drive.measured_force is None:
            return x
        # the piston reverses where the displacement it is given does (it moves
        # dx / (1 + C k) with the stiffness k >= 0 it pushes), so it keeps that
        # displacement's monotone runs; the logged force's noise would make reversals of its
        # own, and a stepped friction law ratchets its state down on every one of them
        # (withheld set single/rig_compliance/1, truth C 9.5e-3 mm/N, seal 55.6 N/mm, force
        # noise 0.11 N AR(1) 0.47: RMS at the true parameters 3.16 N with the raw force,
        # 0.61 N smoothed, 0.15 N with the noise-free force; the fit found C 8.1e-3 at
        # 0.45 N, with the runs kept 9.8e-3 at 0.16 N). The runs are those of ``x`` as it
        # comes (after a time delay, say), so at C = 0 the term leaves it exactly as it is.
        return monotone_in_runs(x - self.compliance * drive.measured_force, *directions(x))
