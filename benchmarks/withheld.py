"""Withheld-effect benchmark of the diagnosis (DESIGN §6 step 5, issue 12).

Datasets are generated blind to the diagnosis by an independent NumPy rig simulator
(:mod:`benchmarks.rig_sim`: sub-stepped RK4, rounded corners, AR(1) force noise, quantised
displacement), three logs each at three speeds, supply pressures and positions, with the
excitation every effect needs (pauses, displaced holds, nested minor loops, sine sweeps).
Each dataset is diagnosed with :func:`fitstiff.diagnosis.diagnose` (``chamber+dahl``, or
``dahl`` when the chamber is withheld; all candidates) and scored.

Families (dataset ids ``family/what/seed``):

``single``   one effect withheld (every DESIGN §3 effect, and ``chamber`` from a ``dahl``
             baseline), sizes log-uniform over a realistic range whose low end is near the
             detection limit; right answer: that effect.
``null``     no missing effect (the programs of all families); right answer: nothing.
``ool``      an effect outside the library (guide ripple, load-cell hysteresis, force
             quantisation); right answer: no library effect named ("unexplained").
``pair``     two withheld effects (sizes from the upper part of their ranges); right answer:
             both.
``missing``  an effect without its excitation (dwell stiction without standstills, pressure
             friction at one supply pressure); right answer: "not testable", nothing named.

Scores (:func:`score`): top-1 identification (the first accepted effect, else the best-ranked
candidate), accepted-set exact match, false-alarm rate on nulls with its Wilson 95 % interval,
median shrink ``(before - after) / (before - noise)`` of the held-out RMS, "unexplained" rate on
out-of-library data, both-found rate on pairs, not-testable rate on missing excitation,
detectability calibration (found rate of effects at or above the size the diagnosis reports
as detectable at 80 % power) and the confusion matrix (true x first named effect), written to
``benchmarks/results/withheld.json`` and ``withheld_confusion.png``.

Resumable (finished datasets are kept in the JSON and skipped); one line per dataset.

    python benchmarks/withheld.py --quick                  # 3 effects, 3 nulls, 1 ool, 1 missing
    python benchmarks/withheld.py --workers 2              # the full run (~210 datasets)
    python benchmarks/withheld.py --family single --seeds 5 --nulls 0
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import multiprocessing
import sys
import time
import traceback
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks import rig_sim as rs  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
JSON_PATH = RESULTS / "withheld.json"
FIGURE_PATH = RESULTS / "withheld_confusion.png"

EFFECTS = ("viscous", "stribeck", "asymmetry", "pressure_friction", "dwell_stiction",
           "heat_transfer", "leakage", "inertia", "force_drift", "time_delay",
           "rig_compliance", "maxwell_slip", "chamber")
OUT_OF_LIBRARY = ("ripple", "load_cell_hysteresis", "force_quantisation")
PAIRS = (("viscous", "dwell_stiction"), ("pressure_friction", "inertia"),
         ("time_delay", "leakage"), ("stribeck", "force_drift"),
         ("heat_transfer", "maxwell_slip"), ("asymmetry", "viscous"),
         ("rig_compliance", "dwell_stiction"), ("inertia", "force_drift"))
MISSING = ("dwell_stiction", "pressure_friction")
FAMILIES = ("single", "null", "ool", "pair", "missing")

#: effect sizes: (low, high) of the main parameter in the diagnosis' display unit, drawn
#: log-uniform; the low ends sit near what the three logs (about 5000 samples) at 0.1-0.3 N noise detect
SIZES = {"viscous": (5.0, 200.0), "stribeck": (0.03, 0.5), "asymmetry": (0.02, 0.2),
         "pressure_friction": (0.02, 0.2), "dwell_stiction": (0.05, 0.6),
         "heat_transfer": (0.1, 3.0), "leakage": (0.005, 0.2), "inertia": (0.3, 8.0),
         "force_drift": (0.005, 0.2), "time_delay": (0.3, 5.0),
         "rig_compliance": (1e-3, 2e-2), "maxwell_slip": (3.0, 30.0), "chamber": (1.0, 1.0)}
UNITS = {"viscous": "N s/m", "stribeck": "Fs/Fc - 1", "asymmetry": "-", "pressure_friction":
         "1/bar", "dwell_stiction": "-", "heat_transfer": "1/s", "leakage": "1/s",
         "inertia": "kg", "force_drift": "N/s", "time_delay": "ms", "rig_compliance": "mm/N",
         "maxwell_slip": "N/mm", "chamber": "gate"}
SUBSTEPS = 15


# ------------------------------------------------------------------------------ datasets

def dataset_ids(*, families: Sequence[str] = FAMILIES, seeds: int = 5, nulls: int = 100,
                pair_seeds: int = 2, quick: bool = False) -> list[str]:
    """Dataset ids in run order: families interleaved so a partial run covers them all."""
    if quick:
        return ["single/viscous/0", "null/0", "single/dwell_stiction/0", "null/1",
                "single/time_delay/0", "ool/ripple/0", "missing/dwell_stiction/0", "null/2"]
    groups: list[list[str]] = []
    if "single" in families:
        groups += [[f"single/{e}/{s}" for s in range(seeds)] for e in EFFECTS]
    if "null" in families and nulls:
        groups.append([f"null/{s}" for s in range(nulls)])
    if "ool" in families:
        groups += [[f"ool/{k}/{s}" for s in range(seeds)] for k in OUT_OF_LIBRARY]
    if "pair" in families:
        groups += [[f"pair/{a}+{b}/{s}" for s in range(pair_seeds)] for a, b in PAIRS]
    if "missing" in families:
        groups += [[f"missing/{e}/{s}" for s in range(seeds)] for e in MISSING]
    keyed = [((i + 0.5) / len(g), j, d) for j, g in enumerate(groups) for i, d in enumerate(g)]
    return [d for _, _, d in sorted(keyed)]


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
                "decay": _loguniform(rng, 0.2e-3, 1.0e-3)}, size
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


def draw_out_of_library(kind: str, rng: np.random.Generator) -> dict[str, float]:
    if kind == "ripple":
        return {"amplitude": _loguniform(rng, 0.3, 1.5),
                "wavelength": _loguniform(rng, 2e-3, 8e-3), "phase": rng.uniform(0, 2 * np.pi)}
    if kind == "load_cell_hysteresis":
        return {"width": _loguniform(rng, 0.3, 1.5), "span": _loguniform(rng, 5.0, 20.0)}
    if kind == "force_quantisation":
        return {"step": _loguniform(rng, 0.25, 1.0)}
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
    if family in ("single", "missing"):
        names = [parts[1]]
    elif family == "pair":
        names = parts[1].split("+")
    else:
        names = []
    for name in names:
        effects[name], sizes[name] = draw_effect(name, rng, strong=family == "pair")
    if family == "ool":
        ool[parts[1]] = draw_out_of_library(parts[1], rng)
    if family == "missing":
        if parts[1] == "dwell_stiction":
            flags = {"pauses": False, "holds": False, "sweeps": True}
        elif parts[1] == "pressure_friction":
            one_pressure = True
    if short:
        flags = {"pauses": False, "holds": False, "sweeps": False}
    baseline = "dahl" if "chamber" in effects else "chamber+dahl"
    sigma0 = _loguniform(rng, 25e3, 60e3)
    fc = rng.uniform(12.0, 22.0)
    n_exp = rng.uniform(1.05, 1.4)
    dead_a, dead_b = rng.uniform(5e-3, 40e-3, size=2)
    positions = rng.permutation([0.15, 0.35, 0.55]) + rng.uniform(-0.04, 0.04, size=3)
    supplies = (np.full(3, rng.uniform(4.0, 6.0)) if one_pressure else
                rng.permutation([3.0, 4.5, 6.0]) + rng.uniform(-0.3, 0.3, size=3)) * 1e5
    p_ref = float(np.mean(supplies))
    noise = rs.SensorNoise(force_N=rng.uniform(0.1, 0.3), ar1=rng.uniform(0.0, 0.5),
                           displacement_um=rng.uniform(0.4, 1.0),
                           quantum_um=float(rng.choice([0.5, 1.0])),
                           pressure_mbar=rng.uniform(2.0, 5.0))
    logs, programs = [], []
    for i in range(3):
        speed = LOGS[i][0] * _loguniform(rng, 0.8, 1.25)
        program = log_program(i, speed, **flags)
        rate = LOGS[i][1] * rate_scale
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
                       "quantum_um": noise.quantum_um, "pressure_mbar": noise.pressure_mbar},
             "excitation": {**flags, "one_pressure": one_pressure}, "logs": programs}
    return logs, truth


def run_dataset(dataset_id: str, rate_scale: float = 1.0, short: bool = False,
                candidates: str = "all") -> dict[str, object]:
    """Generate and diagnose one dataset; the record kept in the JSON. ``short`` and
    ``candidates`` (fewer than all) make the small version of the test suite."""
    from fitstiff.diagnosis import diagnose

    start = time.perf_counter()
    try:
        logs, truth = make_dataset(dataset_id, rate_scale=rate_scale, short=short)
        sim_s = time.perf_counter() - start
        d = diagnose(logs, baseline=truth["baseline"], candidates=candidates)
    except Exception as exc:      # a failure is a result too: keep it, do not stop the run
        return {"id": dataset_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=6),
                "wall_s": time.perf_counter() - start}
    wall = time.perf_counter() - start
    gap = d.gap
    before, after, noise = (gap["heldout_rms_N"], gap["final_heldout_rms_N"], gap["noise_N"])
    ranked = [{"effect": c.effect, "p_value": c.p_value, "accepted": c.accepted,
               "shrink": c.shrink, "testable": c.testable} for c in d.candidates]
    return {
        "id": dataset_id, "family": truth["family"], "baseline": truth["baseline"],
        "withheld": truth["withheld"], "expected": truth["expected"], "sizes": truth["sizes"],
        "units": truth["units"], "accepted": list(d.accepted),
        "top1": d.candidates[0].effect if d.candidates else None,
        "ranked": ranked[:5],
        "detectability": {k: dict(v) for k, v in d.detectability.items()
                          if k in truth["withheld"]},
        "heldout_rms_before_N": before, "heldout_rms_after_N": after, "noise_N": noise,
        "shrink": (before - after) / (before - noise) if before > noise else None,
        "candidate_shrink": {k: d.candidate(k).shrink for k in truth["withheld"]
                             if k in [c.effect for c in d.candidates]},
        "unexplained_cells": len(d.unexplained),
        "baseline_converged": bool(gap["baseline_converged"]),
        "samples": sum(len(log) for log in logs), "logs": len(logs),
        "truth": {k: truth[k] for k in ("effects", "out_of_library", "base", "noise",
                                        "excitation", "logs")},
        "sim_s": sim_s, "wall_s": wall, "timing_s": dict(d.timing_s),
    }


# ------------------------------------------------------------------------------- scoring

def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (95 % by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    denom = 1 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def _rate(k: int, n: int) -> dict[str, object]:
    low, high = wilson(k, n)
    return {"k": k, "n": n, "rate": k / n if n else None, "wilson95": [low, high]}


def named(record: Mapping[str, object]) -> str:
    """The effect a dataset's diagnosis names: its first accepted effect, or ``none``."""
    return record["accepted"][0] if record.get("accepted") else "none"


def confusion(records: Iterable[Mapping[str, object]]) -> tuple[list[str], list[str],
                                                                 np.ndarray]:
    """Rows: the true effect of single-effect datasets, ``none`` for nulls and
    ``out-of-library``; columns: the first named effect or ``none``. Returns
    ``(rows, cols, counts)``."""
    recs = [r for r in records if "error" not in r
            and r["family"] in ("single", "null", "ool")]
    truth = [r["withheld"][0] if r["family"] == "single" else
             "none" if r["family"] == "null" else "out-of-library" for r in recs]
    said = [named(r) for r in recs]
    rows = [e for e in EFFECTS if e in truth] + [t for t in ("none", "out-of-library")
                                                 if t in truth]
    cols = [e for e in EFFECTS if e in said or e in truth] + ["none"]
    counts = np.zeros((len(rows), len(cols)), dtype=int)
    for t, s in zip(truth, said):
        counts[rows.index(t), cols.index(s)] += 1
    return rows, cols, counts


def score(records: Mapping[str, Mapping[str, object]]) -> dict[str, object]:
    """All the benchmark's scores from the dataset records."""
    recs = [r for r in records.values() if "error" not in r]
    by = {f: [r for r in recs if r["family"] == f] for f in FAMILIES}
    single = by["single"]
    out: dict[str, object] = {"datasets": len(records),
                              "errors": sum("error" in r for r in records.values())}
    top1 = sum(r["top1"] == r["withheld"][0] for r in single)
    exact = sum(r["accepted"] == r["withheld"] for r in single)
    out["single"] = {"top1": _rate(top1, len(single)), "exact": _rate(exact, len(single)),
                     "found": _rate(sum(r["withheld"][0] in r["accepted"] for r in single),
                                    len(single))}
    per_effect = {}
    for e in EFFECTS:
        rs_ = [r for r in single if r["withheld"][0] == e]
        if not rs_:
            continue
        per_effect[e] = {"n": len(rs_), "top1": sum(r["top1"] == e for r in rs_),
                         "exact": sum(r["accepted"] == [e] for r in rs_),
                         "named": [named(r) for r in rs_],
                         "sizes": [r["sizes"][e] for r in rs_],
                         "detectable": [r["detectability"].get(e, {}).get("size")
                                        for r in rs_]}
    out["single"]["per_effect"] = per_effect
    shrinks = [r["shrink"] for r in single if r["shrink"] is not None
               and r["withheld"][0] in r["accepted"]]
    out["single"]["median_shrink_found"] = float(np.median(shrinks)) if shrinks else None
    all_shrinks = [r["shrink"] for r in single if r["shrink"] is not None]
    out["single"]["median_shrink_all"] = float(np.median(all_shrinks)) if all_shrinks else None
    nulls = by["null"]
    out["null"] = {"false_alarm": _rate(sum(bool(r["accepted"]) for r in nulls), len(nulls)),
                   "named": sorted({e for r in nulls for e in r["accepted"]})}
    ool = by["ool"]
    out["ool"] = {"unexplained": _rate(sum(not r["accepted"] for r in ool), len(ool)),
                  "unexplained_cells_reported": sum(r["unexplained_cells"] > 0 for r in ool),
                  "named": [named(r) for r in ool]}
    pairs = by["pair"]
    out["pair"] = {"both_found": _rate(sum(set(r["withheld"]) <= set(r["accepted"])
                                           for r in pairs), len(pairs)),
                   "one_found": _rate(sum(bool(set(r["withheld"]) & set(r["accepted"]))
                                          for r in pairs), len(pairs))}
    missing = by["missing"]
    out["missing"] = {
        "not_testable": _rate(sum(r["detectability"].get(r["withheld"][0], {})
                                  .get("testable") is False for r in missing), len(missing)),
        "nothing_named": _rate(sum(not r["accepted"] for r in missing), len(missing))}
    # detectability calibration: effects at or above the reported detectable size
    above = below = found_above = found_below = 0
    for r in single:
        e = r["withheld"][0]
        det = r["detectability"].get(e, {})
        if not det.get("testable") or det.get("size") is None:
            continue
        if r["sizes"][e] >= abs(det["size"]):
            above += 1
            found_above += e in r["accepted"]
        else:
            below += 1
            found_below += e in r["accepted"]
    out["detectability"] = {"above": _rate(found_above, above),
                            "below": _rate(found_below, below)}
    walls = [r["wall_s"] for r in recs]
    out["wall_s"] = {"median": float(np.median(walls)) if walls else None,
                     "total": float(np.sum(walls))}
    rows, cols, counts = confusion(recs)
    out["confusion"] = {"rows": rows, "cols": cols, "counts": counts.tolist()}
    return out


def plot_confusion(ax, rows: Sequence[str], cols: Sequence[str], counts: np.ndarray, *,
                   title: str = "withheld effect -> named effect"):
    """Confusion matrix on ``ax``: counts per row (true effect) normalised to shares for the
    colour, the counts written in the cells."""
    counts = np.asarray(counts)
    share = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1, aspect="auto")
    for i in range(counts.shape[0]):
        for j in range(counts.shape[1]):
            if counts[i, j]:
                ax.text(j, i, str(counts[i, j]), ha="center", va="center", fontsize=7,
                        color="white" if share[i, j] > 0.6 else "black")
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=7)
    ax.set_xlabel("named by the diagnosis (first accepted)")
    ax.set_ylabel("withheld")
    ax.set_title(title, fontsize=9)
    return ax


def save_figure(summary: Mapping[str, object], path: Path = FIGURE_PATH) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = summary["confusion"]
    if not c["rows"]:
        return
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    plot_confusion(ax, c["rows"], c["cols"], np.array(c["counts"]))
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)


# ----------------------------------------------------------------------------------- runs

def _line(r: Mapping[str, object]) -> str:
    if "error" in r:
        return f"{r['id']:<40} ERROR {r['error']}"
    ok = ("ok" if r["accepted"] == r["expected"] else "--")
    sizes = " ".join(f"{k}={v:.3g}" for k, v in r["sizes"].items())
    return (f"{r['id']:<40} {ok} accepted {r['accepted']} top1 {r['top1']} "
            f"{r['heldout_rms_before_N']:.3g}->{r['heldout_rms_after_N']:.3g} N "
            f"(noise {r['noise_N']:.3g}) {sizes} {r['wall_s']:.0f} s")


def _save(path: Path, records: Mapping[str, Mapping[str, object]], figure: bool) -> None:
    from fitstiff.output import to_jsonable, write_atomic

    summary = score(records)
    write_atomic(path, json.dumps(to_jsonable({"summary": summary, "datasets": records}),
                                  indent=1))
    if figure:
        save_figure(summary, path.with_name(path.stem + "_confusion.png"))


def run_many(ids: Sequence[str], *, workers: int = 2, rate_scale: float = 1.0,
             max_crashes: int = 2) -> Iterable[dict[str, object]]:
    """Diagnose ``ids`` in a pool of ``workers`` processes, a fresh process per dataset
    (compiled code does not pile up; a crash loses one dataset, not the run). A dataset
    whose worker died ``max_crashes`` times is recorded as an error."""
    ctx = multiprocessing.get_context("spawn")
    pending = list(ids)
    crashes: dict[str, int] = {}
    while pending:
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                    max_tasks_per_child=1) as pool:
            futures = {pool.submit(run_dataset, d, rate_scale): d for d in pending}
            try:
                for f in cf.as_completed(futures):
                    r = f.result()
                    pending.remove(futures[f])
                    yield r
            except cf.process.BrokenProcessPool:
                # the oldest unfinished datasets were running when a worker died
                for d in pending[:workers]:
                    crashes[d] = crashes.get(d, 0) + 1
                    if crashes[d] >= max_crashes:
                        pending.remove(d)
                        yield {"id": d, "error": f"worker crashed {crashes[d]} times",
                               "wall_s": 0.0}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a small version (8 datasets)")
    parser.add_argument("--family", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    parser.add_argument("--seeds", type=int, default=5, help="seeds per effect (default 5)")
    parser.add_argument("--nulls", type=int, default=100, help="null datasets (default 100)")
    parser.add_argument("--pair-seeds", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rate-scale", type=float, default=1.0,
                        help="factor on the sample rates (smaller logs; default 1)")
    parser.add_argument("--limit", type=int, default=None, help="run at most this many")
    parser.add_argument("--json", type=Path, default=JSON_PATH)
    parser.add_argument("--no-figure", action="store_true")
    args = parser.parse_args(argv)
    records: dict[str, dict] = {}
    if args.json.exists():
        records = json.loads(args.json.read_text()).get("datasets", {})
    ids = dataset_ids(families=args.family, seeds=args.seeds, nulls=args.nulls,
                      pair_seeds=args.pair_seeds, quick=args.quick)
    todo = [d for d in ids if d not in records]
    if args.limit is not None:
        todo = todo[: args.limit]
    print(f"{len(ids)} datasets, {len(ids) - len(todo)} done, {len(todo)} to run "
          f"with {args.workers} worker(s)", flush=True)
    start = time.perf_counter()
    for r in run_many(todo, workers=args.workers, rate_scale=args.rate_scale):
        records[r["id"]] = r
        print(_line(r), flush=True)
        _save(args.json, records, not args.no_figure)
    if not todo and records:
        _save(args.json, records, not args.no_figure)
    summary = score({k: v for k, v in records.items() if k in set(ids)})
    print(f"wall {time.perf_counter() - start:.0f} s for {len(todo)} datasets")
    print(json.dumps({k: summary[k] for k in ("single", "null", "ool", "pair", "missing",
                                               "detectability", "wall_s")},
                     default=float)[:4000])


if __name__ == "__main__":
    main()
