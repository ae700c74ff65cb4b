"""The transform layer: parameter metadata, bounds and bijections to an unconstrained space.

Physics terms hold plain SI values in their fields; they know nothing about bounds. Each term
*declares* its parameters as :class:`Param` entries (display unit, bounds, transform, default,
null value), and :class:`Parameterization` maps a model to one flat unconstrained vector and
back, so the optimiser and the sampler see the same coordinates.

This module is also the one boundary between SI and display units for model parameters:
:meth:`Param.to_display` / :meth:`Param.to_si` for one parameter's value(s),
:meth:`Parameterization.to_display` / :meth:`Parameterization.to_si` for flat vectors of the
free parameters, :func:`to_display` / :func:`to_si` for values by flat name (free or fixed).
Code elsewhere converts through these, not by :attr:`Param.scale` itself (the priors extend
:meth:`Parameterization.scales` with the per-log nuisances' for their sampled vector).

Transforms (``y`` unconstrained, ``x`` physical, SI):

============ ================================================= ==========================
name         x(y)                                              use
============ ================================================= ==========================
identity     ``y``                                             signed, unbounded
log          ``lower + exp(y)``                                positive scales
logit        ``lower + (upper - lower) * sigmoid(y)``          bounded (exponents, ratios)
ordered      ``x_1 = lower + e^{y_1}, x_i = x_{i-1} + e^{y_i}`` increasing vectors
tanh         ``mid + half * tanh(y)`` (mid, half of the bounds) a log's initial friction state
scaled       ``y * scale`` (``y`` in the display unit)         a log's closing pressure (bar)
============ ================================================= ==========================

The per-log nuisances of an identification problem (force offset, initial friction state,
closing pressure) are :class:`Param` entries too (``fitstiff.inference.nuisances.NUISANCE_PARAMS``).
A ``scaled`` or ``identity`` transform has a constant log-Jacobian (:data:`CONSTANT_JACOBIAN`),
which a density may leave out.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable, Mapping

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError

__all__ = ["CONSTANT_JACOBIAN", "Param", "Parameterization", "TRANSFORMS", "find_param", "named_params", "to_display",
           "to_si"]

TRANSFORMS = ("identity", "log", "logit", "ordered", "tanh", "scaled")
#: transforms whose log-Jacobian does not depend on the value
CONSTANT_JACOBIAN = ("identity", "scaled")


@dataclasses.dataclass(frozen=True)
class Param:
    """Metadata of one (scalar or vector) physical parameter of a term.

    Attributes:
        field: attribute name on the term (SI value, or a 1-D array for vectors).
        unit: display unit (``"N/mm"``); ``scale`` converts: ``SI = display * scale``.
        lower, upper: bounds in SI (``-inf`` / ``inf`` for none).
        transform: one of :data:`TRANSFORMS`; chosen from the bounds when ``None``.
        null: the value at which the term has no effect (effects only), in SI.
        doc: one line.
        size: ``None`` for a scalar, else the vector length.
    """

    field: str
    unit: str
    scale: float
    lower: float
    upper: float
    doc: str
    transform: str | None = None
    null: float | None = None
    size: int | None = None

    def __post_init__(self):
        if self.transform is None:
            lo, hi = math.isfinite(self.lower), math.isfinite(self.upper)
            object.__setattr__(self, "transform",
                               "logit" if lo and hi else "log" if lo else "identity")
        if self.transform not in TRANSFORMS:
            raise ValueError(f"unknown transform {self.transform!r} for {self.field}")
        if self.transform in CONSTANT_JACOBIAN and (math.isfinite(self.lower)
                                                    or math.isfinite(self.upper)):
            raise ValueError(f"{self.field}: {self.transform} transform cannot honour bounds")
        if self.transform in ("logit", "tanh") and not (math.isfinite(self.lower)
                                                        and math.isfinite(self.upper)):
            raise ValueError(f"{self.field}: {self.transform} transform needs both bounds")

    @property
    def length(self) -> int:
        return 1 if self.size is None else self.size

    def element_names(self, prefix: str) -> list[str]:
        if self.size is None:
            return [prefix]
        return [f"{prefix}_{i + 1}" for i in range(self.size)]

    # -- units ----------------------------------------------------------------------------
    def to_display(self, si):
        """SI value(s) -> display unit (``si / scale``), elementwise over arrays (the elements
        of a vector parameter, samples); a Python number stays one."""
        return _array(si) / self.scale

    def to_si(self, display):
        """Display value(s) -> SI (``display * scale``): the inverse of :meth:`to_display`."""
        return _array(display) * self.scale

    # -- bijection, vectorised over the element axis ---------------------------------------
    def forward(self, y):
        """Unconstrained ``y`` (shape ``(length,)``) -> physical SI value(s)."""
        lo, hi = self.lower, self.upper
        if self.transform == "identity":
            return y
        if self.transform == "log":
            return lo + jnp.exp(y)
        if self.transform == "logit":
            # clipped: a saturated sigmoid would round one ulp past ``upper``
            return jnp.clip(lo + (hi - lo) * jax.nn.sigmoid(y), lo, hi)
        if self.transform == "tanh":
            return 0.5 * (lo + hi) + 0.5 * (hi - lo) * jnp.tanh(y)
        if self.transform == "scaled":
            return y * self.scale
        return lo + jnp.cumsum(jnp.exp(y))  # ordered

    def inverse(self, x) -> np.ndarray:
        """Physical SI value(s) -> unconstrained; values on a bound are nudged inside.

        NumPy, not traced: it maps concrete values (a start, a held value) into ``theta``.
        As JAX operations on concrete arrays, each would be compiled on its first use in a
        process: a cold ``fitstiff fit`` compiled about ten of them, 20-50 ms each."""
        x = np.asarray(x, dtype=float).reshape(self.length)
        lo, hi = self.lower, self.upper
        tiny = 1e-12
        if self.transform == "identity":
            return x
        if self.transform == "log":
            return np.log(np.maximum(x - lo, tiny * (1 + abs(lo))))
        if self.transform == "logit":
            f = np.clip((x - lo) / (hi - lo), 1e-9, 1 - 1e-9)
            return np.log(f) - np.log1p(-f)
        if self.transform == "tanh":
            u = (x - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
            return np.arctanh(np.clip(u, -1 + 1e-9, 1 - 1e-9))
        if self.transform == "scaled":
            return x / self.scale
        steps = np.diff(x, prepend=lo)
        return np.log(np.maximum(steps, tiny))

    def log_jacobian(self, y):
        """``log |det dx/dy|`` (for densities defined in physical space)."""
        if self.transform == "identity":
            return jnp.zeros(())
        if self.transform in ("log", "ordered"):
            return jnp.sum(y)
        lo, hi = self.lower, self.upper
        if self.transform == "tanh":
            return jnp.sum(math.log(0.5 * (hi - lo)) + jnp.log1p(-jnp.tanh(y) ** 2))
        if self.transform == "scaled":
            return jnp.sum(jnp.full(jnp.shape(y), math.log(self.scale)))
        return jnp.sum(math.log(hi - lo) + jax.nn.log_sigmoid(y) + jax.nn.log_sigmoid(-y))

    def check(self, value, *, where: str) -> None:
        """Raise an :class:`InputError` if ``value`` (SI) is outside the bounds."""
        v = np.atleast_1d(np.asarray(value, dtype=float))
        if not np.all(np.isfinite(v)) or np.any(v < self.lower) or np.any(v > self.upper):
            lo, hi = self.to_display(self.lower), self.to_display(self.upper)
            raise InputError(where, f"parameter '{self.field}'",
                             f"found {np.round(self.to_display(v), 6).tolist()} {self.unit}",
                             f"give a value within [{lo:g}, {hi:g}] {self.unit}")
        if self.transform == "ordered" and np.any(np.diff(v) < 0):
            raise InputError(where, f"parameter '{self.field}'",
                             f"found {np.round(self.to_display(v), 6).tolist()} {self.unit}",
                             "give an increasing sequence")


@dataclasses.dataclass(frozen=True)
class _Entry:
    name: str          # flat name, e.g. "sigma0" or "delta_1"
    term_index: int
    param: Param
    element: int | None  # index into a vector field, None for scalars
    offset: int        # position of the owning Param's first element in the flat vector


class Parameterization:
    """Flat unconstrained coordinates of a model's free parameters.

    ``names`` lists the free scalar names in order (vector parameters expand to
    ``k_1 ... k_N``; a name shared by two terms is qualified as ``term.field``). ``fixed``
    names keep the model's current value.

    >>> par = Parameterization(model, fixed=["n"])           # doctest: +SKIP
    >>> y = par.to_unconstrained(model)                       # doctest: +SKIP
    >>> model2 = par.to_model(y, model)                       # jit/vmap/grad friendly
    """

    def __init__(self, model, *, fixed: Iterable[str] = ()):
        fixed = set(fixed)
        groups = named_params(model)
        all_names = [n for _, _, names in groups for n in names]
        set_ = functools.partial(object.__setattr__, self)
        vector_bases = {_base(p, names) for _, p, names in groups if p.size}
        unknown = fixed - set(all_names) - vector_bases
        if unknown:
            raise InputError(None, f"--fix {', '.join(sorted(unknown))}",
                             "names no parameter of this model",
                             f"use one of: {', '.join(all_names)}")
        free: list[tuple[int, Param, int]] = []          # free (term index, param, offset)
        entries: list[_Entry] = []
        offset = 0
        for i, p, names in groups:
            base = _base(p, names)
            if base in fixed or all(n in fixed for n in names):
                continue
            if p.size and any(n in fixed for n in names):
                raise InputError(None, f"--fix {', '.join(n for n in names if n in fixed)}",
                                 f"fixes part of the vector parameter '{base}'",
                                 f"fix all of {base} or none")
            free.append((i, p, offset))
            for e, name in enumerate(names):
                entries.append(_Entry(name, i, p, None if p.size is None else e, offset))
            offset += p.length
        set_("_groups", tuple(free))
        set_("entries", tuple(entries))
        set_("size", offset)

    def __setattr__(self, name, value):
        raise AttributeError(f"a Parameterization is immutable: cannot set '{name}'")

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.entries]

    def units(self) -> dict[str, str]:
        return {e.name: e.param.unit for e in self.entries}

    def scales(self) -> np.ndarray:
        """SI per display unit of every free element (``SI = display * scale``)."""
        return np.array([e.param.scale for e in self.entries])

    def to_display(self, x):
        """Flat SI values of the free elements (last axis in the order of :attr:`names`; any
        leading axes, e.g. samples) -> display units."""
        return _array(x) / self.scales()

    def to_si(self, display):
        """Flat display values (last axis in the order of :attr:`names`) -> SI."""
        return _array(display) * self.scales()

    # -- maps -------------------------------------------------------------------------------
    def to_unconstrained(self, model) -> np.ndarray:
        """The unconstrained ``y`` of the model's free fields (NumPy; :meth:`Param.inverse`)."""
        parts = [p.inverse(getattr(model.terms[i], p.field)) for i, p, _ in self._groups]
        return np.concatenate(parts) if parts else np.zeros(0)

    def to_model(self, y, model):
        """The model with its free fields replaced by ``forward(y)`` (differentiable)."""
        terms = list(model.terms)
        for i, p, off in self._groups:
            value = p.forward(y[off:off + p.length])
            value = value[0] if p.size is None else value
            terms[i] = dataclasses.replace(terms[i], **{p.field: value})
        return model.with_terms(tuple(terms))

    def log_jacobian(self, y):
        total = jnp.zeros(())
        for _, p, off in self._groups:
            total = total + p.log_jacobian(y[off:off + p.length])
        return total

    def values(self, model) -> dict[str, float]:
        """Free parameter values (SI) by flat name."""
        out = {}
        for e in self.entries:
            v = np.asarray(getattr(model.terms[e.term_index], e.param.field), dtype=float)
            out[e.name] = float(v if e.element is None else v[e.element])
        return out

    def physical_to_model(self, x, model):
        """The model with its free fields set to the SI values ``x`` (flat, in the order of
        :attr:`names`), bypassing the transforms (differentiable).

        The physical-coordinates path: a score test differentiates here at a null value that
        sits on a bound (viscous ``c = 0``, Stribeck ratio 1), where the transform's
        derivative vanishes (``x = lower + exp(y)`` has ``dx/dy = 0`` as ``y -> -inf``).
        ``physical_to_model(physical(y), m)`` equals ``to_model(y, m)``.
        """
        terms = list(model.terms)
        for i, p, off in self._groups:
            value = x[off:off + p.length]
            value = value[0] if p.size is None else value
            terms[i] = dataclasses.replace(terms[i], **{p.field: value})
        return model.with_terms(tuple(terms))

    def nulls(self) -> np.ndarray:
        """Null value (SI) of every free element, NaN where its parameter has none."""
        return np.array([np.nan if e.param.null is None else e.param.null
                         for e in self.entries])

    def physical(self, y) -> jnp.ndarray:
        """Flat vector of SI values for unconstrained ``y`` (same order as :attr:`names`)."""
        parts = [p.forward(y[off:off + p.length]) for _, p, off in self._groups]
        return jnp.concatenate(parts) if parts else jnp.zeros(0)

    def with_values(self, model, values: Mapping[str, float], *, where: str | None = None):
        """Set parameters by flat name (SI); names may be fixed or free."""
        terms = list(model.terms)
        by_name = {n: (i, p, None if p.size is None else e)
                   for i, p, names in named_params(model) for e, n in enumerate(names)}
        touched: dict[tuple[int, str], tuple[Param, str]] = {}
        for name, value in values.items():
            if name not in by_name:
                raise _not_in_model(name, by_name, where)
            i, p, e = by_name[name]
            if e is None:
                new = float(value)
            else:
                new = np.array(getattr(terms[i], p.field), dtype=float)
                new[e] = float(value)
            terms[i] = dataclasses.replace(terms[i], **{p.field: new})
            touched.setdefault((i, p.field), (p, name))
        # checked once all values are in: an ordered vector set element by element passes
        # through orders that the final one does not have
        for (i, field), (p, name) in touched.items():
            p.check(getattr(terms[i], field), where=where or name)
        return model.with_terms(tuple(terms))


def named_params(model) -> list[tuple[int, Param, list[str]]]:
    """``(term index, Param, flat element names)`` for every declared parameter of ``model``.

    A field name used by two terms is qualified with the term name (``dahl.sigma0``).
    """
    count: dict[str, int] = {}
    for term in model.terms:
        for p in term.params():
            count[p.field] = count.get(p.field, 0) + 1
    return [(i, p, p.element_names(p.field if count[p.field] == 1 else f"{term.name}.{p.field}"))
            for i, term in enumerate(model.terms) for p in term.params()]


def find_param(model, name: str) -> Param:
    """The :class:`Param` behind a flat name (free or fixed); ``KeyError`` if none."""
    for _, p, names in named_params(model):
        if name in names:
            return p
    raise KeyError(name)


def to_display(model, values: Mapping[str, object], *, where: str | None = None) -> dict:
    """SI values by flat name (free or fixed parameters of ``model``; numbers or arrays) ->
    the same names in display units. An unknown name raises an :class:`InputError` naming the
    choices."""
    params = _by_name(model)
    return {name: _lookup(params, name, where).to_display(value)
            for name, value in values.items()}


def to_si(model, values: Mapping[str, object], *, where: str | None = None) -> dict:
    """Display values by flat name -> SI: the inverse of :func:`to_display`."""
    params = _by_name(model)
    return {name: _lookup(params, name, where).to_si(value) for name, value in values.items()}


def _by_name(model) -> dict[str, Param]:
    return {n: p for _, p, names in named_params(model) for n in names}


def _lookup(params: Mapping[str, Param], name: str, where: str | None) -> Param:
    if name not in params:
        raise _not_in_model(name, params, where)
    return params[name]


def _not_in_model(name: str, choices: Iterable[str], where: str | None) -> InputError:
    return InputError(where, f"parameter '{name}'", "is not in this model",
                      f"use one of: {', '.join(choices)}")


def _array(value):
    """Lists and tuples as arrays (for the unit conversions); numbers and arrays as given."""
    return np.asarray(value, dtype=float) if isinstance(value, (list, tuple)) else value


def _base(p: Param, names: list[str]) -> str:
    return names[0].rsplit("_", 1)[0] if p.size else names[0]
