"""The velocity's lag behind a manoeuvre (`[uncertainty] velocity_lag_per_acceleration`,
`velocity_lag_per_yaw_acceleration`, `velocity_lag_time`): a bias the reported velocity covariance adds as b b^T.

A motion prior that does not model the vehicle's manoeuvre lags behind it: under the constant-velocity prior a
sustained forward or yaw acceleration leaves the window's velocity behind the truth by about a lag time times the
acceleration (a tracker's steady-state lag to a ramp), and its covariance, which the measurements and the prior
alone shape, does not know. On the city drives CV/C's velocity error followed the estimated yaw acceleration with
correlation 0.8 (the lateral velocity's too, with the opposite sign), and its yaw rate's E[e^2 / P] was 7-9 where the
true yaw acceleration exceeded 0.1 rad/s^2, 0.5 elsewhere (docs/consistency.md, "The velocity's lag behind a
manoeuvre"). The acceleration is read causally from the emitted velocities: the change of the forward velocity
and of the yaw rate since the previous scan over dt, smoothed with time constant T (`velocity_lag_time`),

    a_k = phi a_{k-1} + (1 - phi) (varpi_k - varpi_{k-1})[x, yaw] / dt,    phi = exp(-dt / T)  (0 at T = 0),

from a_k = 0 at a run's first scan and at each re-initialisation (`uncertainty.fresh_starts`). The bias is
b_k = L a_k with L (6, 2) = [per_acceleration, per_yaw_acceleration] (the velocity error per unit of each), and
the reported velocity covariance gains b_k b_k^T: the velocity's mean squared error, its bias included. Nothing
in the solve, the gates or the drift recursion changes. `rodo calibrate` learns L by least squares of the
velocity errors of a drive with its truth on a_k (`validation.calibrate_velocity`), by default for the
constant-velocity prior only (a constant-acceleration prior carries the acceleration in its state); states.npz
stores each scan's b_k (`velocity_lag`) so that the window's covariance can be recovered from the reported one.

Checked by: tests/estimator/test_velocity_lag.py
"""

from __future__ import annotations

import numpy as np

LAG_AXES = np.array([0, 5])  # varpi's forward velocity and yaw rate: the vehicle's two controls


class VelocityLag:
    """A run's lag, scan by scan (`uncertainty.ReportedCovariances`): its smoothed acceleration a_k and each
    estimate's bias b_k = L a_k with P's velocity block + b_k b_k^T; nothing at all without a lag (L zeros).

    Checked by: tests/estimator/test_velocity_lag.py::test_the_run_adds_the_lag_the_states_replay
    """

    def __init__(self, config):
        self.L = lag_matrix(config)
        self.on = bool(self.L.any())
        self.smoothing = float(config.velocity_lag_time)
        self.acceleration = np.zeros(2)

    def annotate(self, est, step):
        """est (`ScanEstimate`) with velocity_lag and P set; step: (the previous estimate's varpi, dt), or None at
        a run's first scan and a re-initialisation (a_k = 0)."""
        if not self.on:
            return est
        self.acceleration = np.zeros(2) if step is None else lag_step(self.acceleration, step[0], est.varpi, step[1],
                                                                      self.smoothing)
        est.velocity_lag = self.L @ self.acceleration
        est.P = with_lag(est.P, est.velocity_lag)
        return est


def lag_matrix(config) -> np.ndarray:
    """L (6, 2) of an `UncertaintyConfig`: its per_acceleration and per_yaw_acceleration as columns."""
    return np.column_stack([np.asarray(config.velocity_lag_per_acceleration, dtype=float),
                            np.asarray(config.velocity_lag_per_yaw_acceleration, dtype=float)])


def lag_step(previous: np.ndarray, varpi_previous: np.ndarray, varpi: np.ndarray, dt: float,
             smoothing: float) -> np.ndarray:
    """a_k (2,) from a_{k-1}, the previous and this scan's velocities (6,) and the interval dt (s) between them
    (module docstring); T = `smoothing` (s), 0: the raw change (the config asks for T > 0)."""
    raw = (np.asarray(varpi, dtype=float)[LAG_AXES] - np.asarray(varpi_previous, dtype=float)[LAG_AXES]) / dt
    phi = np.exp(-dt / smoothing) if smoothing > 0.0 else 0.0
    return phi * previous + (1.0 - phi) * raw


def lag_accelerations(varpi: np.ndarray, t: np.ndarray, fresh: np.ndarray, smoothing: float) -> np.ndarray:
    """(N, 2) a_k of a run's emitted velocities varpi (N, 6) at times t (N,), 0 where `fresh` (N,) bool (a run's
    first scan, a re-initialisation): what the odometry computed scan by scan, bit for bit."""
    varpi, t = np.asarray(varpi, dtype=float), np.asarray(t, dtype=float)
    out = np.zeros((len(t), 2))
    for k in range(1, len(t)):
        if not fresh[k]:
            out[k] = lag_step(out[k - 1], varpi[k - 1], varpi[k], t[k] - t[k - 1], smoothing)
    return out


def with_lag(P: np.ndarray, bias: np.ndarray, sign: float = 1.0) -> np.ndarray:
    """P (d, d) or a stack (N, d, d) with `sign` b b^T added to its velocity block (rows and columns 6:12), b =
    `bias` (6,) or (N, 6); P itself where b is all zeros. sign -1 takes a reported covariance back to the
    window's."""
    bias = np.asarray(bias, dtype=float)
    if not bias.any():
        return P
    P = np.array(P, dtype=float)
    P[..., 6:12, 6:12] += sign * bias[..., :, None] * bias[..., None, :]
    return P
