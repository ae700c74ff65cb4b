"""An unexplained structure's variable against its rivals, on a proposed program.

When a diagnosis ends with an unexplained structure that the logs cannot pin to one
variable (``Structure.confounded_with``: a curve along the position that is as well a level
per supply pressure, or per log), the question for the next rig run is which variable the
residual follows. Each side of that question is a **description** of the final model's
residual (:mod:`fitstiff.diagnosis.structure`, the same columns and penalised fit): the
variable the diagnosis named, in the form it named, and the rival variable in the form that
fits the logs best. Fitted on the logs, a description predicts a program from the program's
own values of its variable (the positions it travels, its supply, its speeds ...): the
program is described as one more log, whose columns the logs' fit already determines
(*shared*: a curve along the stroke, a line in the supply pressure), or not (*own*: a level
or a phase of the new log only, which its refit is free to take).

The separation is :mod:`fitstiff.planning.separation`'s, linearised: if description ``V``
is true, the rival ``R`` refits the logs and the new record (its shared columns with the
information the logs hold on them, its own columns free) together with the final model's
physics (its Jacobian on the program, its information from the logs) and the record's
nuisances; what it leaves of ``V - R`` is the noncentrality, and the same the other way.
The smaller of the two is the program's separation.

The residual described is the final model's fit to all the logs (in-sample; the diagnosis
described the held-out residual, which the plan does not recompute): the curves are a little
smaller than the diagnosis found, so the separation is, if anything, understated.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from fitstiff.diagnosis._structure_basis import Design, fit_predict, gate, ridge
from fitstiff.diagnosis._structure_forms import (Candidate, candidates, one_level_per_log,
                                                 structure_variables)
from fitstiff.diagnosis.structure import Structure
from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.segments.segmentation import Segmentation, segment
from fitstiff.planning.separation import Noise, Outputs, Rival, noncentrality, sizes

__all__ = ["Described", "DescribedPair", "Residuals", "supported"]

#: what :func:`structure_variables` gives besides the variables: the signs of the motion and
#: of the model force's change, and the force's travel since it last turned
_SIGNS = ("_motion", "_force", "_force_since_reversal")


@dataclasses.dataclass(frozen=True, eq=False)
class Residuals:
    """The final model's fit to the logs: per log its residual (model - measured, N), its
    predicted force (N), which samples count, and the logs' segmentations."""

    logs: tuple[Log, ...]
    residual: tuple[np.ndarray, ...]
    force: tuple[np.ndarray, ...]
    counted: tuple[np.ndarray, ...]
    segmentations: tuple[Segmentation, ...]

    def variables(self) -> list[dict[str, np.ndarray]]:
        """Each log's :func:`structure_variables` (the model force its prediction)."""
        return [structure_variables(log, seg, f)
                for log, seg, f in zip(self.logs, self.segmentations, self.force)]


@dataclasses.dataclass(frozen=True)
class Described:
    """One side of a structure confusion: ``variable`` in the form labelled ``label``
    (:attr:`~fitstiff.diagnosis._structure_forms.Candidate.label`), with the ``period`` a
    periodic one keeps."""

    variable: str
    label: str
    period: float | None = None


@dataclasses.dataclass(frozen=True)
class _OnProgram:
    """A description on a program: its prediction ``f`` (N, per program sample), its
    ``shared`` columns (N per unit of each) with the information the logs hold on them
    (whitened), its ``own`` columns (none of the logs' samples: free on new data), and
    where the logs support it."""

    f: np.ndarray
    shared: np.ndarray
    information: np.ndarray
    own: np.ndarray
    #: per program sample: whether the logs hold its value of the variable (:func:`supported`)
    support: np.ndarray


class DescribedPair:
    """The two descriptions of a structure confusion, fitted to the final model's residual
    on the logs and scored on programs.

    Args:
        structure: the accepted description of the diagnosis (its variable and form).
        rival: the variable it is confounded with.
        residuals: the final model's fit to the logs.
        final: the final model as a :class:`~fitstiff.planning.separation.Rival` (its
            physics refits on the new record).
        noise: the logs' noise floor.
    """

    def __init__(self, structure: Structure, rival: str, residuals: Residuals, final: Rival,
                 noise: Noise):
        self.residuals, self.final, self.noise = residuals, final, noise
        self._old = residuals.variables()
        self.sigma = noise.scale(noise.sigma_N)
        label = structure.form.split(" (period")[0]
        self.a = Described(structure.variable, label, structure.period)
        # the logs' samples and their candidate descriptions, built once for both steps
        stack = self._stack()
        cands = candidates(stack[0], stack[1])
        self.b = self._best_form(rival, stack, cands)
        self.rms_on_logs = self._rms_on_logs(stack, cands)

    @property
    def names(self) -> tuple[str, str]:
        return self.a.variable, self.b.variable

    def _stack(self, extra: Sequence[dict[str, np.ndarray]] = ()):
        """The logs' variables and ``extra`` logs' (a program, whose residual is unknown) as
        the structure step stacks them: per log the variables, per sample the log, whether
        it counts, whether it trains (the logs' counted samples), the residual, and the
        number of the logs' samples."""
        per_log = [*self._old, *extra]
        log_id = np.concatenate([np.full(next(iter(v.values())).size, k)
                                 for k, v in enumerate(per_log)])
        counted = np.concatenate([*(np.asarray(c, float) for c in self.residuals.counted),
                                  *(np.ones(next(iter(v.values())).size) for v in extra)])
        n_old = sum(c.size for c in self.residuals.counted)
        train = np.zeros(log_id.size, bool)
        train[:n_old] = counted[:n_old] > 0
        r = np.zeros(log_id.size)
        r[:n_old] = np.concatenate(self.residuals.residual)
        r = np.where(train, r, 0.0)
        return per_log, log_id, counted, train, r, n_old

    def _best_form(self, variable: str, stack, cands: Sequence[Candidate]) -> Described:
        """The form of ``variable`` that describes the logs' residual best (the least
        ``n log(RSS / n) + 2 dof``, as a form with more columns must earn them)."""
        _, log_id, counted, train, r, _ = stack
        best, out = math.inf, None
        for cand in cands:
            # a rival is one of the plain forms: a transition after each reversal is not
            # yet weighed on a program (its support is the travel, not the variable)
            if cand.variable != variable or cand.form == "transition":
                continue
            fit = fit_predict(Design(cand, log_id, counted), r, train, counted)
            rss = float(np.sum(counted * train * (r - fit.pred) ** 2))
            n = float(np.sum(train))
            score = n * math.log(max(rss, 1e-300) / n) + 2 * fit.dof
            if score < best:
                best, out = score, Described(variable, cand.label, fit.period)
        if out is None:
            raise InputError(None, f"the structure's rival '{variable}'",
                             "has no description on these logs",
                             "plan the library's confusions with --separate instead")
        return out

    def _rms_on_logs(self, stack, cands: Sequence[Candidate]) -> dict[str, float]:
        """The RMS (N) of the final model's residual on the logs, and of what each
        description leaves of it: a rival that leaves much more than the structure does
        describes the logs worse, and the separation overstates what a program settles."""
        _, log_id, counted, train, r, _ = stack
        w = counted * train
        out = {"final": math.sqrt(float(np.sum(w * r**2) / np.sum(w)))}
        for d in (self.a, self.b):
            _, x, beta = _fitted(d, cands, log_id, counted, train, r)
            left = r - x @ beta
            out[d.variable] = math.sqrt(float(np.sum(w * left**2) / np.sum(w)))
        return out

    def on(self, program: Log, model_force: np.ndarray) -> tuple[_OnProgram, _OnProgram]:
        """Both descriptions on ``program`` (a log of the program, its force the final
        model's prediction ``model_force``)."""
        seg = segment(program)
        extra = structure_variables(program, seg, np.asarray(model_force, float))
        per_log, log_id, counted, train, r, n_old = self._stack([extra])
        # the two variables' candidates only (and the signs they are taken with)
        keep = {self.a.variable, self.b.variable, *_SIGNS}
        cands = candidates([{k: v for k, v in p.items() if k in keep} for p in per_log],
                           log_id)
        return tuple(self._one(d, cands, log_id, counted, train, r, n_old)
                     for d in (self.a, self.b))

    def _one(self, d: Described, cands: Sequence[Candidate], log_id, counted, train, r,
             n_old) -> _OnProgram:
        cand, x, beta = _fitted(d, cands, log_id, counted, train, r)
        old, new = x[:n_old], x[n_old:]
        w = (counted * train)[:n_old]
        seen = np.any(old[w > 0] != 0.0, axis=0)
        shared, own = new[:, seen], new[:, ~seen]
        xs = old[:, seen] / self.sigma
        return _OnProgram(f=new @ beta, shared=shared, information=(xs.T * w) @ xs,
                          own=own, support=supported(cand, log_id[:n_old], w > 0, n_old))

    def separation(self, ob: Outputs, on: tuple[_OnProgram, _OnProgram], n: int
                   ) -> dict[str, object]:
        """The separation of the two descriptions on a program: ``ob`` the final model's
        outputs on it (whitened, ``n`` force samples first), ``on`` :meth:`on`'s."""
        va, vb = on
        known = va.support & vb.support
        va, vb = (dataclasses.replace(v, f=v.f * known, shared=v.shared * known[:, None],
                                      own=v.own * known[:, None]) for v in on)
        r = np.zeros(ob.y.size)
        r[:n] = (va.f - vb.f) / self.sigma
        # if a is true, b refits (and leaves lam[a] of the difference), and back
        lam = {self.a.variable: self._left(r, ob, vb, n),
               self.b.variable: self._left(-r, ob, va, n)}
        lam_min = min(lam.values())
        return {"objective": lam_min, "z": math.sqrt(lam_min), "noncentrality": lam_min,
                "noncentrality_if": lam, "supported_share": float(np.mean(known)),
                "forms": {self.a.variable: self.a.label, self.b.variable: self.b.label},
                "residual_rms_on_logs_N": dict(self.rms_on_logs),
                "force_difference_rms_N": float(np.sqrt(np.mean((va.f - vb.f) ** 2)))}

    def _left(self, r: np.ndarray, ob: Outputs, refit: _OnProgram, n: int) -> float:
        """What a refit of the physics and of the description ``refit`` leaves of ``r``."""
        rows = ob.y.size

        def padded(cols):
            out = np.zeros((rows, cols.shape[1]))
            out[:n] = cols / self.sigma
            return out

        shared, own = padded(refit.shared), padded(refit.own)
        m = self.final.information.shape[0]
        k = shared.shape[1]
        info = np.zeros((m + k, m + k))
        info[:m, :m] = self.final.information
        info[m:, m:] = refit.information
        jac = np.concatenate([ob.jac, shared], axis=1)
        scale = np.concatenate([sizes(self.final.values[self.final.free]), np.ones(k)])
        return noncentrality(r, jac, np.concatenate([ob.nuisance, own], axis=1), info, scale)


def supported(cand: Candidate, log_id: np.ndarray, train: np.ndarray, n_old: int
              ) -> np.ndarray:
    """Per program sample (the rows of ``cand`` after the logs' ``n_old``): whether the logs
    hold its value of the variable, so that a description predicts it rather than carries a
    curve past the logs' ends. Within some log's range of the variable; between the lowest
    and the highest level of a variable with one level per log (a supply pressure each: its
    line interpolates); always for a step (a level per log, per direction)."""
    new = cand.values[n_old:]
    if cand.form == "step":
        return np.ones(new.size, bool)
    old = cand.values[:n_old]
    ranges = [(float(old[m].min()), float(old[m].max()))
              for k in np.unique(log_id) if (m := (log_id == k) & train).any()]
    if not ranges:
        return np.zeros(new.size, bool)
    if one_level_per_log(old, log_id, train):
        ranges = [(min(lo for lo, _ in ranges), max(hi for _, hi in ranges))]
    tol = 1e-9 * max(1.0, max(abs(v) for r in ranges for v in r))
    return np.any([(new >= lo - tol) & (new <= hi + tol) for lo, hi in ranges], axis=0)


def _fitted(d: Described, cands: Sequence[Candidate], log_id: np.ndarray, counted: np.ndarray,
            train: np.ndarray, r: np.ndarray) -> tuple[Candidate, np.ndarray, np.ndarray]:
    """The candidate of ``d`` among ``cands``, its columns on every sample and its
    coefficients fitted to ``r`` on the ``train`` samples (a periodic one's period fitted
    there when ``d`` keeps none)."""
    cand = next((c for c in cands if c.variable == d.variable and c.label == d.label), None)
    if cand is None:
        raise InputError(None, f"the description '{d.label}' of {d.variable}",
                         "cannot be evaluated on the program",
                         "the program lacks what the variable needs (a time base, "
                         "a supply pressure)")
    design = Design(cand, log_id, counted)
    shape = d.period
    if cand.form == "periodic" and shape is None:
        shape = fit_predict(design, r, train, counted).period
    if cand.form == "gated":
        shape = gate(design, r, train, counted)
    x, pen = design.columns(train, shape)
    return cand, x, ridge(x, r, pen, counted * train)
