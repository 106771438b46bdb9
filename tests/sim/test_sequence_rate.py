"""radar.csv's times against sensor.toml's rate_hz (`sequence.check_scan_rate`): times written in milliseconds,
microseconds or nanoseconds, or a rate in the wrong unit, are refused by the reader and the writer, naming radar.csv's
field t and the unit they look like; scans missing from the file (no detections) or jittered are not a mismatch."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo.sim.sequence import RATE_MISMATCH, read_sequence, write_sequence
from tests.cli.helpers import fails


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    path = tmp_path_factory.mktemp("city")
    scenarios.simulate_to("city", 0, path, duration=1.0)
    return read_sequence(path)


def _with_times(seq, scale: float = 1.0, keep=None, rate_hz=None):
    scans = [dataclasses.replace(s, t=s.t * scale) for k, s in enumerate(seq.scans) if keep is None or keep(k)]
    sensor = seq.sensor if rate_hz is None else dataclasses.replace(seq.sensor, rate_hz=rate_hz)
    return dataclasses.replace(seq, scans=scans, sensor=sensor, groundtruth=None)


def _rewrite_times(path, scale: float) -> None:
    """radar.csv with its t column multiplied by scale (what a writer in other units would have written)."""
    lines = (path / "radar.csv").read_text().splitlines()
    names = lines[0].split(",")
    col = names.index("t")
    out = [lines[0]]
    for line in lines[1:]:
        fields = line.split(",")
        fields[col] = repr(float(fields[col]) * scale)
        out.append(",".join(fields))
    (path / "radar.csv").write_text("\n".join(out) + "\n")


@pytest.mark.parametrize("scale, unit", [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
def test_times_in_smaller_units_are_refused_naming_the_unit(city, tmp_path, capsys, scale, unit):
    write_sequence(tmp_path, _with_times(city))
    _rewrite_times(tmp_path, scale)
    with pytest.raises(InputError, match=rf"radar\.csv, field 't': .*rate_hz = 13 .*times in {unit}\?"):
        read_sequence(tmp_path, use_cache=False)
    fails(capsys, ["run", tmp_path, "--out", tmp_path / "out"], "radar.csv", "field 't'", unit)
    assert not (tmp_path / "out").exists()


def test_the_writer_refuses_what_the_reader_would(city, tmp_path):
    with pytest.raises(InputError, match=r"field 't': .*milliseconds"):
        write_sequence(tmp_path, _with_times(city, 1e3))
    assert not (tmp_path / "radar.csv").exists()


@pytest.mark.parametrize("rate_hz, hint", [(13e3, "times in milliseconds?"), (400.0, "is one of them in another unit?")])
def test_a_rate_in_the_wrong_unit_is_refused(city, tmp_path, rate_hz, hint):
    """A rate_hz that disagrees with scans 1/13 s apart: the message gives both files' units (a rate 1000x too
    high reads as times in milliseconds; one off by a factor no unit explains says so)."""
    with pytest.raises(InputError) as caught:
        write_sequence(tmp_path, _with_times(city, rate_hz=rate_hz))
    message = str(caught.value)
    assert f"rate_hz = {rate_hz:g} means {1 / rate_hz:.6g} s" in message and hint in message
    assert "radar.csv's t is in seconds, sensor.toml's rate_hz in Hz" in message


def test_missing_scans_are_no_mismatch(city, tmp_path):
    """Every third scan alone (the others without detections write no rows): the period per scan index is still
    1 / rate_hz, bit for bit the simulator's times."""
    seq = _with_times(city, keep=lambda k: k % 3 == 0)
    write_sequence(tmp_path, seq)
    back = read_sequence(tmp_path, use_cache=False)
    assert [s.t for s in back.scans] == [s.t for s in seq.scans]


@settings(max_examples=40, deadline=None)
@given(st.floats(0.01, 100.0), st.floats(0.5, 2.0 * RATE_MISMATCH))
def test_the_bound_is_a_factor_of_the_period(rate_hz, factor):
    """Scans a factor of the rate's period apart per scan index: accepted up to RATE_MISMATCH, refused beyond."""
    from rodo.sim.sequence import check_scan_rate
    from rodo.sim.sequence_types import RadarScan
    empty = np.zeros(0)
    scans = [RadarScan(scan=2 * k, t=2.0 * k * factor / rate_hz, range=empty, azimuth=empty, elevation=empty,
                       radial_velocity=empty) for k in range(4)]
    if factor * (1 + 1e-9) < RATE_MISMATCH:
        check_scan_rate(scans, rate_hz, "seq")
    elif factor > RATE_MISMATCH * (1 + 1e-9):
        with pytest.raises(InputError, match="field 't'"):
            check_scan_rate(scans, rate_hz, "seq")
