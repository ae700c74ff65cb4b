"""Scoring of the withheld-effect benchmark (DESIGN §6 step 5, issue 12): which datasets run,
one dataset diagnosed into a record, and the scores over records (top-1, exact accepted set,
false alarms with Wilson intervals, shrink, confusion matrix).

``benchmarks/withheld.py`` runs it at full size, resumably and in parallel; the test suite
runs small versions. The datasets themselves come from :mod:`fitstiff._testing.withheld`.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from fitstiff._testing.withheld import (EFFECTS, FAMILIES, LAWS, MISSING, OOL_VARIABLE,
                                        OUT_OF_LIBRARY, make_dataset)

__all__ = ["PAIRS", "dataset_ids", "run_dataset", "wilson", "named", "confusion", "score",
           "undecided_tie", "plot_confusion", "describe"]

#: the pairs of the ``pair`` family
PAIRS = (("viscous", "dwell_stiction"), ("pressure_friction", "inertia"),
         ("time_delay", "leakage"), ("stribeck", "force_drift"),
         ("heat_transfer", "maxwell_slip"), ("asymmetry", "viscous"),
         ("rig_compliance", "dwell_stiction"), ("inertia", "force_drift"))


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
    if "law" in families:
        groups += [[f"law/{e}/{s}" for s in range(seeds)] for e in LAWS]
    keyed = [((i + 0.5) / len(g), j, d) for j, g in enumerate(groups) for i, d in enumerate(g)]
    return [d for _, _, d in sorted(keyed)]


def run_dataset(dataset_id: str, rate_scale: float = 1.0, short: bool = False,
                candidates: str = "all", residuals: Path | None = None,
                one_log: int | None = None) -> dict[str, object]:
    """Generate and diagnose one dataset; the record kept in the JSON. ``short`` and
    ``candidates`` (fewer than all) make the small version of the test suite. ``residuals``:
    a folder to keep the held-out residuals in (``heldout.npz`` content, one
    ``<id with / as __>.npz`` per dataset), to study them without diagnosing again.
    ``one_log``: diagnose that log of the dataset alone (its folds are blocks of loops)."""
    from fitstiff.diagnosis import diagnose

    start = time.perf_counter()
    try:
        logs, truth = make_dataset(dataset_id, rate_scale=rate_scale, short=short)
        if one_log is not None:
            logs = [logs[one_log]]
        sim_s = time.perf_counter() - start
        d = diagnose(logs, baseline=truth["baseline"], candidates=candidates)
    except Exception as exc:      # a failure is a result too: keep it, do not stop the run
        return {"id": dataset_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=6),
                "wall_s": time.perf_counter() - start}
    wall = time.perf_counter() - start
    if residuals is not None:
        Path(residuals).mkdir(parents=True, exist_ok=True)
        np.savez(Path(residuals) / (dataset_id.replace("/", "__") + ".npz"),
                 noise_N=d.gap["noise_N"], **d.heldout_arrays())
    gap = d.gap
    before, after, noise = (gap["heldout_rms_N"], gap["final_heldout_rms_N"], gap["noise_N"])
    ranked = [{"effect": c.effect, "p_value": c.p_value, "log_p_value": c.log_p_value,
               "score": c.score, "dof": c.dof, "accepted": c.accepted,
               "shrink": c.shrink, "testable": c.testable} for c in d.candidates]
    return {
        "id": dataset_id, "family": truth["family"], "baseline": truth["baseline"],
        "withheld": truth["withheld"], "expected": truth["expected"], "sizes": truth["sizes"],
        "units": truth["units"], "accepted": list(d.accepted),
        "top1": d.candidates[0].effect if d.candidates else None,
        "ranked": ranked[:5],
        # every held-out refit (its last round): the acceptance rule's gains and shrinks,
        # to calibrate its thresholds on the stored records, and why it was not accepted
        "refits": [{"effect": c.effect, "round": c.round, "before_N": c.heldout_rms_before_N,
                    "after_N": c.heldout_rms_after_N, "shrink": c.shrink,
                    "accepted": c.accepted, "together": list(c.together), "why": c.why,
                    "outdone_by": c.outdone_by}
                   for c in d.candidates if c.heldout_rms_after_N is not None],
        # held-out ties the fits to all the data broke (the accepted one, the loser, its
        # BIC gap: below DECISIVE_BIC the verdict says the logs do not tell them apart)
        "ties": [{"accepted": c.tied_with, "tied": c.effect, "bic_gap": c.tie_bic_gap}
                 for c in d.candidates if c.tied_with and not c.accepted],
        "detectability": {k: dict(v) for k, v in d.detectability.items()
                          if k in truth["withheld"]},
        "heldout_rms_before_N": before, "heldout_rms_after_N": after, "noise_N": noise,
        "shrink": (before - after) / (before - noise) if before > noise else None,
        "candidate_shrink": {k: d.candidate(k).shrink for k in truth["withheld"]
                             if k in [c.effect for c in d.candidates]},
        "unexplained_cells": len(d.unexplained),
        "structure": structure_records(d.unexplained_structure),
        "baseline_converged": bool(gap["baseline_converged"]),
        "samples": sum(len(log) for log in logs), "logs": len(logs), "one_log": one_log,
        "truth": {k: truth[k] for k in ("effects", "out_of_library", "base", "noise",
                                        "excitation", "logs")},
        "sim_s": sim_s, "wall_s": wall, "timing_s": dict(d.timing_s),
    }


def structure_records(described) -> list[dict[str, object]]:
    """The benchmark's record of a diagnosis' ``unexplained_structure``."""
    return [{"variable": u.variable, "form": u.form, "accepted": u.accepted,
             "size_N": u.size_N, "shrink": u.shrink, "t": u.t, "t_needed": u.t_needed,
             "heldout_rms_before_N": u.heldout_rms_before_N,
             "heldout_rms_after_N": u.heldout_rms_after_N,
             "confounded_with": list(u.confounded_with)} for u in described]


def structure_from_residuals(dataset_id: str, residuals: Path, rate_scale: float = 1.0,
                             short: bool = False, **rule) -> list[dict[str, object]]:
    """The structure step of :func:`~fitstiff.diagnosis.diagnose` on a dataset's kept
    held-out residuals (``run_dataset(..., residuals=DIR)``): the same inputs the
    diagnosis gives it (its problem's logs, segmentations and counted samples, the pooled
    noise floor kept with them), without diagnosing again. ``rule``: ``alpha``,
    ``min_shrink`` of :func:`~fitstiff.diagnosis.structure.describe_structure`."""
    from fitstiff.diagnosis.structure import describe_structure
    from fitstiff.inference.problem import Problem

    logs, truth = make_dataset(dataset_id, rate_scale=rate_scale, short=short)
    problem = Problem(logs, model=truth["baseline"])
    path = Path(residuals) / (dataset_id.replace("/", "__") + ".npz")
    with np.load(path) as z:
        after = [np.asarray(z[f"after_{k}"]) for k in range(len(logs))]
        if "noise_N" not in z:
            raise ValueError(f"{path}: no noise_N (kept before the benchmark kept the "
                             "diagnosis' floor); run benchmarks/withheld.py --residuals again")
        pooled = float(z["noise_N"])
    masks = [w > 0 for w in problem.sample_weights]
    return structure_records(describe_structure(problem.logs, problem.segmentations, after,
                                                masks, pooled, **rule))


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


def screened(record: Mapping[str, object], effect: str, *, level: float) -> bool:
    """Whether the stored diagnosis of ``record`` may have refitted ``effect``. A record
    keeps each candidate's last screen only, so where anything was accepted an earlier
    round may have refitted it unseen: such a record always counts. Otherwise (one round)
    its ranked candidates (the strongest few) show the effect with ``p < level`` or with a
    refit, or do not show it while the last one shown lies below ``level`` (the effect may
    be hidden below them). The datasets a change to that candidate alone can change are
    among these: a candidate that is never refitted leaves every decision as it was. A
    stored error counts too (nothing is known of it)."""
    if "error" in record or record.get("accepted"):
        return True
    ranked = record.get("ranked", [])
    row = next((r for r in ranked if r["effect"] == effect), None)
    if row is not None:
        return row["shrink"] is not None or row["log_p_value"] < math.log(level)
    return bool(ranked) and ranked[-1]["log_p_value"] < math.log(level)


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
    # wrong names: an accepted effect not withheld; undecided when each such effect won a
    # held-out tie with a withheld one by less than DECISIVE_BIC (the verdict says so)
    wrong = [r for r in single if set(r["accepted"]) - set(r["withheld"])]
    out["single"]["wrong"] = _rate(len(wrong), len(single))
    out["single"]["wrong_undecided_tie"] = sum(undecided_tie(r) for r in wrong)
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
    out["structure"] = _structure_scores(single, nulls, ool)
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
    laws = by["law"]
    out["law"] = {"exact": _rate(sum(r["accepted"] == r["withheld"] for r in laws), len(laws)),
                  "found": _rate(sum(r["withheld"][0] in r["accepted"] for r in laws),
                                 len(laws)),
                  "named": [named(r) for r in laws]}
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


def undecided_tie(record: Mapping[str, object]) -> bool:
    """Whether every accepted effect that was not withheld won a held-out tie with a withheld
    one by a BIC gap below :data:`~fitstiff.diagnosis._choice.DECISIVE_BIC`: the diagnosis
    named it and said the logs do not tell it from the withheld one (records without
    ``ties``, kept before 2026-11-30, have none)."""
    from fitstiff.diagnosis._choice import tie_decided

    extra = set(record["accepted"]) - set(record["withheld"])
    ties = record.get("ties", [])
    return bool(extra) and all(
        any(t["accepted"] == e and t["tied"] in record["withheld"]
            and not tie_decided(t["bic_gap"]) for t in ties)
        for e in extra)


def described(record: Mapping[str, object]) -> list[Mapping[str, object]]:
    """The accepted structure descriptions of a record (``[]`` when none, or not run)."""
    return [u for u in record.get("structure") or () if u["accepted"]]


def _structure_scores(single, nulls, ool) -> dict[str, object]:
    """Issue 32's scores of the unexplained-structure step, over the records that ran it:
    descriptions accepted on nulls; none accepted after a single in-library effect that the
    diagnosis accepted exactly; per out-of-library kind: no library effect named, the right
    variable described first (also counting a variable it is confounded with), the shrink of
    the accepted descriptions."""
    ran = [r for r in (*single, *nulls, *ool) if r.get("structure") is not None]
    nulls = [r for r in nulls if r.get("structure") is not None]
    found = [r for r in single if r.get("structure") is not None
             and r["accepted"] == r["withheld"]]
    ool = [r for r in ool if r.get("structure") is not None]
    per_kind = {}
    for kind in OUT_OF_LIBRARY:
        rs_ = [r for r in ool if r["id"].split("/")[1] == kind]
        if not rs_:
            continue
        want = OOL_VARIABLE[kind]
        first = [described(r)[0] if described(r) else None for r in rs_]
        per_kind[kind] = {
            "n": len(rs_), "variable": want,
            "never_named": sum(not r["accepted"] for r in rs_),
            "described": [u["variable"] if u else None for u in first],
            "right_variable": (sum(u is not None and u["variable"] == want for u in first)
                               if want else None),
            "right_or_confounded": (sum(u is not None and (u["variable"] == want or want in
                                                           u["confounded_with"])
                                        for u in first) if want else None),
            "shrink": [u["shrink"] for u in first if u]}
    judged = [r for r in ool if OOL_VARIABLE[r["id"].split("/")[1]]]
    firsts = [(described(r)[0] if described(r) else None, OOL_VARIABLE[r["id"].split("/")[1]])
              for r in judged]
    shrinks = [u["shrink"] for r in ool for u in described(r)[:1] if u["shrink"] is not None]
    return {
        "datasets": len(ran),
        "null_described": _rate(sum(bool(described(r)) for r in nulls), len(nulls)),
        "after_library_nothing": _rate(sum(not described(r) for r in found), len(found)),
        "ool_never_named": _rate(sum(not r["accepted"] for r in ool), len(ool)),
        "ool_right_variable": _rate(sum(u is not None and u["variable"] == want
                                        for u, want in firsts), len(firsts)),
        "ool_right_or_confounded": _rate(sum(u is not None and (u["variable"] == want or want
                                                                in u["confounded_with"])
                                             for u, want in firsts), len(firsts)),
        "ool_median_shrink": float(np.median(shrinks)) if shrinks else None,
        "per_kind": per_kind}


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


def describe(r: Mapping[str, object]) -> str:
    """One line of a record: id, right or not, accepted, top-1, held-out RMS, sizes, time."""
    if "error" in r:
        return f"{r['id']:<40} ERROR {r['error']}"
    ok = ("ok" if sorted(r["accepted"]) == sorted(r["expected"]) else "--")   # a pair: either order
    sizes = " ".join(f"{k}={v:.3g}" for k, v in r["sizes"].items())
    return (f"{r['id']:<40} {ok} accepted {r['accepted']} top1 {r['top1']} "
            f"{r['heldout_rms_before_N']:.3g}->{r['heldout_rms_after_N']:.3g} N "
            f"(noise {r['noise_N']:.3g}) {sizes} {r['wall_s']:.0f} s")
