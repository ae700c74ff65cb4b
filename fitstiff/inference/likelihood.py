"""Noise models: the likelihood of the whitened residuals of a
:class:`~fitstiff.inference.problem.Problem`.

The residual vector is cut into **series**, one per log and observed channel (force, and the
pressure of each closed chamber whose pressure is logged), each in time order
(:meth:`Problem.residual_series <fitstiff.inference.problem.Problem.residual_series>`). Samples with
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

``ar1`` is the default of :func:`fitstiff.inference.posterior.sample_posterior`; see that module for
the evidence.

**Turning points** (``gaussian`` and ``ar1``). A displacement error at a reversal shifts the
whole branch after it (the denoiser keeps every sample between reversals on a monotone
estimate, but the extremum itself carries the sensor noise); least squares adds this
errors-in-variables term to its covariance (:mod:`fitstiff.inference.fitting`), and so does the
likelihood: :class:`TurningPoints` holds, per reversal sample ``k`` of each log, the column
``u_k = (d r / d x_k) sigma_x`` (the log's displacement noise) of the whitened force
residuals at the least-squares optimum, and the errors ``delta ~ N(0, I)`` along them are
integrated out: the covariance of a series is ``s**2 (C + W W')`` with ``C`` the noise
model's correlation and ``W = C^(-1/2) U / s_hat`` (``s_hat`` the noise scale at the optimum),
so with ``e = C^(-1/2) r``, ``v = W' e`` and ``M = (I + W'W)^-1`` the sum of squares above
becomes ``e'e - v'M v`` (Woodbury). The pressure channels' sensitivity to a micrometre at a
reversal (a few Pa against hundreds) is left out. ``student_t`` has no such closed form and
leaves the turning points out.

**Linear nuisances** (``gaussian`` and ``ar1``). The per-log force offsets enter the residuals
linearly (``r = r_0 + a c``), so under their flat priors they are integrated out exactly
instead of sampled (:class:`LinearNuisances`): their whitened columns ``G`` join ``W`` with
prior precision 0, ``A = [W, G]``, ``P = diag(1 (turning points), 0 (offsets))``, ``b = A'e``,
the sum of squares becomes ``q = e'e - b'(P + A'A)^-1 b`` and each series contributes
``-((n - k)/2) log q`` with ``k`` its flat columns (the Jeffreys-scale marginal loses one
degree of freedom per flat column). Sampling is then in fewer, better-conditioned coordinates;
:meth:`_Quadratic.linear_draws` draws the offsets from their exact conditional afterwards.

A noise model is a small frozen dataclass. :meth:`~NoiseModel.prepared` fills in what it
estimates from the least-squares residuals (returning a new instance);
:meth:`~NoiseModel.log_likelihood` is a pure JAX function of the residual vector (``jit`` /
``vmap`` friendly).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from scipy import stats

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference.problem import Problem, ResidualSeries

__all__ = [
    "AR1",
    "NOISE_MODELS",
    "Gaussian",
    "Layout",
    "LinearNuisances",
    "NoiseModel",
    "StudentT",
    "TurningPoints",
    "noise_from_dict",
    "noise_model",
]

_PHI_LIMIT = 0.999


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """The residual vector of a problem cut into series (see the module docstring).

    Attributes:
        series: one :class:`~fitstiff.inference.problem.ResidualSeries` per log and channel.
        labels: ``"<channel>[<log name>]"`` of each series.
        segment: ``(R,)`` series index of every residual.
        mask: ``(R,)`` the residual is data (weight > 0).
        follows: ``(R,)`` the residual and the one before it are both data, in one series.
        counts: ``(S,)`` number of data per series.

    Two layouts of the same series are equal (and hash alike): compiled functions specialised
    on a layout are shared by every layout of one problem.
    """

    series: tuple[ResidualSeries, ...]
    labels: tuple[str, ...]
    segment: np.ndarray
    mask: np.ndarray
    follows: np.ndarray
    counts: np.ndarray

    @functools.cached_property
    def _key(self) -> tuple:
        return (self.labels, tuple((s.log, s.channel, s.span.start, s.span.stop)
                                   for s in self.series), self.mask.tobytes())

    def __eq__(self, other) -> bool:
        return isinstance(other, Layout) and self._key == other._key

    def __hash__(self) -> int:
        return hash(self._key)

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
        """Sum of ``values`` (``(R,)``) over the data of each series -> ``(S,)``. Series of one
        length follow each other (one stack of logs per channel), so each such run is one
        reshape and a row sum (a product with the 0/1 membership matrix cost twice the time
        of the whole AR(1) whitening on four logs of 35 000 samples; scatter-adds more)."""
        values = jnp.where(self.mask, values, 0.0)
        return jnp.concatenate([values[start:start + count * length].reshape(count, length)
                                .sum(axis=1) for start, count, length in self.runs()])

    def runs(self) -> list[tuple[int, int, int]]:
        """``(start, count, length)``: consecutive series of equal length."""
        out: list[list[int]] = []
        for e in self.series:
            length = e.span.stop - e.span.start
            if out and out[-1][2] == length and out[-1][0] + out[-1][1] * length == e.span.start:
                out[-1][1] += 1
            else:
                out.append([e.span.start, 1, length])
        return [tuple(r) for r in out]

    def previous(self, r):
        """``r`` shifted by one sample (the residual before each entry; 0 for the first)."""
        return jnp.concatenate([jnp.zeros(1), r[:-1]])

    def broadcast(self, values: np.ndarray) -> np.ndarray:
        """Per-series settings ``(S,)`` spread to every residual ``(R,)``."""
        return np.asarray(values)[self.segment]


def _membership(index: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((index.size, size))
    out[np.arange(index.size), index] = mask
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class TurningPoints:
    """Errors of the displacement at the reversal samples, as columns of the whitened residual
    vector (see the module docstring).

    Attributes:
        columns: ``(R, m)``: ``d r / d x_k`` times the log's displacement noise for each
            reversal sample ``k`` with an effect, zero outside the force series.
        series: ``(m,)`` the force series each column belongs to.
    """

    columns: np.ndarray
    series: np.ndarray

    @classmethod
    def at(cls, problem: Problem, theta, layout: Layout) -> TurningPoints:
        """The columns at ``theta`` (one forward-mode Jacobian through the scan)."""
        scales = [np.asarray(s) for s in problem.reversal_noise()]
        where = [np.nonzero(s) for s in scales]
        sizes = [len(rows) for rows, _ in where]
        if not sum(sizes):
            return cls(np.zeros((layout.size, 0)), np.zeros(0, dtype=int))
        columns = np.array(problem.compiled(_turning_point_columns)(
            jnp.zeros(sum(sizes)), jnp.asarray(theta), tuple(where)))
        force = np.array([e.channel == "force" for e in layout.series])[layout.segment]
        columns[~force] = 0.0
        columns = columns[:, np.any(columns != 0.0, axis=0)]
        return cls(columns, layout.segment[np.argmax(np.abs(columns), axis=0)])


#: turning-point columns computed together (:func:`_turning_point_columns`)
_COLUMN_BLOCK = 16


def _turning_point_columns(p: Problem, delta, theta, where):
    """``d residuals / d delta`` at ``delta = 0``: ``delta`` moves the displacement at the
    reversal samples ``where`` (per group, ``(rows, cols)``) by multiples of their errors."""
    scales = p.reversal_noise()

    def residuals(delta):
        moved, start = [], 0
        for x, s, (rows, cols) in zip(p.displacements(), scales, where):
            k = rows.shape[0]
            bump = jnp.zeros(x.shape).at[rows, cols].set(delta[start:start + k] * s[rows, cols])
            moved.append(x + bump)
            start += k
        return p.residuals(theta, tuple(moved))

    # forward mode, a block of columns at a time: all of them at once held several
    # (columns x samples) intermediates (measured: four logs of 35 000 samples, +170 MB peak
    # for the closed-form Dahl over runs)
    basis = jnp.eye(delta.shape[0], dtype=delta.dtype)
    columns = jax.lax.map(lambda t: jax.jvp(residuals, (delta,), (t,))[1], basis,
                          batch_size=_COLUMN_BLOCK)
    return columns.T


@dataclasses.dataclass(frozen=True, eq=False)
class LinearNuisances:
    """Entries of ``theta`` the residuals are linear in (the per-log force offsets), as columns
    of the residual vector, to be integrated out under flat priors (see the module docstring).

    Attributes:
        columns: ``(R, k)``: ``d r / d theta_j`` of each entry (exact: ``r`` is linear in it).
        series: ``(k,)`` the series each column lives in (one series per column).
        index: ``(k,)`` the entries' positions in ``theta``.
    """

    columns: np.ndarray
    series: np.ndarray
    index: np.ndarray

    @classmethod
    def at(cls, problem: Problem, theta, layout: Layout, index: Sequence[int]) -> LinearNuisances:
        """The columns of ``theta[index]``: differences of the compiled residuals over a unit
        step of each entry (exact for a linear entry; a second step checks linearity). Raises
        ``ValueError`` when an entry's column spans more than one series or the residuals are
        not linear in it."""
        index = np.asarray(index, dtype=int)
        theta = np.asarray(theta, dtype=float)
        if not index.size:
            return cls(np.zeros((layout.size, 0)), np.zeros(0, dtype=int), index)
        residuals = problem.compiled(Problem.residuals)
        base = np.asarray(residuals(jnp.asarray(theta)))
        columns = np.empty((base.size, index.size))
        for j, i in enumerate(index):
            unit = np.arange(theta.size) == i
            steps = [np.asarray(residuals(jnp.asarray(theta + h * unit))) - base
                     for h in (1.0, 2.0)]
            columns[:, j] = steps[0]
            if not np.allclose(steps[1], 2.0 * steps[0], rtol=1e-9,
                               atol=1e-9 * (1.0 + np.abs(steps[1]).max())):
                raise ValueError(f"the residuals are not linear in {problem.names[i]}")
        series = []
        for j in range(index.size):
            touched = np.unique(layout.segment[columns[:, j] != 0.0])
            if touched.size != 1:
                raise ValueError(f"{problem.names[index[j]]} acts on {touched.size} series")
            series.append(int(touched[0]))
        return cls(columns, np.asarray(series, dtype=int), index)


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


class NoiseModel:
    """Interface of the noise models (see the module docstring)."""

    name: ClassVar[str]

    #: whether :meth:`prepared` can integrate linear nuisances out (``linear=``)
    integrates_linear: ClassVar[bool] = False

    def prepared(self, residuals: np.ndarray, layout: Layout, *,
                 turning_points: TurningPoints | None = None,
                 linear: LinearNuisances | None = None) -> NoiseModel:
        """This model with the settings it estimates from the least-squares residuals (and,
        where the model can, the turning-point errors and the ``linear`` nuisances
        integrated out)."""
        if linear is not None and linear.columns.shape[1]:
            raise ValueError(f"{self.name} cannot integrate linear nuisances out")
        return self

    def log_likelihood(self, residuals, layout: Layout):
        """Log-likelihood of the whitened residual vector (up to a constant)."""
        raise NotImplementedError

    def series_scale(self, residuals, layout: Layout):
        """Per series: the marginal standard deviation of the errors, in whitened units, that
        best explains ``residuals`` (for reporting and predictive bands)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, object]:
        """The settings as JSON types (:func:`noise_from_dict` reads them back)."""
        return {"name": self.name, **{f.name: _plain(getattr(self, f.name))
                                      for f in dataclasses.fields(self) if f.name != "marginal"}}

    def _check_prepared(self, field: str, layout: Layout) -> np.ndarray:
        values = getattr(self, field)
        if values is None:
            raise ValueError(f"{self.name}: call prepared() before evaluating the likelihood")
        return np.broadcast_to(np.asarray(values, dtype=float), (len(layout.series),))


def _plain(value):
    if isinstance(value, tuple):
        return [float(v) for v in value]
    return value


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

    def _squares(self, residuals, layout: Layout):
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
        return self.squares_likelihood(self._squares(residuals, layout), layout)

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
