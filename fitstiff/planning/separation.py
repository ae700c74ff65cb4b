"""How well a proposed program tells two rival models apart, after the rival refits.

A rival is a model fitted to the logs (:class:`Rival`): its values, its free parameters and
what the logs already say about them (the information matrix, the inverse of the fit's
covariance). On a program the rivals' predicted outputs (force, and the chamber pressures
where the logs record closed chambers) come from the same compiled simulator the fit uses
(:meth:`~fitstiff.physics.model.Model.run`).

The separation that survives refitting, linearised: if rival A is true, rival B is refitted
to the logs **and** the new record. Its misfit on the new record grows by

    lambda = min_d  |W (r - J d)|^2 + d' P d,      r = y_A - y_B  (whitened by W),

``J`` the derivative of B's prediction on the program by its free parameters and the new
record's nuisances (force offset, initial friction state), ``P`` the information the logs
already hold on B's parameters (none on the new record's nuisances). ``lambda`` is the
noncentrality of the likelihood-ratio test between the two on the new record; its square
root the expected z. A single candidate effect against its absence is the same computation
per unit of the effect's main parameter (``r`` the derivative of the prediction by it at its
null), which gives the smallest size the program detects (:func:`detectable_size`).

The noise is the logs' floor: per sample ``sigma`` with lag-one correlation ``rho``, whitened
as white noise of the AR(1) long-run variance ``sigma^2 (1 + rho) / (1 - rho)`` (conservative
for the slow differences the rivals make).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import numpy as np
from scipy import stats

from fitstiff._jax import jax, jnp
from fitstiff.physics.drive import Drive
from fitstiff.physics.model import Model
from fitstiff.physics.params import Parameterization

__all__ = ["Noise", "Rival", "Outputs", "outputs", "outputs_many", "LANES", "noncentrality",
           "detectable_size", "POWER", "LEVEL", "RCOND", "sizes"]

#: power and two-sided level at which :func:`detectable_size` states a size (the
#: diagnosis' detectability uses the same)
POWER = 0.8
LEVEL = 0.05
#: relative cut-off of the pseudo-inverses of information matrices
RCOND = 1e-10
#: the forward tangents of :func:`outputs` come in multiples of this many columns
_TANGENT_STEP = 4
#: drives :func:`outputs_many` runs in one call (16 programs of 10 000 samples: 0.010 s a
#: program against 0.062 s one at a time, 2 cores), fewer for long ones: at most
#: ``_LANE_SAMPLES`` samples a call
LANES = 16
_LANE_SAMPLES = 2_000_000


@dataclasses.dataclass(frozen=True)
class Noise:
    """The logs' noise floor: force ``sigma_N`` with lag-one correlation ``rho``; chamber
    pressures ``pressure_Pa`` (``None`` where the logs record no closed-chamber pressure)."""

    sigma_N: float
    rho: float = 0.0
    pressure_Pa: float | None = None

    def scale(self, sigma: float) -> float:
        """White-noise equivalent of ``sigma`` under this correlation (long-run variance)."""
        rho = min(max(self.rho, 0.0), 0.95)
        return sigma * math.sqrt((1 + rho) / (1 - rho))

    def to_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True, eq=False)
class Rival:
    """One explanation of the logs, fitted to them.

    Attributes:
        name: what it stands for (an effect name, or ``"absent"``).
        model: the fitted model (SI values in its fields).
        par: every parameter of the model (the held ones too: with the rivals of one plan
            fitted as masks of one super-model, the other rivals' effects at their nulls).
        free: per entry of ``par``: refitted on new data (free in the fit).
        information: ``P`` over the free entries, the information the logs hold on them
            (SI; :class:`~fitstiff.planning.rivals.Rivals` computes it), none where the logs
            determine nothing.
        values: every entry's fitted value (SI).
        cost: the fit's whitened sum of squares on the logs (for comparing rivals there).
    """

    name: str
    model: Model
    par: Parameterization
    free: np.ndarray
    information: np.ndarray
    values: np.ndarray
    cost: float = float("nan")


@dataclasses.dataclass(frozen=True)
class Outputs:
    """A rival's whitened outputs on one program and their derivatives: ``y`` (n,),
    ``jac`` (n, its free parameters, in the order of ``Rival.free``), ``nuisance`` (n, 2:
    force offset, initial friction state), ``along`` (n,: the derivative along the
    ``along`` direction asked of :func:`outputs`, or ``None``)."""

    y: np.ndarray
    jac: np.ndarray
    nuisance: np.ndarray
    along: np.ndarray | None = None


def _whitened(x, nuis, model, par, drive, weights):
    m = par.physical_to_model(x, model)
    d = dataclasses.replace(drive, force_offset=nuis[0], friction_state0=nuis[1])
    pred = m.run(d)
    parts = [pred.force * weights[0]]
    if weights.shape[0] > 1:
        parts += [pred.pressure_a * weights[1], pred.pressure_b * weights[1]]
    return jnp.concatenate(parts)


def _with_jacobian(x, tangents, nuis, model, par, drive, weights):
    """``y`` and its derivatives along the columns of ``tangents`` (``J @ tangents``, one
    forward tangent per column: a rival frees a few of the super-model's many entries) and
    by the nuisances."""
    def f(c, nuis):
        return _whitened(x + tangents @ c, nuis, model, par, drive, weights)

    c = jnp.zeros(tangents.shape[1])
    y = f(c, nuis)
    jc, jn = jax.jacfwd(f, argnums=(0, 1))(c, nuis)
    return y, jc, jn


@eqx.filter_jit
def _batched(x, tangents, nuis, model, par, drives, weights):
    """:func:`_with_jacobian` over a stack of drives (a leading axis on every array leaf)."""
    return eqx.filter_vmap(
        lambda drive: _with_jacobian(x, tangents, nuis, model, par, drive, weights))(drives)


def outputs(rival: Rival, drive: Drive, noise: Noise, *,
            along: np.ndarray | None = None) -> Outputs:
    """The rival's whitened outputs on ``drive`` and their derivatives by its free entries,
    by the new record's nuisances and (``along``, a vector over ``rival.par``) along one more
    direction."""
    return outputs_many(rival, [drive], noise, along=along)[0]


def outputs_many(rival: Rival, drives: Sequence[Drive], noise: Noise, *,
                 along: np.ndarray | None = None) -> list[Outputs]:
    """:func:`outputs` on each of ``drives``. Drives of one length and structure are run
    :data:`LANES` at a time as one ``vmap``-ed call (a plan scores its candidate programs so:
    the simulator's scan steps once for all of them), the last call of a group filled with
    copies, so that a group compiles once; a drive alone in its group runs alone. The
    tangents are padded with zero columns to a multiple of :data:`_TANGENT_STEP`, so the
    rivals of a plan share their compilations. (Derivatives by every entry of the
    super-model, one compilation for every rival, made the batched search slower:
    ``ool/saturating_pressure/1``'s 10.0 -> 17.0 s.)"""
    free = np.flatnonzero(rival.free)
    m = free.size + (along is not None)
    width = _TANGENT_STEP * max(1, -(-m // _TANGENT_STEP))
    tangents = np.zeros((rival.par.size, width))
    tangents[free, np.arange(free.size)] = 1.0
    if along is not None:
        tangents[:, free.size] = along
    x = jnp.asarray(rival.values, dtype=float)
    tangents = jnp.asarray(tangents)
    groups: dict[tuple, list[int]] = {}
    for i, drive in enumerate(drives):
        groups.setdefault((len(drive), jax.tree.structure(drive)), []).append(i)
    out: list[Outputs | None] = [None] * len(drives)
    for (n, _), index in groups.items():
        weights = [1.0 / noise.scale(noise.sigma_N)]
        if noise.pressure_Pa is not None and "closed" in drives[index[0]].modes:
            weights.append(1.0 / noise.scale(noise.pressure_Pa))
        weights = jnp.asarray(weights)
        lanes = 1 if len(index) == 1 else max(1, min(LANES, _LANE_SAMPLES // max(n, 1)))
        for k in range(0, len(index), lanes):
            chunk = index[k:k + lanes]
            batch = [drives[i] for i in chunk]
            batch += [batch[-1]] * (lanes - len(batch))
            stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *batch)
            y, jc, jn = _batched(x, tangents, jnp.zeros(2), rival.model, rival.par, stacked,
                                 weights)
            y, jc, jn = np.asarray(y), np.asarray(jc), np.asarray(jn)
            for lane, i in enumerate(chunk):
                out[i] = Outputs(y[lane], jc[lane, :, :free.size], jn[lane],
                                 jc[lane, :, free.size] if along is not None else None)
    return out


def noncentrality(r: np.ndarray, jac: np.ndarray, nuisance: np.ndarray,
                  information: np.ndarray, scale: np.ndarray) -> float:
    """``min_d |r - [J N] d|^2 + d_J' P d_J`` (whitened ``r``, ``J``, ``N``): how much a refit
    of the model with Jacobian ``J`` (its parameters already known to the information ``P``)
    and free nuisances ``N`` leaves of ``r``. ``scale`` (one per column of ``J``) conditions
    the solve (a parameter's size); the result does not depend on it."""
    s = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    a = np.concatenate([jac * s, nuisance], axis=1)
    prior = np.zeros((a.shape[1], a.shape[1]))
    prior[:s.size, :s.size] = information * np.outer(s, s)
    finite = np.all(np.isfinite(a), axis=0)
    a, prior = a[:, finite], prior[np.ix_(finite, finite)]
    h = a.T @ a + prior
    b = a.T @ r
    d = np.linalg.pinv(h, rcond=RCOND, hermitian=True) @ b
    left = float(r @ r - b @ d)
    return max(left, 0.0)


def detectable_size(per_unit: float, *, power: float = POWER, level: float = LEVEL) -> float:
    """The smallest size (in the unit ``per_unit`` was computed for) a two-sided test at
    ``level`` detects with ``power``, given the noncentrality of a unit size."""
    if not per_unit > 0:
        return math.inf
    z = stats.norm.isf(level / 2) + stats.norm.ppf(power)
    return float(z / math.sqrt(per_unit))


def sizes(values: Sequence[float]) -> np.ndarray:
    """Column scales for :func:`noncentrality`: each parameter's size (1e-3 of the largest
    where it is zero)."""
    v = np.abs(np.asarray(values, dtype=float))
    floor = 1e-3 * (v.max() if v.size and v.max() > 0 else 1.0)
    return np.maximum(v, floor)
