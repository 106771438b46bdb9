"""A bounded pose error per axis beside the drift recursion (`uncertainty`; off by default, learned by `rodo
calibrate --stationary-error`).

The drift recursion composes every scan's relative pose covariance as an independent step, so a relative pose
over n scans gains n one-scan variances. Part of the registration's one-scan error is not a step: it is the
change of an error that the scene holds bounded (the far scene holds the heading, the ground the roll and pitch,
the map the position), so its changes cancel over a span instead of adding up. Measured per axis
(`validation.error_growth`), a covariance that composes them is right over one scan and cautious from a second
on: the yaw over 5 s at 0.12-0.40 of its stated variance in every cell of the verdict (docs/consistency.md, "How
the error grows, per axis", "A bounded error per axis").

So the reported covariances model a stationary error s (6, vehicle frame, left perturbation of T_vehicle_world)
beside the composed one, independent per axis, of variance V_i and exponential correlation over T_i seconds,

    Cov(s_i(t), s_i(t + L)) = V_i rho_i(L),   rho_i(L) = exp(-L / T_i),

whose change over one scan of dt, d_i = 2 V_i (1 - rho_i(dt)) (`one_scan_change`), is taken out of that scan's
relative pose covariance before the recursion composes it (`taken_out`: row and column i scaled so that the
variance falls by d_i, by at most 1 - KEEP of it). The pose error is then the composed one plus s at the pose
minus s at the start carried to it, so a relative pose over a span from scan j to scan k (and the absolute pose,
from the run's first scan, where the truth is aligned) adds (`span_term`)

    Cov(s_k - Ad s_j) = V + Ad V Ad^T - D Ad^T - Ad D,   Ad = Ad(T_k T_j^-1),   D = diag(V_i rho_i(t_k - t_j)),

the change of s over the span with its lever arm: a heading error at the span's start moves the lateral position
by the distance driven, as the composition carried the yaw's one-scan errors into it (without the lever arm the
lateral position over a second turned over-confident, 0.67 -> 1.82 per axis on hills CA/P). Over one scan the
relative pose covariance is the scan's own, as without the model (the measures compose the run's unreduced
inputs there: `validation.odometry_consistency.matched_span_terms`). An exponential correlation fits here, where
the attitude jitter's smooth one did not (`attitude_jitter`): its one-scan change is taken out of the
composition, not added to it.

Across a re-initialisation the dead-reckoned step is composed whole (no registration ran) and s keeps its
correlation in time: the model does not change there.

Checked by: tests/estimator/test_stationary_error.py
"""

from __future__ import annotations

import numpy as np

from .lie import se3

KEEP = 0.05  # the share of each axis's one-scan variance that stays in the composition at least


def stationary_error_array(stationary) -> np.ndarray:
    """(2, 6) [V; T] (m^2 or rad^2; s), per axis x, y, z, roll, pitch, yaw, the error's variance and correlation
    time; None: zeros and ones, off. ValueError unless all are finite, V >= 0 and T > 0."""
    if stationary is None:
        return np.vstack([np.zeros(6), np.ones(6)])
    s = np.asarray(stationary, dtype=float).reshape(2, 6)
    if not (np.all(np.isfinite(s)) and np.all(s[0] >= 0) and np.all(s[1] > 0)):
        raise ValueError(f"stationary error [V; T]: finite, V >= 0 and T > 0 expected, got {s.tolist()}")
    return s


def stationary_error_of(config) -> np.ndarray:
    """[V; T] (2, 6) of an `UncertaintyConfig`'s stationary error (V all 0: off)."""
    return stationary_error_array((config.stationary_variance, config.stationary_time))


def is_on(stationary) -> bool:
    return stationary is not None and bool(np.any(np.asarray(stationary, dtype=float)[0] > 0))


def one_scan_change(dt, stationary) -> np.ndarray:
    """(..., 6) d_i = 2 V_i (1 - exp(-dt / T_i)), the variance of s's change over dt (a float or an array)."""
    V, T = stationary_error_array(stationary)
    return 2.0 * V * -np.expm1(-np.asarray(dt, dtype=float)[..., None] / T)


def taken_out(P_relative: np.ndarray, dt, stationary) -> np.ndarray:
    """P_relative (6, 6) or (N, 6, 6) (scans dt (N,) apart) with each axis's one-scan change d_i taken out: row and
    column i scaled by sqrt(c_i), c_i = 1 - min(d_i, (1 - KEEP) P_ii) / P_ii (positive semi-definite as P is;
    the variance falls by d_i where it holds that much). P_relative itself when the model is off; axes with a
    zero variance and rows with NaN are kept as they are."""
    if not is_on(stationary):
        return P_relative
    P = np.array(P_relative, dtype=float)
    v = np.einsum("...ii->...i", P)
    d = one_scan_change(dt, stationary)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(v > 0, 1.0 - np.minimum(d, (1.0 - KEEP) * v) / v, 1.0)
    c = np.where(np.isfinite(c), c, 1.0)
    h = np.sqrt(c)
    return P * h[..., :, None] * h[..., None, :]


def span_term(T_end: np.ndarray, T_start: np.ndarray, L, stationary) -> np.ndarray:
    """(K, 6, 6) (or (6, 6) for single poses) Cov(s_end - Ad(T_end T_start^-1) s_start) of spans L seconds long
    (module docstring); zeros when the model is off."""
    V, T = stationary_error_array(stationary)
    Ad = se3.adjoint(np.asarray(T_end, dtype=float) @ se3.inverse(np.asarray(T_start, dtype=float)))
    D = V * np.exp(-np.abs(np.asarray(L, dtype=float))[..., None] / T)  # (..., 6): diag(V rho(L))
    AdT = np.swapaxes(Ad, -1, -2)
    cross = D[..., :, None] * AdT  # D Ad^T
    return np.diag(V) + (Ad * V[None, :]) @ AdT - cross - np.swapaxes(cross, -1, -2)
