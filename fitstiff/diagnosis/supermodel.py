"""The baseline plus every candidate effect as one model, compiled once (DESIGN §6).

Every candidate nests the baseline at a null value of its parameters (viscous ``c = 0``,
Stribeck ratio 1, Maxwell-slip stiffnesses 0, the chamber's ``gate`` 0 for ``chamber:gated``),
so the baseline, the baseline with any set of candidates and the full model are one
:class:`~fitstiff.inference.problem.Problem` whose free parameters are chosen by masks given at run
time. Screens (score statistics) and refits (least squares on training folds, held-out
predictions) all call the same compiled functions:

- :meth:`SuperProblem.solve` - Levenberg-Marquardt over the entries of ``theta`` selected by
  a mask, the others held; the model parameters that are not free take values from ``hold``
  in physical (SI) units, so a candidate that is not in the model sits exactly at its null
  (never at a transform's bound); residual entries are weighted by a run-time vector (a
  held-out log or loop weighs 0);
- :meth:`SuperProblem.jacobian` - residuals and their Jacobian with respect to every model
  parameter in physical coordinates and every nuisance, the input of the score screen;
- :meth:`SuperProblem.forces` - the predicted force of every log.

Solves and forces in which no candidate that makes the model expensive to run is live (free,
or held away from its null) run on a lighter compiled problem, the super-model without those
candidates (:func:`_heavy`): they add nothing at their nulls, so the result is the same, at a
fraction of the cost (see :class:`SuperProblem`).
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference.fitting import initial_guess
from fitstiff.inference.lm import CONVERGED, levenberg_marquardt
from fitstiff.inference.problem import Problem
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import parse_spec
from fitstiff.physics.terms import EFFECTS, FRICTION_BASES, TERMS
from fitstiff.physics.terms.base import Modifier, SeriesTerm
from fitstiff.physics.terms.chamber import Chamber

__all__ = ["CANDIDATES", "SuperProblem", "best_solve", "candidate_names", "spec_token", "Owner"]

#: every effect the diagnosis can name (DESIGN §3), ``chamber`` for friction-only baselines
CANDIDATES = EFFECTS + ("chamber",)
_TOKENS = {"maxwell_slip": "maxwell_slip:4", "chamber": "chamber:gated",
           "rig_compliance": "rig_compliance:measured"}
_NEEDS_FRICTION = ("stribeck", "asymmetry", "pressure_friction", "dwell_stiction",
                   "maxwell_slip")
_NEEDS_CHAMBER = ("heat_transfer", "leakage")
#: candidates whose shape parameters are held on a grid but where the candidate itself is
#: fitted once it explains the gap (:meth:`SuperProblem.own`): Maxwell-slip's slip
#: displacements start on a log-spaced grid (scaled by the baseline's Fc / sigma0); a refit
#: that passes on the grid is refitted with them free (``_rounds._refine_shapes``), and the
#: full-data fit of an accepted candidate (or pair) frees them; once accepted they stay where
#: each fit put them. Held on the grid, the law's sets ended 0.52-0.78 N in-sample against a
#: 0.19-0.27 N floor (docs/benchmarks.md); free in every later round too, the joint solves
#: of the next candidate with them wandered (a pair's heat exchange ended above its start)
FIXED_SHAPE = ("maxwell_slip",)
#: tolerance of the diagnosis' solves (steps relative to the entries, cost changes relative to
#: the cost); the decisions compare held-out RMS values at a resolution of 5 % of the noise
#: floor, far coarser than the 1e-5 relative cost change at which a solve stops
_RTOL = 1e-5


def _heavy(term) -> bool:
    """A term that makes every sample of a model a step of its scan: a modifier of the
    chamber (the polytropic chamber otherwise runs over all samples at once) or a series
    compliance (couples every term to the piston motion). On 32 000 + 3 x 6 400 samples the
    super-model's residuals took 99 ms, without heat_transfer and leakage 7 ms, the baseline
    chamber+dahl 1 ms (``benchmarks/diagnosis_speed.py --size real``, issue 31)."""
    return isinstance(term, SeriesTerm) or (isinstance(term, Modifier)
                                             and issubclass(term.targets, Chamber))


def spec_token(effect: str) -> str:
    """The spec token that adds ``effect`` to a model as a candidate."""
    return _TOKENS.get(effect, effect)


def candidate_names(baseline: str, requested: str | Sequence[str] = "all", *,
                    logs: Sequence[Log] = ()) -> tuple[list[str], dict[str, str]]:
    """The candidates to screen on ``baseline`` and, for ``"all"``, those left out with why.

    Explicitly requested candidates that cannot apply are an :class:`InputError` (unknown
    name, already in the baseline, base missing, rig data missing); with ``"all"`` they are
    left out and listed.
    """
    base = [name for name, _ in parse_spec(baseline)]
    explicit = not (isinstance(requested, str) and requested == "all")
    names = list(CANDIDATES) if not explicit else (
        [n.strip() for n in requested.split(",") if n.strip()] if isinstance(requested, str)
        else list(requested))
    if explicit and not names:
        raise InputError(None, "--candidates", "names no candidate",
                         f"give 'all' or a comma-separated list of: {', '.join(CANDIDATES)}")
    chosen, skipped = [], {}
    for name in names:
        if name not in CANDIDATES:
            raise InputError(None, f"--candidates {name}", "is not a candidate effect",
                             f"use 'all' or names from: {', '.join(CANDIDATES)}")
        why = _not_applicable(name, base, logs)
        if not explicit and name in base:
            continue
        if why is None:
            chosen.append(name)
        elif explicit:
            raise InputError(None, f"--candidates {name}", why[0], why[1])
        else:
            skipped[name] = why[0]
    if not chosen:
        raise InputError(None, "--candidates", "no candidate applies to this baseline",
                         "choose another baseline; skipped: "
                         + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    return chosen, skipped


def _not_applicable(name: str, base: list[str], logs: Sequence[Log]):
    friction = [b for b in base if b in FRICTION_BASES]
    if name in base:
        return (f"'{name}' is already in the baseline", "drop it from --candidates or the "
                "baseline")
    if name == "maxwell_slip" and not friction:
        return ("'maxwell_slip' tests non-local memory on a Dahl or LuGre baseline",
                "add a friction base (dahl, lugre) to the baseline")
    if name == "maxwell_slip" and friction != ["dahl"] and "lugre" not in friction:
        return ("'maxwell_slip' as a candidate needs a Dahl or LuGre base",
                "use a baseline with dahl or lugre")
    if name in _NEEDS_FRICTION and not friction:
        return (f"'{name}' modifies a friction base and the baseline has none",
                "add a friction base (dahl, lugre, maxwell_slip, coulomb) to the baseline")
    if name == "stribeck" and "lugre" in base:
        return ("'lugre' already contains the Stribeck curve", "drop 'stribeck'")
    if name in _NEEDS_CHAMBER and "chamber" not in base:
        return (f"'{name}' modifies the chamber term and the baseline has none",
                "add 'chamber' to the baseline")
    if TERMS[name].needs_chamber_geometry and logs:
        for log in logs:
            has_pressure = (log.rig.supply_pressure is not None or log.pressure_a is not None
                            or log.pressure_b is not None)
            if log.rig.bore is None or not has_pressure:
                missing = "bore_mm" if log.rig.bore is None else "supply_bar or a pressure column"
                return (f"'{name}' needs chamber pressures and the bore, and log "
                        f"'{log.name}' has no {missing}",
                        f"give {missing} (sidecar or --{missing.split()[0].replace('_', '-')})"
                        " or leave the candidate out")
        if name == "chamber" and not all(log.rig.stroke and log.rig.start_position is not None
                                         for log in logs if log.pressure_a is None
                                         or log.pressure_b is None):
            return ("'chamber' needs stroke_mm and start_position_mm for closed chambers",
                    "give them in the sidecars or leave the candidate out")
    if name == "time_delay" and logs and any(log.time is None for log in logs):
        return ("'time_delay' needs a time column in every log", "log time")
    return None


@dataclasses.dataclass(frozen=True)
class Owner:
    """Which term a parameter element belongs to and its role in the diagnosis."""

    term: str            # the term's canonical name
    name: str            # flat parameter name
    tested: bool         # has a null value: the score tests it
    null: float          # SI null value (NaN for shape parameters)
    fixed: bool = False  # a shape parameter held on its grid (FIXED_SHAPE)


class SuperProblem:
    """The baseline and all candidates as one :class:`~fitstiff.inference.problem.Problem`.

    Args:
        logs: the logs.
        baseline: the baseline spec (``"chamber+dahl"``).
        candidates: effect names (:func:`candidate_names`).
        selection: the data options (:class:`~fitstiff.inference.selection.Selection`), or
            its fields as keywords.
    """

    def __init__(self, logs: Sequence[Log], baseline: str, candidates: Sequence[str], *,
                 selection: Selection | None = None, **options):
        self.baseline_terms = tuple(name for name, _ in parse_spec(baseline))
        self.candidates = tuple(candidates)
        spec = "+".join([baseline] + [spec_token(c) for c in candidates])
        self.problem = Problem(logs, spec, selection=Selection.given(selection, options))
        par = self.problem.par
        model = self.problem.model
        nulls = par.nulls()
        self.owners = tuple(Owner(model.terms[e.term_index].name, e.name,
                                  e.param.null is not None
                                  and model.terms[e.term_index].name not in self.baseline_terms,
                                  float(nulls[k]),
                                  model.terms[e.term_index].name in FIXED_SHAPE
                                  and model.terms[e.term_index].name not in self.baseline_terms
                                  and e.param.null is None)
                            for k, e in enumerate(par.entries))
        self.n_model = par.size
        self.size = self.problem.size
        self.units = par.units()
        self.series = self.problem.residual_series()
        self.n_residuals = max(s.span.stop for s in self.series)
        # sized for the refits on the grid: every solve carries as many tangents as its
        # padded length (4 more for Maxwell-slip's slip displacements cost 7 s cold at
        # real size); a refit that frees them too compiles its own length when it comes
        largest = max((self.elements(c, fitted=True).size for c in self.candidates),
                      default=0)
        self._full = _Solver(self.problem, int(self.model_mask(self.baseline_terms).sum())
                             + largest)
        self._jac = self.problem.compiled(_jacobian, n_model=self.n_model)
        self._column = self.problem.compiled(_column)
        heavy = {t.name for t in model.terms if _heavy(t)} & set(self.candidates)
        self._heavy = np.array([o.term in heavy for o in self.owners])
        self._heavy_tested = np.flatnonzero(self._heavy & np.array([o.tested
                                                                      for o in self.owners]))
        self._nulls = np.array([o.null for o in self.owners])
        light = (_Light(self, baseline, [c for c in self.candidates if c not in heavy])
                 if heavy else None)
        self._light = light if light is not None and light.maps else None
        #: the spec of the lighter problem that solves run on when no heavy candidate is live
        #: (``None``: every solve runs on the super-model)
        self.light_spec = self._light.spec if self._light is not None else None

    # -- masks ------------------------------------------------------------------------------
    def model_mask(self, terms: Sequence[str]) -> np.ndarray:
        """Model entries fitted when ``terms`` (canonical term names) are in the model (a
        candidate's fixed shape parameters are not)."""
        return np.array([o.term in terms and not o.fixed for o in self.owners])

    def elements(self, effect: str, *, tested: bool | None = None,
                 fitted: bool = False) -> np.ndarray:
        """Indices (into the model entries) of ``effect``'s parameters: all, or only the
        tested (``True``) or shape (``False``) ones; ``fitted``: without the fixed shape
        parameters (:data:`FIXED_SHAPE`)."""
        return np.array([k for k, o in enumerate(self.owners) if o.term == effect
                         and (tested is None or o.tested == tested)
                         and not (fitted and o.fixed)], dtype=int)

    def fitting(self, active: Sequence[str], effects: Sequence[str]) -> np.ndarray:
        """Model entries a full fit of ``active`` with the candidates ``effects`` frees: the
        model's, and the candidates' own with their fixed shape (:meth:`own`)."""
        free = self.model_mask(list(active) + list(effects))
        free[self.own(*effects)] = True
        return free

    def own(self, *effects: str) -> np.ndarray:
        """Indices of the model entries a refit of the candidates ``effects`` frees on top
        of the model: all their parameters, their fixed shape (:data:`FIXED_SHAPE`) too."""
        return np.concatenate([np.zeros(0, dtype=int)] + [self.elements(e) for e in effects])

    def nuisance_mask(self, logs: Sequence[int] | None = None, *,
                      names: Sequence[str] | None = None) -> np.ndarray:
        """Nuisance entries of ``logs`` (indices; all logs by default), of the nuisances
        ``names`` (all by default)."""
        p = self.problem
        keep = np.zeros(self.size - self.n_model, dtype=bool)
        for j, name in enumerate(p.nuisance_names):
            if names is not None and name not in names:
                continue
            for i in range(p.n_logs):
                if logs is None or i in logs:
                    keep[j * p.n_logs + i] = True
        return keep

    def entry_weights(self, *, logs: Sequence[int] | None = None,
                      samples: Mapping[int, np.ndarray] | None = None) -> np.ndarray:
        """Run-time weights of the residual entries: 1 on the given ``logs`` (all by default),
        0 elsewhere; ``samples`` maps a log to a boolean per-sample mask to keep."""
        w = np.zeros(self.n_residuals)
        for s in self.series:
            if logs is not None and s.log not in logs:
                continue
            keep = np.ones(s.span.stop - s.span.start)
            if samples is not None and s.log in samples:
                mask = np.asarray(samples[s.log], dtype=float)
                keep[:mask.size] = mask
                keep[mask.size:] = 0.0
            w[s.span] = keep
        return w

    # -- starting point -----------------------------------------------------------------------
    def start(self, values: Mapping[str, float] | None = None, *,
              samples: Sequence[np.ndarray | None] | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, hold)``: the data-driven start of the baseline, candidates at their null
        (shape parameters at their defaults) and ``values`` (SI, by flat name) on top;
        ``samples``: what may inform it (a fold's training part, see
        :func:`~fitstiff.inference.fitting.initial_guess`)."""
        model0, nuis0 = initial_guess(self.problem, bases=self.baseline_terms, samples=samples)
        theta = np.array(self.problem.pack(model0, nuis0), dtype=float)
        hold = np.array(self.problem.par.physical(jnp.asarray(theta[:self.n_model])))
        for k, o in enumerate(self.owners):
            if o.tested:
                hold[k] = o.null
        for name, value in (values or {}).items():
            hold[self.problem.par.names.index(name)] = value
        return theta, hold

    def to_theta(self, theta: np.ndarray, hold: np.ndarray, entries: np.ndarray) -> np.ndarray:
        """``theta`` with the model ``entries`` set to the unconstrained image of ``hold``
        (values on a bound are nudged inside by the transforms)."""
        par = self.problem.par
        model = par.physical_to_model(jnp.asarray(hold), self.problem.model)
        y = np.asarray(par.to_unconstrained(model))
        out = np.array(theta, dtype=float)
        out[entries] = y[entries]
        return out

    # -- compiled functions ------------------------------------------------------------------
    def physical(self, theta, hold, free_model):
        return jnp.where(free_model, self.problem.par.physical(theta[:self.n_model]), hold)

    def solve(self, theta0, hold, free_model, free_nuisance, weights, *, max_steps=200):
        """Least squares over the free entries; returns ``(theta, converged, steps, cost)``.

        The solver sees only the free entries (gathered into a vector of a fixed length, padded
        with a slot that changes nothing), so the Jacobian through the scan carries as many
        tangents as there are free entries, not the whole super-model's. Two lengths are
        compiled: the largest model + nuisance set of the diagnosis, and one log's nuisances
        (the held-out predictions); a model enlarged by accepted effects beyond the first adds
        one more (rounded up to a multiple of 4, so a greedy round compiles at most once).
        With no heavy candidate (:func:`_heavy`) live (none free, all held at their nulls),
        the solve runs on the lighter problem without them (:class:`_Light`).
        """
        theta0 = np.asarray(theta0, dtype=float)
        hold, free_model = np.asarray(hold, dtype=float), np.asarray(free_model, dtype=bool)
        if self._light is None or self._live_heavy(hold, free_model):
            return self._full.solve(theta0, hold, free_model, free_nuisance, weights,
                                    max_steps=max_steps)
        return self._light.solve(theta0, hold, free_model, free_nuisance, weights,
                                 max_steps=max_steps)

    def solve_best(self, starts, free_model, free_nuisance, weights, *, max_steps=200):
        """:meth:`solve` from each of ``starts`` (objects with ``theta`` and ``hold``); returns
        ``(theta, converged, steps, cost, hold)`` of the converged solve of lowest cost (the
        lowest cost when none converged), ``steps`` summed over all, ``hold`` its start's."""
        return best_solve([(*self.solve(start.theta, start.hold, free_model, free_nuisance,
                                        weights, max_steps=max_steps), start.hold)
                           for start in starts])

    def _live_heavy(self, x, free_model=None) -> bool:
        """Whether a heavy candidate is in the model: free, or held away from its null."""
        if free_model is not None and np.any(free_model & self._heavy):
            return True
        k = self._heavy_tested
        return bool(np.any(x[k] != self._nulls[k]))

    def jacobian(self, x, theta) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and ``d residuals / d (x, nuisances)`` at physical model values ``x``."""
        r, j = self._jac(jnp.asarray(x), jnp.asarray(theta))
        return np.asarray(r), np.asarray(j)

    def column(self, x, theta, tangent) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and their derivative along one physical ``tangent`` (one JVP)."""
        r, c = self._column(jnp.asarray(x), jnp.asarray(theta), jnp.asarray(tangent))
        return np.asarray(r), np.asarray(c)

    def forces(self, x, theta) -> list[np.ndarray]:
        """Predicted force (N) of every log, unpadded, in log order."""
        x = np.asarray(x, dtype=float)
        if self._light is None or self._live_heavy(x):
            return self._full.forces(x, theta)
        return self._light.forces(x, theta)

    def residuals(self, x, theta) -> np.ndarray:
        """The residual vector at physical model values ``x`` (unweighted)."""
        x = np.asarray(x, dtype=float)
        if self._light is None or self._live_heavy(x):
            return self._full.residuals(x, theta)
        return self._light.residuals(x, theta)


class _Solver:
    """One compiled problem's masked solves and predicted forces (the super-model's, or the
    lighter one's of :class:`_Light`). ``largest``: the most model entries a solve frees."""

    def __init__(self, problem: Problem, largest: int):
        self.problem = problem
        self.size = problem.size
        n_nuisance = problem.size - problem.par.size
        self._lengths = {len(problem.nuisance_names), largest + n_nuisance}
        self._lock = threading.Lock()
        # the held-out folds call the compiled functions from two threads; the first call
        # of each (function, length) traces and compiles, and is made by one thread alone
        self._compiling = threading.Lock()
        self._warm: set[tuple] = set()
        self._solve = problem.compiled(_masked_solve)
        self._outputs = problem.compiled(_outputs)

    def solve(self, theta0, hold, free_model, free_nuisance, weights, *, max_steps=200):
        """:meth:`SuperProblem.solve` on this problem."""
        free = np.flatnonzero(np.concatenate([free_model, free_nuisance]))
        with self._lock:       # held-out folds solve from two threads
            size = next((k for k in sorted(self._lengths) if k >= free.size), None)
            if size is None:       # accepted effects enlarged the model: one more length
                size = 4 * -(-free.size // 4)
                self._lengths.add(size)
        index = np.full(size, self.size)          # the padding slot: theta[size] is unused
        index[:free.size] = free
        theta_pad = np.append(np.asarray(theta0, dtype=float), 0.0)
        theta, result, steps, cost = self._once(
            ("solve", size, max_steps), self._solve, jnp.asarray(theta_pad),
            jnp.asarray(index), jnp.asarray(hold), jnp.asarray(free_model),
            jnp.asarray(weights), max_steps)
        ok = int(result) == CONVERGED and bool(np.isfinite(cost))
        return np.asarray(theta)[:self.size], ok, int(steps), float(cost)

    def forces(self, x, theta) -> list[np.ndarray]:
        """Predicted force (N) of every log, unpadded, in log order."""
        return self.problem.unpad(self._once(("outputs",), self._outputs, jnp.asarray(x),
                                             jnp.asarray(theta))[1])

    def residuals(self, x, theta) -> np.ndarray:
        """The residual vector at physical model values ``x``."""
        return np.asarray(self._once(("outputs",), self._outputs, jnp.asarray(x),
                                     jnp.asarray(theta))[0])

    def _once(self, key, fn, *args):
        """``fn(*args)``; its first call per ``key`` (a compilation) by one thread at a time:
        the other fold's thread waits and reuses it instead of tracing and compiling the same
        function a second time beside it."""
        if key in self._warm:
            return fn(*args)
        with self._compiling:
            out = jax.block_until_ready(fn(*args))
            self._warm.add(key)
        return out


class _Light:
    """The super-model without its heavy candidates (:func:`_heavy`), compiled on its own:
    a solve or prediction in which none of them is live runs here, its entries mapped from
    and back to the super-model's by term and parameter name. At their nulls the heavy
    candidates add nothing, so the result is the super-model's (checked at construction: the
    layout of the residuals and the parameters' transforms must agree)."""

    def __init__(self, sp: SuperProblem, baseline: str, keep: Sequence[str]):
        spec = "+".join([baseline] + [spec_token(c) for c in keep])
        self.spec = spec
        problem = Problem(sp.problem.logs, spec, segmentations=sp.problem.segmentations,
                          selection=sp.problem.selection)
        where = {(o.term, o.name): k for k, o in enumerate(sp.owners)}
        terms = problem.model.terms
        self.model = np.array([where[(terms[e.term_index].name, e.name)]
                               for e in problem.par.entries], dtype=int)
        n_logs = problem.n_logs
        super_names = sp.problem.nuisance_names
        self.nuisance = np.array([super_names.index(name) * n_logs + i
                                  for name in problem.nuisance_names for i in range(n_logs)],
                                 dtype=int)
        self.n_model = sp.n_model
        same_layout = ([(r.log, r.channel, r.span) for r in problem.residual_series()]
                       == [(r.log, r.channel, r.span) for r in sp.series])
        # the transforms agree where they matter, at any one point (no data-driven start:
        # that would repeat the super-model's initial guess)
        probe = jnp.linspace(-1.0, 1.0, sp.n_model)
        same_transforms = np.allclose(
            np.asarray(problem.par.physical(probe[self.model])),
            np.asarray(sp.problem.par.physical(probe))[self.model], rtol=1e-12, atol=0.0)
        #: False when the light problem does not map onto the super-model (then unused)
        self.maps = same_layout and same_transforms
        largest = max((sp.elements(c, fitted=True).size for c in keep), default=0)
        self.solver = _Solver(problem, int(sp.model_mask(sp.baseline_terms).sum()) + largest)

    def _theta(self, theta) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        return np.concatenate([theta[self.model], theta[self.n_model + self.nuisance]])

    def solve(self, theta0, hold, free_model, free_nuisance, weights, *, max_steps=200):
        th, ok, steps, cost = self.solver.solve(
            self._theta(theta0), hold[self.model], free_model[self.model],
            np.asarray(free_nuisance, dtype=bool)[self.nuisance], weights, max_steps=max_steps)
        out = np.array(theta0, dtype=float)
        out[self.model] = th[:self.model.size]
        out[self.n_model + self.nuisance] = th[self.model.size:]
        return out, ok, steps, cost

    def forces(self, x, theta) -> list[np.ndarray]:
        return self.solver.forces(x[self.model], self._theta(theta))

    def residuals(self, x, theta) -> np.ndarray:
        return self.solver.residuals(x[self.model], self._theta(theta))


def _jacobian(p: Problem, x, theta, *, n_model: int):
    """Residuals and ``d residuals / d (x, nuisances)`` at physical model values ``x``."""
    def f(x, nuis):
        return p.residuals_physical(x, jnp.concatenate([theta[:n_model], nuis]))

    nuis = theta[n_model:]
    jx, jn = jax.jacfwd(f, argnums=(0, 1))(x, nuis)
    return f(x, nuis), jnp.concatenate([jx, jn], axis=1)


def _column(p: Problem, x, theta, tangent):
    return jax.jvp(lambda x: p.residuals_physical(x, theta), (x,), (tangent,))


def best_solve(solves) -> tuple:
    """Of several solves of one problem from different starts, each ``(theta, converged,
    steps, cost, hold)`` in the starts' order: the converged one of lowest cost (the lowest
    cost when none converged; the first on a tie), with ``steps`` summed over all."""
    best, steps = None, 0
    for theta, ok, n, cost, hold in solves:
        steps += int(n)
        cost = float(cost) if np.isfinite(cost) else np.inf
        key = (not bool(ok), cost)
        if best is None or key < best[0]:
            best = (key, theta, bool(ok), cost, hold)
    _, theta, ok, cost, hold = best
    return theta, ok, steps, cost, hold


def _outputs(p: Problem, x, theta):
    """The residual vector and every stack's predicted force at physical model values ``x``:
    one compiled function for both (a second would cost a compilation of the whole model,
    about 2 s at real size, for outputs the first computes anyway)."""
    model, nuisances = p.par.physical_to_model(x, p.model), p.nuisances(theta)
    predictions = p.model_predictions(model, nuisances)
    return (p.model_residuals(model, nuisances, predictions=predictions),
            [pred.force for pred in predictions])


def _masked_solve(p: Problem, theta_pad, index, hold, free_model, weights, max_steps):
    """One masked least-squares solve of a super-problem (compiled per gathered length)."""
    n_model = p.par.size

    def residuals(z):
        theta = theta_pad.at[index].set(z)[:-1]
        x = jnp.where(free_model, p.par.physical(theta[:n_model]), hold)
        return p.weighted_residuals(x, theta, weights)

    sol = levenberg_marquardt(residuals, theta_pad[index], rtol=_RTOL, atol=_RTOL,
                              max_steps=max_steps)
    return theta_pad.at[index].set(sol.value), sol.status, sol.steps, sol.cost
