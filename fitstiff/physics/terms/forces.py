"""Additive force effects (DESIGN §3): viscous friction, inertia, force-channel drift and the
junction a seal forms while it stands still (dwell stiction)."""

from __future__ import annotations

import numpy as np

from fitstiff._jax import jnp
from fitstiff.physics.params import Param
from fitstiff.physics.terms.base import ForceTerm, Modulation, Step

__all__ = ["DwellStiction", "ForceDrift", "Inertia", "Viscous"]


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


class DwellStiction(ForceTerm):
    """Stiction that ages during a standstill: a junction forms where the piston stops, grows
    with the logarithm of the standstill's duration (as static friction is measured to age:
    ``Fs(t) = Fs0 + A ln(1 + t / tau)``), and resists the motion that follows, **whichever way
    it goes**, until it breaks:

        F_j = S (u / d) exp((1 - (s / d)^2) / 2)
        S   = dwell_gain ln(1 + t_dwell / dwell_tau)

    with ``u = x - x_pause`` the displacement from the pause position, ``s`` the travel since
    the motion resumed (``|u|`` until the next reversal; it only grows, so a junction once
    released stays released when the piston passes its position again) and ``d`` =
    ``dwell_decay``: a stiff rise from the pause position (initial slope ``1.65 S / d``), a
    peak of ``S`` at ``d`` of travel, then a release (to 5 % at ``3 d``). Added to the
    friction base's force, it makes the first branch after a pause stiffer and higher, both
    where the motion continues and where it reverses. (A level factor on a Dahl base cannot:
    a higher level makes the branch after a reversal *softer*, initial slope
    ``sigma0 (1 + F / level)``.) The clock runs while the drive's ``still`` flag is set
    (standstills of 0.2 s or more, :mod:`fitstiff.segments.segmentation`); a new standstill starts a
    new junction.
    """

    name = "dwell_stiction"
    summary = ("stiction peak after a standstill, either way the motion resumes, growing with "
               "log(standstill duration)")
    excitation = ("pauses (standstills of 0.2 s or more, better several of different lengths) "
                  "followed by motion")

    dwell_gain: float = 2.0
    dwell_tau: float = 1.0
    dwell_decay: float = 0.1e-3

    def params(self):
        return (Param("dwell_gain", "N", 1.0, 0.0, np.inf,
                      "junction strength per unit of ln(1 + t_dwell / tau)", null=0.0),
                Param("dwell_tau", "s", 1.0, 0.0, np.inf, "ageing time of the junction"),
                Param("dwell_decay", "mm", 1e-3, 0.0, np.inf,
                      "travel from the pause position at which the junction force peaks"))

    def init(self, drive):
        z = jnp.zeros(())
        # standstill duration, pause position, travel since the motion resumed, still at
        # the previous sample
        return (z, z, z, z)

    def step(self, state, s: Step, drive, mod: Modulation):
        t_dwell, x_pause, travel, was_still = state
        still = s.still > 0
        t_dwell = jnp.where(still, jnp.where(was_still > 0, t_dwell + s.dt, s.dt), t_dwell)
        x_pause = jnp.where(still, s.x, x_pause)
        travel = jnp.where(still, 0.0, travel + jnp.abs(s.dx))
        strength = self.dwell_gain * jnp.log1p(t_dwell / self.dwell_tau)
        force = (strength * (s.x - x_pause) / self.dwell_decay
                 * jnp.exp(0.5 * (1.0 - (travel / self.dwell_decay) ** 2)))
        return (t_dwell, x_pause, travel, s.still), force
