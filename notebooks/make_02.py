"""Write ``02_your_own_logs.ipynb`` (without outputs) from the cells below.

The notebook is committed; this script is its source. After editing a cell, run
``python notebooks/make_02.py``; ``tests/test_notebooks.py`` checks that the two agree and
executes the notebook.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import cells  # noqa: E402  (notebooks/cells.py, beside this script)

NOTEBOOK = Path(__file__).with_name("02_your_own_logs.ipynb")

CELLS: list[tuple[str, str]] = [
    ("markdown", r"""
# Your own rig's logs: from `inspect` to a fit and a diagnosis

This notebook walks through what you would do with logs from your own rig, on real
measurements that were not made for fitstiff: the O-ring logs in `data/real/oring/`
(E. Zillen, TU Delft 2021, CC0; see `data/real/oring/SOURCE.md`). A 3D-printed cylinder with
a 25 mm bore and an O-ring piston seal; one chamber is held at a **regulated** pressure
(1, 3, 5 and 7 bar gauge, the valve stays open, so it is not a closed gas spring), the other
side is **vented**; an external drive moves the rod back and forth over about 40 mm while a
load cell measures the force. The files are in a foreign format: tab-separated, no header,
seven columns (time in ms, three raw-volt channels, position in mm, chamber pressure in bar
gauge, rod force in N).

The steps: read the files (with the bundled format, and what you would write for your own
format), `inspect` them, fit `chamber+dahl` and `chamber+dahl+pressure_friction`, look at the
loops, and read the gap diagnosis.
"""),
    ("code", r"""
import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import fitstiff
from fitstiff.io.columns import load_format
from fitstiff.present import plotting
from fitstiff.segments.inspection import format_summary, inspect_log

DATA = Path("..") / "data" / "real" / "oring"
PATHS = [DATA / f"O-ring_{bar}bar.csv" for bar in (1, 3, 5, 7)]
print("the first rows of", PATHS[0].name)
print(*PATHS[0].read_text().splitlines()[:3], sep="\n")
"""),
    ("markdown", r"""
## Reading the files with the bundled format

fitstiff ships a format for these files, `zillen_oring` (`fmt="zillen_oring"` here,
`--format zillen_oring` on the command line). A format says which column holds which
quantity in which unit, whether a channel's sign must be flipped to fitstiff's convention
(displacement and force positive toward the B cap, force = the external force on the piston),
the file's layout (header, delimiter), which chamber is vented, and rig metadata defaults:
"""),
    ("code", r"""
fmt = load_format("zillen_oring")
print("columns:  ", " ".join(spec.describe() for spec in fmt.columns.values()))
print("no header:", fmt.no_header, "| delimiter:", repr(fmt.delimiter),
      "| vented:", sorted(fmt.vented), "| rig:", dict(fmt.rig))

logs = fitstiff.load_logs(PATHS, fmt="zillen_oring")
for log in logs:
    print(f"{log.name}: {len(log)} samples; pressure A logged: {log.pressure_a is not None}, "
          f"B: {log.pressure_b is not None}; vented {sorted(log.vented)}; "
          f"bore {log.rig.bore * 1e3:g} mm")
"""),
    ("markdown", r"""
Why both force and position are flipped is written in the format file's `_comment`
(`fitstiff/io/formats/zillen_oring.json`): at rest the load cell reads about $+pA$, while the
chamber pushes the piston toward A (a negative force in our convention), so the force is
flipped; with that, the friction (force minus the chamber force) has the sign of the velocity
while sliding only when the position is flipped too. That check - friction against the
direction of motion - is the one to make on your own rig's signs.

## Your own format: a column mapping or a format file

For your own files you write the same information yourself, on the command line or in a
small JSON file (docs/guide.md, "Reading your own logs"). Each entry of a column mapping is
`quantity=COLUMN:UNIT[:flip][:scale=K]`, COLUMN a header name or a 1-based column number;
columns not named (the raw volts here) are ignored. The command-line form:

    fitstiff inspect data/real/oring/*.csv --no-header --delimiter tab \
        --columns time=1:ms displacement=5:mm:flip p_a=6:bar force=7:N:flip \
        --bore-mm 25 --vented b

and the same as a format file, `--format my_rig.json`. Both read the files exactly as the
bundled format does:
"""),
    ("code", r"""
mapping = ["time=1:ms", "displacement=5:mm:flip", "p_a=6:bar", "force=7:N:flip"]
by_mapping = fitstiff.load_logs(PATHS, columns=mapping, no_header=True, delimiter="tab",
                                rig_overrides={"bore_mm": 25, "vented": ["b"]})
my_format = {"_comment": "my rig: logger export, no header, tab-separated",
             "no_header": True, "delimiter": "tab", "columns": mapping,
             "vented": ["b"], "rig": {"bore_mm": 25}}
with tempfile.TemporaryDirectory() as tmp:
    format_file = Path(tmp) / "my_rig.json"
    format_file.write_text(json.dumps(my_format, indent=2))
    by_file = fitstiff.load_logs(PATHS, fmt=format_file)
print(format_file.name + ":", json.dumps(my_format, indent=2), sep="\n")


def same_log(a, b):
    return (a.rig == b.rig and a.vented == b.vented and all(
        np.array_equal(getattr(a, k), getattr(b, k))
        for k in ("time", "displacement", "force", "pressure_a")))


print("mapping reads the same logs as the bundled format:",
      all(map(same_log, logs, by_mapping)))
print("format file reads the same logs as the bundled format:",
      all(map(same_log, logs, by_file)))
"""),
    ("markdown", r"""
## `inspect`: what is in a log

Before fitting anything, `fitstiff inspect LOGS... --format zillen_oring` says what each log
holds: sampling (rate, jitter, gaps), ranges, the segmentation (reversals, loops, pauses, the
share of samples per region: **presliding** = the first part of the travel after a reversal,
where the seal's pre-sliding spring acts; **sliding**; **dwell** and **standstill**;
**stroke_end** near the caps) and which rig metadata is present or missing. The same in
Python, for the 7 bar log:
"""),
    ("code", r"""
summaries = [inspect_log(log) for log in logs]
print(format_summary(summaries[-1]))
"""),
    ("code", r"""
def overview(s):
    sampling, seg = s["sampling"], s["segmentation"]
    return {"log": s["file"], "samples": s["samples"], "duration [s]": sampling["duration_s"],
            "rate [Hz]": sampling["sample_rate_hz"], "gaps": sampling["gaps"]["count"],
            "longest gap [s]": sampling["gaps"]["longest_s"],
            "pressure [bar gauge]": s["pressure_level_bar"],
            "travel [mm]": s["ranges"]["displacement_mm"]["span"],
            "reversals": seg["reversals"], "loops": seg["loops"],
            "pauses": seg["pauses"]["count"],
            "pre-sliding range [mm]": seg["presliding_range_mm"],
            "presliding [%]": 100 * s["regions"]["presliding"],
            "sliding [%]": 100 * s["regions"]["sliding"]}


pd.DataFrame([overview(s) for s in summaries]).set_index("log").round(3)
"""),
    ("markdown", r"""
What to read from it:

- **Sampling**: about 100 Hz, with gaps (the logger's pauses); the models step with the
  logged time, so gaps are allowed, but a pre-sliding curve that falls into one is seen
  coarsely.
- **Reversals and loops**: every file is a series of out-and-back strokes of about 40 mm;
  each reversal starts a pre-sliding curve, which is what identifies the seal's pre-sliding
  slope (`sigma0`), and each long stroke shows the sliding level (`Fc`).
- **Regions**: almost every sample is gross sliding; pre-sliding is a few per cent of the
  samples. There are no pauses, so nothing here can tell standstill effects (dwell stiction,
  leakage) apart.
- **Missing metadata**: stroke and start position are unknown, so the stroke-end region is
  skipped. The chamber model needs only the bore here: a chamber whose pressure is logged
  and which has no `supply_bar` is **regulated**, its logged pressure is the model's input.

The measured loops themselves (force over displacement; the chamber's $pA$ shifts each
pressure's loop down, the seal friction is the loop's half-height):
"""),
    ("code", r"""
fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
for log, s in zip(logs, summaries):
    ax.plot(log.displacement * 1e3, log.force, lw=0.6,
            label=f"{log.name} ({s['pressure_level_bar']:.2g} bar)")
ax.set(xlabel="displacement [mm]", ylabel="force [N]", title="measured, as read")
ax.grid(True, alpha=0.3)
ax.legend(fontsize="small")
fig.savefig("02_measured_loops.png", dpi=80)
"""),
    ("markdown", r"""
## Fit `chamber+dahl`

`fitstiff fit data/real/oring/*.csv --format zillen_oring --model chamber+dahl --out out/oring`.
Seal parameters are shared across the four logs; each log has its own force offset and
initial friction state. The regulated chamber adds its force $-A(p - p_\mathrm{amb})$ from
the logged pressure but no stiffness (its pressure does not change with the piston's
position), so the chamber stiffness below is 0 and the stiffness is the seal's alone.
"""),
    ("code", r"""
base = fitstiff.fit(logs, "chamber+dahl")
print(base.table())
"""),
    ("markdown", r"""
## Fit `chamber+dahl+pressure_friction`

The sliding level visibly grows with the pressure (the O-ring is pressed harder against the
bore). `pressure_friction` scales the friction level by $\exp(\beta (p - p_\mathrm{ref}))$,
with $p$ the mean gauge pressure of the two chambers at the seal (here half the regulated
pressure, the other side being vented) and `Fc` the level at $p_\mathrm{ref}$, the logs' mean
seal pressure unless given.
"""),
    ("code", r"""
withp = fitstiff.fit(logs, "chamber+dahl+pressure_friction")
print(withp.table())
"""),
    ("markdown", r"""
## The verdict

`fitstiff report` opens a fit's page with a verdict: did it converge, do the data identify
the seal, how large is the residual against the logs' own force noise (estimated from the
data alone), and what did the fit warn of. The same from the two results:
"""),
    ("code", r"""
def verdict(r):
    noise = ", ".join(f"{p['force_noise_N']:.2g}" for p in r.per_log)
    lines = [f"{r.model.spec}: " + ("converged" if r.converged else
                                    f"did NOT converge ({r.message})")
             + f" after {r.steps} steps; " + r.identifiability.line(),
             f"  RMS residual {r.rms_N:.3g} N against force noise estimates of {noise} N "
             "(per log)"]
    return "\n".join(lines + [f"  warning: {w}" for w in r.warnings])


print(verdict(base), verdict(withp), sep="\n\n")


def row(r):
    p = r.parameters()
    out = {"model": r.model.spec, "RMS [N]": r.rms_N, "BIC": r.bic,
           "residual lag-1 r": r.residual_autocorrelation}
    out |= {f"RMS {log['name']} [N]": log["rms_N"] for log in r.per_log}
    for name, label in (("presliding_slope_N_per_mm", "slope [N/mm]"),
                        ("breakaway_N", "breakaway [N]")):
        value, err = r.derived[name]
        out |= {label: value, f"{label} stderr": err}
    out["beta [1/bar]"] = p["beta"]["value"] if "beta" in p else np.nan
    return out


table = pd.DataFrame([row(base), row(withp)]).set_index("model")
print(f"\nRMS ratio with/without pressure_friction: {withp.rms_N / base.rms_N:.2f}; "
      f"BIC difference {withp.bic - base.bic:.4g}; lower RMS in every log: "
      f"{all(a['rms_N'] < b['rms_N'] for a, b in zip(withp.per_log, base.per_log))}; "
      f"smallest RMS / largest noise estimate: "
      f"{withp.rms_N / max(p['force_noise_N'] for p in withp.per_log):.0f}")
table.T.round(4)
"""),
    ("markdown", r"""
Adding `pressure_friction` lowers the residual in every log and the BIC, with a `beta` many
standard errors from zero. But neither model describes these logs to their noise: the RMS
stays many times the per-log noise estimates and both fits warn that the residuals are
strongly autocorrelated. The warning's standard errors are already inflated for that; they
still describe the noise only, not the misfit of the model (notebook 03 shows what that means
for an interval). The loops show where the misfit is.

## The loops

The 7 bar log: the whole loop, one pre-sliding curve after a reversal, and the sliding
friction level of each log against its pressure (half the difference between the median
seal force sliding one way and the other, measured = the force minus the model's chamber
force).
"""),
    ("code", r"""
k = 3                                                   # the 7 bar log
log = logs[k]
seg = fitstiff.segment(log)
pred = {r.model.spec: r.problem.per_log(r.theta) for r in (base, withp)}
styles = {base.model.spec: dict(color="tab:orange", ls="--", lw=1.2)}

fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained")
curve = plotting.reversal_zoom_samples(seg, log)
for ax, kw in ((axes[0], {}), (axes[1], {"samples": curve})):
    plotting.plot_loop(ax, log, pred[withp.model.spec][k]["force"], label=withp.model.spec,
                       **kw)
    part = kw.get("samples", slice(None))
    ax.plot(log.displacement[part] * 1e3, pred[base.model.spec][k]["force"][part],
            label=base.model.spec, **styles[base.model.spec])
    ax.legend(fontsize="small")
axes[0].set_title(f"{log.name}: the whole log")
axes[1].set_title("one pre-sliding curve after a reversal")


def seal_level(r, i, which):
    # sliding friction level of log i: measured (force minus the chamber) or modelled (seal)
    p = pred[r.model.spec][i]
    chamber = p["contributions"][:, r.model.force_names.index("chamber")]
    force = logs[i].force - chamber if which == "measured" else p["force"] - chamber
    return plotting.sliding_friction_level(force, fitstiff.segment(logs[i]))


pressure = [s["pressure_level_bar"] for s in summaries]
measured = [seal_level(withp, i, "measured") for i in range(len(logs))]
plotting.plot_friction_levels(axes[2], pressure, measured,
                              [seal_level(withp, i, "model") for i in range(len(logs))],
                              names=[log.name for log in logs])
axes[2].plot(pressure, [seal_level(base, i, "model") for i in range(len(logs))], marker="+",
             label=f"model {base.model.spec}", **styles[base.model.spec])
axes[2].legend(fontsize="small")
axes[2].set_title("sliding friction against pressure")
fig.savefig("02_oring_loops.png", dpi=80)
print("measured sliding level [N]:", ", ".join(f"{v:.3g}" for v in measured))
"""),
    ("markdown", r"""
`chamber+dahl` has one friction level for all pressures, so it runs between them;
`pressure_friction` follows the measured levels. What neither does is the shape right after
a reversal: the O-ring's transition is not the Dahl curve.

## The diagnosis

`fitstiff diagnose` asks the logs, on held-out data, where the baseline misses, which effect
of the library explains it and how far the gap shrinks (notebook 04 explains how). It refits
the model once per held-out log and candidate, so on four logs of this size it takes minutes
against the whole library, too slow for a notebook run in the test suite; a short candidate
list (`fitstiff.diagnose(logs, candidates="pressure_friction,asymmetry,viscous")`) still costs
several times the two fits above. So this notebook does not run it: it reads the **stored
result** of the full-library run,

    fitstiff diagnose data/real/oring/*.csv --format zillen_oring \
        --baseline chamber+dahl --out out/oring_diagnosis

kept in `benchmarks/results/diagnosis_oring.json` (its recorded timing is printed below),
through `Diagnosis.from_dict`, as notebook 04 does.
"""),
    ("code", r"""
stored = Path("..") / "benchmarks" / "results" / "diagnosis_oring.json"
diagnosis = fitstiff.Diagnosis.from_dict(json.loads(stored.read_text()))
print(diagnosis.summary())
print(f"\nrecorded run time {diagnosis.timing_s['total']:.0f} s; candidates screened: "
      f"{len(diagnosis.settings['candidates'])}")
beta = diagnosis.candidate("pressure_friction").parameters["beta"]["value"]
print(f"beta: diagnosis {beta:.4g} 1/bar, the fit above "
      f"{withp.parameters()['beta']['value']:.4g} 1/bar")
"""),
    ("markdown", r"""
Where the gap sits, before and after the accepted effect: the held-out RMS per region and
log, pooled over the diagnosis's cells (direction and speed band) from the stored file:
"""),
    ("code", r"""
def region_rms(cells):
    # held-out RMS (N) per region x log, pooled over a region's cells
    frame = pd.DataFrame(cells)
    frame["sq"] = frame["samples"] * frame["rms_N"] ** 2
    pooled = frame.groupby(["region", "file"])[["sq", "samples"]].sum()
    return np.sqrt(pooled["sq"] / pooled["samples"]).unstack("file")


before, after = region_rms(diagnosis.gap["regions"]), region_rms(diagnosis.gap["final_regions"])
limit = float(np.nanmax([before.to_numpy(), after.to_numpy()]))
fig, axes = plt.subplots(1, 2, figsize=(11, 3.2), layout="constrained")
for ax, table, title in ((axes[0], before, diagnosis.baseline),
                         (axes[1], after, diagnosis.final_model)):
    plotting.plot_gap_heatmap(ax, table, label="held-out RMS [N]", limit=limit)
    ax.set_title(title)
fig.savefig("02_oring_gap.png", dpi=80)
print(f"noise floor {diagnosis.gap['noise_N']:.3g} N; cells worse after than before:",
      [f"{region} {log}" for (region, log), worse in (after > before).stack().items()
       if worse] or "none")
print("what the logs cannot test, and what to record for it:")
for effect, d in diagnosis.detectability.items():
    if not d["testable"]:
        print(f"  {effect}: {d['record']}")
"""),
    ("markdown", r"""
Read together with the fits above: the diagnosis accepts `pressure_friction` (the sliding
cells improve most), refits every other significant candidate and accepts none of them, and
reports what stays above the noise floor as **unexplained**, above all in the pre-sliding
cells (the list above names the cells that the accepted effect made worse on held-out data):
the O-ring's transition after a reversal has a shape that neither the Dahl curve nor an
effect of the library reproduces. It then describes what that rest follows
(`unexplained_structure`, the last lines of the summary): about 0.8 N of the 1.1 N follows
the velocity, as a transition after each reversal that scales with the leg's speed (an
elastomer's rate-dependent presliding stiffness would do that), and it says the time and the
force predict it alike on these logs: the next logs should vary them apart. The diagnosis's `beta` agrees with the fit of
`chamber+dahl+pressure_friction` above. For these logs that means: quote the sliding level
and its pressure dependence; treat the pre-sliding slope as a rough figure (its model does not
fit), and record what the detectability list asks for if standstill effects matter.

## On your own logs

    fitstiff inspect LOGS... --format my_rig.json            # or --columns ... --no-header
    fitstiff fit LOGS... --format my_rig.json --model chamber+dahl --out out/fit
    fitstiff fit LOGS... --format my_rig.json \
        --compare chamber+dahl,chamber+dahl+pressure_friction --out out/compare
    fitstiff diagnose LOGS... --format my_rig.json --baseline chamber+dahl --out out/diag
    fitstiff report out/diag
"""),
]


def render() -> str:
    """The notebook file's text."""
    return cells.render(CELLS)


if __name__ == "__main__":
    NOTEBOOK.write_text(render(), encoding="utf-8")
    print(f"wrote {NOTEBOOK}")
