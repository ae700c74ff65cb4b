"""A finished run re-opened: its result and manifest, the verified logs, the rebuilt problem,
and the model's curves recomputed from the result (what :mod:`fitstiff.present.report` draws).

>>> from fitstiff.present.reopen import open_run, fit_curves
>>> run = open_run("out/fit")                                 # doctest: +SKIP
>>> curves = fit_curves(run)                                  # doctest: +SKIP

**What kind of run.** The directory's result file decides (:data:`RESULT_FILES`, first match):
``posterior.json``, ``fit.json`` or ``diagnosis.json``. The directory's ``manifest.json``
must list that file among its outputs, so a manifest of another run in the same directory is
not mistaken for this one's.

**The data.** The logs are re-read from the manifest's ``inputs`` after checking every file's
SHA-256 (a missing or changed file is an :class:`~fitstiff.errors.InputError` naming it),
with the manifest's reading options (``options["reading"]``: keyword arguments of
:func:`~fitstiff.io.loading.load_logs`, when recorded), and the
:class:`~fitstiff.inference.problem.Problem` is rebuilt with the recorded model, fixed parameters
and data options (:class:`~fitstiff.inference.selection.Selection`).

**The curves are recomputed, not stored.** Fit: the parameters of ``fit.json`` and each log's
offset and initial friction state give the fitted ``theta`` exactly; every log's RMS residual
must reproduce ``fit.json`` (else the logs were read or the rig set up differently, and it
says so instead of drawing another fit). Posterior: the median and spread of the model-force
draws that ``fitstiff posterior`` stored in ``predictive.npz`` (at every sample) give the
median curve and a 90 % posterior-predictive band (the spread combined with the estimated
noise level); the most probable kept draw of ``chain.h5`` gives the per-term forces. For a
run without those arrays they are recomputed from draws of ``chain.h5``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference.fitting import FitResult
from fitstiff.inference.posterior import PREDICTIVE, Posterior, PosteriorRecord
from fitstiff.inference.posterior.chain import CHAIN, ChainStore
from fitstiff.inference.nuisances import NUISANCES
from fitstiff.inference.problem import Problem
from fitstiff.inference.selection import Selection
from fitstiff.io.loading import load_logs
from fitstiff.io.log import Log
from fitstiff.io.output import sha256_file
from fitstiff.physics.model import Model, build_model
from fitstiff.physics.params import to_si
from fitstiff.physics.terms import FrictionBase

__all__ = ["MANIFEST", "RESULT_FILES", "Z90", "Chain", "Curves", "RunDirectory", "fit_curves",
           "open_run", "posterior_curves", "read_chain", "read_json", "term_labels"]

MANIFEST = "manifest.json"
RESULT_FILES: Mapping[str, str] = {"posterior": "posterior.json", "fit": "fit.json",
                                   "diagnosis": "diagnosis.json"}
"""Run kind -> the result file that makes a directory one of that kind (checked in order)."""
Z90 = 1.6448536269514722        # two-sided 90 % of a standard normal (the reports' intervals)
_REPRODUCE_RTOL = 1e-3          # recomputed per-log RMS against fit.json


# -- the run directory ----------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class RunDirectory:
    """A finished run re-opened for reporting.

    Attributes:
        path: the directory.
        kind: a key of :data:`RESULT_FILES`.
        result: the result file's content (``fit.json`` / ``posterior.json``).
        manifest: the run's ``manifest.json``.
        problem: the rebuilt problem (re-read logs, recorded model and options); ``None`` for
            a diagnosis (which compares several models: its page works from the logs and the
            held-out residuals it kept).
        inputs: the manifest's input files, each ``(path, sha256)``, all verified.
        logs: the re-read logs.
        posterior: ``posterior.json`` read back (:meth:`Posterior.from_dict`), for a
            posterior run.
    """

    path: Path
    kind: str
    result: Mapping[str, Any]
    manifest: Mapping[str, Any]
    problem: Problem | None
    inputs: tuple[tuple[Path, str], ...]
    logs: tuple[Log, ...] = ()
    posterior: PosteriorRecord | None = None

    @property
    def result_file(self) -> Path:
        return self.path / RESULT_FILES[self.kind]


def open_run(directory: str | Path) -> RunDirectory:
    """Read a run directory: its result and manifest, the verified logs, the rebuilt problem.

    Raises:
        InputError: not a run directory, no or a foreign manifest, an input file missing or
            changed since the run.
    """
    path = Path(directory)
    if not path.is_dir():
        raise InputError(str(path), "report directory", "does not exist or is not a directory",
                         "give the --out directory of fitstiff fit or fitstiff posterior")
    kind = next((k for k, name in RESULT_FILES.items() if (path / name).is_file()), None)
    if kind is None:
        raise InputError(str(path), "report directory",
                         f"holds none of {', '.join(RESULT_FILES.values())}",
                         "give the --out directory of fitstiff fit, posterior or diagnose")
    name = RESULT_FILES[kind]
    result = read_json(path / name)
    posterior = _posterior_record(path / name, result) if kind == "posterior" else None
    latest = read_json(path / MANIFEST, missing="the run did not finish; run it again")
    # the run that wrote the result file: the manifest's, or one it keeps as an earlier run
    manifest = next((record for record in [latest, *latest.get("earlier_runs", [])]
                     if name in record.get("outputs", [])), None)
    if manifest is None:
        raise InputError(str(path / MANIFEST), "outputs",
                         f"do not include {name} (the manifest is of another run: "
                         f"{latest.get('command', '?')})",
                         "give every run its own --out directory")
    started = Path(manifest.get("cwd", "."))   # relative paths are relative to it
    inputs = tuple(_verified({**entry, "path": str(started / entry["path"])},
                             manifest=path / MANIFEST) for entry in manifest["inputs"])
    options = manifest.get("options", {})
    logs = _reread([str(started / f) for f in result["files"]], options,
                   manifest=path / MANIFEST)
    problem = (None if kind == "diagnosis"
               else _problem(logs, result, options, where=str(path / name)))
    return RunDirectory(path=path, kind=kind, result=result, manifest=manifest,
                        problem=problem, inputs=inputs, logs=tuple(logs), posterior=posterior)


def _posterior_record(path: Path, result: Mapping[str, Any]) -> PosteriorRecord:
    """``posterior.json`` read back, or an :class:`InputError` naming what it lacks."""
    try:
        return Posterior.from_dict(result)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(str(path), "posterior.json", f"cannot be read back ({exc!r})",
                         "restore the file written by fitstiff posterior") from None


def _reread(files: Sequence[str], options: Mapping[str, Any], *, manifest: Path) -> list[Log]:
    """The run's logs, read as the run read them (``options["reading"]``: keyword arguments of
    :func:`~fitstiff.io.loading.load_logs`), or as canonical CSV files where the manifest does
    not record how."""
    reading = options.get("reading")
    try:
        return load_logs(files, **(reading or {}))
    except InputError as exc:
        if reading is not None:
            raise
        raise InputError(str(manifest), "re-reading the run's logs",
                         f"failed ({exc}): the manifest does not record how they were read "
                         "(--format, --columns, --no-header, --delimiter, rig overrides), so "
                         "they were read as canonical CSV files",
                         "report runs on canonical CSV logs, or runs whose manifest records "
                         "options['reading']") from None


def read_json(path: Path, *, missing: str = "run the command that writes it") -> dict:
    """A JSON file of the run, or an :class:`InputError` naming it (missing: ``missing`` is
    the advice; unreadable)."""
    if not path.is_file():
        raise InputError(str(path), "file", "is missing", missing)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(str(path), "JSON", f"does not parse ({exc})",
                         "restore the file written by fitstiff") from None


def _verified(entry: Mapping[str, str], *, manifest: Path) -> tuple[Path, str]:
    """An input of the run, checked against the SHA-256 its manifest recorded."""
    path = Path(entry["path"])
    if not path.is_file():
        raise InputError(str(path), f"input of the run in {manifest}",
                         "is missing", "restore the file or run again")
    digest = sha256_file(path)
    if digest != entry["sha256"]:
        raise InputError(str(path), f"input of the run in {manifest}",
                         f"has changed since the run (sha256 {digest[:12]}... now, "
                         f"{entry['sha256'][:12]}... recorded)",
                         "restore the original file or run again on the new one")
    return path, digest


def _problem(logs: Sequence[Log], result: Mapping[str, Any],
             options: Mapping[str, Any], *, where: str) -> Problem:
    """The run's problem: its model, fixed values (from the result file, exact) and the
    nuisances it fixed (from the manifest's ``fix``), its problem options."""
    spec = result["model"]
    template = build_model(spec)
    fix: dict[str, float | None] = to_si(
        template, {name: p["value"] for name, p in result["parameters"].items()
                   if p.get("fixed")}, where=where)
    fix |= dict.fromkeys(n for item in options.get("fix", [])
                         if (n := item.partition("=")[0]) in NUISANCES)
    return Problem(logs, spec, fix=fix, selection=Selection.pick(options)[0])


# -- the model's curves ---------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Curves:
    """What the model says about each log, and a point model for the stroke figure."""

    force: list[np.ndarray]                         # the central model force per log
    contributions: list[dict[str, np.ndarray]]      # label -> per-term force per log
    band: list[tuple[np.ndarray, np.ndarray]] | None
    model: Model
    label: str                                       # legend label of the central curve

    def residual(self, problem: Problem, i: int) -> np.ndarray:
        return self.force[i] - np.asarray(problem.logs[i].force)

    def rms(self, problem: Problem, i: int) -> float:
        """RMS residual over the samples that carried weight in the run."""
        r = self.residual(problem, i)[problem.sample_weights[i] > 0]
        return float(np.sqrt(np.mean(r**2)))


def term_labels(model: Model) -> list[str]:
    return [f"seal ({n})" if isinstance(model.term(n), FrictionBase) else n for n in model.force_names]


def fit_curves(run: RunDirectory) -> Curves:
    """The fitted curves from fit.json's values; each log's RMS must reproduce fit.json."""
    problem, result = run.problem, run.result
    theta = FitResult.theta_from_dict(problem, result, where=str(run.result_file))
    model, _ = problem.unpack(theta)
    per_log = problem.per_log(theta)
    labels = term_labels(model)
    curves = Curves(force=[p["force"] for p in per_log],
                     contributions=[dict(zip(labels, p["contributions"].T)) for p in per_log],
                     band=None, model=model, label=f"fit {model.spec}")
    for i, entry in enumerate(result["per_log"]):
        rms = curves.rms(problem, i)
        if not math.isclose(rms, entry["rms_N"], rel_tol=_REPRODUCE_RTOL):
            raise InputError(str(run.result_file), f"log {entry['name']}",
                             f"the fitted model gives an RMS residual of {rms:.6g} N on the "
                             f"re-read log, fit.json says {entry['rms_N']:.6g} N",
                             "the log was read or its rig set up differently from the fit "
                             "(sidecar JSON edited, or reading options / rig overrides the "
                             "manifest does not record): run the fit again")
    return curves


@dataclasses.dataclass(frozen=True)
class Chain:
    """The posterior chain in physical display units, and the draws kept after burn-in."""

    theta: np.ndarray        # (steps, walkers, size) full theta (integrated entries at their
                             # stored values)
    log_prob: np.ndarray     # (steps, walkers)
    display: np.ndarray      # (steps, walkers, size): model parameters in display units,
                             # nuisances in theirs (N, fraction)
    discard: int
    thin: int
    stored_kept: np.ndarray | None = None   # (draws, walkers, size) with the integrated
                                            # entries' conditional draws

    @property
    def kept(self) -> np.ndarray:
        if self.stored_kept is not None:
            return self.stored_kept.reshape(-1, self.theta.shape[-1])
        return self.theta[self.discard::self.thin].reshape(-1, self.theta.shape[-1])

    @property
    def kept_log_prob(self) -> np.ndarray:
        return self.log_prob[self.discard::self.thin].ravel()


def read_chain(run: RunDirectory) -> Chain:
    problem, diagnostics = run.problem, run.posterior.diagnostics
    path = run.path / CHAIN
    if not path.is_file():
        raise InputError(str(path), "chain file", "is missing",
                         "run fitstiff posterior again into this directory")
    integrated = diagnostics.integrated
    try:
        stored = ChainStore(path, read_only=True).read()
    except (OSError, KeyError, AttributeError) as exc:
        raise InputError(str(path), "chain file", f"cannot be read ({exc})",
                         "run fitstiff posterior again into this directory") from None
    theta, log_prob, base, kept = stored.chain, stored.log_prob, stored.theta_start, stored.kept
    names = list(run.posterior.names)
    sampled = [n for n in names if n not in integrated]
    if (names != problem.names or theta.shape[-1] != len(sampled)
            or (integrated and (base is None or kept is None
                                or kept.shape[-1] != problem.size))):
        raise InputError(str(path), "chain",
                         f"holds {theta.shape[-1]} coordinates ({', '.join(sampled)}), the "
                         f"rebuilt problem {problem.size} ({', '.join(problem.names)}, of which "
                         f"{len(integrated)} integrated out)",
                         "run fitstiff posterior again into this directory")
    if integrated:
        full = np.broadcast_to(base, theta.shape[:2] + base.shape).copy()
        full[..., [problem.names.index(n) for n in sampled]] = theta
        theta = full
    physical = jax.jit(jax.vmap(problem.physical))
    flat = np.asarray(physical(jnp.asarray(theta.reshape(-1, problem.size))))
    # model parameters in their display units, the nuisances as they are (N, -, Pa)
    display = np.concatenate([problem.par.to_display(flat[:, :problem.par.size]),
                              flat[:, problem.par.size:]], axis=1)
    return Chain(theta=theta, log_prob=log_prob, display=display.reshape(theta.shape),
                  discard=diagnostics.discard, thin=diagnostics.thin,
                  stored_kept=kept if integrated else None)


def posterior_curves(run: RunDirectory, chain: Chain, *, draws: int) -> Curves:
    """Median curve and 90 % predictive band (from the run's ``predictive.npz``: the median and
    spread of its model-force draws at every sample, with the noise level), the per-term
    forces of the point model (the most probable kept sample). A run without those arrays
    (an older one) gets them recomputed from ``draws`` evenly spaced kept samples, with the
    median per-term forces."""
    problem = run.problem
    kept = chain.kept
    best_theta = jnp.asarray(kept[int(np.argmax(chain.kept_log_prob))])
    best, _ = problem.unpack(best_theta)
    labels = term_labels(best)
    scale = run.posterior.noise_scale
    stored = _stored_predictive(run)
    if stored is None:
        pick = np.unique(np.linspace(0, kept.shape[0] - 1, min(draws, kept.shape[0])).round()
                         .astype(int))
        per_draw = [problem.per_log(jnp.asarray(kept[k])) for k in pick]
        centres = [np.median(np.stack([d[i]["force"] for d in per_draw]), axis=0)
                   for i in range(problem.n_logs)]
        spreads = [np.std(np.stack([d[i]["force"] for d in per_draw]), axis=0)
                   for i in range(problem.n_logs)]
        terms = [np.median(np.stack([d[i]["contributions"] for d in per_draw]), axis=0)
                 for i in range(problem.n_logs)]
    else:
        centres, spreads = stored
        terms = [p["contributions"] for p in problem.per_log(best_theta)]
    force, band, contributions = [], [], []
    for i, log in enumerate(problem.logs):
        sd = scale[f"force[{log.name}]"][0]
        half = Z90 * np.sqrt(spreads[i] ** 2 + sd**2)
        force.append(centres[i])
        band.append((centres[i] - half, centres[i] + half))
        contributions.append(dict(zip(labels, np.asarray(terms[i]).T)))
    return Curves(force=force, contributions=contributions, band=band, model=best,
                  label=f"posterior median, {best.spec}")


def _stored_predictive(run: RunDirectory) -> tuple[list[np.ndarray], list[np.ndarray]] | None:
    """Per log the median and spread of the model-force draws of ``predictive.npz``, or
    ``None`` when the file (or those arrays) is not there or does not match the logs."""
    path = run.path / PREDICTIVE
    if not path.is_file():
        return None
    with np.load(path) as data:
        names = [str(n) for n in data["log_names"]] if "log_names" in data else []
        if names != [log.name for log in run.problem.logs]:
            return None
        out: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
        for i, log in enumerate(run.problem.logs):
            keys = (f"log{i}_model_force_median_N", f"log{i}_model_force_spread_N")
            if not all(k in data for k in keys):
                return None
            median, spread = (np.asarray(data[k], dtype=float) for k in keys)
            if median.shape != (len(log),) or spread.shape != (len(log),):
                return None
            out[0].append(median)
            out[1].append(spread)
    return out
