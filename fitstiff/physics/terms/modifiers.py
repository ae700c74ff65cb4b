"""Effects that change another term instead of adding a force (DESIGN §3).

Friction modifiers return level / slope factors for every friction base in the model;
chamber modifiers return heat and leak rates for the ``chamber`` term. Every modifier has a
*null* value of its parameters at which it changes nothing (factor 1, rate 0), so a model with
the effect nests the model without it.
"""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np

from fitstiff._jax import jnp
from fitstiff.errors import InputError
from fitstiff.physics.params import Param
from fitstiff.physics.terms.base import FrictionBase, Modifier, Modulation, Step
from fitstiff.physics.terms.chamber import Chamber

__all__ = ["Asymmetry", "HeatTransfer", "Leakage", "PressureFriction", "Stribeck"]


class Stribeck(Modifier):
    name = "stribeck"
    targets = FrictionBase
    summary = "friction level falls from Fs = ratio * Fc at rest to Fc with speed"
    excitation = "slow (below 1 mm/s) and fast (above 10 mm/s) sliding in the same or comparable logs"

    stribeck_ratio: float = 1.2
    stribeck_vs: float = 2e-3

    def params(self):
        return (Param("stribeck_ratio", "-", 1.0, 1.0, 5.0, "Fs / Fc", null=1.0),
                Param("stribeck_vs", "mm/s", 1e-3, 0.0, np.inf, "Stribeck velocity"))

    def modulate(self, state, s: Step, drive):
        level = 1.0 + (self.stribeck_ratio - 1.0) * jnp.exp(-((s.v / self.stribeck_vs) ** 2))
        return state, Modulation(level=level)

    def reference_level(self):
        return self.stribeck_ratio


class Asymmetry(Modifier):
    name = "asymmetry"
    targets = FrictionBase
    summary = "friction level (and slope) differ between the two directions"
    excitation = "sliding in both directions (full loops, not one-way ramps)"

    level_asym: float = 0.0
    slope_asym: float = 0.0

    def params(self):
        return (Param("level_asym", "-", 1.0, -0.9, 0.9,
                      "level factor 1 + a toward B, 1 - a toward A", null=0.0),
                Param("slope_asym", "-", 1.0, -0.9, 0.9,
                      "slope factor 1 + b toward B, 1 - b toward A", null=0.0))

    def init(self, drive):
        return jnp.zeros(())

    def modulate(self, direction, s: Step, drive):
        direction = jnp.where(s.dx != 0, jnp.sign(s.dx), direction)
        return direction, Modulation(level=1.0 + self.level_asym * direction,
                                     slope=1.0 + self.slope_asym * direction)


class PressureFriction(Modifier):
    name = "pressure_friction"
    needs_chamber_geometry = True
    targets = FrictionBase
    summary = "friction level rises with chamber pressure: exp(beta (p - p_ref))"
    excitation = "logs at two or more supply pressures, or a logged chamber pressure that varies"
    lookalike = ("where each log has one supply pressure, whatever else differs between the logs "
                 "looks the same: a friction that drifts over the session, or that changes along "
                 "the stroke when each log sits at another position: record two pressures at "
                 "one position, and repeat the first log at the end of the session")

    beta: float = 0.0
    #: reference gauge pressure (Pa) at which the friction base's levels apply: given in the
    #: spec (``pressure_friction:p_ref=3``, bar gauge), else the mean seal pressure of the
    #: logs the model is built for, rounded to 0.1 bar
    p_ref: float = eqx.field(static=True, default=0.0)
    #: ``p_ref`` was given in the spec (the spec then carries it; not a setting of its own)
    p_ref_given: bool = eqx.field(static=True, default=False, metadata={"setting": False})

    @classmethod
    def from_spec(cls, arg, *, drives=()):
        if arg is not None:
            key, _, value = arg.partition("=")
            try:
                bar = float(value) if key.strip() == "p_ref" else math.nan
            except ValueError:
                bar = math.nan
            if not math.isfinite(bar):
                raise InputError(None, f"model term 'pressure_friction:{arg}'",
                                 "takes only p_ref=BAR (a finite gauge pressure in bar)",
                                 "write e.g. 'pressure_friction:p_ref=3', or "
                                 "'pressure_friction' for the logs' mean pressure")
            return cls(p_ref=bar * 1e5, p_ref_given=True)
        if not drives:
            return cls()
        mean = float(np.mean([float(jnp.mean(d.seal_pressure)) for d in drives]))
        return cls(p_ref=round(mean / 1e4) * 1e4)  # 0.1 bar grid, a readable reference

    @property
    def token(self) -> str:
        return (f"pressure_friction:p_ref={self.p_ref / 1e5:g}" if self.p_ref_given
                else "pressure_friction")

    def params(self):
        return (Param("beta", "1/bar", 1e-5, -2e-5, 5e-5,
                      "relative friction rise per bar of mean chamber pressure", null=0.0),)

    def reading(self) -> str:
        source = ("as given in the model" if self.p_ref_given else
                  "the mean seal pressure of the logs, rounded; set it with "
                  "pressure_friction:p_ref=BAR")
        return (f"friction levels such as Fc apply at p_ref = {self.p_ref / 1e5:.3g} bar gauge "
                f"({source}); beta is per bar of the mean of the two chamber pressures, so on "
                "a rig with one chamber vented and the other at supply it is beta/2 per bar "
                "of supply")

    def modulate(self, state, s: Step, drive):
        p_seal = 0.5 * ((s.p_a if drive.modes[0] == "measured" else
                         drive.p_a0 if drive.modes[0] == "closed" else drive.p_amb)
                        + (s.p_b if drive.modes[1] == "measured" else
                           drive.p_b0 if drive.modes[1] == "closed" else drive.p_amb))
        return state, Modulation(level=jnp.exp(self.beta * (p_seal - drive.p_amb - self.p_ref)))


class HeatTransfer(Modifier):
    name = "heat_transfer"
    targets = Chamber
    summary = "gas-wall heat exchange: rate-dependent stiffness between adiabatic and isothermal"
    excitation = "closed chambers moved at two or more clearly different rates (or with pauses after a stroke), with the chamber pressures logged"

    heat_rate: float = 1.0

    def params(self):
        return (Param("heat_rate", "1/s", 1.0, 0.0, np.inf,
                      "temperature relaxation rate toward the wall", null=0.0),)

    def modulate(self, state, s: Step, drive):
        return state, Modulation(heat_rate=self.heat_rate)


class Leakage(Modifier):
    name = "leakage"
    targets = Chamber
    summary = "the pressure difference across the piston relaxes (leak past the seal)"
    excitation = "closed chambers held displaced for seconds (pauses away from the start), with the chamber pressures logged"

    leak_rate: float = 0.05

    def params(self):
        return (Param("leak_rate", "1/s", 1.0, 0.0, np.inf,
                      "relaxation rate of the pressure difference", null=0.0),)

    def modulate(self, state, s: Step, drive):
        return state, Modulation(leak_rate=self.leak_rate)
