"""What a diagnosis could not settle, as pairs of rival explanations (:class:`Confusion`), and
the rivals fitted to the logs.

Kinds, in the order a plan takes them:

``tie``         two candidates passed on held-out data within a tie of each other, told apart
                only by their fits to all the data (``Candidate.tied_with``);
``rival``       an accepted effect and the strongest candidate its acceptance silenced: not
                accepted, but significant at the first screen, on the baseline's gap (both
                explain the same misfit; a look-alike read in its place is the failure the
                plan guards against);
``untestable``  a candidate the logs cannot test (no excitation: no pauses for dwell
                stiction, one pressure for pressure-dependent friction ...) against its
                absence;
``structure``   an unexplained structure's variable against a variable the logs cannot tell
                it from (``Structure.confounded_with``: a curve along the position that is
                as well a level per supply); both sides are descriptions of the final
                model's residual (:mod:`fitstiff.planning.descriptions`), not effects;
``undecided``   a candidate whose screen is significant on the final model but that the
                held-out rule did not accept, against its absence (or against another such
                candidate whose screen log p-value is within :data:`SCREEN_TIE` of its own);
                planned only when no tie, rival, untestable effect or structure gets runs
                (:func:`deferred`);
``requested``   what the user named (``--separate a,b`` or ``--separate a``).

A pair of effects is fitted as the final model with the one in place of the other; a single
effect as the final model with the effect at its null (the separation is then computed per
unit of its main parameter).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from functools import cached_property
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._choice import full_fit
from fitstiff.diagnosis._refit import refit_start
from fitstiff.diagnosis.diagnose import ALPHA, baseline_fit, noise_floors
from fitstiff.diagnosis.result import Diagnosis
from fitstiff.diagnosis.screen import screen
from fitstiff.diagnosis.select import MIN_GAIN
from fitstiff.diagnosis.structure import Structure
from fitstiff.diagnosis.supermodel import CANDIDATES, SuperProblem, spec_token
from fitstiff.errors import InputError
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import parse_spec
from fitstiff.physics.terms import EFFECTS
from fitstiff.planning.descriptions import Residuals
from fitstiff.planning.separation import RCOND, Rival

__all__ = ["Confusion", "ABSENT", "KINDS", "confusions", "deferred", "Rivals"]

ABSENT = "absent"
KINDS = ("tie", "rival", "untestable", "structure", "undecided", "requested")
#: two undecided candidates whose screen log p-values differ by at most this share are a pair
#: the screen cannot order (heat exchange and a leak on closed chambers: 0.14 %)
SCREEN_TIE = 0.01


@dataclasses.dataclass(frozen=True)
class Confusion:
    """Two explanations the logs do not tell apart: ``separates`` is ``(a, b)`` (effect
    names, ``b`` may be :data:`ABSENT`; for a ``structure``, the variables of
    :data:`~fitstiff.diagnosis.structure.VARIABLES`), ``kind`` one of :data:`KINDS`, ``why``
    in words."""

    kind: str
    separates: tuple[str, str]
    why: str
    #: the diagnosis' description, for a ``structure``
    structure: Structure | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def single(self) -> bool:
        return self.separates[1] == ABSENT

    @property
    def effects(self) -> tuple[str, ...]:
        """The library effects it separates (none for a structure's variables)."""
        return () if self.kind == "structure" else self.separates


def confusions(diagnosis: Diagnosis, *, separate: Sequence[str] | None = None
               ) -> list[Confusion]:
    """The diagnosis' confusions, in the order of :data:`KINDS` (``separate``: the user's
    pair or single effect instead)."""
    if separate:
        names = list(dict.fromkeys(separate))
        unknown = [n for n in names if n not in CANDIDATES]
        if unknown or not 1 <= len(names) <= 2:
            raise InputError(None, f"--separate {','.join(separate)}",
                             "names one or two effects" if not unknown else
                             f"'{unknown[0]}' is not an effect",
                             "give one effect (against its absence) or two, e.g. "
                             "--separate heat_transfer,leakage")
        pair = (names[0], names[1] if len(names) == 2 else ABSENT)
        return [Confusion("requested", pair, "asked for")]
    out: list[Confusion] = []
    m = max(len(diagnosis.candidates), 1)
    level = diagnosis.settings.get("alpha", 0.05) / m
    for c in diagnosis.candidates:
        if c.tied_with and not c.accepted and c.tied_with in diagnosis.accepted:
            out.append(Confusion("tie", (c.tied_with, c.effect),
                                 f"{c.effect} fitted the held-out data as well as "
                                 f"{c.tied_with}: the logs tell them apart by the fit to all "
                                 "the data only"))
    taken = {frozenset(c.separates) for c in out}
    for effect in diagnosis.accepted:
        silenced = sorted((c for c in diagnosis.candidates
                           if not c.accepted and c.first_p_value is not None
                           and c.first_p_value < level and c.testable
                           and frozenset((effect, c.effect)) not in taken),
                          key=lambda c: c.first_p_value)
        if silenced:
            c = silenced[0]
            out.append(Confusion("rival", (effect, c.effect),
                                 f"{c.effect} explained part of the baseline's gap too "
                                 f"(first screen p = {c.first_p_value:.2g}) until {effect} "
                                 "was accepted: the two may read one effect"))
            taken.add(frozenset((effect, c.effect)))
    for effect, entry in diagnosis.detectability.items():
        if not entry.get("testable", True) and effect not in diagnosis.accepted:
            out.append(Confusion("untestable", (effect, ABSENT),
                                 f"the logs cannot test {effect}: {entry.get('reason', '')}"))
    for u in diagnosis.unexplained_structure:
        if u.accepted:
            out += [Confusion("structure", (u.variable, other),
                              f"{u.size_N:.2g} N of the held-out residual follows the "
                              f"{u.variable.replace('_', ' ')} ({u.form}) or the "
                              f"{other.replace('_', ' ')}: the logs cannot tell them apart",
                              structure=u)
                    for other in u.confounded_with]
    # significant on the final model but not accepted, whatever the gap left: a real effect
    # can be certain in the screen and small in force (a leak at p = 1e-173 with the held-out
    # gap 1.5 % above the noise floor); two the screen cannot order are one pair
    undecided = sorted((c for c in diagnosis.candidates
                        if not c.accepted and c.testable and c.p_value < level
                        and not c.tied_with and not any(c.effect in x.separates for x in out)),
                       key=lambda c: c.log_p_value)
    planned: set[str] = set()
    for c in undecided:
        if c.effect in planned:
            continue
        twin = next((d for d in undecided if d.effect not in planned and d is not c
                     and abs(d.log_p_value - c.log_p_value) <= SCREEN_TIE * abs(c.log_p_value)),
                    None)
        if twin is None:
            out.append(Confusion("undecided", (c.effect, ABSENT),
                                 f"{c.effect} is significant on the final model "
                                 f"(p = {c.p_text}) but was not accepted: {c.why}"))
        else:
            out.append(Confusion("undecided", (c.effect, twin.effect),
                                 f"{c.effect} and {twin.effect} are both significant on the "
                                 f"final model (p = {c.p_text} and {twin.p_text}), the screen "
                                 "cannot order them, and neither was accepted"))
            planned.add(twin.effect)
        planned.add(c.effect)
    return out


def deferred(found: Sequence[Confusion]) -> tuple[list[Confusion], list[Confusion]]:
    """``found`` split into the confusions to plan first and those deferred: the undecided
    ones, while a tie, a rival, an untestable effect or a confounded structure is there
    (:func:`~fitstiff.planning.plan` plans the deferred ones when the logs settle all of
    those, or no program can).

    What settles those comes first. A candidate significant on the final model while such a
    question stands may be its shadow: with one logged pressure, Maxwell-slip was significant
    in the place of the untestable pressure-dependent friction, and the runs planned for it
    fed a time delay, a look-alike, into the next diagnosis (benchmark set
    ``missing/pressure_friction/0``, docs/planning.md). The diagnosis of the new runs plans
    what is still undecided then. So is a library candidate beside a structure the logs
    cannot pin to one variable (pressure-dependent friction beside a residual that follows
    the position or the supply pressure)."""
    roots = [c for c in found if c.kind in ("tie", "rival", "untestable", "structure")]
    if not roots:
        return list(found), []
    return ([c for c in found if c.kind != "undecided"],
            [c for c in found if c.kind == "undecided"])


class Rivals:
    """The rivals of confusions, fitted to the logs as masks of one compiled model.

    The final model without the confused effects is the base; the confused effects are the
    candidates of one :class:`~fitstiff.diagnosis.supermodel.SuperProblem` (the diagnosis'
    own super-model), so every rival is a set of candidates switched on: one compilation of
    its solves and Jacobian for all of them, a rival a solve. A rival is fitted as the
    diagnosis fits a model it enlarges: the base fitted to all the data, then each of the
    rival's effects added from its score screen's one-step start (:func:`refit_start`) and
    solved with the model (:func:`full_fit`). What the logs know about its free parameters is
    the Gauss-Newton information at the fit (the nuisances profiled out), from the residual
    variance widened by the residuals' AR(1) factor, as a fit's covariance is.

    Args:
        logs: the diagnosis' logs.
        final_model: the diagnosis' final model spec (baseline plus accepted effects).
        effects: every effect a rival may add or drop (those of the confusions to plan);
            each must be a candidate the diagnosis can name.
        selection: the diagnosis' data options (default: the defaults).
    """

    def __init__(self, logs: Sequence[Log], final_model: str, effects: Sequence[str], *,
                 selection: Selection | None = None):
        self.logs = list(logs)
        self.tokens = final_model.replace(" ", "").split("+")
        self.terms = [name for name, _ in parse_spec(final_model)]
        self.effects = tuple(dict.fromkeys(e for e in effects if e != ABSENT))
        unknown = [e for e in self.effects if e not in CANDIDATES]
        if unknown:
            raise InputError(None, f"--separate {unknown[0]}",
                             "is not an effect the diagnosis can name",
                             f"separate effects of the library: {', '.join(EFFECTS)}")
        self.selection = selection or Selection()
        self._base: _Fit | None = None
        self._fits: dict[frozenset, Rival] = {}
        self._thetas: dict[frozenset, np.ndarray] = {}

    @property
    def base_spec(self) -> str:
        """The final model without the confused effects."""
        return "+".join(t for t, name in zip(self.tokens, self.terms)
                        if name not in self.effects)

    @cached_property
    def sp(self) -> SuperProblem:
        """The base and the confused effects as one compiled problem."""
        return SuperProblem(self.logs, self.base_spec, self.effects, selection=self.selection)

    def _fit_base(self) -> _Fit:
        """The base fitted to all the data, and the noise floors read with its prediction,
        as the diagnosis reads them (once)."""
        if self._base is None:
            fit = baseline_fit(self.sp)
            noise, _ = noise_floors(self.sp, fit)
            self._base = _Fit(fit.theta, fit.hold, self.sp.baseline_terms, bool(fit.converged),
                              tuple(noise))
        return self._base

    def fitted(self, name: str, effects: Sequence[str]) -> Rival:
        """The rival ``name``: the base with ``effects`` (confused effects, in the order they
        are added) fitted to the logs; one fit per set of effects, whatever the name it is
        asked for under. Raises :class:`~fitstiff.errors.InputError` when a solve does not
        converge."""
        key = frozenset(effects)
        if key not in self._fits:
            sp, base = self.sp, self._fit_base()
            weights = sp.entry_weights()
            theta, hold, active, ok = base.theta, base.hold, list(base.active), base.converged
            for effect in effects:
                (s,), hold = screen(sp, theta, hold, active=active, candidates=[effect],
                                    noise=base.noise, weights=weights, alpha=ALPHA,
                                    min_gain=MIN_GAIN)
                start = refit_start(sp, s, theta, hold, active, weights)
                done = full_fit(sp, s, start, active, weights)
                theta, hold, ok = done.theta, done.hold, ok and done.converged
                active.append(effect)
            if not ok:
                spec = "+".join([self.base_spec, *(spec_token(e) for e in effects)])
                raise InputError(None, f"the rival fit of {spec}", "did not converge",
                                 "check the logs fit the diagnosis' final model, or name "
                                 "the rivals with --separate")
            self._fits[key] = _rival(name, sp, theta, hold, active)
            self._thetas[key] = np.asarray(theta)
        return dataclasses.replace(self._fits[key], name=name)

    def final(self) -> tuple[Rival, Residuals]:
        """The final model fitted to the logs, and its residuals there (what a structure's
        descriptions describe, :mod:`fitstiff.planning.descriptions`)."""
        effects = self._with()
        rival = self.fitted("final", effects)
        sp = self.sp
        forces = sp.forces(rival.values, self._thetas[frozenset(effects)])
        problem = sp.problem
        return rival, Residuals(
            logs=tuple(problem.logs),
            residual=tuple(np.asarray(f) - np.asarray(log.force)
                           for f, log in zip(forces, problem.logs)),
            force=tuple(np.asarray(f) for f in forces),
            counted=tuple(np.asarray(w) > 0 for w in problem.sample_weights),
            segmentations=tuple(problem.segmentations))

    def _with(self, add: Sequence[str] = (), drop: Sequence[str] = ()) -> list[str]:
        """The confused effects of the final model without ``drop``, then ``add``."""
        kept = [t for t in self.terms if t in self.effects and t not in drop]
        return kept + [e for e in add if e not in kept]

    def pair(self, confusion: Confusion) -> tuple[Rival, Rival]:
        """Rivals ``a`` and ``b`` of a pair: the final model with each in place of both."""
        a, b = confusion.separates
        return (self.fitted(a, self._with([a], drop=[b])),
                self.fitted(b, self._with([b], drop=[a])))

    def single(self, effect: str):
        """``(rival, direction, name, param)``: the final model with ``effect`` at its null
        (``absent``), the direction of a unit (SI) of the effect's main parameter over the
        rival's entries (every element of a vector), the parameter's name and its
        :class:`~fitstiff.physics.params.Param`."""
        if effect not in self.effects:
            raise InputError(None, f"--separate {effect}", "is not a term of this model",
                             "name an effect of the library")
        rival = self.fitted(ABSENT, self._with(drop=[effect]))
        par = self.sp.problem.par
        tested = self.sp.elements(effect, tested=True)
        if tested.size == 0:
            raise InputError(None, f"effect '{effect}'", "has no parameter with a null value",
                             "separate it from another effect instead")
        param = par.entries[tested[0]].param
        main = [k for k in tested if par.entries[k].param is param]
        direction = np.zeros(len(par.names))
        direction[main] = 1.0
        name = par.names[main[0]] if param.size is None else param.field
        return rival, direction, name, param


class _Fit(NamedTuple):
    """The base fitted to all the data, and the logs' noise floors read with its prediction."""

    theta: np.ndarray
    hold: np.ndarray
    active: tuple[str, ...]
    converged: bool
    noise: tuple


def _rival(name: str, sp: SuperProblem, theta, hold, active) -> Rival:
    """A :class:`Rival` from a fit of the super-model with ``active`` terms: the super-model
    with the other candidates at their nulls, and the information on its free entries (the
    Gauss-Newton matrix over them and the nuisances, the nuisances profiled out, divided by
    the residual variance widened by the AR(1) factor, as :func:`fitted_sizes` reads it)."""
    par = sp.problem.par
    free = sp.model_mask(active)
    x = np.asarray(sp.physical(theta, hold, free), dtype=float)
    r, jac = sp.jacobian(x, theta)
    keep = sp.entry_weights() > 0
    rf = r[keep]
    model_cols = np.flatnonzero(free)
    cols = np.concatenate([model_cols, sp.n_model + np.flatnonzero(sp.nuisance_mask())])
    jf = jac[keep][:, cols]
    finite = np.all(np.isfinite(jf), axis=0)
    jf = np.where(finite, jf, 0.0)
    dof = max(rf.size - int(finite.sum()), 1)
    rho = float(np.clip(np.corrcoef(rf[:-1], rf[1:])[0, 1], 0.0, 0.99)) if rf.size > 2 else 0.0
    h = jf.T @ jf / (float(rf @ rf) / dof * (1.0 + rho) / (1.0 - rho))
    m = model_cols.size
    info = h[:m, :m] - h[:m, m:] @ np.linalg.pinv(h[m:, m:], rcond=RCOND,
                                                  hermitian=True) @ h[m:, :m]
    info[~finite[:m], :] = 0.0
    info[:, ~finite[:m]] = 0.0
    model = par.physical_to_model(x, sp.problem.model)
    return Rival(name, model, par, free, info, x, float(rf @ rf))
