"""Property-based tests (hypothesis) of the loader against mutated logs, sidecars and formats.

Each example takes one small valid log with its sidecar (or format file), applies one to three
random mutations - cell swaps with hostile tokens, truncation, byte flips, line deletion /
duplication / swaps, header renames, delimiter changes, extreme magnitudes (a column times
10**k), JSON type changes and nesting in the sidecar - and asserts:

- ``load_log`` returns a valid log (finite SI arrays, at least ``MIN_SAMPLES`` samples, time
  strictly increasing, every value within :data:`fitstiff.io.validation.CHANNEL_LIMITS`) that
  segmentation and ``inspect_log`` then describe, or it raises a fitstiff
  :class:`~fitstiff.errors.InputError` with a one-line message;
- never another exception, never a ``RuntimeWarning`` (they are errors here);
- the input files are unchanged.

The runs are derandomized (fixed examples, CI is reproducible) with a fixed ``max_examples``;
each test prints its outcome classes (``-s`` shows them). Hypothesis also mixes in constants
it finds in the source of every local module imported so far, which would make the examples
depend on which tests ran before in the same process; the fixture below keeps that pool empty.
"""

from __future__ import annotations

import atexit
import collections
import hashlib
import json
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from fitstiff.data import PAPER_RIG
from fitstiff.errors import InputError
from fitstiff.io.loading import MIN_SAMPLES, load_log
from fitstiff.io.log import RIG_KEYS
from fitstiff.io.validation import CHANNEL_LIMITS
from fitstiff.segments.inspection import inspect_log
from fitstiff.segments.segmentation import segment

EXAMPLES = 500
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])

HEADER = ["time_s", "displacement_mm", "force_N", "p_a_bar", "p_b_bar"]
N_ROWS = 24


def _rows() -> list[list[str]]:
    """A triangle 0 -> 0.3 -> -0.3 -> 0 mm, force 40 N/mm saturating at 18 N, 6 bar."""
    x = np.interp(np.arange(N_ROWS), [0, 6, 18, 23], [0.0, 0.3, -0.3, 0.0])
    force = np.clip(40 * x, -18, 18) + 0.1 * np.sin(np.arange(N_ROWS))
    return [[f"{0.005 * i:.3f}", f"{x[i]:.5f}", f"{force[i]:.4f}", "6.002", "5.998"]
            for i in range(N_ROWS)]


BASE_ROWS = _rows()
BASE_SIDECAR = {k: v for k, v in PAPER_RIG.items() if k in (
    "bore_mm", "rod_mm", "stroke_mm", "start_position_mm", "supply_bar", "ambient_bar")}
RIG_NAMES = [k.key for k in RIG_KEYS]

# -- strategies ----------------------------------------------------------------------------

HOSTILE_TOKENS = ["", " ", "nan", "NaN", "inf", "-inf", "Infinity", "1_000", "0x10", "1e999",
                  "-1e999", "1e300", "-1e300", "1e-320", "4.9e-324", "1,5", "+-1", "1e", ".",
                  "-", "١٢", "１２", "²", "0" * 400, "9" * 500, "1e+07", "1e7", "-0.0",
                  "\x00", '"', '"1"', "'1'", "TRUE", "None", "1.5 2", "\t", "\ufeff1",
                  "1.7976931348623157e308", "-2.2250738585072014e-308",
                  "5.998\x1c", "\u00a05", "5\u2003"]     # blanks float() strips, CSV does not

tokens = st.one_of(
    st.sampled_from(HOSTILE_TOKENS),
    st.text(max_size=8),
    st.floats().map(repr),
    st.integers(min_value=-10**30, max_value=10**30).map(str),
    st.builds(lambda m, e: f"{m}e{e}", st.integers(-9, 9), st.integers(-400, 400)),
)

json_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-10**400, max_value=10**400),
    st.floats(), st.text(max_size=8),
    st.sampled_from([0, -0.0, 1e300, -1e300, 1e-300, 0.032, 32, 1000, 1001, 101325]))
json_values = st.recursive(json_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)


def _cells(rows):
    return [row[:] for row in rows]


@st.composite
def csv_mutation(draw):
    """One mutation of (header, rows, delimiter, raw-bytes edits)."""
    kind = draw(st.sampled_from(["cell", "cell", "cell", "truncate", "flip", "delete", "duplicate",
                                 "swap", "header", "delimiter", "scale", "blank", "whitespace"]))
    row = draw(st.integers(0, N_ROWS - 1))
    col = draw(st.integers(0, len(HEADER) - 1))
    if kind == "cell":
        return kind, (row, col, draw(tokens))
    if kind in ("truncate", "flip"):
        return kind, (draw(st.floats(0, 1)), draw(st.integers(0, 255)))
    if kind in ("delete", "duplicate", "blank"):
        return kind, (row,)
    if kind == "swap":
        return kind, (row, draw(st.integers(0, N_ROWS - 1)), draw(st.booleans()), col)
    if kind == "header":
        name = draw(st.one_of(st.sampled_from([
            "force_kN", "force", "force_mN", "displacement_m", "displacement_um",
            "displacement_N", "time_ms", "time_h", "time_min", "p_a_psi_abs", "p_a_pa",
            "p_b_bar_abs", "p_a_MPa", "force_N", "time_s", "", "volts", "force_N ",
            "p_a_bar_abs_abs"]), st.text(max_size=10)))
        return kind, (col, name)
    if kind == "delimiter":
        return kind, (draw(st.sampled_from([";", "\t", " ", "|", ",,", ", "])),)
    if kind == "scale":
        return kind, (col, draw(st.integers(-330, 330)))
    return kind, (row, col)


def build_csv(mutations) -> bytes:
    header, rows, delimiter = list(HEADER), _cells(BASE_ROWS), ","
    edits = []
    for kind, args in mutations:
        if kind == "cell":
            row, col, token = args
            rows[row % len(rows)][col] = token
        elif kind == "delete" and len(rows) > 1:
            del rows[min(args[0], len(rows) - 1)]
        elif kind == "duplicate":
            i = min(args[0], len(rows) - 1)
            rows.insert(i, rows[i][:])
        elif kind == "swap":
            a, b, whole_row, col = args
            a, b = min(a, len(rows) - 1), min(b, len(rows) - 1)
            if whole_row:
                rows[a], rows[b] = rows[b], rows[a]
            else:
                rows[a][col], rows[b][col] = rows[b][col], rows[a][col]
        elif kind == "header":
            header[args[0]] = args[1]
        elif kind == "delimiter":
            delimiter = args[0]
        elif kind == "scale":
            col, power = args
            for row in rows:
                try:
                    with np.errstate(all="ignore"):
                        row[col] = repr(float(np.float64(row[col]) * 10.0 ** power))
                except (ValueError, OverflowError):
                    pass
        elif kind == "whitespace":
            row, col = args
            row %= len(rows)
            rows[row][col] = f"  {rows[row][col]}\t"
        else:
            edits.append((kind, args))
    lines = [delimiter.join(header)] + [delimiter.join(row) for row in rows]
    raw = ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")
    for kind, args in edits:
        if kind == "truncate":
            raw = raw[:int(args[0] * len(raw))]
        elif kind == "flip" and raw:
            i = min(int(args[0] * len(raw)), len(raw) - 1)
            raw = raw[:i] + bytes([args[1]]) + raw[i + 1:]
        elif kind == "blank":
            parts = raw.split(b"\n")
            parts.insert(min(args[0] + 1, len(parts)), b"   ")
            raw = b"\n".join(parts)
    return raw


@st.composite
def sidecar_mutation(draw):
    kind = draw(st.sampled_from(["set", "set", "set", "drop", "replace", "raw", "nest",
                                 "absent", "extreme"]))
    if kind == "set":
        key = draw(st.one_of(st.sampled_from(RIG_NAMES + ["vented", "_comment"]),
                             st.text(max_size=8)))
        return kind, (key, draw(json_values))
    if kind == "extreme":
        return kind, (draw(st.sampled_from(RIG_NAMES)), draw(st.one_of(
            st.floats(), st.integers(min_value=-10**400, max_value=10**400),
            st.builds(lambda m, e: float(f"{m}e{e}"), st.integers(-9, 9), st.integers(-330, 330)))))
    if kind == "drop":
        return kind, (draw(st.sampled_from(RIG_NAMES)),)
    if kind == "replace":
        return kind, (draw(json_values),)
    if kind == "raw":
        return kind, (draw(st.binary(max_size=40)),)
    if kind == "nest":
        return kind, (draw(st.integers(1, 3000)), draw(st.sampled_from(["[", '{"a":'])))
    return kind, ()


def build_sidecar(mutations) -> bytes | None:
    doc: object = dict(BASE_SIDECAR)
    raw: bytes | None = None
    for kind, args in mutations:
        if kind in ("set", "extreme") and isinstance(doc, dict):
            doc[args[0]] = args[1]
        elif kind == "drop" and isinstance(doc, dict):
            doc.pop(args[0], None)
        elif kind == "replace":
            doc = args[0]
        elif kind == "raw":
            raw = args[0]
        elif kind == "nest":
            depth, opener = args
            closer = "]" if opener == "[" else "}"
            raw = (opener * depth + "1" + closer * depth).encode()
        elif kind == "absent":
            return None
    if raw is not None:
        return raw
    return json.dumps(doc).encode()        # NaN / Infinity / huge integers as Python writes them


# -- the property ----------------------------------------------------------------------------

@pytest.fixture(autouse=True)
def _same_examples_whatever_ran_before(monkeypatch):
    """No constants from local modules (their set grows with every import), so a derandomized
    run draws the same examples alone, in the whole suite and under xdist. Private hypothesis
    internals: where they are missing, nothing is changed."""
    try:
        from hypothesis.internal.cache import LRUCache
        from hypothesis.internal.conjecture import providers
        from hypothesis.internal.constants_ast import Constants
    except ImportError:
        return
    if hasattr(providers, "_get_local_constants") and hasattr(providers, "CONSTANTS_CACHE"):
        monkeypatch.setattr(providers, "_get_local_constants", Constants)
        monkeypatch.setattr(providers, "CONSTANTS_CACHE", LRUCache(1024))


WORK = Path(tempfile.mkdtemp(prefix="fitstiff-hypothesis-"))
atexit.register(shutil.rmtree, WORK, ignore_errors=True)


def _digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def _classify(exc: InputError) -> str:
    what = exc.what or ""
    if what.startswith("line") and "column" in what:
        return "InputError: cell"
    if what.startswith("line") or what in ("file", "header") or what.startswith("column"):
        return "InputError: file structure"
    if "key" in what or "rig metadata" in what or (exc.where or "").endswith(".json"):
        return "InputError: metadata"
    return "InputError: other"


def check_load(csv_bytes: bytes, sidecar_bytes: bytes | None, outcomes: collections.Counter,
               *, fmt: bytes | None = None) -> None:
    """Load; assert the contract; count the outcome class."""
    path, side, fmt_path = WORK / "run1.csv", WORK / "run1.json", WORK / "fmt.json"
    for stale in (side, fmt_path):
        stale.unlink(missing_ok=True)
    path.write_bytes(csv_bytes)
    if sidecar_bytes is not None:
        side.write_bytes(sidecar_bytes)
    if fmt is not None:
        fmt_path.write_bytes(fmt)
    before = [_digest(p) for p in (path, side, fmt_path)]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            log = load_log(path, fmt=fmt_path if fmt is not None else None)
        except InputError as exc:
            message = str(exc)
            assert "\n" not in message and len(message) < 2500, message
            outcome = _classify(exc)
        else:
            _check_log(log)
            inspect_log(log, segmentation=segment(log))
            outcome = "loaded"
    assert [_digest(p) for p in (path, side, fmt_path)] == before
    event(outcome)
    outcomes[outcome] += 1


def _check_log(log) -> None:
    assert len(log) >= MIN_SAMPLES
    for name, quantity in (("time", "time"), ("displacement", "displacement"),
                           ("force", "force"), ("pressure_a", "p_a"), ("pressure_b", "p_b")):
        values = getattr(log, name)
        if values is None:
            continue
        assert np.all(np.isfinite(values)), name
        assert np.all(np.abs(values) <= CHANNEL_LIMITS[quantity].bound * (1 + 1e-12)), name
    if log.time is not None:
        assert np.all(np.diff(log.time) > 0)
    rig = log.rig
    for key in RIG_KEYS:
        value = getattr(rig, key.field)
        assert value is None or np.isfinite(value)


def _run(prop) -> collections.Counter:
    outcomes: collections.Counter = collections.Counter()
    prop(outcomes)
    total = sum(outcomes.values())
    print(f"\n{prop.__name__}: {total} examples: " +
          ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    assert total >= EXAMPLES
    assert outcomes["loaded"] > 0
    assert sum(v for k, v in outcomes.items() if k.startswith("InputError")) > 0
    return outcomes


@SETTINGS
@given(csv=st.lists(csv_mutation(), min_size=1, max_size=3),
       side=st.lists(sidecar_mutation(), max_size=1))
def _mutated_logs(outcomes, csv, side):
    check_load(build_csv(csv), build_sidecar(side), outcomes)


@SETTINGS
@given(side=st.lists(sidecar_mutation(), min_size=1, max_size=3),
       csv=st.lists(csv_mutation(), max_size=1))
def _mutated_sidecars(outcomes, side, csv):
    check_load(build_csv(csv), build_sidecar(side), outcomes)


FORMAT = {"columns": ["time=1:s", "displacement=2:mm", "force=3:N"], "delimiter": "comma",
          "no_header": False, "vented": ["b"], "rig": {"bore_mm": 32}}


@st.composite
def format_mutation(draw):
    key = draw(st.sampled_from(["columns", "delimiter", "no_header", "vented", "rig", "entry",
                                "entry", "extra"]))
    if key == "entry":
        return key, (draw(st.integers(0, 2)), draw(st.one_of(
            json_values,
            st.fixed_dictionaries({"quantity": st.sampled_from(["force", "time", "p_a"]),
                                   "column": st.one_of(st.integers(-3, 10**12), st.text(max_size=4),
                                                       st.booleans()),
                                   "unit": st.one_of(st.sampled_from(["N", "kN", "s"]),
                                                     st.text(max_size=4)),
                                   "scale": st.one_of(st.floats(), st.integers(), st.booleans())}),
            st.builds(lambda c, s: f"force={c}:N:scale={s}", st.sampled_from(["3", "²", "0", "9"]),
                      tokens))))
    return key, (draw(json_values),)


@SETTINGS
@given(mutations=st.lists(format_mutation(), min_size=1, max_size=3))
def _mutated_formats(outcomes, mutations):
    doc = json.loads(json.dumps(FORMAT))
    for key, args in mutations:
        if key == "entry" and isinstance(doc["columns"], list) and doc["columns"]:
            doc["columns"][args[0] % len(doc["columns"])] = args[1]
        elif key == "extra":
            doc["_note"] = args[0]
        else:
            doc[key] = args[0]
    check_load(build_csv([]), None, outcomes, fmt=json.dumps(doc).encode())


def test_mutated_logs_load_or_give_one_input_error():
    _run(_mutated_logs)


def test_mutated_sidecars_load_or_give_one_input_error():
    _run(_mutated_sidecars)


def test_mutated_format_files_load_or_give_one_input_error():
    _run(_mutated_formats)
