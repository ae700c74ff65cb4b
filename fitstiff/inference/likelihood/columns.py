"""Columns of the residual vector integrated out of a likelihood: the displacement errors at
the reversal samples (:class:`TurningPoints`) and the entries of ``theta`` the residuals are
linear in (:class:`LinearNuisances`); see :mod:`fitstiff.inference.likelihood`."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.inference.likelihood.layout import Layout
from fitstiff.inference.problem import Problem

__all__ = ["LinearNuisances", "TurningPoints"]


@dataclasses.dataclass(frozen=True, eq=False)
class TurningPoints:
    """Errors of the displacement at the reversal samples, as columns of the whitened residual
    vector (see :mod:`fitstiff.inference.likelihood`).

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
    of the residual vector, to be integrated out under flat priors (see
    :mod:`fitstiff.inference.likelihood`).

    Attributes:
        columns: ``(R, k)``: ``d r / d theta_j`` of each entry (exact: ``r`` is linear in it).
        series: ``(k,)`` the series each column lives in (one series per column).
        index: ``(k,)`` the entries' positions in ``theta``.
    """

    columns: np.ndarray
    series: np.ndarray
    index: np.ndarray

    @classmethod
    def at(cls, problem: Problem, theta, layout: Layout,
           index: Sequence[int]) -> LinearNuisances:
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
