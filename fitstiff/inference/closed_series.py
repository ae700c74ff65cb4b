"""Residual series in closed form: the closed chambers' pressures as polynomials in ``n``.

With the chamber's closed form (:meth:`Model.closed_form_chamber
<fitstiff.physics.model.Model.closed_form_chamber>`) the residual of a logged pressure is
``r = (p0 * exp(n * L) - measured) * w`` with a log volume ratio ``L`` fixed by the drive
(:func:`pressure_closed_forms`);
only the exponent ``n`` and the start pressure ``p0`` vary with ``theta``. Around a centre
``(n_c, p0_c)`` (the least-squares optimum), with ``d = n - n_c``::

    exp(n L) = exp(n_c L) * sum_k (d L)**k / k!
    r = R_0 + (p0 - p0_c) R_1 + sum_(k=1..K) p0 d**k R_(k+1)
    R_0 = (p0_c exp(n_c L) - measured) w,   R_(k+1) = exp(n_c L) L**k / k! w

exact to double precision with the ``K`` of :func:`taylor_terms` for ``|d L|`` up to
``max |d| * max |L|`` (``d`` between the bounds of ``n``). Every residual of the series is
then linear in the coefficients ``c(theta) = [1, p0 - p0_c, p0 d, ..., p0 d**K]``, so a
quadratic noise model's sum of squares of the series is ``c' G c`` with a Gram matrix ``G``
of the whitened columns made once (:meth:`~fitstiff.inference.likelihood._Quadratic.gram`, the
series' integrated columns reduced): ``(K + 2)**2`` multiply-adds per evaluation instead of
the model, the whitening and the sum over the series' samples. Centred, the columns' terms
are of the size of the noise near the optimum, so the quadratic form loses no precision to
cancellation (``measured`` against ``p0 exp(n L)`` uncentred: about 7 digits of ``q``).

:class:`ClosedFormLikelihood` evaluates a prepared quadratic noise model this way: the other
series (the force) from their residuals, the pressure series from their coefficients. The
posterior's sampler calls it (:class:`~fitstiff.inference.posterior.LogPosterior`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fitstiff._jax import jnp
from fitstiff.inference.likelihood import Layout, NoiseModel, _Quadratic
from fitstiff.inference.problem import Problem
from fitstiff.physics.terms import Chamber

__all__ = ["ClosedFormLikelihood", "PressureExpansion", "taylor_terms", "pressure_closed_forms"]

#: most Taylor terms of an expansion; wider ranges of ``n * L`` keep the residuals
MAX_TERMS = 20


def taylor_terms(bound: float) -> int | None:
    """Least ``K`` for which the Taylor polynomial of ``exp`` of degree ``K`` is exact to
    double precision (relative) on ``|u| <= bound``: the remainder ``bound**(K+1) / (K+1)!
    * exp(bound)`` over ``exp(-bound)`` below ``2**-53``. None beyond :data:`MAX_TERMS`."""
    if bound == 0.0:
        return 0
    limit = -53.0 * math.log(2.0) - 2.0 * bound
    for k in range(MAX_TERMS + 1):
        if (k + 1) * math.log(bound) - math.lgamma(k + 2) <= limit:
            return k
    return None


@dataclasses.dataclass(frozen=True, eq=False)
class PressureExpansion:
    """The pressure series of a problem as polynomials in ``d = n - n_c`` (module docstring).

    Attributes:
        series: ``(P,)`` positions of the pressure series in ``problem.residual_series()``.
        logs, chambers: ``(P,)`` each series' log and chamber (0: A, 1: B).
        columns: per series ``(length, K + 2)``: ``R_0 .. R_(K+1)`` over its span.
        centre_n: ``n_c``.
        centre_p0: ``(P,)`` ``p0_c`` of each series (absolute, Pa).
        max_shift: the largest ``|d|`` within the bounds of ``n`` (0 with ``n`` fixed);
            beyond it the coefficients are NaN, never a wrong value.
    """

    series: np.ndarray
    logs: np.ndarray
    chambers: np.ndarray
    columns: tuple[np.ndarray, ...]
    centre_n: float
    centre_p0: np.ndarray
    max_shift: float

    @property
    def terms(self) -> int:
        """``K``."""
        return self.columns[0].shape[1] - 2

    @classmethod
    def at(cls, problem: Problem, theta) -> PressureExpansion | None:
        """The expansion around ``theta``; None when the problem has no pressure series in
        closed form or ``n * L`` spans too wide a range for :func:`taylor_terms`."""
        forms = pressure_closed_forms(problem)
        if not forms:
            return None
        theta = jnp.asarray(theta)
        model, _ = problem.unpack(theta)
        chamber = model.closed_form_chamber()
        n_c = float(chamber.n)
        free = [e.param for e in problem.par.entries
                if e.param.field == "n" and model.terms[e.term_index] is chamber]
        max_shift = max(abs(free[0].lower - n_c), abs(free[0].upper - n_c)) if free else 0.0
        widest = max(float(np.max(np.abs(ratio), initial=0.0)) for _, _, ratio, _, _ in forms)
        terms = taylor_terms(max_shift * widest)
        if terms is None:
            return None
        starts = np.asarray(problem.closing_pressures(theta))
        logs = np.array([log for log, *_ in forms])
        chambers = np.array([c for _, c, *_ in forms])
        centre_p0 = starts[logs, chambers]
        columns = []
        for (_, _, ratio, measured, weight), p0 in zip(forms, centre_p0):
            power_c = np.exp(n_c * ratio)
            base = power_c * weight
            cols = [(p0 * power_c - measured) * weight, base]
            power = base
            for k in range(1, terms + 1):
                power = power * ratio / k
                cols.append(power)
            columns.append(np.stack(cols, axis=1))
        pressure = [i for i, e in enumerate(problem.residual_series())
                    if e.channel != "force"]
        if len(pressure) != len(forms):
            raise AssertionError("pressure series without a closed form")  # pragma: no cover
        return cls(np.asarray(pressure), logs, chambers, tuple(columns), n_c, centre_p0,
                   max_shift)

    def coefficients(self, problem: Problem, theta):
        """``(P, K + 2)`` coefficients of the columns at ``theta`` (JAX)."""
        model, _ = problem.unpack(theta)
        shift = model.closed_form_chamber().n - self.centre_n
        shift = jnp.where(jnp.abs(shift) <= self.max_shift * (1 + 1e-12), shift, jnp.nan)
        p0 = problem.closing_pressures(theta)[self.logs, self.chambers]
        powers = jnp.cumprod(jnp.full(self.terms, shift))
        return jnp.concatenate([jnp.ones_like(p0)[:, None], (p0 - self.centre_p0)[:, None],
                                p0[:, None] * powers[None, :]], axis=1)


@dataclasses.dataclass(frozen=True, eq=False)
class ClosedFormLikelihood:
    """A prepared quadratic noise model's log-likelihood of a problem, its pressure series
    in closed form (:class:`PressureExpansion`), the others (the force) from the residuals
    of their channels: the same value as ``noise.log_likelihood(problem.residuals(theta),
    layout)`` to rounding.

    Attributes:
        noise: the prepared noise model (all series).
        layout: all series.
        expansion: the pressure series.
        grams: ``(P, K + 2, K + 2)`` their Gram matrices.
        channels: the channels computed from residuals.
        rest: ``(S_r,)`` positions of their series in ``layout``.
        rest_layout, rest_noise: their layout, and ``noise`` restricted to them.
    """

    noise: _Quadratic
    layout: Layout
    expansion: PressureExpansion
    grams: np.ndarray
    channels: tuple[str, ...]
    rest: np.ndarray
    rest_layout: Layout
    rest_noise: _Quadratic

    @classmethod
    def of(cls, problem: Problem, noise: NoiseModel, theta,
           layout: Layout | None = None) -> ClosedFormLikelihood | None:
        """For a noise model prepared on ``problem`` (at ``theta``, the centre); None when
        the noise model is not quadratic or no series has a closed form."""
        if not isinstance(noise, _Quadratic):
            return None
        expansion = PressureExpansion.at(problem, theta)
        if expansion is None:
            return None
        layout = layout or Layout.from_problem(problem)
        grams = np.stack([noise.gram(c, s, layout)
                          for c, s in zip(expansion.columns, expansion.series)])
        channels = ("force",)
        rest = np.asarray([i for i, e in enumerate(layout.series) if e.channel in channels])
        if rest.size + expansion.series.size != len(layout.series):
            raise AssertionError("series neither closed nor computed")   # pragma: no cover
        series = problem.residual_series(channels)
        rest_layout = Layout.from_series(series, [layout.labels[i] for i in rest])
        rest_noise = noise.restricted(rest, layout, rest_layout)
        if (noise.marginal is not None
                and rest_noise.marginal.linear != noise.marginal.linear):   # pragma: no cover
            raise AssertionError("a linear nuisance acts on a closed series")
        return cls(noise, layout, expansion, grams, channels, rest, rest_layout, rest_noise)

    def log_likelihood(self, problem: Problem, theta):
        """The log-likelihood at ``theta`` (JAX; one row)."""
        residuals = problem.residuals(theta, channels=self.channels)
        return self.squares_likelihood(problem, residuals, theta)

    def squares_likelihood(self, problem: Problem, residuals, theta):
        """The log-likelihood from the residuals of :attr:`channels` at ``theta``."""
        return self.solved_likelihood(problem, residuals, theta)[0]

    def solved_likelihood(self, problem: Problem, residuals, theta):
        """``(log-likelihood, statistics)`` from the residuals of :attr:`channels` at
        ``theta``, as :meth:`~fitstiff.inference.likelihood._Quadratic.solved_likelihood` of every
        series (the linear nuisances act on the force series, computed from residuals)."""
        z, q_rest = self.rest_noise._solved(residuals, self.rest_layout)
        c = self.expansion.coefficients(problem, theta)
        q_closed = jnp.einsum("pi,pij,pj->p", c, jnp.asarray(self.grams), c)
        q = (jnp.zeros(len(self.layout.series), q_rest.dtype)
             .at[self.rest].set(q_rest).at[self.expansion.series].set(q_closed))
        return (self.noise.squares_likelihood(q, self.layout),
                self.rest_noise.linear_statistics(z, q))


def pressure_closed_forms(problem: Problem
                          ) -> list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]]:
    """Per pressure series of the problem's residuals (in order), when the model's pressures
    are their closed form (:meth:`Model.closed_form_chamber
    <fitstiff.physics.model.Model.closed_form_chamber>`) ``p = p0 * exp(n * log_ratio)``:
    ``(log, chamber (0: A, 1: B), log_ratio, measured, weight)``, NumPy arrays over the
    series' padded length, ``p0`` the log's
    :meth:`~fitstiff.inference.problem.Problem.closing_pressures`; the residual is
    ``(p - measured) * weight``. Empty when the pressures have no closed form."""
    if problem.model.closed_form_chamber() is None:
        return []
    out = []
    for g in problem.groups:
        ratios = [np.asarray(r) for r in Chamber.log_ratios(g.drive)]
        for c, measured in enumerate(g.pressure):
            if measured is None:
                continue
            for row, i in enumerate(g.index):
                out.append((i, c, ratios[c][row], np.asarray(measured[row]),
                            np.asarray(g.pressure_weight[c][row])))
    return out
