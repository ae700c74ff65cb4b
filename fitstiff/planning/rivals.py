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
``undecided``   a candidate whose screen is significant on the final model but that the
                held-out rule did not accept, against its absence (or against another such
                candidate whose screen log p-value is within :data:`SCREEN_TIE` of its own);
                planned only when no tie, rival or untestable effect gets runs
                (:func:`deferred`);
``requested``   what the user named (``--separate a,b`` or ``--separate a``).

A pair of effects is fitted as the final model with the one in place of the other; a single
effect as the final model with the effect at its null (the separation is then computed per
unit of its main parameter).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff.diagnosis.result import Diagnosis
from fitstiff.diagnosis.supermodel import spec_token
from fitstiff.errors import InputError
from fitstiff.inference.fitting import fit
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import build_model, parse_spec
from fitstiff.physics.params import named_params
from fitstiff.physics.terms import TERMS
from fitstiff.planning.separation import Rival

__all__ = ["Confusion", "ABSENT", "KINDS", "confusions", "deferred", "Rivals"]

ABSENT = "absent"
KINDS = ("tie", "rival", "untestable", "undecided", "requested")
#: two undecided candidates whose screen log p-values differ by at most this share are a pair
#: the screen cannot order (heat exchange and a leak on closed chambers: 0.14 %)
SCREEN_TIE = 0.01


@dataclasses.dataclass(frozen=True)
class Confusion:
    """Two explanations the logs do not tell apart: ``separates`` is ``(a, b)`` (effect
    names, ``b`` may be :data:`ABSENT`), ``kind`` one of :data:`KINDS`, ``why`` in words."""

    kind: str
    separates: tuple[str, str]
    why: str

    @property
    def single(self) -> bool:
        return self.separates[1] == ABSENT


def confusions(diagnosis: Diagnosis, *, separate: Sequence[str] | None = None
               ) -> list[Confusion]:
    """The diagnosis' confusions, in the order of :data:`KINDS` (``separate``: the user's
    pair or single effect instead)."""
    if separate:
        names = list(dict.fromkeys(separate))
        unknown = [n for n in names if n not in TERMS]
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
    ones, while a tie, a rival or an untestable effect is there (:func:`~fitstiff.planning.plan`
    plans the deferred ones when the logs settle all of those, or no program can).

    What settles those comes first. A candidate significant on the final model while such a
    question stands may be its shadow: with one logged pressure, Maxwell-slip was significant
    in the place of the untestable pressure-dependent friction, and the runs planned for it
    fed a time delay, a look-alike, into the next diagnosis (benchmark set
    ``missing/pressure_friction/0``, docs/planning.md). The diagnosis of the new runs plans
    what is still undecided then."""
    roots = [c for c in found if c.kind in ("tie", "rival", "untestable")]
    if not roots:
        return list(found), []
    return ([c for c in found if c.kind != "undecided"],
            [c for c in found if c.kind == "undecided"])


class Rivals:
    """The rivals of confusions, fitted to the logs (one fit per model, cached).

    Args:
        logs: the diagnosis' logs.
        final_model: the diagnosis' final model spec (baseline plus accepted effects).
        seed: seeds the rival fits.
        selection: the diagnosis' data options (default: the defaults).
    """

    def __init__(self, logs: Sequence[Log], final_model: str, *, seed: int = 0,
                 selection: Selection | None = None):
        self.logs = list(logs)
        self.terms = [name for name, _ in parse_spec(final_model)]
        self.seed = seed
        self.selection = selection or Selection()
        self._fits: dict[tuple, Rival] = {}

    def spec(self, effects: Sequence[str], *, drop: Sequence[str] = ()) -> str:
        terms = [t for t in self.terms if t not in drop]
        return "+".join(spec_token(t) for t in terms + [e for e in effects if e not in terms])

    def fitted(self, name: str, spec: str, *, fix: Mapping[str, float | None] = {}) -> Rival:
        """The rival ``name``: ``spec`` fitted to the logs (one fit per spec and fixed
        values, whatever the name it is asked for under)."""
        key = (spec, tuple(sorted(fix.items())))
        if key not in self._fits:
            result = fit(self.logs, spec, fix=dict(fix), seed=self.seed,
                         **self.selection.keywords())
            if not result.converged:
                raise InputError(None, f"the rival fit of {spec}",
                                 f"did not converge ({result.message})",
                                 "check the logs fit the diagnosis' final model, or name "
                                 "the rivals with --separate")
            self._fits[key] = Rival.from_fit(name, result)
        return dataclasses.replace(self._fits[key], name=name)

    def pair(self, confusion: Confusion) -> tuple[Rival, Rival]:
        """Rivals ``a`` and ``b`` of a pair: the final model with each in place of both."""
        a, b = confusion.separates
        return (self.fitted(a, self.spec([a], drop=[b])),
                self.fitted(b, self.spec([b], drop=[a])))

    def single(self, effect: str):
        """``(rival, direction, name, param)``: the final model with ``effect`` at its null
        (``absent``), the direction of a unit (SI) of the effect's main parameter over the
        rival's entries (every element of a vector), the parameter's name and its
        :class:`~fitstiff.physics.params.Param`."""
        spec = self.spec([effect])
        model = build_model(spec)
        index = [i for i, t in enumerate(model.terms) if t.name == effect]
        if not index:
            raise InputError(None, f"--separate {effect}", "is not a term of this model",
                             "name an effect of the library")
        fix: dict[str, float | None] = {}
        main = None
        for i, p, names in named_params(model):
            if i != index[0]:
                continue
            for n in names:
                fix[n] = p.null if p.null is not None else None
            if p.null is not None and main is None:
                main = (p, names)
        if main is None:
            raise InputError(None, f"effect '{effect}'", "has no parameter with a null value",
                             "separate it from another effect instead")
        rival = self.fitted(ABSENT, spec, fix=fix)
        direction = np.array([1.0 if n in main[1] else 0.0 for n in rival.par.names])
        param, names = main
        return rival, direction, names[0] if param.size is None else param.field, param

