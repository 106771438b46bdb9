"""Filter consistency: NEES of the newest state against the truth and NIS of the associations, with chi-square
bounds (Bar-Shalom, Li, Kirubarajan 2001, ch. 5.4).

State error (docs/conventions.md, paper eq. 12), left perturbation, T = T_vehicle_world:
    e = x_true (-) x_est = [ln(T_true T_est^-1)^vee; varpi_true - varpi_est; varpi_dot_true - varpi_dot_est]
    NEES = e^T P^-1 e, d = 18 (CA) or 12 (CV: no varpi_dot).
The estimator's world frame is its own: it starts at T_vehicle_world(0) = I, so the truth is expressed relative
to its first pose, T_true,k <- T_true,k T_true,0^-1, before comparing.

For N independent runs the average NEES at one scan, times N, is chi-square with N d degrees of freedom when the
filter is consistent; the two-sided (1 - alpha) bounds of the average are chi2.ppf([alpha/2, 1 - alpha/2], N d) / N.

Checked by: tests/validation/test_consistency.py
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3

from .alignment import truth_in_estimator_frame
from .association import DEFAULT_TOLERANCE, associate

NIS_DOF = 4  # one polar detection: range, azimuth, elevation, radial velocity


def pose_error(T_true, T_est) -> np.ndarray:
    """Left-perturbation pose error xi = ln(T_true T_est^-1)^vee of state poses T = T_vehicle_world (paper eq.
    12, the error the pose covariance describes: T_true = exp(xi^) T_est), batched (..., 4, 4) -> (..., 6).

    Checked by: tests/validation/test_consistency.py::test_state_error_is_left_perturbation
    """
    return se3.log(np.asarray(T_true, dtype=float) @ se3.inverse(np.asarray(T_est, dtype=float)))


def state_error(T_true, varpi_true, T_est, varpi_est, varpi_dot_true=None, varpi_dot_est=None) -> np.ndarray:
    """e = x_true (-) x_est (paper eq. 12), batched: (..., 4, 4), (..., 6) -> (..., 12), or (..., 18) when both
    varpi_dot are given: [pose_error(T_true, T_est); varpi_true - varpi_est; varpi_dot_true - varpi_dot_est].

    Checked by: tests/validation/test_consistency.py::test_state_error_is_left_perturbation
    """
    parts = [pose_error(T_true, T_est), np.asarray(varpi_true, dtype=float) - np.asarray(varpi_est, dtype=float)]
    if varpi_dot_true is not None and varpi_dot_est is not None:
        parts.append(np.asarray(varpi_dot_true, dtype=float) - np.asarray(varpi_dot_est, dtype=float))
    return np.concatenate(parts, axis=-1)


def nees(e: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared e^T P^-1 e, batched: (..., d) and (..., d, d) -> (...,).

    Computed through the Cholesky factor of the symmetrised P, 0.5 (P + P^T) = L L^T, as |L^-1 e|^2. NaN (never
    an exception, never a number from a meaningless inverse) where e or P has a non-finite entry or P is not
    positive definite (e.g. the first scan, whose pose is fixed with zero covariance); the other entries are
    unaffected.

    Args:
        e: (..., d) errors (state_error, pose_error, a velocity difference, ...).
        P: (..., d, d) their covariances.

    Returns:
        (...,) NEES values.

    Raises:
        InputError: shapes that do not match.

    Checked by: tests/validation/test_consistency.py::test_nees_matches_direct_formula_and_flags_singular_p,
        tests/validation/test_consistency.py::test_nees_is_chi_square_for_sampled_errors
    """
    e = np.asarray(e, dtype=float)
    P = np.asarray(P, dtype=float)
    if P.shape[-2:] != (e.shape[-1], e.shape[-1]) or P.shape[:-2] != e.shape[:-1]:
        raise InputError(f"e, P: expected (..., d) and (..., d, d), got {e.shape} and {P.shape}")
    flat_e = e.reshape(-1, e.shape[-1])
    flat_P = P.reshape(-1, e.shape[-1], e.shape[-1])
    out = np.full(len(flat_e), np.nan)
    good = np.all(np.isfinite(flat_e), axis=1) & np.all(np.isfinite(flat_P), axis=(1, 2))
    if good.any():
        Ps = 0.5 * (flat_P[good] + np.swapaxes(flat_P[good], 1, 2))
        try:
            L = np.linalg.cholesky(Ps)
            z = np.linalg.solve(L, flat_e[good][..., None])[..., 0]
            out[good] = np.sum(z * z, axis=1)
        except np.linalg.LinAlgError:  # some P is not positive definite: do them one by one
            idx = np.flatnonzero(good)
            for k, Pk in zip(idx, Ps):
                try:
                    z = np.linalg.solve(np.linalg.cholesky(Pk), flat_e[k])
                    out[k] = z @ z
                except np.linalg.LinAlgError:
                    pass
    return out.reshape(e.shape[:-1])


def chi2_bounds(n_runs, dim: int, alpha: float = 0.05) -> np.ndarray:
    """Two-sided (1 - alpha) chi-square bounds of the average of n_runs independent chi-square(dim) values.

    n_runs * mean ~ chi2(n_runs * dim) for a consistent estimator, so the bounds of the mean are

        chi2.ppf([alpha / 2, 1 - alpha / 2], n_runs * dim) / n_runs   (Bar-Shalom et al. 2001, sec. 5.4.2).

    The one convention of the package: `alpha` is the probability outside the bounds (0.05: the 2.5 % and
    97.5 % quantiles). n_runs is the number of runs averaged at one scan (Monte Carlo), or of terms of one mean
    (the associated pairs of a scan's NIS, the scans of a time average).

    Args:
        n_runs: a count >= 0, or an array of counts (one per scan); a count of 0 gives NaN bounds.
        dim: degrees of freedom of one term (18 or 12 for a state, 6 for a pose, 4 for a radar detection), >= 1.
        alpha: in (0, 1).

    Returns:
        (..., 2) [lower, upper], the shape of n_runs plus the last axis.

    Raises:
        InputError: dim not a positive integer, a negative count, alpha outside (0, 1).

    Checked by: tests/validation/test_consistency.py::test_chi2_bounds_cover_the_average_of_chi2_samples,
        tests/validation/test_consistency.py::test_chi2_bounds_match_chi_square_quantiles,
        tests/validation/test_consistency.py::test_chi2_bounds_vectorised_over_counts
    """
    if not (0 < alpha < 1):
        raise InputError(f"alpha: must be in (0, 1), got {alpha!r}")
    if isinstance(dim, bool) or int(dim) != dim or dim < 1:
        raise InputError(f"dim: must be a positive integer, got {dim!r}")
    n = np.asarray(n_runs, dtype=float)
    if np.any(n < 0) or not np.all(np.isfinite(n)):
        raise InputError(f"n_runs: counts must be finite and >= 0, got {n_runs!r}")
    with np.errstate(invalid="ignore", divide="ignore"):
        lo = np.where(n > 0, chi2.ppf(alpha / 2, n * dim) / n, np.nan)
        hi = np.where(n > 0, chi2.ppf(1 - alpha / 2, n * dim) / n, np.nan)
    return np.stack([lo, hi], axis=-1)


def fraction_within(values, bounds) -> float:
    """Fraction of the finite values that lie within their bounds, lower <= v <= upper.

    Values that are NaN (no estimate, a P that is not positive definite) or whose bounds are NaN (a count of 0)
    are left out, not counted as outside.

    Args:
        values: (N,) e.g. NEES per scan, average NEES per scan, NIS per scan.
        bounds: (2,) [lower, upper] for all values, or (N, 2) per value (`chi2_bounds`).

    Returns:
        The fraction in [0, 1], NaN when no value is left.

    Checked by: tests/validation/test_consistency.py::test_fraction_within_skips_missing_values
    """
    v = np.asarray(values, dtype=float).reshape(-1)
    b = np.broadcast_to(np.asarray(bounds, dtype=float), v.shape + (2,))
    ok = np.isfinite(v) & np.all(np.isfinite(b), axis=1)
    if not ok.any():
        return float("nan")
    return float(np.mean((v[ok] >= b[ok, 0]) & (v[ok] <= b[ok, 1])))


def require_arrays(states: dict, truth: dict) -> None:
    """InputError naming the first array a run's states (t, T_vehicle_world, varpi, P) or the truth (t,
    T_vehicle_world, varpi) lacks."""
    for key in ("t", "T_vehicle_world", "varpi", "P"):
        if key not in states:
            raise InputError(f"states: missing array {key!r}")
    for key in ("t", "T_vehicle_world", "varpi"):
        if key not in truth:
            raise InputError(f"truth: missing array {key!r}")


def nees_sequence(states: dict, truth: dict, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """Per-scan NEES of a run (states.npz arrays) against the simulator's truth (truth.npz arrays).

    Args:
        states: t (N,), T_vehicle_world (N, 4, 4), varpi (N, 6), varpi_dot (N, 6), P (N, d, d), d in {12, 18}.
        truth: t (M,), T_vehicle_world (M, 4, 4), varpi (M, 6), varpi_dot (M, 6).

    Returns:
        dict: t (K,), nees (K,) (NaN where P is singular or the estimate is not finite; the first scan, whose
        pose is fixed to the identity with zero covariance, usually is), dim, error (K, d).

    Checked by: tests/validation/test_consistency.py::test_nees_sequence_*
    """
    require_arrays(states, truth)
    P = np.asarray(states["P"], dtype=float)
    d = P.shape[-1]
    if d not in (12, 18) or P.shape != (len(states["t"]), d, d):
        raise InputError(f"states: P must be (N, 12, 12) or (N, 18, 18) for N scans, got {P.shape}")
    ia, ib = associate(states["t"], truth["t"], tolerance)
    T_true = truth_in_estimator_frame(np.asarray(truth["T_vehicle_world"], dtype=float))
    use_varpi_dot = d == 18
    if use_varpi_dot and ("varpi_dot" not in states or "varpi_dot" not in truth):
        raise InputError("states, truth: varpi_dot is needed for an 18-dimensional state")
    T_est = np.asarray(states["T_vehicle_world"], dtype=float)[ia]
    finite = np.all(np.isfinite(T_est), axis=(1, 2))
    T_est = np.where(finite[:, None, None], T_est, np.eye(4))  # keep log() away from NaN; masked below
    e = state_error(T_true[ib], np.asarray(truth["varpi"])[ib], T_est, np.asarray(states["varpi"])[ia],
                    np.asarray(truth["varpi_dot"])[ib] if use_varpi_dot else None,
                    np.asarray(states["varpi_dot"])[ia] if use_varpi_dot else None)
    e[~finite] = np.nan
    return {"t": np.asarray(states["t"], dtype=float)[ia], "nees": nees(e, P[ia]), "dim": d, "error": e}


def stacked_runs(runs: list[np.ndarray]) -> np.ndarray:
    """(N, K) the runs' per-scan values one row each, K the longest run, NaN past a run's end."""
    stack = np.full((len(runs), max((len(r) for r in runs), default=0)), np.nan)
    for k, r in enumerate(runs):
        stack[k, :len(r)] = r
    return stack


def average_nees(runs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Average per scan over runs of possibly different lengths (NaN entries skipped).

    Returns (mean (K,), count (K,)) with K the longest run; mean is NaN where count is 0.
    """
    stack = stacked_runs(runs)
    count = np.sum(np.isfinite(stack), axis=0)
    with np.errstate(invalid="ignore"):
        mean = np.where(count > 0, np.nansum(stack, axis=0) / np.maximum(count, 1), np.nan)
    return mean, count


def nis_summary(nis, n_associated, alpha: float = 0.05) -> dict:
    """NIS of the associations of one run: states.npz `nis` (mean d^2 per pair at each scan) and `n_associated`.

    Pooled over the run: mean NIS per pair = sum_k n_k nis_k / sum_k n_k, with bounds chi2_bounds(sum n_k, 4).
    Per scan: the fraction of scans whose mean lies within chi2_bounds(n_k, 4). Associations are gated (95 %
    chi-square by default), which truncates the distribution: a consistent filter then shows a mean NIS a little
    below 4 (the truncated mean: `gated_mean`), not a failure.

    Checked by: tests/validation/test_consistency.py::test_nis_summary_*
    """
    nis = np.asarray(nis, dtype=float)
    n = np.asarray(n_associated, dtype=float)
    if nis.shape != n.shape or nis.ndim != 1:
        raise InputError(f"nis, n_associated: expected equal 1-D arrays, got {nis.shape} and {n.shape}")
    ok = np.isfinite(nis) & (n > 0)
    total = float(n[ok].sum())
    if total == 0:
        return {"mean": float("nan"), "pairs": 0, "bounds": [float("nan")] * 2, "fraction_scans_within": float("nan"),
                "dof": NIS_DOF}
    mean = float(np.sum(nis[ok] * n[ok]) / total)
    per_scan = chi2_bounds(n[ok], NIS_DOF, alpha)
    return {"mean": mean, "pairs": int(total), "bounds": chi2_bounds(total, NIS_DOF, alpha).tolist(),
            "fraction_scans_within": fraction_within(nis[ok], per_scan), "dof": NIS_DOF,
            "gated_mean": gated_mean(NIS_DOF, 0.95)}


def gated_mean(dof: int, gate_probability: float) -> float:
    """Mean of a chi-square(dof) variable conditioned on being below its gate_probability quantile.

    E[x | x < g] = dof * F_{dof+2}(g) / F_dof(g), with F_dof(g) = gate_probability.
    """
    g = chi2.ppf(gate_probability, dof)
    return float(dof * chi2.cdf(g, dof + 2) / gate_probability)
