"""Displacement programs, the simulator, the log writer, ``fitstiff simulate`` and the committed
synthetic data (DESIGN §3 "synthetic data = simulate(model with effects) + realistic noise").

Expectations are written out from the program definitions and closed-form laws (the exact
polytropic chamber force, the exact Dahl curve from a virgin state), never from the code under
test.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import sys

import numpy as np
import pytest
from conftest import REPO

from fitstiff.cli import main
from fitstiff.data import PAPER_RIG
from fitstiff.errors import InputError
from fitstiff.io.log import Rig
from fitstiff.physics import gas_spring
from fitstiff.physics.drive import make_drive
from fitstiff.physics.model import build_model
from fitstiff.physics.params import Parameterization
from fitstiff.physics.programs import (
    Concat,
    NestedLoops,
    Pause,
    Ramp,
    SineSweep,
    TriangleCycles,
    Waypoints,
)
from fitstiff.physics.simulate import Noise, format_log, simulate, write_log

SYNTHETIC = REPO / "data" / "synthetic"
QUIET = Noise(force_N=0.0, displacement_um=0.0, pressure_mbar=0.0)
SEAL = {"sigma0": 40.0, "Fc": 18.0, "n": 1.4}   # display units: N/mm, N, -


def turning_points(x: np.ndarray) -> np.ndarray:
    """Values at the samples where the direction of motion changes (pauses skipped)."""
    moving = np.flatnonzero(np.diff(x) != 0)
    direction = np.sign(np.diff(x)[moving])
    return x[moving[1:][direction[1:] != direction[:-1]]]


def runs_of_rest(x: np.ndarray) -> list[tuple[float, int]]:
    """``(position, number of sample periods)`` of every standstill."""
    still = np.concatenate([[False], np.diff(x) == 0, [False]])
    edges = np.flatnonzero(np.diff(still.astype(int)))
    return [(float(x[a]), int(b - a)) for a, b in zip(edges[::2], edges[1::2])]


# ------------------------------------------------------------------------------- programs

def test_triangle_cycles_reverse_at_the_amplitudes_in_order():
    t, x = TriangleCycles(amplitudes_mm=(0.05, 0.2, 1.0), rate_mm_s=1.0, cycles=2).sample(500.0)
    expected = [s * a for a in (0.05e-3, 0.2e-3, 1e-3) for _ in range(2) for s in (1, -1)]
    np.testing.assert_allclose(turning_points(x), expected, rtol=0, atol=1e-15)
    assert x[0] == 0 and x[-1] == 0
    np.testing.assert_allclose(np.diff(t), 1 / 500.0, rtol=1e-12)
    # total travel 4 * 2 * (0.05 + 0.2 + 1) mm at 1 mm/s = 10 s
    assert t[-1] == pytest.approx(10.0, abs=1 / 500.0 * 12)


def test_pauses_have_the_requested_lengths_at_reversals_and_at_passes():
    rate = 200.0
    at_reversals = TriangleCycles(amplitudes_mm=(0.5,), rate_mm_s=1.0, cycles=2,
                                  pause_s=(0.5, 2.0, 1.25))
    _, x = at_reversals.sample(rate)
    assert runs_of_rest(x) == [(5e-4, 100), (-5e-4, 400), (5e-4, 250), (-5e-4, 100)]
    at_passes = TriangleCycles(amplitudes_mm=(0.5,), rate_mm_s=1.0, cycles=2, pause_s=(3.0,),
                               pause_at="passes")
    _, x = at_passes.sample(rate)
    assert runs_of_rest(x) == [(0.0, 600)] * 3     # the final return to 0 is the end, no joint
    np.testing.assert_allclose(turning_points(x), [5e-4, -5e-4] * 2, atol=1e-15)


def test_nested_loops_turn_at_every_return_point():
    program = NestedLoops(amplitude_mm=1.0, minor_mm=(0.4, 0.2, 0.1), rate_mm_s=2.0)
    _, x = program.sample(400.0)
    # down from 1 to 0, turn up to 0.4, down to 0.2, up to 0.3, back down to 0.2, up to 0.4
    # (closing the 0.2 loop), down through 0 (closing the 0.4 loop: 0 is passed) to -1;
    # the ascending branch mirrors it
    turns = [1.0, 0.0, 0.4, 0.2, 0.3, 0.2, 0.4, -1.0, 0.0, -0.4, -0.2, -0.3, -0.2, -0.4, 1.0]
    np.testing.assert_allclose(turning_points(x), np.array(turns) * 1e-3, atol=1e-15)
    passes = [x[k] for k in range(1, len(x) - 1) if x[k] == 0.0]
    assert len(passes) == 4            # each branch: the turn at 0 and the pass through 0
    assert x[-1] == 0.0


def test_sine_sweep_starts_and_ends_at_rest_with_the_requested_amplitude():
    fs = 2000.0
    t, x = SineSweep(amplitude_mm=0.3, start_hz=5.0, duration_s=2.0).sample(fs)
    v = np.diff(x) * fs
    assert x[0] == 0.0 and abs(x[-1]) < 1e-12
    assert abs(v[0]) < 1e-3 * 0.3e-3 * 2 * np.pi * 5 and abs(v[-1]) < 1e-3 * 0.3e-3 * 2 * np.pi * 5
    assert x.max() == pytest.approx(0.3e-3, rel=1e-4)
    assert np.count_nonzero(np.diff(np.sign(x[1:-1])) != 0) == 2 * 5 * 2 - 1   # 10 periods
    # a sweep gets faster: the last period is shorter than the first
    _, swept = SineSweep(amplitude_mm=0.3, start_hz=2.0, end_hz=20.0, duration_s=2.0,
                         fade_cycles=0.0).sample(fs)
    crossings = np.flatnonzero(np.diff(np.sign(swept[1:])) != 0)
    assert np.diff(crossings)[-1] < np.diff(crossings)[0] / 3


def test_concat_continues_from_where_each_part_ended():
    program = Ramp(distance_mm=0.2, rate_mm_s=1.0) + Pause(duration_s=0.1) + Waypoints(
        points_mm=(-0.1, 0.3), rate_mm_s=2.0)
    t, x = program.sample(1000.0)
    assert isinstance(program, Concat) and len(program.parts) == 3
    # 200 + 100 + (0.1 mm + 0.4 mm) / 2 mm/s * 1000 = 550 periods
    assert len(x) == 551 and t[-1] == pytest.approx(0.55)
    np.testing.assert_allclose(turning_points(x), [0.2e-3, 0.1e-3], atol=1e-15)
    assert x[-1] == pytest.approx(0.5e-3, abs=1e-15)
    assert runs_of_rest(x) == [(pytest.approx(0.2e-3), 100)]
    assert program.describe()["parts"][1] == {"program": "pause", "duration_s": 0.1}


@pytest.mark.parametrize("make, message", [
    (lambda: TriangleCycles(amplitudes_mm=(0.5,), rate_mm_s=0.0),
     "triangle_cycles program option 'rate_mm_s': found 0.0; give a finite number > 0"),
    (lambda: NestedLoops(amplitude_mm=1.0, minor_mm=(0.2, 0.4), rate_mm_s=1.0),
     "nested_loops program option 'minor_mm': found [0.2, 0.4]; give one or more strictly "
     "decreasing loop sizes"),
    (lambda: TriangleCycles(amplitudes_mm=(0.5,), rate_mm_s=1.0, pause_s=(1,), pause_at="end"),
     "triangle_cycles program option 'pause_at': found 'end'; use one of: reversals, passes"),
    (lambda: Ramp(distance_mm=1.0, rate_mm_s=1.0).sample(0.0),
     "sample rate: found 0.0 Hz; give a positive rate"),
])
def test_bad_program_options_are_one_line_input_errors(make, message):
    with pytest.raises(InputError) as info:
        make()
    assert str(info.value) == message


# ----------------------------------------------------------------------------- simulation

def test_noise_free_chamber_dahl_matches_model_run_and_the_closed_forms(paper_rig):
    program = TriangleCycles(amplitudes_mm=(0.1, 0.5), rate_mm_s=1.0)
    sim = simulate("chamber+dahl", program, rig=paper_rig, params=SEAL, noise=QUIET,
                   rate_hz=400.0)
    t, x = program.sample(400.0)
    model = Parameterization(build_model("chamber+dahl")).with_values(
        build_model("chamber+dahl"), {"sigma0": 40e3, "Fc": 18.0, "n": 1.4})
    reference = model.run(make_drive(displacement=x, time=t, rig=paper_rig, needs_chamber=True))
    np.testing.assert_array_equal(sim.log.force, np.asarray(reference.force))
    np.testing.assert_array_equal(sim.log.pressure_a, np.asarray(reference.pressure_a))
    np.testing.assert_array_equal(sim.log.displacement, x)
    np.testing.assert_array_equal(sim.log.time, t)
    np.testing.assert_array_equal(sim.truth["force_noise_free_N"], sim.log.force)

    # first leg 0 -> 0.1 mm from a virgin seal: exact chamber law + exact Dahl curve
    leg = slice(0, 41)
    u = x[leg]
    p0 = 6e5 + 101_325.0
    area = math.pi / 4 * 0.032**2
    chamber = gas_spring.chamber_force(u, p_a0=p0, p_b0=p0, l_a0=0.35, l_b0=0.35,
                                       area_a=area, area_b=area, n=1.4, p_amb=101_325.0)
    dahl = 18.0 * (1 - np.exp(-40e3 * u / 18.0))
    np.testing.assert_allclose(sim.log.force[leg], np.asarray(chamber) + dahl, rtol=1e-9,
                               atol=1e-9)


def test_truth_lists_every_parameter_in_display_units(paper_rig):
    sim = simulate("chamber+dahl+viscous", Ramp(distance_mm=0.2, rate_mm_s=2.0), rig=paper_rig,
                   params={**SEAL, "c": 150}, seed=7, name="ramp", rate_hz=100.0)
    truth = sim.truth
    assert truth["model"] == "chamber+dahl+viscous"
    assert truth["parameters"] == {"n": {"value": 1.4, "unit": "-"},
                                   "sigma0": {"value": 40.0, "unit": "N/mm"},
                                   "Fc": {"value": 18.0, "unit": "N"},
                                   "c": {"value": 150.0, "unit": "N s/m"}}
    assert truth["noise"] == {"force_N": 0.2, "displacement_um": 1.0, "pressure_mbar": 2.0,
                              "ar1": 0.0}
    assert truth["seed"] == 7 and truth["samples"] == 11
    assert truth["program"] == {"program": "ramp", "distance_mm": 0.2, "rate_mm_s": 2.0}
    assert truth["rig"]["supply_bar"] == 6.0
    if "derived" in truth:
        assert truth["derived"]["presliding_slope_N_per_mm"] == pytest.approx(40.0)
        assert truth["derived"]["breakaway_N"] == pytest.approx(18.0)


def test_simulation_is_deterministic_for_a_seed(paper_rig):
    program = TriangleCycles(amplitudes_mm=(0.2,), rate_mm_s=1.0)

    def run(seed):
        return simulate("chamber+dahl", program, rig=paper_rig, params=SEAL, seed=seed,
                        rate_hz=100.0).log

    a, b, c = run(3), run(3), run(4)
    for field in ("displacement", "force", "pressure_a", "pressure_b"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        assert not np.array_equal(getattr(a, field), getattr(c, field))


@pytest.mark.parametrize("phi", [0.0, 0.7])
def test_noise_has_the_requested_std_and_lag1_correlation(paper_rig, phi):
    n = 20_001
    noise = Noise(force_N=0.3, displacement_um=2.0, pressure_mbar=5.0, ar1=phi)
    sim = simulate("chamber+dahl", Pause(duration_s=20.0), rig=paper_rig, params=SEAL,
                   noise=noise, seed=11, rate_hz=1000.0)
    assert len(sim.log) == n
    channels = {
        "force": (sim.log.force - np.asarray(sim.prediction.force), 0.3),
        "displacement": (sim.log.displacement, 2e-6),
        "pressure_a": (sim.log.pressure_a - np.asarray(sim.prediction.pressure_a), 500.0),
        "pressure_b": (sim.log.pressure_b - np.asarray(sim.prediction.pressure_b), 500.0),
    }
    # standard errors of the sample std and lag-1 correlation of an AR(1) series
    se_std = math.sqrt((1 + phi**2) / (2 * n * (1 - phi**2)))
    se_rho = math.sqrt((1 - phi**2) / n)
    for name, (e, std) in channels.items():
        assert abs(e.std() / std - 1) < 5 * se_std, name
        rho = np.corrcoef(e[1:], e[:-1])[0, 1]
        assert abs(rho - phi) < 5 * se_rho, name
    # independent channels
    assert abs(np.corrcoef(channels["pressure_a"][0], channels["pressure_b"][0])[0, 1]) < 0.05


def test_simulate_reports_bad_input(paper_rig):
    program = TriangleCycles(amplitudes_mm=(1.0,), rate_mm_s=1.0)
    with pytest.raises(InputError, match=r"^parameter 'sigma': is not in this model; use one "
                                         r"of: n, sigma0, Fc$"):
        simulate("chamber+dahl", program, rig=paper_rig, params={"sigma": 40})
    near_cap = paper_rig.merged({"start_position_mm": 0.5})
    with pytest.raises(InputError, match="moves the piston over -0.5..1.5 mm, outside the "
                                         "stroke 0..700 mm"):
        simulate("chamber+dahl", program, rig=near_cap)
    no_supply = Rig(bore=0.032, stroke=0.7, start_position=0.35)
    with pytest.raises(InputError, match="'supply_bar'.*--supply-bar"):
        simulate("chamber+dahl", program, rig=no_supply)
    with pytest.raises(InputError, match="ar1"):
        Noise(ar1=1.0)


# ------------------------------------------------------------------------------ the files

def test_written_log_round_trips_through_the_loader(paper_rig, tmp_path):
    loading = pytest.importorskip("fitstiff.io.loading",
                                  reason="fitstiff.io.loading (load_log) is not written yet")
    sim = simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.1, 0.5), rate_mm_s=1.0),
                   rig=paper_rig, params=SEAL, seed=5, name="ignored", rate_hz=200.0)
    written = write_log(sim.log, tmp_path / "run1.csv", truth=sim.truth)
    assert [p.name for p in written] == ["run1.csv", "run1.json", "run1.truth.json"]
    header = (tmp_path / "run1.csv").read_text().splitlines()[0]
    assert header == "time_s,displacement_mm,force_N,p_a_bar,p_b_bar"
    sidecar = json.loads((tmp_path / "run1.json").read_text())
    # the paper's rig (conftest's fixture), every key it knows
    assert sidecar == {k: v for k, v in PAPER_RIG.items() if v is not None}

    log = loading.load_log(tmp_path / "run1.csv")
    assert log.name == "run1" and len(log) == len(sim.log)
    for field, atol in (("time", 0.0), ("displacement", 1e-15), ("force", 1e-12),
                        ("pressure_a", 1e-3), ("pressure_b", 1e-3)):
        np.testing.assert_allclose(getattr(log, field), getattr(sim.log, field), rtol=1e-8,
                                   atol=atol, err_msg=field)
    assert log.rig.supply_pressure == pytest.approx(6e5)
    assert log.rig.start_position == pytest.approx(0.35)
    drive = make_drive(displacement=log.displacement, time=log.time, rig=log.rig,
                       pressure_a=log.pressure_a, pressure_b=log.pressure_b,
                       needs_chamber=True)
    assert drive.modes == ("closed", "closed") and drive.observed == (True, True)

    truth = json.loads((tmp_path / "run1.truth.json").read_text())
    assert truth["parameters"]["sigma0"] == {"value": 40.0, "unit": "N/mm"}
    np.testing.assert_allclose(truth["force_noise_free_N"], sim.truth["force_noise_free_N"],
                               rtol=1e-8, atol=1e-12)


def test_format_log_without_time_or_truth_writes_what_there_is(paper_rig):
    sim = simulate("dahl", Ramp(distance_mm=0.1, rate_mm_s=1.0), rig=paper_rig, noise=QUIET,
                   name="quasi", rate_hz=100.0)
    files = format_log(sim.log.replace(time=None))
    assert list(files) == ["quasi.csv", "quasi.json"]
    lines = files["quasi.csv"].splitlines()
    assert lines[0] == "displacement_mm,force_N" and lines[1] == "0,0"
    assert lines[-1] == "0.1," + f"{sim.log.force[-1]:.9g}"


def test_cli_writes_log_sidecar_truth_and_manifest(tmp_path, capsys):
    out = tmp_path / "sim"
    code = main(["simulate", "--model", "chamber+dahl", "--set", "sigma0=35", "--set", "Fc=16",
                 "--program", "nested", "--amplitudes-mm", "0.5", "--minor-mm", "0.2,0.1",
                 "--rate-hz", "100", "--start-position-mm", "50", "--supply-bar", "4",
                 "--seed", "3", "--name", "run", "--out", str(out)])
    assert code == 0
    assert "wrote" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "run.csv", "run.json",
                                                     "run.truth.json"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["outputs"] == ["run.csv", "run.json", "run.truth.json"]
    assert manifest["seed"] == 3
    truth = json.loads((out / "run.truth.json").read_text())
    assert truth["parameters"]["sigma0"]["value"] == 35.0
    assert truth["program"]["program"] == "nested_loops"
    assert json.loads((out / "run.json").read_text())["supply_bar"] == 4.0


@pytest.mark.parametrize("args, message", [
    (["--set", "sigma=40"], "fitstiff simulate: error: parameter 'sigma': is not in this "
                            "model; use one of: n, sigma0, Fc\n"),
    (["--set", "sigma0"], "fitstiff simulate: error: --set sigma0: is not NAME=NUMBER; write "
                          "e.g. --set sigma0=40\n"),
])
def test_cli_bad_input_exits_2_with_one_line(tmp_path, capsys, args, message):
    assert main(["simulate", *args, "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err == message


# ------------------------------------------------------------------- the committed data

def _sums() -> dict[str, str]:
    lines = (SYNTHETIC / "SHA256SUMS").read_text().splitlines()
    return {path: digest for digest, path in (line.split("  ", 1) for line in lines)}


def test_committed_synthetic_files_match_their_checksums():
    sums = _sums()
    on_disk = {p.relative_to(SYNTHETIC).as_posix() for p in SYNTHETIC.rglob("*")
               if p.is_file() and p.name != "SHA256SUMS"}
    assert on_disk == set(sums), "stale or missing files: rerun data/make_synthetic.py"
    for path, digest in sums.items():
        assert hashlib.sha256((SYNTHETIC / path).read_bytes()).hexdigest() == digest, path


def test_the_generator_still_makes_the_committed_files(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("make_synthetic",
                                                  REPO / "data" / "make_synthetic.py")
    script = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, script)   # dataclasses look their module up
    spec.loader.exec_module(script)
    folder = "effects/time_delay"
    assert script.main(["--only", folder, "--out", str(tmp_path)]) == 0
    made = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert made == sorted(p for p in _sums() if p.startswith(folder + "/"))
    for path in made:
        assert (tmp_path / path).read_bytes() == (SYNTHETIC / path).read_bytes(), (
            f"{path} differs from what data/make_synthetic.py makes now: rerun it")
