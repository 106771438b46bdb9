"""Instantaneous sensor velocity from Doppler alone (RANSAC + least squares, as in reve, Doer & Trommer).

For a static target at unit direction u (sensor frame) the radial velocity is v_r = -u . v_s, with v_s the
sensor's velocity in the sensor frame, so the stacked detections give the linear system U v_s = -v_r.

Algorithm:
1. Hypotheses: `iterations` minimal sets (3 detections in 3D, 2 in planar mode) drawn with the caller's
   Generator, each solved exactly (near-singular sets are skipped), plus the zero-velocity hypothesis (so a
   vehicle at standstill is always a candidate).
2. Score: number of inliers |v_r + u . v| <= threshold (default max(3 sigma_vr, 0.05 m/s); one per detection
   if given so). The hypothesis with the most inliers wins; ties go to the smaller |v| (at standstill a moving
   object never wins over the static world unless it has strictly more detections). With `near=(v, radius)`
   only hypotheses within radius of v compete and v replaces the zero hypothesis (the odometry's
   prediction-gated classification); ties then go to the hypothesis closest to v.
3. Refit: least squares on the inliers, inliers re-selected with the refit, refit again (twice).
4. Covariance sigma^2 (U^T U)^-1 over the inliers, sigma^2 = sum(res^2) / (n_in - dof) (floored at
   (1e-6 m/s)^2 so it stays positive definite on noise-free data).

Planar mode (vz = 0, only vx, vy) is used when the caller says so or when every |elevation| < PLANAR_ELEVATION
(elevation carries no information); the covariance then has zeros in the z row and column.

Steps 1-4 run compiled, in one pass (`doppler_kernels.ransac`; the draws come from the Generator here, so the
stream is the caller's): minimal sets solved by Cramer's rule (|det| <= `doppler_kernels.MIN_DET` skipped), the
least squares by the normal equations.

Failure (too few detections or inliers, or no non-degenerate minimal set) gives ok=False, v_sensor zeros,
a zero covariance and no inliers: never an exception and never NaN.

Checked by: tests/estimator/test_ego_velocity.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator import doppler_kernels
from rodo.estimator.errors import InputError, check_finite

PLANAR_ELEVATION = 1e-3  # rad; all |elevation| below this -> planar mode
MIN_THRESHOLD = 0.05     # m/s; the default inlier threshold is max(3 sigma_vr, MIN_THRESHOLD)
RANSAC_ITERATIONS = 100  # minimal sets drawn per estimate (the default of `estimate_ego_velocity`)


@dataclass
class EgoVelocity:
    """Result of `estimate_ego_velocity`.

    Attributes:
        v_sensor: (3,) sensor velocity in the sensor frame (vz = 0 in planar mode).
        covariance: (3, 3) covariance of v_sensor.
        inliers: (n,) bool, the detections consistent with v_sensor (static world).
        planar: True when only vx, vy were estimated.
        ok: False when no estimate could be made (then v_sensor = 0, inliers all False).
    """

    v_sensor: np.ndarray
    covariance: np.ndarray
    inliers: np.ndarray
    planar: bool
    ok: bool


def is_planar(elevation: np.ndarray) -> bool:
    """The planar rule (vz = 0): no detections, or every |elevation| below PLANAR_ELEVATION."""
    return bool(len(elevation) == 0 or (np.abs(elevation) < PLANAR_ELEVATION).all())


def _directions(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    ce = np.cos(elevation)
    return np.stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)], axis=-1)


def _check_inputs(azimuth, elevation, radial_velocity):
    azimuth = check_finite("azimuth", azimuth)
    elevation = check_finite("elevation", elevation)
    radial_velocity = check_finite("radial_velocity", radial_velocity)
    for name, a in (("azimuth", azimuth), ("elevation", elevation), ("radial_velocity", radial_velocity)):
        if a.ndim != 1 or a.shape != azimuth.shape:
            raise InputError(f"{name}: expected a 1-D array of the same length as azimuth ({azimuth.shape}), "
                             f"got shape {a.shape}")
    return azimuth, elevation, radial_velocity


def doppler_inliers(azimuth, elevation, radial_velocity, v_sensor, threshold) -> np.ndarray:
    """Detections consistent with a sensor velocity: |v_r + u . v_sensor| <= threshold, (n,) bool.

    Args:
        azimuth, elevation, radial_velocity: (n,) detections (rad, rad, m/s).
        v_sensor: (3,) sensor velocity in the sensor frame (e.g. the solver's predicted velocity).
        threshold: m/s, >= 0.

    Checked by: tests/estimator/test_ego_velocity.py::test_doppler_inliers
    """
    azimuth, elevation, radial_velocity = _check_inputs(azimuth, elevation, radial_velocity)
    v = check_finite("v_sensor", v_sensor, (3,))
    if v.shape != (3,):
        raise InputError(f"v_sensor: expected shape (3,), got {v.shape}")
    threshold = float(check_finite("threshold", threshold))
    if threshold < 0:
        raise InputError(f"threshold: must be >= 0, got {threshold}")
    return np.abs(radial_velocity + _directions(azimuth, elevation) @ v) <= threshold


def _failure(n: int, planar: bool) -> EgoVelocity:
    return EgoVelocity(np.zeros(3), np.zeros((3, 3)), np.zeros(n, dtype=bool), planar, False)


def least_squares_velocity(azimuth, elevation, radial_velocity, *, variance_floor: float, max_cond: float = 1e12,
                           planar: bool | None = None):
    """Sensor velocity of detections all taken as static (no outlier rejection): (v, covariance) with v of
    length 2 (planar: vx, vy) or 3, or None with too few detections or a degenerate geometry.

    The odometry's Doppler check of its prediction uses it on the static detections it chose.
    Planar as in `estimate_ego_velocity`. Checked by: tests/estimator/test_ego_velocity.py
    """
    azimuth, elevation, radial_velocity = _check_inputs(azimuth, elevation, radial_velocity)
    if planar is None:
        planar = is_planar(elevation)
    dof = 2 if planar else 3
    if len(azimuth) <= dof:
        return None
    U = np.ascontiguousarray(_directions(azimuth, elevation)[:, :dof])
    v, cov = np.empty(dof), np.empty((dof, dof))
    if not doppler_kernels.fit_velocity(U, -radial_velocity, np.ones(len(U), np.bool_), float(variance_floor),
                                        float(variance_floor), float(max_cond), v, cov):
        return None
    return v, cov


def estimate_ego_velocity(azimuth, elevation, radial_velocity, rng: np.random.Generator, *, sigma_vr: float = 0.01,
                          threshold: float | None = None, iterations: int = RANSAC_ITERATIONS,
                          planar: bool | None = None, near: tuple | None = None) -> EgoVelocity:
    """Sensor velocity from one scan's Doppler measurements, robust to moving objects (see module docstring).

    Model: v_r,i = -u_i . v_s for static targets, u_i = [cos el cos az, cos el sin az, sin el].

    Args:
        azimuth, elevation, radial_velocity: (n,) detections (rad, rad, m/s; v_r negative when approaching).
        rng: numpy Generator (the only source of randomness; same state -> same result).
        sigma_vr: 1-sigma of the radial velocity noise (m/s), sets the default threshold.
        threshold: inlier threshold on |v_r + u . v| (m/s), one number or (n,) per detection; default
            max(3 sigma_vr, 0.05).
        iterations: number of random minimal sets.
        planar: force planar (True) or 3-D (False) mode; None decides from the elevations.
        near: optional (v (3,), radius m/s): only hypotheses within `radius` of v compete, and v itself is a
            hypothesis instead of zero (the estimator's predicted sensor velocity: a prediction-gated RANSAC
            that follows an unmodelled jerk but never jumps to a larger moving consensus, e.g. a truck).

    Returns:
        EgoVelocity (ok=False if fewer detections or inliers than the minimal set).

    Checked by: tests/estimator/test_ego_velocity.py
    """
    azimuth, elevation, radial_velocity = _check_inputs(azimuth, elevation, radial_velocity)
    threshold = _check_ransac_args(azimuth, rng, sigma_vr, threshold, iterations)
    near = None if near is None else _check_near(near)
    n = len(azimuth)
    if planar is None:
        planar = is_planar(elevation)
    return ransac_velocity(_directions(azimuth, elevation), radial_velocity, rng, float(sigma_vr),
                           np.broadcast_to(threshold, (n,)), int(iterations), planar, near)


def ransac_velocity(u: np.ndarray, radial_velocity: np.ndarray, rng: np.random.Generator, sigma_vr: float,
                    threshold: np.ndarray, iterations: int, planar: bool, near) -> EgoVelocity:
    """`estimate_ego_velocity` from checked inputs: the detections' unit directions u (n, 3) (`_directions`),
    their radial velocities (n,), one threshold per detection (n,) and the planar decision (for a caller
    that has the directions already, as the odometry's Doppler front end does)."""
    n = len(u)
    dof = 2 if planar else 3
    if n < dof:
        return _failure(n, planar)
    draws = rng.integers(0, n, size=(iterations, dof))  # with replacement: a repeated row has det 0, skipped
    ref = np.zeros(dof) if near is None else np.array(near[0][:dof], dtype=float)
    v, cov, inliers = np.empty(dof), np.empty((dof, dof)), np.empty(n, np.bool_)
    if not doppler_kernels.ransac(np.ascontiguousarray(u[:, :dof], dtype=float), -np.asarray(radial_velocity, float),
                                  draws, np.ascontiguousarray(threshold, dtype=float), ref,
                                  np.inf if near is None else float(near[1]), float(sigma_vr) ** 2, v, cov, inliers):
        return _failure(n, planar)
    cov_out = np.zeros((3, 3))
    cov_out[:dof, :dof] = cov
    v_out = np.zeros(3)
    v_out[:dof] = v
    return EgoVelocity(v_out, cov_out, inliers, planar, True)


def _check_ransac_args(azimuth, rng, sigma_vr, threshold, iterations) -> np.ndarray:
    """Checked RANSAC settings; returns the inlier threshold (a number or one per detection)."""
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    sigma_vr = float(check_finite("sigma_vr", sigma_vr))
    if sigma_vr <= 0:
        raise InputError(f"sigma_vr: must be > 0, got {sigma_vr}")
    if threshold is None:
        threshold = max(3.0 * sigma_vr, MIN_THRESHOLD)
    threshold = check_finite("threshold", threshold)
    if threshold.ndim > 1 or (threshold.ndim == 1 and threshold.shape != azimuth.shape) or np.any(threshold <= 0):
        raise InputError(f"threshold: must be > 0, a number or one per detection, got shape {threshold.shape}")
    if isinstance(iterations, (bool, np.bool_)) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise InputError(f"iterations: must be a positive integer, got {iterations}")
    return threshold


def _check_near(near) -> tuple[np.ndarray, float]:
    v_near = check_finite("near velocity", near[0], (3,))
    radius = float(check_finite("near radius", near[1]))
    if not radius > 0:
        raise InputError(f"near radius: must be > 0, got {radius}")
    return v_near, radius
