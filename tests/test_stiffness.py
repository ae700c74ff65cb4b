"""Chamber stiffness calculator against closed-form values (the paper's eqs. 13-15, DESIGN §1.1).

Reference values are written out by hand from the formulas, in the style of lmfit's NIST tests:
the code under test never computes its own expectation.
"""

from __future__ import annotations

import json
import math

import pytest

from fitstiff.cli import main
from fitstiff.errors import InputError
from fitstiff.io.log import Rig
from fitstiff.physics import gas_spring
from fitstiff.physics.stiffness import (JSON_KEYS, chamber_stiffness, stiffness_table,
                                        table_positions)

# the paper's cylinder: Festo OSP-P 32 rodless, 700 mm stroke, 6 bar gauge, n = 1.4
BORE, STROKE, GAUGE, N = 0.032, 0.700, 6e5, 1.4
AMBIENT = 101_325.0
P_ABS = GAUGE + AMBIENT                      # 7.01325 bar: every law uses absolute pressure
AREA = math.pi / 4 * BORE**2                 # 804.25 mm^2
PAPER = Rig(bore=BORE, stroke=STROKE, supply_pressure=GAUGE)


def eq15(x: float, *, p: float = P_ABS, n: float = N, area: float = AREA,
         stroke: float = STROKE) -> float:
    """The paper's eq. 15, k = p n A L / (x (L - x)), N/m."""
    return p * n * area * stroke / (x * (stroke - x))


def test_eq14_relative_return_pressure_is_056_percent_at_mid_stroke():
    dx = 0.001 * STROKE                       # dx / L = 0.1 % (the paper's Fig. 3)
    expected = N * dx * STROKE / ((STROKE / 2) * (STROKE / 2))
    assert expected == pytest.approx(0.0056, rel=1e-12)
    result = chamber_stiffness(PAPER, position=STROKE / 2, displacement=dx, n=N)
    assert result.relative_return_pressure == pytest.approx(0.0056, rel=1e-12)
    # for equal closing pressures it is the linearised pressure difference across the piston
    dp = result.stiffness * dx / AREA
    assert dp / P_ABS == pytest.approx(0.0056, rel=1e-12)


def test_eq13_chamber_pressure_change_linearises_to_minus_n_p_dx_over_x():
    x, dx = 0.2, 1e-6
    result = chamber_stiffness(PAPER, position=x, displacement=dx, n=N)
    assert result.pressure_a - P_ABS == pytest.approx(-N * P_ABS * dx / x, rel=1e-5)
    assert result.pressure_b - P_ABS == pytest.approx(N * P_ABS * dx / (STROKE - x), rel=1e-5)


@pytest.mark.parametrize("x", [0.005, 0.05, 0.2, 0.35, 0.5, 0.695])
def test_eq15_equals_general_formula_for_equal_pressures_without_dead_volume(x):
    result = chamber_stiffness(PAPER, position=x, displacement=1e-4, n=N)
    assert result.stiffness == pytest.approx(eq15(x), rel=1e-12)
    assert result.force_linear == pytest.approx(eq15(x) * 1e-4, rel=1e-12)
    assert result.preload == 0.0


def test_paper_discussion_number_mid_stroke_6_bar():
    # 6 bar gauge, n = 1.4, 32 mm, 700 mm stroke, 0.5 mm at mid-stroke: 4.51 N/mm, 2.26 N
    result = chamber_stiffness(PAPER, position=0.35, displacement=0.5e-3, n=N)
    assert result.stiffness / 1e3 == pytest.approx(4.5123, abs=1e-4)
    assert result.force_linear == pytest.approx(2.2562, abs=1e-4)
    assert result.force_exact == pytest.approx(2.2562, abs=1e-4)


@pytest.mark.parametrize("x", [0.01, 0.1, 0.35, 0.6])
@pytest.mark.parametrize(("dead_a", "dead_b"), [(0.02, 0.02), (0.005, 0.04)])
def test_dead_volume_acts_as_extended_stroke(x, dead_a, dead_b):
    dx = 0.7e-3
    with_dead = chamber_stiffness(
        Rig(bore=BORE, stroke=STROKE, supply_pressure=GAUGE, dead_length_a=dead_a,
            dead_length_b=dead_b), position=x, displacement=dx, n=N)
    extended = chamber_stiffness(
        Rig(bore=BORE, stroke=STROKE + dead_a + dead_b, supply_pressure=GAUGE),
        position=x + dead_a, displacement=dx, n=N)
    without = chamber_stiffness(PAPER, position=x, displacement=dx, n=N)
    assert with_dead.relative_return_pressure == pytest.approx(
        extended.relative_return_pressure, rel=1e-12)
    assert with_dead.stiffness == pytest.approx(extended.stiffness, rel=1e-12)
    assert with_dead.force_exact == pytest.approx(extended.force_exact, rel=1e-9)
    assert with_dead.relative_return_pressure < without.relative_return_pressure
    # the closed form with the extended stroke L' = L + d_A + d_B and x' = x + d_A
    big_l, big_x = STROKE + dead_a + dead_b, x + dead_a
    assert with_dead.relative_return_pressure == pytest.approx(
        N * dx * big_l / (big_x * (big_l - big_x)), rel=1e-12)


@pytest.mark.parametrize("x", [0.01, 0.05, 0.35, 0.65, 0.69])
def test_exact_law_agrees_with_linearisation_at_1_um(x):
    result = chamber_stiffness(PAPER, position=x, displacement=1e-6, n=N)
    assert abs(result.relative_gap) < 1e-3


def test_exact_law_gap_at_5_mm_mid_stroke_is_third_order():
    # at mid-stroke the quadratic terms of both chambers cancel:
    # F_exact / F_linear - 1 = (n + 1)(n + 2) / 6 (u / l)^2 + O((u / l)^4) = 2.78e-4
    u, half = 5e-3, STROKE / 2
    result = chamber_stiffness(PAPER, position=half, displacement=u, n=N)
    assert result.relative_gap == pytest.approx((N + 1) * (N + 2) / 6 * (u / half) ** 2,
                                                rel=1e-3)
    assert result.relative_gap == pytest.approx(2.776e-4, rel=1e-3)


@pytest.mark.parametrize(("x", "gap"), [(0.05, -0.0994), (0.65, +0.1250), (0.01, -0.3757)])
def test_exact_law_gap_at_5_mm_near_the_ends(x, gap):
    # away from mid-stroke the gap is first order in u: 10-12 % at 50 mm from a cap
    u = 5e-3
    l_a, l_b = x, STROKE - x
    exact = AREA * P_ABS * ((l_b / (l_b - u)) ** N - (l_a / (l_a + u)) ** N)
    result = chamber_stiffness(PAPER, position=x, displacement=u, n=N)
    assert result.force_exact == pytest.approx(exact, rel=1e-12)
    assert result.relative_gap == pytest.approx(exact / (eq15(x) * u) - 1, rel=1e-9)
    assert result.relative_gap == pytest.approx(gap, abs=5e-4)


def test_exact_law_derivative_at_zero_is_the_linear_stiffness():
    import jax

    law = dict(p_a0=3.2e5, p_b0=7.0e5, l_a0=0.123, l_b0=0.456, n=1.3)
    areas = dict(area_a=8.0e-4, area_b=6.0e-4)
    k = jax.grad(lambda u: gas_spring.chamber_force(u, **law, **areas, p_amb=AMBIENT))(0.0)
    assert float(k) == pytest.approx(gas_spring.linear_stiffness(**law, **areas), rel=1e-12)


def test_rodded_cylinder_has_smaller_b_area_and_a_preload():
    rod = 0.012
    rig = Rig(bore=BORE, rod=rod, stroke=STROKE, supply_pressure=GAUGE)
    x = 0.3
    result = chamber_stiffness(rig, position=x, displacement=1e-4, n=N)
    area_b = math.pi / 4 * (BORE**2 - rod**2)
    assert result.rig.area_b == pytest.approx(area_b, rel=1e-12)
    assert result.stiffness == pytest.approx(N * P_ABS * (AREA / x + area_b / (STROKE - x)),
                                             rel=1e-12)
    # equal gauge pressures push harder on the full A side: hold with -A_rod * p_gauge
    assert result.preload == pytest.approx(-(math.pi / 4 * rod**2) * GAUGE, rel=1e-9)
    assert result.to_dict()["area_b_mm2"] == pytest.approx(area_b * 1e6, rel=1e-12)


def test_unequal_closing_pressures():
    p_a_gauge, p_b_gauge, x = 2e5, 5e5, 0.25
    result = chamber_stiffness(PAPER, position=x, displacement=1e-4, n=N,
                               pressure_a_gauge=p_a_gauge, pressure_b_gauge=p_b_gauge)
    p_a, p_b = p_a_gauge + AMBIENT, p_b_gauge + AMBIENT
    assert (result.pressure_a0, result.pressure_b0) == (p_a, p_b)
    assert result.stiffness == pytest.approx(N * AREA * (p_a / x + p_b / (STROKE - x)),
                                             rel=1e-12)
    assert result.preload == pytest.approx(AREA * (p_b - p_a), rel=1e-12)
    # one chamber overrides the supply, the other keeps it
    half = chamber_stiffness(PAPER, position=x, displacement=1e-4, pressure_b_gauge=p_b_gauge)
    assert (half.pressure_a0, half.pressure_b0) == (P_ABS, p_b)


def test_vented_gauge_zero_is_still_an_ambient_gas_spring():
    rig = Rig(bore=BORE, stroke=STROKE, supply_pressure=0.0)
    result = chamber_stiffness(rig, position=0.35, displacement=1e-4, n=1.0)
    assert result.stiffness == pytest.approx(eq15(0.35, p=AMBIENT, n=1.0), rel=1e-12)


def test_position_defaults_to_the_rigs_start_position():
    rig = Rig(bore=BORE, stroke=STROKE, supply_pressure=GAUGE, start_position=0.2)
    assert chamber_stiffness(rig, displacement=1e-4).stiffness == pytest.approx(eq15(0.2))


def test_table_over_the_stroke():
    rows = stiffness_table(PAPER, count=7, displacement=0.5e-3, n=N)
    positions = [row.position for row in rows]
    assert positions == pytest.approx([0.05, 0.15, 0.25, 0.35, 0.45, 0.55, 0.65], rel=1e-12)
    assert list(table_positions(STROKE, 7)) == pytest.approx(positions, rel=0)
    for row in rows:
        assert row.stiffness == pytest.approx(eq15(row.position), rel=1e-12)
    assert rows[3].stiffness == min(row.stiffness for row in rows)


def test_missing_supply_pressure_names_the_flags():
    rig = Rig(bore=BORE, stroke=STROKE)
    with pytest.raises(InputError, match=r"--supply-bar"):
        chamber_stiffness(rig, position=0.3, displacement=1e-4)
    both = chamber_stiffness(rig, position=0.3, displacement=1e-4, pressure_a_gauge=GAUGE,
                             pressure_b_gauge=GAUGE)
    assert both.stiffness == pytest.approx(eq15(0.3), rel=1e-12)


@pytest.mark.parametrize("count", [0, -3, 2.5, True])
def test_table_count_must_be_a_positive_whole_number(count):
    with pytest.raises(InputError, match=r"^number of table positions \(--table\)"):
        stiffness_table(PAPER, count=count, displacement=1e-4)


# --- command line -----------------------------------------------------------------------------

PAPER_ARGS = ["--bore-mm", "32", "--stroke-mm", "700", "--position-mm", "350",
              "--supply-bar", "6", "--n", "1.4", "--displacement-mm", "0.5"]


def run_cli(capsys, *args: str) -> tuple[int, str, str]:
    try:
        code = main(["stiffness", *args])
    except SystemExit as exc:          # argparse usage errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_json_reproduces_the_paper_number(capsys):
    code, out, err = run_cli(capsys, *PAPER_ARGS, "--json")
    assert (code, err) == (0, "")
    doc = json.loads(out)
    assert list(doc) == list(JSON_KEYS)
    assert doc["stiffness_N_per_mm"] == pytest.approx(eq15(0.35) / 1e3, rel=1e-12)
    assert doc["stiffness_N_per_mm"] == pytest.approx(4.5123, abs=1e-4)
    assert doc["force_linear_N"] == pytest.approx(2.2562, abs=1e-4)
    assert doc["force_exact_N"] == pytest.approx(2.2562, abs=1e-4)
    assert doc["relative_gap"] == pytest.approx(2.78e-6, rel=1e-2)
    assert doc["relative_return_pressure"] == pytest.approx(1.4 * 0.5 * (2 / 350), rel=1e-12)
    assert (doc["pressure_a_bar"], doc["pressure_b_bar"]) == (6.0, 6.0)
    assert (doc["stroke_mm"], doc["position_mm"], doc["bore_mm"]) == (700.0, 350.0, 32.0)


def test_cli_text_output(capsys):
    code, out, _ = run_cli(capsys, *PAPER_ARGS)
    assert code == 0
    assert "linearised stiffness             4.512 N/mm" in out
    assert "restoring force, exact           2.256 N" in out


def test_cli_table_and_out_dir(capsys, tmp_path):
    code, out, _ = run_cli(capsys, "--bore-mm", "32", "--stroke-mm", "700", "--supply-bar",
                           "6", "--table", "5", "--json", "--out", str(tmp_path / "res"))
    assert code == 0
    doc = json.loads(out)
    assert [row["position_mm"] for row in doc["table"]] == pytest.approx([70, 210, 350, 490,
                                                                          630])
    assert json.loads((tmp_path / "res" / "stiffness.json").read_text()) == doc
    manifest = json.loads((tmp_path / "res" / "manifest.json").read_text())
    assert manifest["outputs"] == ["stiffness.json"]
    code, out, _ = run_cli(capsys, "--bore-mm", "32", "--stroke-mm", "700", "--supply-bar", "6",
                           "--table")
    assert code == 0 and len(out.strip().splitlines()) == 3 + 1 + 1 + 7


def test_cli_position_defaults_to_mid_stroke(capsys):
    code, out, _ = run_cli(capsys, "--bore-mm", "32", "--stroke-mm", "700", "--supply-bar", "6",
                           "--json")
    assert code == 0 and json.loads(out)["position_mm"] == 350.0


BASE = ["--bore-mm", "32", "--stroke-mm", "700", "--supply-bar", "6"]


@pytest.mark.parametrize(("args", "fragment"), [
    (["--bore-mm", "0"], "bore (--bore-mm): found 0 mm; give a positive piston diameter"),
    (["--stroke-mm", "-700"], "stroke (--stroke-mm): found -700 mm"),
    (["--rod-mm", "32"], "rod diameter (--rod-mm): found 32 mm with a 32 mm bore"),
    (["--dead-length-b-mm", "-1"], "dead length of chamber B (--dead-length-b-mm)"),
    (["--position-mm", "701"], "closing position (--position-mm): found 701 mm, outside the "
                               "stroke 0..700 mm; give the length of chamber A within the stroke"),
    (["--position-mm", "0"], "closing position (--position-mm): 0 mm leaves chamber A with no "
                             "volume"),
    (["--displacement-mm", "0"], "displacement (--displacement-mm): found 0"),
    (["--position-mm", "690", "--displacement-mm", "20"],
     "displacement (--displacement-mm): 20 mm from 690 mm moves the piston to 710 mm"),
    (["--n", "2"], "polytropic exponent (--n): found 2; give a value from 1 (isothermal) to "
                   "1.67 (adiabatic; 1.4 for air)"),
    (["--n", "nan"], "argument --n: found 'nan', not a plain decimal number"),
    (["--supply-bar", "-1.5"], "closing pressure of chamber A (--supply-bar): found -1.5 bar "
                               "gauge, at or below vacuum (ambient 1.01325 bar); give a gauge "
                               "pressure above -1.01325 bar"),
    (["--pressure-b-bar", "-2"], "closing pressure of chamber B (--pressure-b-bar)"),
    (["--ambient-bar", "0"], "ambient pressure (--ambient-bar): found 0 bar"),
    (["--table", "0"], "number of table positions (--table): found 0"),
    (["--bore-mm", "abc"], "argument --bore-mm: found 'abc', not a plain decimal number"),
    (["--bore-mm", "1_000"], "argument --bore-mm: found '1_000', not a plain decimal number"),
    (["--bore-mm", "1e300"], "--bore-mm: found 1e+300 mm, outside the plausible range (at most "
                             "1000 mm); give the piston bore diameter in mm"),
    (["--supply-bar", "1e300"], "--supply-bar: found 1e+300 bar, outside"),
    (["--pressure-b-bar", "1e300"], "--pressure-b-bar: found 1e+300 bar, outside"),
    (["--table", "3", "--position-mm", "3"], "not allowed with argument"),
])
def test_cli_bad_input_is_one_line_and_exit_2(capsys, args, fragment):
    code, out, err = run_cli(capsys, *BASE, *args)
    assert code == 2
    assert out == ""
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert fragment in err


def test_cli_missing_required_flag(capsys):
    code, _, err = run_cli(capsys, "--bore-mm", "32")
    assert code == 2 and "--stroke-mm" in err and len(err.splitlines()) == 1


def test_cli_missing_pressure_message_is_pinned(capsys):
    code, _, err = run_cli(capsys, "--bore-mm", "32", "--stroke-mm", "700")
    assert code == 2
    assert err == ("fitstiff stiffness: error: closing pressure of chamber A (--supply-bar or "
                   "--pressure-a-bar): is missing; give --supply-bar (gauge), or both "
                   "--pressure-a-bar and --pressure-b-bar\n")
