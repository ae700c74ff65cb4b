"""``fitstiff stiffness``: chamber gas-spring stiffness and restoring force from geometry.

A thin layer over :mod:`fitstiff.physics.stiffness`: flags in engineering units (mm, bar gauge),
a readable aligned text output, or ``--json`` with the keys of
:data:`fitstiff.physics.stiffness.JSON_KEYS` (one object; with ``--table``,
``{"table": [objects]}``).
"""

from __future__ import annotations

import argparse
import contextlib
import json

from fitstiff.cli.common import directory
from fitstiff.io.log import RIG_KEYS, Rig
from fitstiff.io.output import OutputDir, to_jsonable
from fitstiff.io.validation import cli_number, number
from fitstiff.physics.stiffness import (ADIABATIC_AIR, BAR, JSON_KEYS, MM, StiffnessResult,
                                        chamber_stiffness, stiffness_table)

__all__ = ["add_parser", "run"]

DEFAULT_TABLE_ROWS = 7
DEFAULT_DISPLACEMENT_MM = 0.5

# rig-metadata keys whose flags (fitstiff.io.log.RIG_KEYS) this command takes -> help suffix
_RIG_FLAGS = {
    "bore_mm": " (required)",
    "rod_mm": " (default 0)",
    "stroke_mm": " (required)",
    "dead_length_a_mm": " (default 0)",
    "dead_length_b_mm": " (default 0)",
    "supply_bar": " (default for both chamber pressures)",
    "ambient_bar": "",
}
_REQUIRED = ("bore_mm", "stroke_mm")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``fitstiff stiffness``."""
    keys = "\n".join(f"  {key:30s} {meaning}" for key, meaning in JSON_KEYS.items())
    parser = subparsers.add_parser(
        "stiffness",
        help="chamber stiffness / restoring force calculator (exact and linearised)",
        description=(
            "Stiffness of the closed chambers of a pneumatic cylinder (polytropic gas spring) "
            "at a closing position, and the restoring force of a displacement by the "
            "linearised and the exact law. Pressures are gauge on the command line and "
            "absolute in every law."),
        epilog=('--json keys (one object; with --table, {"table": [one object per '
                f"position]}}):\n{keys}"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    by_key = {k.key: k for k in RIG_KEYS}
    for key, suffix in _RIG_FLAGS.items():
        parser.add_argument(by_key[key].flag, dest=key, type=cli_number,
                            required=key in _REQUIRED, metavar="X",
                            help=by_key[key].help + suffix)
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--position-mm", type=cli_number, metavar="X",
                       help="x0: length of chamber A when the valves closed (default mid-stroke)")
    where.add_argument("--table", type=int, nargs="?", const=DEFAULT_TABLE_ROWS, metavar="N",
                       help="evaluate at the centres of N equal slices of the stroke instead "
                            f"of one position (default N = {DEFAULT_TABLE_ROWS})")
    parser.add_argument("--pressure-a-bar", type=cli_number, metavar="P",
                        help="closing pressure of chamber A, gauge (default --supply-bar)")
    parser.add_argument("--pressure-b-bar", type=cli_number, metavar="P",
                        help="closing pressure of chamber B, gauge (default --supply-bar)")
    parser.add_argument("--n", type=cli_number, default=ADIABATIC_AIR, metavar="N",
                        help=f"polytropic exponent, 1 isothermal .. {ADIABATIC_AIR:g} adiabatic "
                             f"(default {ADIABATIC_AIR:g})")
    parser.add_argument("--displacement-mm", type=cli_number, default=DEFAULT_DISPLACEMENT_MM,
                        metavar="U", help="displacement from x0 at which the restoring force "
                                          "is evaluated, + toward the B cap "
                                          f"(default {DEFAULT_DISPLACEMENT_MM:g})")
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument("--out", metavar="DIR", type=directory,
                        help="also write stiffness.json and manifest.json to DIR")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Compute, print (text or JSON) and optionally write ``stiffness.json``."""
    out = (OutputDir(args.out, planned=["stiffness.json"],
                     options={k: v for k, v in vars(args).items() if k != "func"})
           if args.out else None)
    with out or contextlib.nullcontext():
        document, text = _compute(args)
        if out:
            out.write_json("stiffness.json", document)
            out.finish()
    if args.json:
        print(json.dumps(to_jsonable(document), indent=2, allow_nan=False))
    else:
        print(text)
    return 0


def _compute(args: argparse.Namespace) -> tuple[object, str]:
    """The JSON document and the text of the options' computation."""
    by_key = {k.key: k for k in RIG_KEYS}
    for key in _RIG_FLAGS:      # the plausible maximum of each value (the lower limits below)
        spec = by_key[key]
        if getattr(args, key) is not None:
            number(getattr(args, key), where=None, what=spec.flag, unit=spec.unit,
                   high=spec.high, meaning=spec.meaning)
    for flag, value in (("--pressure-a-bar", args.pressure_a_bar),
                        ("--pressure-b-bar", args.pressure_b_bar)):
        if value is not None:
            number(value, where=None, what=flag, unit="bar", high=by_key["supply_bar"].high,
                   meaning="the closing pressure, gauge")
    rig = Rig(**{by_key[key].field: getattr(args, key) * by_key[key].scale
                 for key in _RIG_FLAGS if getattr(args, key) is not None})
    options = dict(displacement=args.displacement_mm * MM, n=args.n,
                   pressure_a_gauge=_pascal(args.pressure_a_bar),
                   pressure_b_gauge=_pascal(args.pressure_b_bar))
    if args.table is not None:
        rows = stiffness_table(rig, count=args.table, **options)
        document: object = {"table": [row.to_dict() for row in rows]}
        text = format_table(rows)
    else:
        position = (rig.stroke / 2 if args.position_mm is None  # stroke is required
                    else args.position_mm * MM)
        result = chamber_stiffness(rig, position=position, **options)
        document = result.to_dict()
        text = format_result(result)
    return document, text


def format_result(result: StiffnessResult) -> str:
    """Readable, aligned text for one position."""
    d = result.to_dict()
    rows = [
        ("linearised stiffness", f"{d['stiffness_N_per_mm']:.4g} N/mm"),
        ("displacement u", f"{d['displacement_mm']:g} mm (+ toward the B cap)"),
        ("restoring force, linearised", f"{d['force_linear_N']:.4g} N"),
        ("restoring force, exact", f"{d['force_exact_N']:.4g} N"),
        ("relative gap (exact/linear - 1)", f"{d['relative_gap']:+.3g}"),
        ("relative return pressure", f"{100 * d['relative_return_pressure']:.4g} %"),
        ("preload at x0", f"{d['preload_N']:.4g} N"),
        ("pressures after u (absolute)", f"A {d['pressure_a_displaced_bar_abs']:.5g} bar, "
                                         f"B {d['pressure_b_displaced_bar_abs']:.5g} bar"),
    ]
    width = max(len(label) for label, _ in rows)
    lines = [*_describe(d, position=True), ""]
    lines += [f"  {label:<{width}}  {value}" for label, value in rows]
    return "\n".join(lines)


def format_table(rows: tuple[StiffnessResult, ...]) -> str:
    """Readable, aligned text for positions over the stroke."""
    columns = (("position_mm", "x0 [mm]", "{:.4g}"),
               ("stiffness_N_per_mm", "k [N/mm]", "{:.4g}"),
               ("force_linear_N", "F linear [N]", "{:.4g}"),
               ("force_exact_N", "F exact [N]", "{:.4g}"),
               ("relative_gap", "gap", "{:+.3g}"),
               ("relative_return_pressure", "dp/p [%]", "{:.4g}"))
    dicts = [row.to_dict() for row in rows]
    cells = [[fmt.format(100 * d[key] if key == "relative_return_pressure" else d[key])
              for key, _, fmt in columns] for d in dicts]
    widths = [max(len(title), *(len(c[i]) for c in cells))
              for i, (_, title, _) in enumerate(columns)]
    lines = [*_describe(dicts[0], position=False),
             f"  restoring force of u = {dicts[0]['displacement_mm']:g} mm (+ toward the B cap)",
             ""]
    lines.append("  " + "  ".join(f"{t:>{w}}" for (_, t, _), w in zip(columns, widths)))
    lines += ["  " + "  ".join(f"{c:>{w}}" for c, w in zip(row, widths)) for row in cells]
    return "\n".join(lines)


def _describe(d: dict[str, float], *, position: bool) -> list[str]:
    """Header lines: the cylinder and the closing state."""
    rod = "rodless" if d["rod_mm"] == 0 else f"rod {d['rod_mm']:g} mm"
    closed = f"closed at x0 = {d['position_mm']:g} mm, " if position else "closed at "
    return [
        f"cylinder: bore {d['bore_mm']:g} mm, {rod}, stroke {d['stroke_mm']:g} mm, "
        f"dead lengths A {d['dead_length_a_mm']:g} mm / B {d['dead_length_b_mm']:g} mm",
        f"{closed}p_A0 {d['pressure_a_bar']:g} bar / p_B0 {d['pressure_b_bar']:g} bar gauge "
        f"(ambient {d['ambient_bar']:g} bar), n = {d['n']:g}",
    ]


def _pascal(bar: float | None) -> float | None:
    return None if bar is None else bar * BAR
