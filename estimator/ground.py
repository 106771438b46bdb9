"""Road returns: the static detections the odometry keeps out of its map and its pairs
(`association.ground_band`).

The road is seen at grazing angles and sampled afresh every scan, so a map point made from an earlier road
return is paired with a different road sample near it, inside the slack that the map sigma and the elevation
noise give. Those pairs are not zero-mean: the solve reads the new road returns as lying below the map points and
raises the sensor a little at every scan, which the map made from the raised pose carries on (docs/consistency.md,
"The bias: ground returns under point-to-point association"). Left out of the pairs, the road still serves the
Doppler front end (its radial velocities are as good as any).

Per scan, in the vehicle frame: among the detections 2-40 m away (horizontally) and `MIN_DROP` below the sensor,
the road starts as the lowest level layer (`LAYER` high) that holds at least half as many as the densest one (on a
highway the guard rails can hold more than the road); a plane z = a x + b y + c, from the layer's median height, is
then fitted `FITS` times by least squares to the detections within `SLAB` of the plane before, trimmed at 2.5
robust sigmas (a tilted road is followed out of the level layer it started from), with at least `MIN_ROAD`
detections; the detections within +-band of it are road. The band is symmetric, so the returns left in keep a
zero-mean spread about the plane (a one-sided height cut clips the noise of low objects and biases them instead).
No road: a sensor whose detections lie in one plane with it (a 2D radar), a layer too sparse, or a plane steeper
than `MAX_SLOPE`.

Checked by: tests/estimator/test_ground.py
"""

from __future__ import annotations

import numpy as np

from .radar_geometry import polar_to_cartesian

MIN_ROAD = 20  # detections the road layer needs
NEAR = (2.0, 40.0)  # m, horizontal distances that can hold the road layer
LAYER = 0.3  # m, height of the layer search's window
FITS = 4  # least-squares fits of the plane, each to the detections near the one before
SLAB = 0.3  # m, half-height of the detections the plane is fitted to
MIN_DROP = 0.2  # m, the road lies at least this far below the sensor
MAX_SLOPE = 0.3  # the steepest road plane (rise over run)


def road_mask(p_vehicle: np.ndarray, sensor_z: float, band: float) -> np.ndarray:
    """(n,) mask of the detections within `band` (m) of this scan's road plane (none when it has no road).

    p_vehicle: (n, 3) the detections in the vehicle frame; sensor_z: the sensor's height in that frame.
    """
    n = len(p_vehicle)
    none = np.zeros(n, bool)
    if band <= 0 or n < MIN_ROAD:
        return none
    x, y, z = p_vehicle[:, 0], p_vehicle[:, 1], p_vehicle[:, 2]
    d = np.hypot(x, y)
    near = np.flatnonzero((d >= NEAR[0]) & (d <= NEAR[1]) & (z <= sensor_z - MIN_DROP))
    if len(near) < MIN_ROAD:
        return none
    A = np.column_stack((x[near], y[near], np.ones(len(near))))
    h = np.sort(z[near])
    counts = np.searchsorted(h, h + LAYER, side="right") - np.arange(len(h))  # in [h[i], h[i] + LAYER]
    if counts.max() < MIN_ROAD:
        return none
    # the lowest layer that holds half as many as the densest (guard rails or a kerb may hold more than the road)
    i = int(np.argmax(counts >= max(MIN_ROAD, 0.5 * counts.max())))
    coef = np.array([0.0, 0.0, np.median(h[i:i + counts[i]])])
    for _ in range(FITS):  # refit to the detections near the plane so far, trimmed at 2.5 robust sigmas
        res = np.abs(z[near] - A @ coef)
        slab = res < SLAB
        if slab.sum() < MIN_ROAD:
            return none
        slab &= res < 2.5 * max(1.4826 * np.median(res[slab]), 0.01)
        coef = np.linalg.lstsq(A[slab], z[near][slab], rcond=None)[0]
    if max(abs(coef[0]), abs(coef[1])) > MAX_SLOPE:
        return none
    return np.abs(z - (coef[0] * x + coef[1] * y + coef[2])) < band


def off_road(polar: np.ndarray, static: np.ndarray, T_vehicle_sensor: np.ndarray, band: float) -> np.ndarray:
    """The static detections that are not road returns: `static` (n,) without `road_mask` of the static
    detections (polar (n, 4) [r, az, el, v_r] in the sensor frame); `static` itself when band is 0."""
    if band <= 0:
        return static
    idx = np.flatnonzero(static)
    p = polar_to_cartesian(polar[idx]) @ T_vehicle_sensor[:3, :3].T + T_vehicle_sensor[:3, 3]
    out = static.copy()
    out[idx[road_mask(p, float(T_vehicle_sensor[2, 3]), band)]] = False
    return out
