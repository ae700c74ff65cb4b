"""Does a fitted time delay follow the data's lag, or the displacement's noise? (issue 33)

The closed loop's `null/6` (no effect withheld) was planned for `time_delay` against its
absence: two 19 s sine sweeps of 0.3 mm, 0.5 to 13.3 Hz, at 6 bar, able to detect a delay
of 0.013 ms. After those runs the diagnosis accepted a time delay. This script plays one
such sweep on a dataset's rig (the independent simulator, its truth, no delay) and fits the
baseline with and without ``time_delay`` to that log alone, four ways:

- ``clean``: no sensor noise at all (denoised as by default, and raw);
- ``noisy``: the dataset's sensor noise (force AR(1), displacement white noise and the
  encoder's quantum), the fit's default denoising;
- ``noisy, raw displacement``: the same log, ``denoise=False``;
- ``force noise only``: the displacement exact (its noise and quantum set to 0), the force
  noise as drawn, denoised and raw.

Each row: the RMS of both fits, the fitted delay with its standard error (ms), and its
z. A delay that is there only because the shifted displacement is a weighted mean of
neighbouring samples (linear interpolation, :class:`~fitstiff.physics.terms.measurement.TimeDelay`)
shows as a delay many standard errors from 0 with the displacement's noise, and none
without it.

    python benchmarks/delay_bias.py [--id null/6] [--json F]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def _fits(log, baseline: str, *, denoise: bool) -> dict[str, object]:
    from fitstiff import fit

    out: dict[str, object] = {}
    for spec in (baseline, baseline + "+time_delay"):
        result = fit([log], spec, denoise=denoise).to_dict()
        out["rms_N" if spec == baseline else "rms_with_delay_N"] = result["rms_N"]
        if "delay" in result["parameters"]:
            p = result["parameters"]["delay"]
            out.update(delay_ms=p["value"], delay_stderr_ms=p["stderr"],
                       z=p["value"] / p["stderr"] if p["stderr"] else None,
                       converged=result["converged"])
    return out


def main(argv=None) -> None:
    from fitstiff._testing.plan_loop import LOOP_LIMITS
    from fitstiff._testing.withheld import make_dataset, simulate_program
    from fitstiff.planning.families import Choice, Limits

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--id", default="null/6", help="a withheld-effect dataset")
    parser.add_argument("--amplitude-mm", type=float, default=0.3)
    parser.add_argument("--end-hz", type=float, default=13.3)
    parser.add_argument("--supply-bar", type=float, default=6.0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    logs, truth = make_dataset(args.id)
    limits = Limits.from_logs(logs, **LOOP_LIMITS)
    start_mm = logs[0].rig.start_position * 1e3
    choice = Choice("sweep", {"amplitude_mm": args.amplitude_mm, "start_hz": 0.5,
                              "end_hz": args.end_hz, "duration_s": 19.0},
                    args.supply_bar, start_mm)
    t, x = choice.sample(limits)
    rows = {}

    def sweep(clean: bool, rig_truth=truth):
        # as the closed loop plays a planned program (its first run's noise)
        return simulate_program(rig_truth, t, x, supply_bar=args.supply_bar,
                                start_position_mm=start_mm, name="planned_0", clean=clean)

    clean = sweep(True)
    rows["clean"] = _fits(clean, truth["baseline"], denoise=True)
    rows["clean, raw displacement"] = _fits(clean, truth["baseline"], denoise=False)
    noisy = sweep(False)
    rows["noisy"] = _fits(noisy, truth["baseline"], denoise=True)
    rows["noisy, raw displacement"] = _fits(noisy, truth["baseline"], denoise=False)
    exact_input = dict(truth["noise"], displacement_um=0.0, quantum_um=0.0)
    exact = sweep(False, dict(truth, noise=exact_input))
    rows["force noise only"] = _fits(exact, truth["baseline"], denoise=True)
    rows["force noise only, raw displacement"] = _fits(exact, truth["baseline"], denoise=False)
    report = {"id": args.id, "program": choice.describe(), "supply_bar": args.supply_bar,
              "rate_hz": limits.rate_hz, "samples": int(t.size), "noise": truth["noise"],
              "fits": rows, "wall_s": time.perf_counter() - start}
    for name, r in rows.items():
        se, z = r["delay_stderr_ms"], r["z"]
        print(f"{name:<36} rms {r['rms_N']:.4f} -> {r['rms_with_delay_N']:.4f} N   delay "
              f"{r['delay_ms']:+.4f} +- {'n/a' if se is None else f'{se:.4f}'} ms  "
              f"(z {'n/a' if z is None else f'{z:+.1f}'})")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
