"""Noise models: the likelihood of the whitened residuals of a :class:`~fitstiff.problem.Problem`.

The residual vector is cut into **series**, one per log and observed channel (force, and the
pressure of each closed chamber whose pressure is logged), each in time order
(:meth:`Problem.residual_series <fitstiff.problem.Problem.residual_series>`). Samples with
weight 0 (padding, ``--skip``, ``--range``) are not data: they enter no likelihood. Every
series has its own noise level and, for :class:`AR1`, its own correlation.

=============== ========================================================================
``gaussian``    independent Gaussian errors. ``sigma=None`` (default): one unknown scale
                per series, integrated out under the Jeffreys prior ``p(s) ~ 1/s``, so the
                series contributes ``-(n/2) log(sum r**2)`` (a Student-t marginal);
                ``sigma=1.0``: the per-log noise estimates used for whitening are taken as
                exact.
``student_t``   independent Student-t errors with ``nu`` degrees of freedom (default 4),
                robust to outliers. The scale of each series is estimated once, from the
                median absolute residual at the least-squares optimum.
``ar1``         stationary AR(1) errors ``e_k = phi e_(k-1) + s w_k`` per series, exact
                likelihood: each run of consecutive weighted samples starts from the
                stationary law and continues with the one-step conditionals (runs
                separated by zero-weight samples are independent). ``phi`` is
                estimated once per series at the least-squares optimum (from thousands of
                samples its uncertainty is ~ ``sqrt((1 - phi**2) / n)``, about 0.01, far below
                anything it influences), the innovation scale ``s`` is integrated out as for
                ``gaussian``: ``-(n/2) log(sum_first (1 - phi**2) r**2 + sum (r_k - phi
                r_(k-1))**2)``.
=============== ========================================================================

``ar1`` is the default of :func:`fitstiff.posterior.sample_posterior`; see that module for the
evidence.

A noise model is a small frozen dataclass. :meth:`prepared` fills in what it estimates from the
least-squares residuals (returning a new instance); :meth:`log_likelihood` is a pure JAX
function of the residual vector (``jit`` / ``vmap`` friendly).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from scipy import stats

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.problem import Problem, ResidualSeries

__all__ = [
    "AR1",
    "NOISE_MODELS",
    "Gaussian",
    "Layout",
    "NoiseModel",
    "StudentT",
    "noise_from_dict",
    "noise_model",
]

_PHI_LIMIT = 0.999


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """The residual vector of a problem cut into series (see the module docstring).

    Attributes:
        series: one :class:`~fitstiff.problem.ResidualSeries` per log and channel.
        labels: ``"<channel>[<log name>]"`` of each series.
        segment: ``(R,)`` series index of every residual.
        mask: ``(R,)`` the residual is data (weight > 0).
        follows: ``(R,)`` the residual and the one before it are both data, in one series.
        counts: ``(S,)`` number of data per series.
    """

    series: tuple[ResidualSeries, ...]
    labels: tuple[str, ...]
    segment: np.ndarray
    mask: np.ndarray
    follows: np.ndarray
    counts: np.ndarray

    @classmethod
    def from_problem(cls, problem: Problem) -> Layout:
        series = problem.residual_series()
        return cls.from_series(series, [f"{e.channel}[{problem.logs[e.log].name}]"
                                        for e in series])

    @classmethod
    def from_series(cls, series: Sequence[ResidualSeries], labels: Sequence[str]) -> Layout:
        """From series covering ``0 .. R`` contiguously, in order."""
        series = tuple(series)
        size = series[-1].span.stop
        segment = np.zeros(size, dtype=np.int32)
        mask = np.zeros(size, dtype=bool)
        follows = np.zeros(size, dtype=bool)
        for s, entry in enumerate(series):
            segment[entry.span] = s
            mask[entry.span] = entry.mask
            follows[entry.span][1:] = entry.mask[1:] & entry.mask[:-1]
        counts = np.array([int(e.mask.sum()) for e in series])
        return cls(series, tuple(labels), segment, mask, follows, counts)

    @property
    def size(self) -> int:
        return self.segment.shape[0]

    def per_series(self, values):
        """Sum of ``values`` (``(R,)``) over the data of each series -> ``(S,)``."""
        return jax.ops.segment_sum(jnp.where(self.mask, values, 0.0), jnp.asarray(self.segment),
                                   num_segments=len(self.series))

    def previous(self, r):
        """``r`` shifted by one sample (the residual before each entry; 0 for the first)."""
        return jnp.concatenate([jnp.zeros(1), r[:-1]])

    def broadcast(self, values) -> jnp.ndarray:
        """A per-series array ``(S,)`` spread to every residual ``(R,)``."""
        return jnp.asarray(values)[jnp.asarray(self.segment)]


class NoiseModel:
    """Interface of the noise models (see the module docstring)."""

    name: ClassVar[str]

    def prepared(self, residuals: np.ndarray, layout: Layout) -> NoiseModel:
        """This model with the settings it estimates from the least-squares residuals."""
        return self

    def log_likelihood(self, residuals, layout: Layout):
        """Log-likelihood of the whitened residual vector (up to a constant)."""
        raise NotImplementedError

    def series_scale(self, residuals, layout: Layout):
        """Per series: the marginal standard deviation of the errors, in whitened units, that
        best explains ``residuals`` (for reporting and predictive bands)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, **{f.name: _plain(getattr(self, f.name))
                                      for f in dataclasses.fields(self)}}

    def _check_prepared(self, field: str, layout: Layout) -> np.ndarray:
        values = getattr(self, field)
        if values is None:
            raise ValueError(f"{self.name}: call prepared() before evaluating the likelihood")
        values = np.broadcast_to(np.asarray(values, dtype=float), (len(layout.series),))
        return values


def _plain(value):
    if isinstance(value, tuple):
        return [float(v) for v in value]
    return value


def _rms(residuals, layout: Layout):
    return jnp.sqrt(layout.per_series(residuals**2) / jnp.asarray(layout.counts))


@dataclasses.dataclass(frozen=True, kw_only=True)
class Gaussian(NoiseModel):
    """Independent Gaussian errors; ``sigma=None``: unknown scale per series, integrated out
    (Jeffreys prior); a number: the known standard deviation of the whitened residuals."""

    name: ClassVar[str] = "gaussian"
    sigma: float | None = None

    def __post_init__(self):
        if self.sigma is not None and not (math.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(None, "noise model 'gaussian'", f"sigma = {self.sigma!r}",
                             "give a standard deviation > 0, or None for an unknown one")

    def log_likelihood(self, residuals, layout: Layout):
        squares = layout.per_series(residuals**2)
        if self.sigma is None:
            return -0.5 * jnp.sum(jnp.asarray(layout.counts) * jnp.log(squares))
        return -0.5 * jnp.sum(squares) / self.sigma**2

    def series_scale(self, residuals, layout: Layout):
        if self.sigma is None:
            return _rms(residuals, layout)
        return jnp.full(len(layout.series), self.sigma)


@dataclasses.dataclass(frozen=True, kw_only=True)
class StudentT(NoiseModel):
    """Independent Student-t errors with ``nu`` degrees of freedom; ``scale`` per series
    (estimated from the median absolute residual when ``None``)."""

    name: ClassVar[str] = "student_t"
    nu: float = 4.0
    scale: tuple[float, ...] | None = None

    def __post_init__(self):
        if not (math.isfinite(self.nu) and self.nu > 0):
            raise InputError(None, "noise model 'student_t'", f"nu = {self.nu!r}",
                             "give degrees of freedom > 0 (4 is robust to outliers)")

    def prepared(self, residuals: np.ndarray, layout: Layout) -> StudentT:
        if self.scale is not None:
            return self
        # the median |r| of a t_nu variable of scale s is s * t_nu.ppf(0.75)
        q = float(stats.t.ppf(0.75, self.nu))
        scale = tuple(float(np.median(np.abs(residuals[e.span][e.mask])) / q)
                      for e in layout.series)
        return dataclasses.replace(self, scale=scale)

    def log_likelihood(self, residuals, layout: Layout):
        s = layout.broadcast(self._check_prepared("scale", layout))
        terms = jnp.log1p((residuals / s) ** 2 / self.nu)
        return -0.5 * (self.nu + 1.0) * jnp.sum(jnp.where(layout.mask, terms, 0.0))

    def series_scale(self, residuals, layout: Layout):
        s = jnp.asarray(self._check_prepared("scale", layout))
        factor = math.sqrt(self.nu / (self.nu - 2.0)) if self.nu > 2 else math.inf
        return s * factor


@dataclasses.dataclass(frozen=True, kw_only=True)
class AR1(NoiseModel):
    """Stationary AR(1) errors per series: ``phi`` per series (estimated from the lag-1
    regression of the least-squares residuals when ``None``), innovation scale integrated
    out (Jeffreys prior)."""

    name: ClassVar[str] = "ar1"
    phi: tuple[float, ...] | None = None

    def prepared(self, residuals: np.ndarray, layout: Layout) -> AR1:
        if self.phi is not None:
            return self
        r = np.asarray(residuals)
        prev = np.concatenate([[0.0], r[:-1]])
        phi = []
        for e in layout.series:
            f = layout.follows[e.span]
            a, b = r[e.span][f], prev[e.span][f]
            value = float(a @ b / (b @ b)) if b @ b > 0 else 0.0
            phi.append(float(np.clip(value, -_PHI_LIMIT, _PHI_LIMIT)))
        return dataclasses.replace(self, phi=tuple(phi))

    def _quadratic(self, residuals, layout: Layout):
        phi = self._check_prepared("phi", layout)
        p = layout.broadcast(phi)
        innovation = jnp.where(layout.follows, residuals - p * layout.previous(residuals),
                               jnp.sqrt(1.0 - p**2) * residuals)
        return layout.per_series(innovation**2), jnp.asarray(phi)

    def log_likelihood(self, residuals, layout: Layout):
        q, _ = self._quadratic(residuals, layout)
        return -0.5 * jnp.sum(jnp.asarray(layout.counts) * jnp.log(q))

    def series_scale(self, residuals, layout: Layout):
        q, phi = self._quadratic(residuals, layout)
        return jnp.sqrt(q / jnp.asarray(layout.counts) / (1.0 - phi**2))


NOISE_MODELS: dict[str, type[NoiseModel]] = {m.name: m for m in (AR1, Gaussian, StudentT)}


def noise_model(spec: str | NoiseModel) -> NoiseModel:
    """A noise model from its name (``"ar1"``, ``"gaussian"``, ``"student_t"``) or as given."""
    if isinstance(spec, NoiseModel):
        return spec
    if spec not in NOISE_MODELS:
        raise InputError(None, f"--noise-model {spec}", "unknown noise model",
                         f"use one of: {', '.join(NOISE_MODELS)}")
    return NOISE_MODELS[spec]()


def noise_from_dict(data: Mapping[str, object]) -> NoiseModel:
    """Inverse of :meth:`NoiseModel.to_dict`."""
    cls = NOISE_MODELS[str(data["name"])]
    kwargs = {k: (tuple(v) if isinstance(v, Sequence) and not isinstance(v, str) else v)
              for k, v in data.items() if k != "name"}
    return cls(**kwargs)
