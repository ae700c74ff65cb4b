"""Column mappings, format files and the bundled formats."""

from __future__ import annotations

import json

import pytest

from fitstiff.errors import InputError
from fitstiff.io.columns import (Format, bundled_formats, load_format, match_header,
                                 parse_column_spec, parse_columns, parse_delimiter, parse_vented)


@pytest.mark.parametrize("entry, quantity, column, unit, factor, absolute", [
    ("time=1:ms", "time", 1, "ms", 1e-3, False),
    ("displacement=position:um:flip", "displacement", "position", "um", -1e-6, False),
    ("force=7:kN:scale=0.5:flip", "force", 7, "kN", -500.0, False),
    ("force=7:N:flip:scale=2", "force", 7, "N", -2.0, False),
    ("p_a=6:bar", "p_a", 6, "bar", 1e5, False),
    ("p_b=p2:psi_abs", "p_b", "p2", "psi_abs", 6894.757293168361, True),
])
def test_mapping_entry(entry, quantity, column, unit, factor, absolute):
    spec = parse_column_spec(entry)
    assert (spec.quantity, spec.column, spec.unit.text) == (quantity, column, unit)
    assert spec.factor == pytest.approx(factor, rel=1e-12)
    assert spec.unit.absolute is absolute
    assert parse_column_spec(spec.describe()) == spec


def test_mapping_entry_as_dict():
    spec = parse_column_spec({"quantity": "force", "column": 7, "unit": "N", "flip": True,
                              "scale": 2})
    assert spec == parse_column_spec("force=7:N:flip:scale=2")


@pytest.mark.parametrize("entry, found", [
    ("force", "has no '='"),
    ("force=7", "has no unit"),
    ("speed=1:m", "unknown quantity 'speed'"),
    ("force=0:N", "column '0' is not a column"),
    ("force=:N", "column '' is not a column"),
    ("force=7:N:flop", "found 'flop'"),
    ("force=7:N:flip:flip", "found 'flip'"),
    ("p_a=6:bar:abs", "found 'abs'"),
    ("force=7:N:scale=abc", "scale 'abc' is not a finite non-zero number"),
    ("force=7:N:scale=0", "scale '0'"),
    ("force=7:mm", "unit 'mm' is not a force unit"),
    ({"quantity": "force", "column": 7}, "is not a valid entry"),
    ({"quantity": "force", "column": 7, "unit": "N", "flip": "yes"}, "is not a valid entry"),
])
def test_bad_mapping_entry_names_it_and_the_form(entry, found):
    with pytest.raises(InputError) as info:
        parse_column_spec(entry, where="rig.json")
    message = str(info.value)
    shown = f"'{entry}'" if isinstance(entry, str) else json.dumps(entry)
    assert message.startswith(f"rig.json: column mapping entry {shown}")
    assert found in message
    if "unit" not in found:
        assert "quantity=COLUMN:UNIT" in message or '"quantity"' in message


def test_each_quantity_mapped_once():
    with pytest.raises(InputError, match="maps force a second time.*keep one entry"):
        parse_columns(["force=7:N", "displacement=5:mm", "force=3:kN"])


@pytest.mark.parametrize("name, expected", [
    ("time_ms", ("time", "ms")), ("Force_kN", ("force", "kN")),
    (" p_b_bar_abs ", ("p_b", "bar_abs")),
    ("displacement", ("displacement", "")), ("force_sensor_V", ("force", "sensor_V")),
    ("timestamp", None), ("p_ab", None), ("volts", None),
])
def test_match_header(name, expected):
    assert match_header(name) == expected


@pytest.mark.parametrize("text, expected", [
    (",", ","), (";", ";"), ("\t", "\t"), ("tab", "\t"), ("\\t", "\t"), ("semicolon", ";"),
    ("comma", ","), ("whitespace", "whitespace"), (" ", "whitespace"), ("|", "|"),
])
def test_delimiter(text, expected):
    assert parse_delimiter(text) == expected


@pytest.mark.parametrize("text", ["ab", "\n", '"', ""])
def test_bad_delimiter(text):
    with pytest.raises(InputError, match="delimiter.*one character or one of: comma"):
        parse_delimiter(text)


def test_vented():
    assert parse_vented("b") == {"b"} and parse_vented(["a", "b"]) == {"a", "b"}
    with pytest.raises(InputError, match=r"key 'vented': found \['B'\]; .*\"a\", \"b\""):
        parse_vented(["B"])


def test_format_file(tmp_path):
    path = tmp_path / "fmt.json"
    path.write_text(json.dumps({"_comment": ["ignored"], "columns": ["time=1:ms", "force=2:N"],
                                "no_header": True, "delimiter": "semicolon", "vented": ["b"],
                                "rig": {"bore_mm": 32, "_why": "ignored"}}))
    fmt = load_format(path)
    assert list(fmt.columns) == ["time", "force"]
    assert (fmt.no_header, fmt.delimiter, fmt.vented) == (True, ";", {"b"})
    assert fmt.rig == {"bore_mm": 32} and fmt.source == str(path)
    assert load_format(fmt) is fmt


@pytest.mark.parametrize("values, fragment", [
    ({"colums": []}, "key 'colums': is not a format key; use one of: columns"),
    ({"columns": "time=1:ms"}, "key 'columns': found 'time=1:ms'; give a list"),
    ({"no_header": "yes"}, "key 'no_header': found 'yes'; give true or false"),
    ({"rig": [25]}, "key 'rig': found [25]; give an object"),
    ({"rig": {"bore": 25}}, "key 'bore': is not a rig metadata key; use one of: bore_mm"),
    ({"delimiter": "tabs"}, "delimiter: found 'tabs'"),
    ({"vented": ["c"]}, "key 'vented'"),
    ({"columns": ["force=7:N", "force=8:N"]}, "maps force a second time"),
])
def test_bad_format(values, fragment):
    with pytest.raises(InputError) as info:
        Format.from_mapping(values, source="fmt.json")
    assert str(info.value).startswith("fmt.json: ") and fragment in str(info.value)


def test_malformed_format_file(tmp_path):
    path = tmp_path / "fmt.json"
    path.write_text('{"columns": ["time=1:ms",]}')
    with pytest.raises(InputError, match=r"fmt\.json: line 1, column 26: malformed JSON"):
        load_format(path)


def test_bundled_format():
    assert "zillen_oring" in bundled_formats()
    fmt = load_format("zillen_oring")
    assert {q: s.describe() for q, s in fmt.columns.items()} == {
        "time": "time=1:ms", "displacement": "displacement=5:mm:flip", "p_a": "p_a=6:bar",
        "force": "force=7:N:flip"}
    assert (fmt.no_header, fmt.delimiter, fmt.vented) == (True, "\t", {"b"})
    assert fmt.rig == {"bore_mm": 25}   # stroke unknown: not invented
    assert fmt.source.endswith("zillen_oring.json")


def test_unknown_format_lists_the_bundled_ones():
    with pytest.raises(InputError, match="nope: --format: is neither a file nor a bundled "
                                         "format; .* zillen_oring"):
        load_format("nope")
