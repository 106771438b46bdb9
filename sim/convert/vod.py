"""View-of-Delft style radar frames (a directory of `*.bin`) -> the sequence format.

Layout: one file per scan, float32 little-endian, N x 7 columns
`x, y, z, RCS, v_r, v_r_compensated, time` (sensor frame x forward, y left, z up; v_r negative when
approaching, as the sequence format). Scans are taken in file-name order; scan k is at t = k / rate.
Polar coordinates from x, y, z (paper eq. 80); `RCS`, `v_r_compensated` and `time` are kept as the extra
columns `rcs`, `vr_compensated`, `point_time`. No ground truth; extrinsics identity unless given.

Checked by: tests/sim/test_convert.py::test_vod_*
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence

from ._common import Conversion, ConversionReport, field_of_view, polar_from_xyz, scans_from_rows

COLUMNS = ("x", "y", "z", "rcs", "v_r", "v_r_compensated", "time")
# nominal 1-sigma of a 3+1D automotive radar (VoD: ZF FRGen21); override with --sigma
DEFAULT_SIGMAS = NoiseSigmas(range=0.1, azimuth=float(np.deg2rad(1.5)), elevation=float(np.deg2rad(1.5)),
                             radial_velocity=0.1)


def read_bin(path) -> np.ndarray:
    """(N, 7) float64 from one VoD radar .bin; InputError naming the file when its size is not N x 28 bytes."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(raw) % (4 * len(COLUMNS)):
        raise InputError(f"{path}: size {len(raw)} bytes is not a multiple of {4 * len(COLUMNS)} "
                         f"(float32 x {len(COLUMNS)} columns: {', '.join(COLUMNS)})")
    return np.frombuffer(raw, dtype="<f4").reshape(-1, len(COLUMNS)).astype(np.float64)


def convert(source, rate_hz: float = 10.0, T_vehicle_sensor=None, noise: NoiseSigmas | None = None,
            max_range: float = 100.0) -> Conversion:
    """Convert a directory of VoD radar .bin files (see module docstring) into one Conversion named 'vod'.

    Args:
        source: directory with the *.bin files (one per scan).
        rate_hz: scan rate; scan k (file-name order) is at k / rate_hz seconds.
        T_vehicle_sensor: (4, 4) extrinsics, identity by default.
        noise: 1-sigma noise, DEFAULT_SIGMAS by default.
        max_range: sensor.toml's max range (m).

    Checked by: tests/sim/test_convert.py::test_vod_round_trip_times_extras_and_ego_velocity
    """
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"SOURCE: {source} is not a directory (expected VoD radar *.bin files)")
    if not (isinstance(rate_hz, (int, float)) and np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate: must be > 0, got {rate_hz!r}")
    files = sorted(source.glob("*.bin"))
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
    p = np.where(keep[:, None], data[:, :3], 1.0)
    rng, az, el = polar_from_xyz(p)
    keep &= report.drop("detections at zero range", keep & ~(rng > 1e-6))
    empty = int(np.sum(np.bincount(scan[keep], minlength=len(files)) == 0))
    if empty:
        report.notes.append(f"{empty} scan(s) without detections (no rows; the estimator bridges them)")
    extra = {"rcs": data[keep, 3], "vr_compensated": data[keep, 5], "point_time": data[keep, 6]}
    scans = scans_from_rows(report, scan[keep], t_scan, rng[keep], az[keep], el[keep], data[keep, 4], extra)
    sensor = SensorConfig(rate_hz=float(rate_hz), T_vehicle_sensor=np.eye(4) if T_vehicle_sensor is None
                          else T_vehicle_sensor, noise=noise or DEFAULT_SIGMAS,
                          azimuth_fov=field_of_view(az[keep], np.pi / 2, np.pi),
                          elevation_fov=field_of_view(el[keep], np.pi / 8, np.pi / 2), max_range=max_range)
    report.info.update({"files": [f.name for f in files], "rate_hz": float(rate_hz)})
    report.notes.append("scan times from --rate (k / rate); sigmas nominal unless --sigma; no ground truth")
    return Conversion("vod", Sequence(sensor=sensor, scans=scans, groundtruth=None), report)
