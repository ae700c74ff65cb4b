"""The noise models by name: ``gaussian`` (:class:`Gaussian`), ``student_t``
(:class:`StudentT`) and ``ar1`` (:class:`AR1`), and reading one back (see
:mod:`fitstiff.inference.likelihood`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from scipy import stats

from fitstiff._jax import jnp
from fitstiff.errors import InputError
from fitstiff.inference.likelihood._quadratic import _Marginal, _Quadratic
from fitstiff.inference.likelihood.base import NoiseModel
from fitstiff.inference.likelihood.layout import Layout

__all__ = ["AR1", "NOISE_MODELS", "Gaussian", "StudentT", "noise_from_dict", "noise_model"]

_PHI_LIMIT = 0.999


@dataclasses.dataclass(frozen=True, kw_only=True)
class Gaussian(_Quadratic):
    """Independent Gaussian errors; ``sigma=None``: unknown scale per series, integrated out
    (Jeffreys prior); a number: the known standard deviation of the whitened residuals."""

    name: ClassVar[str] = "gaussian"
    sigma: float | None = None
    marginal: _Marginal | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        self._check_sigma()

    def whiten(self, residuals, layout: Layout):
        return jnp.where(layout.mask, residuals, 0.0)

    def series_scale(self, residuals, layout: Layout):
        if self.sigma is None:
            return jnp.sqrt(layout.per_series(residuals**2) / jnp.asarray(layout.counts))
        return jnp.full(len(layout.series), self.sigma)


@dataclasses.dataclass(frozen=True, kw_only=True)
class StudentT(NoiseModel):
    """Independent Student-t errors with ``nu`` degrees of freedom; ``scale`` per series
    (estimated from the median absolute residual when ``None``). Turning-point errors are not
    included (no closed-form marginal)."""

    name: ClassVar[str] = "student_t"
    nu: float = 4.0
    scale: tuple[float, ...] | None = None

    def __post_init__(self):
        if not (math.isfinite(self.nu) and self.nu > 0):
            raise InputError(None, "noise model 'student_t'", f"nu = {self.nu!r}",
                             "give degrees of freedom > 0 (4 is robust to outliers)")

    def prepared(self, residuals, layout, *, turning_points=None, linear=None):
        super().prepared(residuals, layout, linear=linear)
        if self.scale is not None:
            return self
        # the median |r| of a t_nu variable of scale s is s * t_nu.ppf(0.75)
        q = float(stats.t.ppf(0.75, self.nu))
        r = np.asarray(residuals)
        scale = tuple(float(np.median(np.abs(r[e.span][e.mask])) / q) for e in layout.series)
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
class AR1(_Quadratic):
    """Stationary AR(1) errors per series: ``phi`` per series (estimated from the lag-1
    regression of the least-squares residuals when ``None``), innovation scale integrated
    out (Jeffreys prior)."""

    name: ClassVar[str] = "ar1"
    phi: tuple[float, ...] | None = None
    marginal: _Marginal | None = dataclasses.field(default=None, repr=False)

    def _series_settings(self, keep):
        phi = self.phi
        if phi is None or np.ndim(phi) == 0 or len(phi) == 1:       # one value for all
            return {}
        return {"phi": tuple(phi[i] for i in keep)}

    def _estimated(self, residuals, layout):
        if self.phi is not None:
            return self
        prev = np.concatenate([[0.0], residuals[:-1]])
        phi = []
        for e in layout.series:
            f = layout.follows[e.span]
            a, b = residuals[e.span][f], prev[e.span][f]
            value = float(a @ b / (b @ b)) if b @ b > 0 else 0.0
            phi.append(float(np.clip(value, -_PHI_LIMIT, _PHI_LIMIT)))
        return dataclasses.replace(self, phi=tuple(phi))

    def whiten(self, residuals, layout: Layout):
        p = layout.broadcast(self._check_prepared("phi", layout))
        innovation = jnp.where(layout.follows, residuals - p * layout.previous(residuals),
                               jnp.sqrt(1.0 - p**2) * residuals)
        return jnp.where(layout.mask, innovation, 0.0)

    def series_scale(self, residuals, layout: Layout):
        phi = jnp.asarray(self._check_prepared("phi", layout))
        q = layout.per_series(self.whiten(residuals, layout) ** 2)
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
