"""A problem's data options as one record: which samples of each log are fitted, with what
weight, and how the logs are read.

:class:`Selection` holds the six options every fit, posterior, comparison, diagnosis and plan
passes to :class:`~fitstiff.inference.problem.Problem` (``denoise``, ``sample_range``,
``weights``, ``skip``, ``free``, ``exclude``). It is built once where a caller's keywords
enter the library (:meth:`Selection.pick` splits them from the solver's) and travels whole;
``fit.json`` records its fields under ``options`` and a re-opened run rebuilds it from there
(:meth:`Selection.pick` of the recorded options).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from fitstiff.errors import InputError
from fitstiff.segments.segmentation import REGIONS, Segmentation

__all__ = ["Selection", "PROBLEM_OPTIONS"]

#: the fields of :class:`Selection`, as keyword options of a fit (and keys of ``fit.json``'s
#: ``options``)
PROBLEM_OPTIONS = ("denoise", "sample_range", "weights", "skip", "free", "exclude")


@dataclasses.dataclass(frozen=True)
class Selection:
    """The data options of a problem.

    Attributes:
        denoise: replace each displacement by its reversal-preserving monotone estimate
            (:mod:`fitstiff.segments.denoise`) before driving the model. ``"auto"``: when the
            estimated displacement noise is above 0.05 um, or when the displacement turns
            where the segmentation finds no reversal (:func:`~fitstiff.segments.denoise.chatters`:
            a quantised encoder toggling by one count during a pause).
        sample_range: ``(start, stop)`` sample indices used in every log (others weigh 0).
        weights: extra weight per segmentation region, e.g. ``{"presliding": 4.0}``.
        skip: samples at the start of every log that drive the model but weigh 0 (a warm-up
            that settles the friction state).
        free: optional nuisances to fit: ``"closing_pressure"`` (each log's closing pressure
            of its closed chambers; ``supply_bar`` then only gives the start value).
        exclude: sample index ranges ``(start, stop)`` of every log that drive the model but
            weigh 0 (a glitch, or a block held out to be predicted).
    """

    denoise: bool | str = "auto"
    sample_range: tuple[int | None, int | None] | None = None
    weights: Mapping[str, float] | None = None
    skip: int = 0
    free: tuple[str, ...] = ()
    exclude: tuple[tuple[int, int], ...] = ()

    def __post_init__(self):
        if not (isinstance(self.denoise, (bool, np.bool_)) or self.denoise == "auto"):
            raise InputError(None, f"denoise {self.denoise!r}", "is not True, False or 'auto'",
                             "give denoise=True (on), False (off) or 'auto'")
        # lists (a JSON round trip, a caller's list) become tuples; the items of ``exclude``
        # are checked where they are used (Problem names a bad one)
        if self.sample_range is not None:
            object.__setattr__(self, "sample_range", tuple(self.sample_range))
        object.__setattr__(self, "free", tuple(self.free))
        object.__setattr__(self, "exclude", tuple(self.exclude))

    @classmethod
    def pick(cls, options: Mapping[str, object]) -> tuple[Selection, dict[str, object]]:
        """Split keyword options: the :class:`Selection` of those among
        :data:`PROBLEM_OPTIONS` and the others (a solver's, a sampler's) as they were."""
        mine = {k: v for k, v in options.items() if k in PROBLEM_OPTIONS}
        rest = {k: v for k, v in options.items() if k not in PROBLEM_OPTIONS}
        return cls(**mine), rest

    @classmethod
    def given(cls, selection: Selection | None, options: Mapping[str, object]) -> Selection:
        """``selection``, or the record of the keyword ``options`` (its field names); both
        at once, or a keyword that is not a field, is a ``TypeError``, as for any call."""
        unknown = set(options) - set(PROBLEM_OPTIONS)
        if unknown:
            raise TypeError(f"unexpected keyword argument(s): {', '.join(sorted(unknown))} "
                            f"(the data options are {', '.join(PROBLEM_OPTIONS)})")
        if selection is None:
            return cls(**options)
        if options:
            raise TypeError("give the data options either as a Selection or as keywords, "
                            f"not both (found selection= and {', '.join(sorted(options))})")
        return selection

    def replace(self, **changes) -> Selection:
        """A copy with ``changes`` (field names)."""
        return dataclasses.replace(self, **changes)

    def keywords(self) -> dict[str, object]:
        """The fields as keyword options (for :func:`~fitstiff.inference.fitting.fit`)."""
        return {name: getattr(self, name) for name in PROBLEM_OPTIONS}

    def to_dict(self) -> dict[str, object]:
        """The fields as JSON values (tuples as lists)."""
        return {"denoise": self.denoise,
                "sample_range": None if self.sample_range is None else list(self.sample_range),
                "weights": None if self.weights is None else dict(self.weights),
                "skip": self.skip, "free": list(self.free),
                "exclude": [list(item) for item in self.exclude]}

    def sample_weights(self, n: int, segmentation: Segmentation, *,
                       where: str | None) -> np.ndarray:
        """The weight of each of a log's ``n`` samples under this selection (``where``: the
        log's file or name, for messages)."""
        w = np.ones(n)
        if self.sample_range is not None:
            start, stop = self.sample_range
            keep = np.zeros(n, dtype=bool)
            keep[slice(start, stop)] = True
            w[~keep] = 0.0
        if self.skip:
            w[:self.skip] = 0.0
        for start, stop in _ranges(self.exclude):
            w[start:stop] = 0.0
        for region, factor in (self.weights or {}).items():
            if region not in REGIONS:
                raise InputError(None, f"--weight {region}={factor}", "unknown region",
                                 f"use one of: {', '.join(REGIONS)}")
            if factor < 0 or not math.isfinite(factor):
                raise InputError(None, f"--weight {region}={factor}", "negative or not finite",
                                 "give a weight >= 0")
            w[segmentation.mask(region)] *= factor
        if not np.any(w > 0):
            raise InputError(where, "sample selection", "leaves no sample with weight > 0",
                             "widen --range or lower --skip")
        return w


def _ranges(items: Iterable[Sequence[int]]) -> list[tuple[int, int]]:
    """``exclude``'s items as checked ``(start, stop)`` pairs."""
    out = []
    for item in items:
        try:
            start, stop = (int(v) for v in item)
        except (TypeError, ValueError):
            raise InputError(None, f"exclude {item!r}", "is not a (start, stop) pair of "
                             "sample indices", "give e.g. (1000, 2000)") from None
        if not 0 <= start < stop:
            raise InputError(None, f"exclude ({start}, {stop})", "is not a range of "
                             "sample indices with 0 <= start < stop",
                             "give e.g. (1000, 2000)")
        out.append((start, stop))
    return out
