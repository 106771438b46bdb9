"""The reported velocity covariance's factor learned from a drive with ground truth (`rodo calibrate`, its
uncertainty section; `estimator.velocity_inflation`): c = a + b |nu| + d ln(1 + nis) + r . |omega| and the per-axis
factors g, by maximum likelihood of the velocity errors; and, when asked, the velocity's lag behind a manoeuvre L
(`estimator.velocity_lag`) before them, by least squares; both without the scans the estimator failed outright
(`gross_failures`).

Checked by: tests/validation/test_calibrate_velocity.py::test_velocity_inflation_recovers_a_known_factor,
    ::test_the_lag_and_the_factor_are_recovered_together, ::test_a_gross_failure_is_left_out_of_the_velocity_fit
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from rodo.estimator.uncertainty import fresh_starts
from rodo.estimator.velocity_inflation import doppler_term
from rodo.estimator.velocity_lag import lag_accelerations

from .association import DEFAULT_TOLERANCE, associate
from .gross_failures import fit_without_gross_failures
from .odometry_consistency import DOF, drift_velocity_covariances
from .run_consistency import runs_of


def _velocity_terms(states, truth, tolerance: float, smoothing: float | None) -> dict:
    """Per scan of every run with finite values: e (K, 6) the velocity errors, P (K, 6, 6) the window's velocity
    covariances (`drift_velocity_covariances`) and Pi their inverses, the factor's regressors X (K, 6) = [1, |nu|,
    ln(1 + nis), |omega_x|, |omega_y|, |omega_z|], the lag's smoothed accelerations A (K, 2) (`lag_accelerations` at
    `smoothing`, across each run from its first scan and its re-initialisations; zeros with smoothing None), and
    where each scan is: run (K,) its run's index, t (K,) its time since that run's first scan (s)."""
    out = {"e": [], "P": [], "Pi": [], "X": [], "A": [], "run": [], "t": []}
    for i, (st, tr) in enumerate(runs_of(states, truth)):
        ia, ib = associate(st["t"], tr["t"], tolerance)
        varpi = np.asarray(st["varpi"], dtype=float)
        out["e"].append(np.asarray(tr["varpi"], dtype=float)[ib] - varpi[ia])
        P = drift_velocity_covariances(st["P"], varpi, st.get("velocity_inflation"), st.get("doppler_nis"),
                                       st.get("velocity_axis_inflation"), st.get("velocity_lag"))[ia]
        out["P"].append(P)
        out["Pi"].append(np.linalg.inv(P))
        w = varpi[ia]
        doppler = doppler_term(np.asarray(st["doppler_nis"])[ia]) if "doppler_nis" in st else np.zeros(len(ia))
        out["X"].append(np.column_stack([np.ones(len(ia)), np.linalg.norm(w[:, :3], axis=1), doppler,
                                         np.abs(w[:, 3:6])]))
        fresh = fresh_starts(st.get("restarted"), len(varpi))
        out["A"].append(np.zeros((len(ia), 2)) if smoothing is None
                        else lag_accelerations(varpi, st["t"], fresh, smoothing)[ia])
        t = np.asarray(st["t"], dtype=float)
        out["run"].append(np.full(len(ia), i))
        out["t"].append(t[ia] - t[0])
    out = {k: np.concatenate(v) for k, v in out.items()}
    finite = np.all(np.isfinite(out["Pi"]), axis=(1, 2)) & np.all(np.isfinite(out["e"]), axis=1)
    return {k: v[finite] for k, v in out.items()}


def _nll(x, X, M_ee, M_eb, M_bb):
    """-2 log-likelihood (up to a constant) of e ~ N(0, c K + b b^T), K = D P D (D = diag(sqrt(g)), prod g = 1, so
    log |K| = log |P|), c = X p, and its gradient in x = (p (6), the first five log g), by Sherman-Morrison from
    q_ee = e^T K^-1 e, q_eb = e^T K^-1 b and q_bb = b^T K^-1 b, each h^T M h with M the elementwise product of the
    vectors' outer product and P^-1 (h = 1 / sqrt(g)): 5 log c + log s + q_ee / c - q_eb^2 / (s c), s = c + q_bb;
    at b = 0, 6 log c + q_ee / c."""
    p, h = x[:6], np.exp(-0.5 * np.r_[x[6:], -np.sum(x[6:])])
    c = X @ p
    Mh = {k: M @ h for k, M in (("ee", M_ee), ("eb", M_eb), ("bb", M_bb))}
    q = {k: v @ h for k, v in Mh.items()}
    s = c + q["bb"]
    f = 5.0 * np.log(c) + np.log(s) + q["ee"] / c - q["eb"] ** 2 / (s * c)
    df_dc = 5.0 / c + 1.0 / s - q["ee"] / c**2 + q["eb"] ** 2 * (s + c) / (s * c) ** 2
    weights = {"ee": 1.0 / c, "eb": -2.0 * q["eb"] / (s * c), "bb": 1.0 / s + q["eb"] ** 2 / (s**2 * c)}
    dq = sum(-w[:, None] * h * Mh[k] for k, w in weights.items())  # d f / d log g_i through each q (M symmetric)
    return float(np.sum(f)), np.r_[df_dc @ X, (dq[:, :5] - dq[:, 5:]).sum(axis=0)]


def fit_velocity_inflation(states: dict | list, truth: dict | list, tolerance: float = DEFAULT_TOLERANCE,
                           per_axis: bool = False, per_rate: bool = True, lag: bool = False,
                           lag_time: float = 0.3) -> dict:
    """The velocity's variance factor c_k = a + b |nu_k| + d ln(1 + nis_k) + r . |omega_k| and, with `per_axis`, its
    per-axis factors g (6,; else ones) of one run (or runs, pooled) by maximum likelihood: the velocity errors
    e_k ~ N(0, c_k D P_k D), D = diag(sqrt(g)), prod g = 1 (the overall scale is c's), P_k the window's velocity
    covariance (`drift_velocity_covariances`: whatever factors the run had are divided out), nu_k its estimated
    linear velocity, omega_k its estimated body rates (r (3,), with `per_rate`; else zeros), nis_k the scan's
    Doppler innovation NIS per dof (states' doppler_nis; NaN, and runs without it, count 0), over every scan (the
    start too: it holds the low speeds; left out, the factor came out over-confident at the start of every
    campaign drive); a > 0, b, d, r >= 0. Returns {"inflation": a, "per_speed": b, "per_doppler": d, "per_rate":
    r, "per_axis": g, "lag_per_acceleration", "lag_per_yaw_acceleration": L's columns (6,) each, "lag_time" T,
    "scans": those fitted, "nees_per_dof": their mean velocity NEES/dof before and after, "gross_failures": the
    scans left out ({"scans": how many, "runs", "t": where; `gross_failures`: the fits run again without the
    scans whose NEES under the fit exceeds 100 per dof at the median scan's level, an outright failure, which no
    Gaussian factor describes and which would otherwise set it)}.

    With `lag`, the velocity's lag behind a manoeuvre first (`estimator.velocity_lag`): L (6, 2) by least squares of
    e_k on a_k, the run's forward and yaw acceleration smoothed over `lag_time` T (the errors' mean given a_k; the
    velocity error follows a_k where the prior lags behind the manoeuvre, on the city drives under CV/C with
    correlation 0.8 in the yaw rate); the factor's likelihood is then that of e_k ~ N(0, c_k D P_k D + b_k b_k^T),
    b_k = L a_k, as the odometry reports it. Without it L is zeros.

    The per-axis factors correct the shape of the window's velocity covariance, which c alone cannot: on the
    verdict's drives its vertical velocity was over-confident 2-4 times, its lateral velocity and roll and yaw
    rates cautious 2-10 times. `rodo calibrate` learns them by default (`--no-velocity-axes`: not): without the
    rate terms the verdict's campaigns had fewer scans inside their bounds with them, with them more or as many in
    every cell (docs/consistency.md, "... and per axis" and "... and with the rates"). The rate terms follow
    where in a drive the window's velocity is over-confident (where its roll and pitch rates are not near zero).

    Checked by: tests/validation/test_calibrate_velocity.py::test_velocity_inflation_recovers_a_known_factor,
        ::test_velocity_axis_inflation_recovers_known_factors,
        ::test_a_gross_failure_is_left_out_of_the_velocity_fit
    """
    terms = _velocity_terms(states, truth, tolerance, lag_time if lag else None)
    e, Pi = terms["e"], terms["Pi"]
    q0 = np.einsum("ki,kij,kj->k", e, Pi, e)
    none = {"inflation": 1.0, "per_speed": 0.0, "per_doppler": 0.0, "per_rate": [0.0] * 3, "per_axis": [1.0] * 6}
    if len(q0) < 2 or not np.mean(q0) > 0:  # too few scans, or no error at all (a noise-free drive)
        return {**none, **_lag_report(np.zeros((6, 2)), lag_time), "scans": int(len(q0)),
                "nees_per_dof": [np.nan, np.nan], "gross_failures": _failures_report(terms, np.zeros(len(q0), bool))}
    (p, g, L), failed, nees = fit_without_gross_failures(
        lambda keep: _fit(terms, keep, per_axis, per_rate), lambda fit: _scan_nees(terms, *fit), len(e), DOF)
    kept = ~failed
    after = float(np.mean(nees[kept])) / DOF
    return {"inflation": float(p[0]), "per_speed": float(p[1]), "per_doppler": float(p[2]),
            "per_rate": [float(x) for x in p[3:6]], "per_axis": [float(x) for x in g], **_lag_report(L, lag_time),
            "scans": int(kept.sum()), "nees_per_dof": [float(np.mean(q0[kept])) / DOF, after],
            "gross_failures": _failures_report(terms, failed)}


def _fit(terms: dict, keep: np.ndarray, per_axis: bool, per_rate: bool) -> tuple:
    """(p (6,), g (6,), L (6, 2)) of `fit_velocity_inflation` on the scans `keep` (K,) of `_velocity_terms`: L by
    least squares (zeros without the lag's accelerations), then p and g by maximum likelihood."""
    e, Pi, X, A = (terms[k][keep] for k in ("e", "Pi", "X", "A"))
    L = np.linalg.lstsq(A, e, rcond=None)[0].T if np.any(A) else np.zeros((6, 2))
    b = A @ L.T
    M_ee = e[:, :, None] * e[:, None, :] * Pi
    M_eb = 0.5 * (e[:, :, None] * b[:, None, :] + b[:, :, None] * e[:, None, :]) * Pi
    M_bb = b[:, :, None] * b[:, None, :] * Pi
    a0 = float(np.mean(M_ee.sum(axis=(1, 2)))) / DOF
    rate_bound = (0.0, None) if per_rate else (0.0, 0.0)
    res = minimize(_nll, np.r_[a0, np.zeros(5), np.zeros(5)], args=(X, M_ee, M_eb, M_bb), jac=True,
                   method="L-BFGS-B", bounds=[(1e-6 * a0, None), (0.0, None), (0.0, None)] + [rate_bound] * 3
                   + [(-12.0, 12.0) if per_axis else (0, 0)] * 5,
                   options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 2000})
    return res.x[:6], np.exp(np.r_[res.x[6:], -np.sum(res.x[6:])]), L


def _scan_nees(terms: dict, p: np.ndarray, g: np.ndarray, L: np.ndarray) -> np.ndarray:
    """(K,) every scan's velocity NEES at the fitted covariance c D P D + b b^T."""
    e, X, A = terms["e"], terms["X"], terms["A"]
    b = A @ L.T
    K = terms["P"] * np.sqrt(g[:, None] * g[None, :])
    Sigma = (X @ p)[:, None, None] * K + b[:, :, None] * b[:, None, :]
    return np.einsum("ki,ki->k", e, np.linalg.solve(Sigma, e[..., None])[..., 0])


def _failures_report(terms: dict, failed: np.ndarray) -> dict:
    """The scans left out as gross failures: how many, and where (run index, seconds since its first scan)."""
    return {"scans": int(failed.sum()), "runs": [int(r) for r in terms["run"][failed]],
            "t": [round(float(t), 3) for t in terms["t"][failed]]}


def _lag_report(L: np.ndarray, lag_time: float) -> dict:
    return {"lag_per_acceleration": [float(x) for x in L[:, 0]],
            "lag_per_yaw_acceleration": [float(x) for x in L[:, 1]], "lag_time": float(lag_time)}
