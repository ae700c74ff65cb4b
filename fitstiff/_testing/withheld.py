"""Withheld-effect datasets (DESIGN §6 step 5, issue 12), generated blind to the diagnosis.

``benchmarks/withheld.py`` diagnoses and scores them; the test suite uses small versions. The
logs come from an independent NumPy rig simulator (:mod:`fitstiff._testing.rig_sim`:
sub-stepped RK4, rounded corners, AR(1) force noise, quantised displacement), three logs each
at three speeds, supply pressures and positions, with the excitation every effect needs
(pauses, displaced holds, nested minor loops, sine sweeps). The baseline is ``chamber+dahl``,
or ``dahl`` when the chamber is withheld.

Families (dataset ids ``family/what/seed``; the id seeds the draws):

``single``   one effect withheld (every DESIGN §3 effect, and ``chamber`` from a ``dahl``
             baseline), sizes log-uniform over a realistic range whose low end is near the
             detection limit; right answer: that effect.
``null``     no missing effect (the programs of all families); right answer: nothing.
``ool``      an effect outside the library (guide ripple, a tight spot in the bore, friction
             drifting over time, a saturating pressure law, a rate-dependent presliding
             stiffness, load-cell hysteresis, force quantisation; ``OOL_VARIABLE``); right
             answer: no library effect named ("unexplained"), and the unexplained structure
             described by the variable it follows.
``pair``     two withheld effects (sizes from the upper part of their ranges); right answer:
             both.
``missing``  an effect without its excitation (dwell stiction without standstills, pressure
             friction at one supply pressure, inertia at slow speeds without sweeps or fast
             moves); right answer: "not testable", nothing named.
``law``      the seal's friction **is** another law than the baseline's Dahl (``LAWS``): a
             Maxwell-slip seal of three elements of unequal stiffness and slip force, no Dahl
             term; right answer: that law's candidate (issue 31: a candidate must be able to
             become the friction law it names).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping

import numpy as np

from fitstiff._testing import rig_sim as rs
from fitstiff.io.log import Log

EFFECTS = ("viscous", "stribeck", "asymmetry", "pressure_friction", "dwell_stiction",
           "heat_transfer", "leakage", "inertia", "force_drift", "time_delay",
           "rig_compliance", "maxwell_slip", "chamber")
OUT_OF_LIBRARY = ("ripple", "load_cell_hysteresis", "force_quantisation", "tight_spot",
                  "friction_drift", "saturating_pressure", "rate_stiffness")
#: what an out-of-library kind's residual follows (the ``variable`` a structure description
#: should name, :mod:`fitstiff.diagnosis.structure`); ``None``: no structure a description
#: could catch (rounding noise)
OOL_VARIABLE = {"ripple": "position", "load_cell_hysteresis": "force",
                "force_quantisation": None, "tight_spot": "position",
                "friction_drift": "time", "saturating_pressure": "pressure",
                "rate_stiffness": "velocity"}
MISSING = ("dwell_stiction", "pressure_friction", "inertia")
#: the speed (mm/s) and sample rate (Hz) of every log of ``missing/inertia``: reversals at this
#: speed accelerate the piston by under 0.1 m/s^2 over the rig's rounded corners
SLOW = (0.5, 100.0)
#: friction laws of the ``law`` family (the seal's whole friction, the baseline's Dahl absent)
LAWS = ("maxwell_slip",)
FAMILIES = ("single", "null", "ool", "pair", "missing", "law")

#: effect sizes: (low, high) of the main parameter in the diagnosis' display unit, drawn
#: log-uniform; the low ends sit near what the three logs (about 5000 samples) at 0.1-0.3 N noise detect
SIZES = {"viscous": (5.0, 200.0), "stribeck": (0.03, 0.5), "asymmetry": (0.02, 0.2),
         "pressure_friction": (0.02, 0.2), "dwell_stiction": (1.0, 10.0),
         "heat_transfer": (0.1, 3.0), "leakage": (0.005, 0.2), "inertia": (0.3, 8.0),
         "force_drift": (0.005, 0.2), "time_delay": (0.3, 5.0),
         "rig_compliance": (1e-3, 2e-2), "maxwell_slip": (3.0, 30.0), "chamber": (1.0, 1.0)}
UNITS = {"viscous": "N s/m", "stribeck": "Fs/Fc - 1", "asymmetry": "-", "pressure_friction":
         "1/bar", "dwell_stiction": "N", "heat_transfer": "1/s", "leakage": "1/s",
         "inertia": "kg", "force_drift": "N/s", "time_delay": "ms", "rig_compliance": "mm/N",
         "maxwell_slip": "N/mm", "chamber": "gate"}
SUBSTEPS = 15


def _loguniform(rng, low, high):
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def draw_effect(name: str, rng: np.random.Generator, *, strong: bool = False
                ) -> tuple[dict[str, object], float]:
    """SI parameters of ``name`` for :func:`rig_sim.simulate_log` and its size in the
    diagnosis' display unit of the main parameter. ``strong``: the upper half (log) of the
    range."""
    low, high = SIZES[name]
    if strong and high > low:
        low = math.sqrt(low * high)
    size = _loguniform(rng, low, high) if high > low else low
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    if name == "viscous":
        return {"c": size}, size
    if name == "stribeck":
        return {"ratio": 1.0 + size, "vs": _loguniform(rng, 1e-3, 4e-3)}, size
    if name == "asymmetry":
        return {"level": sign * size, "slope": 0.5 * sign * size}, size
    if name == "pressure_friction":
        return {"beta": size / 1e5}, size
    if name == "dwell_stiction":
        return {"gain": size, "tau": _loguniform(rng, 0.2, 2.0),
                "decay": _loguniform(rng, 0.05e-3, 0.3e-3)}, size
    if name in ("heat_transfer", "leakage"):
        return {"rate": size}, size
    if name == "inertia":
        return {"mass": size}, size
    if name == "force_drift":
        return {"drift": sign * size}, size
    if name == "time_delay":
        return {"delay": size * 1e-3}, size
    if name == "rig_compliance":
        return {"compliance": size * 1e-3}, size
    if name == "maxwell_slip":
        k = np.full(3, size * 1e3 / 3)
        delta = np.array([0.1, 0.3, 0.6]) * 1e-3 * _loguniform(rng, 0.7, 1.4)
        return {"k": k.tolist(), "delta": delta.tolist()}, size
    if name == "chamber":
        return {}, 1.0
    raise KeyError(name)


def draw_law(name: str, rng: np.random.Generator, *, breakaway: float
             ) -> tuple[dict[str, object], float]:
    """A seal whose whole friction is the law ``name`` (SI parameters) and its size in the
    display unit. ``maxwell_slip``: three elements whose slip displacements spread over
    0.08-1.8 mm (the first 0.08-0.2 mm, each next 2-3 times the last) and whose slip forces
    split ``breakaway`` (N) unequally (a Dirichlet(2, 2, 2) draw); the size is the total
    initial stiffness (N/mm)."""
    if name == "maxwell_slip":
        delta = _loguniform(rng, 0.08e-3, 0.2e-3) * np.cumprod(
            np.r_[1.0, _loguniform(rng, 2.0, 3.0), _loguniform(rng, 2.0, 3.0)])
        k = breakaway * rng.dirichlet([2.0, 2.0, 2.0]) / delta
        return {"k": k.tolist(), "delta": delta.tolist()}, float(k.sum() / 1e3)
    raise KeyError(name)


def draw_out_of_library(kind: str, rng: np.random.Generator) -> dict[str, float]:
    if kind == "ripple":
        return {"amplitude": _loguniform(rng, 0.3, 1.5),
                "wavelength": _loguniform(rng, 2e-3, 8e-3), "phase": rng.uniform(0, 2 * np.pi)}
    if kind == "load_cell_hysteresis":
        return {"width": _loguniform(rng, 0.3, 1.5), "span": _loguniform(rng, 5.0, 20.0)}
    if kind == "force_quantisation":
        return {"step": _loguniform(rng, 0.25, 1.0)}
    if kind == "tight_spot":     # its centre: make_dataset puts it on one log's travel
        return {"gain": _loguniform(rng, 0.15, 0.6), "width": _loguniform(rng, 0.3e-3, 1.0e-3),
                "offset": rng.uniform(-0.6e-3, 0.6e-3), "log": int(rng.integers(3))}
    if kind == "friction_drift":
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        return {"gain": sign * _loguniform(rng, 0.1, 0.35), "tau": _loguniform(rng, 3.0, 15.0)}
    if kind == "saturating_pressure":
        return {"p_sat": _loguniform(rng, 1.0e5, 2.5e5)}
    if kind == "rate_stiffness":
        return {"gamma": _loguniform(rng, 0.15, 0.4), "v_ref": 5e-3}
    raise KeyError(kind)


def log_program(i: int, speed: float, *, pauses: bool = True, holds: bool = True,
                sweeps: bool = True) -> rs.Program:
    """The program of log ``i`` (0, 1, 2): growing triangles and a nested minor loop at
    ``speed`` (mm/s), pauses of two lengths at reversal points, a displaced hold of 0.6 s at
    +-3 mm, a sine sweep 0.5 mm, 1 -> 4 Hz (logs 1 and 2)."""
    d = (0.3, 0.5, 0.8)[i]
    move = max(speed, 10.0)
    segs: list[rs.Segment] = []
    segs += rs.triangles((0.15,), speed)
    segs += [rs.leg(0.5, speed)] + ([rs.pause(d)] if pauses else [])
    segs += [rs.leg(-0.5, speed)] + ([rs.pause(0.5 * d)] if pauses else [])
    segs += [rs.leg(0.0, speed)]
    # a large loop with nested minor loops
    segs += [rs.leg(1.0, speed), rs.leg(0.7, speed), rs.leg(1.0, speed), rs.leg(-1.0, speed),
             rs.leg(-0.6, speed), rs.leg(-1.0, speed), rs.leg(0.0, speed)]
    if holds:
        side = 3.0 if i % 2 == 0 else -3.0
        segs += [rs.leg(side, move), rs.pause(0.6), rs.leg(0.0, move)]
    if sweeps and i >= 1:
        segs += [rs.sweep(0.5, 1.0, 4.0, 0.8)]
    segs += [rs.leg(0.3, speed), rs.leg(0.0, speed)]
    return rs.Program(tuple(segs), description=f"log {i}: {speed:.3g} mm/s")


#: per log: nominal speed (mm/s) and sample rate (Hz); the force-only noise floor needs the
#: signal smooth at the sample scale (at 200 Hz a 7 Hz sweep doubled it, see the report)
LOGS = ((1.5, 200.0), (6.0, 500.0), (25.0, 600.0))


def make_dataset(dataset_id: str, *, rate_scale: float = 1.0, substeps: int = SUBSTEPS,
                 clean: bool = False, short: bool = False) -> tuple[list, dict[str, object]]:
    """The logs of one dataset and its truth (``baseline``, ``effects`` with SI parameters and
    display sizes, ``expected``, rig and noise draws, programs). ``clean``: no sensor noise
    (the same draws otherwise). ``short``: triangles and nested loops only (no pauses, holds
    or sweeps; about 2000 samples in all, for the test suite)."""
    parts = dataset_id.split("/")
    family = parts[0]
    rng = np.random.default_rng([zlib.crc32(dataset_id.encode()), 12])
    effects: dict[str, dict[str, object]] = {}
    sizes: dict[str, float] = {}
    ool: dict[str, dict[str, float]] = {}
    flags = {"pauses": True, "holds": True, "sweeps": True}
    one_pressure = False
    if family in ("single", "missing", "law"):
        names = [parts[1]]
    elif family == "pair":
        names = parts[1].split("+")
    else:
        names = []
    for name in names if family != "law" else ():
        effects[name], sizes[name] = draw_effect(name, rng, strong=family == "pair")
    if family == "ool":
        ool[parts[1]] = draw_out_of_library(parts[1], rng)
    if family == "missing":
        if parts[1] == "dwell_stiction":
            flags = {"pauses": False, "holds": False, "sweeps": True}
        elif parts[1] == "pressure_friction":
            one_pressure = True
        elif parts[1] == "inertia":
            flags = {"pauses": True, "holds": False, "sweeps": False}
    if short:
        flags = {"pauses": False, "holds": False, "sweeps": False}
    baseline = "dahl" if "chamber" in effects else "chamber+dahl"
    sigma0 = _loguniform(rng, 25e3, 60e3)
    fc = rng.uniform(12.0, 22.0)
    if family == "law":          # the law carries the seal's whole friction: no Dahl
        effects[names[0]], sizes[names[0]] = draw_law(names[0], rng, breakaway=fc)
        fc = 0.0
    n_exp = rng.uniform(1.05, 1.4)
    dead_a, dead_b = rng.uniform(5e-3, 40e-3, size=2)
    positions = rng.permutation([0.15, 0.35, 0.55]) + rng.uniform(-0.04, 0.04, size=3)
    supplies = (np.full(3, rng.uniform(4.0, 6.0)) if one_pressure else
                rng.permutation([3.0, 4.5, 6.0]) + rng.uniform(-0.3, 0.3, size=3)) * 1e5
    p_ref = float(np.mean(supplies))
    if "tight_spot" in ool:
        spot = ool["tight_spot"]
        spot["centre"] = float(positions[spot.pop("log")] + spot.pop("offset"))
    noise = rs.SensorNoise(force_N=rng.uniform(0.1, 0.3), ar1=rng.uniform(0.0, 0.5),
                           displacement_um=rng.uniform(0.4, 1.0),
                           quantum_um=float(rng.choice([0.5, 1.0])),
                           pressure_mbar=rng.uniform(2.0, 5.0))
    logs, programs = [], []
    for i in range(3):
        speed = LOGS[i][0] * _loguniform(rng, 0.8, 1.25)
        rate = LOGS[i][1] * rate_scale
        if dataset_id.startswith("missing/inertia/"):
            speed, rate = SLOW[0], SLOW[1] * rate_scale
        program = log_program(i, speed, **flags)
        base = rs.Base(sigma0=sigma0, Fc=fc, n=n_exp, x0=float(positions[i]),
                       supply=float(supplies[i]), dead_a=float(dead_a), dead_b=float(dead_b),
                       chamber=True)
        log, _ = rs.simulate_log(program, base=base, effects=effects, noise=noise,
                                 rate_hz=rate, substeps=substeps, rng=rng,
                                 name=f"{dataset_id.replace('/', '_')}_{i}", p_ref=p_ref,
                                 out_of_library=ool, clean=clean)
        logs.append(log)
        programs.append({"description": program.description, "rate_hz": rate,
                         "samples": len(log), "x0_mm": base.x0 * 1e3,
                         "supply_bar": base.supply / 1e5})
    truth = {"id": dataset_id, "family": family, "baseline": baseline,
             "expected": [] if family in ("null", "ool", "missing") else names,
             "withheld": names, "sizes": sizes, "units": {k: UNITS[k] for k in names},
             "effects": effects, "out_of_library": ool,
             "base": {"sigma0_N_per_mm": sigma0 / 1e3, "Fc_N": fc, "n": n_exp,
                      "dead_a_mm": dead_a * 1e3, "dead_b_mm": dead_b * 1e3},
             "noise": {"force_N": noise.force_N, "ar1": noise.ar1,
                       "displacement_um": noise.displacement_um,
                       "quantum_um": noise.quantum_um, "pressure_mbar": noise.pressure_mbar},
             "p_ref_Pa": p_ref, "substeps": substeps,
             "excitation": {**flags, "one_pressure": one_pressure}, "logs": programs}
    return logs, truth


def simulate_program(truth: Mapping[str, object], time_s: np.ndarray, displacement_m: np.ndarray,
                     *, supply_bar: float, start_position_mm: float, name: str,
                     seed: int = 0, clean: bool = False) -> Log:
    """One more log of a dataset: the displacement setpoints ``(time_s, displacement_m)`` (a
    planned program's CSV) played on the dataset's rig with its truth and noise (none when
    ``clean``), through the independent simulator. The rig follows the setpoints linearly
    between them, its corners rounded as :func:`~fitstiff._testing.rig_sim.render` rounds
    them."""
    substeps = int(truth.get("substeps", SUBSTEPS))
    t = np.asarray(time_s, float)
    rate = 1.0 / float(np.median(np.diff(t)))
    fine = rs.rounded(*rs.piecewise_linear_fine(t, np.asarray(displacement_m, float),
                                                substeps))
    b, n = truth["base"], truth["noise"]
    base = rs.Base(sigma0=b["sigma0_N_per_mm"] * 1e3, Fc=b["Fc_N"], n=b["n"],
                   x0=start_position_mm * 1e-3, supply=supply_bar * 1e5,
                   dead_a=b["dead_a_mm"] * 1e-3, dead_b=b["dead_b_mm"] * 1e-3,
                   chamber=truth["baseline"] != "dahl")
    noise = rs.SensorNoise(force_N=n["force_N"], ar1=n["ar1"],
                           displacement_um=n.get("displacement_um", 0.7),
                           quantum_um=n["quantum_um"], pressure_mbar=n["pressure_mbar"])
    rng = np.random.default_rng([zlib.crc32(f"{truth['id']}/{name}".encode()), seed])
    log, _ = rs.simulate_log(rs.Program(()), base=base, effects=truth["effects"], noise=noise,
                             rate_hz=rate, substeps=substeps, rng=rng, name=name,
                             p_ref=float(truth["p_ref_Pa"]),
                             out_of_library=truth["out_of_library"], fine=fine, clean=clean)
    return log
