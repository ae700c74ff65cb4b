"""Synthetic logs: a model with known parameters, driven by a displacement program, plus noise.

:func:`simulate` runs a model (a spec such as ``"chamber+dahl+viscous"`` or a built
:class:`~fitstiff.physics.model.Model`) on the *true* displacement of a
:mod:`program <fitstiff.physics.programs>`, then adds sensor noise to every measured channel and
returns a :class:`SimulatedLog`: the noisy :class:`~fitstiff.io.log.Log` (what a rig would
record) and the ground truth beside it. :func:`write_log` writes a log in the canonical CSV
form with its sidecar and truth files, which :func:`fitstiff.io.loading.load_log` reads back.

The simulated rig closes both chambers at the supply pressure at the start (``supply_bar`` in
the sidecar), so a model with a ``chamber`` term logs the modelled chamber pressures (plus
noise) and the loaded log treats them as observations of closed chambers.

>>> from fitstiff.io.log import Rig
>>> from fitstiff.physics.programs import TriangleCycles
>>> rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35, supply_pressure=6e5)
>>> sim = simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.1, 0.5), rate_mm_s=1.0),
...                rig=rig, params={"sigma0": 40, "Fc": 18}, seed=1)   # doctest: +SKIP
>>> sim.log.force.shape, sim.truth["parameters"]["sigma0"]              # doctest: +SKIP
((2401,), {'value': 40.0, 'unit': 'N/mm'})
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from scipy import signal

from fitstiff.errors import InputError
from fitstiff.io.log import Log, Rig
from fitstiff.io.output import to_jsonable, write_atomic
from fitstiff.physics.derived import derived_quantities
from fitstiff.physics.drive import Drive, make_drive
from fitstiff.physics.model import Model, Prediction, build_model
from fitstiff.physics.params import Parameterization, named_params, to_si
from fitstiff.physics.programs import Program
from fitstiff.segments.segmentation import standstill
from fitstiff.units import BAR

__all__ = ["Noise", "SimulatedLog", "simulate", "format_log", "write_log", "DEFAULT_RATE_HZ",
           "CSV_DIGITS"]

DEFAULT_RATE_HZ = 1000.0
#: significant digits of every number written by :func:`format_log`
CSV_DIGITS = 9
_ARRAY = "@array:"  # placeholder of a one-line array in _json (never a truth string)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Noise:
    """Sensor noise: standard deviation per channel and an optional AR(1) colour.

    Each channel gets independent noise ``e_k = ar1 * e_{k-1} + sqrt(1 - ar1**2) * w_k``
    (``w`` standard Gaussian, ``e_0`` drawn from the stationary law), scaled to the channel's
    standard deviation: its marginal standard deviation is the given one for any ``ar1`` and
    its lag-1 autocorrelation is ``ar1``.

    Attributes:
        force_N: force channel (N).
        displacement_um: displacement channel (um).
        pressure_mbar: each chamber pressure channel (mbar).
        ar1: AR(1) coefficient in ``(-1, 1)``; 0 for white noise.
    """

    force_N: float = 0.2
    displacement_um: float = 1.0
    pressure_mbar: float = 2.0
    ar1: float = 0.0

    def __post_init__(self):
        for f in ("force_N", "displacement_um", "pressure_mbar"):
            value = getattr(self, f)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(None, f"noise level '{f}'", f"found {value!r}",
                                 "give a standard deviation >= 0")
        if not (math.isfinite(self.ar1) and -1 < self.ar1 < 1):
            raise InputError(None, "noise 'ar1'", f"found {self.ar1!r}",
                             "give an AR(1) coefficient strictly between -1 and 1")

    def draw(self, rng: np.random.Generator, n: int, std: float) -> np.ndarray:
        """``n`` samples of this noise process with standard deviation ``std``."""
        w = rng.standard_normal(n)
        if self.ar1 == 0.0 or n < 2:
            return std * w
        phi = self.ar1
        # e_k = phi e_{k-1} + sqrt(1 - phi^2) w_k for k >= 1, with e_0 = w_0
        rest, _ = signal.lfilter([math.sqrt(1.0 - phi**2)], [1.0, -phi], w[1:], zi=[phi * w[0]])
        return std * np.concatenate([w[:1], rest])


@dataclasses.dataclass(frozen=True, eq=False)
class SimulatedLog:
    """A simulated log and its ground truth.

    Attributes:
        log: the noisy log as a rig would record it (what loading a written copy returns).
        truth: ground truth as plain JSON types (``json.dumps`` takes it): ``name``, ``model``, ``parameters`` (flat name ->
            ``value`` in display units, ``unit``), ``settings`` (static term settings, SI),
            ``rig`` (sidecar keys), ``noise``, ``seed``, ``rate_hz``, ``samples``,
            ``program`` (its description), ``derived`` (:mod:`fitstiff.physics.derived`) and
            ``force_noise_free_N`` (the model's force before noise).
        model: the model with the true parameter values.
        drive: the noise-free drive it ran on.
        prediction: the model's noise-free output (force, per-term forces, pressures).
    """

    log: Log
    truth: dict[str, object]
    model: Model
    drive: Drive
    prediction: Prediction


def simulate(model_or_spec: Model | str, program: Program, *, rig: Rig,
             params: Mapping[str, float] | None = None, noise: Noise = Noise(),
             seed: int = 0, name: str = "simulated",
             rate_hz: float = DEFAULT_RATE_HZ) -> SimulatedLog:
    """Simulate one log.

    Args:
        model_or_spec: a spec string (built without data, so ``pressure_friction`` takes
            0 bar gauge as its reference pressure) or a built model.
        program: the true displacement program (:mod:`fitstiff.physics.programs`).
        rig: rig metadata; a model with a ``chamber`` term needs bore, stroke, start position
            and supply pressure (both chambers are closed at the supply pressure).
        params: parameter values by flat name in **display units** (``Param.unit``, e.g.
            ``{"sigma0": 40, "Fc": 18}`` in N/mm and N); the rest keep the model's values.
        noise: sensor noise (:class:`Noise`; ``Noise(force_N=0, displacement_um=0,
            pressure_mbar=0)`` for none).
        seed: seed of the noise generator (``numpy.random.default_rng``).
        name: the log's name (file stem when written).
        rate_hz: sample rate of the program.

    Raises:
        InputError: unknown parameter name, value out of bounds, missing rig value, bad
            program or noise option.
    """
    model = build_model(model_or_spec) if isinstance(model_or_spec, str) else model_or_spec
    model = _with_display_values(model, params or {})
    time, x_true = program.sample(rate_hz)
    _check_stroke(x_true, rig, program)
    drive = make_drive(displacement=x_true, time=time, rig=rig, still=standstill(x_true, time),
                       name=name, needs_chamber=model.needs_chamber,
                       what=f"model '{model.spec}'")
    prediction = model.run(drive)
    clean_force = np.asarray(prediction.force)

    rng = np.random.default_rng(seed)
    n = x_true.shape[0]
    displacement = x_true + noise.draw(rng, n, noise.displacement_um * 1e-6)
    force = clean_force + noise.draw(rng, n, noise.force_N)
    pressures: dict[str, np.ndarray] = {}
    if model.needs_chamber:
        for key, modelled in (("pressure_a", prediction.pressure_a),
                              ("pressure_b", prediction.pressure_b)):
            pressures[key] = np.asarray(modelled) + noise.draw(rng, n,
                                                               noise.pressure_mbar * 100.0)
    log = Log(name=name, displacement=displacement, force=force, time=time, rig=rig,
              source={"simulated": True, "seed": seed}, **pressures)
    truth = {
        "name": name,
        "model": model.spec,
        "parameters": _parameter_table(model),
        "settings": model.settings(),
        "rig": _sidecar(rig),
        "noise": dataclasses.asdict(noise),
        "seed": seed,
        "rate_hz": float(rate_hz),
        "samples": n,
        "program": program.describe(),
        "derived": derived_quantities(model, drive),
        "force_noise_free_N": clean_force,
    }
    return SimulatedLog(log=log, truth=to_jsonable(truth), model=model, drive=drive,
                        prediction=prediction)


def _with_display_values(model: Model, values: Mapping[str, float]) -> Model:
    """``model`` with parameters set by flat name in display units (checked against bounds)."""
    si = to_si(model, {name: float(value) for name, value in values.items()})
    return Parameterization(model).with_values(model, si)


def _parameter_table(model: Model) -> dict[str, dict[str, object]]:
    table = {}
    for i, p, names in named_params(model):
        value = np.atleast_1d(np.asarray(getattr(model.terms[i], p.field), dtype=float))
        for name, v in zip(names, value):
            table[name] = {"value": p.to_display(float(v)), "unit": p.unit}
    return table


def _check_stroke(x: np.ndarray, rig: Rig, program: Program) -> None:
    """The piston must stay inside the cylinder: ``0 <= x0 + displacement <= stroke``."""
    if rig.stroke is None or rig.start_position is None:
        return
    low, high = rig.start_position + x.min(), rig.start_position + x.max()
    if low < 0 or high > rig.stroke:
        raise InputError(None, f"program {program.describe()['program']}",
                         f"moves the piston over {low * 1e3:.4g}..{high * 1e3:.4g} mm, outside "
                         f"the stroke 0..{rig.stroke * 1e3:.4g} mm",
                         "use smaller amplitudes or another start position")


# ------------------------------------------------------------------------------------ files

def format_log(log: Log, *, truth: Mapping[str, object] | None = None,
               digits: int = CSV_DIGITS) -> dict[str, str]:
    """The files of ``log`` by name: ``<name>.csv``, ``<name>.json`` and ``<name>.truth.json``.

    The CSV has the canonical columns ``time_s, displacement_mm, force_N`` and, where logged,
    ``p_a_bar, p_b_bar`` (gauge); every number has ``digits`` significant digits. The sidecar
    holds the rig keys (:meth:`~fitstiff.io.log.Rig.to_mapping`, and ``vented`` chambers). The
    truth file (only with ``truth``) holds ``truth`` with its floats rounded to ``digits``.
    """
    columns: dict[str, np.ndarray] = {}
    if log.time is not None:
        columns["time_s"] = log.time
    columns["displacement_mm"] = log.displacement * 1e3
    columns["force_N"] = log.force
    for chamber in ("a", "b"):
        pressure = log.pressure_a if chamber == "a" else log.pressure_b
        if pressure is not None:
            columns[f"p_{chamber}_bar"] = (pressure - log.rig.ambient_pressure) / BAR
    table = io.StringIO()
    np.savetxt(table, np.column_stack(list(columns.values())), fmt=f"%.{digits}g",
               delimiter=",", header=",".join(columns), comments="")
    sidecar = _sidecar(log.rig)
    if log.vented:
        sidecar["vented"] = sorted(log.vented)
    files = {f"{log.name}.csv": table.getvalue(), f"{log.name}.json": _json(sidecar)}
    if truth is not None:
        files[f"{log.name}.truth.json"] = _json(_round(to_jsonable(truth), digits))
    return files


def write_log(log: Log, path: str | os.PathLike, *, truth: Mapping[str, object] | None = None,
              digits: int = CSV_DIGITS) -> list[Path]:
    """Write ``log`` to the CSV ``path`` with its sidecar ``<stem>.json`` and, with ``truth``,
    ``<stem>.truth.json`` beside it (each atomically). Returns the paths written.

    The files are named after ``path``'s stem, whatever ``log.name`` is.
    """
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise InputError(str(path), "log path", f"has suffix {path.suffix!r}",
                         "give a path ending in .csv")
    files = format_log(log.replace(name=path.stem), truth=truth, digits=digits)
    return [write_atomic(path.with_name(name), text) for name, text in files.items()]


def _sidecar(rig: Rig) -> dict[str, object]:
    """Sidecar keys of ``rig``, rounded to 12 digits (``350.0``, not ``349.99999999999994``)."""
    return {key: _round(value, 12) for key, value in rig.to_mapping().items()}


def _round(obj, digits: int):
    """Floats in ``obj`` (JSON types) rounded to ``digits`` significant digits."""
    if isinstance(obj, float):
        return float(f"{obj:.{digits}g}")
    if isinstance(obj, dict):
        return {k: _round(v, digits) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_round(v, digits) for v in obj]
    return obj


def _json(obj) -> str:
    """Indented JSON with each list of numbers on one line (compact, still readable)."""
    arrays: list[str] = []

    def stash(o):
        if isinstance(o, dict):
            return {k: stash(v) for k, v in o.items()}
        if isinstance(o, list) and o and all(isinstance(v, (int, float)) for v in o):
            arrays.append(json.dumps(o, allow_nan=False))
            return f"{_ARRAY}{len(arrays) - 1}"
        if isinstance(o, list):
            return [stash(v) for v in o]
        return o

    text = json.dumps(stash(obj), indent=2, allow_nan=False)
    return re.sub(f'"{_ARRAY}(\\d+)"', lambda m: arrays[int(m[1])], text) + "\n"
