"""The radar equation behind a sensor profile: an RCS per scatterer class, the SNR of each target, detection
from SNR (Swerling 1, square-law detector), noise from SNR (angle accuracy worsening off boresight), Doppler
and range ambiguity, and the quantisation of what real sensors report. Pure functions of arrays, no scene code:
`sim.radar.Radar` calls them when `RadarConfig.physics` is set (the default radar has none and never draws
from them). Derivations and the profiles' numbers: docs/simulator.md ("Sensor profiles").

Model (Richards, "Fundamentals of Radar Signal Processing", 2nd ed., eq. 2.17 (radar equation), 6.23 (Swerling 1
detection probability), 7.74-7.76 (measurement precision)):
    SNR(R, sigma) = snr_1m * sigma * G(az, el) / R^4         (linear; snr_1m = SNR of 1 m^2 at 1 m on boresight)
    G(az, el) = -24 ((az / pa)^2 + (el / pe)^2) dB           (two-way Gaussian beam, 3 dB widths (pa, pe))
    x = (1 + SNR) E,  E ~ Exp(1)                             (noise-normalised power of the target's cell)
    detected iff x > T,  T = -ln(pfa),  so  Pd = exp(-T / (1 + SNR))   (monotone in SNR)
    sigma_range = sqrt(floor_r^2 + dR^2 / (2 x)),  sigma_vr likewise with the velocity resolution dV,
    sigma_az = sqrt(floor_az^2 + (theta_az / cos(az))^2 / (k^2 2 x)),  k = 1.6 (elevation with cos(el)),
with x the detection's own power ratio (a strong return is measured more precisely). The reported RCS is the
power turned back through the radar equation: rcs_db = 10 log10(x) - snr_1m_db + 40 log10(R).

Checked by: tests/sim/test_radar_physics.py
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from rodo.estimator.errors import InputError

from .objects import MOVING, STATIC_POINT

ANGLE_K = 1.6  # Richards eq. 7.76: angle precision theta_3dB / (1.6 sqrt(2 SNR))
# scatterer classes (the index is what `scatterer_class` returns)
CLASSES = ("ground", "facade", "metal", "point", "vehicle")
GROUND, FACADE, METAL, POINT, VEHICLE = range(5)


@dataclass(frozen=True, eq=False)
class RadarPhysics:
    """The radar-equation part of a sensor profile (SI units, radians; dB where the name says so).

    Attributes:
        snr_1m_db: SNR of a 1 m^2 (0 dBsm) target at 1 m range (all the radar equation's constants).
        pfa: false-alarm probability per cell; the detection threshold is T = -ln(pfa) on the power ratio.
        rcs_dbsm: per scatterer class (`CLASSES`) the (mean, standard deviation) of the RCS in dBsm (lognormal
            over scatterers and scans). A point scatterer's RCS is lowered by 10 log10 of its own detection
            probability (weak scatterers, e.g. tree canopy, are weak returns).
        range_resolution, velocity_resolution: dR (m) and dV (m/s) of the SNR terms of the noise.
        beamwidth: (azimuth, elevation) 3 dB beamwidths (rad) at boresight, the angle terms of the noise.
        doppler_max: unambiguous radial velocity: measured v_r wraps into [-doppler_max, doppler_max); None = off.
        range_max: unambiguous range: a target beyond folds to range mod range_max; None = off.
        doppler_step, rcs_step_db, snr_step_db: quantisation of the reported values (0 = none).
        report_elevation: False for a 2D radar (elevation reported as 0, no elevation noise).
        ghost_prob: per detected target, the probability of trying one mirror ghost via a random large reflector.
        ghost_loss_db: extra loss of the ghost's double bounce (its SNR is that of the target at the mirrored
            range, minus this).
        ghost_min_area: m^2; reflectors are static non-ground patches at least this large.
        pattern: (azimuth, elevation) one-way 3 dB widths (rad) of the antenna's Gaussian beam pattern, or None
            (a flat pattern over the field of view).
        pattern_tilt: elevation (rad) of the beam's centre in the sensor frame (a beam tilted against the frame the
            sensor reports in; 0: on boresight).
        range_cell: metres, or None: one detection per angular cell *and range bin* of this size instead of per
            angular cell (several detections of an extended object along the range, as a range-Doppler CFAR
            before the angle estimate gives: a 2D radar's clustered returns).
        elevation_missing: probability that a detection is reported without an elevation estimate (elevation 0,
            as 13 % of the LRR30-F's detections in the RaFlow data).
    """

    snr_1m_db: float
    pfa: float = 1e-4
    rcs_dbsm: dict = field(default_factory=lambda: {"ground": (-20.0, 6.0), "facade": (0.0, 6.0),
                                                    "metal": (5.0, 6.0), "point": (5.0, 5.0),
                                                    "vehicle": (10.0, 6.0)})
    range_resolution: float = 0.2
    velocity_resolution: float = 0.1
    beamwidth: tuple = (0.02, 0.04)
    doppler_max: float | None = None
    range_max: float | None = None
    doppler_step: float = 0.0
    rcs_step_db: float = 0.0
    snr_step_db: float = 0.0
    report_elevation: bool = True
    ghost_prob: float = 0.0
    ghost_loss_db: float = 10.0
    ghost_min_area: float = 4.0
    pattern: tuple | None = None
    pattern_tilt: float = 0.0
    range_cell: float | None = None
    elevation_missing: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("rcs_dbsm", "beamwidth", "report_elevation", "pattern") or value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
                raise InputError(f"RadarPhysics.{f.name}: expected a finite number, got {value!r}")
        _positive(self, "range_resolution", "velocity_resolution", "ghost_min_area")
        _nonnegative(self, "doppler_step", "rcs_step_db", "snr_step_db", "ghost_loss_db")
        for name in ("doppler_max", "range_max", "range_cell"):
            if getattr(self, name) is not None:
                _positive(self, name)
        if not 0 < self.pfa < 1:
            raise InputError(f"RadarPhysics.pfa: must be in (0, 1), got {self.pfa!r}")
        for name in ("ghost_prob", "elevation_missing"):
            if not 0 <= getattr(self, name) <= 1:
                raise InputError(f"RadarPhysics.{name}: must be in [0, 1], got {getattr(self, name)!r}")
        if len(self.beamwidth) != 2 or not all(np.isfinite(b) and 0 < b < np.pi for b in self.beamwidth):
            raise InputError(f"RadarPhysics.beamwidth: need (azimuth, elevation) in (0, pi) rad, got {self.beamwidth}")
        if self.pattern is not None and (len(self.pattern) != 2
                                         or not all(np.isfinite(b) and b > 0 for b in self.pattern)):
            raise InputError(f"RadarPhysics.pattern: need (azimuth, elevation) widths > 0 rad, got {self.pattern}")
        if set(self.rcs_dbsm) != set(CLASSES):
            raise InputError(f"RadarPhysics.rcs_dbsm: need exactly the classes {', '.join(CLASSES)}, got "
                             f"{', '.join(self.rcs_dbsm)}")
        for name, pair in self.rcs_dbsm.items():
            if len(pair) != 2 or not all(np.isfinite(v) for v in pair) or pair[1] < 0:
                raise InputError(f"RadarPhysics.rcs_dbsm[{name!r}]: need (mean dBsm, std dB >= 0), got {pair!r}")

    @property
    def threshold(self) -> float:
        """The detection threshold T = -ln(pfa) on the noise-normalised power."""
        return float(-np.log(self.pfa))

    def rcs_table(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std) in dB per class index."""
        return (np.array([self.rcs_dbsm[c][0] for c in CLASSES]), np.array([self.rcs_dbsm[c][1] for c in CLASSES]))


def _positive(obj, *names):
    for name in names:
        if not getattr(obj, name) > 0:
            raise InputError(f"{type(obj).__name__}.{name}: must be > 0, got {getattr(obj, name)!r}")


def _nonnegative(obj, *names):
    for name in names:
        if not getattr(obj, name) >= 0:
            raise InputError(f"{type(obj).__name__}.{name}: must be >= 0, got {getattr(obj, name)!r}")


def scatterer_class(label: np.ndarray, reflectivity: np.ndarray) -> np.ndarray:
    """Class index per candidate: static surface by reflectivity (< 0.5 ground, < 1.5 facade, else metal:
    parked cars, guard rails), static point scatterers, moving vehicles (labels of `sim.objects`)."""
    cls = np.where(reflectivity < 0.5, GROUND, np.where(reflectivity < 1.5, FACADE, METAL))
    cls = np.where(label == STATIC_POINT, POINT, cls)
    return np.where(label == MOVING, VEHICLE, cls)


def snr_db(snr_1m_db: float, rcs_db: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Radar equation in dB: SNR = snr_1m + sigma - 40 log10(R) (Richards eq. 2.17).

    Checked by: tests/sim/test_radar_physics.py::test_snr_falls_as_r4_and_rises_with_rcs"""
    return snr_1m_db + rcs_db - 40.0 * np.log10(np.maximum(r, 1e-3))


def pattern_db(physics: RadarPhysics, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Two-way gain of the Gaussian beam pattern in dB (<= 0; 0 without a pattern):
    -24 ((az / pa)^2 + ((el - tilt) / pe)^2), i.e. each one-way pattern -12 (angle / 3 dB width)^2 dB, -3 dB at
    half the width off the beam's centre."""
    if physics.pattern is None:
        return np.zeros_like(az)
    pa, pe = physics.pattern
    return -24.0 * ((az / pa) ** 2 + ((el - physics.pattern_tilt) / pe) ** 2)


def detection_probability(snr_lin: np.ndarray, pfa: float) -> np.ndarray:
    """Swerling 1 with a square-law detector: Pd = pfa^(1 / (1 + SNR)) = exp(-T / (1 + SNR)) (Richards eq. 6.23).

    Checked by: tests/sim/test_radar_physics.py::test_detection_probability_is_monotone_in_snr"""
    return np.exp(np.log(pfa) / (1.0 + snr_lin))


def sigmas(physics: RadarPhysics, floors, x: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """(4, n) 1-sigma of (range, azimuth, elevation, radial velocity) for detections of power ratio x at (az, el):
    the accuracy floor and the SNR term in quadrature, the angle terms with the beam widened by 1 / cos(angle).

    Checked by: tests/sim/test_radar_physics.py::test_angle_noise_matches_the_formula"""
    two_x = 2.0 * np.maximum(x, 1e-12)
    bw_az = physics.beamwidth[0] / np.maximum(np.cos(az), 0.1)
    bw_el = physics.beamwidth[1] / np.maximum(np.cos(el), 0.1)
    terms = (physics.range_resolution**2 / two_x, bw_az**2 / (ANGLE_K**2 * two_x), bw_el**2 / (ANGLE_K**2 * two_x),
             physics.velocity_resolution**2 / two_x)
    return np.stack([np.sqrt(float(f)**2 + t) for f, t in zip(floors, terms)])


def wrap(value: np.ndarray, limit: float | None) -> np.ndarray:
    """value mapped into [-limit, limit) by adding multiples of 2 limit (identity inside; None: no wrap).

    Checked by: tests/sim/test_radar_physics.py::test_wrap_maps_into_the_interval_and_is_identity_inside"""
    if limit is None:
        return value
    return value - 2.0 * limit * np.floor((value + limit) / (2.0 * limit))


def fold_range(r: np.ndarray, limit: float | None) -> np.ndarray:
    """Range ambiguity: r mod limit (identity below it; None: none)."""
    return r if limit is None else np.mod(r, limit)


def quantise(value: np.ndarray, step: float) -> np.ndarray:
    """value rounded to a multiple of step (0: unchanged)."""
    return value if step <= 0 else np.round(value / step) * step


def target_power(physics: RadarPhysics, cls: np.ndarray, pd_own: np.ndarray, r: np.ndarray, az: np.ndarray,
                 el: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Draw each target's RCS (dBsm, lognormal per class) and its measured power ratio x = (1 + SNR) E at
    (r, az, el).

    Returns (rcs_db (n,), x (n,)); the detected ones are x > physics.threshold."""
    mean, std = physics.rcs_table()
    rcs = mean.take(cls) + std.take(cls) * rng.standard_normal(len(cls)) + 10.0 * np.log10(np.maximum(pd_own, 1e-3))
    snr = 10.0 ** ((snr_db(physics.snr_1m_db, rcs, r) + pattern_db(physics, az, el)) / 10.0)
    return rcs, (1.0 + snr) * rng.standard_exponential(len(cls))


def reported_rcs(physics: RadarPhysics, x: np.ndarray, r: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """RCS as a radar reports it: the measured power through the radar equation and the beam pattern at the
    measured (r, az, el), quantised (dBsm)."""
    power_db = 10.0 * np.log10(np.maximum(x, 1e-12))
    return quantise(power_db - physics.snr_1m_db + 40.0 * np.log10(np.maximum(r, 1e-3)) - pattern_db(physics, az, el),
                    physics.rcs_step_db)


def reported_snr(physics: RadarPhysics, x: np.ndarray) -> np.ndarray:
    """SNR as reported (dB of the measured power ratio), quantised."""
    return quantise(10.0 * np.log10(np.maximum(x, 1e-12)), physics.snr_step_db)


@dataclass(frozen=True)
class Targets:
    """What a physical scan has detected, before it is reported: true (4, n) noise-free (range, azimuth,
    elevation, radial velocity), x (n,) power ratio, label, object_id, landmark_id (n,), p_world (n, 3) (NaN for
    clutter and ghosts), meas (4, n) the noisy measurement (None before `noisy`)."""

    true: np.ndarray
    x: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    landmark_id: np.ndarray
    p_world: np.ndarray
    meas: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.x)

    @staticmethod
    def concat(items) -> "Targets":
        meas = None if any(t.meas is None for t in items) else np.concatenate([t.meas for t in items], axis=1)
        return Targets(np.concatenate([t.true for t in items], axis=1),
                       *(np.concatenate([getattr(t, f) for t in items]) for f in _TARGET_FIELDS[1:-1]), meas)

    def subset(self, idx: np.ndarray) -> "Targets":
        return Targets(self.true[:, idx], *(getattr(self, f)[idx] for f in _TARGET_FIELDS[1:-1]),
                       None if self.meas is None else self.meas[:, idx])

    def noisy(self, physics: RadarPhysics, floors, rng: np.random.Generator) -> "Targets":
        """Gaussian noise with the SNR-dependent sigmas (`sigmas`; none for a noise-free radar, floors all 0),
        then elevation 0 for the detections without an elevation estimate (`elevation_missing`)."""
        if not any(floors):
            meas = self.true.copy()
        else:
            meas = self.true + rng.standard_normal(self.true.shape) * sigmas(physics, floors, self.x, self.true[1],
                                                                             self.true[2])
        if physics.elevation_missing > 0:
            meas[2, rng.random(len(self)) < physics.elevation_missing] = 0.0
        return Targets(*(getattr(self, f) for f in _TARGET_FIELDS[:-1]), meas)

    def permuted(self, rng: np.random.Generator) -> "Targets":
        return self.subset(rng.permutation(len(self)))

    def inserted(self, n_first: int, rng: np.random.Generator) -> "Targets":
        """The rows after the first n_first (ghosts) moved to random places; unchanged when there are none."""
        return self if len(self) == n_first else self.permuted(rng)

    def reported(self, physics: RadarPhysics) -> dict:
        """The fields of `sim.radar.Detections`: range folded, v_r wrapped and quantised, elevation 0 for a 2D
        radar, the reported rcs and snr."""
        r, az, el, vr = self.meas
        r = fold_range(np.abs(r), physics.range_max)
        vr = quantise(wrap(vr, physics.doppler_max), physics.doppler_step)
        el = np.clip(el, -np.pi / 2, np.pi / 2) if physics.report_elevation else np.zeros_like(el)
        az = wrap(az, np.pi)
        return dict(range=r, azimuth=az, elevation=el, radial_velocity=vr, label=self.label,
                    object_id=self.object_id, landmark_id=self.landmark_id, p_world=self.p_world,
                    true_polar=np.ascontiguousarray(self.true.T), rcs=reported_rcs(physics, self.x, r, az, el),
                    snr=reported_snr(physics, self.x))


_TARGET_FIELDS = ("true", "x", "label", "object_id", "landmark_id", "p_world", "meas")


__all__ = ["ANGLE_K", "CLASSES", "RadarPhysics", "Targets", "detection_probability", "fold_range", "pattern_db",
           "quantise", "reported_rcs",
           "reported_snr", "scatterer_class", "sigmas", "snr_db", "target_power", "wrap"]
