"""Colours and the checks every figure shares (the regions' and directions' colours, a log's run
of samples, per-sample values, a segmentation that belongs to its log)."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.segments.segmentation import Segmentation


__all__ = ["DIRECTION_COLORS", "REGION_COLORS"]

if TYPE_CHECKING:
    pass

REGION_COLORS: Mapping[str, str] = MappingProxyType({
    "presliding": "tab:orange", "sliding": "tab:blue", "dwell": "tab:red",
    "standstill": "tab:gray"})
"""Colour of each motion region (the partition :attr:`Segmentation.region`) in every figure.
The overlapping ``stroke_end`` flag is not drawn."""

MEASURED = "0.55"
MODEL = "tab:red"
NOT_FITTED = "0.85"
DIRECTION_COLORS: Mapping[str, str] = MappingProxyType({
    "toward B": "tab:green", "toward A": "tab:purple", "standing": "tab:gray"})
"""Colour of each direction of motion (:attr:`Segmentation.direction` +1, -1, 0)."""
BAND = "#f5c2c2"       # opaque, so a band the loop crosses twice is not darker there
ZOOM_PAD = 0.05        # of the force span in a zoom window


def run_of(samples: slice | None, log: Log) -> slice:
    if samples is None:
        return slice(None)
    if not isinstance(samples, slice) or samples.step not in (None, 1):
        raise InputError(log.name, f"samples {samples!r}", "is not a run of samples",
                         "give slice(start, stop), e.g. reversal_zoom_samples(...)")
    if len(range(*samples.indices(len(log)))) < 2:
        raise InputError(log.name, f"samples {samples.start}:{samples.stop}",
                         "hold fewer than two samples",
                         f"give a run within the log's {len(log)} samples")
    return samples


def samples_of(values: ArrayLike, log: Log, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.shape != (len(log),):
        raise InputError(log.name, what, f"has shape {a.shape}, the log {len(log)} samples",
                         "give one value per sample of the log")
    return a


def check_segmentation(segmentation: Segmentation, log: Log) -> None:
    if segmentation.n_samples != len(log):
        raise InputError(log.name, f"segmentation of '{segmentation.name}'",
                         f"has {segmentation.n_samples} samples, the log {len(log)}",
                         "pass the segmentation of this log "
                         "(fitstiff.segments.segmentation.segment)")
