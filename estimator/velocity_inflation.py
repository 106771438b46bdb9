"""The reported velocity covariance's factor (`uncertainty.velocity_inflation` and its terms): the window's
velocity covariance hardly depends on the speed, the manoeuvre or the rates, its error does
(docs/consistency.md, "The velocity's error grows with the speed" and the sections after it).

- `velocity_factor`: c = a + b |nu| + d ln(1 + nis) + r . |omega| per scan.
- `velocity_inflated`: P with the velocity block scaled by c (and per axis).
- `velocity_inflation_array` / `velocity_inflation_terms`: the factor's terms as states.npz stores them
  (`velocity_inflation` = [a, b, d] or, with rate terms, [a, b, d, r_x, r_y, r_z]) and back.

Checked by: tests/estimator/test_uncertainty_inflation.py
"""

from __future__ import annotations

import numpy as np


def velocity_inflated(P: np.ndarray, varpi: np.ndarray, inflation: float, per_speed: float, per_doppler: float = 0.0,
                      doppler_nis=None, per_axis=None, per_rate=None) -> np.ndarray:
    """P with the velocity's variance scaled by c = inflation + per_speed |nu| + per_doppler ln(1 + nis) + per_rate .
    |omega| (`velocity_factor`; nu = varpi[:3], the speed in m/s; nis the scan's Doppler innovation NIS per dof;
    |omega| the absolute body rates varpi[3:], rad/s) and per axis by per_axis (6,) ([vx, vy, vz, wx, wy, wz];
    None: ones): velocity element i's variance times c g_i, its
    covariances with element j times sqrt(c g_i c g_j) or sqrt(c g_i), the rest unchanged (D P D with D diagonal,
    so it stays a covariance). One (d, d) with varpi (6,) and a float nis, or a stack (N, d, d) with (N, 6) and
    (N,). At c = 1 (inflation 1, per_speed, per_doppler and per_rate 0) and g = 1, P itself, bit for bit; at g = 1
    bit for bit the factor c alone.

    Why (docs/consistency.md, "The velocity's error grows with the speed" and "... and at a manoeuvre"): the
    window's velocity covariance hardly depends on the speed (the same pairs and Doppler rows at any speed),
    its error does (surfaces resampled from farther apart between scans); and where the motion leaves the
    prior's model (a turn's onset, a start), the window's velocity is wrong by more than its covariance says,
    which the scan's Doppler shows against the prediction before any solve; and where the window's roll and pitch
    rates are not near zero ("... and with the rates"). `rodo calibrate` learns the terms from the velocity errors
    of a drive with ground truth (`validation.calibrate_velocity.fit_velocity_inflation`). The drift recursion
    keeps the window's velocity covariance: its tau and drift rate are calibrated with that one.
    """
    axes = np.ones(6) if per_axis is None else np.asarray(per_axis, dtype=float).reshape(6)
    rates = np.zeros(3) if per_rate is None else np.asarray(per_rate, dtype=float).reshape(3)
    if inflation == 1.0 and per_speed == 0.0 and per_doppler == 0.0 and np.all(axes == 1.0) and not rates.any():
        return P
    P = np.asarray(P, dtype=float)
    c = velocity_factor(varpi, inflation, per_speed, per_doppler, doppler_nis, rates)
    d = np.ones(P.shape[:-1])
    d[..., 6:12] = np.sqrt(c)[..., None] * np.sqrt(axes)
    return P * d[..., :, None] * d[..., None, :]


def velocity_factor(varpi, inflation: float, per_speed: float, per_doppler: float = 0.0, doppler_nis=None,
                    per_rate=None):
    """c = inflation + per_speed |nu| + per_doppler ln(1 + nis) + per_rate . |omega| of one varpi (6,) (a float) or
    of a stack (N, 6) ((N,)); nis the Doppler innovation NIS per dof (NaN, a scan without a Doppler fit: no term;
    None: none at all); per_rate (3,) s/rad on the absolute body rates (None: none). Bit for bit the two-term
    factor when per_doppler and per_rate are 0.

    Checked by: tests/estimator/test_uncertainty_inflation.py::test_velocity_factor_with_rates
    """
    varpi = np.asarray(varpi, dtype=float)
    c = inflation + per_speed * np.linalg.norm(varpi[..., :3], axis=-1)
    if per_rate is not None and np.any(per_rate):
        c = c + np.abs(varpi[..., 3:6]) @ np.asarray(per_rate, dtype=float)
    if per_doppler == 0.0 or doppler_nis is None:
        return c
    return c + per_doppler * doppler_term(doppler_nis)


def doppler_term(doppler_nis):
    """ln(1 + nis) of the Doppler innovation NIS per dof (a float or an array), 0 where it is NaN (a scan without
    a prediction or a Doppler fit): the quantity `velocity_factor`'s per_doppler multiplies."""
    nis = np.asarray(doppler_nis, dtype=float)
    return np.log1p(np.where(np.isfinite(nis), np.maximum(nis, 0.0), 0.0))


def velocity_inflation_array(inflation: float, per_speed: float, per_doppler: float, per_rate=None) -> np.ndarray:
    """states.npz `velocity_inflation` of these terms: [a, b, d], and the three rate terms after them only where
    one is not 0 (so runs without them read as before)."""
    rates = [] if per_rate is None else [float(x) for x in per_rate]
    return np.array([inflation, per_speed, per_doppler] + (rates if any(rates) else []), dtype=float)


def velocity_inflation_terms(array) -> tuple[float, float, float, np.ndarray]:
    """(a, b, d, rates (3,)) of a states.npz `velocity_inflation`: [a, b] (older runs: d = 0), [a, b, d] or
    [a, b, d, r_x, r_y, r_z].

    Checked by: tests/estimator/test_uncertainty_inflation.py::test_velocity_inflation_array_round_trips
    """
    v = np.asarray(array, dtype=float).reshape(-1)
    if v.size not in (2, 3, 6):
        raise ValueError(f"velocity_inflation: expected 2, 3 or 6 numbers, got {v.size}")
    a, b, d = np.r_[v, 0.0][:3]
    return float(a), float(b), float(d), (v[3:6].copy() if v.size == 6 else np.zeros(3))
