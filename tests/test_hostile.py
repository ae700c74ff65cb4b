"""Hostile and extreme inputs through ``inspect``, ``fit`` and ``posterior`` (issue 15).

A corpus of malformed or extreme logs, sidecars, format files, file types and command-line
values, each a tiny variation of one synthetic log. Every case either loads correctly (exit 0
from ``inspect``) or gives exit code 2 with one line that names the place and the fix; never a
traceback, never a hang, and every input file stays byte-identical. The commands run in
process (``fitstiff.cli.main``), with an alarm that turns a hang into a failure; one
subprocess run checks the real process on a named pipe.

Below the corpus: the numerical guards (a non-finite fit, a non-finite result document, a
floating-point warning in a command) and the library-level regressions of the issue.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO

from fitstiff.cli import main
from fitstiff.errors import InputError

FIG4 = REPO / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"
BASE_LINES = FIG4.read_text().splitlines()          # time_s, displacement_mm, force_N, p_a, p_b
BASE_SIDECAR = json.loads(FIG4.with_suffix(".json").read_text())
HANG_SECONDS = 30


# ------------------------------------------------------------------------------ builders

def text(lines: list[str]) -> bytes:
    return ("\n".join(lines) + "\n").encode()


def cell(line: int, column: int, value: str) -> bytes:
    """The base log with the cell on (1-based) ``line``, ``column`` replaced."""
    lines = list(BASE_LINES)
    cells = lines[line - 1].split(",")
    cells[column - 1] = value
    lines[line - 1] = ",".join(cells)
    return text(lines)


def column(index: int, fn: Callable[[int, str], str], header: str | None = None) -> bytes:
    """The base log with every cell of column ``index`` (1-based) mapped by ``fn(row, cell)``."""
    lines = [BASE_LINES[0].split(",")] + [line.split(",") for line in BASE_LINES[1:]]
    if header is not None:
        lines[0][index - 1] = header
    for row, cells in enumerate(lines[1:]):
        cells[index - 1] = fn(row, cells[index - 1])
    return text([",".join(cells) for cells in lines])


def sidecar(**changes) -> dict:
    out = dict(BASE_SIDECAR)
    for key, value in changes.items():
        if value is _DROP:
            out.pop(key, None)
        else:
            out[key] = value
    return out


_DROP = object()
BASE = text(BASE_LINES)
ZEROS = text(["displacement_mm,force_N,p_a_bar,p_b_bar"] + ["-0.0,-0.0,-0.0,-0.0"] * 300)


def at_the_cap() -> bytes:
    """The base log shifted so that its smallest displacement is exactly 0 (x0 = 0: the A cap)."""
    lowest = min(float(line.split(",")[1]) for line in BASE_LINES[1:])
    return column(2, lambda _, c: repr(float(c) - lowest))


def hours_with_gap(gap_h: float) -> bytes:
    return column(1, lambda row, c: repr(float(c) / 3600 + (gap_h if row > 700 else 0.0)),
                  header="time_h")


@dataclass
class Case:
    """One corpus entry. ``expect`` per command: a fragment of the one-line error (exit 2) or
    ``0`` (loads and runs). Commands not listed are not run for this case."""

    log: bytes | str = BASE          # bytes, or "fifo" / "dir" / "missing" / "/dev/null"
    side: dict | str | bytes | None = field(default_factory=lambda: dict(BASE_SIDECAR))
    argv: list[str] = field(default_factory=list)
    expect: dict[str, str | int] = field(default_factory=dict)
    extra: dict[str, bytes | str] = field(default_factory=dict)   # more files (format ...)


def everywhere(fragment: str) -> dict[str, str]:
    return {"inspect": fragment, "fit": fragment, "posterior": fragment}


def loads(**others: str) -> dict[str, str | int]:
    return {"inspect": 0, **others}


NESTED = "[" * 100_000 + "]" * 100_000
DEEP = "[" * 40 + "32" + "]" * 40

CORPUS: dict[str, Case] = {
    # -- file types and encodings
    "log is a named pipe": Case(log="fifo", expect=everywhere("named pipe (FIFO)")),
    "log is a directory": Case(log="dir", expect=everywhere("is a directory")),
    "log is a character device": Case(log="/dev/null",
                                      expect=everywhere("is a character device")),
    "log missing": Case(log="missing", expect=everywhere("cannot be read")),
    "empty file": Case(log=b"", expect=everywhere("is empty")),
    "blank file": Case(log=b"\n \r\n\t\n", expect=everywhere("is empty")),
    "header only": Case(log=text(BASE_LINES[:1]), expect=everywhere("no data rows")),
    "five rows": Case(log=text(BASE_LINES[:6]), expect=everywhere("has 5 data rows")),
    "binary garbage": Case(log=bytes(range(256)) * 4, expect=everywhere("is not UTF-8")),
    "UTF-16": Case(log=BASE.decode().encode("utf-16"), expect=everywhere("is not UTF-8")),
    "NUL byte in a cell": Case(log=cell(4, 3, "1\x002"), expect=everywhere("line 4")),
    "unterminated quote": Case(log=cell(5, 3, '"12.5'), expect=everywhere("line 5")),
    "one huge cell": Case(log=cell(3, 3, "9" * 1_000_000),
                          expect=everywhere("line 3: a cell is longer than 131072 characters")),
    "one huge number": Case(log=text([line.replace(",", " ") for line in BASE_LINES[:3]]
                                     + ["0.01 0 " + "9" * 1_000_000 + " 6 6"]
                                     + [line.replace(",", " ") for line in BASE_LINES[4:]]),
                            expect=everywhere("line 4, column 3 'force_N': found '999")),
    "ragged row": Case(log=text(BASE_LINES[:8] + ["0.1,0.2"] + BASE_LINES[9:]),
                       expect=everywhere("has 2 fields, expected 5")),
    "blank line inside": Case(log=text(BASE_LINES[:8] + [""] + BASE_LINES[8:]),
                              expect=everywhere("is blank")),
    "duplicate header": Case(log=text(["time_s,force_N,force_N,p_a_bar,p_b_bar"]
                                      + BASE_LINES[1:]), expect=everywhere("both named")),
    "no displacement column": Case(log=text(["time_s,position,force_N,p_a_bar,p_b_bar"]
                                            + BASE_LINES[1:]),
                                   expect=everywhere("no displacement column")),
    "unknown unit": Case(log=text(["time_s,displacement_mm,force_Nx,p_a_bar,p_b_bar"]
                                  + BASE_LINES[1:]), expect=everywhere("unknown unit 'Nx'")),
    "data as header": Case(log=text(BASE_LINES[1:]), expect=everywhere("looks like data")),
    # -- cells
    "word": Case(log=cell(5, 3, "abc"), expect=everywhere("line 5, column 3 'force_N'")),
    "digit separator": Case(log=cell(7, 3, "1_000"),
                            expect=everywhere("'1_000', not a plain decimal number")),
    "hex": Case(log=cell(7, 3, "0x10"), expect=everywhere("'0x10', not a number")),
    "arabic-indic digits": Case(log=cell(7, 3, "١٢"),
                                expect=everywhere("not a plain decimal number")),
    "full-width digits": Case(log=cell(7, 3, "１２"),
                              expect=everywhere("not a plain decimal number")),
    "nan": Case(log=cell(7, 2, "nan"), expect=everywhere("'nan', not a finite number")),
    "inf": Case(log=cell(7, 3, "inf"), expect=everywhere("'inf', not a finite number")),
    "-Infinity": Case(log=cell(7, 3, "-Infinity"), expect=everywhere("not a finite number")),
    "exponent overflow": Case(log=cell(7, 3, "1e999"),
                              expect=everywhere("'1e999', not a finite number")),
    "decimal comma": Case(log=text([line.replace(",", ";") for line in BASE_LINES[:4]]
                                   + [BASE_LINES[4].replace(",", ";").replace(".", ",", 1)]
                                   + [line.replace(",", ";") for line in BASE_LINES[5:]]),
                          expect=everywhere("decimal point, not a decimal comma")),
    "empty cell": Case(log=cell(6, 3, ""), expect=everywhere("the cell is empty")),
    "double sign": Case(log=cell(6, 3, "+-1"), expect=everywhere("'+-1', not a number")),
    "force spike 1e300 N": Case(log=cell(502, 3, "1e300"),
                                expect=everywhere("line 502, column 3 'force_N': found "
                                                  "'1e300'")),
    "force spike -1e300 N": Case(log=cell(90, 3, "-1e300"), expect=everywhere("1e+07 N")),
    "displacement 1e300 mm": Case(log=cell(90, 2, "1e300"),
                                  expect=everywhere("plausible magnitude of a displacement")),
    "pressure 1e12 bar": Case(log=cell(90, 4, "1e12"),
                              expect=everywhere("plausible magnitude of a pressure a")),
    "subnormal force": Case(log=cell(90, 3, "4e-320"), expect=loads()),
    "force spike 5e6 N": Case(log=cell(90, 3, "5e6"), expect=loads()),
    "time goes back": Case(log=cell(9, 1, "0.001"), expect=everywhere("time does not increase")),
    "time repeats": Case(log=cell(9, 1, BASE_LINES[7].split(",")[0]),
                         expect=everywhere("time does not increase")),
    "time step 1e-300 s": Case(log=column(1, lambda row, _: repr(row * 1e-300)),
                               expect=everywhere("shorter than 1e-09 s")),
    "hours with a 1e160 h gap": Case(log=hours_with_gap(1e160),
                                     expect=everywhere("plausible magnitude of a time")),
    "hours with a 1e5 h gap": Case(log=hours_with_gap(1e5), expect=loads()),
    "gauge pressure below vacuum": Case(log=cell(9, 4, "-1.5"), expect=everywhere("below vacuum")),
    "every value -0.0": Case(log=ZEROS, expect=loads(fit="the piston does not move",
                                                     posterior="the piston does not move")),
    "constant displacement": Case(log=column(2, lambda _, __: "5.0"),
                                  expect=loads(fit="no motion to fit",
                                               posterior="no motion to fit")),
    # -- sidecars
    "bore 1e300": Case(side=sidecar(bore_mm=1e300),
                       expect=everywhere("key 'bore_mm' (--bore-mm): found 1e+300 mm, outside")),
    "bore true": Case(side=sidecar(bore_mm=True),
                      expect=everywhere("found true (a boolean), not a number")),
    "bore as text": Case(side=sidecar(bore_mm="32"), expect=everywhere("without quotes")),
    "bore as list": Case(side=sidecar(bore_mm=[32]), expect=everywhere("(a list), not a number")),
    "bore as object": Case(side=sidecar(bore_mm={"value": 32}),
                           expect=everywhere("an object, not a number")),
    # issue 36: a null is not a number (it used to pass inspect as "missing")
    "bore null": Case(side=sidecar(bore_mm=None), expect=everywhere("key 'bore_mm': is null")),
    "bore negative": Case(side=sidecar(bore_mm=-3), expect=everywhere("found -3 mm, outside")),
    "bore in metres": Case(side=sidecar(bore_mm=0.032),
                           expect=everywhere("found 0.032 mm, outside the plausible range")),
    "bore 1e400": Case(side='{"bore_mm": 1e400}', expect=everywhere("found inf, not a finite")),
    "bore with 400 digits": Case(side='{"bore_mm": 1' + "0" * 400 + "}",
                                 expect=everywhere("not a finite number")),
    "bore with 5000 digits": Case(side='{"bore_mm": 1' + "0" * 5000 + "}",
                                  expect=everywhere("a value JSON cannot represent")),
    "NaN in sidecar": Case(side='{"bore_mm": NaN}', expect=everywhere("found nan, not a finite")),
    "deeply nested sidecar": Case(side=NESTED, expect=everywhere("nested deeper than 16")),
    "40 levels of nesting": Case(side=DEEP, expect=everywhere("nested deeper than 16")),
    "repeated key": Case(side='{"bore_mm": 32, "bore_mm": 40}',
                         expect=everywhere("key 'bore_mm': appears twice")),
    "sidecar not an object": Case(side="[32]", expect=everywhere("JSON list, not an object")),
    "malformed sidecar": Case(side='{"bore_mm": 32,', expect=everywhere("malformed JSON")),
    "sidecar 2 MB": Case(side='{"_c": "' + "x" * 2_000_000 + '"}',
                         expect=everywhere("more than the 1048576 accepted")),
    "sidecar not UTF-8": Case(side=b'{"bore_mm": 32, "_c": "\xff"}',
                              expect=everywhere("is not UTF-8")),
    "sidecar is a named pipe": Case(side="fifo", expect=everywhere("named pipe (FIFO)")),
    "sidecar is a directory": Case(side="dir", expect=everywhere("is a directory")),
    "unknown key": Case(side=sidecar(bore=32), expect=everywhere("not a rig metadata key")),
    "stroke 0": Case(side=sidecar(stroke_mm=0), expect=everywhere("(above 0 up to 50000 mm)")),
    "rod wider than bore": Case(side=sidecar(rod_mm=40), expect=everywhere("rod must be thinner")),
    "start beyond stroke": Case(side=sidecar(start_position_mm=800),
                                expect=everywhere("outside the stroke")),
    "supply below vacuum": Case(side=sidecar(supply_bar=-5), expect=everywhere("below vacuum")),
    "ambient in Pa": Case(side=sidecar(ambient_bar=101325),
                          expect=everywhere("found 101325 bar, outside")),
    "load 1e30 kg": Case(side=sidecar(load_kg=1e30), expect=everywhere("key 'load_kg'")),
    "vented c": Case(side=sidecar(vented=["c"]), expect=everywhere("key 'vented'")),
    "vented true": Case(side=sidecar(vented=True), expect=everywhere("key 'vented'")),
    "chamber A at the cap": Case(log=at_the_cap(), side=sidecar(start_position_mm=0.0),
                                 expect=loads(fit="closed chamber A",
                                              posterior="gas-spring law is singular")),
    # -- command-line values
    "--bore-mm 1_000": Case(argv=["--bore-mm", "1_000"],
                            expect=everywhere("argument --bore-mm: found '1_000'")),
    "--bore-mm nan": Case(argv=["--bore-mm", "nan"], expect=everywhere("argument --bore-mm")),
    "--bore-mm 1e300": Case(argv=["--bore-mm", "1e300"],
                            expect=everywhere("command-line overrides: key 'bore_mm'")),
    "--stroke-mm -5": Case(argv=["--stroke-mm=-5"], expect=everywhere("key 'stroke_mm'")),
    "--supply-bar inf": Case(argv=["--supply-bar", "inf"],
                             expect=everywhere("argument --supply-bar")),
    "--threshold-mm 1_0": Case(argv=["--threshold-mm", "1_0"],
                               expect={"inspect": "argument --threshold-mm"}),
    "--columns non-ASCII column number": Case(
        argv=["--columns", "displacement=2:mm", "force=²:N"],
        expect=everywhere("no column '²'")),
    "--columns scale 1e300": Case(argv=["--columns", "displacement=2:mm", "force=3:N:scale=1e300"],
                                  expect=everywhere("scale 1e+300")),
    "--columns scale 1_0": Case(argv=["--columns", "displacement=2:mm", "force=3:N:scale=1_0"],
                                expect=everywhere("scale '1_0' is not a finite non-zero")),
    "--columns column 10**12": Case(argv=["--columns", "displacement=2:mm",
                                          "force=1000000000000:N"],
                                    expect=everywhere("the file has 5 columns")),
    "--delimiter empty": Case(argv=["--delimiter", ""], expect=everywhere("delimiter")),
    "--fix n=1_000": Case(argv=["--fix", "n=1_000"],
                          expect={"fit": "value '1_000' is not a number",
                                  "posterior": "value '1_000' is not a number"}),
    "--max-steps 0": Case(argv=["--max-steps", "0"],
                          expect={"fit": "--max-steps 0: must be at least 1"}),
    "--skip -5": Case(argv=["--skip=-5"], expect={"fit": "--skip -5: must be at least 0",
                                                  "posterior": "--skip -5: must be at least 0"}),
    "--weight 1e308": Case(argv=["--weight", "presliding=1e308"],
                           expect={"fit": "outside 0..1e+06", "posterior": "outside 0..1e+06"}),
    # -- format files
    "format delimiter 5": Case(argv=["--format", "{fmt}"], extra={"fmt.json": '{"delimiter": 5}'},
                               expect=everywhere("delimiter: found 5")),
    "format column entry 5": Case(argv=["--format", "{fmt}"],
                                  extra={"fmt.json": '{"columns": [5]}'},
                                  expect=everywhere("column mapping entry: found 5")),
    "format column true": Case(argv=["--format", "{fmt}"], extra={"fmt.json": json.dumps(
        {"columns": [{"quantity": "force", "column": True, "unit": "N"}]})},
        expect=everywhere("is not a valid entry")),
    "format rig bore true": Case(side=sidecar(bore_mm=_DROP), argv=["--format", "{fmt}"],
                                 extra={"fmt.json": '{"rig": {"bore_mm": true}}'},
                                 expect=everywhere("fmt.json: key 'bore_mm' (--bore-mm): found "
                                                   "true")),
    "format nested": Case(argv=["--format", "{fmt}"], extra={"fmt.json": NESTED},
                          expect=everywhere("nested deeper than 16")),
    "format is a named pipe": Case(argv=["--format", "{fmt}"], extra={"fmt.json": "fifo"},
                                   expect=everywhere("neither a file nor a bundled format")),
}

COMMAND_ARGS = {"inspect": [], "fit": ["--max-steps", "5"],
                "posterior": ["--walkers", "12", "--steps", "10", "--check-every", "5"]}
RUNS = [(name, command) for name, case in CORPUS.items() for command in case.expect]


@contextlib.contextmanager
def alarm(seconds: int):
    """Fail instead of hanging (a blocked ``open`` of a pipe is interrupted by SIGALRM)."""
    def hang(signum, frame):
        raise TimeoutError(f"no answer within {seconds} s: the command hangs")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def materialise(case: Case, directory: Path) -> Path:
    """Write the case's files into ``directory``; the log's path."""
    path = directory / "run1.csv"
    if case.log == "fifo":
        os.mkfifo(path)
    elif case.log == "dir":
        path.mkdir()
    elif case.log == "missing":
        pass
    elif isinstance(case.log, str):
        path = Path(case.log)
    else:
        path.write_bytes(case.log)
    side = directory / "run1.json"
    if case.side == "fifo":
        os.mkfifo(side)
    elif case.side == "dir":
        side.mkdir()
    elif isinstance(case.side, dict):
        side.write_text(json.dumps(case.side))
    elif isinstance(case.side, str):
        side.write_text(case.side)
    elif isinstance(case.side, bytes):
        side.write_bytes(case.side)
    for name, content in case.extra.items():
        if content == "fifo":
            os.mkfifo(directory / name)
        else:
            (directory / name).write_text(content)
    return path


def digests(directory: Path) -> dict[str, str]:
    """SHA-256 of every regular file (pipes are not read)."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.iterdir()) if p.is_file()}


@pytest.mark.parametrize("name, command", RUNS, ids=[f"{c}:{n}" for n, c in RUNS])
def test_corpus(tmp_path, capsys, name, command):
    case = CORPUS[name]
    inputs = tmp_path / "in"
    inputs.mkdir()
    log = materialise(case, inputs)
    argv = [a.replace("{fmt}", str(inputs / "fmt.json")) for a in case.argv]
    args = [command, str(log), *COMMAND_ARGS[command], *argv]
    if command != "inspect":
        args += ["--out", str(tmp_path / "out")]
    before = digests(inputs)
    with alarm(HANG_SECONDS), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = main(args)
        except SystemExit as exc:       # argparse errors
            code = exc.code
    out, err = capsys.readouterr()
    assert digests(inputs) == before
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], caught
    expected = case.expect[command]
    if expected == 0:
        assert code == 0, err
        return
    assert code == 2, (code, err)
    assert len(err.strip().splitlines()) == 1 and len(err) < 700, err
    assert "Traceback" not in err
    assert expected in err, (expected, err)
    assert not (tmp_path / "out" / "fit.json").exists()
    assert not (tmp_path / "out" / "posterior.json").exists()


def test_corpus_size():
    """The issue's corpus had 62 inputs and 185 runs; this one is at least as large."""
    assert len(CORPUS) >= 62 and len(RUNS) >= 185, (len(CORPUS), len(RUNS))


def test_named_pipe_in_a_real_process(tmp_path):
    """The hang of the issue, end to end: ``fitstiff fit`` on a FIFO answers at once."""
    fifo = tmp_path / "run1.csv"
    os.mkfifo(fifo)
    result = subprocess.run([sys.executable, "-m", "fitstiff", "fit", str(fifo), "--out",
                             str(tmp_path / "out")], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == (f"fitstiff fit: error: {fifo}: file: is a named pipe "
                                     "(FIFO), not a regular file; save the data to a regular "
                                     "file and give its path")


# -- numerical guards ---------------------------------------------------------------------------

@pytest.mark.parametrize("command", ["fit", "posterior"])
def test_a_spike_the_loader_accepts_gives_a_finite_result_or_names_it(tmp_path, capsys,
                                                                       command):
    """The issue's spike at the largest magnitude the loader takes (5e6 N on an 18 N loop): the
    solver chases it; the run ends with a finite result or with one line naming the spike,
    never with a result built on inf."""
    path = tmp_path / "spike.csv"
    path.write_bytes(cell(502, 3, "5e6"))
    path.with_suffix(".json").write_text(json.dumps(BASE_SIDECAR))
    extra = ["--walkers", "12", "--steps", "10", "--check-every", "5"] * (command == "posterior")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code = main([command, str(path), *extra, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    if code == 2:
        assert err.count("\n") == 1 and "force spike of 5e+06 N at line 502" in err, err
        assert not (tmp_path / "out" / f"{command}.json").exists()
    else:
        assert code == 0, err
        from fitstiff.io.guards import first_nonfinite
        assert first_nonfinite(json.loads((tmp_path / "out" / f"{command}.json")
                                          .read_text())) is None


def memory_log(force_at: dict[int, float] | None = None, n: int = 400):
    """A small triangle log made in memory (so the loader's bounds do not apply)."""
    from fitstiff.io.log import Log

    x = 1e-3 * np.interp(np.arange(n), [0, n // 4, 3 * n // 4, n - 1], [0, 1, -1, 0])
    force = 40e3 * np.clip(x, -4.5e-4, 4.5e-4) + 0.01 * np.sin(np.arange(n))
    for i, value in (force_at or {}).items():
        force[i] = value
    return Log(name="memory", displacement=x, force=force, time=np.arange(n) * 1e-3)


def test_fit_refuses_a_spike_that_did_not_pass_the_loader():
    from fitstiff.inference.fitting import fit

    with pytest.raises(InputError) as info:
        fit([memory_log({312: 1e300})], "viscous")
    assert str(info.value) == ("memory: force, sample 312: found 1e+300 N, beyond the "
                               "plausible magnitude 1e+07 N (10 MN, beyond any cylinder or "
                               "load cell); correct or remove the sample (a spike?) and check "
                               "the unit")


def test_non_finite_residuals_are_an_input_error_not_a_result():
    """A fixed parameter that makes the model overflow: the fit stops at the guard instead of
    summarising inf (the issue's fit.json built on inf)."""
    from fitstiff.inference.fitting import fit

    with pytest.raises(InputError, match=r"^memory: the fit's whitened residuals and "
                                         r"Jacobian: not finite or beyond 1e\+100"):
        fit([memory_log()], "viscous", fix={"c": 1e300}, max_steps=5)


def test_likely_cause_names_the_spike_with_its_line(tmp_path):
    from fitstiff.io.guards import likely_cause, nonfinite_error

    log = memory_log({312: 1e300}).replace(path=tmp_path / "spike.csv", source={"header": True})
    culprit, cause = likely_cause([memory_log(), log])
    assert culprit is log
    assert cause.startswith("force spike of 1e+300 N at line 314 (the middle half of the "
                            "channel spans")
    message = str(nonfinite_error([log], "the log-posterior at the least-squares optimum"))
    assert message.startswith(f"{tmp_path / 'spike.csv'}: the log-posterior at the "
                              "least-squares optimum: not finite (likely cause: force spike")


def test_result_json_with_inf_or_nan_is_not_written(tmp_path):
    from fitstiff.io.output import OutputDir

    out = OutputDir(tmp_path / "out")
    with pytest.raises(InputError) as info:
        out.write_json("fit.json", {"rms_N": 0.2, "correlation": {"matrix": np.array(
            [[1.0, np.nan], [np.nan, 1.0]])}})
    assert str(info.value).startswith(f"{tmp_path / 'out' / 'fit.json'}: entry "
                                      "'correlation.matrix[0][1]': is nan, so the result is "
                                      "not written")
    with pytest.raises(InputError, match="entry 'parameters.n.stderr': is inf"):
        out.write_json("posterior.json", {"parameters": {"n": {"stderr": float("inf")}}})
    assert not any((tmp_path / "out").glob("*"))      # nothing written (nor the folder made)
    out.write_json("fit.json", {"rms_N": 0.2, "stderr": None})      # None: not determined
    out.finish()
    assert json.loads((tmp_path / "out" / "fit.json").read_text()) == {"rms_N": 0.2,
                                                                      "stderr": None}


def test_a_floating_point_warning_in_a_command_becomes_one_line(tmp_path, capsys, monkeypatch):
    """Whatever the guards miss: numpy's RuntimeWarning stops the command with exit 2."""
    import fitstiff.cli.inspect as inspect_cli

    def overflowing(args):
        return int(np.float64(1e300) * np.float64(1e300) > 0)

    monkeypatch.setattr(inspect_cli, "run", overflowing)
    path = tmp_path / "run1.csv"
    path.write_bytes(BASE)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fitstiff inspect: error: {path}: numerical problem: overflow "
                          "encountered in scalar multiply")
    assert err.count("\n") == 1 and "fitstiff inspect" in err


def test_velocity_of_a_log_with_a_long_pause_is_exact():
    """Time in hours with a long gap: the denoising velocity stays what it is without the gap
    (window sums relative to each sample; running sums over the log lost every digit)."""
    from fitstiff.segments.denoise import segment_velocity

    n = 1000
    t = np.arange(n) * 1e-3
    x = 1e-3 * np.interp(np.arange(n), [0, 500, 999], [0.0, 1.0, 0.0])
    reference = segment_velocity(x, t, np.array([500]), noise=1e-6)
    for gap_s in (3.6e4, 3.6e6):        # 10 h, 1000 h (the old sums: 3 % and 100 % off)
        paused = t + np.where(np.arange(n) > 700, gap_s, 0.0)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            v = segment_velocity(x, paused, np.array([500]), noise=1e-6)
        near_gap = (np.arange(n) > 650) & (np.arange(n) < 750)
        np.testing.assert_allclose(v[~near_gap], reference[~near_gap], rtol=1e-5)


def test_plain_decimal_numbers():
    from fitstiff.io.validation import cli_number, is_decimal

    good = ["0", "-0.0", "+12", "1.", ".5", "1.5e-3", "2E+10", " 7 "]
    bad = ["1_000", "0x10", "nan", "inf", "Infinity", "١٢", "１２", "1e", "e5", "+-1", "", "1 2"]
    assert all(is_decimal(t) for t in good) and not any(is_decimal(t) for t in bad)
    assert cli_number("1.5e3") == 1500.0
    for text in ("1_000", "nan", "1e999"):
        with pytest.raises(Exception, match="found"):
            cli_number(text)
