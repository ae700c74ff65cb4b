"""Regenerate the synthetic logs in ``data/synthetic/`` (deterministic, byte for byte).

Usage (with the project's Python)::

    python data/make_synthetic.py                               # every set, README, SHA256SUMS
    python data/make_synthetic.py --only effects/leakage --out /tmp/check   # one set elsewhere
    python data/make_synthetic.py --list                        # the set names

Every log is :func:`fitstiff.physics.simulate.simulate` of a model with known parameters on a
displacement program, plus sensor noise, written by :func:`fitstiff.physics.simulate.write_log` as
``<log>.csv`` + sidecar ``<log>.json`` + ground truth ``<log>.truth.json``. The noise seed of a
log is the CRC-32 of ``"<set>/<log>"``, so a log's noise does not depend on which other logs
are generated. A full run also writes ``README.md`` (the sets and their truth) and
``SHA256SUMS`` (every file's hash; ``tests/test_simulate.py`` checks both against the files and
regenerates one set to check the files still follow from the code).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys
import zlib
from collections.abc import Mapping
from pathlib import Path

from fitstiff.io.log import Rig
from fitstiff.io.output import write_atomic
from fitstiff.physics.model import Model, build_model
from fitstiff.physics.programs import (Concat, NestedLoops, Pause, Program, Ramp, SineSweep,
                                       TriangleCycles)
from fitstiff.physics.simulate import Noise, SimulatedLog, simulate, write_log

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "synthetic"

#: the paper's cylinder: Festo OSP-P 32, 32 mm bore, rodless, 700 mm stroke, no dead volume
PAPER_CYLINDER = {"bore_mm": 32.0, "rod_mm": 0.0, "stroke_mm": 700.0, "dead_length_a_mm": 0.0,
                  "dead_length_b_mm": 0.0, "ambient_bar": 1.01325}
#: the seal of DESIGN §1.2 (about 40 N/mm up to a breakaway of 15-20 N) and an adiabatic n
BASELINE = "chamber+dahl"
SEAL = {"n": 1.4, "sigma0": 40.0, "Fc": 18.0}
NOISE = Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0, ar1=0.0)
FIG4_AMPLITUDES = (0.05, 0.1, 0.2, 0.5, 1.0)


@dataclasses.dataclass(frozen=True)
class LogSpec:
    """One log of a set: its program, sample rate and operating point."""

    name: str
    program: Program
    rate_hz: float
    supply_bar: float = 6.0
    start_position_mm: float = 350.0
    load_kg: float | None = None

    def rig(self) -> Rig:
        return Rig.from_mapping({**PAPER_CYLINDER, "supply_bar": self.supply_bar,
                                 "start_position_mm": self.start_position_mm,
                                 "load_kg": self.load_kg})


@dataclasses.dataclass(frozen=True)
class DataSet:
    """A folder of logs simulated with one model and one set of true parameters."""

    folder: str
    about: str
    logs: tuple[LogSpec, ...]
    effect: str | None = None
    params: Mapping[str, float] = dataclasses.field(default_factory=dict)
    settings: Mapping[str, Mapping[str, object]] = dataclasses.field(default_factory=dict)

    @property
    def spec(self) -> str:
        return BASELINE if self.effect is None else f"{BASELINE}+{self.effect}"

    def model(self) -> Model:
        """The model with this set's static settings (e.g. a reference pressure)."""
        model = build_model(self.spec)
        return model.with_terms(dataclasses.replace(t, **self.settings.get(t.name, {}))
                                for t in model.terms)

    def simulate(self) -> list[SimulatedLog]:
        model = self.model()
        return [simulate(model, log.program, rig=log.rig(), params={**SEAL, **self.params},
                         noise=NOISE, seed=zlib.crc32(f"{self.folder}/{log.name}".encode()),
                         name=log.name, rate_hz=log.rate_hz) for log in self.logs]


def triangles(amplitudes=(0.2, 0.5, 1.0), *, rate: float = 1.0, **options) -> TriangleCycles:
    return TriangleCycles(amplitudes_mm=amplitudes, rate_mm_s=rate, **options)


def speed_series(*, prefix: str) -> tuple[LogSpec, ...]:
    """Triangle cycles of 0.5 and 1 mm at three speeds, ~600-1200 samples each."""
    return (LogSpec(f"{prefix}_1mm_s", triangles((0.5, 1.0), rate=1.0), 200.0),
            LogSpec(f"{prefix}_5mm_s", triangles((0.5, 1.0), rate=5.0), 1000.0),
            LogSpec(f"{prefix}_20mm_s", triangles((0.5, 1.0), rate=20.0, cycles=2), 1000.0))


def operating_points(program: Program, rate_hz: float, *, prefix: str) -> tuple[LogSpec, ...]:
    """The same program at three pressures / positions."""
    return tuple(LogSpec(f"{prefix}_p{p:g}bar_x{x:g}mm", program, rate_hz, supply_bar=p,
                         start_position_mm=x)
                 for p, x in ((2.0, 350.0), (6.0, 350.0), (6.0, 50.0)))


def relaxation(hold_s: float) -> Program:
    """Out 1 mm, hold, 2 mm back, hold, return to the start."""
    return Concat(parts=(Ramp(distance_mm=1.0, rate_mm_s=1.0), Pause(duration_s=hold_s),
                         Ramp(distance_mm=-2.0, rate_mm_s=1.0), Pause(duration_s=hold_s),
                         Ramp(distance_mm=1.0, rate_mm_s=1.0)))


FIG4 = DataSet(
    "fig4",
    "The paper's Fig. 4 experiment on its cylinder: triangle cycles of growing amplitude "
    f"({', '.join(f'{a:g}' for a in FIG4_AMPLITUDES)} mm) at 1 mm/s, 200 Hz, supply 0, 2, 4 "
    "and 6 bar gauge, closed at mid-stroke and near both ends. No load: the baseline model "
    "has no inertia term, so a load would not change the force.",
    tuple(LogSpec(f"p{p:g}bar_x{x:g}mm", triangles(FIG4_AMPLITUDES), 200.0, supply_bar=p,
                  start_position_mm=x)
          for p in (0.0, 2.0, 4.0, 6.0) for x in (350.0, 50.0, 650.0)),
)

NULL = DataSet(
    "null",
    "The baseline model with no missing effect, on the programs the effect sets use (slow "
    "and fast triangles, pauses, nested loops, a sine): the diagnosis should accept nothing.",
    (LogSpec("triangle_1mm_s", triangles(), 100.0),
     LogSpec("triangle_10mm_s_pauses", triangles(rate=10.0, pause_s=(0.5, 2.0)), 200.0,
             supply_bar=2.0, start_position_mm=50.0),
     LogSpec("nested", NestedLoops(amplitude_mm=1.0, minor_mm=(0.4, 0.2, 0.1), rate_mm_s=1.0),
             100.0, supply_bar=4.0, start_position_mm=650.0),
     LogSpec("sine_8hz", SineSweep(amplitude_mm=0.3, start_hz=8.0, duration_s=1.0), 1000.0)),
)

EFFECTS = (
    DataSet("effects/viscous", "Viscous friction c v: 0.2, 1 and 4 N at 1, 5 and 20 mm/s.",
            speed_series(prefix="triangle"), "viscous", {"c": 200.0}),
    DataSet("effects/stribeck",
            "Friction level 30 % higher at rest than in sliding, Stribeck speed 2 mm/s; "
            "slow, medium and fast triangles.",
            speed_series(prefix="triangle"), "stribeck",
            {"stribeck_ratio": 1.3, "stribeck_vs": 2.0}),
    DataSet("effects/asymmetry",
            "Friction level 15 % higher (slope 10 % higher) toward the B cap than toward A.",
            operating_points(triangles(), 100.0, prefix="triangle"), "asymmetry",
            {"level_asym": 0.15, "slope_asym": 0.1}),
    DataSet("effects/pressure_friction",
            "Friction level rises 5 %/bar with the chamber pressure (exp(beta (p - p_ref))); "
            "supply 0, 2, 4 and 6 bar. The reference pressure p_ref is 3 bar gauge (settings, "
            "Pa): the mean over the four logs, which is what a joint fit of the set uses, so "
            "the true Fc is the level at 3 bar.",
            tuple(LogSpec(f"triangle_p{p:g}bar", triangles(), 100.0, supply_bar=p)
                  for p in (0.0, 2.0, 4.0, 6.0)),
            "pressure_friction", {"beta": 0.05}, {"pressure_friction": {"p_ref": 3e5}}),
    DataSet("effects/dwell_stiction",
            "A stiction peak after every standstill, whichever way the motion resumes: a "
            "junction of strength 4 N x ln(1 + pause / 1 s) (1.6 N after 0.5 s, 8.8 N after "
            "8 s) peaking 0.1 mm from the pause position; pauses of 0.5-8 s at mid-stroke "
            "passes and at reversals.",
            (LogSpec("pauses_mid_stroke", triangles((0.5,), cycles=2, pause_s=(1.0, 4.0),
                                                    pause_at="passes"), 50.0),
             LogSpec("pauses_at_reversals", triangles((0.5,), cycles=2, pause_s=(0.5, 2.0, 5.0)),
                     50.0),
             LogSpec("long_pauses_mid_stroke", triangles((0.5, 1.0), pause_s=(8.0, 3.0),
                                                         pause_at="passes"), 50.0,
                     supply_bar=2.0)),
            "dwell_stiction", {"dwell_gain": 4.0, "dwell_tau": 1.0, "dwell_decay": 0.1}),
    DataSet("effects/heat_transfer",
            "Gas-wall heat exchange (rate 2 /s) with n = 1.4: nearly isothermal at 0.2 mm/s, "
            "adiabatic at 20 mm/s; closed near the A end at 6 bar, where the chambers are "
            "stiffest.",
            (LogSpec("triangle_0p2mm_s", triangles((1.0,), rate=0.2), 50.0,
                     start_position_mm=50.0),
             LogSpec("triangle_2mm_s", triangles((1.0,), rate=2.0, cycles=2), 250.0,
                     start_position_mm=50.0),
             LogSpec("triangle_20mm_s", triangles((1.0,), rate=20.0, cycles=4), 1000.0,
                     start_position_mm=50.0)),
            "heat_transfer", {"heat_rate": 2.0}),
    DataSet("effects/leakage",
            "The pressure difference across the piston relaxes at 0.05 /s (leak past the "
            "seal): 1 mm out, 15 s hold, 2 mm back, 15 s hold.",
            tuple(LogSpec(f"holds_p{p:g}bar_x{x:g}mm", relaxation(15.0), 25.0, supply_bar=p,
                          start_position_mm=x)
                  for p, x in ((6.0, 50.0), (4.0, 650.0), (6.0, 350.0))),
            "leakage", {"leak_rate": 0.05}),
    DataSet("effects/inertia",
            "A 5 kg moving mass (load_kg 5 in the sidecars) under sines of 0.3 mm at 5 and "
            "10 Hz and a 2-15 Hz sweep: up to about 13 N of m a.",
            (LogSpec("sine_5hz", SineSweep(amplitude_mm=0.3, start_hz=5.0, duration_s=1.0),
                     1000.0, load_kg=5.0),
             LogSpec("sine_10hz", SineSweep(amplitude_mm=0.3, start_hz=10.0, duration_s=0.8),
                     1000.0, load_kg=5.0),
             LogSpec("sweep_2_15hz", SineSweep(amplitude_mm=0.3, start_hz=2.0, end_hz=15.0,
                                               duration_s=1.2), 1000.0, load_kg=5.0)),
            "inertia", {"mass": 5.0}),
    DataSet("effects/force_drift",
            "The force channel's offset drifts by 0.1 N/s (about 0.7 N over a log).",
            operating_points(triangles(), 100.0, prefix="triangle"), "force_drift",
            {"drift": 0.1}),
    DataSet("effects/time_delay",
            "The force channel lags the displacement by 2 ms; fast triangles and a sine "
            "(about 40 N/mm x 20 mm/s x 2 ms = 1.6 N after each reversal).",
            (LogSpec("triangle_10mm_s", triangles(rate=10.0), 1000.0),
             LogSpec("triangle_20mm_s", triangles(rate=20.0, cycles=2), 1000.0,
                     supply_bar=2.0),
             LogSpec("sine_10hz", SineSweep(amplitude_mm=0.5, start_hz=10.0, duration_s=0.8),
                     1000.0, start_position_mm=50.0)),
            "time_delay", {"delay": 2.0}),
    DataSet("effects/rig_compliance",
            "A 100 N/mm rig spring (0.01 mm/N) in series between the displacement sensor and "
            "the piston: the apparent pre-sliding slope drops from 40 to about 29 N/mm.",
            operating_points(triangles((0.1, 0.2, 0.5, 1.0)), 100.0, prefix="triangle"),
            "rig_compliance", {"compliance": 0.01}),
    DataSet("effects/maxwell_slip",
            "Half of the seal's slope and breakaway is Maxwell-slip (4 elements, 5 N/mm each, "
            "slip at 0.18-0.72 mm; 20 N/mm and 9 N in all) beside a Dahl element of 20 N/mm "
            "and 9 N: nested minor loops close at their return points.",
            tuple(LogSpec(f"nested_p{p:g}bar_x{x:g}mm",
                          NestedLoops(amplitude_mm=1.0, minor_mm=(0.4, 0.2, 0.1),
                                      centre_mm=c, rate_mm_s=1.0), 100.0,
                          supply_bar=p, start_position_mm=x)
                  for p, x, c in ((6.0, 350.0, 0.0), (2.0, 350.0, 0.3), (6.0, 50.0, -0.3))),
            "maxwell_slip",
            {"sigma0": 20.0, "Fc": 9.0, **{f"k_{i}": 5.0 for i in range(1, 5)},
             **{f"delta_{i}": 0.18 * i for i in range(1, 5)}}),
)

SETS = {s.folder: s for s in (FIG4, *EFFECTS, NULL)}


def generate(dataset: DataSet, out: Path) -> list[SimulatedLog]:
    """Simulate and write one set into ``out/<folder>``."""
    sims = dataset.simulate()
    for sim in sims:
        write_log(sim.log, out / dataset.folder / f"{sim.log.name}.csv", truth=sim.truth)
    return sims


def readme(results: Mapping[str, list[SimulatedLog]]) -> str:
    """README.md: how the data were made, and every set with its truth."""
    lines = [
        "# Synthetic logs",
        "",
        "Generated by `data/make_synthetic.py` (do not edit by hand: rerun it; "
        "`tests/test_simulate.py` checks that the files match `SHA256SUMS` and that the code "
        "still makes them). Each log is `<log>.csv` (columns `time_s, displacement_mm, "
        "force_N, p_a_bar, p_b_bar`, pressures gauge), its sidecar `<log>.json` (rig keys; "
        "`supply_bar` closes both chambers) and its ground truth `<log>.truth.json` (model, "
        "every parameter in display units, static settings in SI, noise, seed, program, "
        "derived quantities, noise-free force).",
        "",
        "Cylinder: the paper's Festo OSP-P 32 (32 mm bore, rodless, 700 mm stroke, no dead "
        "volume, ambient 1.01325 bar). Baseline model `chamber+dahl` with "
        + ", ".join(f"{k} = {v:g}" for k, v in SEAL.items())
        + " (N/mm, N); every effect set adds one effect to it. Noise on every log: "
        f"force {NOISE.force_N:g} N, displacement {NOISE.displacement_um:g} um, each pressure "
        f"{NOISE.pressure_mbar:g} mbar (white, standard deviations).",
        "",
        "Derived quantities of the baseline seal (from the truth files): pre-sliding slope "
        "40 N/mm, breakaway 18 N, pre-sliding range (95 % of the swing after a reversal) "
        f"{_derived(results['fig4'][0], 'presliding_range_mm'):.3g} mm.",
        "",
    ]
    for folder, sims in results.items():
        dataset = SETS[folder]
        truth = sims[0].truth
        settings = "".join(f"; {term} settings (SI): " + ", ".join(
            f"{k} = {v:g}" for k, v in values.items())
            for term, values in dataset.settings.items())
        lines += [f"## `{folder}/`", "", dataset.about, "",
                  f"Model `{truth['model']}`; parameters: "
                  + ", ".join(f"{k} = {p['value']:g} {p['unit']}".rstrip(" -")
                              for k, p in truth["parameters"].items()) + settings + ".", "",
                  "| log | supply bar | x0 mm | program | rate Hz | samples | chamber k N/mm |",
                  "|---|---|---|---|---|---|---|"]
        for spec, sim in zip(dataset.logs, sims):
            t = sim.truth
            lines.append(f"| `{spec.name}` | {spec.supply_bar:g} | {spec.start_position_mm:g} "
                         f"| {_program(t['program'])} | {t['rate_hz']:g} | {t['samples']} "
                         f"| {_derived(sim, 'chamber_stiffness_N_per_mm'):.3g} |")
        lines.append("")
    return "\n".join(lines)


def _derived(sim: SimulatedLog, key: str) -> float:
    return float(sim.truth.get("derived", {}).get(key, float("nan")))


def _program(description: Mapping[str, object]) -> str:
    kind = description["program"]
    if kind == "concat":
        return " + ".join(_program(p) for p in description["parts"])
    options = {k: v for k, v in description.items() if k != "program" and v not in ([], None)}
    if "pause_s" not in options:
        options.pop("pause_at", None)
    return f"{kind} ({', '.join(f'{k} {_short(v)}' for k, v in options.items())})"


def _short(value: object) -> str:
    if isinstance(value, (list, tuple)):
        return "/".join(f"{v:g}" for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def checksums(out: Path) -> str:
    """``SHA256SUMS`` of every file below ``out`` (except itself), sorted by path."""
    files = sorted(p for p in out.rglob("*") if p.is_file() and p.name != "SHA256SUMS")
    return "".join(f"{hashlib.sha256(p.read_bytes()).hexdigest()}  "
                   f"{p.relative_to(out).as_posix()}\n" for p in files)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--only", nargs="+", choices=SETS, metavar="SET",
                        help="generate only these sets (no README.md / SHA256SUMS)")
    parser.add_argument("--list", action="store_true", help="list the set names and exit")
    args = parser.parse_args(argv)
    if args.list:
        print("\n".join(SETS))
        return 0
    results = {}
    for folder in args.only or SETS:
        results[folder] = generate(SETS[folder], args.out)
        print(f"{folder}: {len(results[folder])} logs", file=sys.stderr)
    if not args.only:
        write_atomic(args.out / "README.md", readme(results))
        write_atomic(args.out / "SHA256SUMS", checksums(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
