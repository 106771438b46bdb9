"""View-of-Delft style radar frames (a directory of `*.bin`) -> the sequence format.

Layout: one file per scan, float32 little-endian, N x 7 columns
`x, y, z, RCS, v_r, v_r_compensated, time` (sensor frame x forward, y left, z up; v_r negative when
approaching, as the sequence format). Scans are taken in the natural order of the file names (numbers by
value: 2.bin before 10.bin; zero-padded names sort as they read); scan k is at t = k / rate.
Polar coordinates from x, y, z (paper eq. 80); `RCS`, `v_r_compensated` and `time` are kept as the extra
columns `rcs`, `vr_compensated`, `point_time`. No ground truth; extrinsics identity unless given.

A file in another dtype or byte order (float64 rows are two float32 rows; big-endian float32 reads as
subnormal or huge values) is refused naming it: more than 1 % of its rows with an implausible value (|x|, |y|,
|z| > MAX_COORD_M, |v_r| > MAX_SPEED_MPS, or a subnormal float32, below 1.2e-38 in magnitude; fewer are
dropped and counted), or float64 values that are all float32 numbers (float32 data saved as float64). NaN or infinity in
x, y, z, v_r is dropped and counted (a sensor's invalid points). No detections at all is refused.

Checked by: tests/sim/test_convert.py::test_vod_*, tests/sim/test_convert_review55.py::test_vod_*
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence

from ._common import (MAX_DROP_SHARE, SCAN_RATE_HZ, Conversion, ConversionReport, field_of_view, polar_from_xyz,
                      require_detections, scans_from_rows)

COLUMNS = ("x", "y", "z", "rcs", "v_r", "v_r_compensated", "time")
MAX_COORD_M = 1e4  # m: |x|, |y|, |z| beyond it is no radar point (a wrong dtype or byte order)
MAX_SPEED_MPS = 1e3  # m/s: |v_r|, |v_r_compensated| beyond it, likewise
TINY = float(np.finfo(np.float32).tiny)  # a non-zero |value| below it (a subnormal): another byte order or dtype
RULE = f"|x|, |y|, |z| > {MAX_COORD_M:g} m, |v_r| > {MAX_SPEED_MPS:g} m/s or 0 < |value| < {TINY:.3g}"
IMPLAUSIBLE = f"detections with implausible values ({RULE})"
DTYPE_HINT = ("wrong dtype or byte order? (expected little-endian float32 x, y, z, rcs, v_r, v_r_compensated, "
              "time)")
# nominal 1-sigma of a 3+1D automotive radar (VoD: ZF FRGen21); override with --sigma
DEFAULT_SIGMAS = NoiseSigmas(range=0.1, azimuth=float(np.deg2rad(1.5)), elevation=float(np.deg2rad(1.5)),
                             radial_velocity=0.1)


def read_bin(path) -> np.ndarray:
    """(N, 7) float64 from one VoD radar .bin; InputError naming the file when its size is not N x 28 bytes or
    its values say another dtype or byte order (module docstring).

    Checked by: tests/sim/test_convert_review55.py::test_vod_float64_or_big_endian_files_are_refused
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(raw) % (4 * len(COLUMNS)):
        raise InputError(f"{path}: size {len(raw)} bytes is not a multiple of {4 * len(COLUMNS)} "
                         f"(float32 x {len(COLUMNS)} columns: {', '.join(COLUMNS)})")
    if _float32_as_float64(raw):
        raise InputError(f"{path}: read as float64, its {len(raw) // 8} values are plausible and all float32 "
                         f"numbers (float32 data saved as float64?): {DTYPE_HINT}")
    data = np.frombuffer(raw, dtype="<f4").reshape(-1, len(COLUMNS)).astype(np.float64)
    bad = implausible(data)
    if bad.sum() > MAX_DROP_SHARE * len(data):
        k = int(np.flatnonzero(bad)[0])
        c = int(np.flatnonzero(_implausible_values(data[k]))[0])
        raise InputError(f"{path}, row {k}, column '{COLUMNS[c]}': {float(data[k, c])!r} ({int(bad.sum())} of "
                         f"{len(data)} rows with {RULE}): {DTYPE_HINT}")
    return data


def _implausible_values(data: np.ndarray) -> np.ndarray:
    """(..., 7) -> (..., 7) True where a finite value is no radar's (module docstring)."""
    limit = np.array([MAX_COORD_M] * 3 + [np.inf, MAX_SPEED_MPS, MAX_SPEED_MPS, np.inf])
    a = np.abs(np.where(np.isfinite(data), data, 0.0))
    return (a > limit) | ((a > 0) & (a < TINY))


def implausible(data: np.ndarray) -> np.ndarray:
    """(N, 7) rows -> (N,) True where a finite value is implausible (module docstring)."""
    return np.any(_implausible_values(data), axis=1)


def _float32_as_float64(raw: bytes) -> bool:
    """The bytes read as float64 are finite, plausible, not all zero, and every one a float32 number: float32
    data saved as float64 (as float32 they are plausible-looking garbage: 10, 1 reads as 0, 2.5625, 0, 1.875)."""
    if not raw or len(raw) % (8 * len(COLUMNS)):
        return False
    d = np.frombuffer(raw, dtype="<f8")
    if not np.all(np.isfinite(d)) or not np.any(d) or np.any(_implausible_values(d.reshape(-1, len(COLUMNS)))):
        return False
    return bool(np.all(d.astype(np.float32).astype(np.float64) == d))


def natural_key(name: str) -> list:
    """Sort key of a file name with its digit runs compared as numbers ('2.bin' < '10.bin'), ties by name."""
    parts = re.split(r"(\d+)", name)
    return [int(p) if i % 2 else p for i, p in enumerate(parts)] + [name]


def convert(source, rate_hz: float = 10.0, T_vehicle_sensor=None, noise: NoiseSigmas | None = None,
            max_range: float = 100.0) -> Conversion:
    """Convert a directory of VoD radar .bin files (see module docstring) into one Conversion named 'vod'.

    Args:
        source: directory with the *.bin files (one per scan).
        rate_hz: scan rate (0.1-1000 Hz); scan k (natural file-name order) is at k / rate_hz seconds.
        T_vehicle_sensor: (4, 4) extrinsics, identity by default.
        noise: 1-sigma noise, DEFAULT_SIGMAS by default.
        max_range: sensor.toml's max range (m).

    Checked by: tests/sim/test_convert.py::test_vod_round_trip_times_extras_and_ego_velocity,
        tests/sim/test_convert_review55.py::test_vod_unpadded_names_are_taken_in_numeric_order
    """
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"SOURCE: {source} is not a directory (expected VoD radar *.bin files)")
    lo, hi = SCAN_RATE_HZ
    if not (isinstance(rate_hz, (int, float)) and np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate: must be > 0, got {rate_hz!r}")
    if not lo <= rate_hz <= hi:
        raise InputError(f"--rate: must be a scan rate from {lo:g} to {hi:g} Hz, got {rate_hz!r}")
    files = sorted(source.glob("*.bin"), key=lambda f: natural_key(f.name))
    if not files:
        raise InputError(f"SOURCE: no *.bin files in {source}")
    report = ConversionReport("vod", str(source))
    frames = [read_bin(f) for f in files]
    n = np.array([len(f) for f in frames])
    data = np.concatenate(frames) if n.sum() else np.zeros((0, len(COLUMNS)))
    scan = np.repeat(np.arange(len(files)), n)
    t_scan = np.arange(len(files)) / float(rate_hz)
    keep = report.drop("detections with NaN or infinity in x, y, z or v_r",
                       ~np.all(np.isfinite(data[:, [0, 1, 2, 4]]), axis=1))
    keep &= report.drop(IMPLAUSIBLE, keep & implausible(data))
    p = np.where(keep[:, None], data[:, :3], 1.0)
    rng, az, el = polar_from_xyz(p)
    keep &= report.drop("detections at zero range", keep & ~(rng > 1e-6))
    empty = int(np.sum(np.bincount(scan[keep], minlength=len(files)) == 0))
    if empty:
        report.notes.append(f"{empty} scan(s) without detections (no rows; the estimator bridges them)")
    extra = {"rcs": data[keep, 3], "vr_compensated": data[keep, 5], "point_time": data[keep, 6]}
    scans = scans_from_rows(report, scan[keep], t_scan, rng[keep], az[keep], el[keep], data[keep, 4], extra)
    require_detections(report, source)
    sensor = SensorConfig(rate_hz=float(rate_hz), T_vehicle_sensor=np.eye(4) if T_vehicle_sensor is None
                          else T_vehicle_sensor, noise=noise or DEFAULT_SIGMAS,
                          azimuth_fov=field_of_view(az[keep], np.pi / 2, np.pi),
                          elevation_fov=field_of_view(el[keep], np.pi / 8, np.pi / 2), max_range=max_range)
    report.info.update({"files": [f.name for f in files], "rate_hz": float(rate_hz)})
    report.notes.append("scan times from --rate (k / rate); sigmas nominal unless --sigma; no ground truth")
    return Conversion("vod", Sequence(sensor=sensor, scans=scans, groundtruth=None), report)
