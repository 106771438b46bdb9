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


# ---------------------------------------------------------------------------------------------------------------
# Random streams drawn through hypothesis (sim engineer's block; appended, keep separate from the blocks above).
#
# Code under test that takes a numpy Generator (e.g. the trajectory profiles `sim.trajectory.city(rng, T)`) can be
# handed a `HypothesisRng` instead of `np.random.default_rng(seed)`: every draw then comes from hypothesis, so a
# failure shrinks (towards the low end of each range) instead of being reported as an opaque seed.


class HypothesisRng:
    """The scalar part of numpy's Generator interface (uniform, normal, integers, choice), backed by a
    hypothesis-controlled `random.Random` (`st.randoms()`). Array draws (`size=`) are drawn element by element."""

    def __init__(self, random):
        self._random = random

    def _many(self, draw, size):
        if size is None:
            return draw()
        return np.array([draw() for _ in range(int(np.prod(size)))], dtype=float).reshape(size)

    def uniform(self, low=0.0, high=1.0, size=None):
        return self._many(lambda: low + (high - low) * self._random.random(), size)

    def normal(self, loc=0.0, scale=1.0, size=None):
        # Box-Muller from two uniforms: |z| <= 8.6 (hypothesis's own gauss() may return any float, e.g. 1e300)
        def draw():
            u1, u2 = 1.0 - self._random.random(), self._random.random()
            return loc + scale * np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
        return self._many(draw, size)

    def integers(self, low, high=None, size=None):
        lo, hi = (0, low) if high is None else (low, high)
        out = self._many(lambda: self._random.randrange(lo, hi), size)
        return out if size is None else out.astype(int)

    def choice(self, a, size=None):
        items = list(a)
        return self._many(lambda: items[self._random.randrange(len(items))], size)

    def __repr__(self) -> str:
        return "HypothesisRng(...)"


def hypothesis_rngs():
    """`HypothesisRng`s whose draws hypothesis controls and shrinks (the calls are printed on failure)."""
    return st.randoms(note_method_calls=True, use_true_random=False).map(HypothesisRng)


# Covariances (added for the validation metrics: tests/validation/test_covariance.py, test_consistency.py).
# Keep additions of other areas in their own block below this one.
def orthogonal_matrices(d: int):
    """(d, d) orthogonal matrices: the Q factor of a drawn matrix (orthogonal even when the draw is singular)."""
    return arrays(np.float64, (d, d), elements=st.floats(-1.0, 1.0, **_finite)).map(lambda A: np.linalg.qr(A)[0])


def covariances(d: int, min_sd: float = 0.01, max_sd: float = 3.0):
    """Symmetric positive-definite (d, d) matrices Q diag(sd^2) Q^T, standard deviations in [min_sd, max_sd]."""
    sds = arrays(np.float64, (d,), elements=st.floats(min_sd, max_sd, **_finite))

    def build(t):
        Q, sd = t
        P = (Q * sd**2) @ Q.T
        return 0.5 * (P + P.T)

    return st.tuples(orthogonal_matrices(d), sds).map(build)
