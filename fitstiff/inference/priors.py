"""Priors of the posterior, one per sampled parameter, in physical (display) units.

Defaults, by the parameter's transform (:mod:`fitstiff.physics.params`):

============ ============================================================================
identity     ``flat`` (signed, unbounded: drift, force offsets)
log          ``log_normal`` of ``x - lower`` with its median at the model's starting value
             (the term's default for a spec string) and ``sd_log = ln 10``: a factor of 10
             per standard deviation, proper, and flat to within 0.5 % over a 1 % change
logit        ``uniform`` between the bounds (exponents, ratios, asymmetries)
ordered      ``log_normal`` of each increment over the previous element (the first over the
             lower bound), median at the starting increment, ``sd_log = ln 10``
============ ============================================================================

Per-log nuisances: the force offset (N) and, when fitted, the closing pressure (bar gauge)
are flat; the initial friction state is uniform in ``(-1, 1)``. The log-posterior adds the
log-Jacobian of the transforms, so these are densities of the physical values.

Overrides come from a JSON file (``--priors FILE``) or a mapping, keyed by parameter name
(``"offset"`` / ``"friction_state0"`` set every log's nuisance, ``"offset[p6]"`` one log's),
values in the parameter's display unit::

    {"sigma0": {"dist": "normal", "mean": 40, "sd": 10, "unit": "N/mm"},
     "n": {"dist": "uniform", "lower": 1.0, "upper": 1.4},
     "c": {"dist": "flat"}}

=============== =========================== =========================================
``dist``        arguments                   log density (up to a constant)
=============== =========================== =========================================
``flat``        --                          0 (within the parameter's bounds)
``uniform``     ``lower``, ``upper``        0 inside, -inf outside
``log_uniform`` ``lower`` > 0, ``upper``    ``-log x`` inside, -inf outside
``normal``      ``mean``, ``sd``            ``-(x - mean)**2 / (2 sd**2)``
``log_normal``  ``median``, ``sd_log``      ``-log x - (log x - log median)**2 / (2 sd_log**2)``
=============== =========================== =========================================

``unit`` is optional; when given it must be the parameter's display unit (as in fit.json).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from fitstiff._jax import jnp
from fitstiff.errors import InputError
from fitstiff.inference.nuisances import NUISANCE_PARAMS
from fitstiff.inference.problem import Problem
from fitstiff.io.validation import describe_type, read_json, shown
from fitstiff.physics.params import Parameterization, named_params

__all__ = ["DISTRIBUTIONS", "Prior", "Priors", "load_priors"]

#: distribution -> its arguments, in order
DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    "flat": (),
    "uniform": ("lower", "upper"),
    "log_uniform": ("lower", "upper"),
    "normal": ("mean", "sd"),
    "log_normal": ("median", "sd_log"),
}
_CODES = {name: i for i, name in enumerate(DISTRIBUTIONS)}
_SD_LOG = math.log(10.0)


@dataclasses.dataclass(frozen=True)
class Prior:
    """One parameter's prior in display units.

    Attributes:
        dist: a key of :data:`DISTRIBUTIONS`.
        args: its arguments in order (display units).
        unit: the display unit the arguments are in.
        on: ``"value"``, or ``"increment"`` for the defaults of ordered vectors (the density
            is of the element minus the previous one).
        shift: subtracted from the value (or increment) first (the lower bound of a ``log``
            parameter's default).
    """

    dist: str
    args: tuple[float, ...] = ()
    unit: str = ""
    on: str = "value"
    shift: float = 0.0

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"dist": self.dist,
                                  **dict(zip(DISTRIBUTIONS[self.dist], self.args)),
                                  "unit": self.unit}
        if self.on != "value":
            out["on"] = self.on
        if self.shift:
            out["shift"] = self.shift
        return out

    @classmethod
    def from_mapping(cls, data: object, *, name: str, unit: str, where: str | None) -> Prior:
        """Validate one JSON entry (see the module docstring)."""
        what = f"prior '{name}'"
        if not isinstance(data, Mapping):
            raise InputError(where, what, f"found {describe_type(data)}",
                             'give an object such as {"dist": "normal", "mean": 1, "sd": 0.1}')
        dist = data.get("dist")
        if dist not in DISTRIBUTIONS:
            raise InputError(where, what, f"unknown dist {shown(dist)}",
                             f"use one of: {', '.join(DISTRIBUTIONS)}")
        wanted = DISTRIBUTIONS[dist]
        extra = set(data) - set(wanted) - {"dist", "unit"}
        missing = [k for k in wanted if k not in data]
        if extra or missing:
            found = (f"unexpected {', '.join(sorted(extra))}" if extra
                     else f"missing {', '.join(missing)}")
            raise InputError(where, what, found,
                             f"'{dist}' takes {', '.join(wanted) or 'no arguments'}")
        given_unit = data.get("unit", unit)
        if given_unit != unit:
            raise InputError(where, what, f"unit {shown(given_unit)} differs from the parameter's "
                             f"display unit {unit!r}", f"write the values in {unit}")
        args = []
        for key in wanted:
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) or (key == "upper" and value == math.inf)):
                raise InputError(where, f"{what}, '{key}'", f"found {describe_type(value)}",
                                 "give a finite number")
            args.append(float(value))
        _check_args(dist, args, where=where, what=what)
        return cls(dist, tuple(args), unit)


def _check_args(dist: str, args: list[float], *, where: str | None, what: str) -> None:
    problems = {
        "uniform": lambda lo, hi: lo < hi or "needs lower < upper",
        "log_uniform": lambda lo, hi: (0 < lo < hi) or "needs 0 < lower < upper",
        "normal": lambda mean, sd: sd > 0 or "needs sd > 0",
        "log_normal": lambda median, sd: (median > 0 and sd > 0) or "needs median > 0 and "
                                                                   "sd_log > 0",
    }
    if dist in problems:
        verdict = problems[dist](*args)
        if verdict is not True:
            raise InputError(where, what, f"{dist} {args}", verdict)


def load_priors(path: str | os.PathLike) -> dict[str, Mapping[str, object]]:
    """Read a priors JSON file (validated against a problem by :class:`Priors`)."""
    path = Path(path)
    data = read_json(path, what="--priors",
                     example='{"sigma0": {"dist": "normal", "mean": 40, "sd": 10}}')
    if not isinstance(data, dict):
        raise InputError(str(path), "--priors", f"found a JSON {type(data).__name__}",
                         "write an object keyed by parameter name")
    return data


class Priors:
    """The priors of every entry of a problem's ``theta`` (defaults plus overrides).

    Args:
        problem: the problem whose :attr:`~fitstiff.inference.problem.Problem.names` are sampled.
        overrides: name -> :class:`Prior` or a JSON-style mapping, or the path of a JSON file.
    """

    def __init__(self, problem: Problem,
                 overrides: Mapping[str, Prior | Mapping[str, object]] | str | os.PathLike
                 | None = None):
        where = None
        if isinstance(overrides, (str, os.PathLike)):
            where = str(overrides)
            overrides = load_priors(overrides)
        self.names = tuple(problem.names)
        self.units, self.scales, defaults, previous = _defaults(problem)
        chosen = dict(defaults)
        for key, entry in (overrides or {}).items():
            targets = _targets(key, problem, where)
            for name in targets:
                unit = self.units[name]
                prior = entry if isinstance(entry, Prior) else Prior.from_mapping(
                    entry, name=key, unit=unit, where=where)
                chosen[name] = prior
                previous[name] = None
        self.priors: dict[str, Prior] = {n: chosen[n] for n in self.names}
        index = {n: i for i, n in enumerate(self.names)}
        priors = [self.priors[n] for n in self.names]
        self._code = np.array([_CODES[p.dist] for p in priors])
        args = [p.args + (0.0,) * (2 - len(p.args)) for p in priors]
        self._a = np.array([a[0] for a in args])
        self._b = np.array([a[1] for a in args])
        self._shift = np.array([p.shift for p in priors])
        self._previous = np.array([index[previous[n]] if previous.get(n) else -1
                                   for n in self.names])

    @property
    def key(self) -> tuple:
        """Hashable identity (for caching compiled functions)."""
        return tuple((n, p) for n, p in self.priors.items())

    def __eq__(self, other) -> bool:
        return isinstance(other, Priors) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)

    def to_dict(self) -> dict[str, dict[str, object]]:
        return {n: p.to_dict() for n, p in self.priors.items()}

    def to_display(self, physical, index=slice(None)):
        """SI values of the sampled names (last axis: ``names[index]``) -> display units: the
        model's parameters as :meth:`Param.to_display <fitstiff.physics.params.Param.to_display>`,
        the per-log nuisances by theirs
        (:data:`~fitstiff.inference.nuisances.NUISANCE_PARAMS`)."""
        return physical / self.scales[index]

    def log_density(self, physical):
        """Log prior density at the SI values ``physical`` (order of ``names``)."""
        return jnp.sum(self.log_densities(physical))

    def log_densities(self, physical):
        """Each entry's log prior density at the SI values ``physical``."""
        x = self.to_display(physical)
        before = jnp.where(self._previous >= 0, x[np.maximum(self._previous, 0)], 0.0)
        u = x - before - self._shift
        a, b, code = self._a, self._b, self._code
        inside = (u >= a) & (u <= b)
        positive = jnp.where(u > 0, u, 1.0)
        log_u = jnp.log(positive)
        dens = [
            jnp.zeros_like(u),                                                    # flat
            jnp.where(inside, 0.0, -jnp.inf),                                     # uniform
            jnp.where(inside, -log_u, -jnp.inf),                                  # log_uniform
            -0.5 * ((u - a) / jnp.where(code == 3, b, 1.0)) ** 2,                 # normal
            jnp.where(u > 0, -log_u - 0.5 * ((log_u - jnp.log(jnp.where(code == 4, a, 1.0)))
                                             / jnp.where(code == 4, b, 1.0)) ** 2,
                      -jnp.inf),                                                  # log_normal
        ]
        return jnp.select([code == i for i in range(len(dens))], dens)


def _defaults(problem: Problem):
    """Units, SI-per-display scales, default priors and the 'previous element' of ordered
    vectors, for every name of ``problem``."""
    units: dict[str, str] = {}
    scales: list[float] = []
    defaults: dict[str, Prior] = {}
    previous: dict[str, str | None] = {}
    free = set(problem.par.names)
    values = Parameterization(problem.model).values(problem.model)
    for _, p, names in named_params(problem.model):
        for e, name in enumerate(names):
            if name not in free:
                continue
            units[name] = p.unit
            scales.append(p.scale)
            lower = p.to_display(p.lower)
            start = p.to_display(values[name])
            if p.transform == "identity":
                defaults[name] = Prior("flat", unit=p.unit)
            elif p.transform == "logit":
                defaults[name] = Prior("uniform", (lower, p.to_display(p.upper)), p.unit)
            elif p.transform == "log" or e == 0:   # log, or the first of an ordered vector
                defaults[name] = Prior("log_normal", (max(start - lower, 1e-12), _SD_LOG),
                                       p.unit, shift=lower)
            else:   # ordered: increment over the previous element
                step = start - p.to_display(values[names[e - 1]])
                defaults[name] = Prior("log_normal", (max(step, 1e-12), _SD_LOG), p.unit,
                                       on="increment")
                previous[name] = names[e - 1]
    for nuisance in problem.nuisance_names:
        for log in problem.logs:
            name = f"{nuisance}[{log.name}]"
            p = NUISANCE_PARAMS[nuisance]
            bounded = math.isfinite(p.lower) and math.isfinite(p.upper)
            units[name] = p.unit
            scales.append(p.scale)
            defaults[name] = Prior("uniform" if bounded else "flat",
                                   (p.to_display(p.lower), p.to_display(p.upper)) if bounded
                                   else (), p.unit)
    return units, np.array(scales), defaults, previous


def _targets(key: str, problem: Problem, where: str | None) -> list[str]:
    names = problem.names
    if key in names:
        return [key]
    if key in problem.nuisance_names:
        return [f"{key}[{log.name}]" for log in problem.logs]
    if key in problem.par_fixed:
        raise InputError(where, f"prior '{key}'", "the parameter is fixed (--fix)",
                         "drop its prior or the --fix")
    raise InputError(where, f"prior '{key}'", "names no sampled parameter",
                     f"use one of: {', '.join(problem.par.names + problem.nuisance_names)}")
