"""The fleet page's numbers: the rows the population uses, each cylinder's estimate (the
geometric mean over its usable runs), the typical cylinder and a cylinder's first log."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from fitstiff.errors import InputError
from fitstiff.present.fleet_page._read import _files


def _usable(table: pd.DataFrame) -> pd.Series:
    """The rows the population uses: no error, converged, identifiable."""
    return (table["error"] == "") & table["converged"] & table["identifiable"]


def _quantity_mask(table: pd.DataFrame, name: str) -> np.ndarray:
    """The rows whose estimate of ``name`` enters the population (as population.py)."""
    value = table[name].to_numpy(float)
    err = (table[f"{name}_stderr"].to_numpy(float) if f"{name}_stderr" in table
           else np.zeros_like(value))
    return _usable(table).to_numpy() & np.isfinite(value) & (value > 0) & np.isfinite(err)


def _per_cylinder(table: pd.DataFrame, quantities: Sequence[str]) -> pd.DataFrame:
    """One row per cylinder: per quantity the geometric mean over its usable runs (the
    population model's per-cylinder estimate), ``files`` of its first usable run (else of
    its first run) and ``runs``."""
    ordered = table.sort_values(["cylinder", "run_index"], kind="stable")
    usable = ordered[_usable(ordered)]
    first = usable.groupby("cylinder", sort=True).first()
    fallback = ordered.groupby("cylinder", sort=True).first()
    out = pd.DataFrame(index=fallback.index)
    out["files"] = first["files"].reindex(out.index).fillna(fallback["files"])
    out["usable"] = out.index.isin(first.index)
    out["runs"] = ordered.groupby("cylinder", sort=True).size()
    for name in quantities:
        keep = _quantity_mask(ordered, name)
        logs = np.log(np.where(keep, ordered[name].to_numpy(float), 1.0))
        geo = pd.Series(logs[keep], index=ordered["cylinder"].to_numpy()[keep])
        out[name] = np.exp(geo.groupby(level=0).mean()).reindex(out.index)
    return out


def _outliers_of(population: Mapping, name: str) -> list[str]:
    return [o["cylinder"] for o in population["outliers"] if name in o.get("quantities", ())]


def _typical(per: pd.DataFrame, population: Mapping) -> str | None:
    """The cylinder nearest the population's breakaway (on the log scale) among those not
    flagged; ``None`` without a usable one."""
    flagged = {o["cylinder"] for o in population["outliers"]}
    pool = per[per["usable"] & ~per.index.isin(flagged)]
    if pool.empty:
        pool = per[per["usable"]]
    if pool.empty:
        return None
    est = population["quantities"].get("breakaway_N") or {}
    column = pool["breakaway_N"] if "breakaway_N" in pool else None
    if column is None or column.isna().all() or not est.get("mean"):
        return str(pool.index[0])
    return str((np.log(column) - math.log(est["mean"])).abs().idxmin())


def _first_log(per: pd.DataFrame, name: str | None, reading: Mapping, manifest: Mapping):
    """The first log of a cylinder's first usable run, and why not when it cannot be read."""
    from fitstiff.io.loading import load_logs

    if name is None or name not in per.index:
        return None, "no such cylinder"
    files = _files(per.loc[name, "files"], manifest)
    if not files:
        return None, f"{name}: no logs"
    try:
        return load_logs(files[:1], **dict(reading or {}))[0], ""
    except (InputError, OSError, TypeError, ValueError) as exc:
        return None, f"{name}: log not read ({' '.join(str(exc).split())[:80]})"
