"""``chamber``: the closed-chamber polytropic gas spring (DESIGN §1.1).

Each chamber follows the mode its drive gives it: a *closed* chamber is compressed with the
polytropic exponent ``n`` (the exact law, step by step: ``p' = p (V/V')**n``), a *measured*
chamber uses the logged pressure, a *vented* one stays at ambient. The force is
``A_B (p_B - p_amb) - A_A (p_A - p_amb)`` (external force that holds the piston).

Two modifiers act on closed chambers (see :mod:`fitstiff.physics.terms.modifiers`):
``heat_transfer`` relaxes the gas temperature toward the wall with a rate ``h`` after each
polytropic step (``h = 0``: plain polytropic law; ``n = 1.4`` with ``h > 0``: between adiabatic
and isothermal, rate dependent); ``leakage`` relaxes the pressure difference across the piston
with a rate ``lambda`` while conserving ``p_A V_A + p_B V_B``.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx

from fitstiff._jax import jax, jnp
from fitstiff.physics.drive import chamber_log_ratios
from fitstiff.physics.params import Param
from fitstiff.physics.terms.base import ForceSource, Modulation, Step

__all__ = ["Chamber", "polytropic_ratio", "series_terms"]

#: exponents ``|n|`` up to which :func:`polytropic_ratio`'s series is exact (the law's ``n``
#: is bounded to [1, 1.67]; beyond the limit the series gives NaN)
SERIES_EXPONENT_LIMIT = 3.0
#: most terms of the series; a wider span takes ``exp``
_MAX_SERIES_TERMS = 10


def series_terms(span: float | None) -> int | None:
    """Degree ``K`` of the Taylor polynomial of ``exp`` exact to double precision for
    ``|u| <= U = SERIES_EXPONENT_LIMIT * span``: ``U**K / K!`` times ``exp(2 U)`` (the
    relative error) below ``2**-53``, one term more than the value needs; None without a
    span or beyond :data:`_MAX_SERIES_TERMS`."""
    if span is None:
        return None
    bound = SERIES_EXPONENT_LIMIT * span
    term, k = 1.0, 0
    while term * math.exp(2.0 * bound) > 2.0 ** -53:
        k += 1
        term *= bound / k
        if k > _MAX_SERIES_TERMS:
            return None
    return max(k, 1)


def polytropic_ratio(log_ratio, n, *, span: float | None = None, bounded: bool = False):
    """``exp(n * log_ratio)``: the polytropic power ``(V / V')**n`` from ``log(V / V')``.

    With ``span``, a bound on ``|log_ratio|`` known before tracing
    (:attr:`~fitstiff.physics.drive.Drive.log_volume_span`), small enough for :func:`series_terms`:
    its Taylor polynomial, exact to double precision for ``|n| <= SERIES_EXPONENT_LIMIT``, a
    few multiply-adds per sample instead of an ``exp`` (the log-posterior of
    ``benchmarks/posterior_speed.py``'s log, 7 terms: x1.14-1.21 faster on 32 walkers, x1.11
    on 16), with the derivatives of ``exp``.
    Where ``|log_ratio|`` exceeds ``span`` or ``|n|`` the limit: NaN, never a wrong value.
    ``bounded``: ``|log_ratio| <= span`` is known (a drive's own
    :attr:`~fitstiff.physics.drive.Drive.log_volume_ratios`, from which its span was found), so it
    is not checked again per call.
    """
    terms = series_terms(span)
    if terms is None:
        return jnp.exp(n * log_ratio)
    # under vmap over walkers the bound on the logs (shared) is checked once per call
    ok = jnp.abs(n) <= SERIES_EXPONENT_LIMIT
    if not bounded:
        ok = ok & (jnp.max(jnp.abs(log_ratio)) <= span)
    return _exp_series(log_ratio, jnp.where(ok, n, jnp.nan), terms)


@functools.partial(jax.custom_jvp, nondiff_argnums=(2,))
def _exp_series(log_ratio, n, terms: int):
    """``exp(n * log_ratio)`` by its Taylor polynomial of degree ``terms``, Horner on the
    coefficients ``1 / k!``: multiply-adds only (dividing by ``k`` per term, the call was
    1.2 x slower than with ``exp``)."""
    u = n * log_ratio
    value = 1.0 / math.factorial(terms)
    for k in range(terms - 1, -1, -1):
        value = 1.0 / math.factorial(k) + u * value
    return value


@_exp_series.defjvp
def _exp_series_jvp(terms, primals, tangents):
    # the derivative of exp, not of the polynomial: exact to the same precision, and a
    # Jacobian traces two products instead of the polynomial's chain
    log_ratio, n = primals
    d_log, d_n = tangents
    value = _exp_series(log_ratio, n, terms)
    return value, value * (n * d_log + log_ratio * d_n)


class Chamber(ForceSource):
    """Role and term: the gas spring (the chamber modifiers' target)."""

    name = "chamber"
    described = "the chamber term"
    needs_chamber_geometry = True
    summary = "closed-chamber gas spring (measured pressures if logged, else polytropic, n fitted)"
    excitation = "closed chambers and motion of a millimetre or more, best at several positions or pressures"

    n: float = 1.3
    #: factor on the chamber force, a parameter only for ``chamber:gated``
    gate: float = 1.0
    #: False when every chamber of every log is measured or vented: then n is not a parameter
    closed: bool = eqx.field(static=True, default=True)
    #: ``chamber:gated``: the force is scaled by ``gate`` (null 0), so that a model with the
    #: chamber nests the one without it - the chamber as a candidate effect of the diagnosis
    #: on a friction-only baseline (every other effect nests its baseline by its own null)
    gated: bool = eqx.field(static=True, default=False)

    @classmethod
    def from_spec(cls, arg, *, drives=()):
        if arg not in (None, "gated"):
            super().from_spec(arg)
        closed = not drives or any("closed" in d.modes for d in drives)
        return cls(closed=closed, gated=arg == "gated")

    @property
    def token(self) -> str:
        return "chamber:gated" if self.gated else "chamber"

    def params(self):
        out = ()
        if self.closed:
            out += (Param("n", "-", 1.0, 1.0, 1.67,
                          "polytropic exponent (1 isothermal, 1.4 adiabatic)"),)
        if self.gated:
            out += (Param("gate", "-", 1.0, 0.0, 2.0,
                          "factor on the chamber force (1: the gas spring as modelled)",
                          null=0.0),)
        return out

    def init(self, drive):
        one = jnp.ones(())
        return (drive.p_a0 * one, drive.p_b0 * one, one, one)

    def step(self, state, s: Step, drive, mod: Modulation):
        p_a, p_b, th_a, th_b = state
        x_prev = s.x - s.dx
        closed_a, closed_b = (m == "closed" for m in drive.modes)
        if closed_a or closed_b:
            # exact polytropic step on the effective lengths (volumes / area)
            # r**n as exp(n log r): the logs depend on the drive only, so under vmap over
            # parameter sets (the posterior's walkers) they are computed once per step
            log_a = jnp.log((drive.l_a0 + x_prev) / (drive.l_a0 + s.x))
            log_b = jnp.log((drive.l_b0 - x_prev) / (drive.l_b0 - s.x))
            p_a, p_b = p_a * jnp.exp(self.n * log_a), p_b * jnp.exp(self.n * log_b)
            if mod.heat_rate is not None:      # gas temperature / wall temperature
                th_a = th_a * jnp.exp((self.n - 1) * log_a)
                th_b = th_b * jnp.exp((self.n - 1) * log_b)
                decay = jnp.exp(-mod.heat_rate * s.dt)
                new_a = 1 + (th_a - 1) * decay
                new_b = 1 + (th_b - 1) * decay
                p_a, p_b, th_a, th_b = p_a * new_a / th_a, p_b * new_b / th_b, new_a, new_b
            if mod.leak_rate is not None and closed_a and closed_b:
                v_a = drive.area_a * (drive.l_a0 + s.x)
                v_b = drive.area_b * (drive.l_b0 - s.x)
                p_eq = (p_a * v_a + p_b * v_b) / (v_a + v_b)
                decay = jnp.exp(-mod.leak_rate * s.dt)
                p_a, p_b = p_eq + (p_a - p_eq) * decay, p_eq + (p_b - p_eq) * decay
        state = (p_a, p_b, th_a, th_b)
        return state, self.force(state, s, drive)

    def run_all(self, steps: Step, drive):
        """:meth:`step` over all samples without heat exchange or leakage: the per-step
        polytropic ratios telescope to ``p = p0 (V(x0) / V(x))**n`` from the first sample."""
        one = jnp.ones_like(steps.x)
        p_a, p_b = drive.p_a0 * one, drive.p_b0 * one
        if "closed" in drive.modes:
            # gas_spring.chamber_pressures written as exp(n log r), like step: under vmap over
            # walkers the logs are shared and only the power runs per walker (with r**n the
            # 32-walker chamber+dahl residuals took 8.4 ms instead of 3.1 ms)
            span = drive.log_volume_span
            own = drive.log_volume_ratios is not None and steps.x is drive.displacement
            log_a, log_b = self.log_ratios(drive, steps.x)
            p_a = p_a * polytropic_ratio(log_a, self.n, span=span, bounded=own)
            p_b = p_b * polytropic_ratio(log_b, self.n, span=span, bounded=own)
        state = (p_a, p_b, one, one)
        return state, self.force(state, steps, drive)

    @staticmethod
    def log_ratios(drive, x=None):
        """``log(V(x[0]) / V(x))`` of chambers A and B over the displacement ``x`` (the last
        axis; default and when it is the drive's: the drive's
        :attr:`~fitstiff.physics.drive.Drive.log_volume_ratios` where it has them): the closed form
        of :meth:`run_all` is ``p = p0 * exp(n * log_ratio)``. Works on a stack of drives
        (leading log axis) as on one."""
        if x is None or x is drive.displacement:
            if drive.log_volume_ratios is not None:
                return drive.log_volume_ratios
            x = drive.displacement
        return chamber_log_ratios(x, drive.l_a0, drive.l_b0)

    def force(self, state, s: Step, drive):
        """Chamber force (N, + toward the B cap) of a state at one step (or all samples)."""
        pa, pb = self.pressures(state, s, drive)
        force = drive.area_b * (pb - drive.p_amb) - drive.area_a * (pa - drive.p_amb)
        return force * self.gate if self.gated else force

    @staticmethod
    def pressures(state, s: Step, drive):
        """Absolute chamber pressures at this step: modelled, logged or ambient by mode."""
        def pick(mode, modelled, measured):
            return {"closed": modelled, "measured": measured, "vented": drive.p_amb}[mode]

        return (pick(drive.modes[0], state[0], s.p_a), pick(drive.modes[1], state[1], s.p_b))

    def stiffness(self, drive):
        """Linearised stiffness (N/m) at the start of ``drive``; closed chambers only count."""
        closed_a, closed_b = (m == "closed" for m in drive.modes)
        k_a = self.n * drive.p_a0 * drive.area_a / drive.l_a0 if closed_a else 0.0
        k_b = self.n * drive.p_b0 * drive.area_b / drive.l_b0 if closed_b else 0.0
        return k_a + k_b

