"""The per-log nuisances of a problem as transform-layer entries.

Each log has a force-channel offset and, for models with a friction base, an initial friction
state; on request (``free``) the closing pressure of its closed chambers. ``theta`` holds their
unconstrained values: the offset as it is, the initial friction state through ``tanh``, the
closing pressure in bar, on the scale of the other entries.
"""

from __future__ import annotations

import math

from fitstiff.physics.params import Param

__all__ = ["NUISANCE_PARAMS", "NUISANCES", "OPTIONAL_NUISANCES"]

#: the per-log nuisances as transform-layer entries (SI values)
NUISANCE_PARAMS = {
    "offset": Param("offset", "N", 1.0, -math.inf, math.inf, "force-channel offset of a log"),
    "friction_state0": Param("friction_state0", "-", 1.0, -1.0, 1.0,
                             "initial friction state of a log (fraction of saturation)",
                             transform="tanh"),
    "closing_pressure": Param("closing_pressure", "bar", 1e5, -math.inf, math.inf,
                              "gauge pressure at which a log's chambers were closed",
                              transform="scaled"),
}
#: per-log nuisance names (fit.json ``per_log``)
NUISANCES = tuple(NUISANCE_PARAMS)
#: nuisances held unless asked for with ``free``
OPTIONAL_NUISANCES = ("closing_pressure",)
