"""Seal-friction bases (DESIGN §1.2): Dahl, LuGre, Maxwell-slip and static Coulomb.

All return the friction force the seal resists with (+ toward B while moving toward B) and
accept the modifiers' level factor (multiplies ``Fc``, ``Fs``, ``W_i``) and slope factor
(multiplies ``sigma0``, ``k_i``). Every per-step update is exact for a displacement that
changes linearly between samples, so the models stay accurate and stable at any sample rate
and any stiffness:

- Dahl, ``alpha = 1``: ``F' = s Fc + (F - s Fc) exp(-sigma0 |dx| / Fc)``; general ``alpha``:
  ``|y'|**(1-alpha) = |y|**(1-alpha) - (1-alpha) sigma0 |dx| / Fc`` with ``y = 1 - F s / Fc``.
- LuGre: along one step with constant ``v`` the bristle ODE is linear in ``z`` per unit
  travel: ``z' = s g/sigma0 + (z - s g/sigma0) exp(-sigma0 |dx| / g(v))``.
- Maxwell-slip: each element ``F_i' = clip(F_i + k_i dx, -W_i, W_i)``.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.physics.params import Param
from fitstiff.physics.terms.base import FrictionBase, FrictionEstimate, Modulation, Step

__all__ = ["Coulomb", "Dahl", "LuGre", "MaxwellSlip"]

_SIGMA0 = Param("sigma0", "N/mm", 1e3, 0.0, np.inf, "pre-sliding stiffness after a reversal")
_FC = Param("Fc", "N", 1.0, 0.0, np.inf, "Coulomb (sliding) friction level")


#: a friction level (N) below which a model's rate ``sigma0 / Fc`` is taken at this level:
#: a fit may drive a friction base to nothing when another law takes its place (Dahl's Fc
#: reached 7e-215 N beside Maxwell-slip elements), and forward-mode derivatives of ``a / Fc``
#: carry ``a * dFc / Fc**2``, NaN when ``Fc**2`` underflows even where ``dFc`` is 0
_LEAST_LEVEL = 1e-12


def _direction(dx):
    return jnp.sign(dx)


def _divisor(level):
    """``level`` as a divisor: at least :data:`_LEAST_LEVEL` (the force it scales is then
    below a piconewton: the same model)."""
    return jnp.maximum(level, _LEAST_LEVEL)


class Dahl(FrictionBase):
    name = "dahl"
    summary = "Dahl pre-sliding friction (sigma0, Fc; 'dahl:alpha' also fits the shape exponent)"

    sigma0: float = 40e3
    Fc: float = 18.0
    alpha: float = 1.0
    fit_alpha: bool = eqx.field(static=True, default=False)

    @classmethod
    def from_spec(cls, arg, *, drives=()):
        if arg not in (None, "alpha"):
            raise InputError(None, f"model term 'dahl:{arg}'", "unknown option",
                             "write 'dahl' (alpha = 1) or 'dahl:alpha' (alpha fitted)")
        return cls(fit_alpha=arg == "alpha")

    @property
    def token(self) -> str:
        return "dahl:alpha" if self.fit_alpha else "dahl"

    def params(self):
        out = (_SIGMA0, _FC)
        if self.fit_alpha:
            out += (Param("alpha", "-", 1.0, 0.2, 5.0, "Dahl shape exponent"),)
        return out

    def init(self, drive):
        return drive.friction_state0 * self.Fc

    def step(self, F, s: Step, drive, mod: Modulation):
        fc = self.Fc * mod.level_or()
        sigma = self.sigma0 * mod.slope_or()
        d = _direction(s.dx)
        divisor = _divisor(fc)
        c = sigma * jnp.abs(s.dx) / divisor
        if not self.fit_alpha:
            F_new = d * fc + (F - d * fc) * jnp.exp(-c)
            return F_new, F_new
        y = 1.0 - F * d / divisor
        beta = 1.0 - self.alpha
        ay = jnp.maximum(jnp.abs(y), 1e-300)
        near_one = jnp.abs(beta) < 1e-6
        safe_beta = jnp.where(near_one, 1e-6, beta)
        powered = jnp.maximum(ay**safe_beta - safe_beta * c, 0.0)
        ay_new = jnp.where(near_one, ay * jnp.exp(-c),
                           jnp.where(powered > 0, jnp.maximum(powered, 1e-300) ** (1 / safe_beta),
                                     0.0))
        F_new = jnp.where(d == 0, F, d * fc * (1.0 - jnp.sign(y) * ay_new))
        return F_new, F_new

    def run_all(self, steps: Step, drive):
        """With ``alpha = 1``, over the monotone runs of the drive
        (:mod:`fitstiff.signal.monotone`): ``F = s Fc + (F0 - s Fc) exp(-sigma0 |x - x0| / Fc)`` in
        a run of direction ``s`` from its start ``(x0, F0)``; only the run starts are stepped. NaN
        where the displacement goes against its run's direction (a displacement other than the one
        the runs were found in)."""
        runs = drive.runs
        if self.fit_alpha or runs is None:
            return None
        x0 = runs.start(steps.x)
        travel = runs.sign * (jnp.concatenate([x0[1:], steps.x[-1:]]) - x0)
        rate = self.sigma0 / _divisor(self.Fc)

        def across(F, run):
            s, travel = run
            return s * self.Fc + (F - s * self.Fc) * jnp.exp(-rate * travel), F

        _, F0 = jax.lax.scan(across, self.init(drive), (runs.sign, travel))
        s = runs.sign[runs.index]                          # per sample: the data alone
        travelled = s * (steps.x - x0[runs.index])
        gap = (F0 - runs.sign * self.Fc)[runs.index]       # F0 - s Fc of each sample's run
        F = jnp.where(runs.holds(steps.dx), s * self.Fc + gap * jnp.exp(-rate * travelled),
                      jnp.nan)
        return F, F

    def start(self, estimate: FrictionEstimate, *, share: float = 1.0) -> Dahl:
        new = dataclasses.replace(self, Fc=estimate.level * share)
        sigma0 = _sigma0_start(estimate)
        return new if sigma0 is None else dataclasses.replace(new, sigma0=sigma0 * share)

    def presliding_slope(self):
        return self.sigma0

    def breakaway(self):
        return self.Fc


def _sigma0_start(estimate: FrictionEstimate) -> float | None:
    """Dahl/LuGre ``sigma0`` from the tangent after reversals: the tangent of a Dahl branch
    at relative state ``r`` is ``sigma0 (1 + r)``."""
    if not estimate.tangent:
        return None
    return estimate.tangent / (1.0 + estimate.reversal_state)


class LuGre(FrictionBase):
    name = "lugre"
    summary = "LuGre friction (sigma0, sigma1, Fc, Fs, vs); viscous sigma2 v is the 'viscous' term"

    sigma0: float = 40e3
    sigma1: float = 200.0
    Fc: float = 15.0
    Fs: float = 18.0
    vs: float = 2e-3

    def params(self):
        return (_SIGMA0,
                Param("sigma1", "N s/m", 1.0, 0.0, np.inf, "bristle damping"),
                _FC,
                Param("Fs", "N", 1.0, 0.0, np.inf, "static (breakaway) friction level"),
                Param("vs", "mm/s", 1e-3, 0.0, np.inf, "Stribeck velocity"))

    def g(self, v):
        return self.Fc + (self.Fs - self.Fc) * jnp.exp(-((v / self.vs) ** 2))

    def init(self, drive):
        return drive.friction_state0 * self.Fs / self.sigma0

    def step(self, z, s: Step, drive, mod: Modulation):
        g = self.g(s.v) * mod.level_or()
        sigma = self.sigma0 * mod.slope_or()
        d = _direction(s.dx)
        z_ss = d * g / sigma
        z_new = z_ss + (z - z_ss) * jnp.exp(-sigma * jnp.abs(s.dx) / _divisor(g))
        z_dot = s.v - sigma * jnp.abs(s.v) * z_new / _divisor(g)
        return z_new, sigma * z_new + self.sigma1 * z_dot

    def start(self, estimate: FrictionEstimate, *, share: float = 1.0) -> LuGre:
        level = estimate.level * share
        new = dataclasses.replace(self, Fc=0.85 * level, Fs=level)
        sigma0 = _sigma0_start(estimate)
        return new if sigma0 is None else dataclasses.replace(new, sigma0=sigma0 * share)

    def presliding_slope(self):
        return self.sigma0

    def breakaway(self):
        return self.Fs

    def implausible(self) -> list[str]:
        """A static level below 0.9 times the sliding one: the breakaway below the sliding
        friction."""
        sliding, static = float(self.Fc), float(self.Fs)
        if static < 0.9 * sliding:
            return [f"the static friction Fs {static:.4g} N (the breakaway) is below the "
                    f"sliding friction Fc {sliding:.4g} N: not seal physics; the logs do not "
                    "determine the friction near rest (record slow starts from standstill) or "
                    "the model does not fit them"]
        return []


class MaxwellSlip(FrictionBase):
    name = "maxwell_slip"
    summary = "Maxwell-slip: N elasto-slide elements (k_i, slip displacement delta_i); 'maxwell_slip:N'"
    excitation = "nested minor loops (a small reversal inside a larger loop) or triangles of several amplitudes"
    lookalike = ("a hysteresis of the force sensor or of its mounting (the reading lagging the "
                 "force) draws the same loops: load the sensor alone with known weights, up and "
                 "down, to see whether it has one")

    k: jnp.ndarray = eqx.field(default_factory=lambda: jnp.full(4, 10e3))
    delta: jnp.ndarray = eqx.field(
        default_factory=lambda: jnp.asarray(np.linspace(0.18e-3, 0.72e-3, 4)))

    @classmethod
    def from_spec(cls, arg, *, drives=()):
        if arg is None:
            return cls()
        try:
            n = int(arg)
        except ValueError:
            n = 0
        if not 1 <= n <= 32:
            raise InputError(None, f"model term 'maxwell_slip:{arg}'",
                             "the number of elements must be a whole number from 1 to 32",
                             "write e.g. 'maxwell_slip:4'")
        return cls.with_elements(n)

    @classmethod
    def with_elements(cls, n: int, *, slope: float = 40e3, breakaway: float = 18.0):
        """``n`` equal-stiffness elements with evenly spread slip displacements that give the
        total ``slope`` (N/m) and ``breakaway`` (N)."""
        k = np.full(n, slope / n)
        shape = np.arange(1, n + 1, dtype=float)
        delta = shape * breakaway / (k * shape).sum()
        return cls(k=jnp.asarray(k), delta=jnp.asarray(delta))

    @property
    def token(self) -> str:
        n = int(np.shape(self.k)[0])
        return "maxwell_slip" if n == 4 else f"maxwell_slip:{n}"   # 4: the default

    def params(self):
        n = int(np.shape(self.k)[0])
        return (Param("k", "N/mm", 1e3, 0.0, np.inf, "element stiffness", size=n, null=0.0),
                Param("delta", "mm", 1e-3, 0.0, np.inf, "element slip displacement (W_i = k_i delta_i)",
                      transform="ordered", size=n))

    def start(self, estimate: FrictionEstimate, *, share: float = 1.0) -> MaxwellSlip:
        return self.with_elements(int(np.shape(self.k)[0]),
                                  slope=(estimate.tangent or 40e3) * share,
                                  breakaway=estimate.level * share)

    @property
    def slip_forces(self):
        return self.k * self.delta

    def init(self, drive):
        return drive.friction_state0 * self.slip_forces

    def step(self, F, s: Step, drive, mod: Modulation):
        w = self.slip_forces * mod.level_or()
        F_new = jnp.clip(F + self.k * mod.slope_or() * s.dx, -w, w)
        return F_new, jnp.sum(F_new)

    def presliding_slope(self):
        return jnp.sum(self.k)

    def breakaway(self):
        return jnp.sum(self.slip_forces)


class Coulomb(FrictionBase):
    name = "coulomb"
    summary = "static Coulomb friction Fc sgn(v) (no pre-sliding: infinite slope)"

    Fc: float = 18.0

    def params(self):
        return (_FC,)

    def init(self, drive):
        return jnp.sign(drive.friction_state0) * jnp.ones(())

    def step(self, direction, s: Step, drive, mod: Modulation):
        direction = jnp.where(s.dx != 0, _direction(s.dx), direction)
        return direction, self.Fc * mod.level_or() * direction

    def start(self, estimate: FrictionEstimate, *, share: float = 1.0) -> Coulomb:
        return dataclasses.replace(self, Fc=estimate.level * share)

    def presliding_slope(self):
        return jnp.inf

    def breakaway(self):
        return self.Fc
