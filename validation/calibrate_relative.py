"""The one-scan relative pose covariance's factor learned from a drive with ground truth (`rodo calibrate`, its
uncertainty section): c = f + r . |omega| (`[uncertainty] inflation` f and `inflation_per_rate` r, s/rad on the
scan's absolute estimated body rates) on the window's relative pose covariance and its revision term
(`estimator.uncertainty.ReportedCovariances`). The one-scan relative pose's composed covariance is then
c A + V, A the part the factor scales, V the velocity error's and the drift rate's shares, which it does not.

- Without the rates, f makes the median ratio of the one-scan relative pose 1 (robust to the few scans where an
  association fails outright); fitted only where that ratio is off by more than the tolerance.
- With them, the shape (f : r) is the maximum likelihood of the one-scan errors, then f and r are scaled
  together so that the median ratio is 1: the mean fit alone follows the heavy tails, and its level did not
  carry over to the campaigns' drives (docs/consistency.md, "The one-scan relative pose with the rates").

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

from rodo.estimator.velocity_inflation import velocity_factor

from .odometry_consistency import DOF, span_terms
from .replayed_states import relative_inflated_states
from .run_consistency import DEFAULT_TAU, runs_of

MEDIAN_CHI2 = float(chi2.median(DOF))


def median_ratio(values) -> float:
    """median(NEES) / median of chi2(6): 1 when consistent, > 1 over-confident, NaN without finite values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.median(v) / MEDIAN_CHI2) if v.size else float("nan")


def relative_factor(varpi, inflation: float, per_rate=None):
    """The factor f + r . |omega| of each scan's relative pose covariance (`estimator.velocity_factor`'s form)."""
    return velocity_factor(varpi, inflation, 0.0, 0.0, None, per_rate)


def relative_terms(states, truth, inflation: float, per_rate=None, drift_rate_sigma=None):
    """(e (K, 6), A (K, 6, 6), V (K, 6, 6), W (K, 3)) of the one-scan relative poses of a run (or runs, pooled)
    that had the factor f = `inflation`, r = `per_rate`: errors, the factor's part per unit factor, the unscaled
    rest and the scan's absolute estimated body rates; only scans with finite values, not restarted."""
    out = [[], [], [], []]
    for st, tr in runs_of(states, truth):
        tau = float(st.get("velocity_correlation_time", DEFAULT_TAU))
        terms = span_terms(st, tr, span=0.0, tau=tau, drift_rate_sigma=drift_rate_sigma)
        if terms is None:
            continue
        e, C, t, _ = terms
        rest = {k: v for k, v in st.items() if k != "P_revision"}
        rest["P_relative"] = np.zeros_like(np.asarray(st["P_relative"], dtype=float))
        V = span_terms(rest, tr, span=0.0, tau=tau, drift_rate_sigma=drift_rate_sigma)[1]
        idx = np.searchsorted(np.asarray(st["t"], dtype=float), t[1:])  # the matched scans, in the run's rows
        varpi = np.asarray(st["varpi"], dtype=float)[idx]
        c = np.broadcast_to(relative_factor(varpi, inflation, per_rate), (len(idx),))
        keep = ~np.asarray(st.get("restarted", np.zeros(len(st["t"]), bool)), dtype=bool)[idx]
        keep &= np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(C), axis=(1, 2)) & (c > 0)
        for acc, v in zip(out, (e, (C - V) / c[:, None, None], V, np.abs(varpi[:, 3:6]))):
            acc.append(v[keep])
    if not out[0]:
        return np.zeros((0, 6)), np.zeros((0, 6, 6)), np.zeros((0, 6, 6)), np.zeros((0, 3))
    return tuple(np.concatenate(v) for v in out)


def _nees(c, e, A, V) -> np.ndarray:
    C = c[:, None, None] * A + V
    return np.einsum("ki,ki->k", e, np.linalg.solve(C, e[..., None])[..., 0])


def _max_likelihood(e, A, V, W, f0: float) -> np.ndarray:
    """(f, r_x, r_y, r_z) maximising the Gaussian likelihood of the errors e_k ~ N(0, c_k A_k + V_k), c_k = f +
    r . W_k, f > 0, r >= 0 (L-BFGS-B with the analytic gradient, each term scaled to its mean regressor)."""
    X = np.column_stack([np.ones(len(e)), W])
    scale = np.where(X.mean(axis=0) > 0, X.mean(axis=0), 1.0)
    Xs = X / scale

    def nll(p):
        c = Xs @ p
        C = c[:, None, None] * A + V
        Ci_e = np.linalg.solve(C, e[..., None])[..., 0]
        Ci_A = np.linalg.solve(C, A)
        value = np.sum(np.linalg.slogdet(C)[1] + np.einsum("ki,ki->k", e, Ci_e))
        g = np.trace(Ci_A, axis1=1, axis2=2) - np.einsum("ki,kij,kj->k", Ci_e, A, Ci_e)
        return float(value), g @ Xs

    bounds = [(1e-6 * f0, None)] + [(0.0, None)] * W.shape[1]
    p = minimize(nll, np.r_[f0, np.zeros(W.shape[1])], jac=True, method="L-BFGS-B", bounds=bounds).x
    return p / scale


def _median_scale(c, e, A, V) -> float | None:
    """s at which the median ratio of the NEES at factors s c is 1, or None when no s within 2^30 of 1 reaches
    it (the unscaled shares alone too cautious, or no finite ratio)."""
    def log_ratio(s):
        return np.log(median_ratio(_nees(s * c, e, A, V)))

    r = log_ratio(1.0)
    if not np.isfinite(r):
        return None
    if r == 0.0:
        return 1.0
    step = 2.0 if r > 0.0 else 0.5  # the ratio falls as the factor grows
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
                           drift_rate_sigma=None, per_rate=None, rates: bool = False) -> dict:
    """The one-scan relative pose covariance's factor for a run (or runs, pooled) that had f = `inflation` and r =
    `per_rate` (None: 0): with `rates`, the shape by maximum likelihood and the level by the median ratio
    (module docstring); without, f alone at the median ratio 1, or kept when that ratio is within
    ratio_tolerance of 1 already (|ln r| < ln(1 + ratio_tolerance), as the kappa fixed point stops), as it is
    when fitted rates all come out 0. Kept too when no factor within 2^30 reaches a ratio of 1. The one-scan
    measure is the same at every tau > 0 (at tau 0 it loses the velocity term, so a tau of 0 chosen after f
    leaves it over-confident: hills CA/P with prior_memory 0.5 s, 1.28 where f made it 1).

    Returns {"inflation": f, "per_rate": [r_x, r_y, r_z], "median_ratio": [before, after], "outcome": "fitted",
    "within tolerance" or "out of reach"}.
    """
    e, A, V, W = relative_terms(states, truth, inflation, per_rate, drift_rate_sigma)
    return fit_factor(e, A, V, W, inflation, per_rate, ratio_tolerance, rates)


def fit_factor(e, A, V, W, inflation: float, per_rate=None, ratio_tolerance: float = 0.0,
               rates: bool = False) -> dict:
    """`fit_relative_inflation` on the one-scan terms (`relative_terms`) of runs that had f = `inflation` and r =
    `per_rate`.

    Checked by: tests/validation/test_calibrate_relative.py::test_the_fit_recovers_a_known_rate_factor
    """
    r0 = np.zeros(3) if per_rate is None else np.asarray(per_rate, dtype=float)
    c0 = inflation + W @ r0
    before = median_ratio(_nees(c0, e, A, V)) if len(e) else float("nan")

    def kept(outcome):
        return {"inflation": float(inflation), "per_rate": [float(x) for x in r0], "median_ratio": [before, before],
                "outcome": outcome}

    if not np.isfinite(before):
        return kept("out of reach")
    p = _max_likelihood(e, A, V, W, inflation) if rates else np.r_[inflation, r0]
    if (not rates or not np.any(p[1:] > 0.0)) and abs(np.log(before)) < np.log1p(ratio_tolerance):
        return kept("within tolerance")
    c = p[0] + W @ p[1:]
    s = _median_scale(c, e, A, V)
    if s is None:
        return kept("out of reach")
    return {"inflation": float(s * p[0]), "per_rate": [float(s * x) for x in p[1:]],
            "median_ratio": [before, median_ratio(_nees(s * c, e, A, V))], "outcome": "fitted"}


def relative_factor_states(states: dict, old, new) -> dict:
    """The states a run that had the factor old = (f, r) would have written at new = (f, r)
    (`replayed_states.relative_inflated_states` with each scan's ratio of the two factors)."""
    varpi = np.asarray(states["varpi"], dtype=float)
    return relative_inflated_states(states, relative_factor(varpi, *new) / relative_factor(varpi, *old))
