"""Hypothesis strategies for the estimator's property tests: scenes drawn element by element (so a failure
shrinks to a small scene with simple numbers), not from a seeded generator."""

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

_finite = dict(allow_nan=False, allow_infinity=False)


@st.composite
def _column_array(draw, n_min: int, n_max: int, *bounds):
    """(n, len(bounds)) arrays, column c in bounds[c] = (lo, hi); n in [n_min, n_max]."""
    n = draw(st.integers(n_min, n_max))
    columns = [draw(arrays(np.float64, (n,), elements=st.floats(lo, hi, **_finite))) for lo, hi in bounds]
    return np.stack(columns, axis=1) if n else np.zeros((0, len(bounds)))


def polar_points(n_min: int, n_max: int, r=(5.0, 80.0), az=(-1.0, 1.0), el=(-0.15, 0.15)):
    """(n, 3) sensor-frame positions as [range, azimuth, elevation]."""
    return _column_array(n_min, n_max, r, az, el)


def detections(n_min: int, n_max: int, r=(5.0, 15.0), az=(-1.0, 1.0), el=(-0.15, 0.15), vr=(-6.0, -3.0)):
    """(n, 4) detections [range, azimuth, elevation, radial velocity]."""
    return _column_array(n_min, n_max, r, az, el, vr)


@st.composite
def directions(draw, n: int, az_fov: float = np.deg2rad(60), el_fov: float = np.deg2rad(15),
               planar: bool = False):
    """(n, 2) [azimuth, elevation] spread over a field of view: a regular grid (azimuths across the view,
    elevations cycling over five levels; 0 when planar) with each point moved by a drawn jitter of up to half a
    grid cell. Shrinks to the grid; never degenerate (the ego-velocity fit needs spread directions)."""
    az = np.linspace(-az_fov, az_fov, n)
    levels = np.linspace(-el_fov, el_fov, 5)
    el = np.zeros(n) if planar else levels[np.arange(n) % 5]
    jitter = draw(arrays(np.float64, (n, 2), elements=st.floats(-0.5, 0.5, **_finite)))
    az = az + jitter[:, 0] * (2 * az_fov / max(n - 1, 1))
    if not planar:
        el = el + jitter[:, 1] * (levels[1] - levels[0])
    return np.stack([az, el], axis=1)


def cartesian_points(n_min: int, n_max: int, extent: float):
    """(n, 3) points in a cube of half-edge `extent`."""
    b = (-extent, extent)
    return _column_array(n_min, n_max, b, b, b)


def scans_of_points(max_scans: int, max_points: int, extent: float = 50.0):
    """A list of (k, 3) point sets, one per scan."""
    return st.lists(cartesian_points(0, max_points, extent), min_size=1, max_size=max_scans)
