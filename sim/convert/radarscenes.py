"""RadarScenes (2D + Doppler, 4 radars, odometry) export -> the sequence format, one sequence per radar.

Input layout (the folder `radarscenes_seq105_2d`, see its README): `radar{N}_detections.csv.gz` with columns
`scan_idx,range_m,azimuth_rad,vr_mps,rcs_dbsm,vr_comp_mps,label_id` and `radar{N}_timestamp_and_odom.csv` with
`timestamp_rad,timestamp_odom,x_loc,y_loc,yaw_loc,vx_ego,yaw_rate_ego` (row i <-> scan_idx i + 1).

Output per radar: radar.csv (elevation 0, extra columns `label`, `rcs`), sensor.toml (mounting as extrinsics,
sigmas estimated from the data, elevation sigma ELEVATION_SIGMA: unknown elevation), groundtruth.txt (odometry
pose moved to the scan time), odom.csv, conversion.json. Details and measured numbers: docs/realdata.md.

Sensor velocity implied by the odometry (README formula; the oracle of the ego-velocity checks):
v_vehicle = (vx - w y_m, w x_m) at the mounting (x_m, y_m), rotated into the sensor frame by -yaw_m;
a static target at azimuth az then has v_r = -(cos az, sin az) . v_sensor.

Refused, naming the file, line and field (an offset or a unit would move groundtruth.txt by 100 m to tens of
km, degrees would keep a few wrong azimuths): scan times whose median step is no scan rate (0.1-1000 Hz),
|timestamp_rad - timestamp_odom| above MAX_ODOM_OFFSET_S, more than 1 % of the azimuths outside [-pi, pi]
(fewer are dropped and counted), no detections.

Checked by: tests/sim/test_convert.py, tests/validation/test_realdata.py, tests/sim/test_convert_review55.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import so3
from rodo.estimator.sensor_values import ANGLE_BOUNDS, angle_hint
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence, Trajectory

from ._common import (Conversion, ConversionReport, check_scan_step, drop_few, field_of_view, planar_poses,
                      read_csv, require_detections, scans_from_rows)

# radar -> (x_m, y_m, yaw_rad) in the vehicle frame (origin rear-axle centre), from the export's const.py
MOUNTING = {1: (3.663, -0.873, -1.48418552), 2: (3.86, -0.70, -0.436185662),
            3: (3.86, 0.70, 0.436), 4: (3.663, 0.873, 1.484)}
ELEVATION_SIGMA = np.deg2rad(10.0)  # 2D radar: elevation unknown, reported as 0 with a large sigma
ELEVATION_FOV = 1e-4                # rad; |elevation| fov below PLANAR_ELEVATION marks the sensor planar
RANGE_SIGMA = 0.1                   # m; not observable from single scans (nominal; see docs/realdata.md)
NOMINAL_SIGMAS = (0.1, float(np.deg2rad(0.5)))  # (sigma_vr, sigma_az) when the data cannot tell
STATIC_LABEL = 11
DET_COLUMNS = ("scan_idx", "range_m", "azimuth_rad", "vr_mps", "rcs_dbsm", "vr_comp_mps", "label_id")
MIN_SCAN_STEP = 1e-6  # s
ODOM_LIMIT = 1e9  # s, m, rad, m/s, rad/s: larger odometry values are refused
MAX_ODOM_OFFSET_S = 1.0  # s: |timestamp_rad - timestamp_odom| above it is refused (sequence 105: at most 0.136 s)
ODOM_COLUMNS = ("timestamp_rad", "timestamp_odom", "x_loc", "y_loc", "yaw_loc", "vx_ego", "yaw_rate_ego")


def parse_radars(text: str) -> list[int]:
    """'2' or '2,3' -> [2] or [2, 3]; InputError naming --radars for anything else."""
    try:
        radars = [int(s) for s in str(text).split(",")]
    except ValueError:
        raise InputError(f"--radars: expected radar numbers 1-4 separated by commas (e.g. 2,3), got {text!r}") from None
    bad = [r for r in radars if r not in MOUNTING]
    if bad or not radars:
        raise InputError(f"--radars: radar numbers must be in 1-4, got {text!r}")
    if len(set(radars)) != len(radars):
        raise InputError(f"--radars: duplicate radar in {text!r}")
    return radars


def T_vehicle_sensor(radar: int) -> np.ndarray:
    """(4, 4) mounting of a radar: translation (x_m, y_m, 0), rotation yaw_m about z (height unknown: 0)."""
    x, y, yaw = MOUNTING[radar]
    T = np.eye(4)
    T[:3, :3] = so3.exp(np.array([0.0, 0.0, yaw]))
    T[:2, 3] = x, y
    return T


def sensor_velocity(radar: int, vx, yaw_rate) -> np.ndarray:
    """Planar sensor velocity in the sensor frame from odometry speed and yaw rate, (M,) -> (M, 2).

    v_vehicle = (vx - w y_m, w x_m); v_sensor = R(-yaw_m) v_vehicle (rigid-body velocity at the mounting).

    Checked by: tests/validation/test_realdata.py::test_radarscenes_doppler_matches_odometry
    """
    x, y, yaw = MOUNTING[radar]
    vx = np.asarray(vx, dtype=float)
    w = np.asarray(yaw_rate, dtype=float)
    vvx, vvy = vx - w * y, w * x
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * vvx + s * vvy, -s * vvx + c * vvy], axis=-1)


def estimate_noise(azimuth, radial_velocity, v_sensor) -> tuple[float, float]:
    """Radial-velocity and azimuth 1-sigma from static detections' Doppler residuals against a known velocity.

    Residual e = v_r + u(az) . v. An azimuth error d enters as g d with g = u'(az) . v, so per bin of |g|
    Var(e) = sigma_vr^2 + sigma_az^2 g^2. Robust variances (1.4826 MAD) in 10 quantile bins of |g|, fitted by
    non-negative least squares. Odometry errors are part of the residual: the values are upper bounds.

    Args:
        azimuth, radial_velocity: (n,) static detections; v_sensor: (n, 2) sensor velocity at each.

    Returns:
        (sigma_vr m/s, sigma_azimuth rad), or None with fewer than 200 usable static detections.
    """
    from scipy.optimize import nnls

    c, s = np.cos(azimuth), np.sin(azimuth)
    e = radial_velocity + c * v_sensor[:, 0] + s * v_sensor[:, 1]
    g = -s * v_sensor[:, 0] + c * v_sensor[:, 1]
    keep = np.abs(e) < 1.0  # gross outliers (mislabelled movers, multipath) out
    e, g = e[keep], np.abs(g[keep])
    if len(e) < 200:
        return None
    edges = np.quantile(g, np.linspace(0, 1, 11))
    idx = np.clip(np.searchsorted(edges, g, side="right") - 1, 0, 9)
    A, b = [], []
    for k in range(10):
        ek = e[idx == k]
        if len(ek) < 20:
            continue
        mad = 1.4826 * np.median(np.abs(ek - np.median(ek)))
        A.append([1.0, np.mean(g[idx == k] ** 2)])
        b.append(mad**2)
    if len(A) < 2:
        return None
    sol, _ = nnls(np.array(A), np.array(b))
    return float(max(np.sqrt(sol[0]), 1e-3)), float(max(np.sqrt(sol[1]), 1e-4))


def convert_radar(source, radar: int, t_max: float | None = None) -> Conversion:
    """Convert one radar of a RadarScenes export folder (see module docstring).

    Args:
        source: the folder with radar{N}_detections.csv.gz and radar{N}_timestamp_and_odom.csv.
        radar: 1-4.
        t_max: keep only scans with t <= t_max (seconds from the sequence start), e.g. for short tests.

    Returns:
        Conversion named 'radar{N}' with odom.csv (scan,t,t_odom,vx,yaw_rate) as an extra file.

    Checked by: tests/sim/test_convert.py::test_radarscenes_*
    """
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"SOURCE: {source} is not a directory (expected a RadarScenes export folder)")
    if radar not in MOUNTING:
        raise InputError(f"--radars: radar numbers must be in 1-4, got {radar}")
    det_path = source / f"radar{radar}_detections.csv.gz"
    if not det_path.exists() and (source / f"radar{radar}_detections.csv").exists():
        det_path = source / f"radar{radar}_detections.csv"
    odom_path = source / f"radar{radar}_timestamp_and_odom.csv"
    odom = read_csv(odom_path, ODOM_COLUMNS)
    det = read_csv(det_path, DET_COLUMNS, int_columns=("scan_idx",))
    report = ConversionReport("radarscenes", str(source))
    report.info["radar"] = radar
    t, n_scans = _scan_times(odom, odom_path, t_max, report)
    scan, rng, az, vr, label, rcs = _kept_detections(det, len(t), n_scans, report, det_path)
    scans = scans_from_rows(report, scan, t, rng, az, np.zeros_like(az), vr, {"label": label, "rcs": rcs})
    require_detections(report, det_path)
    sensor = _sensor_config(radar, odom, t, scan, rng, az, vr, label, report)
    gt, dt = _groundtruth(odom, t, n_scans)
    report.info["max_abs_odom_time_offset_s"] = float(np.max(np.abs(dt)))
    report.info["static_fraction"] = float(np.mean(label == STATIC_LABEL)) if len(label) else 0.0
    report.notes.append("2D radar: elevation written as 0 with sigma 10 deg (unknown)")
    report.notes.append("sigma_range is nominal (not observable from the data); radial velocity and azimuth "
                        "sigmas from static Doppler residuals against the odometry (upper bounds)")
    rows = ["scan,t,t_odom,vx,yaw_rate"]
    cols = [t, odom["timestamp_odom"], odom["vx_ego"], odom["yaw_rate_ego"]]
    rows += [f"{k}," + ",".join(repr(float(c[k])) for c in cols) for k in range(n_scans)]
    seq = Sequence(sensor=sensor, scans=scans, groundtruth=gt)
    return Conversion(f"radar{radar}", seq, report, {"odom.csv": "\n".join(rows) + "\n"})


def _scan_times(odom: dict, odom_path, t_max: float | None, report: ConversionReport) -> tuple[np.ndarray, int]:
    """The scan times (row i of the odometry file is scan_idx i + 1; the sequence's scan index is row i),
    checked, and the number of scans kept with t <= t_max."""
    bad_odom = ~np.all(np.isfinite(np.stack([odom[c] for c in ODOM_COLUMNS])), axis=0)
    if bad_odom.any():
        k = int(np.flatnonzero(bad_odom)[0])
        raise InputError(f"{odom_path}, line {k + 2}: NaN or infinity in the odometry row")
    for c in ODOM_COLUMNS:  # huge finite values overflowed the sensor velocity (found by the fuzzer)
        if np.any(np.abs(odom[c]) > ODOM_LIMIT):
            k = int(np.flatnonzero(np.abs(odom[c]) > ODOM_LIMIT)[0])
            raise InputError(f"{odom_path}, line {k + 2}, field '{c}': |value| > {ODOM_LIMIT:g} is not plausible")
    t = odom["timestamp_rad"]
    if len(t) == 0:
        raise InputError(f"{odom_path}: no data rows")
    if np.any(np.diff(t) < MIN_SCAN_STEP):  # closer times were one time in groundtruth.txt (1 ns; fuzzer)
        k = int(np.flatnonzero(np.diff(t) < MIN_SCAN_STEP)[0]) + 1
        raise InputError(f"{odom_path}, line {k + 2}, field 'timestamp_rad': times must increase by at least "
                         f"{MIN_SCAN_STEP:g} s")
    check_scan_step(t, 1.0, "s", f"{odom_path}, field 'timestamp_rad'")
    n_scans = len(t) if t_max is None else int(np.searchsorted(t, t_max, side="right"))
    if n_scans == 0:
        raise InputError(f"t_max: {t_max} is before the first scan at {t[0]} s")
    _check_odom_offset(odom, odom_path, n_scans)
    if n_scans < len(t):
        report.notes.append(f"kept the {n_scans} scans with t <= {t_max} s of {len(t)}")
    return t, n_scans


def _check_odom_offset(odom: dict, odom_path, n_scans: int) -> None:
    """InputError naming the first row of the kept scans whose odometry time is more than MAX_ODOM_OFFSET_S
    from its scan time: groundtruth.txt moves the pose by vx dt, which an offset or a unit would make wrong."""
    dt = (odom["timestamp_rad"] - odom["timestamp_odom"])[:n_scans]
    far = np.abs(dt) > MAX_ODOM_OFFSET_S
    if far.any():
        k = int(np.flatnonzero(far)[0])
        t_rad, t_odom = float(odom["timestamp_rad"][k]), float(odom["timestamp_odom"][k])
        raise InputError(f"{odom_path}, line {k + 2}, field 'timestamp_odom': {t_odom!r} s is {t_odom - t_rad:+.6g} "
                         f"s from timestamp_rad {t_rad!r} s (more than {MAX_ODOM_OFFSET_S:g} s; RadarScenes' are at "
                         f"most 0.14 s): an offset, or another unit?")


def _kept_detections(det: dict, n_rows: int, n_scans: int, report: ConversionReport, det_path) -> tuple:
    """The usable detections (dropped ones counted in the report): scan index, range, azimuth, radial
    velocity, label, rcs. More than 1 % of the azimuths outside [-pi, pi] (degrees, a [0, 2pi) convention):
    InputError naming `det_path`, the first one's line and the field."""
    scan = det["scan_idx"] - 1
    in_time = (scan >= 0) & (scan < n_rows)
    keep = report.drop("detections whose scan_idx has no row in the odometry file", ~in_time)
    keep &= report.drop("detections after t_max", in_time & (scan >= n_scans))
    values = np.stack([det[c] for c in DET_COLUMNS[1:]])
    keep &= report.drop("detections with NaN or infinity", keep & ~np.all(np.isfinite(values), axis=0))
    rng, az, vr = det["range_m"], det["azimuth_rad"], det["vr_mps"]
    keep &= report.drop("detections with range <= 0", keep & ~(rng > 0))
    keep = drop_few(report, keep, ~(np.abs(az) <= ANGLE_BOUNDS["azimuth"]), "detections with azimuth outside [-pi, pi]",
                    lambda k: f"{det_path}, line {k + 2}, field 'azimuth_rad': {float(az[k])!r} is outside [-pi, pi]; "
                              f"{angle_hint('azimuth', az[k])}")
    return scan[keep], rng[keep], az[keep], vr[keep], det["label_id"][keep], det["rcs_dbsm"][keep]


def _sensor_config(radar: int, odom: dict, t, scan, rng, az, vr, label, report: ConversionReport) -> SensorConfig:
    """sensor.toml: the mounting, noise from the static detections' Doppler residuals against the odometry
    (nominal when too few), the field of view and maximum range seen in the data, the median scan rate."""
    v_sensor = sensor_velocity(radar, odom["vx_ego"], odom["yaw_rate_ego"])
    static = label == STATIC_LABEL
    sigmas = estimate_noise(az[static], vr[static], v_sensor[scan[static]])
    if sigmas is None:
        sigmas = NOMINAL_SIGMAS
        report.notes.append(f"too few static detections to estimate the noise: nominal sigmas {NOMINAL_SIGMAS}")
    sigma_vr, sigma_az = sigmas
    noise = NoiseSigmas(range=RANGE_SIGMA, azimuth=sigma_az, elevation=float(ELEVATION_SIGMA),
                        radial_velocity=sigma_vr)
    rate = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 13.0
    report.info.update({
        "sigma_radial_velocity_mps": sigma_vr, "sigma_azimuth_rad": sigma_az, "sigma_range_m": RANGE_SIGMA,
        "sigma_elevation_rad": float(ELEVATION_SIGMA), "rate_hz": rate,
    })
    return SensorConfig(rate_hz=rate, T_vehicle_sensor=T_vehicle_sensor(radar), noise=noise,
                        azimuth_fov=field_of_view(az, np.pi / 2, np.pi),
                        elevation_fov=(-ELEVATION_FOV, ELEVATION_FOV),
                        max_range=float(np.ceil(np.max(rng))) if len(rng) else 100.0, min_range=0.0)


def _groundtruth(odom: dict, t: np.ndarray, n_scans: int) -> tuple[Trajectory, np.ndarray]:
    """The odometry pose moved from the odometry time to the scan time with vx and yaw rate; and the time
    offsets (n_scans,) it was moved by."""
    sl = slice(0, n_scans)
    dt = (t - odom["timestamp_odom"])[sl]
    yaw = odom["yaw_loc"][sl] + odom["yaw_rate_ego"][sl] * dt
    x = odom["x_loc"][sl] + np.cos(odom["yaw_loc"][sl]) * odom["vx_ego"][sl] * dt
    y = odom["y_loc"][sl] + np.sin(odom["yaw_loc"][sl]) * odom["vx_ego"][sl] * dt
    return Trajectory(t[sl], planar_poses(x, y, yaw)), dt


def convert(source, radars=(2,), t_max: float | None = None) -> list[Conversion]:
    """Convert several radars (one Conversion each, in the order given)."""
    return [convert_radar(source, r, t_max) for r in radars]


def read_odom_csv(path) -> dict[str, np.ndarray]:
    """Read the odom.csv written next to a converted sequence: scan, t, t_odom, vx, yaw_rate arrays."""
    return read_csv(path, ("scan", "t", "t_odom", "vx", "yaw_rate"), int_columns=("scan",))
