"""The one-scan relative pose covariance's factor learned from a drive with ground truth (`rodo calibrate`, its
uncertainty section): c = f + r . |omega| + d ln(1 + nis) + p pull (`[uncertainty] inflation` f,
`inflation_per_rate` r, s/rad on the scan's absolute estimated body rates, `inflation_per_doppler` d on its Doppler
innovation NIS per dof, as the velocity's factor, and `inflation_per_pull` p on its pull on the solved pose,
`estimator.pull`) on the window's relative pose covariance and its revision term
(`estimator.uncertainty.ReportedCovariances`). The one-scan relative pose's composed covariance is then
c A + V, A the part the factor scales, V the velocity error's and the drift rate's shares, which it does not (but
`rodo calibrate` learns a factor g on the velocity error's share with it: `[uncertainty] velocity_error_share`).

- Without the rates, f makes the mean NEES per dof of the one-scan relative pose 1; fitted only where that mean
  ratio is off by more than the tolerance.
- With them, the shape (f : r : d : p) is the maximum likelihood of the one-scan errors, then all of them are
  scaled together so that the mean ratio is 1 (with V, which the level does not scale, not quite the likelihood's
  own level).
- Both leave out the scans at which the estimator failed outright (`gross_failures`): a mean is what the
  campaigns' N-run averages measure, and without them it is not pulled by a few scans. Until session 56 the level
  was the median ratio's, which left the one scan cautious on the campaigns' drives (mean NEES per dof 0.90-0.99
  in every cell; docs/consistency.md, "The level of the one-scan factor").

Every fit works on the decomposition (e, A, V) of the run it is given, so no run is needed; restarted scans (a
dead-reckoned step, not scaled) are left out.

Checked by: tests/validation/test_calibrate_consistency.py::test_relative_factor_makes_the_one_scan_pose_consistent,
    ::test_relative_factor_out_of_reach_is_left_as_it_was,
    tests/validation/test_calibrate_relative.py
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize
from scipy.stats import chi2

from rodo.estimator.pull import pull_term, relative_factor
from rodo.estimator.velocity_inflation import doppler_term

from .gross_failures import fit_without_gross_failures, gross_failures
from .odometry_consistency import DOF, span_terms
from .replayed_states import relative_inflated_states
from .run_consistency import DEFAULT_TAU, runs_of

MEDIAN_CHI2 = float(chi2.median(DOF))
# the velocity error's share g of the maximum likelihood: at most the window's whole velocity covariance (the level,
# set after it by the mean ratio, scales it with the factor)
SHARE_RANGE = (1e-3, 1.0)
# the share's growth with the speed is learned only from a drive that stops: at least REST_FRACTION of its scans
# below REST_SPEED (m/s); a drive always at speed cannot tell g + g_v |nu| from a constant share (hills: 12-30 m/s)
REST_SPEED, REST_FRACTION = 0.5, 0.01
OVERCONFIDENCE_WEIGHT = 2.0  # how much more an over-confident ln ratio (> 0) counts than a cautious one in tau_cost


def median_ratio(values) -> float:
    """median(NEES) / median of chi2(6): 1 when consistent, > 1 over-confident, NaN without finite values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.median(v) / MEDIAN_CHI2) if v.size else float("nan")


def mean_ratio(values) -> float:
    """mean(NEES) / DOF: 1 when consistent on average (what the campaigns' N-run means measure), > 1
    over-confident, NaN without finite values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.mean(v) / DOF) if v.size else float("nan")


def tau_cost(ratios) -> float:
    """sum_i w_i |ln r_i| of NEES ratios r_i (median ratios, or E[e^2 / sigma^2] per axis), w_i =
    OVERCONFIDENCE_WEIGHT where r_i > 1 (the covariance too small), else 1: the cost the calibration's grid fits
    minimise (`calibrate_consistency`'s tau, heading and correlation, `calibrate_stationary`)."""
    log_r = np.log(np.asarray(ratios, dtype=float))
    return float(np.sum(np.where(log_r > 0, OVERCONFIDENCE_WEIGHT, 1.0) * np.abs(log_r)))


def _run_factor(states: dict, factor) -> np.ndarray:
    """Each scan's factor (f, r, d[, p]) (`relative_factor`) in a run's states."""
    p = float(factor[3]) if len(factor) > 3 else 0.0
    return relative_factor(np.asarray(states["varpi"], dtype=float), factor[0], factor[1], factor[2],
                           states.get("doppler_nis"), p, states.get("pose_pull"))


def relative_terms(states, truth, inflation: float, per_rate=None, drift_rate_sigma=None, per_doppler: float = 0.0,
                   per_pull: float = 0.0):
    """(e (K, 6), A (K, 6, 6), V (K, 6, 6), W (K, 5)) of the one-scan relative poses of a run (or runs, pooled)
    that had the factor f = `inflation`, r = `per_rate`, d = `per_doppler`, p = `per_pull`: errors, the factor's
    part per unit factor, the unscaled rest and the factor's regressors, the scan's absolute estimated body rates,
    ln(1 + its Doppler NIS) (0 without one) and its pull (`pull_term`; 0 in states written before it, so p is not
    learned from them); only scans with finite values, not restarted."""
    e, A, V_velocity, V_rest, W = relative_terms_split(states, truth, inflation, per_rate, drift_rate_sigma,
                                                        per_doppler, per_pull)
    return e, A, V_velocity + V_rest, W


def relative_terms_split(states, truth, inflation: float, per_rate=None, drift_rate_sigma=None,
                         per_doppler: float = 0.0, per_pull: float = 0.0, with_speed: bool = False):
    """(e, A, V_velocity, V_rest, W): `relative_terms` with its unscaled rest V split into the velocity error's
    share (at the runs' own `velocity_error_share` g and `velocity_error_share_per_speed`; the composed covariance
    is linear in g) and the rest (the drift rate's, the registration's correlated share at the runs'
    `registration_correlation` and, with the heading's reversion on, the anchor's deviation); `with_speed`: and the
    scans' speeds |nu| (K,) last."""
    out = [[], [], [], [], [], []]
    for st, tr in runs_of(states, truth):
        tau = float(st.get("velocity_correlation_time", DEFAULT_TAU))
        terms = span_terms(st, tr, span=0.0, tau=tau, drift_rate_sigma=drift_rate_sigma)
        if terms is None:
            continue
        e, C, t, _ = terms
        C_rest = span_terms(dict(st, velocity_error_share=0.0, velocity_error_share_per_speed=0.0), tr, span=0.0,
                            tau=tau, drift_rate_sigma=drift_rate_sigma)[1]
        idx = np.searchsorted(np.asarray(st["t"], dtype=float), t[1:])  # the matched scans, in the run's rows
        # over one scan the window's relative covariance and the revision enter the composition as they are
        # (`span_covariances`: added once, untransformed), so the rest of it is what the factor does not scale
        scaled = np.asarray(st["P_relative"], dtype=float)[idx]
        if "P_revision" in st:
            scaled = scaled + np.asarray(st["P_revision"], dtype=float)[idx]
        varpi = np.asarray(st["varpi"], dtype=float)[idx]
        nis = np.asarray(st["doppler_nis"], dtype=float)[idx] if "doppler_nis" in st else np.full(len(idx), np.nan)
        pull = np.asarray(st["pose_pull"], dtype=float)[idx] if "pose_pull" in st else None
        c = relative_factor(varpi, inflation, per_rate, per_doppler, nis, per_pull, pull)
        c = np.broadcast_to(c, (len(idx),))
        keep = ~np.asarray(st.get("restarted", np.zeros(len(st["t"]), bool)), dtype=bool)[idx]
        keep &= np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(C) & np.isfinite(scaled), axis=(1, 2)) & (c > 0)
        W = np.column_stack([np.abs(varpi[:, 3:6]), doppler_term(nis),
                             np.zeros(len(idx)) if pull is None else pull_term(pull)])
        speed = np.linalg.norm(varpi[:, :3], axis=1)
        for acc, v in zip(out, (e, scaled / c[:, None, None], C - C_rest, C_rest - scaled, W, speed)):
            acc.append(v[keep])
    if not out[0]:
        out = [[np.zeros((0,) + shape)] for shape in ((6,), (6, 6), (6, 6), (6, 6), (5,), ())]
    return tuple(np.concatenate(v) for v in out[:6 if with_speed else 5])


def _nees(c, e, A, V) -> np.ndarray:
    """(K,) e_k^T (c_k A_k + V_k)^-1 e_k."""
    C = c[:, None, None] * A + V
    return np.einsum("ki,ki->k", e, np.linalg.solve(C, e[..., None])[..., 0])


def _max_likelihood(e, A, V, W, f0: float, V_velocity=None, h_range=SHARE_RANGE, Y=None) -> np.ndarray:
    """(f, then one coefficient per column of W: r_x, r_y, r_z, d and p) maximising the Gaussian likelihood of the
    errors e_k ~ N(0, c_k A_k + V_k), c_k = f + r . W_k, f > 0, r >= 0 (L-BFGS-B with the analytic gradient, each
    term scaled to its mean regressor); with `V_velocity`, e_k ~ N(0, c_k A_k + h_k V_velocity,k + V_k), h_k = h .
    Y_k (Y (K, m), None: ones, h the one share), h_0 within `h_range` and the others >= 0, last."""
    X = np.column_stack([np.ones(len(e)), W])
    share = V_velocity is not None
    Y = np.ones((len(e), 1)) if Y is None else np.asarray(Y, dtype=float)
    scale = np.where(X.mean(axis=0) > 0, X.mean(axis=0), 1.0)
    y_scale = np.r_[1.0, np.where(Y[:, 1:].mean(axis=0) > 0, Y[:, 1:].mean(axis=0), 1.0)]
    Xs, Ys = X / scale, Y / y_scale

    def nll(p):
        c = Xs @ p[:X.shape[1]]
        C = c[:, None, None] * A + V + ((Ys @ p[X.shape[1]:])[:, None, None] * V_velocity if share else 0.0)
        Ci_e = np.linalg.solve(C, e[..., None])[..., 0]
        value = np.sum(np.linalg.slogdet(C)[1] + np.einsum("ki,ki->k", e, Ci_e))

        def gradient(B):  # d nll / d (a factor on B), per scan
            return np.trace(np.linalg.solve(C, B), axis1=1, axis2=2) - np.einsum("ki,kij,kj->k", Ci_e, B, Ci_e)
        g = gradient(A) @ Xs
        return float(value), (np.r_[g, gradient(V_velocity) @ Ys] if share else g)

    bounds = [(1e-6 * f0, None)] + [(0.0, None)] * W.shape[1]
    start = np.r_[f0, np.zeros(W.shape[1])]
    if share:
        bounds += [tuple(h_range)] + [(0.0, None)] * (Y.shape[1] - 1)
        start = np.r_[start, 1.0, np.zeros(Y.shape[1] - 1)]
    p = minimize(nll, start, jac=True, method="L-BFGS-B", bounds=bounds).x
    return np.r_[p[:X.shape[1]] / scale, p[X.shape[1]:] / (y_scale if share else 1.0)]


def _mean_scale(e, A, V) -> float | None:
    """s at which the mean ratio of the NEES at c A + V, c = s for every scan, is 1 (it falls as s grows), or None
    when no s within 2^30 of 1 reaches it (the unscaled shares V alone too cautious, or no finite ratio)."""
    def log_ratio(s):
        return np.log(mean_ratio(_nees(np.full(len(e), s), e, A, V)))

    r = log_ratio(1.0)
    if not np.isfinite(r):
        return None
    if r == 0.0:
        return 1.0
    step = 2.0 if r > 0.0 else 0.5
    near, far = 1.0, step
    for _ in range(30):
        r_far = log_ratio(far)
        if not np.isfinite(r_far):
            return None
        if (r_far > 0.0) != (r > 0.0):
            lo, hi = sorted((near, far))
            return float(np.exp(brentq(lambda u: log_ratio(np.exp(u)), np.log(lo), np.log(hi), xtol=1e-4)))
        near, far = far, far * step
    return None


def fit_relative_inflation(states: dict | list, truth: dict | list, inflation: float, ratio_tolerance: float,
                           drift_rate_sigma=None, per_rate=None, rates: bool = False, per_doppler: float = 0.0,
                           per_pull: float = 0.0, share: bool = False) -> dict:
    """The one-scan relative pose covariance's factor for a run (or runs, pooled) that had f = `inflation`, r =
    `per_rate` (None: 0), d = `per_doppler` and p = `per_pull`: with `rates`, the shape (f : r : d : p) by maximum
    likelihood and the level by the mean ratio (module docstring); without, f (with the run's r, d and p) scaled
    to the mean ratio 1, or kept when that ratio is within ratio_tolerance of 1 already (|ln r| < ln(1 +
    ratio_tolerance), as the kappa fixed point stops), as it is when the fitted r, d and p all come out 0. Kept
    too when no factor within 2^30 reaches a ratio of 1. The one-scan measure is the same at every tau > 0 (at
    tau 0 it loses the velocity term, so a tau of 0 chosen after f leaves it over-confident: hills CA/P with
    prior_memory 0.5 s, 1.28 where f made it 1).

    With `share` (and `rates`) the velocity error's share g (`[uncertainty] velocity_error_share`) is learned with
    the shape, and the level scales it with the factor; so is its growth with the speed g_v where the drive stops
    (REST_FRACTION of its scans below REST_SPEED; "rest_fraction" in the result), else 0.

    Returns {"inflation": f, "per_rate": [r_x, r_y, r_z], "per_doppler": d, "per_pull": p, "velocity_error_share":
    g (the runs' own unless learned), "mean_ratio": [before, after] (`mean_ratio`), "outcome": "fitted", "within
    tolerance" or "out of reach", "gross_failures": how many scans the ratio, the shape's fit and the level left out
    (`gross_failures`: NEES above 100 per dof at the median scan's level, an outright failure of the estimator);
    the ratio before is at the run's factor without its gross failures, after at the fit's without the fit's}.
    """
    e, A, V_velocity, V_rest, W, speed = relative_terms_split(states, truth, inflation, per_rate, drift_rate_sigma,
                                                               per_doppler, per_pull, with_speed=True)
    first = states if isinstance(states, dict) else states[0]
    g = float(first.get("velocity_error_share", 1.0))
    g_v = float(first.get("velocity_error_share_per_speed", 0.0))
    if not share:
        return dict(fit_factor(e, A, V_velocity + V_rest, W, inflation, per_rate, ratio_tolerance, rates,
                               per_doppler, per_pull), velocity_error_share=g, velocity_error_share_per_speed=g_v)
    if g_v != 0.0:  # per unit share (exact for one scan where the share varies slowly over tau)
        V_velocity, g = V_velocity / (g + g_v * speed)[:, None, None], 1.0
    rest = float(np.mean(speed < REST_SPEED)) if len(speed) else 0.0
    fit = fit_factor(e, A, V_rest, W, inflation, per_rate, ratio_tolerance, rates, per_doppler, per_pull,
                     V_velocity=V_velocity, share=g, speed=speed if rest >= REST_FRACTION else None)
    return dict(fit, rest_fraction=rest)


def fit_factor(e, A, V, W, inflation: float, per_rate=None, ratio_tolerance: float = 0.0, rates: bool = False,
               per_doppler: float = 0.0, per_pull: float = 0.0, V_velocity=None, share: float = 1.0,
               speed=None) -> dict:
    """`fit_relative_inflation` on the one-scan terms (`relative_terms`: W (K, 5); (K, 4) without the pull, (K, 3)
    without the Doppler term either) of runs that had f = `inflation`, r = `per_rate`, d = `per_doppler` and p =
    `per_pull`; with `V_velocity` (`relative_terms_split`, of runs at the velocity error's share `share`; V then
    the rest), that share too, its shape within SHARE_RANGE ("velocity_error_share" in the result), and with the
    scans' `speed` (K,) its growth with the speed, g + g_v |nu| ("velocity_error_share_per_speed"; 0 without).

    Checked by: tests/validation/test_calibrate_relative.py::test_the_fit_recovers_a_known_rate_factor,
        ::test_the_fit_recovers_a_known_velocity_error_share, ::test_the_fit_recovers_a_share_growing_with_the_speed,
        ::test_a_gross_failure_is_left_out_of_the_one_scan_fit
    """
    rates0 = np.zeros(3) if per_rate is None else np.asarray(per_rate, dtype=float)
    r0 = np.r_[rates0, per_doppler, per_pull][:W.shape[1]]
    c0 = inflation + W @ r0
    V_all = V if V_velocity is None else V + V_velocity
    nees0 = _nees(c0, e, A, V_all)
    failed = gross_failures(nees0, DOF)  # left out of the ratio, the shape's fit and the level
    before = mean_ratio(nees0[~failed]) if len(e) else float("nan")
    Y = None if speed is None or V_velocity is None else np.column_stack([np.ones(len(e)), speed])

    def result(f, r, outcome, after, h=(1.0, 0.0), failures: int = 0):
        r = np.r_[r, np.zeros(5 - len(r))]
        out = {"inflation": float(f), "per_rate": [float(x) for x in r[:3]], "per_doppler": float(r[3]),
               "per_pull": float(r[4]), "mean_ratio": [before, after], "outcome": outcome,
               "gross_failures": failures}
        if V_velocity is None:
            return out
        return dict(out, velocity_error_share=float(h[0] * share), velocity_error_share_per_speed=float(h[1] * share))

    if not np.isfinite(before):
        return result(inflation, r0, "out of reach", before)
    n_h = 0 if V_velocity is None else (1 if Y is None else 2)
    if rates:
        p, failed, _ = fit_without_gross_failures(
            lambda keep: _max_likelihood(e[keep], A[keep], V[keep], W[keep], inflation,
                                         None if V_velocity is None else V_velocity[keep],
                                         np.divide(SHARE_RANGE, share), None if Y is None else Y[keep]),
            lambda p: _nees(np.ones(len(e)), e, _scaled(p, n_h, A, W, V_velocity, speed), V), len(e), DOF)
    else:
        p = np.r_[inflation, r0, [1.0, 0.0][:n_h]]
    k = len(p) - n_h
    h = np.r_[p[k:], (1.0, 0.0)[n_h:]]  # the share's (g, g_v) as fitted, (1, 0) where not
    if (not rates or not np.any(p[1:k] > 0.0)) and tuple(h) == (1.0, 0.0) \
            and abs(np.log(before)) < np.log1p(ratio_tolerance):
        return result(inflation, r0, "within tolerance", before, failures=int(failed.sum()))  # the fit not used
    kept = ~failed
    scaled = _scaled(p, n_h, A, W, V_velocity, speed)[kept]  # what the level scales
    s = _mean_scale(e[kept], scaled, V[kept])
    if s is None:
        return result(inflation, r0, "out of reach", before)
    after = mean_ratio(_nees(np.full(len(scaled), s), e[kept], scaled, V[kept]))
    return result(s * p[0], s * p[1:k], "fitted", after, s * h, int(failed.sum()))


def _scaled(p, n_h: int, A, W, V_velocity=None, speed=None) -> np.ndarray:
    """(K, 6, 6) the part of the one-scan covariance the level scales, at the fitted (f, r, d, p[, g[, g_v]]) `p`
    (`n_h` of the share's terms last): c_k A_k, plus (g + g_v |nu_k|) V_velocity,k with the share."""
    k = len(p) - n_h
    scaled = (p[0] + W @ p[1:k])[:, None, None] * A
    if V_velocity is None:
        return scaled
    h = np.r_[p[k:], (1.0, 0.0)[n_h:]]
    h_k = h[0] + (0.0 if speed is None else h[1] * np.asarray(speed, dtype=float))
    return scaled + np.broadcast_to(h_k, (len(A),))[:, None, None] * V_velocity


def relative_factor_states(states: dict, old, new) -> dict:
    """The states a run that had the factor old = (f, r, d[, p]) would have written at new = (f, r, d[, p])
    (`replayed_states.relative_inflated_states` with each scan's ratio of the two factors)."""
    return relative_inflated_states(states, _run_factor(states, new) / _run_factor(states, old))
