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
from rodo.sim.sequence import RATE_MISMATCH, check_scan_rate, read_sequence, write_sequence
from rodo.sim.sequence_types import RadarScan
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


@pytest.mark.parametrize("rate_hz, hint", [(200.0, "is one of them in another unit?"),
                                            (900.0, "is one of them in another unit?")])
def test_a_rate_in_the_wrong_unit_is_refused(city, tmp_path, rate_hz, hint):
    """A rate_hz that disagrees with scans 1/13 s apart: the message gives both files' units (one off by a factor
    no unit explains says so; a rate 1000x too high, 13 kHz, is no radar's and SensorConfig refuses it first)."""
    with pytest.raises(InputError) as caught:
        write_sequence(tmp_path, _with_times(city, rate_hz=rate_hz))
    message = str(caught.value)
    assert f"rate_hz = {rate_hz:g} means {1 / rate_hz:.6g} s" in message and hint in message
    assert "radar.csv's t is in seconds, sensor.toml's rate_hz in Hz" in message
    with pytest.raises(InputError, match=r"rate_hz: 13000.0 Hz is no radar's scan rate .* milliseconds"):
        _with_times(city, rate_hz=13e3)


def test_missing_scans_are_no_mismatch(city, tmp_path):
    """Every twelfth scan alone (the others without detections write no rows): the time steps are 12 periods, more
    than RATE_MISMATCH, but per scan index the period is 1 / rate_hz; read back bit for bit."""
    seq = _with_times(city, keep=lambda k: k % 12 == 0)
    assert len(seq.scans) >= 2
    write_sequence(tmp_path, seq)
    back = read_sequence(tmp_path, use_cache=False)
    assert [s.t for s in back.scans] == [s.t for s in seq.scans]


def _scans(index, t):
    empty = np.zeros(0)
    return [RadarScan(scan=int(k), t=float(tk), range=empty, azimuth=empty, elevation=empty, radial_velocity=empty)
            for k, tk in zip(index, t)]


def test_an_index_that_counts_something_else_is_no_mismatch():
    """Scans 1/13 s apart whose index steps by 1000 (a hardware counter): the per-index period is tiny, the time
    steps are right; accepted. Times 1000x too long with that index are still refused."""
    index = 1000 * np.arange(6)
    check_scan_rate(_scans(index, np.arange(6) / 13.0), 13.0, "seq")
    with pytest.raises(InputError, match="milliseconds"):
        check_scan_rate(_scans(np.arange(6), 1000 * np.arange(6) / 13.0), 13.0, "seq")


@pytest.mark.parametrize("t", [[-1e308, 1e308], [0.0, 5e-324]])
def test_extreme_times_are_an_error_not_a_traceback(t):
    """Finite times whose step overflows, or underflows to a period of 0: refused with the generic hint."""
    with pytest.raises(InputError, match="is one of them in another unit"):
        check_scan_rate(_scans([0, 1], t), 13.0, "seq")


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 100.0), st.floats(-np.log(2 * RATE_MISMATCH), np.log(2 * RATE_MISMATCH)))
def test_the_bound_is_a_factor_of_the_period_both_ways(rate_hz, log_factor):
    """Consecutive scans a factor of the rate's period apart: accepted within RATE_MISMATCH either way, refused
    beyond it, above or below."""
    factor = float(np.exp(log_factor))
    scans = _scans(np.arange(4), np.arange(4) * factor / rate_hz)
    margin = 1 + 1e-9
    if 1 / RATE_MISMATCH * margin < factor < RATE_MISMATCH / margin:
        check_scan_rate(scans, rate_hz, "seq")
    elif factor > RATE_MISMATCH * margin or factor < 1 / (RATE_MISMATCH * margin):
        with pytest.raises(InputError, match="field 't'"):
            check_scan_rate(scans, rate_hz, "seq")
