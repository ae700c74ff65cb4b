"""A cylinder's report on demand: one unit of a fleet fitted again as the fleet fitted it, then
reported as any fit directory is (``fitstiff report DIR --cylinder NAME [--run RUN]``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir
from fitstiff.present.fleet_page._read import _files, _read, cylinder_dir
from fitstiff.present.fleet_page._text import _command


def cylinder_report(directory: str | Path, cylinder: str, *, run: str | None = None) -> Path:
    """Fit one unit of a fleet directory again as the fleet fitted it (its model, options
    and reading), write ``fit.json`` to ``cylinders/<cylinder>[/<run>]/`` and its report there;
    returns the report's path. The fleet page links to it.

    Raises:
        InputError: an unknown cylinder or run, a cylinder with several runs and no ``run``,
            a unit that failed in the fleet, or what fitting it raises.
    """
    from fitstiff.inference.fitting import fit
    from fitstiff.io.loading import load_logs
    from fitstiff.physics.model import DEFAULT_MODEL, parse_fix
    from fitstiff.present.report import write_report

    directory = Path(directory)
    table, _, manifest = _read(directory)
    row = _unit_row(table, directory, cylinder, run)
    options = dict(manifest.get("options") or {})
    model = options.get("model") or DEFAULT_MODEL
    fix_items = list(options.get("fix") or [])
    fit_options = {k: options[k] for k in ("solver", "starts", "seed", "max_steps", "denoise",
                                           "weights", "skip", "free")
                   if options.get(k) is not None}
    if options.get("sample_range") is not None:
        fit_options["sample_range"] = tuple(options["sample_range"])
    reading = options.get("reading") or {}
    files = _files(row["files"], manifest)
    inputs = files + [f.with_suffix(".json") for f in files if f.with_suffix(".json").is_file()]
    sub = directory / cylinder_dir(cylinder, row["run"])
    with OutputDir(sub, inputs=inputs, planned=["fit.json"], seed=fit_options.get("seed"),
                   command=_command(directory, cylinder, row["run"]),
                   options={"model": model, "fix": fix_items, **fit_options, "compare": [],
                            "reading": reading}) as out:
        logs = load_logs(files, **reading)
        result = fit(logs, model, fix=parse_fix(fix_items, model), **fit_options)
        out.write_json("fit.json", result.to_dict())
        out.finish()
    return write_report(sub)


def _unit_row(table: pd.DataFrame, directory: Path, cylinder: str, run: str | None) -> pd.Series:
    """The fleet table's row of the unit ``cylinder`` [``run``], or an InputError saying why
    there is none to fit again."""
    rows = table[table["cylinder"] == cylinder]
    if rows.empty:
        names = sorted(set(table["cylinder"]))
        shown = ", ".join(names[:5]) + (" ..." if len(names) > 5 else "")
        raise InputError(str(directory), f"--cylinder {cylinder}", "is not in the fleet",
                         f"give one of its cylinders ({shown})")
    if run is not None:
        found = rows[rows["run"] == run]
        if found.empty:
            runs = ", ".join(repr(r) for r in rows["run"])
            raise InputError(str(directory), f"--run {run}", f"is not a run of {cylinder}",
                             f"give one of {runs}" if rows["run"].ne("").any()
                             else "leave --run out: it was logged once")
        rows = found
    elif len(rows) > 1:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"has {len(rows)} runs",
                         "name one with --run (" + ", ".join(rows["run"]) + ")")
    row = rows.iloc[0]
    if row["error"]:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"failed in the fleet: "
                         f"{row['error']}", "fix its logs and run the fleet again")
    return row
