"""Effects on the measurement rather than the force (DESIGN §3): delay and rig compliance.

``time_delay`` shifts the displacement the model sees: the force channel lags the
displacement channel by ``delay`` (the model is driven by ``x(t - delay)``, linearly
interpolated). ``rig_compliance`` is a spring in series between the displacement sensor and
the piston: the piston moves ``x_sensor - compliance * F``; the composition solves that
implicit relation every step (:mod:`fitstiff.model`).
"""

from __future__ import annotations

import numpy as np

from fitstiff._jax import jnp
from fitstiff.params import Param
from fitstiff.terms.base import Term

__all__ = ["RigCompliance", "TimeDelay"]


class TimeDelay(Term):
    name = "time_delay"
    kind = "input"
    summary = "the force channel lags the displacement channel"

    delay: float = 0.0

    def params(self):
        return (Param("delay", "ms", 1e-3, -0.1, 0.1, "force lag behind displacement", null=0.0),)

    def transform_input(self, drive, x):
        if not drive.has_time:
            return x
        return jnp.interp(drive.time - self.delay, drive.time, x)


class RigCompliance(Term):
    name = "rig_compliance"
    kind = "series"
    summary = "a spring in series between the displacement sensor and the piston"

    compliance: float = 1e-6

    def params(self):
        return (Param("compliance", "mm/N", 1e-3, 0.0, np.inf,
                      "series compliance of the rig (1 / rig stiffness)", null=0.0),)
