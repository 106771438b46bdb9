"""Hypothesis strategies shared by the tests: vectors and twists in named regimes."""

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

_finite = dict(allow_nan=False, allow_infinity=False)


def vectors(n: int, scale: float):
    """Vectors of length n with components in [-scale, scale]."""
    return arrays(np.float64, (n,), elements=st.floats(-scale, scale, **_finite))


def rotation_vectors(regime: str = "any"):
    """Rotation vectors: 'tiny' (|phi| < 1e-6), 'vehicle' (< 0.5), 'near_pi' (pi - 1e-3 .. pi), 'any' (< pi)."""
    bounds = {"tiny": (0.0, 1e-6), "vehicle": (0.0, 0.5), "near_pi": (np.pi - 1e-3, np.pi - 1e-9),
              "any": (0.0, np.pi - 1e-6)}[regime]
    direction = vectors(3, 1.0).filter(lambda v: np.linalg.norm(v) > 1e-3)
    return st.tuples(direction, st.floats(*bounds)).map(lambda t: t[0] / np.linalg.norm(t[0]) * t[1])


def twists(regime: str = "any", translation_scale: float = 10.0):
    """se(3) vectors [rho; phi] with the rotation part in the given regime."""
    return st.tuples(vectors(3, translation_scale), rotation_vectors(regime)).map(lambda t: np.r_[t[0], t[1]])


def vehicle_motion():
    """(varpi, varpi_dot) of vehicle-like motion in the paper's convention (nu = -forward speed):
    speed up to 30 m/s, yaw rate up to 0.5 rad/s, roll/pitch rate up to 0.1 rad/s,
    accelerations up to 3 m/s^2, angular accelerations up to 0.5 rad/s^2."""
    speed = st.floats(0.0, 30.0)
    lateral = vectors(2, 1.0)
    rates = st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.5, 0.5))
    acc = vectors(3, 3.0)
    ang_acc = vectors(3, 0.5)

    def build(t):
        s, lat, (wx, wy, wz), a, aa = t
        varpi = np.array([-s, lat[0], lat[1], wx, wy, wz])
        return varpi, np.r_[a, aa]

    return st.tuples(speed, lateral, rates, acc, ang_acc).map(build)
