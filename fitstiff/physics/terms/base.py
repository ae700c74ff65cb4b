"""What every model term is: an immutable JAX module with physical parameters and a role.

A model is a sum of terms (``chamber+dahl+viscous``). The composition
(:mod:`fitstiff.physics.model`) runs the terms together in one ``lax.scan`` over the samples of a
:class:`~fitstiff.physics.drive.Drive`; force sources that need no scan
(:meth:`ForceSource.run_all`: stateless ones, the polytropic chamber, Dahl over the monotone
runs of the displacement) are evaluated over all samples at once. Every term is an instance
of exactly one role, an abstract base class whose methods are what the composition calls on
it:

:class:`~fitstiff.physics.terms.chamber.Chamber`  the gas spring; its step returns the chamber
force.
:class:`FrictionBase`  a seal-friction base (Dahl, LuGre, Maxwell-slip, Coulomb); its step
              returns the friction force and honours the level / slope factors of the
              modifiers; it starts from the data (:meth:`FrictionBase.start`).
:class:`ForceTerm`  any other additive force (viscous, inertia, force drift, dwell stiction).
:class:`Modifier`  changes another term rather than adding a force: it returns a
              :class:`Modulation` every step (friction level and slope factors for
              Stribeck, asymmetry and pressure-dependent friction; heat and
              leak rates for the chamber); :attr:`Modifier.targets` is the role it acts on.
:class:`InputTerm`  transforms the measured displacement before the scan (time delay).
:class:`SeriesTerm`  a compliance between the displacement sensor and the piston (rig
              compliance); the composition solves for the piston motion every step.

The first three are force sources (:class:`ForceSource`): each gives one column of
:meth:`fitstiff.physics.model.Model.contributions`. Terms also declare the rig data they need
(:attr:`Term.needs_chamber_geometry`, :attr:`Term.needs_acceleration`; see
:func:`fitstiff.physics.model.model_needs`).

Parameters live in the fields, in SI units; bounds, display units and transforms are declared
by :meth:`Term.params` and applied by :mod:`fitstiff.physics.params`, never inside the physics.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, NamedTuple

import equinox as eqx

from fitstiff._jax import jax
from fitstiff.physics.params import Param

__all__ = ["ForceSource", "ForceTerm", "FrictionBase", "FrictionEstimate", "InputTerm",
           "Modifier", "Modulation", "SeriesTerm", "Step", "Term"]


class Step(NamedTuple):
    """Per-sample inputs of one scan step (all scalars, SI).

    ``dx`` is the displacement increment from the previous sample (0 for the first), ``v`` the
    mean velocity over that increment, ``a`` the acceleration estimate, ``p_a``/``p_b`` the
    measured absolute pressures (0 where the chamber is not measured), ``still`` 1.0 while the
    piston stands still.
    """

    t: Any
    dt: Any
    x: Any
    dx: Any
    v: Any
    a: Any
    p_a: Any
    p_b: Any
    still: Any


class Modulation(NamedTuple):
    """What modifiers tell the other terms at one step. ``None`` means "no modifier"."""

    level: Any = None       # friction level factor (multiplies Fc, Fs, W_i)
    slope: Any = None       # friction slope factor (multiplies sigma0, k_i)
    heat_rate: Any = None   # 1/s, gas-wall heat exchange rate (chamber)
    leak_rate: Any = None   # 1/s, relaxation rate of the pressure difference (chamber)

    def combine(self, other: Modulation) -> Modulation:
        def mul(a, b):
            return b if a is None else a if b is None else a * b

        def add(a, b):
            return b if a is None else a if b is None else a + b

        return Modulation(mul(self.level, other.level), mul(self.slope, other.slope),
                          add(self.heat_rate, other.heat_rate),
                          add(self.leak_rate, other.leak_rate))

    def level_or(self, one=1.0):
        return one if self.level is None else self.level

    def slope_or(self, one=1.0):
        return one if self.slope is None else self.slope


class FrictionEstimate(NamedTuple):
    """What the data say about the seal before any fit (see
    :func:`fitstiff.inference.fitting.initial_guess`); friction bases start from it
    (:meth:`FrictionBase.start`).

    ``level``: sliding friction level (N), half the spread of the sliding force plateaus with
    the chamber force removed; ``tangent``: slope of the friction force right after the
    reversals (N/m), ``None`` when no reversal shows one; ``reversal_state``: median
    ``|F| / level`` at those reversals (1.0 after a saturated branch).
    """

    level: float
    tangent: float | None
    reversal_state: float


class Term(eqx.Module):
    """Base class of every term. A term subclasses one role (:class:`ForceTerm`,
    :class:`FrictionBase`, :class:`~fitstiff.physics.terms.chamber.Chamber`, :class:`Modifier`,
    :class:`InputTerm`, :class:`SeriesTerm`), sets ``name`` and implements what its role
    needs."""

    name: ClassVar[str] = ""
    #: one line for --help and docs
    summary: ClassVar[str] = ""
    #: effects: the excitation that makes the effect testable (the diagnosis says to record it
    #: when the logs cannot test the effect)
    excitation: ClassVar[str] = ""
    #: effects: what outside the library draws the same force on logs where the effect is
    #: accepted, and what to record to tell them apart (one sentence; the diagnosis says it
    #: beside an accepted effect); set where the withheld-effect benchmark has seen the
    #: mix-up (docs/benchmarks.md, "What else looks like an accepted effect")
    lookalike: ClassVar[str] = ""
    #: the drives need the chamber's rig values (bore; stroke, start position and supply
    #: pressure for a closed chamber)
    needs_chamber_geometry: ClassVar[bool] = False
    #: the term uses the acceleration (a smoothed one is built when the displacement is
    #: denoised)
    needs_acceleration: ClassVar[bool] = False
    #: the term takes the logged force as an input (the problem smooths its noise out first:
    #: :func:`fitstiff.segments.denoise.smooth_force`)
    needs_measured_force: ClassVar[bool] = False
    #: roles that modifiers act on: how messages name the role ("'stribeck' modifies ...")
    described: ClassVar[str] = ""

    @classmethod
    def from_spec(cls, arg: str | None, *, drives=()) -> Term:
        """Build from the spec token argument (``maxwell_slip:4`` -> ``"4"``) and the drives
        the model will see (for terms whose structure depends on the data)."""
        if arg is not None:
            from fitstiff.errors import InputError

            raise InputError(None, f"model term '{cls.name}:{arg}'",
                             f"'{cls.name}' takes no argument", f"write '{cls.name}'")
        return cls()

    @property
    def token(self) -> str:
        """The spec token that builds this term again (``maxwell_slip:6``, ``dahl:alpha``):
        :attr:`fitstiff.physics.model.Model.spec` joins them, and a run directory's model is rebuilt
        from it."""
        return self.name

    def params(self) -> tuple[Param, ...]:
        """Declared free parameters (field names on this module)."""
        return ()

    def reading(self) -> str:
        """What the fitted values refer to, where a unit alone does not say it (a reference
        pressure, a per-what): one sentence shown beside them by fit, diagnose and the
        reports; empty when the units say it all."""
        return ""

    def init(self, drive):
        """Scan state at the first sample (a pytree; ``()`` for stateless terms)."""
        return ()


class ForceSource(Term):
    """A term that gives a force every step: one column of the model's contributions (the
    chamber, the friction bases, the additive forces)."""

    @abc.abstractmethod
    def step(self, state, s: Step, drive, mod: Modulation):
        """One sample: ``(new_state, force_N)``. Forces are + toward the B cap."""

    def run_all(self, steps: Step, drive):
        """All samples at once, outside the scan: ``(states, forces)`` with a leading sample
        axis, or ``None`` to be stepped in the scan (the default for terms with a state).

        The composition uses it only when no modifier acts on the term and no series
        compliance couples the terms, and it must equal stepping from :meth:`init` with a
        neutral :class:`Modulation`. Stateless terms get it here (their step ``vmap``-ed over
        the samples); terms whose state has a closed form (the polytropic chamber; Dahl over the
        monotone runs of the drive, :mod:`fitstiff.signal.monotone`) override it.
        """
        if jax.tree_util.tree_leaves(self.init(drive)):
            return None
        return jax.vmap(lambda s: self.step((), s, drive, Modulation()))(steps)


class ForceTerm(ForceSource):
    """Role: an additive force other than the chamber and the friction base (viscous,
    inertia, force drift, the junction of dwell stiction)."""


class FrictionBase(ForceSource):
    """Role: a seal-friction base. Its step honours the modifiers' level and slope factors."""

    described = "a friction base (dahl, lugre, maxwell_slip or coulomb)"

    @abc.abstractmethod
    def start(self, estimate: FrictionEstimate, *, share: float = 1.0) -> FrictionBase:
        """This base with data-driven starting values carrying ``share`` of the estimated
        friction (several bases split it). Other terms keep their values: effects start where
        they are (their defaults, or their null value in the diagnosis)."""

    @abc.abstractmethod
    def presliding_slope(self):
        """Slope (N/m) of the friction force right after a reversal."""

    @abc.abstractmethod
    def breakaway(self):
        """Largest friction force (N) the seal holds before gross sliding."""

    def implausible(self) -> list[str]:
        """What in this seal's values is not seal physics, in words (none by default)."""
        return []


class Modifier(Term):
    """Role: changes the terms of role :attr:`targets` instead of adding a force."""

    #: the role of the terms it acts on (:class:`FrictionBase` or
    #: :class:`~fitstiff.physics.terms.chamber.Chamber`); a model with the modifier needs one
    targets: ClassVar[type[Term]]

    @abc.abstractmethod
    def modulate(self, state, s: Step, drive):
        """``(new_state, Modulation)``."""

    def reference_level(self):
        """Friction level factor at the reference condition (low speed, reference pressure,
        no dwell, direction-averaged)."""
        return 1.0


class InputTerm(Term):
    """Role: transforms the measured displacement before the scan."""

    @abc.abstractmethod
    def transform_input(self, drive, x):
        """The displacement the model should see, given the measured ``x``."""

    def reach_s(self) -> float:
        """How far (s) before or after a sample :meth:`transform_input` reads the
        displacement (0: the sample alone); a log run in windows gives each window this
        margin (:meth:`fitstiff.physics.model.Model.run_window`)."""
        return 0.0


class SeriesTerm(Term):
    """Role: a spring in series between the displacement sensor and the piston; the
    composition solves ``x_piston = x_sensor - compliance * F_model`` every step."""

    compliance: eqx.AbstractVar[float]
