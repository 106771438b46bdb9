"""In-memory types of a radar sequence (docs/sequence_format.md): sensor configuration, scans, trajectory.

Public names are re-exported by `sim.sequence`; import them from there.

Checked by: tests/sim/test_sequence.py
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.sensor_values import check_pose, check_sensor_values  # noqa: F401 (re-exported)

REQUIRED_COLUMNS = ("scan", "t", "range", "azimuth", "elevation", "radial_velocity")
SIGMA_NAMES = ("range", "azimuth", "elevation", "radial_velocity")


def _number(name: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name}: expected a number, got {type(value).__name__} {value!r}")
    try:
        value = float(value)
    except OverflowError:
        raise InputError(f"{name}: number too large") from None
    if not np.isfinite(value):
        raise InputError(f"{name}: must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class NoiseSigmas:
    """1-sigma measurement noise of the polar measurement model (paper eq. 80-81), SI units and radians."""

    range: float
    azimuth: float
    elevation: float
    radial_velocity: float

    def __post_init__(self):
        for key in SIGMA_NAMES:
            value = _number(f"NoiseSigmas.{key}", getattr(self, key))
            if value <= 0:
                raise InputError(f"NoiseSigmas.{key}: 1-sigma must be > 0, got {value!r}")
            object.__setattr__(self, key, value)

    def as_array(self) -> np.ndarray:
        """(4,) sigmas in [range, azimuth, elevation, radial_velocity] order."""
        return np.array([self.range, self.azimuth, self.elevation, self.radial_velocity])


@dataclass(frozen=True, eq=False)
class SensorConfig:
    """Radar sensor description (sensor.toml). `T_vehicle_sensor` maps sensor into vehicle coordinates.

    Validated on construction (InputError naming the field). Equality compares arrays exactly.
    """

    rate_hz: float
    T_vehicle_sensor: np.ndarray
    noise: NoiseSigmas
    azimuth_fov: tuple[float, float]
    elevation_fov: tuple[float, float]
    max_range: float
    min_range: float = 0.0

    def __post_init__(self):
        set_ = object.__setattr__
        for key in ("rate_hz", "max_range", "min_range"):
            set_(self, key, _number(f"SensorConfig.{key}", getattr(self, key)))
        for key in ("azimuth_fov", "elevation_fov"):
            pair = getattr(self, key)
            if np.ndim(pair) != 1 or len(pair) != 2:
                raise InputError(f"SensorConfig.{key}: expected (min, max), got {pair!r}")
            set_(self, key, tuple(_number(f"SensorConfig.{key}[{j}]", pair[j]) for j in range(2)))
        if not isinstance(self.noise, NoiseSigmas):
            raise InputError(f"SensorConfig.noise: expected NoiseSigmas, got {type(self.noise).__name__}")
        T = check_pose("SensorConfig.T_vehicle_sensor", self.T_vehicle_sensor)
        if T.shape != (4, 4):
            raise InputError(f"SensorConfig.T_vehicle_sensor: expected shape (4, 4), got {T.shape}")
        T.setflags(write=False)
        set_(self, "T_vehicle_sensor", T)

        def fail(key, reason):
            raise InputError(f"SensorConfig.{key}: {reason}")

        check_sensor_values(self.rate_hz, tuple(self.noise.as_array()), self.azimuth_fov, self.elevation_fov,
                            self.max_range, self.min_range, T[:3, 3], fail)

    def __eq__(self, other):
        if not isinstance(other, SensorConfig):
            return NotImplemented
        return (self.rate_hz == other.rate_hz and np.array_equal(self.T_vehicle_sensor, other.T_vehicle_sensor)
                and self.noise == other.noise and self.azimuth_fov == other.azimuth_fov
                and self.elevation_fov == other.elevation_fov and self.max_range == other.max_range
                and self.min_range == other.min_range)

    __hash__ = None


def polar_to_cartesian(range, azimuth, elevation) -> np.ndarray:  # noqa: A002 (the format's column name)
    """Polar -> Cartesian in the sensor frame (inverse of paper eq. 80), broadcasting, (...,) -> (..., 3).

    x = r cos(el) cos(az), y = r cos(el) sin(az), z = r sin(el).

    Checked by: tests/sim/test_sequence.py::test_polar_to_cartesian_inverts_polar_model
    """
    r = np.asarray(range, dtype=float)
    az = np.asarray(azimuth, dtype=float)
    el = np.asarray(elevation, dtype=float)
    rc = r * np.cos(el)
    return np.stack(np.broadcast_arrays(rc * np.cos(az), rc * np.sin(az), r * np.sin(el)), axis=-1)


@dataclass(eq=False)
class RadarScan:
    """Detections of one radar scan, all at time `t` (seconds); arrays (n,), SI units and radians.

    `extra` holds further CSV columns (e.g. 'snr'), (n,) each. Construction checks shapes only; the reader
    and writer check values.
    """

    scan: int
    t: float
    range: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    radial_velocity: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        if isinstance(self.scan, (bool, np.bool_)) or not isinstance(self.scan, (int, np.integer)):
            raise InputError(f"RadarScan.scan: expected an integer, got {self.scan!r}")
        self.scan = int(self.scan)
        self.t = _number("RadarScan.t", self.t)
        n = None
        for key in SIGMA_NAMES:
            arr = np.asarray(getattr(self, key), dtype=float)
            if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
                want = "n" if n is None else n
                raise InputError(f"RadarScan.{key}: expected shape ({want},), got {arr.shape}")
            n = arr.shape[0]
            setattr(self, key, arr)
        extra = {}
        for key, value in dict(self.extra).items():
            arr = np.asarray(value, dtype=float)
            if arr.shape != (n,):
                raise InputError(f"RadarScan.extra[{key!r}]: expected shape ({n},), got {arr.shape}")
            extra[str(key)] = arr
        self.extra = extra

    def __len__(self) -> int:
        return int(self.range.shape[0])

    @property
    def polar(self) -> np.ndarray:
        """(n, 4) [range, azimuth, elevation, radial_velocity]."""
        return np.stack([self.range, self.azimuth, self.elevation, self.radial_velocity], axis=-1)

    @property
    def points_sensor(self) -> np.ndarray:
        """(n, 3) Cartesian detections in the sensor frame (`polar_to_cartesian`)."""
        return polar_to_cartesian(self.range, self.azimuth, self.elevation).reshape(len(self), 3)


@dataclass(eq=False)
class Trajectory:
    """Poses T_world_vehicle (M, 4, 4) at strictly increasing times t (M,) seconds (groundtruth.txt, TUM).

    Checked on construction: shapes, finiteness, rigid transforms, strictly increasing t.
    """

    t: np.ndarray
    T_world_vehicle: np.ndarray

    def __post_init__(self):
        t = np.array(self.t, dtype=float)
        if t.ndim != 1:
            raise InputError(f"Trajectory.t: expected shape (M,), got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("Trajectory.t: contains NaN or infinity")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
            raise InputError(f"Trajectory.t: must be strictly increasing "
                             f"(t[{k}] = {t[k].item()!r} <= t[{k - 1}] = {t[k - 1].item()!r})")
        T = check_pose("Trajectory.T_world_vehicle", self.T_world_vehicle)
        if T.shape != (t.size, 4, 4):
            raise InputError(f"Trajectory.T_world_vehicle: expected shape ({t.size}, 4, 4), got {T.shape}")
        self.t = t
        self.T_world_vehicle = T

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(eq=False)
class Sequence:
    """A radar sequence: sensor, scans that have detections (in order), optional ground truth."""

    sensor: SensorConfig
    scans: list[RadarScan]
    groundtruth: Trajectory | None = None
