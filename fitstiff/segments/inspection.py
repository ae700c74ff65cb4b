"""What is in a log: sampling, ranges, segmentation and metadata, as one plain summary.

:func:`inspect_log` returns a JSON-ready dict in engineering units (mm, N, bar gauge, s, Hz);
:func:`format_summary` renders it as readable text. ``fitstiff inspect`` prints either.
"""

from __future__ import annotations

import numpy as np

from fitstiff.io.log import Log
from fitstiff.segments.segmentation import SPEED_BANDS, Segmentation, segment
from fitstiff.units import BAR, MM

__all__ = ["format_summary", "inspect_log"]


def _range(values: np.ndarray, scale: float) -> dict[str, float]:
    lo, hi = float(values.min()) / scale, float(values.max()) / scale
    return {"min": lo, "max": hi, "span": hi - lo}


GAP_FACTOR = 1.5  # an interval longer than this times the median one is a gap


def _sampling(log: Log) -> dict[str, object]:
    dt = None if log.time is None else np.diff(log.time)
    if dt is None or not dt.size:
        return {"has_time": dt is not None, "duration_s": log.duration, "sample_rate_hz": None,
                "interval_ms": None, "jitter_percent": None, "gaps": None}
    median = float(np.median(dt))
    regular = dt <= GAP_FACTOR * median
    gaps = dt[~regular]
    return {
        "has_time": True,
        "duration_s": log.duration,
        "sample_rate_hz": 1.0 / median,
        "interval_ms": {"median": median * 1e3, "min": float(dt.min()) * 1e3,
                        "max": float(dt.max()) * 1e3},
        "jitter_percent": 100.0 * float(dt[regular].std()) / median,
        "gaps": {"count": int(gaps.size), "total_s": float(gaps.sum()),
                 "longest_s": float(gaps.max()) if gaps.size else 0.0},
    }


def inspect_log(log: Log, *, segmentation: Segmentation | None = None) -> dict[str, object]:
    """Summary of ``log`` (engineering units), JSON-ready.

    Args:
        log: the log.
        segmentation: its segmentation; default :func:`~fitstiff.segments.segmentation.segment`
            with default options.

    Returns:
        A dict with ``file``, ``path``, ``samples``, ``sampling`` (``has_time``,
        ``duration_s``, ``sample_rate_hz`` = 1 / median interval, ``interval_ms`` median /
        min / max, ``jitter_percent`` = standard deviation of the regular intervals / median
        interval, ``gaps``: intervals longer than 1.5 x the median, ``count`` / ``total_s`` /
        ``longest_s``), ``ranges``
        (``displacement_mm``, ``force_N``, ``pressure_a_bar``, ``pressure_b_bar`` gauge:
        ``min`` / ``max`` / ``span``, ``None`` where not logged), ``vented``,
        ``pressure_level_bar``, ``segmentation`` (``noise_mm``, ``threshold_mm``,
        ``presliding_range_mm``, ``reversals``, ``reversal_samples``, ``reversal_times_s``,
        ``loops``, ``pauses`` with ``count`` / ``total_s`` / ``longest_s``, ``None`` without
        time), ``regions`` (share of samples per available region), ``speed_bands`` (share
        of samples per band), ``rig`` (``present``: sidecar-style values, ``missing``: keys)
        and ``notes`` (the loader's, then the segmentation's).
    """
    seg = segment(log) if segmentation is None else segmentation
    n = len(log)
    pressures = {}
    for chamber in ("a", "b"):
        p = log.pressure_a if chamber == "a" else log.pressure_b
        pressures[f"pressure_{chamber}_bar"] = (
            None if p is None else _range(p - log.rig.ambient_pressure, BAR))
    rev = seg.reversals
    pauses = None
    if seg.has_time:
        durations = seg.pause_durations
        pauses = {"count": int(durations.size), "total_s": float(durations.sum()),
                  "longest_s": float(durations.max()) if durations.size else 0.0}
    bands = np.bincount(seg.speed_band, minlength=len(SPEED_BANDS)) / max(n, 1)
    notes = list(log.notes) + [note for note in seg.notes if note not in log.notes]
    return {
        "file": log.name,
        "path": None if log.path is None else str(log.path),
        "samples": n,
        "sampling": _sampling(log),
        "ranges": {"displacement_mm": _range(log.displacement, MM),
                   "force_N": _range(log.force, 1.0), **pressures},
        "vented": sorted(log.vented),
        "pressure_level_bar": None if seg.pressure_level is None else seg.pressure_level / BAR,
        "segmentation": {
            "noise_mm": seg.noise / MM,
            "threshold_mm": seg.threshold / MM,
            "presliding_range_mm": seg.presliding_range / MM,
            "reversals": int(rev.size),
            "reversal_samples": rev.tolist(),
            "reversal_times_s": None if log.time is None else log.time[rev].tolist(),
            "loops": int(seg.loops.shape[0]),
            "pauses": pauses,
        },
        "regions": seg.shares(),
        "speed_bands": {name: float(share) for name, share in zip(SPEED_BANDS, bands)
                        if share > 0},
        "rig": {"present": log.rig.to_mapping(), "missing": log.rig.missing()},
        "notes": notes,
    }


def _span(r: dict[str, float] | None, unit: str, fmt: str = ".4g") -> str:
    if r is None:
        return "not logged"
    return f"{r['min']:{fmt}} .. {r['max']:{fmt}} {unit} (span {r['span']:{fmt}} {unit})"


def format_summary(summary: dict[str, object]) -> str:
    """Readable, aligned text of one :func:`inspect_log` summary."""
    s, seg, ranges = summary["sampling"], summary["segmentation"], summary["ranges"]
    rows: list[tuple[str, str]] = [("samples", f"{summary['samples']}")]
    if s["interval_ms"] is not None:
        iv = s["interval_ms"]
        rows += [("duration", f"{s['duration_s']:.4g} s"),
                 ("sample rate", f"{s['sample_rate_hz']:.4g} Hz (median interval "
                                 f"{iv['median']:.4g} ms, {iv['min']:.4g} .. {iv['max']:.4g} ms)"),
                 ("jitter", f"{s['jitter_percent']:.2f} % (std / median of the intervals "
                            f"within {GAP_FACTOR:g} x the median)"),
                 ("gaps", f"{s['gaps']['count']} (total {s['gaps']['total_s']:.3g} s, "
                          f"longest {s['gaps']['longest_s']:.3g} s)")]
    elif not s["has_time"]:
        rows.append(("time", "none (quasi-static log)"))
    rows += [("displacement", _span(ranges["displacement_mm"], "mm")),
             ("force", _span(ranges["force_N"], "N")),
             ("pressure A (gauge)", _span(ranges["pressure_a_bar"], "bar")),
             ("pressure B (gauge)", _span(ranges["pressure_b_bar"], "bar"))]
    if summary["vented"]:
        rows.append(("vented", ", ".join(c.upper() for c in summary["vented"])))
    level = summary["pressure_level_bar"]
    rows.append(("pressure level", "unknown" if level is None else f"{level:.4g} bar gauge"))
    rows += [("displacement noise", f"{seg['noise_mm']:.3g} mm (std, from 2nd differences)"),
             ("reversal threshold", f"{seg['threshold_mm']:.3g} mm"),
             ("reversals", f"{seg['reversals']}"),
             ("loops", f"{seg['loops']}")]
    p = seg["pauses"]
    rows.append(("pauses", "n/a (no time)" if p is None else
                 f"{p['count']} (total {p['total_s']:.3g} s, longest {p['longest_s']:.3g} s)"))
    rows.append(("regions", ", ".join(f"{name} {100 * share:.1f} %"
                                      for name, share in summary["regions"].items())))
    rows.append(("speed bands", ", ".join(f"{name} {100 * share:.1f} %"
                                          for name, share in summary["speed_bands"].items())))
    present = summary["rig"]["present"]
    rows.append(("rig metadata", ", ".join(f"{k} {v:g}" for k, v in present.items())
                 or "none"))
    rows.append(("missing metadata", ", ".join(summary["rig"]["missing"]) or "none"))
    width = max(len(label) for label, _ in rows)
    lines = [f"{summary['file']}" + (f" ({summary['path']})" if summary["path"] else "")]
    lines += [f"  {label:<{width}}  {value}" for label, value in rows]
    lines += [f"  note: {note}" for note in summary["notes"]]
    return "\n".join(lines)
