"""``fitstiff simulate``: a synthetic log from a model spec, a displacement program and noise.

A thin layer over :func:`fitstiff.physics.simulate.simulate`: writes ``<name>.csv`` (canonical
columns), the sidecar ``<name>.json`` (rig keys; ``supply_bar`` makes the chambers closed on
reload), ``<name>.truth.json`` (every parameter, the noise, the seed, the program, the derived
quantities and the noise-free force) and ``manifest.json`` to ``--out DIR``.

Example (the paper's cylinder, Fig. 4-style triangle cycles)::

    fitstiff simulate --model chamber+dahl --set sigma0=40 --set Fc=18 \\
        --program triangle --amplitudes-mm 0.05,0.1,0.2,0.5,1 --rate-mm-s 1 --out sim/
"""

from __future__ import annotations

import argparse
import re

from fitstiff.cli.common import add_out_argument, model_spec
from fitstiff.data import PAPER_RIG
from fitstiff.errors import InputError
from fitstiff.io.log import RIG_KEYS, Rig
from fitstiff.io.output import OutputDir
from fitstiff.physics.model import DEFAULT_MODEL
from fitstiff.physics.programs import (PAUSE_AT, NestedLoops, Pause, Program, Ramp, SineSweep,
                                       TriangleCycles)
from fitstiff.physics.simulate import DEFAULT_RATE_HZ, Noise, format_log, simulate

__all__ = ["add_parser", "run", "PROGRAMS"]

#: --program choices and what they do
PROGRAMS = {
    "triangle": "triangle cycles 0 -> +A -> -A -> 0 for each of --amplitudes-mm "
                "(default 0.05,0.1,0.2,0.5,1)",
    "nested": "a major cycle of amplitude --amplitudes-mm (one value, default 1) with nested "
              "minor loops --minor-mm (default 0.4,0.2,0.1) on both branches",
    "sine": "sine of amplitude --amplitudes-mm (one value, default 0.5) at --frequency-hz F, "
            "or a linear sweep F0,F1, for --duration-s",
    "ramp": "one ramp of --distance-mm, then a hold of --pause-s (relaxation test)",
}
_DEFAULT_AMPLITUDES = {"triangle": (0.05, 0.1, 0.2, 0.5, 1.0), "nested": (1.0,), "sine": (0.5,)}


_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def _floats(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers such as 0.1,0.5, found {text!r}") from None
    return values


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``fitstiff simulate``."""
    programs = "\n".join(f"  {name:9s} {meaning}" for name, meaning in PROGRAMS.items())
    parser = subparsers.add_parser(
        "simulate",
        help="synthetic logs from a model spec, a displacement program and sensor noise",
        description=(
            "Simulate a model with known parameters on a displacement program, add sensor "
            "noise, and write <name>.csv (canonical columns), the sidecar <name>.json (rig "
            "keys; both chambers closed at --supply-bar), <name>.truth.json (parameters, "
            "noise, seed, program, derived quantities, noise-free force) and manifest.json."),
        epilog=f"programs:\n{programs}\n\nExample:\n  fitstiff simulate --model chamber+dahl "
               "--set sigma0=40 --set Fc=18 --program triangle --out sim/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--model", default=DEFAULT_MODEL, metavar="SPEC", type=model_spec,
                        help="model spec, terms joined by '+' (default chamber+dahl)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        dest="values",
                        help="a parameter value in its display unit (sigma0=40 is N/mm, "
                             "Fc=18 is N; see the truth file for names and units); repeatable")
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    parser.add_argument("--name", default="simulated",
                        help="file stem of the written log (default simulated)")
    add_out_argument(parser)

    program = parser.add_argument_group("displacement program")
    program.add_argument("--program", choices=PROGRAMS, default="triangle",
                         help="see the list below (default triangle)")
    program.add_argument("--amplitudes-mm", type=_floats, metavar="A[,A...]",
                         help="cycle amplitude(s)")
    program.add_argument("--rate-mm-s", type=float, default=1.0, metavar="V",
                         help="speed of triangle, nested and ramp legs (default 1)")
    program.add_argument("--cycles", type=int, default=1, metavar="N",
                         help="cycles per amplitude (triangle) or major cycles (nested); "
                              "default 1")
    program.add_argument("--pause-s", type=_floats, default=(), metavar="T[,T...]",
                         help="pauses at --pause-at, used in turn (triangle, nested); the hold "
                              "after a ramp")
    program.add_argument("--pause-at", choices=PAUSE_AT, default="reversals",
                         help="where triangle / nested programs pause: at reversals or where "
                              "they pass the cycle centre (default reversals)")
    program.add_argument("--minor-mm", type=_floats, default=(0.4, 0.2, 0.1), metavar="D[,D...]",
                         help="nested minor loop sizes, decreasing (default 0.4,0.2,0.1)")
    program.add_argument("--frequency-hz", type=_floats, default=(5.0,), metavar="F[,F1]",
                         help="sine frequency, or start,end of a sweep (default 5)")
    program.add_argument("--duration-s", type=float, default=2.0, metavar="T",
                         help="sine duration (default 2)")
    program.add_argument("--distance-mm", type=float, default=1.0, metavar="D",
                         help="ramp distance, + toward the B cap (default 1)")
    program.add_argument("--rate-hz", type=float, default=DEFAULT_RATE_HZ, metavar="FS",
                         help=f"sample rate (default {DEFAULT_RATE_HZ:g})")

    rig = parser.add_argument_group(
        "rig (default: the paper's Festo OSP-P 32 rodless cylinder, closed at mid-stroke)")
    for key in RIG_KEYS:
        default = PAPER_RIG[key.key]
        rig.add_argument(key.flag, dest=key.key, type=float, default=default,
                         metavar=key.key.rsplit("_", 1)[1].upper(),
                         help=key.help if default is None or "default" in key.help
                         else f"{key.help} (default {default:g})")

    noise = parser.add_argument_group("sensor noise (standard deviations)")
    defaults = Noise()
    noise.add_argument("--force-noise-n", type=float, default=defaults.force_N, metavar="N",
                       help=f"force channel, N (default {defaults.force_N:g})")
    noise.add_argument("--displacement-noise-um", type=float, default=defaults.displacement_um,
                       metavar="UM", help="displacement channel, um "
                                          f"(default {defaults.displacement_um:g})")
    noise.add_argument("--pressure-noise-mbar", type=float, default=defaults.pressure_mbar,
                       metavar="MBAR", help="each pressure channel, mbar "
                                            f"(default {defaults.pressure_mbar:g})")
    noise.add_argument("--ar1", type=float, default=defaults.ar1, metavar="PHI",
                       help="AR(1) colour of every channel's noise, -1 < PHI < 1 (default 0)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Simulate and write the log, sidecar, truth and manifest."""
    if not _NAME.match(args.name):
        raise InputError(None, "--name", f"found {args.name!r}",
                         "give a file stem of letters, digits, '_', '-' and '.'")
    rig = Rig.from_mapping({k.key: getattr(args, k.key) for k in RIG_KEYS},
                           source="command line")
    noise = Noise(force_N=args.force_noise_n, displacement_um=args.displacement_noise_um,
                  pressure_mbar=args.pressure_noise_mbar, ar1=args.ar1)
    program = program_from_args(args)
    values = parse_values(args.values)
    planned = [f"{args.name}.csv", f"{args.name}.json", f"{args.name}.truth.json"]
    with OutputDir(args.out, planned=planned, seed=args.seed,
                   options={k: v for k, v in vars(args).items() if k != "func"}) as out:
        sim = simulate(args.model, program, rig=rig, params=values, noise=noise,
                       seed=args.seed, name=args.name, rate_hz=args.rate_hz)
        for name, text in format_log(sim.log, truth=sim.truth).items():
            out.write_bytes(name, text)
        out.finish()
    log = sim.log
    print(f"wrote {out.path / (log.name + '.csv')}: {len(log)} samples over {log.duration:g} s "
          f"at {args.rate_hz:g} Hz, model {sim.model.spec}, sidecar and truth beside it")
    return 0


def parse_values(entries: list[str]) -> dict[str, float]:
    """``["sigma0=40", "Fc=18"]`` -> ``{"sigma0": 40.0, "Fc": 18.0}`` (display units)."""
    values = {}
    for entry in entries:
        name, sep, text = entry.partition("=")
        try:
            value = float(text)
        except ValueError:
            value = None
        if not sep or not name.strip() or value is None:
            raise InputError(None, f"--set {entry}", "is not NAME=NUMBER",
                             "write e.g. --set sigma0=40")
        values[name.strip()] = value
    return values


def program_from_args(args: argparse.Namespace) -> Program:
    """The displacement program the options describe."""
    amplitudes = args.amplitudes_mm or _DEFAULT_AMPLITUDES.get(args.program, ())
    if args.program in ("nested", "sine") and len(amplitudes) != 1:
        raise InputError(None, "--amplitudes-mm", f"found {len(amplitudes)} values",
                         f"give one amplitude for --program {args.program}")
    if args.program == "triangle":
        return TriangleCycles(amplitudes_mm=amplitudes, rate_mm_s=args.rate_mm_s,
                              cycles=args.cycles, pause_s=args.pause_s, pause_at=args.pause_at)
    if args.program == "nested":
        return NestedLoops(amplitude_mm=amplitudes[0], minor_mm=args.minor_mm,
                           rate_mm_s=args.rate_mm_s, cycles=args.cycles, pause_s=args.pause_s,
                           pause_at=args.pause_at)
    if args.program == "sine":
        if len(args.frequency_hz) not in (1, 2):
            raise InputError(None, "--frequency-hz", f"found {len(args.frequency_hz)} values",
                             "give F for a sine or F0,F1 for a sweep")
        return SineSweep(amplitude_mm=amplitudes[0], start_hz=args.frequency_hz[0],
                         end_hz=args.frequency_hz[-1], duration_s=args.duration_s)
    if len(args.pause_s) > 1:
        raise InputError(None, "--pause-s", f"found {len(args.pause_s)} values",
                         "give one hold duration for --program ramp")
    ramp = Ramp(distance_mm=args.distance_mm, rate_mm_s=args.rate_mm_s)
    return ramp + Pause(duration_s=args.pause_s[0]) if args.pause_s else ramp
