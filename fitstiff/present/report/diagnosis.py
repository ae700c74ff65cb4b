"""The page of a diagnosis run: the gap heat map before and after, the residual signatures per
region, each log's loop with the accepted effects, the candidate table and the verdict."""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.figure import Figure

from fitstiff.errors import InputError
from fitstiff.present import plotting
from fitstiff.present.reopen import RunDirectory
from fitstiff.present.report.figures import ReportFigure, Section, file_stem
from fitstiff.present.report.kinds import Report
from fitstiff.present.report.text import Verdict, fmt, paragraph, per_log_noise, html_table
from fitstiff.units import MM

__all__ = ["diagnosis_report"]



def diagnosis_report(run: RunDirectory, *, draws: int) -> Report:
    """The diagnosis page: verdict, gap heat maps, candidate and detectability tables,
    residual signatures and loops before / after the accepted effects."""
    del draws
    from fitstiff.diagnosis import HELDOUT, Diagnosis
    from fitstiff.diagnosis.gap import region_summary
    from fitstiff.segments.segmentation import segment
    from fitstiff.signal.noise import NoiseFloor

    result = Diagnosis.from_dict(run.result)
    logs = run.logs
    try:
        with np.load(run.path / HELDOUT) as arrays:
            heldout = Diagnosis.heldout_from_arrays(dict(arrays), len(logs))
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(str(run.path / HELDOUT), "held-out residuals of the diagnosis",
                         f"cannot be read ({exc})", "run fitstiff diagnose again") from None
    for which, residuals in heldout.items():
        for log, r in zip(logs, residuals):
            if r.shape != (len(log),):
                raise InputError(str(run.path / HELDOUT), f"{which} residuals of {log.name}",
                                 f"have {r.shape[0]} samples, the log {len(log)}",
                                 "run fitstiff diagnose again")
    segs = [segment(log) for log in logs]
    noise = [NoiseFloor(float(result.noise_N[log.name]["sigma_N"]),
                        float(result.noise_N[log.name]["rho"])) for log in logs]
    masks = _diagnosis_masks(run)
    before, after = heldout["before"], heldout["after"]
    changed = bool(result.accepted)

    fig = Figure(figsize=(12, 3.6 + 0.3 * len(logs)), layout="constrained")
    axes = fig.subplots(1, 2 if changed else 1, squeeze=False)[0]
    # the RMS above the noise in N, on one colour scale before and after: the z-score
    # saturates on real logs (every cell of the O-ring set above any cap, up to 1.8e5), so
    # before and after looked the same
    tables = [region_summary(r, segs, noise, masks, value="excess_N")
              for r in ((before, after) if changed else (before,))]
    top = max((float(np.nanmax(t.to_numpy())) for t in tables
               if np.isfinite(t.to_numpy()).any()), default=0.0)
    label = "held-out RMS above the noise floor [N]"
    for ax, table, title in zip(axes, tables, (f"baseline {result.baseline}",
                                               f"with {', '.join(result.accepted)}")):
        plotting.plot_gap_heatmap(ax, table, label=label, limit=max(top, 1e-9))
        ax.set_title(title)
    heat = ReportFigure("gap_heatmap", "Held-out misfit per region and log: RMS above the "
                        "log's noise floor in N, sqrt(max(rms^2 - sigma^2, 0)) (0: at the "
                        "noise; blank: no such samples)"
                        + (", before and after the accepted effects on one colour scale."
                           if changed else "."), fig)
    signature = _signature_figure(logs, segs, before, after if changed else None, masks)
    loops = tuple(_diagnosis_loop(log, b, a if changed else None, result, i)
                  for i, (log, b, a) in enumerate(zip(logs, before, after)))
    gap = result.gap
    summary = (_diagnosis_tables(result)
               + paragraph(f"Held-out RMS of the baseline {gap['heldout_rms_N']:.3g} N, of "
                    f"{result.final_model} {gap['final_heldout_rms_N']:.3g} N; noise floor "
                    f"{gap['noise_N']:.3g} N pooled over the logs, from the high-frequency "
                    "part of the force and of the baseline's residual ("
                    + per_log_noise({k: float(v["sigma_N"])
                                      for k, v in result.noise_N.items()},
                                     what="noise floor") + "). Folds: "
                    + "; ".join(result.folds) + "."))
    sections = [
        Section("Where the baseline misses", figures=(heat,)),
        Section("Residual signatures", figures=(signature,)),
        Section("Loops", figures=loops),
    ]
    if result.unexplained_structure:
        sections.insert(1, _structure_section(result, logs, segs, after, masks))
    planned = _plan_section(run.path)
    if planned is not None:
        sections.insert(1, planned)
    return Report(f"Diagnosis: {result.baseline}", _diagnosis_verdict(result), summary,
                   tuple(sections), summary_title="Candidate effects")


def _diagnosis_masks(run: RunDirectory) -> list[np.ndarray]:
    options = run.manifest.get("options", {})
    out = []
    for log in run.logs:
        keep = np.ones(len(log), dtype=bool)
        if options.get("sample_range") is not None:
            start, stop = options["sample_range"]
            keep[:] = False
            keep[slice(start, stop)] = True
        keep[:int(options.get("skip") or 0)] = False
        out.append(keep)
    return out


def _signature_figure(logs, segs, before, after, masks) -> ReportFigure:
    since, velocity, pressure, position, time = [], [], [], [], []
    for log, seg in zip(logs, segs):
        x = np.asarray(log.displacement)
        origin = np.concatenate([[0], seg.reversals])
        last = origin[np.searchsorted(origin, np.arange(len(log)), side="right") - 1]
        since.append(np.abs(x - x[last]) / MM)
        velocity.append((seg.velocity if seg.velocity is not None
                         else np.full(len(log), np.nan)) / MM)
        level = seg.pressure_level
        pressure.append(np.full(len(log), np.nan if level is None else level / 1e5))
        start = log.rig.start_position
        position.append((x + (start if start is not None else 0.0)) / MM)
        time.append(np.asarray(log.time) if log.time is not None
                    else np.full(len(log), np.nan))
    keep = np.concatenate(masks)
    b = np.concatenate(before)[keep]
    a = None if after is None else np.concatenate(after)[keep]
    panels = [(since, "displacement since the last reversal (mm)"),
              (velocity, "velocity (mm/s)"), (pressure, "pressure level (bar gauge)"),
              (position, "position (mm)"), (time, "time (s)")]
    fig = Figure(figsize=(12, 7.0), layout="constrained")
    axes = fig.subplots(2, 3).ravel()
    for ax, (values, label) in zip(axes, panels):
        v = np.concatenate(values)[keep]
        if not np.any(np.isfinite(v)):
            ax.set_axis_off()
            ax.text(0.5, 0.5, f"no {label.split(' (')[0]} in these logs", ha="center",
                    transform=ax.transAxes)
            continue
        plotting.plot_residual_signature(ax, v, b, a, xlabel=label)
    axes[-1].set_axis_off()
    caption = ("Held-out residuals (model - measured) of every log against the variables that "
               "reveal effects: displacement since the last reversal (pre-sliding shape, "
               "memory), velocity (viscous, Stribeck), pressure level (pressure-dependent "
               "friction), position (stroke ends, chamber), time (drift, leakage). Red: "
               "baseline" + ("; blue: with the accepted effects" if after is not None else "")
               + "; lines: binned mean, bands: +-1 sd.")
    return ReportFigure("residual_signatures", caption, fig)


def _structure_section(result, logs, segs, after, masks) -> Section:
    """What the unexplained gap follows: the descriptions' table and, per accepted one, the
    held-out residual against its variable before and after it, with its fitted shape."""
    from fitstiff.diagnosis.structure import accepted_descriptions

    rows = [[u.variable.replace("_", " "), u.form, fmt(u.size_N, 3),
             fmt(u.heldout_rms_before_N, 4), fmt(u.heldout_rms_after_N, 4), fmt(u.shrink, 2),
             "yes" if u.accepted else "no",
             (u.description + ". " + u.suggestion) if u.accepted else u.why]
            for u in result.unexplained_structure]
    html = (html_table(["follows", "form", "size N", "held-out before N", "held-out after N",
                        "shrink", "accepted", "what it is / why not"], rows, numeric_from=2,
                       prose=(7,))
            + paragraph("After the library, the final model's held-out residual is described "
                        "by one variable at a time (a small regularised curve, fitted on "
                        "other blocks of the logs than the ones it predicts), and a "
                        "description is accepted by the library's kind of rule: significant "
                        "over the held-out blocks, and it removes a share of the gap above "
                        "the noise floor."))
    # redrawn from heldout.npz; only what diagnosis.json accepted (the same unless the
    # samples counted differ from the run's, which the table then still reports)
    stored = {(u.variable, u.form) for u in result.unexplained_structure if u.accepted}
    found = [d for d in accepted_descriptions(logs, segs, after, masks,
                                              float(result.gap["noise_N"]))
             if (d.structure.variable, d.structure.form) in stored]
    figures = ()
    if found:
        fig = Figure(figsize=(5.0 * len(found), 3.8), layout="constrained")
        axes = fig.subplots(1, len(found), squeeze=False)[0]
        keep = np.concatenate(masks)
        for ax, d in zip(axes, found):
            u = d.structure
            even = not u.form.startswith("sign-dependent")
            plotting.plot_structure(ax, d.values[keep], d.residual[keep], d.prediction[keep],
                                    sign=None if even else d.sign[keep], shape=u.shape,
                                    xlabel=u.axis or u.variable)
            ax.set_title(textwrap.fill(f"{u.variable.replace('_', ' ')}: {u.form}, "
                                       f"{u.size_N:.2g} N", 60), fontsize=9)
        figures = (ReportFigure(
            "unexplained_structure", "What the unexplained held-out residual follows: red, "
            "the residual left by the final model; blue, after taking off the description's "
            "held-out prediction; black, the description fitted to all samples (a "
            "sign-dependent one drawn times the direction).", fig),)
    return Section("What the unexplained gap follows", html=html, figures=figures)


def _plan_section(path) -> Section | None:
    """The next experiment (``plan/`` of the diagnosis directory, written by fitstiff diagnose
    or fitstiff plan): its table and each program with the rivals' predicted forces."""
    from fitstiff.planning import PLAN, PLAN_DIR
    from fitstiff.planning.plan import PREDICTED, Plan, read_predicted
    from fitstiff.present.reopen import read_json

    folder = path / PLAN_DIR
    if not (folder / PLAN).is_file():
        return None
    try:
        plan = Plan.from_dict(read_json(folder / PLAN))
        with np.load(folder / PREDICTED) as stored:
            arrays = dict(stored)
        drawn = [read_predicted(arrays, k) for k in range(1, len(plan.programs) + 1)]
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputError(str(folder), "the plan of the diagnosis", f"cannot be read ({exc})",
                         "run fitstiff plan again") from None
    rows = []
    for p in plan.programs:
        e, n = p.expected, p.naive
        if "z" in e:
            expect, naive = f"z {e['z']:.3g}", f"z {n.get('z', 0.0):.3g}"
        else:
            expect = (f"{e['parameter']} from {fmt(e['detectable_size'], 3)} {e['unit']}"
                      if e.get("detectable_size") is not None else "-")
            naive = (f"from {fmt(n['detectable_size'], 3)} {n['unit']}"
                     if n.get("detectable_size") is not None else "not detectable")
        rows.append([f"{PLAN_DIR}/{p.file}", " vs ".join(p.separates), p.kind,
                     p.program.get("family", ""), fmt(p.supply_bar, 3),
                     fmt(p.start_position_mm, 4), fmt(p.duration_s, 3), expect, naive, p.why])
    html = (html_table(["program", "separates", "kind", "family", "supply bar", "start mm",
                        "duration s", "expected", "log replayed", "why"], rows,
                       numeric_from=4, prose=(9,))
            + paragraph("What the logs could not settle, and the program of the next rig run "
                        "that settles it: the displacement (relative to the start position) in "
                        "the CSV, run at the supply pressure and start position given. "
                        "'expected' is the z of the test between the two rivals on the new "
                        "record after both refit (with what the logs already say about their "
                        "parameters), or the smallest size of an effect it detects at "
                        f"{plan.to_dict()['method']['power']:.0%} power; 'log replayed' the "
                        "same for the longest log run again for as long."))
    for u in plan.unplanned:
        html += paragraph(f"Not planned: {' vs '.join(u['separates'])}: {u['why']}")
    figures = ()
    if drawn:
        fig = Figure(figsize=(12, 3.2 * len(drawn)), layout="constrained")
        axes = fig.subplots(len(drawn), 2, squeeze=False)
        for (motion, forces), (t, x, predicted), p in zip(axes, drawn, plan.programs):
            plotting.plot_program(motion, t, x, forces_N=predicted, force_ax=forces,
                                  noise_N=plan.noise.sigma_N)
            motion.set_title(f"{p.file}: {p.program.get('family', '')} at "
                             f"{p.supply_bar:.3g} bar", fontsize=9)
            forces.set_title(" vs ".join(p.separates).replace("_", " "), fontsize=9)
        figures = (ReportFigure(
            "next_experiment", "The planned programs: displacement against time (left) and "
            "the difference of the rival models' predicted forces on it (right; for one "
            "effect against its absence, the effect at the size the program detects), against "
            "the logs' noise floor (grey).", fig),)
    return Section("Next experiment", html=html, figures=figures)


def _diagnosis_loop(log, before, after, result, i) -> ReportFigure:
    fig = Figure(figsize=(12, 4.2), layout="constrained")
    axes = fig.subplots(1, 2 if after is not None else 1, squeeze=False)[0]
    force = np.asarray(log.force)
    plotting.plot_loop(axes[0], log, force + before, label=f"{result.baseline} (held out)")
    axes[0].set_title(f"{log.name}: baseline")
    if after is not None:
        plotting.plot_loop(axes[1], log, force + after,
                           label=f"{result.final_model} (held out)")
        axes[1].set_title(f"{log.name}: with {', '.join(result.accepted)}")
    caption = (f"{log.name}: measured force and the held-out prediction (fitted without this "
               "log or this block of loops) of the baseline"
               + (" and of the model with the accepted effects." if after is not None else "."))
    return ReportFigure(f"diagnosis_loop_{file_stem(log.name)}", caption, fig)


def _diagnosis_tables(result) -> str:
    rows = []
    for c in result.candidates:
        det = result.detectability.get(c.effect, {})
        detect = (f"{det['size']:.3g} {det['unit']} ({det['parameter']})" if det.get("testable")
                  else "not testable")
        rows.append([c.effect, fmt(c.score, 4), c.p_text,
                     fmt(c.heldout_rms_before_N, 4), fmt(c.heldout_rms_after_N, 4),
                     fmt(c.shrink, 2), "yes" if c.accepted else "no",
                     ", ".join(c.regions_improved) or "-", detect,
                     (c.fitted_text + (f" ({c.reading})" if c.reading else ""))
                     if c.accepted else c.why])
    table = html_table(["candidate", "score", "p", "held-out before N", "held-out after N",
                    "shrink", "accepted", "regions improved", "detectable at 80 %",
                    "fitted (95 % interval) / why not"],
                   rows, numeric_from=1, prose=(7, 9))
    untestable = [f"{e}: {d['reason']}; record {d['record']}"
                  for e, d in result.detectability.items() if not d.get("testable")]
    skipped = [f"{e}: {why}" for e, why in result.skipped.items()]
    return (table
            + paragraph("Score: the Lagrange-multiplier statistic of the effect at its null value "
                 "(for one-sided effects z squared with the sign of z: negative where the data "
                 "push the parameter below its null, i.e. away from the effect); p after the "
                 "grid correction; "
                 "the screen's level is alpha / number of candidates = "
                 f"{result.settings.get('screen_level', float('nan')):.2g}. An effect is "
                 "accepted when its held-out RMS falls and it removes at least "
                 f"{result.settings.get('min_shrink', float('nan')):.0%} of the gap above "
                 "the noise.")
            + ("".join(paragraph("Not testable with these logs - " + u) for u in untestable))
            + ("".join(paragraph("Not screened - " + u) for u in skipped)))


def _diagnosis_verdict(result) -> Verdict:
    if not result.gap.get("baseline_converged", True):
        return Verdict("bad", "The baseline did not converge on every fold: do not trust "
                        "this diagnosis.", tuple(result.verdict))
    if result.accepted and not result.unexplained:
        status = "ok"
    elif result.accepted or not result.unexplained:
        status = "caution" if result.unexplained else "ok"
    else:
        status = "bad"
    headline = (f"Accepted: {', '.join(result.accepted)}." if result.accepted
                else "No candidate effect is accepted.")
    if not result.accepted and not result.unexplained:
        headline += " The baseline is adequate: its held-out misfit is at the noise floor."
    elif result.unexplained:
        follows = [u.variable.replace("_", " ") for u in result.unexplained_structure
                   if u.accepted]
        headline += (" Part of the gap stays unexplained (see the heat map)" if not follows
                     else " Part of the gap stays unexplained; it follows "
                     + " and ".join(follows) + " (see what the unexplained gap follows)") + "."
    programs = (result.next_experiment or {}).get("programs", [])
    if programs:
        questions = list(dict.fromkeys(" against ".join(p["separates"]) for p in programs))
        headline += (f" Next experiment: {len(programs)} programs settle "
                     + "; ".join(questions) + " (see the next experiment).")
    return Verdict(status, headline, tuple(result.verdict))
