"""The result noun of the diagnosis: :class:`Diagnosis` (``diagnosis.json``, DESIGN §5)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from fitstiff.diagnosis.structure import Structure

__all__ = ["Diagnosis", "Candidate"]


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One candidate effect: its screen, its held-out refit (if it was refitted) and the
    verdict."""

    effect: str
    score: float
    dof: int
    p_value: float
    testable: bool
    #: natural log of ``p_value`` (ranks candidates whose p-values underflow to 0)
    log_p_value: float = 0.0
    heldout_rms_before_N: float | None = None
    heldout_rms_after_N: float | None = None
    shrink: float | None = None
    accepted: bool = False
    converged: bool | None = None
    regions_improved: tuple[str, ...] = ()
    parameters: Mapping[str, Mapping[str, float | str]] = dataclasses.field(
        default_factory=dict)
    round: int = 1
    why: str = ""
    #: the effects accepted together with it in one step (its refit, held-out RMS and shrink
    #: are theirs together), when none passed alone; empty otherwise
    together: tuple[str, ...] = ()
    #: what the fitted values refer to where the units do not say it
    #: (:meth:`fitstiff.physics.terms.base.Term.reading`: pressure_friction's reference pressure and
    #: per-bar basis), for accepted effects
    reading: str = ""
    #: what outside the library draws the same force, and what to record to tell them apart
    #: (:attr:`fitstiff.physics.terms.base.Term.lookalike`), for accepted effects
    lookalike: str = ""
    #: the p-value of its first screen (on the baseline, before any acceptance): what it
    #: explained of the baseline's gap, which an accepted effect may have taken since
    first_p_value: float | None = None
    #: the accepted effect it tied with on held-out data (told apart by the fits to all the
    #: data only, :mod:`fitstiff.planning` proposes the experiment that separates them)
    tied_with: str = ""
    #: how much larger its BIC on all the data is than that of ``tied_with`` (the tie's only
    #: judge): below :data:`~fitstiff.diagnosis._choice.DECISIVE_BIC` (6) the logs do not
    #: tell the two apart and the verdict says so; None without a tie
    tie_bic_gap: float | None = None
    #: the log that alone determines it, where its held-out refit found one: every fold that
    #: trains on that log finds the effect, the fold that leaves it out does not, so the
    #: held-out rule cannot confirm it (:func:`fitstiff.diagnosis._refit.lone_log`)
    determined_by: str = ""
    #: the description of the held-out residual (``"<form> in <variable>"``) that explained
    #: the gap better than it, by more than ``MIN_GAIN`` of the noise floor, when it passed
    #: the rule otherwise and was refused for it (:class:`~fitstiff.diagnosis._rounds.Rival`);
    #: else empty
    outdone_by: str = ""

    @property
    def p_text(self) -> str:
        """The p-value for reading: two digits, or ``< 1e-300`` below that (the screen's
        tail is exact there, but no decision turns on it; :attr:`log_p_value` keeps it)."""
        if self.p_value < 1e-300 and (self.p_value > 0 or self.log_p_value < 0):
            return "< 1e-300"
        return f"{self.p_value:.2g}"

    @property
    def fitted_text(self) -> str:
        """``beta 0.21 1/bar [0.2, 0.22]``: the parameters in their units, with their 95 %
        intervals where the diagnosis gave them (the accepted effects' final fit)."""
        parts = []
        for name, p in self.parameters.items():
            unit = "" if p.get("unit") in ("-", None) else f" {p['unit']}"
            interval = p.get("interval_95")
            parts.append(f"{name} {p['value']:.3g}{unit}"
                         + (f" [{interval[0]:.3g}, {interval[1]:.3g}]" if interval else ""))
        return ", ".join(parts)

    def to_dict(self) -> dict[str, object]:
        out = dataclasses.asdict(self)
        out["regions_improved"] = list(self.regions_improved)
        out["together"] = list(self.together)
        out["parameters"] = {k: dict(v) for k, v in self.parameters.items()}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Candidate:
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in data.items() if k in fields}
        kw["regions_improved"] = tuple(kw.get("regions_improved", ()))
        kw["together"] = tuple(kw.get("together", ()))
        return cls(**kw)


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """Where the baseline misses, which effect explains it, and how far the gap shrinks.

    Attributes:
        baseline: the baseline spec.
        final_model: baseline plus the accepted effects, as a spec.
        gap: ``heldout_rms_N`` (baseline), ``noise_N`` (pooled noise floor), ``regions``
            (the baseline's held-out residual per cell, :mod:`fitstiff.diagnosis.gap`),
            ``final_heldout_rms_N`` and ``final_regions`` (after the accepted effects).
        candidates: every screened candidate, best-ranked first (accepted ones in the order
            of acceptance).
        accepted: accepted effect names, in order; empty when the baseline is adequate.
        unexplained: cells still above the noise floor after the accepted effects.
        unexplained_structure: what the rest of the held-out residual follows
            (:class:`~fitstiff.diagnosis.structure.Structure`).
        noise_N: per log: the noise floor (``sigma_N``, ``rho``, ``method``).
        detectability: per candidate: ``testable``, ``parameter``, ``size`` and ``unit`` of the
            smallest effect detected at 80 % power, or ``reason`` and ``record``.
        skipped: candidates that could not apply to this baseline, with why.
        folds: how the data were held out.
        settings: the acceptance rule's thresholds.
        verdict: the findings in words.
        files: the logs.
    """

    baseline: str
    final_model: str
    gap: Mapping[str, object]
    candidates: tuple[Candidate, ...]
    accepted: tuple[str, ...]
    unexplained: tuple[Mapping[str, object], ...]
    noise_N: Mapping[str, Mapping[str, object]]
    detectability: Mapping[str, Mapping[str, object]]
    skipped: Mapping[str, str]
    folds: tuple[str, ...]
    settings: Mapping[str, object]
    verdict: tuple[str, ...]
    files: tuple[str, ...]
    timing_s: Mapping[str, float] = dataclasses.field(default_factory=dict)
    #: what the unexplained held-out residual follows (:mod:`fitstiff.diagnosis.structure`):
    #: the accepted descriptions in order, then the best of every other variable tried
    unexplained_structure: tuple[Structure, ...] = ()
    #: the next experiment (``plan.json``'s content, :mod:`fitstiff.planning`), when the
    #: diagnosis ended with a tie, a rival, an untestable or an undecided candidate and a plan
    #: was made (``fitstiff diagnose`` makes it); empty otherwise
    next_experiment: Mapping[str, object] = dataclasses.field(default_factory=dict)
    #: held-out residuals (model - measured force, N) per log: ``"before"`` (the baseline)
    #: and ``"after"`` (the final model); kept beside diagnosis.json as ``heldout.npz``
    heldout: Mapping[str, tuple[np.ndarray, ...]] = dataclasses.field(
        default_factory=dict, compare=False, repr=False)

    def heldout_arrays(self) -> dict[str, np.ndarray]:
        """``heldout.npz`` content: ``before_<k>`` / ``after_<k>`` for log ``k``."""
        return {f"{which}_{k}": np.asarray(r) for which, rs in self.heldout.items()
                for k, r in enumerate(rs)}

    @staticmethod
    def heldout_from_arrays(arrays: Mapping[str, np.ndarray],
                            n_logs: int) -> dict[str, tuple[np.ndarray, ...]]:
        """Inverse of :meth:`heldout_arrays`."""
        return {which: tuple(np.asarray(arrays[f"{which}_{k}"]) for k in range(n_logs))
                for which in ("before", "after")}

    def to_dict(self) -> dict[str, object]:
        """The ``diagnosis.json`` content. Values that are not determined (a shrink when the
        gap is already at the noise floor, a z-score against a zero noise floor) are ``None``."""
        return _undetermined_as_none({
            "baseline": self.baseline,
            "final_model": self.final_model,
            "gap": dict(self.gap),
            "candidates": [c.to_dict() for c in self.candidates],
            "accepted": list(self.accepted),
            "unexplained": [dict(u) for u in self.unexplained],
            "unexplained_structure": [u.to_dict() for u in self.unexplained_structure],
            "noise_N": {k: dict(v) for k, v in self.noise_N.items()},
            "detectability": {k: dict(v) for k, v in self.detectability.items()},
            "skipped": dict(self.skipped),
            "folds": list(self.folds),
            "settings": dict(self.settings),
            "verdict": list(self.verdict),
            "files": list(self.files),
            "timing_s": dict(self.timing_s),
            "next_experiment": dict(self.next_experiment) or None,
        })

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Diagnosis:
        """Read back what :meth:`to_dict` wrote (``diagnosis.json``)."""
        return cls(
            baseline=data["baseline"], final_model=data["final_model"], gap=data["gap"],
            candidates=tuple(Candidate.from_dict(c) for c in data["candidates"]),
            accepted=tuple(data["accepted"]),
            unexplained=tuple(data["unexplained"]),
            unexplained_structure=tuple(Structure.from_dict(u) for u in
                                        data.get("unexplained_structure", ())),
            noise_N=data["noise_N"],
            detectability=data["detectability"], skipped=data.get("skipped", {}),
            folds=tuple(data.get("folds", ())), settings=data.get("settings", {}),
            verdict=tuple(data.get("verdict", ())), files=tuple(data.get("files", ())),
            timing_s=data.get("timing_s", {}),
            next_experiment=data.get("next_experiment") or {})

    def candidate(self, effect: str) -> Candidate:
        for c in self.candidates:
            if c.effect == effect:
                return c
        raise KeyError(effect)

    def summary(self) -> str:
        """A readable summary for the terminal."""
        lines = [f"diagnosis of {self.baseline}: " + ("accepted " + ", ".join(self.accepted)
                                                      if self.accepted else
                                                      "no effect accepted"),
                 f"  held-out rms {self.gap['heldout_rms_N']:.4g} N -> "
                 f"{self.gap['final_heldout_rms_N']:.4g} N; noise floor "
                 f"{self.gap['noise_N']:.4g} N",
                 f"  {'candidate':<18}{'score':>10}{'p':>10}{'before N':>10}{'after N':>10}"
                 f"{'shrink':>8}  verdict"]
        for c in self.candidates:
            def f(v, fmt):
                return "-" if v is None else format(v, fmt)
            verdict = "ACCEPTED" if c.accepted else c.why
            lines.append(f"  {c.effect:<18}{c.score:>10.3g}{c.p_text:>10}"
                         f"{f(c.heldout_rms_before_N, '.4g'):>10}"
                         f"{f(c.heldout_rms_after_N, '.4g'):>10}{f(c.shrink, '.2f'):>8}  "
                         f"{verdict}")
        found = [u for u in self.unexplained_structure if u.accepted]
        if found:
            lines.append("  unexplained structure (held out):")
            lines += [f"    {u.description}" for u in found]
        lines += [f"  {v}" for v in self.verdict]
        programs = self.next_experiment.get("programs", []) if self.next_experiment else []
        if programs:
            lines.append("  next experiment (plan/):")
            lines += [f"    {p['file']}: {p['why']}" for p in programs]
        return "\n".join(lines)


def _undetermined_as_none(obj):
    if isinstance(obj, Mapping):
        return {k: _undetermined_as_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_undetermined_as_none(v) for v in obj]
    if isinstance(obj, (float, np.floating)) and not np.isfinite(obj):
        return None
    return obj
