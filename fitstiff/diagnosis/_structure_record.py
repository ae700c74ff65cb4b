"""The :class:`Structure` record of a description of the held-out residual
(:mod:`fitstiff.diagnosis.structure`): what it says (which variable, in which form, what
usually looks like that and what to record to tell those apart) and the shape a plot draws.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._structure_forms import UNITS, Candidate, disjoint

__all__ = ["LOOKALIKES", "Shown", "Structure", "Trial", "record", "shown"]

_WHAT = {
    "position": "the piston position along the stroke",
    "time": "the time within each log",
    "pressure": "the supply pressure, beyond the library's pressure law",
    "velocity": "the velocity",
    "since_reversal": "the travel since the last reversal (the shape of the transition)",
    "direction": "the direction of motion",
    "acceleration": "the acceleration",
    "force": "the force itself",
    "log": "the log (one log differs from the others)",
}
#: (physical effects that usually look like this, what to record to tell them apart)
_SUGGEST = {
    ("position", False): (
        "a force that depends on where the piston is: a guide or bore ripple, a cyclic error "
        "of the displacement sensor, the chambers' spring beyond the polytropic law, or "
        "friction that changes along the bore",
        "record the same program at two start positions a fraction of the period apart: a "
        "bore feature moves with the position, a sensor error with the sensor"),
    ("position", True): (
        "friction that changes along the bore: a tight spot, a wear track or a scratch, or "
        "an out-of-round barrel",
        "record slow full strokes in both directions and the same program at shifted start "
        "positions"),
    ("time", False): (
        "drift of the force sensor or of its amplifier (temperature, creep) beyond the "
        "library's linear force drift",
        "record a zero-load reading before and after each log and the sensor's temperature"),
    ("time", True): (
        "friction that changes during the run: warm-up of the seal and the grease, wear-in, "
        "or the lubricant film building up",
        "repeat the same program at the start and the end of a session, log the cylinder's "
        "temperature"),
    ("pressure", True): (
        "a seal whose friction does not grow in proportion with the pressure (contact "
        "saturation, a preloaded lip)",
        "record at four or more supply pressures with two logs at one pressure, so pressure "
        "and log can be told apart"),
    ("velocity", False): (
        "a force that grows with speed in a way no library law has (fluid drag in the "
        "valves, sensor dynamics)",
        "record the same amplitude over a decade of speeds"),
    ("velocity", True): (
        "friction that depends on the speed beyond viscous and Stribeck laws, or a "
        "presliding stiffness that depends on the rate (a viscoelastic seal)",
        "record nested loops at three or more speeds a decade apart, at one pressure"),
    ("since_reversal", False): (
        "a transition shape the friction model cannot follow",
        "record small nested loops (a tenth of the presliding range and up) at a high "
        "sample rate around the reversals"),
    ("since_reversal", True): (
        "a presliding curve of another shape than the model's (several asperity scales, a "
        "rate-dependent seal)",
        "record small nested loops (a tenth of the presliding range and up) at a high "
        "sample rate around the reversals"),
    ("direction", False): (
        "friction that differs between the two directions (a tilted seal, a rod side load)",
        "record the same program mirrored (start from the other end)"),
    ("acceleration", False): (
        "a moving mass or a sensor's dynamics the library's inertia does not match",
        "record an accelerometer on the carriage, or sine sweeps at several frequencies"),
    ("force", False): (
        "a load cell's nonlinearity",
        "calibrate the load cell with known weights over the force range of the logs"),
    ("force", True): (
        "hysteresis of the load cell or of its mounting",
        "load the cell with known weights up and down with the piston blocked"),
    ("log", True): (
        "something that changed between logs: a remounted sensor, the seal's state, the "
        "temperature",
        "repeat one log at the end of the session, unchanged"),
}

#: library effects whose residual has the shape of a description: when one of them was tried
#: and not accepted, the description says so (the library's held-out refit is the test of
#: that effect; the description only says where the rest goes)
LOOKALIKES = {("velocity", True): ("viscous", "stribeck"), ("time", False): ("force_drift",),
              ("pressure", True): ("pressure_friction",), ("direction", False): ("asymmetry",),
              ("acceleration", False): ("inertia",), ("since_reversal", True):
              ("maxwell_slip",), ("time", True): ("dwell_stiction",)}


@dataclasses.dataclass(frozen=True)
class Structure:
    """One description of the unexplained held-out residual (``unexplained_structure``).

    ``form`` names the shape (``linear``, ``smooth``, ``periodic``, ``step``), prefixed by
    ``sign-dependent`` when it changes sign with the direction; ``period`` (in the
    variable's unit) for a periodic one, whose ``shape`` runs over one period (each log's
    phase aligned). ``size_N`` is the RMS of the description fitted to
    all samples; the held-out RMS before and after are of the residual with the description
    held out (its own folds); ``shrink`` is the share of the gap above the noise floor it
    removes. ``shape`` holds the fitted curve (``x`` as ``axis`` says; ``y`` N, or
    ``toward_B`` and ``toward_A`` for a sign-dependent one) for plots."""

    variable: str
    form: str
    size_N: float
    heldout_rms_before_N: float
    heldout_rms_after_N: float
    shrink: float | None
    accepted: bool
    description: str
    suggestion: str
    t: float = 0.0
    t_needed: float = 0.0
    parameters: int = 0
    period: float | None = None
    unit: str = ""
    round: int = 1
    confounded_with: tuple[str, ...] = ()
    why: str = ""
    shape: Mapping[str, list[float]] = dataclasses.field(default_factory=dict)
    #: what ``shape``'s ``x`` is, with its unit (the plot's axis)
    axis: str = ""

    def to_dict(self) -> dict[str, object]:
        out = dataclasses.asdict(self)
        out["confounded_with"] = list(self.confounded_with)
        out["shape"] = {k: list(v) for k, v in self.shape.items()}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Structure:
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in data.items() if k in fields}
        kw["confounded_with"] = tuple(kw.get("confounded_with", ()))
        return cls(**kw)


class Shown(NamedTuple):
    """A description's variable as its plot shows it, and the axis' label (with its unit)."""

    values: np.ndarray
    axis: str


@dataclasses.dataclass(frozen=True, eq=False)
class Trial:
    """A candidate description tried in one round: its held-out prediction (its own folds),
    its fit to all counted samples, the held-out RMS before and after it, the t statistic of
    its held-out gain over the blocks, and its variable as plotted."""

    cand: Candidate
    pred: np.ndarray       # held-out prediction (its own folds)
    full: np.ndarray       # fitted to all counted samples
    period: float | None
    dof: int
    t: float
    before: float
    after: float
    shown: np.ndarray      # the variable as plotted (see :func:`shown`)
    axis: str              # what `shown` is, with its unit
    gains: np.ndarray      # the held-out gain per block (N^2), whose t statistic is ``t``


def record(x: Trial, relative: bool, noise: float, *, accepted: bool, round_: int,
           t_needed: float, rivals: tuple[str, ...] = (), apart: tuple[str, ...] = (),
           why: str = "", library: Mapping[str, str] = {}) -> Structure:
    """The :class:`Structure` of a tried description: ``relative``, whether the positions are
    relative to the start (a start position not known); ``rivals``, the variables it is
    confounded with; ``apart``, where no two logs share a range of its variable, ``log`` and
    the variables with one level per log (a supply pressure each): rivals too, since the
    curve is as well a shape of each log's own; ``library``, the library effects tried and
    not accepted, with why (:data:`LOOKALIKES`)."""
    c = x.cand
    unit = UNITS[c.variable]
    size = math.sqrt(float(np.mean(x.full**2)))
    form = c.label
    if c.form == "periodic":
        form += f" (period {x.period:.3g} {unit})"
    shrink = (x.before - x.after) / (x.before - noise) if x.before > noise else None
    what = _WHAT[c.variable]
    if c.variable == "position" and relative:
        what += " (relative to the start: the start position is not known)"
    description = (f"{size:.2g} N of the held-out residual follows {what}: {form}"
                   + (", changing sign with the direction" if c.signed else "")
                   + f"; held-out RMS {x.before:.3g} -> {x.after:.3g} N")
    effects, to_record = _SUGGEST.get((c.variable, c.signed), _SUGGEST.get(
        (c.variable, not c.signed), ("", "")))
    suggestion = (f"Usually {effects}; to pin it down, {to_record}" if effects else "")
    # each rival once, with the reason that says what to record: a variable whose logs lie
    # apart is told from the curve by two logs over one range, whatever else it shares
    same = tuple(v for v in rivals if v not in apart)
    if same:
        suggestion += (f". The logs cannot tell it from {', '.join(same)} (the same "
                       "prediction): record data that vary them separately")
    if apart:
        rivals += tuple(v for v in apart if v not in rivals)
        per_log = [v.replace("_", " ") for v in apart if v != "log"]
        suggestion += (f". The logs cannot tell it from {', '.join(apart)}: no two logs share a "
                       f"range of the {c.variable.replace('_', ' ')}, so the curve is as well "
                       "a shape of each log's own"
                       + (f" (and each log has its own {', '.join(per_log)})" if per_log else "")
                       + "; record two logs over one range of it"
                       + (f" at one {', '.join(per_log)}" if per_log else ""))
    for effect in LOOKALIKES.get((c.variable, c.signed), ()):
        if effect in library:
            suggestion += (f". {effect} has a shape like it; the library tried it and did "
                           f"not accept it ({library[effect]})")
    return Structure(variable=c.variable, form=form, size_N=size,
                     heldout_rms_before_N=x.before, heldout_rms_after_N=x.after,
                     shrink=shrink, accepted=accepted, description=description,
                     suggestion=suggestion, t=x.t, t_needed=t_needed, parameters=x.dof,
                     period=x.period, unit=unit, round=round_, confounded_with=rivals,
                     why=why, shape=_shape(x), axis=x.axis)


def shown(cand: Candidate, log_id: np.ndarray, counted: np.ndarray, full: np.ndarray,
          period: float | None) -> Shown:
    """The variable as a plot of the description shows it, and the axis' label: within the
    period for a periodic one (:func:`_folded`); from each log's middle where the logs lie
    apart in it (a curve per log, side by side); else as it is."""
    name = cand.variable.replace("_", " ")
    unit = f" ({UNITS[cand.variable]})" if UNITS[cand.variable] else ""
    if cand.form == "hysteresis":
        return Shown(cand.values, f"the force's change since it last turned{unit}")
    if cand.form == "transition":
        return Shown(cand.values, f"travel since the reversal (mm), scaled by the {name}")
    if period is not None:
        return Shown(_folded(cand, log_id, full, period),
                     f"{name} within the period, each log's phase aligned{unit}")
    if cand.form in ("linear", "smooth", "gated") and disjoint(cand.values, log_id, counted):
        out = cand.values.copy()
        for k in np.unique(log_id):
            m = log_id == k
            out[m] -= np.median(cand.values[m & counted]) if (m & counted).any() else 0.0
        return Shown(out, f"{name} from each log's middle{unit}")
    return Shown(cand.values, f"{name}{unit}")


def _folded(cand: Candidate, log_id: np.ndarray, full: np.ndarray, period: float
            ) -> np.ndarray:
    """A periodic description's variable within its period, each log's phase aligned to
    a sine starting at 0 (the logs' phases differ): ``(v + phase_k) mod period``."""
    theta = 2 * np.pi * cand.values / period
    out = np.empty_like(theta)
    shape = full * np.where(cand.sign != 0, cand.sign, 1.0)
    for k in np.unique(log_id):
        m = log_id == k
        a = np.column_stack([np.sin(theta[m]), np.cos(theta[m]), np.ones(m.sum())])
        (s, c, _), *_ = np.linalg.lstsq(a, shape[m], rcond=None)
        out[m] = np.mod(theta[m] + math.atan2(c, s), 2 * np.pi) * period / (2 * np.pi)
    return out


def _shape(x: Trial) -> dict[str, list[float]]:
    """The fitted description on 40 points of its variable (binned means of the full fit;
    a periodic one over one period, :func:`_folded`)."""
    c = x.cand
    v = x.shown
    if c.form == "step" or np.ptp(v) <= 0:
        return {}
    edges = (np.linspace(0, x.period, 41) if x.period is not None else
             np.quantile(v, np.linspace(0, 1, 41)))
    idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, 39)
    centre = 0.5 * (edges[:-1] + edges[1:])
    out = {"x": centre.tolist()}
    keys = {"y": c.sign != 0} if not c.signed else {"toward_B": c.sign > 0,
                                                      "toward_A": c.sign < 0}
    for key, sel in keys.items():
        s = np.bincount(idx[sel], weights=x.full[sel], minlength=40)
        n = np.bincount(idx[sel], minlength=40)
        out[key] = [float(a / b) if b else None for a, b in zip(s, n)]
    return out
