""":func:`plan`: the next rig run that settles what a diagnosis could not, as programs.

For each confusion of the diagnosis (:mod:`fitstiff.planning.rivals`), the rivals are fitted
to the logs and every gridded program of the limits (:mod:`fitstiff.planning.families`) is
scored by the separation that survives the rivals' refits
(:mod:`fitstiff.planning.separation`, or for a structure's variable against its rivals
:mod:`fitstiff.planning.descriptions`): first every shape at the logs' median supply and at
the allowed supply farthest from it, from a logged start position (the middle one), then the
best shapes at every allowed supply and three start positions (and every logged start, for a
structure). The best program is kept, with the naive alternative of the same duration
(the longest log replayed) scored the same way for comparison. Deterministic: a grid, no
random draws (``seed`` is recorded with the plan; nothing draws from it).
"""

from __future__ import annotations

import dataclasses
import io
import math
import time
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff.diagnosis.result import Diagnosis
from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.physics.drive import make_drive
from fitstiff.physics.simulate import CSV_DIGITS
from fitstiff.planning.descriptions import DescribedPair
from fitstiff.planning.families import Choice, Limits, choices, naive_choice
from fitstiff.planning.rivals import ABSENT, Confusion, Rivals, confusions, deferred
from fitstiff.planning.separation import (LEVEL, POWER, Noise, Outputs, detectable_size,
                                          noncentrality, outputs_many, sizes)
from fitstiff.segments.segmentation import standstill
from fitstiff.inference.problem import channel_noise
from fitstiff.inference.selection import Selection
from fitstiff.units import BAR, MM

__all__ = ["plan", "Plan", "PlannedProgram", "MAX_PROGRAMS", "PREDICTED", "noise_of",
           "read_predicted"]

#: the programs and the rivals' predicted forces beside ``plan.json`` (for the report)
PREDICTED = "predicted.npz"

#: runs (logs) per confusion: the diagnosis decides on held-out logs, so an effect only one
#: log excites is never trained where it is predicted (measured: dwell stiction planned as
#: one program and appended to the three logs of missing/dwell_stiction/0 raised the held-out
#: RMS to 0.41 N, twice the noise, and was not accepted)
RUNS = 2
#: programs per plan: RUNS per confusion, in the order of the confusions' kinds
MAX_PROGRAMS = 6
_SHORTLIST = 3
#: an expected z below this does not settle a pair (the programs are still written)
Z_SETTLES = 3.0


@dataclasses.dataclass(frozen=True)
class PlannedProgram:
    """One proposed program and what it is for (``plan.json``'s ``programs``)."""

    file: str
    supply_bar: float
    start_position_mm: float
    duration_s: float
    rate_hz: float
    program: Mapping[str, object]
    kind: str
    separates: tuple[str, str]
    expected: Mapping[str, object]
    naive: Mapping[str, object]
    why: str
    time_s: np.ndarray = dataclasses.field(default=None, compare=False, repr=False)
    displacement_mm: np.ndarray = dataclasses.field(default=None, compare=False, repr=False)
    #: the rivals' predicted force (N) on the program, by rival name (the report's panel)
    predicted_N: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict,
                                                               compare=False, repr=False)

    def to_dict(self) -> dict[str, object]:
        return {"file": self.file, "supply_bar": self.supply_bar,
                "start_position_mm": self.start_position_mm, "duration_s": self.duration_s,
                "rate_hz": self.rate_hz, "program": dict(self.program), "kind": self.kind,
                "separates": list(self.separates), "expected": dict(self.expected),
                "naive": dict(self.naive), "why": self.why}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> PlannedProgram:
        fields = {f.name for f in dataclasses.fields(cls)} - {"time_s", "displacement_mm",
                                                               "predicted_N"}
        kw = {k: data[k] for k in fields}
        kw["separates"] = tuple(kw["separates"])
        return cls(**kw)


@dataclasses.dataclass(frozen=True)
class Plan:
    """The next experiment (``plan.json``).

    Attributes:
        programs: one per settled confusion (:class:`PlannedProgram`).
        unplanned: confusions no program of the limits separates, each with why.
        limits: what the programs keep to.
        noise: the logs' noise floor the separation is computed against.
        diagnosis: the diagnosis' files and final model.
        timing_s: seconds spent fitting the rivals and searching.
    """

    programs: tuple[PlannedProgram, ...]
    unplanned: tuple[Mapping[str, object], ...]
    limits: Limits
    noise: Noise
    diagnosis: Mapping[str, object]
    seed: int = 0
    timing_s: Mapping[str, float] = dataclasses.field(default_factory=dict, compare=False)

    def to_dict(self) -> dict[str, object]:
        return {"programs": [p.to_dict() for p in self.programs],
                "unplanned": [dict(u) for u in self.unplanned],
                "limits": self.limits.to_dict(), "noise": self.noise.to_dict(),
                "diagnosis": dict(self.diagnosis), "seed": self.seed,
                "method": {"separation": "noncentrality of the likelihood-ratio test on the "
                                         "new record after the rival refits (linearised, "
                                         "with the logs' information on its parameters)",
                           "z_settles": Z_SETTLES, "power": POWER, "level": LEVEL},
                "timing_s": dict(self.timing_s)}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Plan:
        limits = dict(data["limits"])
        limits["stroke_range_mm"] = tuple(limits["stroke_range_mm"])
        limits["pressures_bar"] = tuple(limits["pressures_bar"])
        return cls(programs=tuple(PlannedProgram.from_dict(p) for p in data["programs"]),
                   unplanned=tuple(data.get("unplanned", ())), limits=Limits(**limits),
                   noise=Noise(**data["noise"]), diagnosis=data.get("diagnosis", {}),
                   seed=int(data.get("seed", 0)), timing_s=data.get("timing_s", {}))

    def files(self) -> dict[str, bytes]:
        """What ``fitstiff plan`` writes: ``program_<k>.csv`` (``time_s,displacement_mm``)
        per program and :data:`PREDICTED` (the programs and the rivals' predicted forces, for
        the report); ``plan.json`` is :meth:`to_dict`."""
        out: dict[str, bytes] = {}
        arrays: dict[str, np.ndarray] = {}
        for k, p in enumerate(self.programs, start=1):
            rows = "\n".join(f"{t:.{CSV_DIGITS}g},{x:.{CSV_DIGITS}g}"
                             for t, x in zip(p.time_s, p.displacement_mm))
            out[p.file] = f"time_s,displacement_mm\n{rows}\n".encode()
            arrays[f"time_s_{k}"] = np.asarray(p.time_s)
            arrays[f"displacement_mm_{k}"] = np.asarray(p.displacement_mm)
            for j, (name, force) in enumerate(p.predicted_N.items()):
                arrays[f"force_N_{k}_{j}"] = np.asarray(force)
                arrays[f"rival_{k}_{j}"] = np.asarray(name)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        out[PREDICTED] = buffer.getvalue()
        return out

    def summary(self) -> str:
        if not self.programs and not self.unplanned:
            return "nothing to plan: the diagnosis left no tie, rival or untestable effect"
        lines = []
        for p in self.programs:
            lines.append(f"{p.file}: {p.why}")
        for u in self.unplanned:
            lines.append(f"not planned: {' vs '.join(u['separates'])}: {u['why']}")
        return "\n".join(lines)


def noise_of(diagnosis: Diagnosis, logs: Sequence[Log]) -> Noise:
    """The logs' noise floor as the diagnosis measured it (pooled force floor, mean lag-one
    correlation) and the chamber pressures' white-noise level where the logs record them."""
    rhos = [float(v.get("rho", 0.0) or 0.0) for v in diagnosis.noise_N.values()]
    pressure = [channel_noise(p) for log in logs for p in (log.pressure_a, log.pressure_b)
                if p is not None]
    return Noise(sigma_N=float(diagnosis.gap["noise_N"]),
                 rho=float(np.mean(rhos)) if rhos else 0.0,
                 pressure_Pa=float(np.median(pressure)) if pressure else None)


class _Scorer:
    """Scores choices (programs) for one confusion: its rivals fitted, the drive of a choice
    built as the fit builds a log's."""

    def __init__(self, confusion: Confusion, rivals: Rivals, logs: Sequence[Log],
                 limits: Limits, noise: Noise):
        self.confusion, self.limits, self.noise = confusion, limits, noise
        self.template = logs[0].rig
        self.described = None
        if confusion.kind == "structure":
            self.a, (self.b, residuals) = None, rivals.final()
            self.described = DescribedPair(confusion.structure, confusion.separates[1],
                                           residuals, self.b, noise)
        elif confusion.single:
            self.b, self.direction, self.parameter, self.param = rivals.single(
                confusion.separates[0])
            self.a = None
        else:
            self.a, self.b = rivals.pair(confusion)
        self.chamber = self.b.model.needs_chamber

    def rig(self, choice: Choice):
        return dataclasses.replace(self.template, start_position=choice.start_position_mm * MM,
                                   supply_pressure=choice.supply_bar * BAR)

    def drive(self, choice: Choice):
        t, x = choice.sample(self.limits)
        drive = make_drive(displacement=x, time=t, rig=self.rig(choice),
                           still=standstill(x, t), needs_chamber=self.chamber,
                           what="the planned program")
        return dataclasses.replace(drive, runs=None, log_volume_span=None,
                                   log_volume_ratios=None, name=""), t, x

    def described_on(self, choice: Choice, t, x, force):
        """The structure's two descriptions on ``choice`` (sampled as ``t``, ``x``), the
        final model predicting ``force`` (N) there."""
        log = Log(name="program", displacement=x, force=force, time=t, rig=self.rig(choice))
        return self.described.on(log, force)

    def score(self, choice: Choice) -> dict[str, object]:
        """``objective`` (larger separates better) and the ``expected`` record."""
        return self.score_many([choice])[0]

    def score_many(self, choices: Sequence[Choice]) -> list[dict[str, object]]:
        """:meth:`score` of each of ``choices``, their rivals' predictions computed together
        (:func:`~fitstiff.planning.separation.outputs_many`)."""
        out: list[dict[str, object] | None] = [None] * len(choices)
        built = []
        for i, choice in enumerate(choices):
            try:
                built.append((i, *self.drive(choice)))
            except InputError as exc:  # leaves the chambers' room: not a program of the rig
                out[i] = {"objective": -math.inf, "error": str(exc)}
        drives = [b[1] for b in built]
        if self.described is not None:
            obs = outputs_many(self.b, drives, self.noise)
            sigma = self.noise.scale(self.noise.sigma_N)
            for (i, _, t, x), ob in zip(built, obs):
                n = len(t)
                try:
                    on = self.described_on(choices[i], t, x, ob.y[:n] * sigma)
                except InputError as exc:
                    out[i] = {"objective": -math.inf, "error": str(exc)}
                    continue
                out[i] = self.described.separation(ob, on, n)
        elif self.a is None:
            obs = outputs_many(self.b, drives, self.noise, along=self.direction)
            for (i, *_), ob in zip(built, obs):
                out[i] = self._single(ob)
        else:
            pairs = zip(outputs_many(self.a, drives, self.noise),
                        outputs_many(self.b, drives, self.noise))
            for (i, _, t, _), (oa, ob) in zip(built, pairs):
                out[i] = self._pair(oa, ob, len(t))
        return out

    def _single(self, ob: Outputs) -> dict[str, object]:
        per_unit = noncentrality(ob.along, ob.jac, ob.nuisance, self.b.information,
                                 sizes(self.b.values[self.b.free]))
        size = detectable_size(per_unit) * self.direction.sum()
        shown = self.param.to_display(size) if math.isfinite(size) else None
        return {"objective": per_unit, "parameter": self.parameter,
                "unit": self.param.unit, "detectable_size": shown,
                "power": POWER, "level": LEVEL,
                "noncentrality_per_unit_si": per_unit}

    def _pair(self, oa: Outputs, ob: Outputs, n: int) -> dict[str, object]:
        r = oa.y - ob.y
        lam_ab = noncentrality(r, ob.jac, ob.nuisance, self.b.information,
                               sizes(self.b.values[self.b.free]))
        lam_ba = noncentrality(-r, oa.jac, oa.nuisance, self.a.information,
                               sizes(self.a.values[self.a.free]))
        lam = min(lam_ab, lam_ba)
        a, b = self.confusion.separates
        return {"objective": lam, "z": math.sqrt(lam), "noncentrality": lam,
                # if a is true, b refits (and leaves lam_ab of the difference), and back
                "noncentrality_if": {a: lam_ab, b: lam_ba},
                "force_difference_rms_N": float(np.sqrt(np.mean(
                    (r[:n] * self.noise.scale(self.noise.sigma_N)) ** 2)))}

    def predicted(self, choice: Choice, expected: Mapping[str, object]
                  ) -> dict[str, np.ndarray]:
        """The rivals' predicted force (N) on ``choice``, in the order of ``separates``; for
        a single effect, the final model with it at the size the program detects, then
        without it."""
        drive, t, x = self.drive(choice)
        if self.described is not None:
            force = np.asarray(self.b.model.predict(drive))
            on = self.described_on(choice, t, x, force)
            return {name: force + d.f for name, d in zip(self.confusion.separates, on)}
        if self.a is not None:
            return {r.name: np.asarray(r.model.predict(drive)) for r in (self.a, self.b)}
        absent = np.asarray(self.b.model.predict(drive))
        size = expected.get("detectable_size")
        if size is None:
            return {ABSENT: absent}
        x = self.b.values + self.direction * self.param.to_si(size) / self.direction.sum()
        model = self.b.par.physical_to_model(x, self.b.model)
        return {self.confusion.separates[0]: np.asarray(model.predict(drive)), ABSENT: absent}


def plan(diagnosis: Diagnosis, logs: Sequence[Log], *, limits: Limits | None = None,
         separate: Sequence[str] | None = None, max_programs: int = MAX_PROGRAMS,
         seed: int = 0, selection: Selection | None = None, **options) -> Plan:
    """The programs that settle what ``diagnosis`` could not.

    Args:
        diagnosis: a :class:`~fitstiff.diagnosis.Diagnosis` of ``logs``.
        logs: the logs it diagnosed.
        limits: what the rig can do (default :meth:`Limits.from_logs`).
        separate: one effect (against its absence) or two to separate, instead of the
            diagnosis' confusions.
        max_programs: the most programs (:data:`RUNS` per confusion).
        seed: recorded with the plan (the rivals' fits and the search are deterministic).
        selection: the diagnosis' data options
            (:class:`~fitstiff.inference.selection.Selection`), or its fields as keywords.

    Returns:
        The :class:`Plan`; a confusion no program of the limits separates is in
        ``unplanned`` with why.
    """
    start = time.perf_counter()
    limits = limits or Limits.from_logs(logs)
    noise = noise_of(diagnosis, logs)
    found, later = deferred(confusions(diagnosis, separate=separate))
    most = max(1, max_programs // RUNS)
    rivals = Rivals(logs, diagnosis.final_model,
                    [e for c in found + later for e in c.effects],
                    selection=Selection.given(selection, options))
    spent = {"rivals": 0.0, "search": 0.0}
    programs: list[PlannedProgram] = []
    unplanned: list[dict] = []
    naive_log = max(logs, key=len)
    for confusion in found[:most]:
        _plan_one(confusion, rivals, logs, limits, noise, naive_log, programs, unplanned, spent)
    waiting = [c for c in found if any(p.separates == c.separates for p in programs)]
    if waiting:
        unplanned += [{"separates": list(c.separates), "kind": c.kind,
                       "why": "deferred: the runs planned for "
                              + "; ".join(" vs ".join(f.separates) for f in waiting)
                              + " come first (it may be their shadow); diagnose them, then "
                                "plan again"} for c in later]
    else:       # the logs settle every root question, or no program can: nothing to wait for
        for confusion in later[:most]:
            _plan_one(confusion, rivals, logs, limits, noise, naive_log, programs, unplanned,
                      spent)
    return Plan(programs=tuple(programs), unplanned=tuple(unplanned), limits=limits,
                noise=noise, diagnosis={"final_model": diagnosis.final_model,
                                        "files": list(diagnosis.files)},
                seed=seed, timing_s={**spent, "total": time.perf_counter() - start})


def _plan_one(confusion: Confusion, rivals: Rivals, logs: Sequence[Log], limits: Limits,
              noise: Noise, naive_log: Log, programs: list, unplanned: list,
              spent: dict) -> None:
    """The runs that separate ``confusion`` best, appended to ``programs`` (or why none is,
    to ``unplanned``); the time spent, to ``spent``."""
    t0 = time.perf_counter()
    try:
        scorer = _Scorer(confusion, rivals, logs, limits, noise)
    except InputError as exc:
        unplanned.append({"separates": list(confusion.separates), "kind": confusion.kind,
                          "why": f"its rivals could not be fitted: {exc}"})
        return
    settled = _settled_by_logs(confusion, scorer, noise)
    if settled:
        spent["rivals"] += time.perf_counter() - t0
        unplanned.append({"separates": list(confusion.separates), "kind": confusion.kind,
                          "why": settled})
        return
    t1 = time.perf_counter()
    runs = _search(scorer, limits, logs)
    naive = scorer.score(naive_choice(naive_log))
    spent["rivals"] += t1 - t0
    spent["search"] += time.perf_counter() - t1
    if not runs:
        unplanned.append({"separates": list(confusion.separates), "kind": confusion.kind,
                          "why": "no program within the limits separates them (widen "
                                 "--pressures, --stroke-range, --max-speed or "
                                 "--max-duration)"})
        return
    for run, (best, expected) in enumerate(runs):
        t, x = best.sample(limits)
        k = len(programs) + 1
        programs.append(PlannedProgram(
            file=f"program_{k}.csv", supply_bar=best.supply_bar,
            start_position_mm=best.start_position_mm, duration_s=float(t[-1]),
            rate_hz=limits.rate_hz, program=best.describe(), kind=confusion.kind,
            separates=confusion.separates, expected=_public(expected),
            naive={"program": f"the log {naive_log.name} replayed",
                   **_public(naive)},
            why=_why(confusion, best, expected, naive, run=run),
            time_s=t, displacement_mm=x / MM,
            predicted_N=scorer.predicted(best, expected)))



def _settled_by_logs(confusion: Confusion, scorer: _Scorer, noise: Noise) -> str:
    """Why a rival pair needs no experiment (the logs already prefer one by more than
    :data:`Z_SETTLES` squared in their whitened misfit, AR(1)-deflated), or ``""``. Ties are
    always planned (held out, the logs could not tell them apart)."""
    if confusion.kind != "rival" or scorer.a is None:
        return ""
    rho = min(max(noise.rho, 0.0), 0.95)
    gap = (scorer.b.cost - scorer.a.cost) * (1 - rho) / (1 + rho)
    if abs(gap) <= Z_SETTLES**2:
        return ""
    better, worse = ((scorer.a.name, scorer.b.name) if gap > 0
                     else (scorer.b.name, scorer.a.name))
    return (f"the logs already tell them apart: {better} fits them better than {worse} by "
            f"a chi-square of {abs(gap):.3g} (above {Z_SETTLES**2:.3g})")


def _public(score: Mapping[str, object]) -> dict[str, object]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in score.items() if k != "objective"}


def _search(scorer: _Scorer, limits: Limits, logs: Sequence[Log]
            ) -> list[tuple[Choice, dict[str, object]]]:
    """The :data:`RUNS` runs of a confusion with their scores (none when no program separates
    the rivals): every shape at two supplies, then the shortlist at every supply and three
    start positions (and the logged ones, for a structure); the best, then the best of its
    shape at another condition."""
    supplies = limits.pressures_bar
    logged = [log.rig.supply_pressure / BAR for log in logs
              if log.rig.supply_pressure is not None]
    middle = float(np.median(logged)) if logged else supplies[len(supplies) // 2]
    near = min(supplies, key=lambda p: abs(p - middle))
    far = max(supplies, key=lambda p: abs(p - middle))
    lo, hi = limits.stroke_range_mm
    starts_logged = [float(np.clip(log.rig.start_position / MM, lo, hi)) for log in logs
                     if log.rig.start_position is not None]
    # a logged start, the nearest the middle one (the median of an odd count)
    home = (min(starts_logged, key=lambda s: abs(s - np.median(starts_logged)))
            if starts_logged else (lo + hi) / 2)
    first = [choice for supply in dict.fromkeys((near, far))
             for choice in choices(limits, supply_bar=supply, start_position_mm=home)]
    scored: list[tuple[float, Choice, dict]] = [
        (s["objective"], choice, s) for choice, s in zip(first, scorer.score_many(first))]
    if not scored:
        return []
    scored.sort(key=lambda v: -v[0])
    shapes = []
    for _, choice, _ in scored:
        if (choice.family, tuple(choice.options.items())) not in shapes:
            shapes.append((choice.family, tuple(choice.options.items())))
        if len(shapes) == _SHORTLIST:
            break
    positions = dict.fromkeys((home, lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo)))
    if scorer.described is not None:
        # a structure's description is known on the logged stretches of its variable only
        # (:func:`~fitstiff.planning.descriptions.supported`): each logged start is a place
        positions |= dict.fromkeys(starts_logged)
    seen = {(c.family, tuple(c.options.items()), c.supply_bar, c.start_position_mm)
            for _, c, _ in scored}
    shortlist = []
    for family, options in shapes:
        for supply in supplies:
            for position in positions:
                key = (family, options, supply, position)
                if key not in seen:
                    seen.add(key)
                    shortlist.append(Choice(family, dict(options), supply, position))
    scored += [(s["objective"], choice, s)
               for choice, s in zip(shortlist, scorer.score_many(shortlist))]
    scored.sort(key=lambda v: -v[0])
    objective, best, s = scored[0]
    if not objective > 0:
        return []
    # the second run: the same shape at another supply or start position (the best such),
    # else the same program again
    same = [(c, v) for o, c, v in scored[1:]
            if (c.family, c.options) == (best.family, best.options) and o > 0]
    second = same[0] if same else (best, s)
    return [(best, s), second][:RUNS]


def _why(confusion: Confusion, choice: Choice, expected, naive, *, run: int = 0) -> str:
    a, b = confusion.separates
    if run:
        return (f"the same {choice.family} program at {choice.supply_bar:.3g} bar from "
                f"{choice.start_position_mm:.4g} mm: a second log of it, which the diagnosis "
                "predicts from the first (it decides on held-out logs)")
    what = (f"tests {a} against its absence" if b == ABSENT else
            f"tells whether the unexplained residual follows the {a.replace('_', ' ')} or the "
            f"{b.replace('_', ' ')}" if confusion.kind == "structure" else
            f"separates {a} from {b}")
    how = (f"{choice.family} ({', '.join(f'{k} {v:.3g}' for k, v in choice.options.items())}) "
           f"at {choice.supply_bar:.3g} bar from {choice.start_position_mm:.4g} mm")
    if b == ABSENT:
        size, unit = expected.get("detectable_size"), expected.get("unit", "")
        was = naive.get("detectable_size")
        gain = (f"detects {expected['parameter']} of {size:.3g} {unit} at {POWER:.0%} power"
                if size is not None else "cannot detect it")
        ref = (f"(replaying a log: {was:.3g} {unit})" if was is not None
               else "(replaying a log: not detectable)")
        return f"{how} {what}: {gain} {ref}; {confusion.why}"
    return (f"{how} {what}: expected z {expected['z']:.3g} after both refit (replaying a log: "
            f"{naive['z']:.3g}); {confusion.why}")


def read_predicted(arrays: Mapping[str, np.ndarray], k: int
                   ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Program ``k`` (from 1) of a :data:`PREDICTED` file: time (s), displacement (mm) and the
    rivals' predicted forces (N) by name."""
    forces, j = {}, 0
    while f"force_N_{k}_{j}" in arrays:
        forces[str(arrays[f"rival_{k}_{j}"])] = np.asarray(arrays[f"force_N_{k}_{j}"])
        j += 1
    return (np.asarray(arrays[f"time_s_{k}"]), np.asarray(arrays[f"displacement_mm_{k}"]),
            forces)
