"""What the unexplained gap follows: descriptions of the held-out residual (issue 32).

When the library's effects are exhausted (:func:`~fitstiff.diagnosis.diagnose.diagnose`'s greedy
acceptance), the final model's **held-out** residual ``r`` (model - measured, N; every sample
predicted by a fit that never saw it, :mod:`fitstiff.diagnosis.select`) may still follow
something. This module tries small regularised models ``d(v)`` of ``r`` in one variable ``v``
of a fixed vocabulary (:data:`VARIABLES`), and names the one that holds on held-out data.

**Descriptions.** For each variable: ``linear`` (one column), ``smooth`` (hat functions at
``KNOTS`` quantiles of ``v``, of each log's own for the position, a second-difference penalty
chosen by generalised cross-validation), ``periodic`` (a sine and a cosine whose period is scanned; position only)
``step`` (one level per log, or per direction) and, for the force, ``hysteresis`` (smooth in
the force's change since it last turned, times the direction of its change), each either
**even** (the same in both directions of motion) or **sign-dependent** (times the direction
of motion: a friction-like force). Every column is
centred per log, so no description can take over a log's force offset (a nuisance the fit
already owns).

**Held out twice.** The residual is already held out from the physics; a description is held
out from itself too: each log's samples are cut into ``BLOCKS`` consecutive blocks, block
``b`` belongs to fold ``b mod FOLDS``, the description is fitted on the other folds (its
knots, penalty and period included) and predicts the fold. No physics model is refitted.

**The rule** (the library's, :mod:`fitstiff.diagnosis.select`, on the description): the
gap must exist (held-out RMS above the pooled noise floor); the description's held-out
gain ``sum(r^2) - sum((r - d)^2)`` per block is positive by a one-sided t-test over the blocks
at ``alpha`` Bonferroni-corrected over the descriptions tried; the held-out RMS falls by at
least ``MIN_GAIN`` of the noise floor; and the fall is at least ``min_shrink`` of the gap
above the noise. Among the descriptions that pass, the lowest held-out RMS wins (within
``TIE`` of the noise floor: fewer parameters, then the vocabulary's order); its held-out
prediction is taken off the residual and the rest is described again, up to
``MAX_ACCEPT`` descriptions. Descriptions of other variables that do about as well (a tie,
or passing with at least ``RIVAL_GAIN`` of the winner's held-out gain) and predict the same
thing (correlation above ``CONFOUNDED``) are its ``confounded_with``: the logs cannot tell
those variables apart; so is ``log`` for a curve (not a period) of a
variable whose ranges in the logs do not overlap (a curve of it is as well a shape per log).

The rates are measured in the withheld-effect benchmark (``benchmarks/withheld.py``: nulls,
datasets whose in-library effect was accepted, and the out-of-library family).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff.inference.comparison import TIE
from fitstiff.io.log import Log
from fitstiff.segments.segmentation import Segmentation

__all__ = ["VARIABLES", "LOOKALIKES", "Described", "Structure", "accepted_descriptions",
           "describe_structure", "structure_variables",
           "STRUCTURE_ALPHA", "STRUCTURE_MIN_SHRINK"]

#: what a residual can follow, in the order ties are broken (physical variables first)
VARIABLES = ("position", "time", "pressure", "velocity", "since_reversal", "direction",
             "acceleration", "force", "log")
UNITS = {"position": "mm", "time": "s", "pressure": "bar", "velocity": "mm/s",
         "since_reversal": "mm", "direction": "", "acceleration": "mm/s^2", "force": "N",
         "log": ""}
#: family-wise level of the descriptions' test in each round
STRUCTURE_ALPHA = 0.05
#: share of the gap above the noise floor a description must remove on held-out data
STRUCTURE_MIN_SHRINK = 0.2
#: least fall of the held-out RMS, as a share of the noise floor (as the library's MIN_GAIN)
MIN_GAIN = 0.05
MAX_ACCEPT = 3
FOLDS = 4
BLOCKS = 16
KNOTS = 8
#: descriptions of two variables whose held-out predictions correlate above this, and whose
#: held-out gains are within a tie or the rival's at least RIVAL_GAIN of the chosen one's
#: (passing the rule itself), are one: the logs cannot tell the variables apart
CONFOUNDED = 0.8
RIVAL_GAIN = 0.8
_PERIODS = 40
_LAMBDAS = 10.0 ** np.arange(-4.0, 4.5, 1.0)

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


# ------------------------------------------------------------------------------ variables

def structure_variables(log: Log, seg: Segmentation, model_force: np.ndarray
                        ) -> dict[str, np.ndarray]:
    """Per-sample values of every variable this log has (display units), and the two signs:
    ``_motion`` (direction of motion, 0 standing still) and ``_force`` (direction of the
    model force's change). ``model_force``: the final model's held-out prediction (N)."""
    n = len(log)
    out: dict[str, np.ndarray] = {}
    x0 = log.rig.start_position
    out["position"] = 1e3 * ((x0 or 0.0) + np.asarray(log.displacement))
    if log.time is not None:
        out["time"] = np.asarray(log.time) - float(log.time[0])
    if seg.pressure_level is not None:
        out["pressure"] = np.full(n, seg.pressure_level / 1e5)
    if seg.velocity is not None:
        v = np.asarray(seg.velocity)
        out["velocity"] = 1e3 * v
        if log.time is not None and n > 4:
            out["acceleration"] = 1e3 * _smooth(np.gradient(v, np.asarray(log.time)), 5)
    out["since_reversal"] = 1e3 * _since_reversal(np.asarray(log.displacement), seg.reversals)
    out["direction"] = np.asarray(seg.direction, float)
    out["force"] = np.asarray(model_force, float)
    out["_motion"] = np.asarray(seg.direction, float)
    # the model force has no noise: the sign of its change marks its reversals
    f = np.asarray(model_force, float)
    change = np.sign(np.gradient(f))
    out["_force"] = change
    turn = np.flatnonzero((change[1:] != change[:-1]) & (change[1:] != 0)) + 1
    out["_force_since_reversal"] = _since_reversal(f, turn)
    return out


def _smooth(a: np.ndarray, width: int) -> np.ndarray:
    if a.size < width:
        return a
    kernel = np.ones(width) / width
    padded = np.pad(a, width // 2, mode="edge")
    return np.convolve(padded, kernel, mode="valid")[: a.size]


def _since_reversal(x: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """Travel since the last reversal (or since the start), m."""
    anchor = np.zeros(x.size, dtype=np.int64)
    for r in np.asarray(reversals, dtype=np.int64):
        anchor[r:] = r
    return np.abs(x - x[anchor])


# ---------------------------------------------------------------------------- candidates

@dataclasses.dataclass(frozen=True, eq=False)
class _Candidate:
    variable: str
    form: str              # linear / smooth / periodic / step
    signed: bool
    values: np.ndarray     # the variable, all samples (concatenated logs)
    sign: np.ndarray       # the sign multiplying the columns (ones when even)

    @property
    def label(self) -> str:
        if self.form == "hysteresis":
            return "hysteresis (smooth in the force's change since it last turned)"
        return ("sign-dependent " if self.signed else "") + self.form


def _candidates(per_log: Sequence[Mapping[str, np.ndarray]], log_id: np.ndarray
                ) -> list[_Candidate]:
    n_logs = len(per_log)
    out: list[_Candidate] = []

    def cat(name):
        if any(name not in v for v in per_log):
            return None
        return np.concatenate([v[name] for v in per_log])

    motion, force_sign = cat("_motion"), cat("_force")
    ones = np.ones_like(motion)
    for name in VARIABLES:
        if name == "log":
            if n_logs >= 2:
                out.append(_Candidate("log", "step", True, log_id.astype(float), motion))
            continue
        v = cat(name)
        if v is None or not np.all(np.isfinite(v)):
            continue
        if name == "direction":
            out.append(_Candidate(name, "step", False, v, ones))
            continue
        if name == "pressure":
            levels = np.unique(np.round(v, 3))
            if levels.size >= 2:
                out.append(_Candidate(name, "linear", True, v, motion))
            if levels.size >= 3:
                out.append(_Candidate(name, "curved", True, v, motion))
            continue
        if np.ptp(v) <= 0:
            continue
        sign = force_sign if name == "force" else motion
        if name == "force":         # a nonlinearity of F, a hysteresis in F
            out.append(_Candidate(name, "smooth", False, v, ones))
            travel = cat("_force_since_reversal")
            if travel is not None and np.ptp(travel) > 0:
                out.append(_Candidate(name, "hysteresis", True, travel, sign))
            continue
        if name == "velocity":      # a friction-like law of the speed, or any law of v
            out.append(_Candidate(name, "smooth", True, np.abs(v), sign))
            out.append(_Candidate(name, "smooth", False, v, ones))
            continue
        if name == "acceleration":
            out.append(_Candidate(name, "linear", False, v, ones))
            out.append(_Candidate(name, "smooth", False, v, ones))
            continue
        if name in ("time",):
            out.append(_Candidate(name, "linear", False, v, ones))
            out.append(_Candidate(name, "linear", True, v, sign))
        for signed in (False, True):
            out.append(_Candidate(name, "smooth", signed, v, sign if signed else ones))
        if name == "position" and _periods(v, log_id).size:
            for signed in (False, True):
                out.append(_Candidate(name, "periodic", signed, v, sign if signed else ones))
    return out


def _hats(v: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear hat functions at ``knots`` (constant beyond the ends)."""
    x = np.clip(v, knots[0], knots[-1])
    cols = np.zeros((v.size, knots.size))
    idx = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, knots.size - 2)
    w = (x - knots[idx]) / (knots[idx + 1] - knots[idx])
    rows = np.arange(v.size)
    cols[rows, idx] = 1.0 - w
    cols[rows, idx + 1] += w
    return cols


class _Design:
    """The columns of one candidate given the training samples (knots, period), centred per
    log over all samples (the centring uses no residual)."""

    def __init__(self, cand: _Candidate, log_id: np.ndarray, weight: np.ndarray):
        self.cand, self.log_id, self.weight = cand, log_id, weight
        self.n_logs = int(log_id.max()) + 1
        self.own = (log_id[:, None] == np.arange(self.n_logs)[None, :]).astype(float)
        # the logs lie one after another: per-log sums are sums over these runs of rows
        self._starts = np.flatnonzero(np.r_[True, np.diff(log_id) != 0])
        total = self._per_log(weight)
        self._total = np.where(total > 0, total, 1.0)

    def columns(self, train: np.ndarray, period: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        c = self.cand
        v = c.values
        if c.form == "linear":
            base = v[:, None] - np.mean(v[train])
            pen = np.zeros((1, 1))
        elif c.form == "curved":
            z = v - np.mean(v[train])
            base = np.column_stack([z, z**2])
            pen = np.zeros((2, 2))
        elif c.form == "step":
            if c.variable == "direction":
                base = v[:, None]
            else:
                base = (self.log_id[:, None] == np.arange(self.n_logs)[None, :]).astype(float)
            pen = np.zeros((base.shape[1], base.shape[1]))
        elif c.form == "periodic":
            # one period, a phase per log: logs far apart along the stroke would need the
            # period to a part in 10^5 to share one phase
            phase = 2 * np.pi * v / period
            base = np.concatenate([self.own * np.sin(phase)[:, None],
                                   self.own * np.cos(phase)[:, None]], axis=1)
            pen = np.zeros((base.shape[1], base.shape[1]))
        else:                       # smooth; a hysteresis is smooth in the force's travel
            knots = self._knots(v, train)
            if knots.size < 3:
                knots = np.linspace(v[train].min(), v[train].max() + 1e-12, 3)
            base = _hats(v, knots)
            d2 = np.diff(np.eye(knots.size), 2, axis=0)
            pen = d2.T @ d2
        x = base * c.sign[:, None]
        return self._centre(x), pen

    def _knots(self, v: np.ndarray, train: np.ndarray) -> np.ndarray:
        """``KNOTS`` quantiles of the training values; of each log's own for the position
        (logs far apart along the stroke would otherwise share a handful of knots)."""
        q = np.linspace(0, 1, KNOTS)
        if self.cand.variable != "position":
            return np.unique(np.quantile(v[train], q))
        return np.unique(np.concatenate([np.quantile(v[train & (self.log_id == k)], q)
                                         for k in range(self.n_logs)
                                         if np.any(train & (self.log_id == k))]))

    def _per_log(self, x: np.ndarray) -> np.ndarray:
        """Sums over each log's samples (rows), one row per log."""
        return np.add.reduceat(x, self._starts, axis=0)

    def _centre(self, x: np.ndarray) -> np.ndarray:
        """Each column less its weighted mean over each log's samples."""
        w = self.weight if x.ndim == 1 else self.weight[:, None]
        means = self._per_log(w * x) / (self._total if x.ndim == 1 else self._total[:, None])
        return x - means[self.log_id]

    def period_rss(self, r: np.ndarray, wt: np.ndarray, periods: np.ndarray) -> np.ndarray:
        """The training RSS of the periodic description at each of ``periods`` at once:
        its columns are a sine and a cosine per log, so the least squares fall apart into
        a 2 x 2 system per log and period (what :meth:`columns` and :func:`_ridge` give one
        period at a time)."""
        phase = 2 * np.pi * self.cand.values[:, None] / periods[None, :]
        sign = self.cand.sign[:, None]
        sin, cos = self._centre(sign * np.sin(phase)), self._centre(sign * np.cos(phase))
        ws, wc = wt[:, None] * sin, wt[:, None] * cos
        ss, cc, sc = self._per_log(ws * sin), self._per_log(wc * cos), self._per_log(ws * cos)
        rs, rc = self._per_log(r[:, None] * ws), self._per_log(r[:, None] * wc)
        det = ss * cc - sc**2
        ok = det > 1e-12 * np.maximum(ss * cc, 1e-300)
        safe = np.where(ok, det, 1.0)
        a, b = (cc * rs - sc * rc) / safe, (ss * rc - sc * rs) / safe
        explained = np.where(ok, a * rs + b * rc, 0.0).sum(axis=0)
        return float(np.sum(wt * r**2)) - explained


def _ridge(x: np.ndarray, r: np.ndarray, pen: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Penalised least squares of ``r`` on ``x`` with weights ``w``; the penalty's weight by
    generalised cross-validation (a tiny ridge keeps flat columns harmless)."""
    xtw = x.T * w
    a = xtw @ x
    b = xtw @ r
    n = float(np.sum(w > 0))
    scale = max(float(np.trace(a)) / max(a.shape[0], 1), 1e-300)
    ridge = 1e-9 * scale * np.eye(a.shape[0])
    if not np.any(pen):
        return np.linalg.solve(a + ridge, b)
    best, beta_best = math.inf, None
    for lam in _LAMBDAS:
        m = a + lam * scale * pen + ridge
        try:
            beta = np.linalg.solve(m, b)
            dof = float(np.trace(np.linalg.solve(m, a)))
        except np.linalg.LinAlgError:
            continue
        rss = max(float(np.sum(w * r**2) - 2 * beta @ b + beta @ a @ beta), 0.0)
        gcv = rss / max(n * (1 - dof / n) ** 2, 1e-300)
        if gcv < best:
            best, beta_best = gcv, beta
    return beta_best


def _periods(v: np.ndarray, log_id: np.ndarray) -> np.ndarray:
    """The periods scanned: from 20 sample steps (at least 0.2 of the unit) to half the
    widest log's span (a period is only claimed where two of them were travelled; a
    longer one is a smooth curve); empty when the logs are too short for that."""
    spans = [np.ptp(v[log_id == k]) for k in np.unique(log_id)]
    step = np.median(np.abs(np.diff(v)))
    low = max(0.2, 20 * step)
    high = 0.5 * max(spans)
    return np.geomspace(low, high, _PERIODS) if high > 1.5 * low else np.zeros(0)


def _fit_predict(design: _Design, r: np.ndarray, train: np.ndarray, w: np.ndarray
                 ) -> tuple[np.ndarray, float | None, int]:
    """Fit on ``train`` (weights ``w``), predict every sample; the period chosen on
    ``train`` for a periodic candidate."""
    wt = w * train
    if design.cand.form != "periodic":
        x, pen = design.columns(train)
        beta = _ridge(x, r, pen, wt)
        return x @ beta, None, x.shape[1]
    def rss(period):
        x, pen = design.columns(train, period)
        beta = _ridge(x, r, pen, wt)
        pred = x @ beta
        return float(np.sum(wt * (r - pred) ** 2)), pred, x.shape[1]

    grid = _periods(design.cand.values, design.log_id)
    k = int(np.argmin(design.period_rss(r, wt, grid)))
    # refine between the neighbours of the best grid period
    fine = np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)], 21)
    period = float(fine[int(np.argmin(design.period_rss(r, wt, fine)))])
    _, pred, dof = rss(period)
    return pred, float(period), dof


# -------------------------------------------------------------------------------- the step

def _blocks(log_id: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per sample its block (``BLOCKS`` consecutive blocks of counted samples per log),
    numbered over the logs; -1 for samples that do not count."""
    out = np.full(log_id.size, -1, dtype=np.int64)
    offset = 0
    for k in np.unique(log_id):
        idx = np.flatnonzero((log_id == k) & (weight > 0))
        if idx.size == 0:
            continue
        parts = np.array_split(idx, BLOCKS)
        for b, part in enumerate(parts):
            out[part] = offset + b
        offset += BLOCKS
    return out


@dataclasses.dataclass(frozen=True)
class Described:
    """An accepted description with what its plot needs, all samples of all logs
    concatenated: ``values`` of its variable, the ``sign`` that multiplies it (ones for an
    even form), the residual it described (``residual``: after the descriptions accepted
    before it) and its own held-out prediction."""

    structure: Structure
    values: np.ndarray
    sign: np.ndarray
    residual: np.ndarray
    prediction: np.ndarray


def describe_structure(logs: Sequence[Log], segmentations: Sequence[Segmentation],
                       residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                       noise_N: float, *, alpha: float = STRUCTURE_ALPHA,
                       min_shrink: float = STRUCTURE_MIN_SHRINK,
                       max_accept: int = MAX_ACCEPT,
                       library: Mapping[str, str] | None = None) -> tuple[Structure, ...]:
    """Describe what the held-out residual follows (see the module docstring).

    Args:
        logs, segmentations: the diagnosed logs and their segmentations.
        residuals: per log, the final model's held-out residual (model - measured, N).
        masks: per log, the samples that count.
        noise_N: the pooled noise floor (N).
        library: the library effects tried and not accepted, with why (a description with
            one's shape says so, :data:`LOOKALIKES`).

    Returns:
        The accepted descriptions in order, then the best description of every other
        variable tried in the last round (not accepted, with why), best first.
    """
    found, rest = _describe(logs, segmentations, residuals, masks, noise_N, alpha=alpha,
                            min_shrink=min_shrink, max_accept=max_accept, library=library)
    return tuple(d.structure for d in found) + tuple(rest)


def accepted_descriptions(logs: Sequence[Log], segmentations: Sequence[Segmentation],
                          residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                          noise_N: float, **rule) -> tuple[Described, ...]:
    """:func:`describe_structure`'s accepted descriptions with their data (for plots)."""
    return tuple(_describe(logs, segmentations, residuals, masks, noise_N, **rule)[0])


def _describe(logs, segmentations, residuals, masks, noise_N, *,
              alpha: float = STRUCTURE_ALPHA, min_shrink: float = STRUCTURE_MIN_SHRINK,
              max_accept: int = MAX_ACCEPT, library: Mapping[str, str] | None = None
              ) -> tuple[list[Described], list[Structure]]:
    from scipy import stats

    r_logs = [np.asarray(r, float) for r in residuals]
    per_log = [structure_variables(log, seg, np.asarray(log.force) + r)
               for log, seg, r in zip(logs, segmentations, r_logs)]
    log_id = np.concatenate([np.full(len(r), k) for k, r in enumerate(r_logs)])
    weight = np.concatenate([np.asarray(m, float) for m in masks])
    r = np.concatenate(r_logs)
    r = np.where(weight > 0, r, 0.0)
    block = _blocks(log_id, weight)
    fold = np.where(block >= 0, block % FOLDS, -1)
    n_blocks = int(block.max()) + 1
    counted = weight > 0
    candidates = _candidates(per_log, log_id)
    if not candidates or n_blocks < 4 or not counted.any():
        return [], []
    designs = [_Design(c, log_id, weight) for c in candidates]
    relative = any(log.rig.start_position is None for log in logs)

    accepted: list[Described] = []
    last: list[Structure] = []
    for round_ in range(1, max_accept + 1):
        before = math.sqrt(float(np.sum(weight * r**2) / weight.sum()))
        if before <= noise_N:
            why = (f"no gap left: held-out RMS {before:.3g} N is at the noise floor "
                   f"{noise_N:.3g} N")
            last = [dataclasses.replace(s, why=why) for s in last]
            break
        t_needed = float(stats.t.ppf(1 - alpha / len(designs), n_blocks - 1))
        tried = []
        for design in designs:
            pred = np.zeros_like(r)
            for f in range(FOLDS):
                test = fold == f
                pred[test] = _fit_predict(design, r, (fold >= 0) & ~test, weight)[0][test]
            gains = np.bincount(block[counted], weights=(weight * (r**2 - (r - pred) ** 2))
                                [counted], minlength=n_blocks)
            sd = float(np.std(gains, ddof=1))
            t = float(np.mean(gains) / (sd / math.sqrt(n_blocks))) if sd > 0 else 0.0
            after = math.sqrt(float(np.sum(weight * (r - pred) ** 2) / weight.sum()))
            full, period, dof = _fit_predict(design, r, fold >= 0, weight)
            shown, axis = _shown(design.cand, log_id, counted, full, period)
            tried.append(_Tried(design.cand, pred, full, period, dof, t, before, after, shown,
                                axis))
        shrinks = {id(x): (x.before - x.after) / (x.before - noise_N) for x in tried}
        passing = [x for x in tried
                   if x.t > t_needed and x.before - x.after >= MIN_GAIN * noise_N
                   and shrinks[id(x)] >= min_shrink]
        band = TIE * noise_N

        def order(x):
            return (round((x.after - best_after) / band) if band > 0 else x.after,
                    x.dof, VARIABLES.index(x.cand.variable))

        best_by_var = _best_per_variable(tried, band)
        if not passing:
            last = [_record(x, relative, noise_N, accepted=False, round_=round_,
                            t_needed=t_needed,
                            why=_why_not(x, t_needed, noise_N, min_shrink, shrinks[id(x)]))
                    for x in sorted(best_by_var, key=lambda x: x.after)]
            break
        best_after = min(x.after for x in passing)
        chosen = min(passing, key=order)
        gain = chosen.before - chosen.after
        rivals = tuple(x.cand.variable for x in best_by_var
                       if x.cand.variable != chosen.cand.variable
                       and (x.after - best_after <= band or any(x is y for y in passing)
                            and x.before - x.after >= RIVAL_GAIN * gain)
                       and _corr(x.pred, chosen.pred, weight) > CONFOUNDED)
        apart = (chosen.cand.form in ("linear", "smooth", "curved")
                 and _disjoint(chosen.cand.values, log_id, counted))
        accepted.append(Described(
            _record(chosen, relative, noise_N, accepted=True, round_=round_,
                    t_needed=t_needed, rivals=rivals, apart=apart, library=library or {}),
            chosen.shown, chosen.cand.sign, r, chosen.pred))
        r = r - chosen.pred
        designs = [d for d in designs if d.cand.variable != chosen.cand.variable]
        last = []
        if not designs:
            break
    return accepted, last


@dataclasses.dataclass(eq=False)
class _Tried:
    cand: _Candidate
    pred: np.ndarray       # held-out prediction (its own folds)
    full: np.ndarray       # fitted to all counted samples
    period: float | None
    dof: int
    t: float
    before: float
    after: float
    shown: np.ndarray      # the variable as plotted (see _shown)
    axis: str              # what `shown` is, with its unit


def _best_per_variable(tried: Sequence[_Tried], band: float) -> list[_Tried]:
    best: dict[str, _Tried] = {}
    for x in tried:
        cur = best.get(x.cand.variable)
        if cur is None or x.after < cur.after - band or (
                abs(x.after - cur.after) <= band and x.dof < cur.dof):
            best[x.cand.variable] = x
    return list(best.values())


def _disjoint(v: np.ndarray, log_id: np.ndarray, counted: np.ndarray) -> bool:
    """Whether no two logs share a range of ``v`` (two logs or more): a curve of ``v`` is
    then as well a shape of its own per log."""
    ranges = sorted((float(v[m].min()), float(v[m].max()))
                    for k in np.unique(log_id) if (m := (log_id == k) & counted).any())
    return len(ranges) >= 2 and all(a[1] < b[0] for a, b in zip(ranges, ranges[1:]))


def _corr(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> float:
    a, b = a - np.average(a, weights=w), b - np.average(b, weights=w)
    den = math.sqrt(float(np.sum(w * a * a) * np.sum(w * b * b)))
    return float(np.sum(w * a * b)) / den if den > 0 else 0.0


def _why_not(x: _Tried, t_needed: float, noise: float, min_shrink: float,
             shrink: float) -> str:
    if x.t <= t_needed:
        return f"not significant on held-out blocks (t = {x.t:.2g}, needs > {t_needed:.2g})"
    if x.before - x.after < MIN_GAIN * noise:
        return (f"held-out RMS falls by {x.before - x.after:.2g} N, less than "
                f"{MIN_GAIN:.0%} of the noise floor")
    return f"removes {shrink:.0%} of the gap above the noise, needs {min_shrink:.0%}"


def _record(x: _Tried, relative: bool, noise: float, *, accepted: bool, round_: int,
            t_needed: float, rivals: tuple[str, ...] = (), apart: bool = False,
            why: str = "", library: Mapping[str, str] = {}) -> Structure:
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
    effects, record = _SUGGEST.get((c.variable, c.signed), _SUGGEST.get(
        (c.variable, not c.signed), ("", "")))
    suggestion = (f"Usually {effects}; to pin it down, {record}" if effects else "")
    if rivals:
        suggestion += (f". The logs cannot tell it from {', '.join(rivals)} (the same "
                       "prediction): record data that vary them separately")
    if apart and "log" not in rivals:
        rivals += ("log",)
        suggestion += (f". The logs cannot tell it from log: no two logs share a range of "
                       f"the {c.variable.replace('_', ' ')}, so the curve is as well a shape "
                       "of each log's own; record two logs over one range of it")
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


def _shown(cand: _Candidate, log_id: np.ndarray, counted: np.ndarray, full: np.ndarray,
           period: float | None) -> tuple[np.ndarray, str]:
    """The variable as a plot of the description shows it, and the axis' label: within the
    period for a periodic one (:func:`_folded`); from each log's middle where the logs lie
    apart in it (a curve per log, side by side); else as it is."""
    name = cand.variable.replace("_", " ")
    unit = f" ({UNITS[cand.variable]})" if UNITS[cand.variable] else ""
    if cand.form == "hysteresis":
        return cand.values, f"the force's change since it last turned{unit}"
    if period is not None:
        return (_folded(cand, log_id, full, period),
                f"{name} within the period, each log's phase aligned{unit}")
    if cand.form in ("linear", "smooth") and _disjoint(cand.values, log_id, counted):
        out = cand.values.copy()
        for k in np.unique(log_id):
            m = log_id == k
            out[m] -= np.median(cand.values[m & counted]) if (m & counted).any() else 0.0
        return out, f"{name} from each log's middle{unit}"
    return cand.values, f"{name}{unit}"


def _folded(cand: _Candidate, log_id: np.ndarray, full: np.ndarray, period: float
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


def _shape(x: _Tried) -> dict[str, list[float]]:
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
