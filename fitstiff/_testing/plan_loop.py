"""The closed loop of issue 33: diagnose a withheld-effect dataset, plan the next experiment,
run it on the dataset's rig (the independent simulator, with the dataset's truth and noise),
diagnose again; and the same with the naive experiment of the same duration (the longest log
replayed). ``benchmarks/withheld.py --plan`` runs it over datasets and scores it
(:func:`score_loop`).

A dataset gets a plan when its diagnosis ends with a tie, a candidate the logs cannot test, a
wrong or a missing name, or an unexplained structure; a null dataset always gets one, for its
strongest candidate against its absence (the false alarms a planned experiment could raise).
The right answer after the experiment is the withheld effects (``missing`` too: the
experiment supplies the excitation), nothing for nulls and out-of-library datasets.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Mapping, Sequence

from fitstiff._testing.withheld import OOL_VARIABLE, make_dataset, simulate_program
from fitstiff._testing.withheld_scoring import _rate
from fitstiff.diagnosis import Diagnosis, diagnose
from fitstiff.planning import Limits, plan
from fitstiff.planning.families import naive_choice

__all__ = ["LOOP_LIMITS", "needs_plan", "run_closed_loop", "score_loop"]

#: what the benchmark's rig can do on the next run: 20 s programs, its three supply pressures,
#: the 25 mm/s its regular logs run at (the missing-inertia sets record 0.5 mm/s only; a user
#: states the rig's limits, not the logs')
LOOP_LIMITS = {"max_duration_s": 20.0, "pressures_bar": (3.0, 4.5, 6.0),
               "max_speed_mm_s": 25.0}


def target(truth: Mapping[str, object]) -> list[str]:
    """The right answer once the experiment is run."""
    return [] if truth["family"] in ("null", "ool") else sorted(truth["withheld"])


def needs_plan(d: Diagnosis, truth: Mapping[str, object]) -> str | None:
    """Why the diagnosis of this dataset gets a plan, or None."""
    if truth["family"] == "null":
        return "null"
    if any(c.tied_with for c in d.candidates):
        return "tie"
    if any(not v.get("testable", True) for v in d.detectability.values()):
        return "untestable"
    if sorted(d.accepted) != target(truth):
        return "wrong name" if d.accepted else "missing name"
    if any(u.accepted for u in d.unexplained_structure):
        return "structure"
    return None


def _summary(d: Diagnosis, truth) -> dict[str, object]:
    return {"accepted": list(d.accepted), "exact": sorted(d.accepted) == target(truth),
            "heldout_rms_N": d.gap["final_heldout_rms_N"],
            "untestable": sorted(k for k, v in d.detectability.items()
                                 if not v.get("testable", True)),
            "structure": [u.variable for u in d.unexplained_structure if u.accepted],
            "described": [{"variable": u.variable, "form": u.form,
                           "confounded_with": list(u.confounded_with)}
                          for u in d.unexplained_structure if u.accepted]}


def run_closed_loop(dataset_id: str, rate_scale: float = 1.0) -> dict[str, object]:
    """One dataset through the loop (a JSON-able record; a failure is recorded with its
    traceback, not raised: the run goes on)."""
    start = time.perf_counter()
    try:
        return _loop(dataset_id, rate_scale, start)
    except Exception as exc:
        return {"id": dataset_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=8),
                "wall_s": time.perf_counter() - start}


def _loop(dataset_id: str, rate_scale: float, start: float) -> dict[str, object]:
    logs, truth = make_dataset(dataset_id, rate_scale=rate_scale)
    kw = {"baseline": truth["baseline"]}
    before = diagnose(logs, **kw)
    record: dict[str, object] = {"id": dataset_id, "family": truth["family"],
                                 "withheld": truth["withheld"], "target": target(truth),
                                 "before": _summary(before, truth)}
    reason = needs_plan(before, truth)
    record["reason"] = reason
    if reason is None:
        record["wall_s"] = time.perf_counter() - start
        return record
    limits = Limits.from_logs(logs, **LOOP_LIMITS)
    separate = None
    if reason == "null":
        strongest = min(before.candidates, key=lambda c: c.log_p_value)
        separate = [strongest.effect]
    t0 = time.perf_counter()
    p = plan(before, logs, limits=limits, separate=separate)
    record["plan_s"] = time.perf_counter() - t0
    record["plan"] = [{"separates": list(q.separates), "kind": q.kind,
                       "program": dict(q.program), "supply_bar": q.supply_bar,
                       "expected": dict(q.expected), "naive": dict(q.naive)}
                      for q in p.programs]
    record["unplanned"] = [dict(u) for u in p.unplanned]
    if not p.programs:
        record["after_planned"] = record["after_naive"] = record["before"]
        record["wall_s"] = time.perf_counter() - start
        return record
    planned = [simulate_program(truth, q.time_s, q.displacement_mm * 1e-3,
                                supply_bar=q.supply_bar,
                                start_position_mm=q.start_position_mm, name=f"planned_{k}")
               for k, q in enumerate(p.programs)]
    record["after_planned"] = _summary(diagnose(logs + planned, **kw), truth)
    naive = naive_choice(max(logs, key=len))
    t, x = naive.sample(limits)
    replayed = [simulate_program(truth, t, x, supply_bar=naive.supply_bar,
                                 start_position_mm=naive.start_position_mm,
                                 name=f"naive_{k}")
                for k in range(len(p.programs))]
    record["after_naive"] = _summary(diagnose(logs + replayed, **kw), truth)
    record["wall_s"] = time.perf_counter() - start
    return record


def _row(record: Mapping[str, object]) -> str:
    """The row of the closed-loop table: the dataset's family and what it withheld."""
    if record["family"] == "ool":
        return f"ool/{record['id'].split('/')[1]}"
    if record["family"] == "null":
        return "null"
    return f"{record['family']}/{'+'.join(record['withheld'])}"


def _pinned(summary: Mapping[str, object], want: str) -> bool:
    """Whether the first description names ``want`` and no variable it is confounded with."""
    first = (summary.get("described") or [None])[0]
    return first is not None and first["variable"] == want and not first["confounded_with"]


def _structure_rates(records: Sequence[Mapping[str, object]]) -> dict[str, object]:
    """Out-of-library datasets: the variable their residual follows described first and
    confounded with nothing, before, after the naive and after the planned experiment (and
    confounded at all)."""
    def want(r):
        return OOL_VARIABLE[r["id"].split("/")[1]]

    out = {}
    for stage in ("before", "after_naive", "after_planned"):
        out[stage] = {
            "pinned": _rate(sum(_pinned(r[stage], want(r)) for r in records), len(records)),
            "confounded": _rate(sum(bool(r[stage].get("described"))
                                    and bool(r[stage]["described"][0]["confounded_with"])
                                    for r in records), len(records))}
    return out


def score_loop(records: Sequence[Mapping[str, object]]) -> dict[str, object]:
    """The closed-loop table: per row (family and withheld effect), named exactly before,
    after the naive and after the planned experiment; totals over the datasets that got a
    plan, nulls apart."""
    planned = [r for r in records if r.get("reason") and "after_planned" in r]
    rows: dict[str, list] = {}
    for r in planned:
        rows.setdefault(_row(r), []).append(r)

    def rates(rs):
        return {stage: _rate(sum(r[stage]["exact"] for r in rs), len(rs))
                for stage in ("before", "after_naive", "after_planned")}

    effects = [r for r in planned if r["family"] != "null"]
    nulls = [r for r in planned if r["family"] == "null"]
    structure = [r for r in planned
                 if r["family"] == "ool" and OOL_VARIABLE[r["id"].split("/")[1]]]
    times = sorted(r["plan_s"] for r in planned if "plan_s" in r)
    return {"rows": {k: rates(v) for k, v in sorted(rows.items())},
            "effects": rates(effects), "nulls": rates(nulls),
            "structure": _structure_rates(structure),
            "no_plan_needed": sum(1 for r in records if r.get("reason") is None),
            "plan_s_median": times[len(times) // 2] if times else None,
            "plan_s_max": times[-1] if times else None}
