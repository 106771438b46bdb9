"""Learning the radar's measurement noise R without ground truth (`rodo calibrate --no-truth`,
docs/calibration.md), from one estimator run's poses and the detections it kept as static.

- **Radial velocity.** A static target at unit direction u gives v_r = -u . v_s. Per scan, the least-squares
  sensor velocity of the detections the estimator's Doppler test kept as static (robustly: the movers the test
  let through are gated out). Its residuals have variance (1 - h_i)(sigma_vr^2 + a_i), h_i the leverage and a_i
  the share of the angles' noise, which moves u (`doppler_sigma`); sigma_vr^2 is their maximum likelihood over
  the scans, gated at `DOPPLER_GATE` sigma and corrected for it. A scan's own fit absorbs an error common to its
  radial velocities, so this is the independent sigma (as `calibrate_sensor.common_doppler_error` gives it with
  truth). The angles' sigmas come from the pairs below, which are fitted first.
- **Range, azimuth, elevation.** The same scatterer seen in two consecutive scans. Scan k-1's static detections
  are moved into scan k's sensor frame with the estimated relative pose and paired with scan k's static
  detections as mutual nearest neighbours that are isolated (the second-nearest neighbour at least
  `ISOLATION` times farther, both ways): a surface sampled afresh every scan has no such counterpart. The pair's
  difference in scan k's polar coordinates, d = z_k - s(M p(z_{k-1})), is n_k - G n_{k-1} - J delta, with G =
  ds/dz_{k-1}, delta the relative pose's error (covariance `P_relative` of the run) and J its Jacobian, so
  E[d_c^2] = sigma_c^2 + sum_c' G_cc'^2 sigma_c'^2 + (J P_relative J^T)_cc: linear in the three variances.
  Weighted least squares over all pairs (weights from the fitted variances), the pairs gated at the chi-square
  `PAIR_GATE` quantile of their fitted covariance and the variances corrected for that truncation, iterated to a
  fixed point.

What it assumes: static scatterers that persist from scan to scan (point scatterers, edges), and noise
independent from scan to scan. Scans at standstill (the sensor slower than `MOVING_SPEED`) are left out: a real
radar seeing the same scene from the same place often repeats its detections (the TI demo of `../shared/realdata`
to the bit), and a quantised Doppler reads exactly 0 there. Where the world is surfaces sampled afresh every scan,
isolated pairs are partly two different points of a surface, which reads as more noise (docs/calibration.md gives
the figures).

Checked by: tests/validation/test_calibrate_sensor_em.py
"""

from __future__ import annotations

import numpy as np
from scipy import optimize, spatial, stats

from rodo.estimator.ego_velocity import is_planar
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from rodo.estimator.radar_geometry import cartesian_to_polar_jacobian, polar_to_cartesian, polar_to_cartesian_jacobian
from rodo.estimator.radar_geometry import wrap_angle

from .calibrate_sensor import CHANNELS, cartesian_sigma
from .consistency import gated_mean

DOPPLER_GATE = 3.0  # sigma
PAIR_GATE = 0.999  # chi-square quantile of a pair's 3-dof difference
ISOLATION = 2.0  # the second-nearest neighbour at least this many times farther than the nearest
MIN_STATIC = 10  # a scan's static detections for its Doppler fit
MOVING_SPEED = 0.05  # m/s at the sensor: below it (at standstill) a scan is left out
ITERATIONS = 20  # at most, for each fixed point
TOLERANCE = 1e-4  # relative change of the variances that ends a fixed point


def _gated_share(dof: int, gate_probability: float) -> float:
    """E[d d^T | d inside its gate] over the covariance of d, for a Gaussian d of `dof` dimensions gated at its
    chi-square `gate_probability` quantile (`consistency.gated_mean` per dof)."""
    return gated_mean(dof, gate_probability) / dof


def _doppler_scan(polar: np.ndarray, dof: int):
    """(U (n, dof), y, du/d(az, el) (n, dof, 2), a robust first inlier mask) of one scan's static detections:
    y = -v_r = U v_s. The mask: least squares, then three times the residuals within 3 x 1.4826 x their median
    absolute deviation and the fit again (the movers the estimator's Doppler test let through)."""
    unit = np.column_stack([np.ones(len(polar)), polar[:, 1:3]])  # the directions: range 1
    U, du = polar_to_cartesian(unit)[:, :dof], polar_to_cartesian_jacobian(unit)[:, :dof, 1:3]
    y = -polar[:, 3]
    keep = np.ones(len(y), bool)
    for _ in range(3):
        v, *_ = np.linalg.lstsq(U[keep], y[keep], rcond=None)
        res = np.abs(y - U @ v)
        scale = 1.4826 * np.median(res[keep])
        keep = res <= 3.0 * max(scale, 1e-9)
        if keep.sum() <= dof + 1:
            keep = np.ones(len(y), bool)
            break
    return U, y, du, keep


def doppler_sigma(scans, planar: bool, angle_variances) -> dict:
    """sigma_vr from per-scan least-squares fits of the static detections: `scans` is a list of (n_k, 4) polar
    arrays of the detections kept as static, `angle_variances` (sigma_az^2, sigma_el^2) the angles' noise. The
    angles' noise enters the radial velocity's residual through the direction u (at 30 m/s, 3 mrad of azimuth
    noise 60 degrees off boresight is 0.08 m/s): its share a_i = g^T diag(angle_variances) g, g = d v_r / d(az,
    el) at the scan's velocity, is taken out. Maximum likelihood of sigma_vr^2 with the residuals' variances
    sigma_vr^2 + a_i: a fixed point with weights 1 / (sigma_vr^2 + a_i)^2 and the leverages h_i of each scan's
    fit (E[res_i^2] = (1 - h_i)(sigma_vr^2 + a_i)), the residuals gated at `DOPPLER_GATE` sigma and corrected for
    it. Returns sigma, the number of scans and detections used."""
    dof = 2 if planar else 3
    fits = [_doppler_scan(p, dof) for p in scans if len(p) >= MIN_STATIC]
    if not fits:
        raise InputError(f"radial velocity noise: no scan with >= {MIN_STATIC} static detections")
    a_var = np.asarray(angle_variances, dtype=float)
    keeps = [f[3] for f in fits]
    var, shrink = None, _gated_share(1, 2.0 * stats.norm.cdf(DOPPLER_GATE) - 1.0)
    for _ in range(ITERATIONS):
        sq, angle, weight, used, n_used = 0.0, 0.0, 0.0, 0, 0
        for i, (U, y, du, _) in enumerate(fits):
            keep = keeps[i]
            v, *_ = np.linalg.lstsq(U[keep], y[keep], rcond=None)
            res = y - U @ v
            a = np.einsum("nda,d->na", du, v) ** 2 @ a_var
            if var is not None:
                keeps[i] = keep = np.abs(res) <= DOPPLER_GATE * np.sqrt(var + a)
                if keep.sum() <= dof + 1:
                    continue
                v, *_ = np.linalg.lstsq(U[keep], y[keep], rcond=None)
                res = y - U @ v
            Uk, ak = U[keep], a[keep]
            h = np.einsum("ia,ab,ib->i", Uk, np.linalg.inv(Uk.T @ Uk), Uk)  # leverages
            w = 1.0 / (np.ones_like(ak) if var is None else var + ak) ** 2  # near boresight counts most
            sq += float(w @ res[keep] ** 2) / (1.0 if var is None else shrink)
            angle += float(w @ ((1.0 - h) * ak))
            weight += float(w @ (1.0 - h))
            used, n_used = used + 1, n_used + int(keep.sum())
        new = max((sq - angle) / max(weight, 1e-300), 1e-12)
        done = var is not None and abs(new - var) <= TOLERANCE * var
        var = new
        if done:
            break
    return {"sigma": float(np.sqrt(var)), "scans": used, "detections": n_used}


def _pairs(prev: np.ndarray, cur: np.ndarray, M: np.ndarray):
    """Isolated mutual nearest neighbours between scan k-1's static detections `prev` moved by M (sensor k-1 ->
    sensor k) and scan k's `cur`: (i_prev, i_cur, moved Cartesian points of prev in sensor k)."""
    if len(prev) < 2 or len(cur) < 2:
        return np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3))
    moved = polar_to_cartesian(prev) @ M[:3, :3].T + M[:3, 3]
    dist_f, j_f = spatial.cKDTree(polar_to_cartesian(cur)).query(moved, k=2)
    dist_b, j_b = spatial.cKDTree(moved).query(polar_to_cartesian(cur), k=2)
    i = np.arange(len(prev))
    mutual = j_b[j_f[:, 0], 0] == i
    isolated = (dist_f[:, 1] >= ISOLATION * dist_f[:, 0]) & (dist_b[j_f[:, 0], 1] >= ISOLATION * dist_f[:, 0])
    keep = mutual & isolated
    return i[keep], j_f[keep, 0], moved[keep]


def pair_terms(prev: np.ndarray, cur: np.ndarray, T_rel: np.ndarray, T_vehicle_sensor: np.ndarray,
               P_relative: np.ndarray | None):
    """The pairs of two consecutive scans (`_pairs`): differences d (m, 3) in scan k's [range, azimuth,
    elevation], G (m, 3, 3) = d s(M p(z_{k-1})) / d z_{k-1}, the pose term diag(J P_relative J^T) (m, 3) (zeros
    without P_relative) and scan k's ranges (m,). T_rel = T_k T_{k-1}^-1 of the vehicle poses."""
    T_sv = se3.inverse(T_vehicle_sensor)
    M = T_sv @ T_rel @ T_vehicle_sensor
    ip, ic, moved = _pairs(prev, cur, M)
    s, ds_dp = cartesian_to_polar_jacobian(moved)
    d = cur[ic, :3] - s
    d[:, 1] = wrap_angle(d[:, 1])
    G = ds_dp @ M[:3, :3] @ polar_to_cartesian_jacobian(prev[ip])
    pose = np.zeros_like(d)
    if P_relative is not None and np.all(np.isfinite(P_relative)):
        J = pose_jacobian(moved, T_vehicle_sensor, ds_dp)
        pose = np.einsum("mca,ab,mcb->mc", J, P_relative, J)
    return d, G, pose, cur[ic, 0]


def pose_jacobian(p_sensor: np.ndarray, T_vehicle_sensor: np.ndarray, ds_dp: np.ndarray | None = None) -> np.ndarray:
    """d s / d delta (m, 3, 6) of the polar coordinates s of points p_sensor (m, 3) in scan k's sensor frame
    under a left perturbation exp(delta^) of the relative vehicle pose T_k T_{k-1}^-1 (delta = [rho; phi]): the
    vehicle-frame point p_v moves by rho + phi x p_v. `ds_dp`: ds/dp at p_sensor when the caller has it."""
    if ds_dp is None:
        ds_dp = cartesian_to_polar_jacobian(p_sensor)[1]
    p_vehicle = p_sensor @ T_vehicle_sensor[:3, :3].T + T_vehicle_sensor[:3, 3]
    dpv = np.concatenate([np.broadcast_to(np.eye(3), (len(p_sensor), 3, 3)), -so3.hat(p_vehicle)], axis=2)
    return ds_dp @ T_vehicle_sensor[:3, :3].T @ dpv


def position_sigmas(d: np.ndarray, G: np.ndarray, pose: np.ndarray, s0: np.ndarray, planar: bool) -> dict:
    """Fixed point of the weighted least squares for s = [sigma_r^2, sigma_az^2, sigma_el^2] (module docstring)
    from the pairs' differences d, Jacobians G and pose terms, started at s0; in planar data the elevation is
    not learned (its variance stays s0[2] and its row is left out)."""
    rows = [0, 1] if planar else [0, 1, 2]
    dof = len(rows)
    gate, shrink = stats.chi2.ppf(PAIR_GATE, dof), _gated_share(dof, PAIR_GATE)
    s = np.asarray(s0, dtype=float).copy()
    A = np.eye(3)[None, :, :] + G**2  # (m, c, c'): E[d_c^2] = A[c] . s + pose_c
    keep = np.ones(len(d), bool)
    for _ in range(ITERATIONS):
        S = np.einsum("mac,c,mbc->mab", G, s, G) + np.diag(s)[None] + pose[:, :, None] * np.eye(3)[None]
        S = S[:, rows][:, :, rows]
        dr = d[:, rows]
        keep = np.einsum("ma,mab,mb->m", dr, np.linalg.inv(S), dr) <= gate
        if keep.sum() < 10:
            raise InputError(f"measurement noise: {int(keep.sum())} scan-to-scan pairs left after gating, need 10")
        a = A[keep][:, rows][:, :, rows]
        y = d[keep][:, rows] ** 2 - pose[keep][:, rows]
        expected = np.maximum(a @ s[rows], 1e-300)
        w = 1.0 / expected  # sqrt of 1 / Var(y) ~ 1 / (2 E[y]^2)
        sol, _ = optimize.nnls((a * w[..., None]).reshape(-1, dof), (y * w).reshape(-1))
        new = s.copy()
        new[rows] = np.maximum(sol, 1e-12 * max(float(np.max(sol)), 1e-300)) / shrink
        done = np.all(np.abs(new - s) <= TOLERANCE * s)
        s = new
        if done:
            break
    return {"variances": s, "pairs": int(keep.sum())}


def measurement_noise(estimates, T_vehicle_sensor: np.ndarray, s0) -> dict:
    """R from one run with detail (`run_sequence(..., record_detail=True)`'s estimates): per channel sigma,
    the Cartesian sigma of the CV/C model (None for planar data: the unknown elevation would dominate it), the
    pairs and scans used; s0 the starting sigmas (4,) (the config's). Raises InputError when the run holds
    too little (no detail, too few static detections or pairs)."""
    if not estimates or any(e.detail is None for e in estimates):
        raise InputError("measurement noise: the run holds no association detail (record_detail)")
    static = [e.detail.polar[e.detail.static] for e in estimates]
    all_el = np.concatenate([p[:, 2] for p in static]) if static else np.zeros(0)
    planar = is_planar(all_el)
    lever = float(np.linalg.norm(T_vehicle_sensor[:3, 3]))
    moving = [bool(np.linalg.norm(e.varpi[:3]) + lever * np.linalg.norm(e.varpi[3:]) >= MOVING_SPEED)
              for e in estimates]
    terms = []
    for k in range(1, len(estimates)):
        if estimates[k].restarted or not (moving[k - 1] or moving[k]):
            continue
        T_rel = estimates[k].T_vehicle_world @ se3.inverse(estimates[k - 1].T_vehicle_world)
        P_rel = estimates[k].P_relative
        terms.append(pair_terms(static[k - 1], static[k], T_rel, T_vehicle_sensor, P_rel))
    if not terms or sum(len(t[0]) for t in terms) < 10:
        raise InputError("measurement noise: fewer than 10 scan-to-scan pairs of static detections")
    d, G, pose, _ = (np.concatenate(x) for x in zip(*terms))
    s0 = np.asarray(s0, dtype=float)
    start = 4.0 * s0[:3] ** 2  # from above: a generous first gate
    if planar:
        start[2] = s0[2] ** 2  # not learned: the configured elevation sigma is kept
    fit = position_sigmas(d, G, pose, start, planar)
    sig = np.sqrt(fit["variances"])
    r_static = np.concatenate([p[:, 0] for p in static])  # the Cartesian sigma over every static detection
    cart = None if planar else cartesian_sigma(np.broadcast_to(np.r_[sig, 0.0], (len(r_static), 4)), r_static)
    doppler = doppler_sigma([p for p, m in zip(static, moving) if m], planar,
                            fit["variances"][1:3] * np.array([1.0, 0.0 if planar else 1.0]))
    sigmas = np.append(sig, doppler["sigma"])
    return {"sigmas": dict(zip(CHANNELS, sigmas.tolist())), "learned": [True, True, not planar, True],
            "pairs": fit["pairs"], "doppler_scans": doppler["scans"], "doppler_detections": doppler["detections"],
            "cartesian_sigma": cart, "planar": planar}
