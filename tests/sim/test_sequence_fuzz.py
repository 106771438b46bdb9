"""Malformed sequences: every mutation of a valid sequence gives a clean InputError naming file, line, field.

A valid sequence is drawn and written, one file is mutated, and reading must raise `InputError` (never another
exception type) whose message names the file and, where the problem has one, the 1-based line and the field.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.sim.sequence import SequenceFormatError, read_sequence, write_sequence
from tests.sim.test_sequence import sequences

REQUIRED = ("scan", "t", "range", "azimuth", "elevation", "radial_velocity")
FLOAT_COLUMNS = REQUIRED[1:]


def read_error(d: Path, name: str) -> SequenceFormatError:
    """Read the sequence, expecting an InputError about file `name`; return it."""
    with pytest.raises(InputError) as info:
        read_sequence(d, use_cache=False)
    err = info.value
    assert str(d / name) in str(err), str(err)
    return err


def assert_located(err, line, field=None, words=()):
    msg = str(err)
    if line is not None:
        assert f"line {line}" in msg and err.line == line, msg
    if field is not None:
        assert f"field '{field}'" in msg and err.field == field, msg
    for w in words:
        assert w in msg, (w, msg)


def first_order_violation(rows: list[list[str]]) -> int:
    """Independent oracle: data index of the first row breaking the scan/time ordering rules."""
    scan = [int(r[0]) for r in rows]
    t = [float(r[1]) for r in rows]
    for k in range(1, len(rows)):
        if scan[k] < scan[k - 1] or (scan[k] == scan[k - 1] and t[k] != t[k - 1]) or \
                (scan[k] > scan[k - 1] and not t[k] > t[k - 1]):
            return k
    raise AssertionError("no violation")


CSV_MUTATIONS = ["drop_column", "dup_column", "rename_deg", "nonfinite", "text", "negative_range", "degrees",
                 "truncate", "extra_field", "swap_lines", "same_scan_other_t", "blank_line", "empty",
                 "no_header", "bad_scan"]


@given(sequences(min_nonempty=2), st.sampled_from(CSV_MUTATIONS), st.data())
def test_malformed_radar_csv_gives_located_input_error(seq, kind, data):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_sequence(d, seq)
        csv = d / "radar.csv"
        lines = csv.read_text().rstrip("\n").split("\n")
        names = lines[0].split(",")
        rows = [ln.split(",") for ln in lines[1:]]
        r = data.draw(st.integers(0, len(rows) - 1), label="row")
        line = r + 2  # header is line 1
        expect = dict(line=line, field=None, words=())
        if kind in ("drop_column", "dup_column"):
            c = names.index(data.draw(st.sampled_from(REQUIRED)))
            op = (lambda f: f[:c] + f[c + 1:]) if kind == "drop_column" else (lambda f: f + [f[c]])
            lines = [",".join(op(ln.split(","))) for ln in lines]
            expect = dict(line=1, field=names[c], words=("missing" if kind == "drop_column" else "duplicate",))
        elif kind == "rename_deg":
            col = data.draw(st.sampled_from(["azimuth", "elevation"]))
            lines[0] = lines[0].replace(col, col + "_deg")
            expect = dict(line=1, field=col, words=(f"{col}_deg", "radians"))
        elif kind in ("nonfinite", "text", "bad_scan"):
            col = "scan" if kind == "bad_scan" else data.draw(st.sampled_from(REQUIRED))
            if kind == "nonfinite":
                value = data.draw(st.sampled_from(["nan", "inf", "-inf", "NaN", "1e999"]))
            elif kind == "text":
                value = data.draw(st.sampled_from(["abc", "1.2.3", "", "--1", "1e", "0x1F", "1_0", "#", "é"]))
            else:
                value = data.draw(st.sampled_from(["1.5", "1e3", "-1", "99999999999999999999", "nan"]))
            rows[r][names.index(col)] = value
            lines[r + 1] = ",".join(rows[r])
            expect["field"] = col
        elif kind == "negative_range":
            rows[r][names.index("range")] = repr(-data.draw(st.floats(1e-300, 1e6)))
            lines[r + 1] = ",".join(rows[r])
            expect.update(field="range", words=("negative",))
        elif kind == "degrees":
            col = data.draw(st.sampled_from(["azimuth", "elevation"]))
            deg = data.draw(st.floats(200.0, 359.0) if col == "azimuth" else st.floats(2.0, 89.0))
            rows[r][names.index(col)] = repr(deg * data.draw(st.sampled_from([1, -1])))
            lines[r + 1] = ",".join(rows[r])
            expect.update(field=col, words=("degrees",))
        elif kind == "truncate":
            text = lines[r + 1]
            last_comma = text.rindex(",")
            cut = data.draw(st.integers(1, last_comma))
            lines[r + 1] = text[:cut]
            nfields = len(text[:cut].split(","))
            expect.update(field=names[nfields], words=(f"got {nfields}",))
        elif kind == "extra_field":
            lines[r + 1] += ",1.0"
            expect.update(words=(f"got {len(names) + 1}",))
        elif kind == "swap_lines":
            pairs = [(i, j) for i in range(len(rows)) for j in range(i + 1, len(rows)) if rows[i][0] != rows[j][0]]
            i, j = data.draw(st.sampled_from(pairs))
            rows[i], rows[j] = rows[j], rows[i]
            lines[1:] = [",".join(x) for x in rows]
            k = first_order_violation(rows)
            expect = dict(line=k + 2, field=None, words=())
            expect_field_in = ("scan", "t")
        elif kind == "same_scan_other_t":
            same = [k for k in range(1, len(rows)) if rows[k][0] == rows[k - 1][0]]
            assume(same)
            k = data.draw(st.sampled_from(same))
            rows[k][1] = repr(float(rows[k][1]) + 1.0)
            lines[k + 1] = ",".join(rows[k])
            expect = dict(line=k + 2, field="t", words=("different times",))
        elif kind == "blank_line":
            lines.insert(r + 1, data.draw(st.sampled_from(["", " ", "\t"])))
            expect.update(words=("blank",))
        elif kind == "empty":
            csv.write_bytes(data.draw(st.sampled_from([b"", b"\xef\xbb\xbf", b"\n\n", b"  \r\n"])))
            err = read_error(d, "radar.csv")
            assert "empty" in str(err)
            return
        elif kind == "no_header":
            lines = lines[1:]
            expect = dict(line=1, field=None, words=("header",))
        csv.write_text("\n".join(lines) + "\n")
        err = read_error(d, "radar.csv")
        assert_located(err, **expect)
        if kind == "swap_lines":
            assert err.field in expect_field_in


TOML_MUTATIONS = ["unknown_top", "unknown_in_section", "syntax", "wrong_type", "missing_section", "missing_key",
                  "non_positive", "quaternion", "fov_degrees", "duplicate_key", "empty"]
SECTION_KEYS = {"noise": ["range", "azimuth", "elevation", "radial_velocity"],
                "fov": ["azimuth", "elevation", "max_range", "min_range"],
                "extrinsics": ["translation", "quaternion"]}


def _key_index(lines, section, key):
    current = None
    for i, ln in enumerate(lines):
        m = re.match(r"\[(\w+)\]", ln)
        if m:
            current = m.group(1)
        elif current == section and re.match(rf"{key}\s*=", ln):
            return i
    raise AssertionError((section, key))


@given(sequences(), st.sampled_from(TOML_MUTATIONS), st.data())
def test_malformed_sensor_toml_gives_input_error(seq, kind, data):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_sequence(d, seq)
        path = d / "sensor.toml"
        lines = path.read_text().rstrip("\n").split("\n")
        section = data.draw(st.sampled_from(sorted(SECTION_KEYS)))
        key = data.draw(st.sampled_from(SECTION_KEYS[section]))
        i = _key_index(lines, section, key)
        words, field, line = (), None, None
        if kind == "unknown_top":
            lines.insert(1, "doppler_sign = 1")
            line, field, words = 2, "doppler_sign", ("unknown key",)
        elif kind == "unknown_in_section":
            lines.insert(i + 1, "bogus = 2.0")
            line, field, words = i + 2, f"{section}.bogus", ("unknown key",)
        elif kind == "syntax":
            lines[i] = data.draw(st.sampled_from([f"{key} = = 1", f"{key} = [1.0, 2.0", f"{key}", "[noise"]))
            words = ("TOML syntax",)  # the parser may notice it on a later line
        elif kind == "wrong_type":
            value = data.draw(st.sampled_from(['"0.1"', "true", "{a = 1}", "[1.0, 2.0, 3.0, 4.0, 5.0]", "nan",
                                               "1" + "0" * 400, "[1" + "0" * 400 + ", 2, 3, 4]"]))
            lines[i] = f"{key} = {value}"
            line, field = i + 1, f"{section}.{key}"
        elif kind == "missing_section":
            start = next(k for k, ln in enumerate(lines) if ln.startswith(f"[{section}]"))
            end = next((k for k in range(start + 1, len(lines)) if lines[k].startswith("[")), len(lines))
            del lines[start:end]
            field, words = section, ("missing section",)
        elif kind == "missing_key":
            assume(key != "min_range")  # optional
            del lines[i]
            field, words = f"{section}.{key}", ("missing key",)
        elif kind == "non_positive":
            key = data.draw(st.sampled_from(SECTION_KEYS["noise"] + ["rate_hz"]))
            i = 1 if key == "rate_hz" else _key_index(lines, "noise", key)
            lines[i] = f"{key} = " + data.draw(st.sampled_from(["0.0", "-1e-3", "0"]))
            line, field = i + 1, key if key == "rate_hz" else f"noise.{key}"
        elif kind == "quaternion":
            i = _key_index(lines, "extrinsics", "quaternion")
            q = np.array([float(v) for v in lines[i].split("[")[1].split("]")[0].split(",")])
            q = q * (1.0 + data.draw(st.floats(1e-5, 0.5)) * data.draw(st.sampled_from([1, -0.5])))
            lines[i] = "quaternion = [" + ", ".join(map(repr, q.tolist())) + "]"
            line, field, words = i + 1, "extrinsics.quaternion", ("unit quaternion",)
        elif kind == "fov_degrees":
            i = _key_index(lines, "fov", "elevation")
            lines[i] = "elevation = [-20.0, 20.0]"
            line, field, words = i + 1, "fov.elevation", ("degrees",)
        elif kind == "duplicate_key":
            lines.insert(i + 1, lines[i])
            line, words = i + 2, ("TOML syntax",)
        elif kind == "empty":
            lines = [""]
            words = ("empty",)
        path.write_text("\n".join(lines) + "\n")
        err = read_error(d, "sensor.toml")
        assert_located(err, line, field, words)
        if kind in ("syntax", "duplicate_key"):
            assert err.line is not None and err.line >= i + 1


@given(sequences(min_nonempty=1, with_groundtruth=True),
       st.sampled_from(["radar.csv", "sensor.toml", "groundtruth.txt"]), st.data())
def test_random_byte_damage_never_escapes_as_another_exception(seq, name, data):
    """Garbage inserted anywhere: reading either succeeds or raises InputError naming the damaged file."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_sequence(d, seq)
        p = d / name
        raw = p.read_bytes()
        pos = data.draw(st.integers(0, len(raw)))
        cut = data.draw(st.integers(0, 8))
        junk = data.draw(st.binary(max_size=12) | st.sampled_from([b",", b"\n", b"\r", b"nan", b"-", b"#", b"\x00",
                                                                    b"\xff", b"[", b"=", b'"', b"e9999"]))
        p.write_bytes(raw[:pos] + junk + raw[pos + cut:])
        try:
            read_sequence(d, use_cache=data.draw(st.booleans()))
        except InputError as err:
            assert str(p) in str(err)
