"""Value rules of a radar's description and detections, one set for every way in: the sequence files
(`rodo.sim.sensor_config`, `rodo.sim.radar_csv`), the in-memory `SensorConfig`, and the estimator's Python API
(`RadarOdometry`). A unit mistaken (degrees for radians, millimetres for metres, km/h for m/s) is an error that
names the value, not a silently wrong estimate.

Checked by: tests/estimator/test_sensor_values.py, tests/sim/test_sequence.py
"""

from __future__ import annotations

import numpy as np

from .errors import InputError, check_finite

ANGLE_BOUNDS = {"azimuth": np.pi, "elevation": np.pi / 2}  # rad: |angle| above it is out of any radar's view
MAX_DOPPLER_SIGMA = 50.0  # m/s: a radial-velocity sigma above it is a unit mistake
RATE_RANGE = (0.1, 1000.0)  # Hz: a scan rate outside it comes from times in another unit than seconds
MAX_MOUNT = 50.0  # m: no radar is mounted farther from the vehicle's origin (a larger value is a unit mistake)
POLAR_COLUMNS = ("range", "azimuth", "elevation", "radial_velocity")


def angle_hint(name: str, value: float) -> str:
    """Why an out-of-bounds azimuth or elevation `value` is likely wrong: degrees, or a [0, 2pi) azimuth."""
    if name == "azimuth" and abs(value) <= 2 * np.pi:
        return "looks like degrees or a [0, 2pi) convention: angles must be radians in [-pi, pi]"
    return "looks like degrees: angles must be in radians"


def check_polar_bounds(name: str, polar: np.ndarray) -> None:
    """Detections (n, 4) [range, azimuth, elevation, radial_velocity]: InputError naming the first bad row's
    column for a negative range or an angle outside [-pi, pi] (azimuth) or [-pi/2, pi/2] (elevation)."""
    bad = ((polar[:, 0] < 0) | (np.abs(polar[:, 1]) > ANGLE_BOUNDS["azimuth"])
           | (np.abs(polar[:, 2]) > ANGLE_BOUNDS["elevation"]))
    if not bad.any():
        return
    row = int(np.flatnonzero(bad)[0])
    r, az, el = (float(v) for v in polar[row, :3])
    if r < 0:
        raise InputError(f"{name}[{row}, 0] (range): negative value {r!r} (range must be >= 0)")
    col, value = (1, az) if abs(az) > ANGLE_BOUNDS["azimuth"] else (2, el)
    column = POLAR_COLUMNS[col]
    bound = ANGLE_BOUNDS[column]
    raise InputError(f"{name}[{row}, {col}] ({column}): value {value!r} outside [-{bound:.9g}, {bound:.9g}]; "
                     f"{angle_hint(column, value)}")


def check_pose(name: str, T) -> np.ndarray:
    """(4, 4) or (M, 4, 4) rigid transforms: finite, bottom row [0, 0, 0, 1], rotation orthonormal (1e-6)."""
    T = np.array(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise InputError(f"{name}: expected shape (..., 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{name}: contains NaN or infinity")
    if np.any(T[..., 3, :] != np.array([0.0, 0.0, 0.0, 1.0])):
        raise InputError(f"{name}: bottom row must be [0, 0, 0, 1]")
    C = T[..., :3, :3]
    err = np.abs(C @ np.swapaxes(C, -1, -2) - np.eye(3)).max(axis=(-1, -2))
    if np.any(err > 1e-6):
        raise InputError(f"{name}: rotation block is not a proper rotation (|C C^T - I| = {np.max(err):.3g})")
    det = np.linalg.det(C)
    if np.any(det <= 0):
        raise InputError(f"{name}: rotation block is not a proper rotation (determinant {np.min(det):.3g}: a "
                         "reflection)")
    return T


def check_sensor_values(rate_hz, sigmas, azimuth_fov, elevation_fov, max_range, min_range, translation,
                        fail) -> None:
    """Value rules of a sensor configuration, shared by `SensorConfig` and the TOML reader.

    `fail(key, reason)` raises the caller's error for a dotted key such as 'fov.max_range'.
    """
    if rate_hz <= 0:
        fail("rate_hz", f"must be > 0, got {rate_hz!r}")
    if not RATE_RANGE[0] <= rate_hz <= RATE_RANGE[1]:
        fail("rate_hz", f"{rate_hz!r} Hz is no radar's scan rate (expected {RATE_RANGE[0]:g}-{RATE_RANGE[1]:g} Hz): "
             "were the scan times in milliseconds, microseconds or nanoseconds? they are in seconds")
    check_sigmas(sigmas, fail)
    check_fov_bounds(azimuth_fov, elevation_fov, fail)
    if max_range <= 0:
        fail("fov.max_range", f"must be > 0, got {max_range!r}")
    check_mount(translation, fail)
    if sigmas[0] >= max_range:
        fail("noise.range", f"1-sigma {sigmas[0]!r} m is not below fov.max_range {max_range!r} m")
    if not (0 <= min_range < max_range):
        fail("fov.min_range", f"need 0 <= min_range < max_range, got {min_range!r}")


def check_sigmas(sigmas, fail) -> None:
    """1-sigma noise [range, azimuth, elevation, radial_velocity]: positive, and not in degrees or km/h."""
    sigmas = [float(s) for s in sigmas]
    for key, s in zip(POLAR_COLUMNS, sigmas):
        if s <= 0:
            fail("noise." + key, f"1-sigma must be > 0, got {s!r}")
    if sigmas[1] > np.pi:
        fail("noise.azimuth", f"{sigmas[1]!r} rad is implausibly large: degrees? angles are in radians")
    if sigmas[2] > np.pi / 2:
        fail("noise.elevation", f"{sigmas[2]!r} rad is implausibly large: degrees? angles are in radians")
    if sigmas[3] > MAX_DOPPLER_SIGMA:
        fail("noise.radial_velocity", f"{sigmas[3]!r} m/s is implausibly large (above {MAX_DOPPLER_SIGMA:g}): "
             "km/h? radial velocities are in m/s")


def check_fov_bounds(azimuth_fov, elevation_fov, fail) -> None:
    """A field of view (min, max) per angle: min < max, inside [-pi, pi] and [-pi/2, pi/2] (else degrees?)."""
    for key, (lo, hi), bound in (("fov.azimuth", azimuth_fov, np.pi), ("fov.elevation", elevation_fov, np.pi / 2)):
        lo, hi = float(lo), float(hi)
        if not (-bound <= lo < hi <= bound):
            hint = " (looks like degrees: angles are in radians)" if max(abs(lo), abs(hi)) > bound else ""
            fail(key, f"need -{bound:.6g} <= min < max <= {bound:.6g} rad, got [{lo!r}, {hi!r}]{hint}")


def check_mount(translation, fail) -> None:
    """The radar's mounting position (m): within MAX_MOUNT of the vehicle's origin (else millimetres?)."""
    if max(abs(float(x)) for x in translation) > MAX_MOUNT:
        fail("extrinsics.translation", f"{[float(x) for x in translation]} m puts the radar more than {MAX_MOUNT:g} m "
             "from the vehicle's origin: millimetres? it is in metres")


# the Python API's argument for each dotted key of the sensor configuration
_ARGUMENTS = {"noise.range": "sensor_sigmas[0] (range)", "noise.azimuth": "sensor_sigmas[1] (azimuth)",
              "noise.elevation": "sensor_sigmas[2] (elevation)",
              "noise.radial_velocity": "sensor_sigmas[3] (radial_velocity)", "fov.azimuth": "fov[0] (azimuth)",
              "fov.elevation": "fov[1] (elevation)", "extrinsics.translation": "T_vehicle_sensor[:3, 3]"}


def check_sensor_arguments(T_vehicle_sensor, sensor_sigmas, max_range, fov):
    """`RadarOdometry`'s sensor arguments checked as a sensor.toml is: T (4, 4) rigid, sigmas (4,), max_range
    (m) and fov ((az_min, az_max), (el_min, el_max)) rad or None. Returns them as arrays and a float."""
    T = check_pose("T_vehicle_sensor", T_vehicle_sensor)
    if T.shape != (4, 4):
        raise InputError(f"T_vehicle_sensor: expected shape (4, 4), got {T.shape}")

    def fail(key, reason):
        raise InputError(f"{_ARGUMENTS[key]}: {reason}")

    check_mount(T[:3, 3], fail)
    sigmas = check_finite("sensor_sigmas", sensor_sigmas, (4,))
    if sigmas.shape != (4,):
        raise InputError(f"sensor_sigmas: expected shape (4,), got {sigmas.shape}")
    check_sigmas(sigmas, fail)
    try:
        max_range = float(max_range)
    except (TypeError, ValueError):
        raise InputError(f"max_range: expected a number of metres, got {max_range!r}") from None
    if not (np.isfinite(max_range) and max_range > sigmas[0]):
        raise InputError(f"max_range: must be > 0 and above the range sigma {sigmas[0]!r} m, got {max_range!r}")
    if fov is not None:
        fov = check_finite("fov", fov, (2, 2))
        if fov.shape != (2, 2):
            raise InputError(f"fov: expected ((az_min, az_max), (el_min, el_max)), got shape {fov.shape}")
        check_fov_bounds(fov[0], fov[1], fail)
    return T, sigmas, max_range, fov
