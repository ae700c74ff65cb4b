"""Can the data separate the seal parameters? :func:`assess_identifiability` -> verdict.

A least-squares fit always returns numbers; whether they mean anything depends on the
excitation. Three checks, each with its reason in words (``fit.json`` ``identifiable``,
``identifiable_reason`` and ``identifiability``; one line on stdout; the report's verdict):

1. **No reversal.** Along one monotone stroke a Dahl seal ``(sigma0, Fc)`` started from the
   friction state ``z0 Fc`` draws ``Fc - Fc (1 - z0) exp(-sigma0 x / Fc)`` + offset: three
   numbers from four unknowns. ``(40 N/mm, 18 N, z0 = 0)`` and ``(20 N/mm, 9 N, z0 = -1)``
   (offset + 9 N) give the same curve, so the initial friction state trades off with the
   seal. Only a reversal, where the state is known from the fitted history, separates them.
   Without one: the pre-sliding slope, breakaway, pre-sliding range, total stiffness and every
   seal parameter get no standard error.
2. **No saturation.** If no stroke after a reversal travels past the fitted pre-sliding range
   (the travel in which the friction force makes 95 % of its swing), the friction force never
   levels off in the data: the breakaway is an extrapolation of the model's curve shape, not a
   measurement. The breakaway, the pre-sliding range and the seal's force-level parameters
   (unit N, or any the breakaway depends on) get no standard error; the slope right after a
   reversal is still measured.
3. **Near-null directions** of the Jacobian in *physical* coordinates (columns scaled to unit
   length), with the initial friction states taken as values in ``[-1, 1]``: a fit that ends
   with a state at saturation has a vanishing ``tanh`` derivative there, which hides the
   trade-off from the unconstrained covariance. A direction with eigenvalue below
   ``_NULL_EIGENVALUE`` that involves a seal parameter and moves a derived seal quantity
   (slope, breakaway, range) makes the fit not identifiable; the quantities it moves lose
   their standard errors.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

__all__ = ["Identifiability", "assess_identifiability", "reversal_travel", "SEAL_DERIVED"]

#: derived quantities that describe the seal (chamber stiffness does not)
SEAL_DERIVED = ("presliding_slope_N_per_mm", "breakaway_N", "presliding_range_mm",
                "total_stiffness_N_per_mm")
_SATURATION = 1.0          # travel after a reversal, in fitted pre-sliding ranges
_NULL_EIGENVALUE = 1e-6    # of the column-normalised J^T J: variance inflation 1e6
_INVOLVED = 0.1            # |component| of a null vector that involves a parameter
_MOVES = 0.05              # |g . v| / |g| above which a derived quantity is moved


@dataclasses.dataclass(frozen=True)
class Identifiability:
    """Whether the data separate the seal parameters, and if not, why and what it affects.

    Attributes:
        identifiable: False when any check failed.
        reasons: one sentence per failed check (what was found, what to record instead).
        parameters: flat parameter names whose standard errors are withheld.
        derived: derived quantities whose standard errors are withheld.
        reversals: genuine direction reversals over all logs (segmentation).
        longest_travel_mm: the longest travel after a reversal (``None`` without one).
        presliding_range_mm: the fitted pre-sliding range it is compared with.
        null_directions: near-null combinations of physical parameters, in words.
    """

    identifiable: bool
    reasons: tuple[str, ...] = ()
    parameters: tuple[str, ...] = ()
    derived: tuple[str, ...] = ()
    reversals: int = 0
    longest_travel_mm: float | None = None
    presliding_range_mm: float | None = None
    null_directions: tuple[str, ...] = ()

    @property
    def reason(self) -> str | None:
        """The reasons as one text; ``None`` when identifiable."""
        return " ".join(self.reasons) if self.reasons else None

    def line(self) -> str:
        """One line for stdout."""
        if not self.identifiable:
            return f"identifiable: NO - {self.reason}"
        if self.longest_travel_mm is None:
            return "identifiable: yes (no seal term)"
        return (f"identifiable: yes ({self.reversals} reversals; longest travel after one "
                f"{self.longest_travel_mm:.3g} mm, pre-sliding range "
                f"{self.presliding_range_mm:.3g} mm)")

    def to_dict(self) -> dict[str, object]:
        """``fit.json``'s ``identifiability`` details."""
        return {"reasons": list(self.reasons), "parameters": list(self.parameters),
                "derived": list(self.derived), "reversals": self.reversals,
                "longest_travel_after_reversal_mm": self.longest_travel_mm,
                "presliding_range_mm": self.presliding_range_mm,
                "null_directions": list(self.null_directions)}


def reversal_travel(displacements: Sequence[np.ndarray], reversals: Sequence[np.ndarray],
                    weights: Sequence[np.ndarray] | None = None) -> tuple[int, float | None]:
    """``(number of reversals, longest travel after one in m)`` over the logs; travel is the
    largest distance from a reversal reached before the next one (or the log's end), at a
    sample the fit uses (``weights`` > 0; all samples without ``weights``)."""
    count, longest = 0, None
    for k, (x, revs) in enumerate(zip(displacements, reversals)):
        x = np.asarray(x, dtype=float)
        used = (np.ones(x.shape[0], dtype=bool) if weights is None
                else np.asarray(weights[k]) > 0)
        revs = np.asarray(revs, dtype=int)
        count += revs.size
        ends = np.append(revs[1:], x.shape[0] - 1)
        for r, end in zip(revs, ends):
            seen = used[r:end + 1]
            if not seen.any():
                continue
            travel = float(np.max(np.abs(x[r:end + 1][seen] - x[r])))
            longest = travel if longest is None else max(longest, travel)
    return count, longest


def assess_identifiability(*, names: Sequence[str], seal: Sequence[str],
                           levels: Sequence[str], reversals: int,
                           longest_travel_m: float | None,
                           derived: Mapping[str, float], gram: np.ndarray | None = None,
                           derived_gradient: np.ndarray | None = None,
                           derived_names: Sequence[str] = ()) -> Identifiability:
    """The three checks of the module docstring.

    Args:
        names: flat names of the fitted entries (model parameters, then per-log nuisances).
        seal: the names among them that belong to the seal (friction bases, friction
            modifiers); empty for a model without friction.
        levels: the seal's force-level names (what a non-saturating log cannot determine).
        reversals, longest_travel_m: from :func:`reversal_travel`.
        derived: fitted derived quantities (needs ``presliding_range_mm``).
        gram: ``J^T J`` of the whitened residuals in physical coordinates (entries as
            ``names``, initial friction states as values in ``[-1, 1]``); ``None`` skips the
            third check.
        derived_gradient: ``(len(derived_names), len(names))`` gradient of the derived
            quantities in the same physical coordinates.
    """
    if not seal:
        return Identifiability(True)
    names = list(names)
    reasons: list[str] = []
    params: set[str] = set()
    affected: set[str] = set()
    prange = derived.get("presliding_range_mm")
    prange = float(prange) if prange is not None and np.isfinite(prange) else None
    travel_mm = None if longest_travel_m is None else longest_travel_m * 1e3
    seal_model = [n for n in seal if not n.startswith("friction_state0[")]
    if reversals == 0:
        reasons.append(
            "no log reverses direction: along one monotone stroke the initial friction state "
            "trades off with the seal (a Dahl seal (sigma0, Fc) starting at rest draws the same "
            "curve as (sigma0/2, Fc/2) starting from the opposite saturation), so the seal "
            "parameters are not separated; record back-and-forth strokes.")
        params.update(seal_model)
        affected.update(SEAL_DERIVED)
    elif prange is not None and travel_mm is not None and travel_mm < _SATURATION * prange:
        reasons.append(
            f"the seal never saturates: the longest travel after a reversal is "
            f"{travel_mm:.3g} mm, less than the fitted pre-sliding range {prange:.3g} mm, so "
            "the breakaway force is an extrapolation of the model's curve, not a measurement; "
            f"record at least one stroke longer than {_SATURATION * prange:.2g} mm after a "
            "reversal.")
        params.update(levels)
        affected.update(("breakaway_N", "presliding_range_mm"))
    nulls: list[str] = []
    if gram is not None and gram.size:
        nulls = _null_directions(names, set(seal_model), gram, derived_gradient,
                                 list(derived_names), params, affected)
        if nulls and not reasons:
            reasons.append("the data do not determine the combination "
                           + "; ".join(nulls) + " (a near-null direction of the Jacobian); "
                           "fix one of these parameters or record more varied motion.")
    return Identifiability(
        identifiable=not reasons, reasons=tuple(reasons),
        parameters=tuple(n for n in names if n in params),
        derived=tuple(d for d in derived if d in affected), reversals=reversals,
        longest_travel_mm=travel_mm, presliding_range_mm=prange, null_directions=tuple(nulls))


def _null_directions(names, seal, gram, gradient, derived_names, params, affected):
    """Near-null directions of the column-normalised ``gram`` that involve a seal parameter
    and move a derived seal quantity; adds what they involve / move to ``params`` /
    ``affected`` and returns them in words."""
    scale = np.sqrt(np.clip(np.diag(gram), 0.0, None))
    live = np.flatnonzero(scale > 0)
    if live.size == 0:
        return []
    normalised = gram[np.ix_(live, live)] / np.outer(scale[live], scale[live])
    eigenvalues, vectors = np.linalg.eigh(normalised)
    words = []
    for lam, v in zip(eigenvalues, vectors.T):
        if lam >= _NULL_EIGENVALUE:
            break
        involved = [live[k] for k in np.flatnonzero(np.abs(v) > _INVOLVED)]
        if not any(names[j] in seal for j in involved):
            continue
        moved = []
        if gradient is not None:
            g = gradient[:, live] / scale[live]
            norm = np.linalg.norm(g, axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                share = np.abs(g @ v) / norm
            moved = [d for d, s in zip(derived_names, share)
                     if d in SEAL_DERIVED and np.isfinite(s) and s > _MOVES]
        if not moved:
            continue
        params.update(names[j] for j in involved if names[j] in seal)
        affected.update(moved)
        words.append(" ".join(f"{v[k]:+.2f} {names[live[k]]}" for k in
                              np.flatnonzero(np.abs(v) > _INVOLVED)))
    return words
