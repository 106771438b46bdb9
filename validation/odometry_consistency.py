"""Consistency measures that fit odometry (docs/consistency.md).

An odometry estimate drifts: its error against the world grows without bound, and the sliding window's own
pose covariance (relative to its local map) says nothing about that. So the measures are, per scan, each the
NEES e^T P^-1 e of a 6-dof error (left perturbations, T = T_vehicle_world):

    velocity        varpi_true - varpi                               P[6:12, 6:12]
    acceleration    varpi_dot_true - varpi_dot (CA only)             P[12:18, 12:18]
    relative_scan   ln(R_true R_est^-1), R = T_k T_{k-1}^-1            `uncertainty.span_covariance` over 1 scan
    relative_span   the same over `span` seconds, T_k T_{k-n}^-1      `uncertainty.span_covariance`
    (all spans of a run at once, bit for bit: `validation.span_covariances`)
    pose            ln(T_true T_est^-1) in the estimator's world      P_pose_absolute[k]
    pose_window     the same against the window's marginal P[:6, :6] (relative to the map: not a drift bound)

For N runs, the average of a measure at one scan lies within `consistency.chi2_bounds(N, 6)` when consistent.

Checked by: tests/validation/test_odometry_consistency.py::test_measures_are_chi_square_on_consistent_synthetic_runs,
    ::test_measures_detect_an_overconfident_run
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.attitude_jitter import span_excess, with_roll_pitch_variance
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.stationary_error import is_on, span_term
from rodo.estimator.uncertainty import recursion_inputs, registration_shares
from rodo.estimator.velocity_inflation import velocity_factor, velocity_inflation_terms
from rodo.estimator.velocity_lag import with_lag

from .alignment import truth_in_estimator_frame
from .association import DEFAULT_TOLERANCE, associate
from .consistency import nees, require_arrays
from .span_covariances import heading_deviations, span_covariances, step_matrices

# not per scan
RUN_CONSTANTS = ("drift_rate_sigma", "velocity_inflation", "velocity_axis_inflation", "heading_reversion",
                 "attitude_jitter", "velocity_error_share", "velocity_error_share_per_speed",
                 "registration_correlation", "registration_axis_correlation", "stationary_error")
MEASURES = ("velocity", "acceleration", "relative_scan", "relative_span", "pose", "pose_window")
DOF = 6


def _relative_errors(T_true: np.ndarray, T_est: np.ndarray, n: int) -> np.ndarray:
    """ln(R_true R_est^-1) of the relative poses over n scans ending at scans n .. N-1, (N - n, 6)."""
    R_true = T_true[n:] @ se3.inverse(T_true[:-n])
    R_est = T_est[n:] @ se3.inverse(T_est[:-n])
    return se3.log(R_true @ se3.inverse(R_est))


def drift_velocity_covariances(P: np.ndarray, varpi: np.ndarray, velocity_inflation=None,
                               doppler_nis=None, axis_inflation=None, lag=None) -> np.ndarray:
    """(N, 6, 6) the velocity covariances a run's drift recursion used: the window's, i.e. the reported ones
    (states.npz P) divided by the run's velocity factor (`estimator.velocity_inflation.velocity_factor`; states.npz
    velocity_inflation = [a, b], [a, b, d] with the per-scan doppler_nis, or [a, b, d, r_x, r_y, r_z] with the
    rate terms; none in runs before them) and by its
    per-axis factors (states.npz velocity_axis_inflation g: element (i, j) by sqrt(g_i g_j); none in runs
    before them), after the lag's b b^T is taken off (states.npz velocity_lag b (N, 6), `estimator.velocity_lag`;
    none in runs before it)."""
    P = np.asarray(P, dtype=float)
    P_varpi = (P if lag is None else with_lag(P, lag, -1.0))[:, 6:12, 6:12]
    if axis_inflation is not None and np.any(np.asarray(axis_inflation) != 1.0):
        h = np.sqrt(np.asarray(axis_inflation, dtype=float).reshape(6))
        P_varpi = P_varpi / (h[:, None] * h[None, :])
    if velocity_inflation is None:
        return P_varpi
    a, b, d, rates = velocity_inflation_terms(velocity_inflation)
    if d != 0.0 and doppler_nis is None:
        raise InputError(f"states: velocity_inflation has a Doppler term (d = {d:g}) but no doppler_nis array")
    c = velocity_factor(varpi, a, b, d, doppler_nis, rates)
    return P_varpi / c[:, None, None] if (a, b, d) != (1.0, 0.0, 0.0) or rates.any() else P_varpi


def recursion_inputs_of_run(states: dict, Sigma_rel: np.ndarray, P_window: np.ndarray, rows=None,
                            restarted=None, stationary=None) -> tuple[np.ndarray, np.ndarray]:
    """(Sigma_rel, P_varpi) (N, 6, 6) a run's drift recursion composed at its scans `rows` (None: all):
    `estimator.uncertainty.recursion_inputs` of their relative pose covariances Sigma_rel and window velocity
    covariances P_window at the run's `registration_correlation` alpha (per axis with its
    `registration_axis_correlation`, `registration_shares`), `velocity_error_share` g and
    `velocity_error_share_per_speed` g_v (states.npz; 0, 1 and 0 in runs before them) and the stationary error
    `stationary` ([V; T]; None: off; a run's own is its states' `stationary_error`), dt the interval since the
    scan before each in the run. The velocity covariances of every scan are g + g_v |nu| times the window's; alpha
    and the stationary error move covariance only at registered scans (not a run's first scan, not a re-initialisation's
    dead-reckoned step: `restarted` (N,), None: states' own)."""
    alpha = registration_shares(float(states.get("registration_correlation", 0.0)),
                                states.get("registration_axis_correlation"))
    g = float(states.get("velocity_error_share", 1.0))
    g_v = float(states.get("velocity_error_share_per_speed", 0.0))
    rows = np.arange(len(states["t"])) if rows is None else rows
    speed = np.linalg.norm(np.asarray(states["varpi"], dtype=float)[rows, :3], axis=1) if g_v != 0.0 else None
    share = g if speed is None else (g + g_v * speed)[:, None, None]
    if np.ndim(alpha) == 0 and alpha == 0.0 and not is_on(stationary):
        return Sigma_rel, (P_window if g == 1.0 and speed is None else share * np.asarray(P_window, dtype=float))
    dt = np.diff(np.asarray(states["t"], dtype=float), prepend=np.nan)[rows]
    if restarted is None:
        restarted = np.asarray(states.get("restarted", np.zeros(len(states["t"]), bool)), dtype=bool)[rows]
    ok = np.isfinite(dt) & ~np.asarray(restarted, dtype=bool) & np.all(np.isfinite(Sigma_rel), axis=(1, 2))
    S, P = np.array(Sigma_rel, dtype=float), share * np.asarray(P_window, dtype=float)
    S[ok], P[ok] = recursion_inputs(Sigma_rel[ok], P_window[ok], dt[ok], alpha, g, g_v,
                                    None if speed is None else speed[ok], stationary)
    return S, P


def matched_span_terms(m: dict, n: int, starts=None):
    """(e (K - n, 6), C (K - n, 6, 6), t (K,), n) of the relative poses over n scans of a matched run
    (`matched_run`, at its tau, drift rate, heading reversion and stationary error): their errors, covariances (the
    drift's composed over the span, the revision at its first scan and, over two scans and more, the stationary
    error's change with its lever arm, `stationary_error.span_term`; over one scan the run's unreduced inputs
    composed; no jitter), the scan times and n; None where there are none. With `starts` (increasing first scans,
    each below K - n) the rows of those spans alone."""
    t, T_est, states = m["t"], m["T_est"], m["sub"]
    if m["drift_inputs"] is None or n >= len(t):
        return None
    rows = slice(None) if starts is None else np.asarray(starts, dtype=int)
    if n == 1 and m["scan_inputs"] is None:
        raise ValueError("matched_span_terms: the run was matched without its one-scan inputs (one_scan=False)")
    Sigma_rel, P_varpi, restarts, deviations, steps = m["drift_inputs"] if n > 1 else m["scan_inputs"]
    C = span_covariances(T_est, t, Sigma_rel, P_varpi, n, m["tau"], m["drift_rate_sigma"], restarts, m["heading"],
                         deviations, starts, steps)
    if "P_revision" in states:  # the revision of each span's first emitted pose, by the scan after it
        C = C + _transported(T_est, np.asarray(states["P_revision"], dtype=float), n)[rows]
    if n > 1 and is_on(m["stationary"]):
        first = np.arange(len(t) - n)[rows]
        C = C + span_term(T_est[first + n], T_est[first], t[first + n] - t[first], m["stationary"])
    return _relative_errors(m["T_true"], T_est, n)[rows], C, t, n


def _span_nees(m: dict, n: int, jitter) -> np.ndarray:
    """Per-scan NEES of the relative pose over n scans of a matched run (`matched_run`), with the roll and pitch
    jitter [V, T] (None: off)."""
    out = np.full(len(m["t"]), np.nan)
    terms = matched_span_terms(m, n)
    if terms is not None:
        e, C, t, n = terms
        out[n:] = nees(e, with_roll_pitch_variance(C, span_excess(t, n, jitter)))
    return out


def _transported(T: np.ndarray, R: np.ndarray, n: int) -> np.ndarray:
    """(N - n, 6, 6) the revision covariance R[j] of the step into scan j = k - n + 1, carried to the frame of
    the span's relative pose ending at scan k: Ad(T_k T_j^-1) R[j] Ad(T_k T_j^-1)^T (R[j] itself for n = 1)."""
    j = np.arange(1, len(T) - n + 1)
    A = se3.adjoint(T[j + n - 1] @ se3.inverse(T[j]))
    return A @ R[j] @ np.swapaxes(A, -1, -2)


def odometry_nees(states: dict, truth: dict, span: float = 1.0, tau: float = 0.25,
                  tolerance: float = DEFAULT_TOLERANCE, drift_rate_sigma=None, heading=None, jitter=None) -> dict:
    """Per-scan NEES of every measure (module docstring) of one run against the simulator's truth.

    Args:
        states: states.npz arrays (t, T_vehicle_world, varpi, varpi_dot, P; P_relative and P_pose_absolute
            when the run wrote them, else those measures are NaN; P_revision when the run wrote it, added to
            every span at its first scan (`_transported`); velocity_inflation (and velocity_axis_inflation) when
            the run scaled its reported velocity covariance: the span measures divide it out, as the run's drift
            recursion did).
        truth: truth.npz arrays (t, T_vehicle_world, varpi, varpi_dot).
        span: seconds of the relative_span measure (rounded to whole scans).
        tau: the velocity error's correlation time the run used (config `uncertainty`).
        drift_rate_sigma: (6,) the drift rate sigma for the span measures; None: the run's own (states'
            `drift_rate_sigma`, none when absent).
        heading: [T_r, T_a] (s) of the heading's reversion for the span measures; None: the run's own (states'
            `heading_reversion`, off when absent).
        jitter: [V, T] (rad^2, s) of the roll and pitch jitter for the span measures (`estimator.attitude_jitter`);
            None: the run's own (states' `attitude_jitter`, off when absent). The absolute pose's is in its stored
            covariance.
        tolerance: seconds within which a state and a truth time match.

    Returns:
        dict: t (K,) the matched scan times, dof 6, span (s), and one (K,) array per measure (NaN where it is
        undefined: the first scans of a span, a singular covariance, acceleration of a CV run).
    """
    require_arrays(states, truth)
    if jitter is None:
        jitter = states.get("attitude_jitter")
    m = matched_run(states, truth, tolerance, tau, drift_rate_sigma, heading)
    t, P, sub, ib = m["t"], m["P"], m["sub"], m["ib"]
    xi = se3.log(m["T_true"] @ se3.inverse(m["T_est"]))
    out = {"t": t, "dof": DOF, "span": float(span)}
    out["velocity"] = nees(np.asarray(truth["varpi"])[ib] - sub["varpi"], P[:, 6:12, 6:12])
    out["acceleration"] = np.full(len(t), np.nan)
    if P.shape[-1] == 18 and "varpi_dot" in truth and "varpi_dot" in sub:
        out["acceleration"] = nees(np.asarray(truth["varpi_dot"])[ib] - sub["varpi_dot"], P[:, 12:18, 12:18])
    for name, n in (("relative_scan", 1), ("relative_span", span_scans(t, span))):
        out[name] = _span_nees(m, n, jitter)
    out["pose"] = nees(xi, sub["P_pose_absolute"]) if "P_pose_absolute" in sub else np.full(len(t), np.nan)
    out["pose_window"] = nees(xi, P[:, :6, :6])
    return out


def span_scans(t: np.ndarray, span: float) -> int:
    """The scans (>= 1) of a relative pose over `span` seconds: span over the median scan interval, rounded."""
    return max(1, int(round(span / np.median(np.diff(t))))) if len(t) > 1 else 1


def span_terms(states: dict, truth: dict, span: float = 1.0, tau: float = 0.25,
               tolerance: float = DEFAULT_TOLERANCE, drift_rate_sigma=None, heading=None):
    """(e (M, 6), C (M, 6, 6), t (M + n,), n) of one run's relative poses over `span` seconds (as `odometry_nees`'s
    relative_span, M of them, n scans each): errors, covariances without the roll and pitch jitter, the matched
    scan times and n; None without P_relative or with too few scans. For fitting the jitter
    (`validation.calibrate_jitter`)."""
    require_arrays(states, truth)
    m = matched_run(states, truth, tolerance, tau, drift_rate_sigma, heading)
    return matched_span_terms(m, span_scans(m["t"], span))


def matched_poses(states: dict, truth: dict, tolerance: float = DEFAULT_TOLERANCE):
    """(ia, ib, T_est, T_true): a run's scans matched to the truth (`association.associate`'s indices), the
    estimated state poses there and the true ones in the estimator's world, the first matched true pose on the
    first matched estimate (what every measure compares)."""
    ia, ib = associate(states["t"], truth["t"], tolerance)
    T_est = np.asarray(states["T_vehicle_world"], dtype=float)[ia]
    T_true = truth_in_estimator_frame(np.asarray(truth["T_vehicle_world"], dtype=float)[ib])
    return ia, ib, T_est, (T_true @ T_est[0] if len(ia) else T_true)


def matched_run(states: dict, truth: dict, tolerance: float, tau: float, drift_rate_sigma, heading,
                one_scan: bool = True) -> dict:
    """A run's scans matched to the truth (`odometry_nees`'s arguments): t, T_est, T_true (in the estimator's
    world), P, sub (the per-scan states arrays at the matched scans), ib (the truth's indices), the drift rate and
    heading reversion in use (the run's own where None), tau, the run's stationary error (states'
    `stationary_error`, None when absent), and drift_inputs, what the run's drift recursion composed, for every span
    measure ((Sigma_rel, P_varpi, restarts, deviations, and the steps' matrices of `span_covariances.step_matrices`
    into scans 1 .. K-1, built once for all the spans), `recursion_inputs_of_run`; None without P_relative), and
    scan_inputs, the same without the stationary error's one-scan change taken out (drift_inputs themselves when
    it is off), for the one-scan span (None with the error on and `one_scan` False: a caller of longer spans)."""
    if drift_rate_sigma is None and "drift_rate_sigma" in states:
        drift_rate_sigma = np.asarray(states["drift_rate_sigma"], dtype=float)
    if heading is None:
        heading = states.get("heading_reversion")
    per_scan = {k for k, v in states.items()
                if k not in RUN_CONSTANTS and np.ndim(v) >= 1 and len(v) == len(states["t"])}
    ia, ib, T_est, T_true = matched_poses(states, truth, tolerance)
    t = np.asarray(states["t"], dtype=float)[ia]
    sub = {k: np.asarray(states[k])[ia] for k in per_scan}
    if "restarted" in sub:  # a restart at a scan without truth: the kept scan after it takes the restart's step
        n_restarts = np.cumsum(np.asarray(states["restarted"], dtype=bool))[ia]
        sub["restarted"] = np.diff(n_restarts, prepend=0) > 0
    stationary = states.get("stationary_error")
    drift_inputs = scan_inputs = None
    if "P_relative" in sub:
        drift_inputs = _drift_inputs(states, sub, ia, T_est, t, tau, drift_rate_sigma, heading, stationary)
        scan_inputs = drift_inputs
        if is_on(stationary):
            scan_inputs = _drift_inputs(states, sub, ia, T_est, t, tau, drift_rate_sigma, heading, None) \
                if one_scan else None
    return {"t": t, "T_est": T_est, "T_true": T_true, "P": np.asarray(states["P"], dtype=float)[ia], "sub": sub,
            "ib": ib, "drift_rate_sigma": drift_rate_sigma, "heading": heading, "tau": tau,
            "stationary": stationary, "drift_inputs": drift_inputs, "scan_inputs": scan_inputs}


def _drift_inputs(states: dict, sub: dict, ia, T_est, t, tau: float, drift_rate_sigma, heading, stationary):
    """(Sigma_rel, P_varpi, restarts, deviations, steps) of `matched_run`'s drift_inputs at this stationary error
    ([V; T]; None: off, for the one-scan span)."""
    restarts = sub.get("restarted")
    P_window = drift_velocity_covariances(sub["P"], sub["varpi"], states.get("velocity_inflation"),
                                          sub.get("doppler_nis"), states.get("velocity_axis_inflation"),
                                          sub.get("velocity_lag"))
    Sigma_rel, P_varpi = recursion_inputs_of_run(states, np.asarray(sub["P_relative"], dtype=float), P_window,
                                                 ia, restarts, stationary)
    deviations = heading_deviations(T_est, t, Sigma_rel, P_varpi, tau, drift_rate_sigma, restarts, heading)
    steps = step_matrices(T_est, t, Sigma_rel, P_varpi, tau, np.arange(1, len(t)), restarts, heading)
    return Sigma_rel, P_varpi, restarts, deviations, steps


def summarise(measures: dict, alpha: float = 0.05) -> dict:
    """Per measure of one run: mean NEES/dof over the scans, the fraction of scans inside the per-scan
    (1 - alpha) bounds of chi2(6), and the number of finite scans."""
    from .consistency import chi2_bounds, fraction_within

    bounds = chi2_bounds(1, DOF, alpha)
    out = {}
    for name in MEASURES:
        v = np.asarray(measures[name], dtype=float)
        fin = v[np.isfinite(v)]
        out[name] = {"mean_per_dof": float(fin.mean() / DOF) if fin.size else None,
                     "within": fraction_within(v, bounds) if fin.size else None, "scans": int(fin.size)}
    out["bounds_per_dof"] = (bounds / DOF).tolist()
    return out
