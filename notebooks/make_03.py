"""Write ``03_posteriors_and_calibration.ipynb`` (without outputs) from the cells below.

The notebook is committed; this script is its source. After editing a cell, run
``python notebooks/make_03.py``; ``tests/test_notebooks.py`` checks that the two agree and
executes the notebook.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import cells  # noqa: E402  (notebooks/cells.py, beside this script)

NOTEBOOK = Path(__file__).with_name("03_posteriors_and_calibration.ipynb")

CELLS: list[tuple[str, str]] = [
    ("markdown", r"""
# Posteriors, calibration, and when not to trust an interval

A least-squares fit gives each number a standard error; `fitstiff posterior` samples the
posterior with emcee and gives intervals. This notebook

1. samples a posterior on a bundled synthetic log whose truth is known and reads its
   summary of the pre-sliding slope (N/mm) and the breakaway force (N);
2. shows how fitstiff judges that the chain has converged;
3. reads what the stored calibration benchmark found: how often the 90 % intervals cover the
   truth over 50 synthetic data sets;
4. fits a model that misses an effect in the data, shows the warning fitstiff gives, and why
   the interval is then too narrow.

The chains here are short (a small ensemble, checked often) so that the notebook runs
quickly; the command line's defaults (`fitstiff posterior`: 32 walkers, up to 20 000 steps)
are what to use for numbers you quote.
"""),
    ("code", r"""
import json
import tempfile
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import fitstiff
from fitstiff.inference.posterior.chain import ChainStore
from fitstiff.present import plotting

warnings.filterwarnings("ignore", message="IProgress not found")   # tqdm, no progress bar here
Z90 = 1.6449              # a central 90 % interval is +- 1.645 standard deviations
SYNTHETIC = Path("..") / "data" / "synthetic"
QUANTITIES = {"presliding_slope_N_per_mm": "pre-sliding slope [N/mm]",
              "breakaway_N": "breakaway [N]"}


def truth_of(csv):
    # the ground truth stored beside a synthetic log (<stem>.truth.json)
    return json.loads(csv.with_suffix(".truth.json").read_text())


log_path = SYNTHETIC / "fig4" / "p6bar_x350mm.csv"
truth = truth_of(log_path)
logs = fitstiff.load_logs([log_path])
print(f"{log_path.name}: {len(logs[0])} samples; true model {truth['model']}, "
      f"parameters {({k: v['value'] for k, v in truth['parameters'].items()})}; "
      f"force noise {truth['noise']['force_N']} N")
"""),
    ("markdown", r"""
## A posterior

`fitstiff.sample_posterior(logs, "chamber+dahl")` (command line: `fitstiff posterior LOG
--model chamber+dahl --out DIR`) fits least squares first, starts the walkers in a small ball
around the optimum and runs emcee (differential-evolution moves) with the default `ar1` noise
model (per log and channel, AR(1) errors whose lag-1 coefficient is estimated at the
optimum); the force offset is integrated out analytically. The chain runs in chunks and stops
as soon as the convergence rules hold (below). Here: 12 walkers, a check every 250 steps, at
most 3 000 steps; the chain is written to a temporary HDF5 file so that we can look at it, and
only one draw of the model force is kept (`draws`: the report's predictive band needs them,
this notebook does not).
"""),
    ("code", r"""
with tempfile.TemporaryDirectory() as tmp:
    post = fitstiff.sample_posterior(logs, "chamber+dahl", walkers=12, steps=3000,
                                     check_every=250, seed=1, progress=False, draws=1,
                                     backend=Path(tmp) / "chain.h5")
    chain = ChainStore(Path(tmp) / "chain.h5", read_only=True).read().chain
print(post.table())
"""),
    ("markdown", r"""
### The slope and the breakaway

The posterior's median and central 90 % interval (5 % and 95 % quantiles), the least-squares
value with its 90 % interval (value $\pm 1.645$ standard errors), and the truth of the
synthetic log:
"""),
    ("code", r"""
def intervals(post, truths):
    rows = []
    for key, label in QUANTITIES.items():
        s = post.summary(key)
        value, err = post.fit.derived[key]
        lo, hi = value - Z90 * err, value + Z90 * err
        rows.append({"quantity": label, "truth": truths[key],
                     "posterior q05": s["q05"], "q50": s["q50"], "q95": s["q95"],
                     "covers": s["q05"] <= truths[key] <= s["q95"],
                     "least squares": value, "stderr": err, "LS covers": lo <= truths[key] <= hi,
                     "(q50 - truth) / sd": (s["q50"] - truths[key]) / s["std"],
                     "(q50 - truth) / width": (s["q50"] - truths[key]) / (s["q95"] - s["q05"])})
    return pd.DataFrame(rows).set_index("quantity")


intervals(post, truth["derived"]).round(4)
"""),
    ("code", r"""
names = ["sigma0", "Fc", "n"]
units = {name: post.summary(name)["unit"] for name in names}
samples = np.column_stack([post.priors.to_display(post.flat(name), post.names.index(name))
                           for name in names])
fig = plt.figure(figsize=(7, 7))      # empty: the corner package lays out its own axes
plotting.plot_corner(fig, samples, [f"{n} [{units[n]}]" if units[n] != "-" else n
                                    for n in names],
                     truths=[truth["parameters"][n]["value"] for n in names])
fig.savefig("03_corner.png", dpi=80, bbox_inches="tight")
"""),
    ("markdown", r"""
## Has the chain converged?

An emcee chain is a correlated sequence: its number of independent samples is the chain
length over the **integrated autocorrelation time** $\tau$. fitstiff estimates $\tau$ for
every sampled coordinate after each chunk and stops when all of these hold
(`fitstiff/inference/convergence.py`):

- the chain is longer than `tau_multiple` (50) times the largest $\tau$;
- every $\tau$ changed since the previous check by less than 5 %, or by less than three
  standard deviations of the estimate's own noise;
- the mean acceptance fraction is at least 0.05 and no walker accepts less than a fifth of
  the median walker (a stuck walker).

Then the first 5 $\tau$ are discarded as burn-in and the rest thinned by $\tau/2$. A chain
that reaches `steps` first is kept but marked **not converged**, with the reason, and its
intervals must not be quoted (`fitstiff posterior --resume --steps N` continues it).
"""),
    ("code", r"""
d = post.diagnostics
tau = pd.Series(d.autocorr_time)
print(f"converged: {d.converged} ({d.reason})")
print(f"{d.steps} steps x {d.walkers} walkers; acceptance {d.acceptance_fraction:.2f} "
      f"(lowest walker {d.acceptance_fraction_min:.2f}); burn-in {d.discard} steps, "
      f"thin {d.thin}; "
      f"{post.samples.shape[0] * post.samples.shape[1]} samples kept; "
      f"integrated out: {', '.join(d.integrated)}")
pd.DataFrame({"tau [steps]": tau, "steps / tau": d.steps / tau,
              "effective samples": pd.Series(d.effective_samples)}).round(1)
"""),
    ("markdown", r"""
The trace of the sampler's coordinate for `sigma0` (the walkers move in unconstrained
coordinates; the rules above are applied to exactly these), with the burn-in marked, and the
running estimate of its $\tau$ against the chain length: the chain is long enough where the
estimate has levelled off below the line $N/50$. A short chain that stops at the first check
where the rules hold sits near that line; an estimate still rising at the end means the
chain is borderline, and a longer run (the command line's default ensemble and check
interval) is the safer figure to quote.
"""),
    ("code", r"""
coordinates = list(d.autocorr_time)
j = coordinates.index("sigma0")
fig, (ax_trace, ax_tau) = plt.subplots(1, 2, figsize=(12, 3.8), layout="constrained")
plotting.plot_trace(ax_trace, chain[:, :, j], "sigma0 (sampler coordinate)")
ax_trace.axvline(d.discard, color="tab:blue", ls=":", label=f"burn-in end (step {d.discard})")
ax_trace.legend(fontsize="small")
plotting.plot_autocorr(ax_tau, chain[:, :, j], "sigma0")
fig.savefig("03_trace.png", dpi=80)
"""),
    ("markdown", r"""
## Calibration: do the 90 % intervals cover the truth 90 % of the time?

A converged chain answers the question its model asks; whether its intervals are honest is a
different question, answered by the calibration benchmark (`benchmarks/calibration.py`,
datasets from `fitstiff/_testing/calibration.py`). Each of 50 datasets draws a truth
(slope 30-50 N/mm, breakaway 14-21 N, $n$ 1.0-1.4, force noise 0.1-0.3 N with lag-1
correlation 0-0.9, 1 µm displacement and 2 mbar pressure noise), simulates two
`chamber+dahl` logs of the paper's cylinder, fits, samples, and checks whether each 90 %
interval contains the truth. The current result was measured with (docs/benchmarks.md)

    python -m benchmarks.calibration --datasets 25 --first-seed 0 --steps 12000 --noise-models ar1
    python -m benchmarks.calibration --datasets 25 --first-seed 25 --steps 12000 --noise-models ar1

(two processes, stored together as `benchmarks/results/calibration_50_runs.json`). An older
run on the code of several sessions earlier, `calibration_50.json`, also sampled with white
`gaussian` noise, the likelihood that treats every sample as independent. Both are read here;
nothing is re-run:
"""),
    ("code", r"""
RESULTS = Path("..") / "benchmarks" / "results"
runs = {name: json.loads((RESULTS / f"{name}.json").read_text())
        for name in ("calibration_50_runs", "calibration_50")}


def coverage_row(rows, method, key):
    hits = np.array([r[method][key]["covered"] for r in rows])
    p = hits.mean()
    se = np.sqrt(p * (1 - p) / hits.size)
    return f"{hits.sum()}/{hits.size} = {100 * p:.0f} % +- {100 * se:.0f}"


table = []
for name, rows in runs.items():
    for method in ("least_squares", "ar1", "gaussian"):
        if method not in rows[0]:
            continue
        entry = {"run": name, "interval": "least squares +- 1.645 stderr"
                 if method == "least_squares" else f"posterior, {method} noise"}
        entry |= {label: coverage_row(rows, method, key) for key, label in QUANTITIES.items()}
        if method != "least_squares":
            entry["chains converged"] = sum(r[method]["converged"] for r in rows)
            entry["median steps"] = int(np.median([r[method]["steps"] for r in rows]))
        table.append(entry)
pd.DataFrame(table).set_index(["run", "interval"])
"""),
    ("markdown", r"""
Coverage is a count out of 50, so its binomial standard error is about 4 percentage points
near 90 %. Why white noise under-covers: with correlated force noise, thousands of samples
carry far less independent information than their number suggests, and a likelihood that
treats them as independent gives intervals that are too narrow, the more so the more
correlated the noise. The older run shows it per dataset: the error of the posterior median in
units of its own interval's half-width over 1.645 (inside $\pm 1.645$ = covered; values beyond
$\pm 8$ are drawn at $\pm 8$), against the noise correlation of the dataset:
"""),
    ("code", r"""
older = runs["calibration_50"]
LIMIT = 8.0
rho = np.array([r["truth"]["ar1"] for r in older])
fig, axes = plt.subplots(1, 2, figsize=(12, 4), layout="constrained", sharey=True)
for ax, (key, label) in zip(axes, QUANTITIES.items()):
    for method, marker in (("gaussian", "x"), ("ar1", "o")):
        q = [r[method][key] for r in older]
        z = [(e["q50"] - r["truth"][key]) / ((e["q95"] - e["q05"]) / (2 * Z90))
             for e, r in zip(q, older)]
        ax.plot(rho, np.clip(z, -LIMIT, LIMIT), marker, ls="", mfc="none",
                label=f"posterior, {method} noise")
    ax.axhspan(-Z90, Z90, color="0.9", label="covered (+- 1.645)")
    ax.set(xlabel="lag-1 correlation of the force noise", title=label,
           ylim=(-1.05 * LIMIT, 1.05 * LIMIT))
    ax.grid(True, alpha=0.3)
axes[0].set_ylabel("(median - truth) / (half-width / 1.645)")
axes[0].legend(fontsize="small")
fig.savefig("03_calibration.png", dpi=80)
for method in ("gaussian", "ar1"):
    for band, keep in (("rho < 0.3", rho < 0.3), ("rho >= 0.6", rho >= 0.6)):
        hits = [r[method]["presliding_slope_N_per_mm"]["covered"]
                for r, k in zip(older, keep) if k]
        print(f"{method:>8}, {band}: slope covered in {sum(hits)}/{len(hits)}")
"""),
    ("markdown", r"""
The calibration datasets are drawn from the very model that is fitted. The coverage above is
therefore the best case: it says the intervals are about right **when the model is right**.

## When not to trust an interval: a missing effect

`data/synthetic/effects/viscous/` holds three logs of the same cylinder at 1, 5 and 20 mm/s
with a viscous force $c\,v$ added to the seal ($c$ = 200 N s/m). We fit and sample
`chamber+dahl`, which has no viscous term, with a short chain as above (16 walkers: with
three logs there are more coordinates to sample):
"""),
    ("code", r"""
viscous_paths = sorted((SYNTHETIC / "effects" / "viscous").glob("*.csv"))
viscous_truth = truth_of(viscous_paths[0])
print(f"true model {viscous_truth['model']}: "
      f"{({k: v['value'] for k, v in viscous_truth['parameters'].items()})}")
vlogs = fitstiff.load_logs(viscous_paths)
wrong = fitstiff.sample_posterior(vlogs, "chamber+dahl", walkers=16, steps=3000,
                                  check_every=250, seed=1, progress=False, draws=1)
print(wrong.fit.table())
print()
print(wrong.table())
"""),
    ("code", r"""
intervals(wrong, viscous_truth["derived"]).round(4)
"""),
    ("markdown", r"""
Compare with the first table: the distance of the median from the truth, in posterior
standard deviations and in widths of the 90 % interval (the last two columns), and whether the
interval covers it (the posterior's table above says whether this chain converged). What
fitstiff said:
"""),
    ("code", r"""
print("least-squares fit warnings:")
for w in wrong.fit.warnings:
    print("  -", w)
print(f"residual lag-1 correlation {wrong.fit.residual_autocorrelation:.2f}; RMS per log "
      + ", ".join(f"{p['name']} {p['rms_N']:.3g} N" for p in wrong.fit.per_log)
      + f" against the simulated force noise of {viscous_truth['noise']['force_N']} N")
print("posterior warnings:", list(wrong.warnings) or "none")
disagree = any("posterior and least squares disagree" in w for w in wrong.warnings)
print("posterior-vs-least-squares disagreement warning raised:", disagree)
"""),
    ("markdown", r"""
The fit warns that its residuals are strongly autocorrelated and that the model may miss an
effect; compare each log's RMS with the simulated noise. The posterior adds a warning of
its own only when its median and the least-squares value disagree by more than four combined
standard deviations (the estimate then depends on how the residuals are weighted); whether it
did here is printed above. So read the fit's warnings before any interval.

Where the misfit is: the residual against the velocity steps with the direction of motion and
grows with the speed, the signature of a viscous force:
"""),
    ("code", r"""
predicted = wrong.fit.problem.per_log(wrong.fit.theta)
velocity = np.concatenate([fitstiff.segment(log).velocity for log in vlogs]) * 1e3
residual = np.concatenate([p["force"] - log.force for p, log in zip(predicted, vlogs)])
fast = [log.name for log in vlogs].index("triangle_20mm_s")
fig, (ax_loop, ax_sig) = plt.subplots(1, 2, figsize=(12, 4.2), layout="constrained")
plotting.plot_loop(ax_loop, vlogs[fast], predicted[fast]["force"], label="fit chamber+dahl")
ax_loop.set_title(f"{vlogs[fast].name}")
plotting.plot_residual_signature(ax_sig, velocity, residual, None, xlabel="velocity (mm/s)")
ax_sig.set_ylabel("residual (N)")
ax_sig.set_title("residual (model - measured) of the three logs")
fig.savefig("03_viscous_misfit.png", dpi=80)
"""),
    ("markdown", r"""
**Why the interval is too narrow.** A standard error or a posterior interval measures how much
the estimate would move with another draw of the **noise**, given the model. A missing effect
is not noise: it is a systematic force that the model's parameters absorb as best they can
(here the seal parameters take up part of the velocity-dependent force), and that bias does not
shrink with more data and does not show in the spread of the samples. The AR(1) treatment
widens the intervals for the correlated residuals it sees, but it still assumes the model is
right; compare the bias with the interval's width in the table above. The interval answers
"how well do these logs pin down the parameters of *this* model", not "how far is the number
from the cylinder's".

What to do: treat the fit's warnings (autocorrelated residuals, a slow systematic misfit) as
a stop sign for quoting intervals, run `fitstiff diagnose` to name the missing effect, and
refit with it. On these logs the stored run of the diagnosis benchmark
(`benchmarks/results/diagnosis_sets.json`) found it:
"""),
    ("code", r"""
stored = json.loads((RESULTS / "diagnosis_sets.json").read_text())["sets"]["viscous"]
print(f"accepted {stored['accepted']} (expected {stored['expected']}); held-out RMS "
      f"{stored['heldout_rms_before_N']:.3g} N -> {stored['heldout_rms_after_N']:.3g} N "
      f"against a noise floor of {stored['noise_N']:.3g} N")
for line in stored["verdict"]:
    print("  " + line)
"""),
]


def render() -> str:
    """The notebook file's text."""
    return cells.render(CELLS)


if __name__ == "__main__":
    NOTEBOOK.write_text(render(), encoding="utf-8")
    print(f"wrote {NOTEBOOK}")
