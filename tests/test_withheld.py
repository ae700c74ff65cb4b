"""The withheld-effect benchmark (benchmarks/withheld.py, issue 12): its independent rig
simulator (fitstiff/_testing/rig_sim.py) agrees with fitstiff's, effects enter with the right
sign and size, its datasets (fitstiff/_testing/withheld.py) are reproducible, the scores are
computed right, and a small run goes through the diagnosis."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fitstiff._testing import rig_sim as rs
from fitstiff._testing import withheld as datasets
from fitstiff._testing import withheld_scoring as wh
from fitstiff.diagnosis._choice import DECISIVE_BIC
from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

QUIET = Noise(force_N=0, displacement_um=0, pressure_mbar=0)


def _both(spec, params, effects, *, rate=500.0, amplitudes=(0.2, 1.0, 4.0), speed=5.0,
          x0=0.25, supply=5e5):
    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=x0, supply_pressure=supply,
              dead_length_a=0.02, dead_length_b=0.015)
    sim = simulate(spec, TriangleCycles(amplitudes_mm=amplitudes, rate_mm_s=speed), rig=rig,
                   params=params, noise=QUIET, rate_hz=rate)
    t, x = np.asarray(sim.log.time), np.asarray(sim.log.displacement)
    base = rs.Base(sigma0=params["sigma0"] * 1e3, Fc=params["Fc"], n=params.get("n", 1.3),
                   x0=x0, supply=supply, dead_a=0.02, dead_b=0.015)
    _, truth = rs.simulate_log(None, base=base, effects=effects, clean=True,
                               fine=rs.piecewise_linear_fine(t, x, 15), substeps=15)
    return sim, truth


def test_rig_simulator_agrees_with_fitstiff_simulate_on_noise_free_chamber_dahl():
    sim, truth = _both("chamber+dahl", {"sigma0": 40, "Fc": 18, "n": 1.3}, {})
    force = np.asarray(sim.prediction.force)
    assert np.ptp(force) > 50      # chamber and friction both at work
    np.testing.assert_allclose(truth["force"], force, atol=1e-6)
    np.testing.assert_allclose(truth["p_a"], np.asarray(sim.prediction.pressure_a), atol=1e-3)
    np.testing.assert_allclose(truth["p_b"], np.asarray(sim.prediction.pressure_b), atol=1e-3)


def test_rig_simulator_heat_and_leak_agree_with_fitstiff_to_its_step_error():
    """Heat exchange and leakage: fitstiff splits the laws per sample, the rig simulator
    integrates their ODE; at 2 kHz they agree to far below the noise."""
    params = {"sigma0": 40, "Fc": 18, "n": 1.4, "heat_rate": 2.0, "leak_rate": 0.1}
    sim, truth = _both("chamber+dahl+heat_transfer+leakage", params,
                       {"heat_transfer": {"rate": 2.0}, "leakage": {"rate": 0.1}}, rate=2000)
    quiet, _ = _both("chamber+dahl", {"sigma0": 40, "Fc": 18, "n": 1.4}, {}, rate=2000)
    effect = np.asarray(sim.prediction.force) - np.asarray(quiet.prediction.force)
    assert np.abs(effect).max() > 1.0
    assert np.abs(truth["force"] - np.asarray(sim.prediction.force)).max() < 0.01


def _clean(effects, *, program=None, ool=None, **base_kw):
    program = program or rs.Program(tuple(rs.triangles((0.5, 2.0), 5.0)))
    base = rs.Base(**base_kw)
    return rs.simulate_log(program, base=base, effects=effects, clean=True, rate_hz=400,
                           out_of_library=ool or {})[1]


def test_viscous_injection_adds_c_times_velocity():
    plain, visc = _clean({}), _clean({"viscous": {"c": 100.0}})
    t, x = plain["time"], plain["x_sensor"]
    v = np.gradient(x, t)
    moving = np.abs(np.abs(v) - 5e-3) < 1e-6     # the constant-speed legs, 5 mm/s
    diff = visc["force"] - plain["force"]
    np.testing.assert_allclose(diff[moving], 100.0 * v[moving], rtol=0.02, atol=0.01)


def test_time_delay_injection_makes_the_force_lag():
    plain, late = _clean({}), _clean({"time_delay": {"delay": 0.01}})
    t = plain["time"]
    np.testing.assert_allclose(late["force"][t > 0.02], np.interp(t[t > 0.02] - 0.01, t,
                                                                  plain["force"]), atol=0.05)


def test_dwell_stiction_junction_peaks_after_a_pause_whichever_way_the_motion_goes():
    # the pause at -1 mm: motion reverses (toward B) in one program, continues (toward A)
    # in the other
    for after, sign in ((6.0, 1.0), (-6.0, -1.0)):
        program = rs.Program((rs.leg(1.0, 5.0), rs.leg(-1.0, 5.0), rs.pause(2.0),
                              rs.leg(after, 5.0)))
        plain = _clean({}, program=program)
        dwell = _clean({"dwell_stiction": {"gain": 3.0, "tau": 0.5, "decay": 0.1e-3}},
                       program=program)
        diff = dwell["force"] - plain["force"]
        t, x = plain["time"], plain["x_sensor"]
        assert np.abs(diff[t < 0.55]).max() < 1e-9
        # against the new motion, up to the strength gain ln(1 + t / tau), then released
        strength = 3.0 * np.log1p(2.0 / 0.5)
        peak = int(np.argmax(sign * diff))
        assert sign * diff[peak] == pytest.approx(strength, rel=0.1)   # logged at 400 Hz
        assert abs(abs(x[peak] - (-1e-3)) - 0.1e-3) < 0.02e-3
        assert abs(diff[-1]) < 1e-3 * strength


def test_dwell_stiction_level_kind_raises_the_level_after_a_pause_only():
    program = rs.Program((rs.leg(1.0, 5.0), rs.leg(-1.0, 5.0), rs.pause(2.0), rs.leg(6.0, 5.0)))
    plain = _clean({}, program=program)
    dwell = _clean({"dwell_stiction": {"kind": "level", "gain": 0.5, "tau": 0.5,
                                       "decay": 1e-3}}, program=program)
    diff = dwell["force"] - plain["force"]
    t = plain["time"]
    assert np.abs(diff[t < 0.55]).max() < 1e-9
    # after the pause, toward B: an extra breakaway below gain * (1 - exp(-4)) * Fc, faded
    # over the ~0.5 mm the Dahl branch needs to reach it
    assert 0.5 * 18 > diff.max() > 0.5 * 18 * 0.2
    assert abs(diff[-1]) < 0.1 * diff.max()


def test_rig_compliance_softens_the_loop():
    plain, soft = _clean({}), _clean({"rig_compliance": {"compliance": 1e-5}})
    # the stiff pre-sliding slope after a reversal is reduced: K / (1 + C K)
    i = int(np.argmax(plain["x_sensor"]))
    j = i + 6
    k_plain = (plain["force"][j] - plain["force"][i]) / (plain["x_sensor"][j] - plain["x_sensor"][i])
    k_soft = (soft["force"][j] - soft["force"][i]) / (soft["x_sensor"][j] - soft["x_sensor"][i])
    assert k_soft == pytest.approx(k_plain / (1 + 1e-5 * k_plain), rel=0.1)
    # piston moves less than the sensor by C F
    np.testing.assert_allclose(soft["x_sensor"] - soft["x_piston"], 1e-5 * soft["force"],
                               atol=2e-7)


def test_wilson_interval_matches_the_closed_form():
    low, high = wh.wilson(0, 100)
    assert low == pytest.approx(0.0, abs=1e-12) and high == pytest.approx(0.0370, abs=2e-4)
    low, high = wh.wilson(5, 100)
    assert (low, high) == pytest.approx((0.02154, 0.11175), abs=2e-4)
    assert wh.wilson(0, 0) == (0.0, 1.0)


def _rec(family, withheld, accepted, top1=None, size=1.0, det=0.5):
    return {"id": f"{family}/{'+'.join(withheld)}/{len(accepted)}{top1}{size}",
            "family": family, "withheld": withheld, "expected": withheld if family in
            ("single", "pair", "law") else [], "accepted": accepted,
            "top1": top1 or (accepted[0] if accepted else None),
            "sizes": {e: size for e in withheld},
            "detectability": {e: {"testable": family != "missing", "size": det}
                              for e in withheld},
            "shrink": 0.9 if accepted else None, "unexplained_cells": 0 if accepted else 2,
            "wall_s": 10.0}


def test_scores_and_confusion_matrix_on_hand_made_results():
    recs = [_rec("single", ["viscous"], ["viscous"]),
            _rec("single", ["viscous"], [], top1="viscous", size=0.1),
            _rec("single", ["stribeck"], ["time_delay"]),
            _rec("single", ["stribeck"], ["stribeck", "time_delay"]),
            _rec("null", [], []), _rec("null", [], ["inertia"]), _rec("null", [], []),
            _rec("ool", [], []), _rec("ool", [], ["maxwell_slip"]),
            _rec("pair", ["viscous", "inertia"], ["inertia", "viscous"]),
            _rec("pair", ["viscous", "inertia"], ["viscous"]),
            _rec("missing", ["dwell_stiction"], []),
            _rec("law", ["maxwell_slip"], ["maxwell_slip"]),
            _rec("law", ["maxwell_slip"], ["maxwell_slip", "viscous"]),
            _rec("law", ["maxwell_slip"], ["rig_compliance"])]
    for i, r in enumerate(recs):
        r["id"] += str(i)
    s = wh.score({r["id"]: r for r in recs})
    assert s["single"]["top1"]["k"] == 3 and s["single"]["top1"]["n"] == 4
    assert s["single"]["exact"]["k"] == 1
    assert s["null"]["false_alarm"]["k"] == 1 and s["null"]["false_alarm"]["n"] == 3
    assert s["null"]["false_alarm"]["wilson95"] == pytest.approx(list(wh.wilson(1, 3)))
    assert s["ool"]["unexplained"]["k"] == 1
    assert s["pair"]["both_found"]["k"] == 1
    assert s["missing"]["not_testable"]["k"] == 1
    assert s["law"]["exact"]["k"] == 1 and s["law"]["found"]["k"] == 2
    assert s["law"]["exact"]["n"] == 3
    assert s["law"]["named"] == ["maxwell_slip", "maxwell_slip", "rig_compliance"]
    # viscous 0.1 below its detectable size 0.5; the other three above: 2 of 3 found
    assert s["detectability"]["above"]["k"] == 2 and s["detectability"]["above"]["n"] == 3
    assert s["detectability"]["below"]["n"] == 1
    rows, cols, counts = wh.confusion(recs)
    assert rows == ["viscous", "stribeck", "none", "out-of-library"]
    c = dict(zip(cols, range(len(cols))))
    assert counts[0, c["viscous"]] == 1 and counts[0, c["none"]] == 1
    assert counts[1, c["time_delay"]] == 1 and counts[1, c["stribeck"]] == 1
    assert counts[2, c["none"]] == 2 and counts[2, c["inertia"]] == 1
    assert counts[3, c["maxwell_slip"]] == 1
    assert counts.sum() == 9


def test_screened_finds_the_stored_diagnoses_a_candidate_may_have_changed():
    """benchmarks/withheld.py --rerun-screened: a dataset is run again when the candidate
    was refitted, screened below the level, or may hide below a ranked list that ends below
    it, and always when anything was accepted (the record keeps the last round's screens);
    not when, in a single round, it was screened weakly or is absent below a list that ends
    above the level."""
    def rec(*rows, accepted=()):
        return {"accepted": list(accepted),
                "ranked": [{"effect": e, "log_p_value": math.log(p), "shrink": sh}
                           for e, p, sh in rows]}

    level = 0.01
    assert wh.screened(rec(("a", 1e-9, 0.5), ("c", 1e-9, None)), "c", level=level)
    assert wh.screened(rec(("c", 0.2, -0.1)), "c", level=level)          # refitted
    assert not wh.screened(rec(("a", 1e-9, 0.5), ("c", 0.2, None)), "c", level=level)
    assert wh.screened(rec(("a", 1e-9, 0.5), ("b", 1e-3, None)), "c", level=level)
    assert not wh.screened(rec(("a", 1e-9, 0.5), ("b", 0.3, None)), "c", level=level)
    assert wh.screened({"error": "boom"}, "c", level=level)
    assert wh.screened(rec(("a", 1e-9, 0.5), ("c", 0.9, None), accepted=["a"]), "c",
                       level=level)


def test_plot_confusion_draws_on_the_given_axes():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    out = wh.plot_confusion(ax, ["viscous", "none"], ["viscous", "none"],
                            np.array([[3, 1], [0, 5]]))
    assert out is ax and len(ax.texts) == 3
    plt.close(fig)


def test_dataset_ids_interleave_families_and_are_reproducible():
    ids = wh.dataset_ids(seeds=2, nulls=4, pair_seeds=1)
    n_ool = len(datasets.OUT_OF_LIBRARY)
    assert len(ids) == len(set(ids)) == (13 * 2 + 4 + n_ool * 2 + 8 + len(datasets.MISSING) * 2
                                         + len(datasets.LAWS) * 2)
    assert len(datasets.OUT_OF_LIBRARY) == 7 and set(datasets.OOL_VARIABLE) == set(
        datasets.OUT_OF_LIBRARY)
    assert {i.split("/")[0] for i in ids[: len(ids) // 2 + 8]} == set(wh.FAMILIES)
    a, ta = datasets.make_dataset("single/viscous/3", rate_scale=0.2)
    b, tb = datasets.make_dataset("single/viscous/3", rate_scale=0.2)
    assert ta["sizes"] == tb["sizes"] and np.array_equal(a[0].force, b[0].force)
    low, high = datasets.SIZES["viscous"]
    assert low <= ta["sizes"]["viscous"] <= high
    _, miss = datasets.make_dataset("missing/pressure_friction/0", rate_scale=0.2)
    assert len({round(p["supply_bar"], 9) for p in miss["logs"]}) == 1
    assert all(0 < p["x0_mm"] < 700 for p in miss["logs"])
    assert not math.isnan(ta["base"]["Fc_N"])


def test_a_law_dataset_is_a_seal_whose_whole_friction_is_that_law():
    """``law/maxwell_slip``: no Dahl term; three elements of unequal stiffness and slip force
    whose slip forces add up to the seal's breakaway (12-22 N), reproducible from the id."""
    logs, truth = datasets.make_dataset("law/maxwell_slip/3")
    again, _ = datasets.make_dataset("law/maxwell_slip/3")
    assert np.array_equal(logs[1].force, again[1].force)
    assert truth["expected"] == ["maxwell_slip"] and truth["base"]["Fc_N"] == 0.0
    k, delta = (np.array(truth["effects"]["maxwell_slip"][p]) for p in ("k", "delta"))
    slip = k * delta
    assert k.size == 3 and len(set(np.round(k))) == 3 and len(set(np.round(slip, 6))) == 3
    assert 12.0 <= slip.sum() <= 22.0
    assert np.all(np.diff(delta) > 0) and 0.08e-3 <= delta[0] <= 0.2e-3
    assert truth["sizes"]["maxwell_slip"] == pytest.approx(k.sum() / 1e3)
    _, other = datasets.make_dataset("single/maxwell_slip/3")
    assert other["base"]["Fc_N"] > 0           # the single family keeps its Dahl seal


@pytest.mark.slow
def test_quick_run_of_one_null_and_one_effect_through_the_diagnosis():
    """A strong viscous effect is found; the null names nothing (short logs, four rate
    candidates, to keep it near half a minute)."""
    rate_effects = "viscous,stribeck,time_delay,inertia"
    effect = wh.run_dataset("single/viscous/1", short=True, candidates=rate_effects)
    null = wh.run_dataset("null/3", short=True, candidates=rate_effects)
    assert "error" not in effect and "error" not in null, (effect, null)
    assert effect["accepted"] == ["viscous"], wh.describe(effect)
    assert null["accepted"] == [], wh.describe(null)
    assert effect["detectability"]["viscous"]["testable"]
    assert effect["sizes"]["viscous"] > effect["detectability"]["viscous"]["size"]
    # every refit is kept with its round and held-out figures (the rule's calibration data)
    (viscous,) = [r for r in effect["refits"] if r["effect"] == "viscous"]
    assert viscous["accepted"] and viscous["round"] == 1
    assert viscous["after_N"] < viscous["before_N"] == effect["heldout_rms_before_N"]
    assert all(not r["accepted"] for r in null["refits"])


@pytest.mark.parametrize("dataset, accepted, top1", [
    # held out, leakage predicted 0.12216 N against heat exchange's 0.12219 N (noise 0.12 N):
    # a tie, which the fits to all the data broke for heat exchange (BIC 4.0 lower). Since the
    # turning points are fitted with a rounded kink (54ca651) the fits to all the data
    # preferred leakage (BIC 2477.5 against 2499.7); with one rounding per log and the pauses
    # standing still in the drive (1956883) they break it for heat exchange again (held out
    # 0.1533 -> 0.1159 N). A tie the logs barely break: issue 33's planned experiment is
    # what settles it
    ("single/heat_transfer/2", ["heat_transfer"], "heat_transfer"),
    # a leak below the detectable size: nothing accepted, and the two scores agree to 0.04 in
    # log p; ranked by their fits to all the data, leakage comes first
    ("single/leakage/3", [], "leakage"),
])
def test_heat_exchange_and_leakage_the_screen_cannot_order_are_told_apart_by_their_fits(
        dataset, accepted, top1):
    r = wh.run_dataset(dataset, candidates="heat_transfer,leakage")
    assert "error" not in r, r
    assert r["accepted"] == accepted and r["top1"] == top1, wh.describe(r)
    if accepted:
        # the tie and its BIC gap stay on the loser's record after it is screened again on
        # the enlarged model (round 2); 44.7 at 5bd97f1: told apart, the verdict says by what
        [tie] = r["ties"]
        assert (tie["accepted"], tie["tied"]) == ("heat_transfer", "leakage")
        assert tie["bic_gap"] >= DECISIVE_BIC


def test_a_wrong_name_that_won_a_tie_by_a_small_bic_gap_is_counted_as_undecided():
    """single/heat_transfer/8 (5bd97f1): leakage and heat exchange predicted the held-out
    data alike (0.26717 against 0.26717 N) and leakage won on all the data by BIC 1.31."""
    def rec(accepted, ties):
        return {"withheld": ["heat_transfer"], "accepted": accepted, "ties": ties}

    tie = {"accepted": "leakage", "tied": "heat_transfer", "bic_gap": 1.31}
    assert wh.undecided_tie(rec(["leakage"], [tie]))
    assert wh.undecided_tie(rec(["leakage"], [tie | {"bic_gap": math.nan}]))
    assert not wh.undecided_tie(rec(["leakage"], [tie | {"bic_gap": DECISIVE_BIC}]))
    assert not wh.undecided_tie(rec(["leakage"], []))            # named outright
    assert not wh.undecided_tie(rec(["heat_transfer"], []))      # right
    # a second wrong name that tied with nothing is wrong outright
    assert not wh.undecided_tie(rec(["leakage", "viscous"], [tie]))
    # a tie with another wrong candidate is no tie with the withheld effect
    assert not wh.undecided_tie(rec(["leakage"], [tie | {"tied": "viscous"}]))


def test_a_rig_compliance_is_accepted_over_the_maxwell_slip_mimic():
    """The compliance's refit takes the logged force as its input: raw, its noise times the
    compliance and the seal's stiffness came back as force error, the refit kept the
    compliance near 0 and Maxwell-slip elements were accepted in its place (shrink 0.81).
    With the force smoothed (and the refit started from the joint Gauss-Newton step) the
    compliance removes 60 % of the gap, Maxwell-slip 47 %."""
    r = wh.run_dataset("single/rig_compliance/0", candidates="rig_compliance,maxwell_slip")
    assert "error" not in r, r
    assert r["accepted"] == ["rig_compliance"], wh.describe(r)


def test_two_missing_effects_that_fail_alone_are_accepted_together():
    """Pressure-dependent friction and a 2.3 kg inertia both withheld: alone, each refit
    removes 25 % of the gap (held-out RMS 2.94 -> 2.28 and 2.27 N; the other's misfit spoils
    the transfer to the left-out log), together they reach 1.02 N. (The pair of issue 31's
    first session, a rig compliance with dwell stiction, no longer serves: with the junction
    law of dwell stiction its screen has the wrong sign under a large compliance.)"""
    r = wh.run_dataset("pair/pressure_friction+inertia/2",
                       candidates="pressure_friction,inertia")
    assert "error" not in r, r
    assert sorted(r["accepted"]) == ["inertia", "pressure_friction"], wh.describe(r)
    assert r["shrink"] > 0.3


@pytest.mark.parametrize("kind", ["tight_spot", "friction_drift", "saturating_pressure",
                                  "rate_stiffness"])
def test_each_new_out_of_library_kind_changes_the_force_where_it_should(kind):
    """Issue 32's kinds in the independent simulator, on clean logs: a tight spot raises the
    friction level only near its centre, a drift only as time goes on, a saturating law
    only away from the reference pressure, a rate-dependent stiffness only the transitions."""
    from fitstiff._testing.withheld import draw_out_of_library

    program = datasets.log_program(1, 6.0, pauses=False, holds=False, sweeps=False)
    base = rs.Base(sigma0=40e3, Fc=18.0, n=1.2, x0=0.35, supply=4.5e5, dead_a=0.02,
                   dead_b=0.02, chamber=True)
    ool = draw_out_of_library(kind, np.random.default_rng(0))
    if kind == "tight_spot":
        ool = {"gain": 0.5, "width": 0.4e-3, "centre": 0.35 + 0.5e-3}
    plain, truth = rs.simulate_log(program, base=base, rate_hz=400.0, clean=True, p_ref=3.0e5)
    other, _ = rs.simulate_log(program, base=base, rate_hz=400.0, clean=True, p_ref=3.0e5,
                               out_of_library={kind: ool})
    diff = np.asarray(other.force) - np.asarray(plain.force)
    assert np.sqrt(np.mean(diff**2)) > 0.1
    if kind == "tight_spot":                # the spot at +0.5 mm, not at -0.5 mm and below
        u = truth["x_piston"]
        near, away = np.abs(u - 0.5e-3) < 0.2e-3, u < -0.5e-3
        assert near.any() and away.any()
        assert np.abs(diff[near]).mean() > 3 * np.abs(diff[away]).mean()
    if kind == "friction_drift":            # it grows with time
        early, late = diff[: diff.size // 10], diff[-diff.size // 10:]
        assert np.abs(early).mean() < np.abs(late).mean()


def test_a_planned_program_is_played_on_the_datasets_rig():
    """The closed loop's rig (issue 33): a program's setpoints ``time_s,displacement_mm`` run
    through the independent simulator with the dataset's truth, at the plan's supply and start
    position; the motion follows the setpoints up to the rounded corners and the noise."""
    _, truth = datasets.make_dataset("missing/inertia/0", short=True)
    assert truth["excitation"]["sweeps"] is False and "inertia" in truth["effects"]
    t = np.arange(0, 4.0, 1 / 200.0)
    x = 0.5e-3 * np.sin(2 * np.pi * 1.0 * t)
    log = datasets.simulate_program(truth, t, x, supply_bar=4.2, start_position_mm=300.0,
                                    name="planned_0")
    assert len(log) == t.size and np.allclose(log.time, t)
    assert log.rig.supply_pressure == pytest.approx(4.2e5)
    assert log.rig.start_position == pytest.approx(0.3)
    assert np.max(np.abs(log.displacement - x)) < 20e-6           # rounding + encoder noise
    again = datasets.simulate_program(truth, t, x, supply_bar=4.2, start_position_mm=300.0,
                                      name="planned_0")
    assert np.array_equal(again.force, log.force)                 # seeded by dataset and name


def test_the_closed_loop_table_counts_named_exactly_per_stage():
    from fitstiff._testing.plan_loop import score_loop

    def record(i, family, withheld, before, naive, planned):
        return {"id": f"{family}/{'+'.join(withheld) or 'x'}/{i}", "family": family,
                "withheld": withheld, "reason": "untestable",
                "before": {"exact": before}, "after_naive": {"exact": naive},
                "after_planned": {"exact": planned}, "plan_s": 10.0 + i}

    records = [record(0, "missing", ["dwell_stiction"], False, False, True),
               record(1, "missing", ["dwell_stiction"], False, False, False),
               record(2, "missing", ["inertia"], False, True, True),
               record(3, "null", [], True, True, True),
               {"id": "single/viscous/0", "family": "single", "withheld": ["viscous"],
                "reason": None, "before": {"exact": True}}]
    table = score_loop(records)
    assert table["rows"]["missing/dwell_stiction"]["after_planned"]["k"] == 1
    assert table["rows"]["missing/dwell_stiction"]["after_planned"]["n"] == 2
    assert table["effects"]["after_naive"]["k"] == 1
    assert table["effects"]["after_planned"]["k"] == 2
    assert table["nulls"]["after_planned"]["k"] == 1
    assert table["no_plan_needed"] == 1 and table["plan_s_max"] == 13.0


@pytest.mark.parametrize("dataset, alone", [("single/stribeck/4", True),
                                            ("single/stribeck/8", False)])
def test_an_effect_one_log_alone_determines_says_which_log(dataset, alone):
    """Stribeck friction at 1.34 mm/s shows in the slow log (1.4 mm/s) and only at the
    reversal samples of the fast ones (7 and 25 mm/s), where its level and velocity trade
    off: left out, the slow log is predicted by folds that find no Stribeck friction, so
    its held-out refit gains little although the score test finds it (log p -395). The
    candidate's why says which log alone determines it and what to record. At 2.8 mm/s
    (``/8``) the 5.8 mm/s log sees it too: no such sentence."""
    from fitstiff.diagnosis import diagnose

    logs, truth = datasets.make_dataset(dataset)
    d = diagnose(logs, baseline=truth["baseline"], candidates="stribeck", structure=False)
    c = d.candidate("stribeck")
    assert not c.accepted and c.p_value < 1e-10
    said = "alone determines it" in c.why
    assert said == alone, c.why
    assert c.determined_by == (logs[0].name if alone else "")
    told = [line for line in d.verdict if "alone determines it" in line]
    assert len(told) == int(alone), d.verdict
    if alone:
        slow = logs[0].name
        assert f"the fold that leaves out log {slow} finds stribeck_ratio 1.00" in c.why
        assert f"log {slow} alone determines it" in c.why and "record a second log" in c.why
        assert told[0].startswith("stribeck is significant (p = ") and "record a second log" \
            in told[0]
        again = type(d).from_dict(json.loads(json.dumps(d.to_dict())))
        assert again.candidate("stribeck").determined_by == slow


def test_merged_records_take_each_rerun_over_the_stored_and_add_none(tmp_path, capsys):
    """benchmarks/withheld_merge.py: the stored files merge (a later one's records replace
    an earlier one's), a --rerun file replaces records and adds none, and the scores are of
    the merged records."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "withheld_merge.py"
    spec = importlib.util.spec_from_file_location("withheld_merge", path)
    merge = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(merge)

    results = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
    kept = {**json.loads((results / "withheld_single_eb901e8.json").read_text())["datasets"],
            **json.loads((results / "withheld_rest_5bd97f1.json").read_text())["datasets"]}

    def rec(i, accepted):              # a stored record, with what it accepted replaced
        return dict(kept[i.replace("/7", "/2")], id=i, accepted=accepted)

    stored = {"single/viscous/0": rec("single/viscous/0", ["viscous"]),
              "ool/ripple/1": rec("ool/ripple/1", ["pressure_friction"])}
    (tmp_path / "a.json").write_text(json.dumps({"datasets": stored}))
    rerun = {"ool/ripple/1": rec("ool/ripple/1", []),
             "ool/ripple/7": rec("ool/ripple/7", ["stribeck"])}
    (tmp_path / "b.json").write_text(json.dumps({"datasets": rerun}))
    records = merge.merge([tmp_path / "a.json"], [tmp_path / "b.json"])
    assert sorted(records) == ["ool/ripple/1", "single/viscous/0"]
    assert records["ool/ripple/1"]["accepted"] == []
    assert sorted(merge.merge([tmp_path / "a.json", tmp_path / "b.json"])) == [
        "ool/ripple/1", "ool/ripple/7", "single/viscous/0"]
    out = tmp_path / "scores.json"
    assert merge.main([str(tmp_path / "a.json"), "--rerun", str(tmp_path / "b.json"),
                       "--json", str(out), "--summary-only"]) == 0
    capsys.readouterr()
    scores = json.loads(out.read_text())
    assert "datasets" not in scores and scores["reruns"] == [str(tmp_path / "b.json")]
    assert scores["summary"]["ool"]["unexplained"]["k"] == 1
    assert scores["summary"]["single"]["exact"]["k"] == 1
    with pytest.raises(SystemExit, match="not a withheld-benchmark record"):
        merge.merge([tmp_path / "scores.json"])
