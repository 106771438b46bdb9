"""Where a radar sits on the vehicle and what it sees of a point: mounts (T_vehicle_sensor), the sensor's own
velocity from the vehicle's, and polar coordinates (paper eq. 80). Shared by the radar model, the sensor
profiles and the rigs; re-exported by `sim.radar`.

Checked by: tests/sim/test_radar.py, tests/sim/test_culling.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.lie import se3, so3

from .culling import norm3
from .occlusion import cross

DEG = np.pi / 180.0


def mount(x: float, y: float, z: float, yaw: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """T_vehicle_sensor of a radar at (x, y, z) m of the rear-axle centre, yawed left by `yaw` and pitched up by
    `pitch` (rad)."""
    C = so3.exp(np.array([0.0, 0.0, yaw])) @ so3.exp(np.array([0.0, -pitch, 0.0]))
    return se3.from_rotation_translation(C, np.array([x, y, z]))


def default_mount() -> np.ndarray:
    """T_vehicle_sensor: 3.5 m forward, 0.5 m up of the rear-axle centre, yawed 1.0 deg, pitched up 0.5 deg."""
    return mount(3.5, 0.0, 0.5, yaw=1.0 * DEG, pitch=0.5 * DEG)


def sensor_velocity(varpi: np.ndarray, T_vehicle_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocity of the sensor origin and angular velocity, both in the sensor frame, from the state's varpi.

    v_sensor = C_vehicle_sensor^T (v + w x r_vehicle_sensor), w_sensor = C_vehicle_sensor^T w with
    [v; w] = -varpi (docs/conventions.md)."""
    v, w = -varpi[:3], -varpi[3:]
    C, r = T_vehicle_sensor[:3, :3], T_vehicle_sensor[:3, 3]
    return C.T @ (v + cross(w, r)), C.T @ w


def polar(p_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper eq. 80: (n, 3) sensor-frame points -> range, azimuth, elevation."""
    r = norm3(p_sensor)
    az = np.arctan2(p_sensor[:, 1], p_sensor[:, 0])
    el = np.arcsin(np.clip(p_sensor[:, 2] / np.maximum(r, 1e-300), -1.0, 1.0))
    return r, az, el
