"""Fuzzing a converter's input: whatever the bytes of a View-of-Delft radar directory, `convert vod` gives a
sequence that writes and reads back with only finite detections, or an InputError naming the file (a torn row,
values no float32 radar file holds: another dtype or byte order, or no detections at all); never another
exception. Sizes follow the hypothesis profile of tests/conftest.py (nightly: 1000 cases)."""

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.sim.convert import vod
from rodo.sim.sequence import read_sequence, write_sequence

ROW = 4 * len(vod.COLUMNS)
specials = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1e38, -1e38, 1e-40, 5.0, -3.0])
values = st.one_of(st.floats(width=32, allow_nan=True, allow_infinity=True), specials)


@st.composite
def bin_files(draw) -> list[bytes]:
    """1-3 files: whole rows of float32 values (any, including NaN, infinity, huge, subnormal), sometimes
    followed by a few stray bytes."""
    files = []
    for _ in range(draw(st.integers(1, 3))):
        rows = draw(st.lists(st.lists(values, min_size=len(vod.COLUMNS), max_size=len(vod.COLUMNS)), max_size=6))
        raw = np.asarray(rows, dtype="<f4").reshape(-1, len(vod.COLUMNS)).tobytes()
        files.append(raw + draw(st.one_of(st.just(b""), st.binary(min_size=1, max_size=ROW - 1))))
    return files


@given(bin_files())
@settings(suppress_health_check=[HealthCheck.too_slow], deadline=None)
def test_vod_bytes_convert_to_a_finite_sequence_or_a_named_input_error(files):
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "vod"
        src.mkdir()
        for k, raw in enumerate(files):
            (src / f"{k:05d}.bin").write_bytes(raw)
        try:
            conv = vod.convert(src)
        except InputError as exc:
            assert str(src) in str(exc) and "\n" not in str(exc), str(exc)
            torn = any(len(raw) % ROW for raw in files)
            assert torn or "wrong dtype or byte order?" in str(exc) or "no detections" in str(exc), str(exc)
            return
        assert all(len(raw) % ROW == 0 for raw in files)
        for scan in conv.sequence.scans:
            assert np.all(np.isfinite(scan.polar))
            assert np.all(scan.polar[:, 0] > 0)
        out = Path(d) / "seq"
        try:
            write_sequence(out, conv.sequence)
        except InputError as exc:
            assert str(out) in str(exc), str(exc)
            return
        back = read_sequence(out)
        assert len(back.scans) == len(conv.sequence.scans)
        for a, b in zip(back.scans, conv.sequence.scans):
            np.testing.assert_allclose(a.polar, b.polar, rtol=1e-12, atol=0)
