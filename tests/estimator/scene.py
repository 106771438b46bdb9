"""A tiny hand-built scene for estimator tests, independent of sim/: persistent point landmarks, a
constant-acceleration trajectory integrated exactly, and radar measurements computed from plain geometry
(range = |p|, azimuth = atan2, elevation = asin, radial velocity = d(range)/dt by central differences of the
true motion), so the estimator's measurement models are checked against something they did not produce."""

from __future__ import annotations

import numpy as np

from rodo.estimator.lie import se3, so3
from rodo.estimator.priors.exact import exact_predict

T_VEHICLE_SENSOR = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.02, 0.03])), np.array([3.5, 0.1, 0.6]))
SIGMAS = np.array([0.02, np.deg2rad(0.15), np.deg2rad(0.3), 0.01])


def trajectory(n_scans: int, rate: float = 13.0, speed: float = 10.0, accel: float = 1.0,
               yaw_rate: float = 0.1, yaw_acc: float = 0.05, pitch_acc: float = 0.02):
    """Times, T_vehicle_world, varpi, varpi_dot of one CA segment (paper convention: nu = -speed)."""
    varpi = np.array([-speed, 0, 0, 0, 0, -yaw_rate])
    vd = np.array([-accel, 0, 0, 0, -pitch_acc, -yaw_acc])
    t = np.arange(n_scans) / rate
    Ts = [exact_predict(np.eye(4), varpi, vd, tk)[0] if tk > 0 else np.eye(4) for tk in t]
    return t, np.stack(Ts), varpi[None] + t[:, None] * vd[None], np.tile(vd, (n_scans, 1))


def landmarks(rng: np.random.Generator, n: int = 600, extent: float = 160.0) -> np.ndarray:
    x = rng.uniform(-20, extent, n)
    y = rng.choice([-1, 1], n) * rng.uniform(4, 30, n)
    z = rng.uniform(-1.0, 6.0, n)
    return np.c_[x, y, z]


def _polar(p_s):
    r = np.linalg.norm(p_s, axis=1)
    return r, np.arctan2(p_s[:, 1], p_s[:, 0]), np.arcsin(p_s[:, 2] / r)


def measure(T_vw, varpi, vd, p_world, rng=None, sigmas=SIGMAS, fov=(np.deg2rad(60), np.deg2rad(15)),
            max_range=120.0, T_vehicle_sensor=T_VEHICLE_SENSOR):
    """Detections (n, 4) [r, az, el, vr] of the landmarks in the field of view of the radar mounted at
    T_vehicle_sensor, noisy if rng is given."""
    T_sw = se3.inverse(T_vehicle_sensor) @ T_vw
    p_s = se3.transform_points(T_sw, p_world)
    r, az, el = _polar(p_s)
    keep = (r < max_range) & (np.abs(az) < fov[0]) & (np.abs(el) < fov[1]) & (p_s[:, 0] > 0.5)
    # radial velocity by differentiating the range along the true CA motion (no measurement model involved)
    h = 1e-4
    ranges = []
    for s in (-h, h):
        T, _, _ = exact_predict(T_vw, varpi, vd, s) if s > 0 else _backward(T_vw, varpi, vd, -s)
        ranges.append(np.linalg.norm(se3.transform_points(se3.inverse(T_vehicle_sensor) @ T, p_world), axis=1))
    vr = (ranges[1] - ranges[0]) / (2 * h)
    z = np.c_[r, az, el, vr][keep]
    if rng is not None:
        z = z + rng.normal(size=z.shape) * sigmas
    return z


def _backward(T, varpi, vd, s):
    # integrate backwards: reverse time dynamics
    from scipy.integrate import solve_ivp

    def rhs(t, y):
        w = varpi - t * vd
        return (-(se3.hat(w) @ y.reshape(4, 4))).ravel()

    sol = solve_ivp(rhs, (0, s), T.ravel(), method="DOP853", rtol=1e-13, atol=1e-13)
    return sol.y[:, -1].reshape(4, 4), None, None
