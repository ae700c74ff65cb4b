"""Loading logs: SI conversion, metadata layering, and one pinned message per bad input."""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fitstiff.cli.common import add_log_arguments, add_out_argument, logs_from_args
from fitstiff.errors import InputError
from fitstiff.io.columns import match_header
from fitstiff.io.loading import load_log, load_logs
from fitstiff.io.log import STANDARD_AMBIENT_PA
from fitstiff.units import parse_unit

HEADER = "time_s,displacement_mm,force_N,p_a_bar"
N_ROWS = 12


def good_lines(n: int = N_ROWS, header: str = HEADER) -> list[str]:
    """A canonical log: time 0, 0.1 ... s; displacement 0, 0.01 ... mm; force i + 0.5 N; 6 bar."""
    return [header] + [f"{0.1 * i:.1f},{0.01 * i:.2f},{i}.5,6" for i in range(n)]


def with_line(lines: list[str], number: int, text: str) -> list[str]:
    """``lines`` with (1-based) line ``number`` replaced."""
    out = list(lines)
    out[number - 1] = text
    return out


def write(directory: Path, lines: list[str] | str | bytes, *, name: str = "run1.csv",
          sidecar: object = None, eol: str = "\n", bom: bool = False) -> Path:
    """Write a log (and its sidecar ``<stem>.json`` if given: a dict, or raw text)."""
    path = directory / name
    if isinstance(lines, bytes):
        data = lines
    else:
        text = lines if isinstance(lines, str) else eol.join(lines) + eol
        data = (b"\xef\xbb\xbf" if bom else b"") + text.encode()
    path.write_bytes(data)
    if sidecar is not None:
        side = sidecar if isinstance(sidecar, str) else json.dumps(sidecar)
        path.with_suffix(".json").write_text(side)
    return path


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def error_message(path: Path, **options) -> str:
    """The one-line InputError message of loading ``path``; the file stays unchanged."""
    before = sha256(path)
    with pytest.raises(InputError) as info:
        load_log(path, **options)
    assert sha256(path) == before
    message = str(info.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------ good files

def test_canonical_log_in_si(tmp_path):
    path = write(tmp_path, [good_lines()[0] + ",volts"] + [f"{r},3.3" for r in good_lines()[1:]],
                 sidecar={"bore_mm": 32})
    log = load_log(path)
    assert log.name == "run1" and len(log) == N_ROWS
    np.testing.assert_allclose(log.time, 0.1 * np.arange(N_ROWS))
    np.testing.assert_allclose(log.displacement, 1e-5 * np.arange(N_ROWS))
    np.testing.assert_allclose(log.force, np.arange(N_ROWS) + 0.5)
    np.testing.assert_allclose(log.pressure_a, 6e5 + STANDARD_AMBIENT_PA)
    assert log.pressure_b is None
    assert log.rig.bore == pytest.approx(0.032)
    source = log.source
    assert source["sha256"] == sha256(path)
    assert source["path"] == str(path) and source["header"] is True
    assert source["delimiter"] == "','"
    assert source["ignored_columns"] == ["volts"]
    assert source["columns"]["time"] == {"column": 1, "name": "time_s", "unit": "s",
                                         "absolute": False, "flip": False, "scale": 1.0}
    assert source["columns"]["displacement"]["scale"] == pytest.approx(1e-3)
    assert source["sidecar"] == str(path.with_suffix(".json"))


def test_one_logged_pressure_means_the_other_chamber_is_vented(tmp_path):
    log = load_log(write(tmp_path, good_lines()))
    assert log.vented == {"b"}
    assert len(log.notes) == 1 and "chamber B is taken as vented" in log.notes[0]
    np.testing.assert_array_equal(log.gauge("b"), 0.0)


def test_declared_vented_chamber_gives_no_note(tmp_path):
    log = load_log(write(tmp_path, good_lines(), sidecar={"vented": ["b"]}))
    assert log.vented == {"b"} and log.notes == ()


def test_log_without_time_is_quasi_static(tmp_path):
    lines = [line.split(",", 1)[1] for line in good_lines()]
    log = load_log(write(tmp_path, lines, sidecar={"vented": ["b"]}))
    assert log.time is None
    assert log.notes == ("no time column: treated as quasi-static",)


def test_bom_and_crlf_read_like_plain_text(tmp_path):
    plain = load_log(write(tmp_path, good_lines(), name="plain.csv"))
    for name, eol in (("crlf.csv", "\r\n"), ("cr.csv", "\r")):
        odd = load_log(write(tmp_path, good_lines(), name=name, eol=eol, bom=True))
        for field in ("time", "displacement", "force", "pressure_a"):
            np.testing.assert_array_equal(getattr(odd, field), getattr(plain, field))
        assert odd.source["columns"]["time"]["name"] == "time_s"  # BOM not glued to the name


@pytest.mark.parametrize("delimiter, expected",
                         [(";", "';'"), ("\t", "tab"), ("   ", "whitespace")])
def test_delimiter_detected(tmp_path, delimiter, expected):
    log = load_log(write(tmp_path, [line.replace(",", delimiter) for line in good_lines()]))
    assert log.source["delimiter"] == expected
    np.testing.assert_allclose(log.force, np.arange(N_ROWS) + 0.5)


@pytest.mark.parametrize("column, cell, attribute, expected", [
    ("time_ms", "1500", "time", 1.5),
    ("time_min", "2", "time", 120.0),
    ("displacement_um", "250", "displacement", 250e-6),
    ("displacement_inch", "2", "displacement", 0.0508),
    ("displacement_in", "1", "displacement", 0.0254),
    ("displacement_m", "0.25", "displacement", 0.25),
    ("force_mN", "1500", "force", 1.5),
    ("force_kN", "2", "force", 2000.0),
    ("force_lbf", "1", "force", 4.4482216152605),
    ("p_a_psi", "14.5", "pressure_a", 14.5 * 6894.757293168361 + STANDARD_AMBIENT_PA),
    ("p_a_kPa", "600", "pressure_a", 600e3 + STANDARD_AMBIENT_PA),
    ("p_a_MPa", "0.6", "pressure_a", 0.6e6 + STANDARD_AMBIENT_PA),
    ("p_b_mbar_abs", "1013.25", "pressure_b", 101325.0),
    ("p_b_Pa_abs", "5e5", "pressure_b", 5e5),
])
def test_units_convert_to_si(tmp_path, column, cell, attribute, expected):
    quantity, _ = match_header(column)
    names = {"time": "time_s", "displacement": "displacement_mm", "force": "force_N",
             quantity: column}
    lines = [",".join(names.values())]
    for i in range(N_ROWS):
        row = {"time": str(i), "displacement": "0", "force": "0", quantity: cell}
        if quantity == "time":  # must increase: cell, 2 * cell, ...
            row["time"] = repr(float(cell) * (i + 1))
        lines.append(",".join(row[q] for q in names))
    log = load_log(write(tmp_path, lines))
    assert getattr(log, attribute)[0] == pytest.approx(expected, rel=1e-12)


def test_gauge_pressure_uses_the_sidecar_ambient(tmp_path):
    lines = [HEADER + ",p_b_bar_abs"] + [f"{line},7" for line in good_lines()[1:]]
    log = load_log(write(tmp_path, lines, sidecar={"ambient_bar": 0.95}))
    np.testing.assert_allclose(log.pressure_a, 6.95e5)   # gauge + ambient
    np.testing.assert_allclose(log.pressure_b, 7e5)      # absolute as logged
    np.testing.assert_allclose(log.gauge("b"), 6.05e5)
    assert log.notes == ()


def test_overrides_beat_sidecar_beats_format(tmp_path):
    fmt = tmp_path / "fmt.json"
    fmt.write_text(json.dumps({"rig": {"bore_mm": 25, "rod_mm": 10, "stroke_mm": 100},
                               "vented": ["a"]}))
    path = write(tmp_path, good_lines(), sidecar={"bore_mm": 32, "stroke_mm": 200,
                                                  "vented": ["b"], "_note": "a comment"})
    log = load_log(path, fmt=fmt, rig_overrides={"stroke_mm": 300, "load_kg": None})
    assert (log.rig.bore, log.rig.rod, log.rig.stroke) == pytest.approx((0.032, 0.010, 0.3))
    assert log.rig.load_mass is None
    assert log.vented == {"b"}
    assert load_log(path, rig_overrides={"vented": ["a", "b"]}).vented == {"a", "b"}


def test_missing_metadata_names_the_sidecar_and_the_flag(tmp_path):
    log = load_log(write(tmp_path, good_lines()))
    with pytest.raises(InputError, match=r"run1\.json.*stroke_mm.*--stroke-mm"):
        log.rig.require("stroke", needed_for="the chamber model")


def test_format_file_with_command_line_override(tmp_path):
    lines = [f"{i * 10}\t9.9\t{-0.01 * i:.2f}\t{2 * i}" for i in range(N_ROWS)]
    path = write(tmp_path, lines, name="foreign.txt")
    fmt = tmp_path / "rig.json"
    fmt.write_text(json.dumps({
        "_comment": "time ms, raw volts, position mm (opposite sign), force in units of 0.5 N",
        "no_header": True, "delimiter": "tab", "vented": ["a", "b"], "rig": {"bore_mm": 40},
        "columns": ["time=1:ms", "displacement=3:mm:flip",
                    {"quantity": "force", "column": 4, "unit": "N", "scale": 0.5}],
    }))
    log = load_log(path, fmt=fmt)
    np.testing.assert_allclose(log.time, 0.01 * np.arange(N_ROWS))
    np.testing.assert_allclose(log.displacement, 1e-5 * np.arange(N_ROWS))
    np.testing.assert_allclose(log.force, np.arange(N_ROWS))
    assert log.rig.bore == pytest.approx(0.04) and log.vented == {"a", "b"}
    assert log.source["ignored_columns"] == [2] and log.source["format"] == str(fmt)
    flipped = load_log(path, fmt=fmt, columns=["force=4:kN:flip"])  # overrides force only
    np.testing.assert_allclose(flipped.force, -2000.0 * np.arange(N_ROWS))
    np.testing.assert_allclose(flipped.displacement, log.displacement)


def test_bundled_format_by_name(tmp_path):
    lines = [f"{i * 10}\t0\t0\t0\t{0.1 * i:.1f}\t3\t{150 + i}" for i in range(N_ROWS)]
    log = load_log(write(tmp_path, lines, name="O-ring_3bar.csv"), fmt="zillen_oring")
    np.testing.assert_allclose(log.displacement, -1e-4 * np.arange(N_ROWS))
    np.testing.assert_allclose(log.force, -(150.0 + np.arange(N_ROWS)))
    np.testing.assert_allclose(log.gauge("a"), 3e5)
    assert log.vented == {"b"} and log.rig.bore == pytest.approx(0.025)
    assert log.rig.stroke is None


def test_load_logs_reads_every_file(tmp_path):
    paths = [write(tmp_path, with_line(good_lines(), 2, f"0.0,0.00,{i}.25,6"),
                   name=f"run{i}.csv") for i in range(3)]
    assert [log.name for log in load_logs(paths)] == ["run0", "run1", "run2"]
    with pytest.raises(InputError, match="log files: none given"):
        load_logs([])


def test_a_log_given_twice_is_refused_naming_both(tmp_path):
    """Issue 36: the same file, or the same content, twice would count its data twice."""
    one = write(tmp_path, good_lines(), name="one.csv")
    two = write(tmp_path, good_lines(), name="two.csv")
    with pytest.raises(InputError, match=f"{one}: log: is the same file as {one}"):
        load_logs([one, one])
    with pytest.raises(InputError, match=f"{two}: log: has the same content as {one}"):
        load_logs([one, two])


# ------------------------------------------------------------------------------- bad files

def header(text: str) -> list[str]:
    return with_line(good_lines(), 1, text)


def cell(line: int, column: int, text: str, *, sep: str = ",") -> list[str]:
    """``good_lines`` separated by ``sep``, with one cell replaced."""
    lines = [line.replace(",", sep) for line in good_lines()]
    cells = lines[line - 1].split(sep)
    cells[column - 1] = text
    return with_line(lines, line, sep.join(cells))


BAD = {
    # id: (lines, options, sidecar, fragments that must appear)
    "missing displacement": (header("time_s,position,force_N,p_a_bar"), {}, None,
                             ["header", "no displacement column", "position",
                              "displacement_mm", "--columns"]),
    "missing force": (header("time_s,displacement_mm,load_N,p_a_bar"), {}, None,
                      ["no force column", "force_N"]),
    "no unit suffix": (header("time,displacement_mm,force_N,p_a_bar"), {}, None,
                       ["column 1 'time'", "no unit suffix", "time_s"]),
    "same quantity twice": (header("time_s,displacement_mm,force_N,displacement_m"), {}, None,
                            ["column 2 'displacement_mm' and column 4 'displacement_m'",
                             "both hold displacement", "keep one"]),
    "duplicate header name": (header("time_s,force_N,displacement_mm,force_N"), {}, None,
                              ["columns 2 and 4 are both named 'force_N'", "rename or delete"]),
    "non-numeric": (cell(5, 3, "abc"), {}, None,
                    ["line 5, column 3 'force_N'", "found 'abc'", "make every cell"]),
    "decimal comma": (cell(4, 3, "1,5", sep=";"), {}, None,
                      ["line 4, column 3 'force_N'", "'1,5'", "decimal point"]),
    "nan": (cell(7, 2, "nan"), {}, None,
            ["line 7, column 2 'displacement_mm'", "'nan'", "not a finite number"]),
    "inf": (cell(3, 3, "-inf"), {}, None, ["line 3, column 3 'force_N'", "'-inf'",
                                            "not a finite number"]),
    "empty cell": (cell(6, 3, ""), {}, None,
                   ["line 6, column 3 'force_N'", "the cell is empty", "fill it in"]),
    "time goes back": (cell(8, 1, "0.1"), {}, None,
                       ["line 8, column 1 'time_s'", "'0.5' on line 7", "'0.1' on line 8",
                        "increase strictly"]),
    "time repeats": (cell(8, 1, "0.5"), {}, None,
                     ["line 8, column 1 'time_s'", "'0.5' on line 7", "'0.5' on line 8"]),
    "too few samples": (good_lines(5), {}, None, ["has 5 data rows", "at least 10"]),
    "unknown unit": (header("time_s,displacement_mm,force_Nx,p_a_bar"), {}, None,
                     ["column 3 'force_Nx'", "unknown unit 'Nx'", "N, mN, kN, lbf"]),
    "wrong dimension": (header("time_s,displacement_N,force_N,p_a_bar"), {}, None,
                        ["column 2 'displacement_N'", "not a length unit", "mm"]),
    "unit case": (header("time_s,displacement_mm,force_N,p_a_kpa"), {}, None,
                  ["column 4 'p_a_kpa'", "did you mean 'kPa'", "_abs"]),
    "gauge below vacuum": (cell(4, 4, "-1.5"), {}, None,
                           ["line 4, column 4 'p_a_bar'", "'-1.5' (gauge)", "below vacuum",
                            "_abs", "--ambient-bar"]),
    "absolute below vacuum": (with_line(header("time_s,displacement_mm,force_N,p_a_bar_abs"),
                                        9, "0.7,0.07,7.5,-0.2"), {}, None,
                              ["line 9, column 4 'p_a_bar_abs'", "(absolute)", "below vacuum"]),
    "beyond stroke": (good_lines(), {}, {"stroke_mm": 100, "start_position_mm": 99.955},
                      ["line 7, column 2 'displacement_mm'", "'0.05'", "100 mm",
                       "outside the stroke 0..100 mm", "--stroke-mm", "--start-position-mm"]),
    "before the A cap": (cell(3, 2, "-0.01"), {}, {"start_position_mm": 0, "stroke_mm": 50},
                         ["line 3, column 2 'displacement_mm'", "'-0.01'", "outside the stroke"]),
    "empty file": ("", {}, None, ["file", "is empty"]),
    "blank file": ("\n  \r\n", {}, None, ["file", "is empty"]),
    "header only": (good_lines(0), {}, None, ["has a header row but no data rows"]),
    "comma for semicolons": ([line.replace(",", ";") for line in good_lines()],
                             {"delimiter": ","}, None,
                             ["line 1", "single column", "pass --delimiter ';'"]),
    "semicolon for tabs": ([line.replace(",", "\t") for line in good_lines()],
                           {"delimiter": ";"}, None, ["line 1", "pass --delimiter tab"]),
    "pipes": ([line.replace(",", "|") for line in good_lines()], {}, None,
              ["line 1", "single column", "pass --delimiter '|'"]),
    "blank line inside": (with_line(good_lines(), 6, " "), {}, None,
                          ["line 6", "is blank", "remove blank lines"]),
    "ragged row": (with_line(good_lines(), 4, "0.2,0.02,2.5"), {}, None,
                   ["line 4", "has 3 fields, expected 4", "check the delimiter"]),
    "data where the header should be": (good_lines()[1:], {}, None,
                                        ["line 1", "looks like data", "--no-header"]),
    "header with --no-header": (good_lines(), {"no_header": True, "columns": [
        "time=1:s", "displacement=2:mm", "force=3:N"]}, None,
        ["line 1, column 1", "found 'time_s'", "drop --no-header"]),
    "no header, no mapping": (good_lines()[1:], {"no_header": True}, None,
                              ["columns", "no column mapping", "--columns", "--format"]),
    "mapped column out of range": (good_lines(), {"columns": ["displacement=2:mm",
                                                              "force=9:N"]}, None,
                                   ["column mapping entry 'force=9:N'", "has 4 columns",
                                    "from 1 to 4"]),
    "mapped name absent": (good_lines(), {"columns": ["displacement=2:mm", "force=load:N"]},
                           None, ["entry 'force=load:N'", "no column 'load'", "time_s"]),
    "mapped name without header": (good_lines()[1:], {"no_header": True, "columns": [
        "displacement=2:mm", "force=force_N:N"]}, None,
        ["entry 'force=force_N:N'", "no header", "1-based number"]),
    "mapping without force": (good_lines(), {"columns": ["displacement=2:mm"]}, None,
                              ["column mapping", "no force entry", "force=COLUMN:UNIT"]),
    "column mapped twice": (good_lines(), {"columns": ["displacement=2:mm", "force=2:N"]},
                            None, ["entry 'force=2:N'", "column 2 'displacement_mm'",
                                   "already mapped by 'displacement=2:mm'"]),
    "not UTF-8": (b"time_s,displacement_\xb5m,force_N\n", {}, None,
                  ["line 1", "0xb5 is not UTF-8", "save the file as UTF-8"]),
    "sidecar key": (good_lines(), {}, {"bore": 32},
                    ["run1.json", "key 'bore'", "not a rig metadata key", "bore_mm"]),
    "sidecar value": (good_lines(), {}, {"bore_mm": "wide"},
                      ["run1.json", "key 'bore_mm'", "'wide'", "give a number"]),
    "sidecar vented": (good_lines(), {}, {"vented": ["c"]},
                       ["run1.json", "key 'vented'", "['c']", '["b"]']),
    "sidecar JSON": (good_lines(), {}, '{"bore_mm": 32,\n "stroke_mm": }',
                     ["run1.json", "line 2, column 15", "malformed JSON", "fix the JSON"]),
    "sidecar not an object": (good_lines(), {}, "[32]",
                              ["run1.json", "JSON list, not an object", "bore_mm"]),
}


@pytest.mark.parametrize("lines, options, sidecar, fragments", BAD.values(), ids=BAD.keys())
def test_bad_input_gives_one_clear_message(tmp_path, lines, options, sidecar, fragments):
    message = error_message(write(tmp_path, lines, sidecar=sidecar), **options)
    assert "run1." in message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_bad_override_names_the_command_line(tmp_path):
    message = error_message(write(tmp_path, good_lines()), rig_overrides={"bore_mm": -3})
    assert message == ("command-line overrides: key 'bore_mm' (--bore-mm): found -3 mm, "
                       "outside the plausible range (from 1 to 1000 mm); give the piston bore "
                       "diameter in mm (check the unit and the decimal point)")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: file: cannot be read.*check the path"):
        load_log(tmp_path / "nope.csv")


@pytest.mark.parametrize("kind, unit, scale, absolute", [
    ("time", "us", 1e-6, False), ("length", "µm", 1e-6, False), ("force", "kgf", 9.80665, False),
    ("pressure", "psi_abs", 6894.757293168361, True), ("pressure", "atm", 101325.0, False),
])
def test_parse_unit(kind, unit, scale, absolute):
    spec = parse_unit(kind, unit)
    assert spec.scale == pytest.approx(scale, rel=1e-12) and spec.absolute is absolute


@pytest.mark.parametrize("kind, unit, fragment", [
    ("pressure", "pa", "not a pressure unit"),     # pint: picoyear
    ("length", "mil", "not a length unit"),        # pint: per mille
    ("force", "N_abs", "unknown unit 'N_abs'"),    # _abs only for pressures
    ("time", "", "has no unit"),
    ("force", "2*N", "unknown unit"),
])
def test_parse_unit_rejects(kind, unit, fragment):
    with pytest.raises(InputError, match="where: what") as info:
        parse_unit(kind, unit, where="where", what="what")
    assert fragment in str(info.value)


# --------------------------------------------------------------------------- command line

def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_log_arguments(parser)
    add_out_argument(parser)
    return parser.parse_args(argv)


def test_log_arguments_reach_the_loader(tmp_path):
    path = write(tmp_path, good_lines(), sidecar={"bore_mm": 32, "stroke_mm": 200})
    args = parse([str(path), "--stroke-mm", "300", "--supply-bar", "6", "--vented", "b",
                  "--columns", "displacement=2:mm", "force=3:N:flip", "--out", "res"])
    [log] = logs_from_args(args)
    assert args.out == Path("res")
    assert (log.rig.bore, log.rig.stroke, log.rig.supply_pressure) == pytest.approx(
        (0.032, 0.3, 6e5))
    assert log.vented == {"b"} and log.time is None and log.pressure_a is None
    np.testing.assert_allclose(log.force, -(np.arange(N_ROWS) + 0.5))


def test_log_file_after_columns_is_explained(tmp_path):
    with pytest.raises(InputError, match="'run1.csv'.*put the log files before --columns"):
        load_log(write(tmp_path, good_lines()), columns=["force=3:N", "run1.csv"])


HAS_INSPECT = importlib.util.find_spec("fitstiff.cli.inspect") is not None
needs_inspect = pytest.mark.skipif(
    not HAS_INSPECT, reason="fitstiff.cli.inspect is not written yet (a colleague's module); "
                            "the CLI error path is tested through it")


def run_cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fitstiff", *argv], capture_output=True,
                          text=True, timeout=120)


CLI_BAD = {
    "non-numeric": (cell(5, 3, "abc"), [], None, "line 5, column 3 'force_N'"),
    "mapping entry": (good_lines(), ["--columns", "force=3"], None,
                      "column mapping entry 'force=3'"),
    "unknown format": (good_lines(), ["--format", "no_such_format"], None,
                       "neither a file nor a bundled format"),
    "sidecar JSON": (good_lines(), [], "{", "malformed JSON"),
    "bad flag value": (good_lines(), ["--ambient-bar", "-7"], None, "ambient_bar"),
}


@needs_inspect
@pytest.mark.parametrize("lines, argv, sidecar, fragment", CLI_BAD.values(), ids=CLI_BAD.keys())
def test_cli_bad_input_exits_2_with_one_line(tmp_path, lines, argv, sidecar, fragment):
    path = write(tmp_path, lines, sidecar=sidecar)
    before = {p: sha256(p) for p in tmp_path.iterdir()}
    result = run_cli("inspect", str(path), *argv)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert fragment in result.stderr
    assert {p: sha256(p) for p in tmp_path.iterdir()} == before


@needs_inspect
def test_cli_reads_a_good_log(tmp_path):
    result = run_cli("inspect", str(write(tmp_path, good_lines())))
    assert result.returncode == 0, result.stderr


# ------------------------------------------------------------------ spikes and force scale

FIG4_LOG = Path(__file__).resolve().parents[1] / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"


def _edited(tmp_path, edit) -> Path:
    lines = FIG4_LOG.read_text().splitlines()
    lines = edit(lines)
    path = tmp_path / "log.csv"
    path.write_text("\n".join(lines) + "\n")
    (tmp_path / "log.json").write_text(FIG4_LOG.with_suffix(".json").read_text())
    return path


def test_a_spike_is_named_at_load_and_in_the_fit(tmp_path):
    """Issue 36: one legal 1e6 N force sample gave 'converged', Fc = 23 730 N and warnings
    that never named it. The loader names it (sample, line, size against the noise); a fit
    through it repeats that among its warnings."""
    def spike(lines):
        cells = lines[815].split(",")
        cells[2] = "1e6"                                 # force_N of sample 814 (line 816)
        lines[815] = ",".join(cells)
        return lines

    log = load_log(_edited(tmp_path, spike))
    [note] = [n for n in log.notes if "spike" in n]
    assert note.startswith("force: 1 spike: sample 814 (line 816) is 1e+06 N, ")
    assert "times the noise floor" in note and note.endswith("is not to be trusted")
    assert not [n for n in log.notes if "reaches" in n]     # the scale check leaves it out

    from fitstiff.inference.fitting import fit

    result = fit([log], "chamber+dahl")
    assert f"log: {note}" in result.warnings


def test_a_force_in_the_wrong_unit_is_named(tmp_path):
    """Issue 36: force_N relabelled force_kN fitted 'converged', Fc = 23 446 N on a 32 mm
    bore (p A is about 480 N at 6 bar), identifiable: yes."""
    log = load_log(_edited(tmp_path, lambda lines: [lines[0].replace("force_N", "force_kN"),
                                                    *lines[1:]]))
    [note] = [n for n in log.notes if "reaches" in n]
    assert note.startswith("force: reaches 2.241e+04 N, 46 times what the supply pressure "
                           "holds on the piston (p A = 482.5 N at 6 bar on a 32 mm bore)")


def test_the_bundled_and_real_logs_have_no_spike_or_scale_note():
    """The screens catch gross errors only: no note on any bundled log (sharp reversals,
    fast rates, pauses) or on the real O-ring logs where they are present."""
    from conftest import REALDATA

    repo = FIG4_LOG.parents[3]
    paths = sorted((repo / "data" / "synthetic").rglob("*.csv"))
    assert len(paths) > 20
    for log in load_logs(paths):
        assert not [n for n in log.notes if "spike" in n or "reaches" in n], log.name
    real = sorted(REALDATA.glob("O-ring_*bar.csv"))
    for log in (load_logs(real, fmt="zillen_oring") if real else []):
        assert not [n for n in log.notes if "spike" in n or "reaches" in n], log.name


# ------------------------------------------------------- clean files, read without their lines
def _channels(log):
    return [None if a is None else np.asarray(a) for a in
            (log.time, log.displacement, log.force, log.pressure_a, log.pressure_b)]


@pytest.mark.parametrize("variant", ["plain", "crlf", "bom", "tab", "semicolon", "blanks",
                                     "trailing blank lines", "text column", "no header"])
def test_a_clean_file_reads_as_the_same_file_read_line_by_line(tmp_path, variant):
    """A clean file (one delimiter, plain ASCII, no quotes) is parsed straight from its bytes;
    the same rows with a quoted cell in an unused column go through csv line by line. Both
    give the same numbers to the bit (those of float() on each cell), rows and notes."""
    rng = np.random.default_rng(3)
    values = rng.normal(size=(400, 3)) * [0.3, 20.0, 0.4] + [0.0, 0.0, 6.0]
    cells = [[f"{0.001 * i:.3f}", repr(float(d)), f"{f:.9e}", f"{p:.17g}"]
             for i, (d, f, p) in enumerate(values)]
    header = ["time_s", "displacement_mm", "force_N", "p_a_bar"]
    delimiter, eol, options = ",", "\n", {}
    if variant == "tab":
        delimiter = "\t"
    if variant == "semicolon":
        delimiter = ";"
    if variant == "crlf":
        eol = "\r\n"
    if variant == "blanks":
        cells = [[f" {c}  " if k % 2 else f"+{c}" if c[0] != "-" else c for k, c in
                  enumerate(row)] for row in cells]
    if variant == "text column":
        header.append("comment")
        cells = [row + [f"step {i}"] for i, row in enumerate(cells)]
    if variant == "no header":
        options = {"columns": ["time=1:s", "displacement=2:mm", "force=3:N", "p_a=4:bar"],
                   "no_header": True}

    def text(rows):
        lines = ([] if variant == "no header" else [delimiter.join(header)])
        lines += [delimiter.join(row) for row in rows]
        return eol.join(lines) + eol + ("\n \n\n" if variant == "trailing blank lines" else "")

    clean = write(tmp_path, text(cells), name="clean.csv", bom=variant == "bom")
    quoted_rows = [row + ['"q"'] for row in cells] if variant != "text column" else [
        row[:-1] + ['"q"'] for row in cells]
    if variant != "text column" and variant != "no header":
        header.append("comment")
    quoted = write(tmp_path, text(quoted_rows), name="quoted.csv", bom=variant == "bom")
    a, b = load_log(clean, **options), load_log(quoted, **options)
    for x, y in zip(_channels(a), _channels(b)):
        assert (x is None and y is None) or np.array_equal(x, y)
    assert a.source["rows"] == b.source["rows"] == 400
    assert a.notes == b.notes
    expected = np.array([float(row[2]) for row in cells])
    assert np.array_equal(np.asarray(a.force), expected)


@pytest.mark.parametrize("cell, found", [
    ("nan", "found 'nan', not a finite number"),
    ("1e999", "found '1e999', not a finite number"),
    ("1_000", "found '1_000', not a plain decimal number"),
    ("", "the cell is empty"),
    ("12,5", None),
])
def test_a_bad_cell_deep_in_a_clean_file_is_named_by_its_line(tmp_path, cell, found):
    """A file clean but for one cell of a used column deep down: the line-by-line reader
    names that cell (line and column), as for any file."""
    lines = good_lines(3000)
    row = lines[2500].split(",")
    row[2] = cell
    lines[2500] = ",".join(row)
    message = error_message(write(tmp_path, lines))
    if found is None:       # a decimal comma splits the row: one cell too many
        assert "line 2501: has 5 fields, expected 4" in message
    else:
        assert "line 2501, column 3 'force_N'" in message and found in message


@pytest.mark.slow
@pytest.mark.parametrize("eol", ["\n", "\r\n"])
def test_a_clean_file_larger_than_a_block_reads_whole(tmp_path, eol):
    """A clean file longer than the reader's 16 MB block (a row end falls anywhere in
    it): every row once, the numbers of float() on each cell, the file's digest."""
    rng = np.random.default_rng(5)
    n = 420_000
    force = rng.normal(size=n) * 30
    lines = ["time_s,displacement_mm,force_N,p_a_bar,p_b_bar"] + [
        f"{0.0001 * i:.4f},{0.001 * np.sin(i / 5000):.12f},{float(f)!r},6.{i % 10},5.5"
        for i, f in enumerate(force)]
    path = write(tmp_path, lines, eol=eol)
    assert path.stat().st_size > 16 * 2**20
    log = load_log(path)
    assert log.source["rows"] == n and log.source["sha256"] == sha256(path)
    assert np.array_equal(np.asarray(log.force), force)
    assert np.array_equal(np.asarray(log.time), [float(f"{0.0001 * i:.4f}") for i in range(n)])
