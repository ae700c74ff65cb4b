"""Model terms by canonical name (DESIGN §3). See :mod:`fitstiff.physics.terms.base` for the
roles."""

from fitstiff.physics.terms.base import (ForceSource, ForceTerm, FrictionBase, InputTerm, Modifier,
                                         Modulation, SeriesTerm, Step, Term)
from fitstiff.physics.terms.chamber import Chamber
from fitstiff.physics.terms.forces import DwellStiction, ForceDrift, Inertia, Viscous
from fitstiff.physics.terms.friction import Coulomb, Dahl, LuGre, MaxwellSlip
from fitstiff.physics.terms.measurement import RigCompliance, TimeDelay
from fitstiff.physics.terms.modifiers import (Asymmetry, HeatTransfer, Leakage, PressureFriction,
                                              Stribeck)

__all__ = ["ROLES", "TERMS", "EFFECTS", "FRICTION_BASES", "Chamber", "ForceSource",
           "ForceTerm", "FrictionBase", "InputTerm", "Modifier", "Modulation", "SeriesTerm",
           "Step", "Term"]

#: the role bases; every term is an instance of exactly one
ROLES: tuple[type[Term], ...] = (Chamber, FrictionBase, ForceTerm, Modifier, InputTerm,
                                 SeriesTerm)

#: every term class by its canonical name
TERMS: dict[str, type[Term]] = {cls.name: cls for cls in (
    Chamber, Dahl, LuGre, MaxwellSlip, Coulomb, Viscous, Stribeck, Asymmetry, PressureFriction,
    DwellStiction, HeatTransfer, Leakage, Inertia, ForceDrift, TimeDelay, RigCompliance)}

FRICTION_BASES = tuple(n for n, c in TERMS.items() if issubclass(c, FrictionBase))

#: the effects the diagnosis can add to a baseline (DESIGN §3 table)
EFFECTS = ("viscous", "stribeck", "asymmetry", "pressure_friction", "dwell_stiction",
           "heat_transfer", "leakage", "inertia", "force_drift", "time_delay", "rig_compliance",
           "maxwell_slip")
