"""What a fleet worker does with a chunk of units: load, fit, and one row per unit.

:func:`fit_units` runs wherever the fleet's tasks run (in the calling process with one
worker, in a Dask worker otherwise) and returns plain rows (dicts), the columns of
``fleet.parquet`` (:data:`BASE_COLUMNS`, then each derived quantity and model parameter with
its standard error). Every unit becomes a row: a unit whose logs cannot be read or fitted has
its one-line message in ``error`` and the rest of the chunk goes on.

Each unit is fitted by :func:`fitstiff.inference.fitting.fit_problem` as ``fitstiff fit`` would
(one start), or, with ``lanes > 1``, by :func:`fitstiff.inference.fitting.fit_problems`: the solves
of ``lanes`` units of one structure as one ``vmap``-ed call, the GPU's way (on CPUs one unit per
core is faster: ``benchmarks/fleet.py``). Either way a worker compiles once per structure, not
per unit (:meth:`fitstiff.inference.problem.Problem.compiled`), and a unit's estimates do not depend
on the chunk it came in.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence

from fitstiff.errors import InputError
from fitstiff.fleet.source import Unit, input_hash
from fitstiff.physics.model import DEFAULT_MODEL

__all__ = ["Settings", "fit_units", "BASE_COLUMNS", "column_name"]

#: the columns of every row, in order (then derived quantities, then parameters)
BASE_COLUMNS = ("cylinder", "run", "run_index", "files", "model", "converged", "message",
                "identifiable", "rms_N", "n_data", "warnings", "error", "input_hash")


@dataclasses.dataclass(frozen=True)
class Settings:
    """What every unit of a fleet is fitted with (picklable: it travels to the workers).

    Attributes:
        model: the model spec.
        fix: parameters held (SI values, or ``None``: the model's), as for
            :func:`fitstiff.fit`.
        fit: options of :func:`fitstiff.inference.fitting.fit` (solver, max_steps, denoise,
            sample_range, weights, skip, free).
        reading: options of :func:`fitstiff.io.loading.load_logs`.
        lanes: units solved per ``vmap``-ed call (1: one at a time).
        diagnose: also run :func:`fitstiff.diagnose` on each unit (baseline ``model``).
    """

    model: str = DEFAULT_MODEL
    fix: Mapping[str, float | None] = dataclasses.field(default_factory=dict)
    fit: Mapping[str, object] = dataclasses.field(default_factory=dict)
    reading: Mapping[str, object] = dataclasses.field(default_factory=dict)
    lanes: int = 1
    diagnose: bool = False

    def text(self) -> str:
        """The settings as canonical text: part of each unit's input hash (``lanes`` is not:
        it changes how, not what, is computed)."""
        from fitstiff import __version__

        return json.dumps({"version": __version__, "model": self.model, "fix": self.fix,
                           "fit": self.fit, "reading": self.reading,
                           "diagnose": self.diagnose}, sort_keys=True, default=str)


def column_name(name: str, unit: str) -> str:
    """A parameter's column: its name and display unit (``sigma0_N_per_mm``; no unit for a
    dimensionless one)."""
    if unit in ("-", ""):
        return name
    slug = unit.replace("/", "_per_").replace(" ", "_").replace("^", "").replace(".", "_")
    return f"{name}_{slug}"


def _number(value) -> float:
    return math.nan if value is None else float(value)


def _row(result) -> dict[str, object]:
    """The fit's columns: verdict, derived quantities and parameters with standard errors
    (display units; NaN where fit.json says null)."""
    data = result.to_dict()
    row: dict[str, object] = {
        "converged": bool(data["converged"]), "message": str(data["message"]),
        "identifiable": bool(data["identifiable"]), "rms_N": float(data["rms_N"]),
        "n_data": int(data["n_data"]), "warnings": "; ".join(data["warnings"])}
    for name, entry in data["derived"].items():
        row[name] = _number(entry["value"])
        row[f"{name}_stderr"] = _number(entry["stderr"])
    for name, entry in data["parameters"].items():
        column = column_name(name, entry["unit"])
        row[column] = _number(entry["value"])
        row[f"{column}_stderr"] = _number(entry["stderr"])
    return row


def _diagnosis_row(logs, settings: Settings) -> dict[str, object]:
    from fitstiff.diagnosis import diagnose

    options = {k: v for k, v in settings.fit.items()
               if k in ("denoise", "sample_range", "weights", "skip")}
    found = diagnose(logs, baseline=settings.model, **options)
    after = [c.heldout_rms_after_N for c in found.candidates if c.accepted]
    before = found.gap.get("heldout_rms_N")
    return {"accepted_effects": ",".join(found.accepted),
            "heldout_rms_N": _number(before),
            "heldout_rms_final_N": _number(after[-1] if after else before)}


def _failure(exc: BaseException) -> str:
    if isinstance(exc, InputError):
        return str(exc)
    text = " ".join(str(exc).split()) or "no message"
    return f"internal error ({type(exc).__name__}): {text}"


def fit_units(units: Sequence[Unit], settings: Settings) -> list[dict[str, object]]:
    """One row per unit of ``units`` (in their order): loaded, fitted, summarised. A unit
    that fails has its one-line message in ``error`` (and ``converged`` False)."""
    from fitstiff._jax import on_host
    from fitstiff.inference.fitting import fit_problem, fit_problems
    from fitstiff.inference.problem import Problem
    from fitstiff.inference.selection import Selection
    from fitstiff.io.loading import load_logs

    settings_text = settings.text()
    selection, _ = Selection.pick(settings.fit)
    solve_keys = ("solver", "max_steps")
    rows: list[dict[str, object]] = []
    ready = []
    for unit in units:
        row: dict[str, object] = {
            "cylinder": unit.cylinder, "run": unit.run, "run_index": unit.run_index,
            "files": ";".join(str(f) for f in unit.files), "model": settings.model,
            "converged": False, "message": "", "identifiable": False, "rms_N": math.nan,
            "n_data": 0, "warnings": "", "error": "",
            "input_hash": input_hash(unit, settings_text)}
        rows.append(row)
        try:
            if not unit.files:
                where = unit.cylinder + (f"/{unit.run}" if unit.run else "")
                raise InputError(where, "cylinder", "has no logs", "put its CSV logs in its "
                                 "folder, or list them in the manifest")
            with on_host():
                logs = load_logs(unit.files, **settings.reading)
                problem = Problem(logs, settings.model, fix=settings.fix, selection=selection)
            ready.append((row, logs, problem))
        except Exception as exc:      # one bad cylinder never stops the fleet
            row["error"] = _failure(exc)
    solve = {k: v for k, v in settings.fit.items() if k in solve_keys}
    single = solve | {k: v for k, v in settings.fit.items() if k in ("starts", "seed")}
    results: list = [None] * len(ready)
    if settings.lanes > 1 and len(ready) > 1 and single.get("starts", 1) == 1:
        try:
            results = fit_problems([p for _, _, p in ready], lanes=settings.lanes, **solve)
        except Exception:     # noqa: BLE001  - each unit again on its own, to name the bad one
            results = [None] * len(ready)
    for k, (row, logs, problem) in enumerate(ready):
        try:
            if results[k] is None:
                with on_host():     # one unit at a time: faster on the CPU than on a GPU
                    results[k] = fit_problem(problem, **single)
            result = results[k]
            row.update(_row(result))
            if settings.diagnose:
                row.update(_diagnosis_row(logs, settings))
        except Exception as exc:
            row["error"] = _failure(exc)
    return rows
