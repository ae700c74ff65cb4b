"""What the unexplained gap follows (issue 32): descriptions of a held-out residual.

The residuals here are built by hand on the logs of a benchmark dataset (their positions,
times, pressures and reversals are real), so each test knows what the residual follows."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from fitstiff._testing.withheld import make_dataset
from fitstiff.diagnosis.result import Diagnosis
from fitstiff.diagnosis.structure import VARIABLES, Structure, describe_structure
from fitstiff.segments.segmentation import segment

SIGMA = 0.15


@pytest.fixture(scope="module")
def logs():
    logs, _ = make_dataset("null/0", short=True)
    return logs, [segment(log) for log in logs]


def _noise(logs, seed, rho=0.3):
    rng = np.random.default_rng(seed)
    out = []
    for log in logs:
        e = np.empty(len(log))
        e[0] = rng.standard_normal()
        for i in range(1, e.size):
            e[i] = rho * e[i - 1] + math.sqrt(1 - rho**2) * rng.standard_normal()
        out.append(SIGMA * e)
    return out


def _describe(logs, segs, residuals):
    masks = [np.ones(len(log), bool) for log in logs]
    return describe_structure(logs, segs, residuals, masks, SIGMA)


def _first(found):
    accepted = [s for s in found if s.accepted]
    return accepted[0] if accepted else None


@pytest.mark.parametrize("seed", range(6))
def test_noise_alone_is_never_described(logs, seed):
    logs_, segs = logs
    found = _describe(logs_, segs, _noise(logs_, seed))
    assert _first(found) is None, [s.description for s in found if s.accepted]


def test_the_needed_t_counts_correlated_descriptions_once():
    """The family-wise threshold (max-T over sign flips of the blocks): copies of one
    description need the t of one test; unrelated ones about Bonferroni's; and over
    symmetric null gains the largest t of ten correlated descriptions passes it in about
    alpha of the draws."""
    from scipy import stats

    from fitstiff.diagnosis.structure import max_t_threshold

    rng = np.random.default_rng(3)
    n = 48
    one = rng.standard_normal(n)
    single = stats.t.ppf(0.95, n - 1)
    assert max_t_threshold(np.tile(one, (10, 1)), 0.05) == pytest.approx(single, abs=0.15)
    bonferroni = stats.t.ppf(1 - 0.05 / 10, n - 1)
    apart = max_t_threshold(rng.standard_normal((10, n)), 0.05)
    assert single + 0.5 < apart < bonferroni + 0.15
    passed = 0
    for _ in range(300):
        common = rng.standard_normal(n)
        gains = 0.8 * common + 0.6 * rng.standard_normal((10, n))
        t = gains.mean(axis=1) / (gains.std(axis=1, ddof=1) / math.sqrt(n))
        passed += bool(t.max() > max_t_threshold(gains, 0.05))
    assert passed / 300 < 0.09


def test_a_ripple_along_the_stroke_is_described_by_position_with_its_period(logs):
    logs_, segs = logs
    period = 0.7e-3       # two periods and more within each log's 2 mm
    r = [e + 0.25 * np.sin(2 * np.pi * log.position() / period)
         for log, e in zip(logs_, _noise(logs_, 1))]
    found = _describe(logs_, segs, r)
    first = _first(found)
    assert first is not None and first.variable == "position", found
    assert first.form.startswith("periodic") and first.period == pytest.approx(0.7, rel=0.05)
    assert first.size_N == pytest.approx(0.25 / math.sqrt(2), rel=0.2)
    assert first.shrink > 0.7
    assert "ripple" in first.suggestion and "start position" in first.suggestion
    assert first.heldout_rms_after_N < first.heldout_rms_before_N


def test_logs_on_one_stretch_of_the_stroke_share_a_periods_phase():
    """Logs whose ranges of the position overlap (directly or through another) are one
    stretch; logs apart, or positions relative to each log's start, keep a phase each."""
    from fitstiff.diagnosis._structure_forms import stretches

    log_id = np.repeat([0, 1, 2, 3], 3)
    v = np.array([0, 5, 10, 30, 35, 40, 8, 12, 20, 19, 25, 29.5], float)
    assert stretches(v, log_id, True).tolist() == [0] * 3 + [1] * 3 + [0] * 3 + [0] * 3
    v[9:] = (21, 25, 29.5)      # log 3 now starts past log 2's end: apart from the rest
    assert stretches(v, log_id, True).tolist() == [0] * 3 + [2] * 3 + [0] * 3 + [1] * 3
    assert stretches(v, log_id, False).tolist() == log_id.tolist()


def _at(logs_, starts):
    return [dataclasses.replace(log, rig=dataclasses.replace(log.rig, start_position=x))
            for log, x in zip(logs_, starts)]


def test_a_period_with_a_phase_of_its_own_in_each_log_is_not_a_ripple_of_the_bore(logs):
    """A ripple of the bore is where it is: logs that travel one stretch see it in one
    phase. A periodic shape with a phase of its own in each of them (a program's own
    cycles, a per-log shape) is not described as one; the same ripple in phase is. Logs
    apart keep a phase each, and the period is then reported as confounded with the log
    and the supply pressure (one each), as a curve over ranges apart is."""
    logs_, segs = logs
    period = 0.7e-3
    together = _at(logs_, (0.35, 0.35, 0.35))
    ripple = [e + 0.25 * np.sin(2 * np.pi * log.position() / period)
              for log, e in zip(together, _noise(logs_, 1))]
    first = _first(_describe(together, segs, ripple))
    assert first is not None and first.variable == "position", first
    assert first.form.startswith("periodic") and first.confounded_with == ()
    own = [e + 0.25 * np.sin(2 * np.pi * log.position() / period + phase)
           for log, e, phase in zip(together, _noise(logs_, 1), (0.0, 2.1, 4.2))]
    found = _describe(together, segs, own)
    assert not any(s.accepted and s.form.startswith("periodic") for s in found), found
    apart = _at(logs_, (0.15, 0.35, 0.55))
    first = _first(_describe(apart, segs, [e + 0.25 * np.sin(2 * np.pi * log.position()
                                                             / period + phase)
                                           for log, e, phase in zip(apart, _noise(logs_, 1),
                                                                    (0.0, 2.1, 4.2))]))
    assert first is not None and first.form.startswith("periodic"), first
    assert {"log", "pressure"} <= set(first.confounded_with)


def test_friction_that_grows_during_each_log_is_described_by_time(logs):
    logs_, segs = logs
    r = [e + 0.4 * (log.time - log.time[0]) / log.duration * seg.direction
         for log, seg, e in zip(logs_, segs, _noise(logs_, 2))]
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "time", first
    assert first.form.startswith("sign-dependent")
    assert "warm-up" in first.suggestion


def test_a_friction_level_per_log_cannot_be_told_from_the_pressure_of_one_log_each(logs):
    # three logs at three pressures: one level per log is also a curve of the pressure
    logs_, segs = logs
    levels = (0.5, -0.1, 0.3)
    r = [e + a * seg.direction for a, seg, e in zip(levels, segs, _noise(logs_, 3))]
    first = _first(_describe(logs_, segs, r))
    assert first is not None and {first.variable, *first.confounded_with} >= {"pressure", "log"}
    assert "cannot tell" in first.suggestion


def test_a_friction_level_linear_in_the_supply_is_described_by_the_pressure(logs):
    """Left out log by log, a friction level linear in the supply pressure leaves each log
    its level less the mean of the others': a line in the pressure whose zero is not the
    samples' mean pressure (the logs differ in length), so the line needs its own level.
    One line (two parameters) is then fewer than a level per log, and the log a rival."""
    logs_, segs = logs
    p = np.array([seg.pressure_level / 1e5 for seg in segs])
    assert np.unique(np.round(p, 3)).size == 3
    level = 0.3 * p
    left_out = [level[k] - np.delete(level, k).mean() for k in range(p.size)]
    r = [e + a * seg.direction for a, seg, e in zip(left_out, segs, _noise(logs_, 4))]
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "pressure", first
    assert first.form == "sign-dependent linear" and "log" in first.confounded_with


def _travel_and_sign(log, seg):
    """Per sample the travel since the last reversal (mm) and the friction's sign (the
    last motion's direction, held through a stop)."""
    from fitstiff.diagnosis._structure_forms import held_direction, structure_variables

    v = structure_variables(log, seg, np.asarray(log.force))
    return v["since_reversal"], held_direction(np.asarray(seg.direction, float))


def test_a_presliding_stiffness_that_grows_with_the_rate_is_described_by_the_velocity(logs):
    """A stiffer seal at a higher rate leaves, after each reversal, a bump in the travel
    since it (where the presliding curve's slope matters) whose size follows the log of the
    leg's speed: a transition scaled by the velocity, not a level per log or a position.
    The logs' supply pressures are set so they do not rise with the speed (where they do,
    the pressure is a rival the logs cannot tell from it)."""
    logs_, segs = logs
    segs = [dataclasses.replace(seg, pressure_level=p) for seg, p in zip(segs, (4.5e5, 6e5,
                                                                               3e5))]
    r = []
    for log, seg, e in zip(logs_, segs, _noise(logs_, 11)):
        s, sign = _travel_and_sign(log, seg)
        speed = np.percentile(np.abs(seg.velocity), 90) * 1e3
        r.append(e + 0.5 * np.log(speed / 5.0) * sign * (s / 0.3) * np.exp(1 - s / 0.3))
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "velocity", first
    assert first.form.startswith("sign-dependent transition")
    assert first.shrink > 0.5
    assert "rate" in first.suggestion


def test_a_friction_level_that_follows_the_supply_through_the_transition(logs):
    """A friction level that follows the supply pressure shows as the seal slides: after
    each reversal it grows from nothing to the level's change over the presliding travel.
    Three logs at three pressures: the transition scaled by the pressure, and the log
    (one pressure each) cannot be told from it."""
    logs_, segs = logs
    levels = [0.6 * (seg.pressure_level / 1e5 - 4.5) for seg in segs]
    r = []
    for log, seg, a, e in zip(logs_, segs, levels, _noise(logs_, 12)):
        s, sign = _travel_and_sign(log, seg)
        r.append(e + a * sign * -np.expm1(-s / 0.2))
    first = _first(_describe(logs_, segs, r))
    assert first is not None and {first.variable, *first.confounded_with} >= {"pressure",
                                                                            "log"}, first


def test_a_tight_spot_in_the_bore_is_described_by_the_position(logs):
    """Friction that rises over a millimetre of the bore, on one log's travel: the
    seal feels it once it slides, so after each reversal it grows in over the transition; a
    friction level along the stroke, not a level of that log alone."""
    logs_, segs = logs
    r = []
    for k, (log, seg, e) in enumerate(zip(logs_, segs, _noise(logs_, 13))):
        s, sign = _travel_and_sign(log, seg)
        x = 1e3 * np.asarray(log.displacement)
        bump = np.exp(-0.5 * (x / 0.4) ** 2) if k == 1 else 0.0 * x
        r.append(e + 1.2 * sign * -np.expm1(-s / 0.1) * bump)
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "position", first
    assert first.form.startswith("sign-dependent friction level")
    assert "tight spot" in first.suggestion


def test_the_friction_keeps_its_sign_through_a_stop():
    from fitstiff.diagnosis._structure_forms import held_direction

    d = np.array([0, 0, 1, 1, 0, 0, -1, 0, 1], float)
    assert held_direction(d).tolist() == [0, 0, 1, 1, 1, 1, -1, -1, 1]
    assert held_direction(np.zeros(3)).tolist() == [0, 0, 0]


def test_a_described_residual_is_described_once(logs):
    # after the accepted description, what is left is noise: nothing more is accepted
    logs_, segs = logs
    r = [e + 0.3 * np.sin(2 * np.pi * log.position() / 2e-3)
         for log, e in zip(logs_, _noise(logs_, 4))]
    found = _describe(logs_, segs, r)
    assert sum(s.accepted for s in found) == 1
    rest = [s for s in found if not s.accepted]
    assert rest and all(s.why for s in rest) and all(s.round == 2 for s in rest)


def test_no_gap_above_the_noise_floor_describes_nothing(logs):
    logs_, segs = logs
    r = [0.5 * e for e in _noise(logs_, 5)]
    assert _describe(logs_, segs, r) == ()


def test_a_period_longer_than_half_a_logs_travel_is_a_smooth_curve(logs):
    # a 3 mm period over logs of 2 mm travel: not claimed as periodic; the logs lie apart
    # along the stroke, so a curve of the position is as well a shape per log, and of the
    # pressure (one supply pressure each)
    logs_, segs = logs
    r = [e + 0.3 * np.sin(2 * np.pi * log.position() / 3e-3)
         for log, e in zip(logs_, _noise(logs_, 7))]
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "position" and first.form == "smooth"
    assert first.confounded_with == ("log", "pressure")
    assert "cannot tell it from log, pressure" in first.suggestion
    assert "each log has its own pressure" in first.suggestion


def test_logs_at_one_pressure_leave_the_pressure_out_of_a_per_log_curve(logs):
    # the same curve with every log at one supply pressure: the logs still lie apart along
    # the stroke (log is a rival) but the pressure does not tell them apart
    logs_, segs = logs
    segs = [dataclasses.replace(seg, pressure_level=4e5) for seg in segs]
    r = [e + 0.3 * np.sin(2 * np.pi * log.position() / 3e-3)
         for log, e in zip(logs_, _noise(logs_, 7))]
    first = _first(_describe(logs_, segs, r))
    assert first is not None and first.variable == "position"
    assert first.confounded_with == ("log",)


def test_structure_round_trips_through_diagnosis_json(logs):
    logs_, segs = logs
    r = [e + 0.25 * np.sin(2 * np.pi * log.position() / 0.7e-3)
         for log, e in zip(logs_, _noise(logs_, 1))]
    found = _describe(logs_, segs, r)
    assert all(s.variable in VARIABLES for s in found)
    d = Diagnosis(baseline="chamber+dahl", final_model="chamber+dahl", gap={},
                  candidates=(), accepted=(), unexplained=(), unexplained_structure=found,
                  noise_N={}, detectability={}, skipped={}, folds=(), settings={},
                  verdict=(), files=())
    text = json.dumps(d.to_dict())
    back = Diagnosis.from_dict(json.loads(text))
    assert back.unexplained_structure == tuple(
        Structure.from_dict(json.loads(json.dumps(s.to_dict()))) for s in found)
    entry = json.loads(text)["unexplained_structure"][0]
    for key in ("variable", "form", "size_N", "heldout_rms_before_N", "heldout_rms_after_N",
                "shrink", "accepted", "description", "suggestion"):
        assert key in entry


@pytest.mark.slow
def test_a_ripple_is_described_through_the_diagnosis_and_the_report_draws_it(tmp_path, capsys):
    """End to end on an independent simulator's guide ripple (short logs, two rate
    candidates): no library effect is named, the ripple is described by the position, the
    kept held-out residuals give the same description without diagnosing again (the
    benchmark's path, ``benchmarks/structure.py``), and the report has the panel."""
    from fitstiff.cli import main
    from fitstiff.diagnosis.structure import describe_structure
    from fitstiff.inference.problem import Problem
    from fitstiff.physics.simulate import write_log
    logs_, _ = make_dataset("ool/ripple/2", short=True)
    paths = []
    for log in logs_:
        write_log(log, tmp_path / f"{log.name}.csv")
        paths.append(str(tmp_path / f"{log.name}.csv"))
    out = tmp_path / "out"
    for argv in (["diagnose", *paths, "--candidates", "viscous,stribeck", "--out", str(out)],
                 ["report", str(out)]):
        assert main(argv) == 0, capsys.readouterr().err
    data = json.loads((out / "diagnosis.json").read_text())
    assert data["accepted"] == []
    found = [u for u in data["unexplained_structure"] if u["accepted"]]
    assert found and found[0]["variable"] == "position", data["unexplained_structure"]
    assert any("follows position" in line for line in data["verdict"])
    page = next(out.glob("*.html")).read_text()
    assert "What the unexplained gap follows" in page and "unexplained_structure" in page

    from fitstiff.io.loading import load_logs

    problem = Problem(load_logs(paths), model="chamber+dahl")     # as the command read them
    masks = [w > 0 for w in problem.sample_weights]
    pooled = data["gap"]["noise_N"]
    with np.load(out / "heldout.npz") as z:
        after = [z[f"after_{k}"] for k in range(len(logs_))]
    again = describe_structure(problem.logs, problem.segmentations, after, masks, pooled)
    assert [(u.variable, u.form, u.accepted, round(u.heldout_rms_after_N, 9))
            for u in again] == [(u["variable"], u["form"], u["accepted"],
                                 round(u["heldout_rms_after_N"], 9))
                                for u in data["unexplained_structure"]]


def test_a_description_with_a_library_effects_shape_says_the_library_tried_it(logs):
    # a friction level that differs between the directions is asymmetry's shape
    logs_, segs = logs
    r = [e + 0.3 * seg.direction for seg, e in zip(segs, _noise(logs_, 6))]
    masks = [np.ones(len(log), bool) for log in logs_]
    found = describe_structure(logs_, segs, r, masks, SIGMA,
                               library={"asymmetry": "held-out RMS did not fall"})
    first = _first(found)
    assert first is not None and first.variable == "direction", found
    assert "asymmetry has a shape like it; the library tried it and did not accept it " \
           "(held-out RMS did not fall)" in first.suggestion


@pytest.mark.parametrize("case", ["quasi-static", "one log", "masked, no start position"])
def test_a_ripple_is_found_without_time_in_one_log_and_relative_to_the_start(logs, case):
    import dataclasses

    logs_, _ = logs
    masks = [np.ones(len(log), bool) for log in logs_]
    if case == "quasi-static":            # no time: no time, velocity or acceleration
        logs_ = [dataclasses.replace(log, time=None, pressure_a=None, pressure_b=None)
                 for log in logs_]
    elif case == "one log":               # blocks of one log
        logs_, masks = logs_[:1], masks[:1]
    else:                                 # a third of each log excluded, positions relative
        logs_ = [dataclasses.replace(log, rig=dataclasses.replace(log.rig, start_position=None))
                 for log in logs_]
        masks = [np.arange(len(log)) > len(log) // 3 for log in logs_]
    segs = [segment(log) for log in logs_]
    r = [e + 0.3 * np.sin(2 * np.pi * log.displacement / 0.7e-3)
         for log, e in zip(logs_, _noise(logs_, 8))]
    found = describe_structure(logs_, segs, r, masks, SIGMA)
    first = _first(found)
    assert first is not None and first.variable == "position" and first.period == \
        pytest.approx(0.7, rel=0.05), found
    tried = {s.variable for s in found}
    if case == "quasi-static":
        assert not tried & {"time", "velocity", "acceleration"}
    if case.startswith("masked"):
        assert "relative to the start" in first.description


def test_held_out_log_by_log_a_shape_the_logs_share_passes_and_a_logs_own_level_does_not(
        logs):
    """``hold_out="logs"`` (what a library effect is held against in the diagnosis' rounds,
    ``_rounds.Rival``): a ripple along the stroke that the logs travel alike is learnt from
    the other logs and predicts the left-out one; a friction level of each log's own
    predicts nothing of a log it never saw, though block folds within the logs describe
    it."""
    from fitstiff.diagnosis.structure import passing_descriptions

    logs_, segs = logs
    masks = [np.ones(len(log), bool) for log in logs_]
    together = _at(logs_, (0.35, 0.35, 0.35))
    ripple = [e + 0.25 * np.sin(2 * np.pi * log.position() / 0.7e-3)
              for log, e in zip(together, _noise(logs_, 1))]
    found = passing_descriptions(together, segs, ripple, masks, SIGMA, hold_out="logs")
    assert found and found[0].structure.variable == "position", found
    assert found[0].structure.form.startswith("periodic") and found[0].lookalike_of == ()
    assert all(p.structure.accepted for p in found)
    assert [p.structure.heldout_rms_after_N for p in found] == sorted(
        p.structure.heldout_rms_after_N for p in found)

    own = [e + a * seg.direction for a, seg, e in zip((0.5, -0.1, 0.3), segs,
                                                         _noise(logs_, 3))]
    by_blocks = passing_descriptions(logs_, segs, own, masks, SIGMA)
    assert "log" in {p.structure.variable for p in by_blocks}
    by_logs = passing_descriptions(logs_, segs, own, masks, SIGMA, hold_out="logs")
    assert "log" not in {p.structure.variable for p in by_logs}, by_logs
    with pytest.raises(ValueError, match="two logs or more"):
        passing_descriptions(logs_[:1], segs[:1], own[:1], masks[:1], SIGMA, hold_out="logs")
