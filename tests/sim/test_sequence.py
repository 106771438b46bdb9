"""Sequence format: bit-exact round trip, deterministic bytes, cache, validation (docs/sequence_format.md).

The hypothesis strategies for sequences live here and are imported by test_sequence_fuzz.py.
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rodo.estimator.lie import se3, so3
from rodo.sim.sequence import NoiseSigmas, RadarScan, SensorConfig, Sequence, Trajectory
from tests.strategies import rotation_vectors, vectors

_fin = dict(allow_nan=False, allow_infinity=False)


@st.composite
def sensor_configs(draw):
    T = se3.from_rotation_translation(so3.exp(draw(rotation_vectors("any"))), draw(vectors(3, 5.0)))
    sig = [draw(st.floats(1e-9, 1.0)) for _ in range(4)]
    az = (draw(st.floats(-np.pi, -1e-3)), draw(st.floats(1e-3, np.pi)))
    el = (draw(st.floats(-np.pi / 2, -1e-3)), draw(st.floats(1e-3, np.pi / 2)))
    max_range = draw(st.floats(1.0, 1e4).filter(lambda m: m > sig[0]))  # the range noise below the range
    return SensorConfig(rate_hz=draw(st.floats(0.1, 1e3)), T_vehicle_sensor=T, noise=NoiseSigmas(*sig),
                        azimuth_fov=az, elevation_fov=el, max_range=max_range,
                        min_range=draw(st.floats(0.0, 0.5)))


def _col(n, lo, hi):
    return arrays(np.float64, (n,), elements=st.floats(lo, hi, **_fin))


@st.composite
def scan_lists(draw, rate_hz: float = 10.0, min_nonempty: int = 0, max_scans: int = 6, max_rows: int = 5):
    """Scans with increasing (gappy) indices, some empty, full-range float values; times whose period per scan
    index is within a factor 5 of 1 / rate_hz, each scan up to 0.4 periods late (sequence.check_scan_rate)."""
    k = draw(st.integers(min_nonempty, max_scans))
    indices = sorted(draw(st.lists(st.integers(0, 10**6), min_size=k, max_size=k, unique=True)))
    period = draw(st.floats(0.2, 5.0)) / rate_hz
    t = draw(st.floats(-1e6, 1e6)) + period * (np.array(indices, dtype=float)
                                               + np.array([draw(st.floats(0.0, 0.4)) for _ in range(k)]))
    extras = draw(st.sampled_from([(), ("snr",), ("snr", "rcs")]))
    nonempty = set(draw(st.permutations(range(k)))[:min_nonempty]) if k else set()
    scans = []
    for j in range(k):
        n = draw(st.integers(1 if j in nonempty else 0, max_rows))
        scans.append(RadarScan(
            scan=indices[j], t=float(t[j]), range=draw(_col(n, 0.0, 1e6)),
            azimuth=draw(_col(n, -np.pi, np.pi)), elevation=draw(_col(n, -np.pi / 2, np.pi / 2)),
            radial_velocity=draw(_col(n, -1e3, 1e3)), extra={e: draw(_col(n, -1e300, 1e300)) for e in extras}))
    return scans


@st.composite
def trajectories_at(draw, times):
    times = np.asarray(times, dtype=float)
    xi = np.array([draw(st.tuples(vectors(3, 1e3), rotation_vectors("any")).map(np.concatenate))
                   for _ in range(times.size)]).reshape(-1, 6)
    return Trajectory(t=times, T_world_vehicle=se3.exp(xi).reshape(-1, 4, 4))


@st.composite
def sequences(draw, min_nonempty: int = 0, with_groundtruth=None):
    sensor = draw(sensor_configs())
    scans = draw(scan_lists(sensor.rate_hz, min_nonempty=min_nonempty))
    gt = None
    want_gt = draw(st.booleans()) if with_groundtruth is None else with_groundtruth
    if scans and want_gt:
        gt = draw(trajectories_at([s.t for s in scans]))
    return Sequence(sensor=sensor, scans=scans, groundtruth=gt)


def same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


# ---------------------------------------------------------------------------------------------------- tests
import os  # noqa: E402
import tempfile  # noqa: E402
from rodo.estimator.tomlcompat import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from hypothesis import given  # noqa: E402

from rodo.estimator.errors import InputError  # noqa: E402
from rodo.sim import radar_csv  # noqa: E402
from rodo.sim.sequence import (  # noqa: E402
    cache_path,
    polar_to_cartesian,
    read_sensor_config,
    read_sequence,
    write_sensor_config,
    write_sequence,
)

FIELDS = ("range", "azimuth", "elevation", "radial_velocity")


def assert_sensor_equal(a: SensorConfig, b: SensorConfig):
    """Scalars bit-exact; the rotation goes through a quaternion, so T is compared to 4e-15 (a few ulp)."""
    assert (a.rate_hz, a.noise, a.azimuth_fov, a.elevation_fov, a.max_range, a.min_range) == \
        (b.rate_hz, b.noise, b.azimuth_fov, b.elevation_fov, b.max_range, b.min_range)
    assert same_bits(a.T_vehicle_sensor[:3, 3], b.T_vehicle_sensor[:3, 3])
    np.testing.assert_allclose(a.T_vehicle_sensor, b.T_vehicle_sensor, rtol=0, atol=4e-15)


def files_bytes(d) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(Path(d).iterdir()) if not p.name.startswith(".")}


@given(sequences())
def test_round_trip_is_bit_exact_and_deterministic(seq):
    with tempfile.TemporaryDirectory() as tmp:
        a, b, c = Path(tmp, "a"), Path(tmp, "b"), Path(tmp, "c")
        write_sequence(a, seq)
        back = read_sequence(a, use_cache=False)
        nonempty = [s for s in seq.scans if len(s)]
        assert [s.scan for s in back.scans] == [s.scan for s in nonempty]
        for orig, got in zip(nonempty, back.scans):
            assert same_bits(np.float64(orig.t), np.float64(got.t)) and len(got) == len(orig)
            for name in FIELDS:
                assert same_bits(getattr(orig, name), getattr(got, name)), name
            assert list(got.extra) == list(orig.extra)
            for name in orig.extra:
                assert same_bits(orig.extra[name], got.extra[name]), name
        assert_sensor_equal(seq.sensor, back.sensor)
        if seq.groundtruth is None:
            assert back.groundtruth is None
        else:  # TUM is written with %.9f
            np.testing.assert_allclose(back.groundtruth.t, seq.groundtruth.t, rtol=0, atol=6e-10)
            np.testing.assert_allclose(back.groundtruth.T_world_vehicle, seq.groundtruth.T_world_vehicle,
                                       rtol=0, atol=3e-8)
        # same sequence -> same bytes; and writing what was read reproduces radar.csv byte for byte
        write_sequence(b, seq)
        assert files_bytes(a) == files_bytes(b)
        write_sequence(c, back)
        assert (c / "radar.csv").read_bytes() == (a / "radar.csv").read_bytes()
        # the cached read gives the same bits as the parsed one
        first, cached = read_sequence(a), read_sequence(a)
        assert cache_path(a / "radar.csv").is_file()
        for x, y, z in zip(back.scans, first.scans, cached.scans):
            for name in FIELDS:
                assert same_bits(getattr(x, name), getattr(y, name))
                assert same_bits(getattr(x, name), getattr(z, name))


@given(sensor_configs())
def test_sensor_config_round_trip(cfg):
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp, "sensor.toml")
        write_sensor_config(p, cfg)
        back = read_sensor_config(p)
        assert_sensor_equal(cfg, back)
        q = np.array(tomllib.loads(p.read_text())["extrinsics"]["quaternion"])
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-15


@given(st.floats(1e-3, 1e4), st.floats(-np.pi, np.pi), st.floats(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6))
def test_polar_to_cartesian_inverts_polar_model(r, az, el):
    """Inverse of paper eq. 80: range = |p|, azimuth = atan2(y, x), elevation = asin(z / r)."""
    p = polar_to_cartesian([r], [az], [el])
    assert p.shape == (1, 3)
    x, y, z = p[0]
    assert np.isclose(np.linalg.norm(p[0]), r, rtol=1e-12)
    assert np.isclose(np.arcsin(z / r), el, atol=1e-9)
    if abs(np.cos(el)) > 1e-6:
        d = np.angle(np.exp(1j * (np.arctan2(y, x) - az)))
        assert abs(d) < 1e-9


def test_scan_properties_and_axes():
    scan = RadarScan(scan=3, t=0.5, range=[2.0, 3.0], azimuth=[0.0, np.pi / 2], elevation=[0.0, 0.0],
                     radial_velocity=[-1.0, 0.5])
    assert len(scan) == 2 and scan.polar.shape == (2, 4)
    np.testing.assert_allclose(scan.points_sensor, [[2.0, 0, 0], [0, 3.0, 0]], atol=1e-15)  # x fwd, y left
    up = polar_to_cartesian(1.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(up, [0, 0, 1.0], atol=1e-15)  # z up
    assert scan.polar[1, 3] == 0.5
    assert np.array_equal(NoiseSigmas(1, 2, 0.5, 4).as_array(), [1, 2, 0.5, 4])


def _write_example(d, **kw) -> Sequence:
    cfg = SensorConfig(13.0, np.eye(4), NoiseSigmas(0.02, 0.0026, 0.005, 0.01), (-1.0, 1.0), (-0.3, 0.3), 100.0)
    scans = [RadarScan(0, 0.0, [1.0, 2.0], [0.1, -0.2], [0.0, 0.1], [-1.0, 1.0], {"snr": [3.0, 4.0]}),
             RadarScan(1, 0.1, [], [], [], [], {}),
             RadarScan(3, 0.3, [150.0], [0.0], [0.0], [0.0], {"snr": [np.nan]})]
    seq = Sequence(cfg, scans, kw.get("groundtruth"))
    write_sequence(d, seq)
    return seq


def test_bom_crlf_column_order_and_nan_extras_are_accepted(tmp_path):
    _write_example(tmp_path)
    ref = read_sequence(tmp_path, use_cache=False)
    assert len(ref.scans) == 2 and np.isnan(ref.scans[1].extra["snr"][0])
    assert ref.scans[1].range[0] == 150.0  # beyond max_range is allowed
    for name in ("radar.csv", "sensor.toml"):
        p = tmp_path / name
        p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))
    got = read_sequence(tmp_path, use_cache=False)
    assert [len(s) for s in got.scans] == [2, 1] and got.sensor == ref.sensor
    # columns in another order, extras in between
    (tmp_path / "radar.csv").write_text("t,snr,range,scan,azimuth,radial_velocity,elevation\n"
                                        "0.5,1,2.0,7,0.1,-3.0,0.2\n")
    (s,) = read_sequence(tmp_path, use_cache=False).scans
    assert (s.scan, s.t, s.range[0], s.azimuth[0], s.elevation[0], s.radial_velocity[0], s.extra["snr"][0]) == \
        (7, 0.5, 2.0, 0.1, 0.2, -3.0, 1.0)


def test_header_only_is_a_sequence_without_scans(tmp_path):
    _write_example(tmp_path)
    (tmp_path / "radar.csv").write_text("scan,t,range,azimuth,elevation,radial_velocity\n")
    assert read_sequence(tmp_path).scans == []


def test_missing_files_and_directory(tmp_path):
    with pytest.raises(InputError, match="not a sequence directory"):
        read_sequence(tmp_path / "nope")
    _write_example(tmp_path)
    (tmp_path / "sensor.toml").unlink()
    with pytest.raises(InputError, match=r"sensor\.toml: file not found"):
        read_sequence(tmp_path)
    _write_example(tmp_path)
    (tmp_path / "radar.csv").unlink()
    with pytest.raises(InputError, match=r"radar\.csv: file not found"):
        read_sequence(tmp_path)


def test_stale_groundtruth_and_cache_are_removed_and_other_files_kept(tmp_path):
    traj = Trajectory(np.array([0.0, 0.1]), np.stack([np.eye(4)] * 2))
    _write_example(tmp_path, groundtruth=traj)
    (tmp_path / "truth.npz").write_bytes(b"x")
    read_sequence(tmp_path)
    assert (tmp_path / "groundtruth.txt").is_file() and cache_path(tmp_path / "radar.csv").is_file()
    _write_example(tmp_path)
    assert not (tmp_path / "groundtruth.txt").exists() and not cache_path(tmp_path / "radar.csv").exists()
    assert (tmp_path / "truth.npz").read_bytes() == b"x"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_cache_is_used_and_invalidated(tmp_path, monkeypatch):
    _write_example(tmp_path)
    csv = tmp_path / "radar.csv"
    read_sequence(tmp_path, use_cache=False)
    assert not cache_path(csv).exists()  # use_cache=False neither reads nor writes it
    ref = read_sequence(tmp_path)
    assert cache_path(csv).is_file()

    calls = []
    real_parse = radar_csv.parse_radar_csv

    def counting_parse(path, text):
        calls.append(path)
        return real_parse(path, text)

    monkeypatch.setattr(radar_csv, "parse_radar_csv", counting_parse)
    hit = read_sequence(tmp_path)
    assert calls == []  # served from the cache
    assert [same_bits(a.range, b.range) for a, b in zip(ref.scans, hit.scans)] == [True, True]

    # same size, same mtime, different bytes in the first KiB: the hash catches it
    st_ = os.stat(csv)
    text = csv.read_text()
    changed = text.replace("0,0.0,2.0,", "0,0.0,5.0,")
    assert len(changed) == len(text) and changed != text
    csv.write_text(changed)
    os.utime(csv, ns=(st_.st_atime_ns, st_.st_mtime_ns))
    got = read_sequence(tmp_path)
    assert len(calls) == 1 and got.scans[0].range[1] == 5.0
    assert read_sequence(tmp_path).scans[0].range[1] == 5.0 and len(calls) == 1  # re-cached

    # a different mtime alone invalidates it too
    os.utime(csv, ns=(st_.st_atime_ns, st_.st_mtime_ns + 10**9))
    read_sequence(tmp_path)
    assert len(calls) == 2
    # a corrupt cache is ignored and rewritten
    cache_path(csv).write_bytes(b"garbage")
    assert read_sequence(tmp_path).scans[0].range[1] == 5.0 and len(calls) == 3
    # an invalid CSV is never masked by an old cache
    csv.write_text(changed.replace("5.0", "-5.0"))
    with pytest.raises(InputError, match="negative"):
        read_sequence(tmp_path)


def test_writer_rejects_what_the_reader_would(tmp_path):
    cfg = _write_example(tmp_path).sensor

    def scan(i, t, r=1.0, el=0.0, extra=None):
        return RadarScan(i, t, [r], [0.0], [el], [0.0], extra or {})

    bad = {
        "must strictly increase": [scan(1, 0.0), scan(1, 0.1)],
        "strictly increase": [scan(1, 0.1), scan(2, 0.1)],
        "negative range": [scan(1, 0.0, r=-1.0)],
        "elevation": [scan(1, 0.0, el=2.0)],
        "NaN": [scan(1, 0.0, r=np.nan)],
        "differ": [scan(1, 0.0, extra={"snr": [1.0]}), scan(2, 0.1)],
        "reserved": [scan(1, 0.0, extra={"range": [1.0]})],
    }
    for message, scans in bad.items():
        with pytest.raises(InputError, match=message):
            write_sequence(tmp_path / "out", Sequence(cfg, scans, None))
        assert not (tmp_path / "out" / "radar.csv").exists()  # nothing written


def test_sensor_config_rejects_bad_values():
    good = dict(rate_hz=13.0, T_vehicle_sensor=np.eye(4), noise=NoiseSigmas(0.02, 0.003, 0.005, 0.01),
                azimuth_fov=(-1.0, 1.0), elevation_fov=(-0.3, 0.3), max_range=100.0)
    SensorConfig(**good)
    T = np.eye(4)
    T[0, 1] = 0.1
    for key, value, message in [("rate_hz", 0.0, "rate_hz"), ("T_vehicle_sensor", T, "rotation"),
                                ("elevation_fov", (-20.0, 20.0), "degrees"), ("max_range", -1.0, "max_range"),
                                ("rate_hz", True, "number"), ("min_range", 200.0, "min_range"),
                                ("rate_hz", 1.02e7, r"rate_hz: 10200000.0 Hz is no radar's scan rate .*milliseconds"),
                                ("rate_hz", 0.0132, r"rate_hz: 0.0132 Hz is no radar's scan rate")]:
        with pytest.raises(InputError, match=message):
            SensorConfig(**{**good, key: value})
    with pytest.raises(InputError, match="NoiseSigmas.range"):
        NoiseSigmas(0.0, 1.0, 1.0, 1.0)
    for noise, message in [(NoiseSigmas(100.0, 0.003, 0.005, 0.01), "noise.range.*not below fov.max_range"),
                           (NoiseSigmas(0.02, 0.003, 0.005, 0.036 * 3600), "noise.radial_velocity.*km/h")]:
        with pytest.raises(InputError, match=message):  # values the estimator cannot use, or in other units
            SensorConfig(**{**good, "noise": noise})
    mm = np.eye(4)
    mm[:3, 3] = [3500.0, 0.0, 500.0]
    with pytest.raises(InputError, match="extrinsics.translation: .* millimetres"):
        SensorConfig(**{**good, "T_vehicle_sensor": mm})


def test_sensor_toml_in_other_units_names_the_field(tmp_path):
    """sensor.toml with the mount in millimetres, or a range noise beyond the field of view, is refused naming
    the file, line and field, not run (the millimetres gave an ATE of 0.9 m on a 19 m path with no word)."""
    good = tmp_path / "good"
    write_sequence(good, Sequence(SensorConfig(13.0, np.eye(4), NoiseSigmas(0.02, 0.003, 0.005, 0.01), (-1.0, 1.0),
                                               (-0.3, 0.3), 100.0), [RadarScan(0, 0.0, [10.0], [0.1], [0.0], [1.0])]))
    text = (good / "sensor.toml").read_text()
    for old, new, field in [("translation = [0.0, 0.0, 0.0]", "translation = [3500.0, 0.0, 500.0]",
                             "extrinsics.translation"), ("range = 0.02", "range = 1000000.0", "noise.range"),
                            ("rate_hz = 13.0", "rate_hz = 13000.0", "rate_hz")]:
        assert old in text
        bad = tmp_path / field
        bad.mkdir()
        for name in ("radar.csv",):
            (bad / name).write_bytes((good / name).read_bytes())
        (bad / "sensor.toml").write_text(text.replace(old, new))
        with pytest.raises(InputError, match=f"sensor.toml, line \\d+, field '{field}'"):
            read_sequence(bad)


def test_examples_in_the_format_document_are_valid(tmp_path):
    """docs/sequence_format.md's example files read back as described there."""
    import re

    doc = (Path(__file__).resolve().parents[2] / "docs" / "sequence_format.md").read_text()
    blocks = re.findall(r"```(\w*)\n(.*?)```", doc, re.S)
    csv_block = next(b for lang, b in blocks if b.startswith("scan,t,"))
    toml_block = next(b for lang, b in blocks if lang == "toml")
    tum_block = next(b for lang, b in blocks if b.startswith("# t tx"))
    for name, text in (("radar.csv", csv_block), ("sensor.toml", toml_block), ("groundtruth.txt", tum_block)):
        (tmp_path / name).write_text(text)
    seq = read_sequence(tmp_path)
    assert [(s.scan, len(s), list(s.extra)) for s in seq.scans] == [(0, 2, ["snr"]), (2, 1, ["snr"])]
    assert seq.sensor.T_vehicle_sensor[0, 3] == 3.5 and seq.sensor.min_range == 0.5
    assert len(seq.groundtruth) == 2
