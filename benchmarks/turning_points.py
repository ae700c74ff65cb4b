"""How far off are the denoiser's turning points, by program, speed and sample rate?

A rate-independent friction model restarts its pre-sliding branch at every reversal, from the
turning point's displacement: an apex placed ``e`` beyond the true one lowers the modelled
force on the whole return branch by about the pre-sliding stiffness times ``e`` (0.17 N for
3 um at 56 N/mm). This script plays triangle cycles (corners rounded over 6 ms, as
:func:`fitstiff._testing.rig_sim.render` rounds them) and sines on the independent simulator's
fine grid, samples them at 200, 500 and 1000 Hz with the withheld-effect benchmark's sensor
noise (0.73 um white, 1 um encoder quantum), and compares every turning point of
:func:`fitstiff.segments.denoise.turning_points` (given the segmentation's pauses, as a fit
gives them) with the fine path's extremum. Per case: the
mean outward error and its scatter (um), for the fitted turns and, as the reference measured
in the same run, for the raw extreme sample.

    python benchmarks/turning_points.py [--json F]

About 20 s.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

SUBSTEPS = 20
NOISE_M = 0.73e-6
QUANTUM_M = 1e-6
RATES_HZ = (200.0, 500.0, 1000.0)


def programs() -> dict[str, object]:
    import fitstiff._testing.rig_sim as rs

    out = {}
    for amplitude in (0.3, 1.0):
        for speed in (0.2, 1.0, 5.0, 20.0):
            legs = tuple(seg for _ in range(12)
                         for seg in (rs.leg(amplitude, speed), rs.leg(-amplitude, speed)))
            out[f"triangle {amplitude} mm, {speed} mm/s"] = rs.Program(legs)
    for hz in (1.0, 3.0, 6.0, 10.0):
        out[f"sine 0.3 mm, {hz} Hz"] = rs.Program((rs.sweep(0.3, hz, hz, 6.0),))
    out["sweep 0.3 mm, 0.5-13.3 Hz"] = rs.Program((rs.sweep(0.3, 0.5, 13.3, 19.0),))
    return out


def benchmark_logs() -> list[tuple[float, str, object]]:
    """The withheld-effect benchmark's three log programs at their own speeds and rates
    (triangles, a nested loop, pauses at turns, a fast stroke into a hold, a sine sweep):
    turns of several kinds in one log, as a diagnosis meets them."""
    from fitstiff._testing.withheld import LOGS, log_program

    return [(rate, f"withheld log {i} ({speed:g} mm/s)", log_program(i, speed))
            for i, (speed, rate) in enumerate(LOGS)]


def outward_errors(program, rate_hz: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Outward errors (m) of the fitted and of the raw turning points against the fine
    path's extrema."""
    import fitstiff._testing.rig_sim as rs
    from fitstiff.io.log import Log
    from fitstiff.segments.denoise import reversal_samples, turning_points
    from fitstiff.segments.segmentation import segment
    from fitstiff.signal.noise import estimate_noise

    _, fine = rs.render(program, rate_hz, SUBSTEPS)
    sampled = fine[::SUBSTEPS]
    apex, sign, reversals = rs.fine_turns(fine, SUBSTEPS)
    keep = (reversals > 40) & (reversals < sampled.size - 40)
    rng = np.random.default_rng(seed)
    x = np.round((sampled + NOISE_M * rng.standard_normal(sampled.size)) / QUANTUM_M) * QUANTUM_M
    # the pauses as a fit finds them (the segmentation's standstills), as Problem passes them
    log = Log(name="turns", displacement=x, force=np.zeros_like(x),
              time=np.arange(x.size) / rate_hz)
    _, fitted, _ = turning_points(x, reversals[keep], noise=estimate_noise(x),
                                  still=segment(log).still)
    raw = x[reversal_samples(x, reversals[keep])]
    return (fitted - apex[keep]) * sign[keep], (raw - apex[keep]) * sign[keep]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = []
    cases = [(rate, name, program) for rate in RATES_HZ for name, program in programs().items()]
    cases += benchmark_logs()
    for rate, name, program in cases:
        if True:
            fitted, raw = (e * 1e6 for e in outward_errors(program, rate, args.seed))
            row = {"rate_hz": rate, "program": name, "turns": int(fitted.size),
                   "fitted_mean_um": float(fitted.mean()), "fitted_sd_um": float(fitted.std()),
                   "raw_mean_um": float(raw.mean()), "raw_sd_um": float(raw.std())}
            rows.append(row)
            print(f"{rate:6.0f} Hz  {name:28s} turns {row['turns']:3d}   fitted "
                  f"{row['fitted_mean_um']:+6.2f} +- {row['fitted_sd_um']:4.2f} um   raw "
                  f"{row['raw_mean_um']:+6.2f} +- {row['raw_sd_um']:4.2f} um", flush=True)
    def rms(key: str) -> float:
        return float(np.sqrt(np.mean([r[f"{key}_mean_um"] ** 2 + r[f"{key}_sd_um"] ** 2
                                      for r in rows])))

    bias = np.abs([r["fitted_mean_um"] for r in rows])
    largest = rows[int(np.argmax(bias))]
    summary = {"fitted_rms_error_um": rms("fitted"), "raw_rms_error_um": rms("raw"),
               "fitted_median_abs_bias_um": float(np.median(bias)),
               "fitted_cases_above_1um": int(np.sum(bias > 1.0)), "cases": len(rows),
               "largest_fitted_bias_um": largest["fitted_mean_um"],
               "largest_fitted_bias_case": f"{largest['program']} at {largest['rate_hz']:.0f} Hz"}
    print(f"RMS error over the cases: fitted {summary['fitted_rms_error_um']:.2f} um, raw "
          f"{summary['raw_rms_error_um']:.2f} um; fitted median abs bias "
          f"{summary['fitted_median_abs_bias_um']:.2f} um, above 1 um in "
          f"{summary['fitted_cases_above_1um']} of {len(rows)} cases; largest "
          f"{summary['largest_fitted_bias_um']:+.2f} um ({summary['largest_fitted_bias_case']})")
    if args.json:
        args.json.write_text(json.dumps({"noise_um": NOISE_M * 1e6, "quantum_um": QUANTUM_M * 1e6,
                                         "seed": args.seed, "rows": rows, "summary": summary,
                                         "wall_s": time.perf_counter() - start}, indent=1))


if __name__ == "__main__":
    main()
