"""Additive force effects (DESIGN §3): viscous friction, inertia, force-channel drift."""

from __future__ import annotations

import numpy as np

from fitstiff._jax import jnp
from fitstiff.params import Param
from fitstiff.terms.base import ForceTerm, Modulation, Step

__all__ = ["ForceDrift", "Inertia", "Viscous"]


class Viscous(ForceTerm):
    name = "viscous"
    summary = "viscous friction c v"
    excitation = "logs at two or more clearly different speeds (e.g. 1 and 20 mm/s)"

    c: float = 50.0

    def params(self):
        return (Param("c", "N s/m", 1.0, 0.0, np.inf, "viscous coefficient", null=0.0),)

    def step(self, state, s: Step, drive, mod: Modulation):
        return state, self.c * s.v


class Inertia(ForceTerm):
    name = "inertia"
    needs_acceleration = True
    summary = "m a of the moving mass"
    excitation = "motion with acceleration: sine sweeps or fast reversals (the force of m a must exceed the noise)"

    mass: float = 1.0

    def params(self):
        return (Param("mass", "kg", 1.0, 0.0, np.inf, "moving mass", null=0.0),)

    def step(self, state, s: Step, drive, mod: Modulation):
        return state, self.mass * s.a


class ForceDrift(ForceTerm):
    name = "force_drift"
    summary = "slow linear drift of the force channel's offset"
    excitation = "a longer log, or pauses spread over it, so a slow offset change shows against the noise"

    drift: float = 0.0

    def params(self):
        return (Param("drift", "N/s", 1.0, -np.inf, np.inf, "offset drift rate", null=0.0),)

    def init(self, drive):
        return drive.time[0]

    def step(self, t0, s: Step, drive, mod: Modulation):
        return t0, self.drift * (s.t - t0)

    def run_all(self, steps: Step, drive):
        t0 = jnp.broadcast_to(drive.time[0], steps.t.shape)
        return t0, self.drift * (steps.t - t0)
