"""What the :class:`~fitstiff.diagnosis.result.Diagnosis` says of the gap: its motion-region
cells as records (``gap["regions"]``, ``unexplained``) and the verdict's lines.
"""

from __future__ import annotations

import math

import numpy as np

from fitstiff.diagnosis._choice import DECISIVE_BIC, tie_decided
from fitstiff.diagnosis.gap import pooled_excess
from fitstiff.physics.terms import TERMS

__all__ = ["cell", "region_records", "verdict"]


#: said of an accepted effect when one log is diagnosed (blocks of its loops held out): the
#: withheld benchmark's out-of-library sets diagnosed one log at a time name library effects
#: that several logs together do not (docs/diagnosis_heldout.md, session of 2026-11-29 22:40)
_ONE_LOG = ("one log ({log}): its blocks of loops confirm what is accepted within this log "
            "only, and something particular to it (a tight spot in its stretch of the bore, "
            "friction drifting over the run, a sensor's hysteresis) can pass for a library "
            "effect; confirm it with a second log of other rates, pressures or positions")


def cell(row) -> dict[str, object]:
    """One row of a :func:`~fitstiff.diagnosis.gap.region_table` as a JSON record."""
    return {"file": row["file"], "region": row["region"],
            "pressure_bar": None if not np.isfinite(row["pressure_bar"]) else
            float(row["pressure_bar"]), "direction": row["direction"],
            "speed_band": row["speed_band"], "samples": int(row["samples"]),
            "rms_N": float(row["rms_N"]), "excess_N": float(row["excess_N"]),
            "bias_N": float(row["bias_N"]), "z_rms": float(row["z_rms"])}


def region_records(table) -> list[dict[str, object]]:
    """Every row of a region table as a record, with its share, bias z-score and noise."""
    return [] if table.empty else [cell(row) | {"share": float(row["share"]),
                                                "z_bias": float(row["z_bias"]),
                                                "noise_N": float(row["noise_N"])}
                                   for _, row in table.iterrows()]


def verdict(baseline, accepted, decided, gap, still, noise, described=(), *,
            one_log: str | None = None) -> list[str]:
    """The verdict's lines: whether the baseline converged, what the accepted effects
    explain (or that none passed), what stays above the noise floor (``still``: the cells
    above it) and what of it a description follows (``described``). ``one_log``: the name
    of the log when there is only one (its blocks of loops held out): an accepted effect then
    rests on that log alone, and the verdict says so."""
    before, after = gap["heldout_rms_N"], gap["final_heldout_rms_N"]
    lines = []
    if not gap["baseline_converged"]:
        lines.append(f"the baseline {baseline} did not converge on every fold: the diagnosis "
                     "below rests on an unfinished fit")
    if not accepted:
        lines.append(f"no candidate passes the rule: held-out RMS {before:.3g} N against a "
                     f"noise floor of {noise:.3g} N")
    else:
        lines.append(_explained(accepted, decided, before, after, noise))
        lines += [f"{e}: {decided[e].reading}" for e in accepted if decided[e].reading]
        lines += [f"{e} could also be something outside the library: {decided[e].lookalike}"
                  for e in accepted if decided[e].lookalike]
        lines += [_tie(c) for c in decided.values()
                  if c.tied_with in accepted and not c.accepted]
        if one_log is not None:
            lines.append(_ONE_LOG.format(log=one_log))
    lines += [f"{c.effect} is significant (p = {c.p_text}) but log {c.determined_by} alone "
              "determines it, so held-out data cannot confirm it: record a second log that "
              f"excites it ({TERMS[c.effect].excitation})"
              for c in decided.values() if c.determined_by and not c.accepted]
    lines += [f"{c.effect} would pass the rule, but a description that names no physics "
              f"({c.outdone_by}) explains the gap better held out: the gap has a shape "
              f"{c.effect} does not have, so it is not named"
              for c in decided.values() if c.outdone_by and not c.accepted]
    if still.empty:
        lines.append("nothing stays above the noise floor")
    else:
        lines.append("unexplained: " + ", ".join(
            f"{excess:.2g} N RMS above the noise in the {region} cells above the floor"
            for region, excess in pooled_excess(still).items()))
    found = [d for d in described if d.accepted]
    if found:
        left = math.sqrt(max(after**2 - noise**2, 0.0))
        lines.append(f"{left:.2g} N stays unexplained above the noise; " + "; ".join(
            f"{d.size_N:.2g} N of it follows {d.variable.replace('_', ' ')} ({d.form}"
            + (f", or {', '.join(d.confounded_with)}: the logs cannot tell them apart"
               if d.confounded_with else "") + ")" for d in found)
            + ": no library effect has that shape (see unexplained_structure for what "
            "usually does and what to record)")
    return lines


def _tie(c) -> str:
    """The verdict's line of a candidate that tied on held-out data with an accepted one."""
    gap = c.tie_bic_gap
    head = f"{c.effect} predicts the held-out data as well as {c.tied_with}"
    if tie_decided(gap):
        return f"{head}; all the data favour {c.tied_with} (BIC +{gap:.3g})"
    by = (f"by BIC {gap:.2g} only (below {DECISIVE_BIC:g})"
          if gap is not None and math.isfinite(gap) else "not at all (a fit did not converge)")
    return (f"{c.tied_with} or {c.effect}: {head}, and all the data favour {c.tied_with} "
            f"{by}: these logs do not tell them apart, and {c.tied_with} stands for either; "
            "`fitstiff plan` proposes runs that do")


def _explained(accepted, decided, before: float, after: float, noise: float) -> str:
    """The verdict's line of what the accepted effects explain."""
    total = max(before - noise, 1e-12)
    parts = []
    for e in accepted:
        together = decided[e].together
        if not together:
            parts.append(f"{e} ({decided[e].fitted_text}) explains "
                         f"{decided[e].shrink:.0%} of the remaining gap")
        elif e == together[0]:
            parts.append(f"{' and '.join(together)} together ("
                         + "; ".join(decided[t].fitted_text for t in together)
                         + f") explain {decided[e].shrink:.0%} of the remaining gap "
                         "(neither passed alone)")
    return ("; ".join(parts) + f" (held-out RMS {before:.3g} -> {after:.3g} N, "
            f"{(before - after) / total:.0%} of the gap above the noise floor "
            f"{noise:.3g} N)")
