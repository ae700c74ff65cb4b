"""Gaussian errors with a per-series correlation (``gaussian``, ``ar1``): whitening, the
likelihood with the scale integrated out, and the Woodbury terms of the columns integrated
out (turning points, linear nuisances; see :mod:`fitstiff.inference.likelihood`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference.likelihood.base import NoiseModel
from fitstiff.inference.likelihood.layout import Layout


def _membership(index: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((index.size, size))
    out[np.arange(index.size), index] = mask
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class _Marginal:
    """Precomputed Woodbury terms of the columns integrated out (turning points with their
    N(0, 1) priors, linear nuisances with flat ones) for one prepared noise model.

    Every column lives in one series, so ``A`` is kept as one dense block per series that has
    columns (rows of the series' span x its columns): ``A'e`` then costs the series' length
    times its own columns, not the whole vector times all columns."""

    blocks: tuple[tuple[slice, np.ndarray], ...]   # (span, block) per series with columns
    order: np.ndarray      # (m + k,) column index of each block column, in block order
    inverse: np.ndarray    # (m + k, m + k) (P + A'A)^-1, P = diag(1 (turning), 0 (linear))
    series: np.ndarray     # (m + k,)
    flat: np.ndarray       # (S,) number of flat-prior columns per series
    linear: int = 0        # k: the last k columns are the linear nuisances

    @classmethod
    def build(cls, a: np.ndarray, precision: np.ndarray, series: np.ndarray, layout: Layout,
              *, linear: int) -> _Marginal:
        inverse = np.linalg.inv(np.diag(precision) + a.T @ a)
        blocks, order = [], []
        for s in np.unique(series):
            cols = np.flatnonzero(series == s)
            span = layout.series[s].span
            blocks.append((span, np.ascontiguousarray(a[span, cols])))
            order.extend(cols)
        flat = np.bincount(series[precision == 0], minlength=len(layout.series))
        return cls(tuple(blocks), np.asarray(order), inverse, series, flat, linear)

    def restricted(self, keep: np.ndarray, sub: Layout) -> _Marginal:
        """The terms of the series ``keep`` (positions in the layout built with, in order)
        alone, spans in ``sub`` (the layout of those series): exact, since ``(P + A'A)^-1``
        is block-diagonal by series (no column spans two)."""
        position = {int(s): j for j, s in enumerate(keep)}
        cols = np.flatnonzero(np.isin(self.series, keep))
        renumber = np.full(self.series.size, -1)
        renumber[cols] = np.arange(cols.size)
        blocks, order, start = [], [], 0
        for span, block in self.blocks:
            width = block.shape[1]
            s = int(self.series[self.order[start]])
            if s in position:
                blocks.append((sub.series[position[s]].span, block))
                order.extend(renumber[self.order[start:start + width]])
            start += width
        linear = int(np.sum(cols >= self.series.size - self.linear))
        return _Marginal(tuple(blocks), np.asarray(order, dtype=int),
                         self.inverse[np.ix_(cols, cols)],
                         np.asarray([position[int(s)] for s in self.series[cols]], dtype=int),
                         self.flat[np.asarray(keep, dtype=int)], linear)

    def project(self, e):
        """``A'e`` ``(m + k,)``."""
        parts = jnp.concatenate([e[span] @ jnp.asarray(block) for span, block in self.blocks])
        return jnp.zeros(self.order.size, parts.dtype).at[self.order].set(parts)

    def solve(self, e):
        """``(z, q)`` for whitened residuals ``e``: the most probable column coefficients
        ``z = -(P + A'A)^-1 A'e`` and the per-column-set reduction ``b'(P + A'A)^-1 b`` of the
        sum of squares, per entry of ``z`` (summed per series by the caller)."""
        b = self.project(e)
        mb = jnp.asarray(self.inverse) @ b
        return -mb, b * mb


class _Quadratic(NoiseModel):
    """Gaussian errors with a per-series correlation ``C`` and scale: :meth:`whiten` applies
    ``C^(-1/2)``; the scale is known (``sigma``) or integrated out (Jeffreys prior)."""

    sigma: float | None = None
    marginal: _Marginal | None = None
    integrates_linear: ClassVar[bool] = True

    def whiten(self, residuals, layout: Layout):
        raise NotImplementedError

    def _estimated(self, residuals: np.ndarray, layout: Layout) -> _Quadratic:
        return self

    def prepared(self, residuals, layout, *, turning_points=None, linear=None):
        model = self._estimated(np.asarray(residuals), layout)
        m = 0 if turning_points is None else turning_points.columns.shape[1]
        k = 0 if linear is None else linear.columns.shape[1]
        if not m + k:
            return model
        whiten = jax.vmap(lambda c: model.whiten(c, layout), in_axes=1, out_axes=1)
        parts, series = [], []
        if m:
            if model.sigma is None:
                e = model.whiten(jnp.asarray(residuals), layout)
                scale = np.sqrt(np.asarray(layout.per_series(e**2)) / layout.counts)
            else:
                scale = np.full(len(layout.series), model.sigma)
            parts.append(np.asarray(whiten(jnp.asarray(turning_points.columns)))
                         / scale[layout.segment, None])
            series.append(turning_points.series)
        if k:
            # flat prior: the column's scale does not matter
            parts.append(np.asarray(whiten(jnp.asarray(linear.columns))))
            series.append(linear.series)
        return dataclasses.replace(model, marginal=_Marginal.build(
            np.concatenate(parts, axis=1), np.r_[np.ones(m), np.zeros(k)],
            np.concatenate(series).astype(int), layout, linear=k))

    def squares(self, residuals, layout: Layout):
        """The per-series sums of squares of the whitened ``residuals``, with the turning
        points' errors and the integrated columns (if any) marginalised."""
        return self._solved(residuals, layout)[1]

    def _solved(self, residuals, layout: Layout):
        """``(z, q)``: the integrated columns' most probable coefficients (``None`` without
        any) and the per-series sum of squares with them integrated out."""
        e = self.whiten(residuals, layout)
        q = layout.per_series(e**2)
        if self.marginal is None:
            return None, q
        m = self.marginal
        z, reduction = m.solve(e)
        members = _membership(m.series, np.ones(m.series.size, bool), len(layout.series))
        return z, q - reduction @ members

    def restricted(self, keep: Sequence[int], layout: Layout, sub: Layout) -> _Quadratic:
        """This model for the series ``keep`` of ``layout`` alone (``sub``: their layout),
        e.g. those of one channel: the same likelihood terms for them."""
        keep = np.asarray(keep, dtype=int)
        marginal = None if self.marginal is None else self.marginal.restricted(keep, sub)
        return dataclasses.replace(self, marginal=marginal, **self._series_settings(keep))

    def _series_settings(self, keep: np.ndarray) -> dict[str, object]:
        """The per-series settings of the series ``keep`` (for :meth:`restricted`)."""
        return {}

    def gram(self, columns: np.ndarray, series: int, layout: Layout) -> np.ndarray:
        """``(K, K)`` ``G``: the sum of squares of ``series`` (its columns integrated out) is
        ``c' G c`` when its residuals are ``columns @ c`` (``columns``: ``(length, K)`` over
        the series' span)."""
        entry = layout.series[series]
        sub = Layout.from_series([entry._replace(span=slice(0, columns.shape[0]))],
                                 [layout.labels[series]])
        alone = self.restricted([series], layout, sub)
        whiten = jax.jit(jax.vmap(lambda c: alone.whiten(c, sub), in_axes=1, out_axes=1))
        v = np.asarray(whiten(jnp.asarray(columns)))
        g = v.T @ v
        m = alone.marginal
        if m is not None and m.blocks:         # its integrated columns: one block
            av = m.blocks[0][1].T @ v
            g = g - av.T @ m.inverse @ av
        return 0.5 * (g + g.T)

    def log_likelihood(self, residuals, layout: Layout):
        return self.squares_likelihood(self.squares(residuals, layout), layout)

    def squares_likelihood(self, q, layout: Layout):
        """The log-likelihood (up to a constant) of the per-series sums of squares ``q``
        ``(S,)`` (whitened, integrated columns reduced)."""
        if self.sigma is None:
            # the scale integrated out: q^(-(n - k)/2) with k flat columns in the series
            return -0.5 * jnp.sum(jnp.asarray(self.dof(layout)) * jnp.log(q))
        return -0.5 * jnp.sum(q) / self.sigma**2

    def dof(self, layout: Layout) -> np.ndarray:
        """Per series: data less the flat-prior columns integrated out of it."""
        flat = 0 if self.marginal is None else self.marginal.flat
        return np.asarray(layout.counts - flat)

    def solved_likelihood(self, residuals, layout: Layout):
        """``(log-likelihood, statistics)`` of ``residuals``: the log-likelihood and the
        :meth:`linear_statistics` of the integrated linear nuisances (JAX; one row)."""
        z, q = self._solved(residuals, layout)
        return self.squares_likelihood(q, layout), self.linear_statistics(z, q)

    def linear_statistics(self, z, q):
        """``[c, q]`` ``(k + S,)``: what :meth:`linear_draws` needs of one row, from its
        :meth:`_solved` ``(z, q)``: the integrated linear nuisances' most probable
        corrections ``c`` (the last ``k`` entries of ``z``) and the per-series sums of
        squares ``q``."""
        k = 0 if self.marginal is None else self.marginal.linear
        return q if not k else jnp.concatenate([z[z.shape[0] - k:], q])

    def linear_draws(self, statistics: np.ndarray, normal: np.ndarray,
                     chi2: np.ndarray) -> np.ndarray:
        """Draws of the integrated linear nuisances given the other entries, as corrections
        ``(rows, k)`` to the values the :meth:`linear_statistics` were computed at. Their
        conditional posterior is normal around the least-squares correction ``c`` with
        covariance ``s**2 (P + A'A)^-1``; the scale ``s`` of each series is drawn from its
        conditional ``q / chi2`` (NumPy, rows at once).

        Args:
            statistics: ``(rows, k + S)`` :meth:`linear_statistics` of each row.
            normal: ``(rows, m + k)`` standard normal deviates.
            chi2: ``(rows, S)`` chi-square deviates with :meth:`dof` degrees of freedom.
        """
        m = self.marginal
        k = m.linear
        c, q = statistics[:, :k], statistics[:, k:]
        s = np.sqrt(q / chi2) if self.sigma is None else np.full(q.shape, self.sigma)
        # the inverse is block-diagonal by series (no column spans two), so scaling the
        # deviates by their series' s first scales each block's draw by its own s
        root = np.linalg.cholesky(0.5 * (m.inverse + m.inverse.T))[m.series.size - k:]
        return c + (normal * s[:, m.series]) @ root.T

    def _check_sigma(self) -> None:
        if self.sigma is not None and not (math.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(None, f"noise model '{self.name}'", f"sigma = {self.sigma!r}",
                             "give a standard deviation > 0, or None for an unknown one")

