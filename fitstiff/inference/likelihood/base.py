"""The interface every noise model implements (:class:`NoiseModel`)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from fitstiff.inference.likelihood.columns import LinearNuisances, TurningPoints
from fitstiff.inference.likelihood.layout import Layout

__all__ = ["NoiseModel"]


class NoiseModel:
    """Interface of the noise models (see :mod:`fitstiff.inference.likelihood`)."""

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
        """The settings as JSON types
        (:func:`~fitstiff.inference.likelihood.noise_from_dict` reads them back)."""
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
