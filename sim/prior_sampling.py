"""Monte Carlo of the constant-acceleration prior SDE on SE(3) (the paper's Fig. 1, eq. 13-14).

Samples x(t) = {T, varpi, varpi_dot} of dT/dt = varpi^ T, d varpi/dt = varpi_dot, d varpi_dot/dt = w(t),
w ~ GP(0, Qc delta), from x(0) = x0 (+) gamma0, gamma0 ~ N(0, P0) (left perturbation, eq. 4-5), by fine
sub-steps of length h with piecewise-constant jerk w_j ~ N(0, Qc / h). Within a sub-step varpi is quadratic
in time, varpi(s) = varpi_j + s varpi_dot_j + s^2/2 w_j, and the pose step is the Magnus expansion of that
polynomial up to the terms that matter at h ~ 5 ms:

    sigma_j = sigma_CA,4(varpi_j, varpi_dot_j, h) + h^3/6 w_j + h^4/24 ad(w_j) varpi_j,

(sigma_CA,4 = the order-4 constant-acceleration term, docs/priors.md), so the simulated process converges to
the SDE as h -> 0 independently of the prior's discretisation that it is used to check.

The stepping (`substep_sigma`, `ca_substeps`, `cv_substeps`, `compose_poses`) is shared with
`sim.sde_trajectory`, which draws whole vehicle trajectories from the same SDEs.

`propagate_mean_cov` gives the prior's Gaussian (mean f(x0), P = F P0 F^T + Q), `nees` the normalised
errors of samples against it, `covariance_test` a likelihood-ratio test of the sample covariance (Bartlett-corrected,
refused below `covariance_test_min_samples`).

Checked by: tests/sim/test_prior_sampling.py
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3


def _ad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """curlyhat(a) b for (..., 6) arrays: [phi_a x rho_b + rho_a x phi_b; phi_a x phi_b]."""
    return np.concatenate([np.cross(a[..., 3:], b[..., :3]) + np.cross(a[..., :3], b[..., 3:]),
                           np.cross(a[..., 3:], b[..., 3:])], axis=-1)


def substep_sigma(varpi, varpi_dot, jerk, h):
    """Pose increment sigma of one sub-step, T(s + h) = exp(sigma^) T(s), for varpi quadratic in time
    (the module docstring's formula). varpi, varpi_dot, jerk (..., 6); h > 0, scalar or broadcastable
    (e.g. (..., 1) for a partial step per row). A constant-velocity step is jerk = 0, varpi_dot = the step's
    acceleration."""
    s = h * varpi + h**2 / 2 * varpi_dot + h**3 / 6 * jerk
    c = _ad(varpi_dot, varpi)
    s += h**3 / 12 * c + h**5 / 240 * _ad(varpi_dot, c)
    s += h**5 / 720 * _ad(varpi, _ad(varpi, _ad(varpi, varpi_dot)))
    s += h**4 / 24 * _ad(jerk, varpi)
    return s


def ca_substeps(varpi0, vd0, jerk, h: float):
    """The CA SDE path over m sub-steps of piecewise-constant jerk (d varpi_dot = jerk dt on each).

    Args:
        varpi0, vd0: (..., 6) velocity and acceleration at the first knot.
        jerk: (m, ..., 6) jerk of each sub-step (for the SDE: w_j ~ N(0, Qc / h)).
        h: sub-step length, s.

    Returns:
        varpi (m + 1, ..., 6) and varpi_dot (m + 1, ..., 6) at the knots, and sigma (m, ..., 6) with
        T_{j+1} = exp(sigma_j^) T_j (`compose_poses`).
    """
    zero = np.zeros_like(jerk[:1])
    vd = vd0 + np.concatenate([zero, np.cumsum(h * jerk, axis=0)])
    varpi = varpi0 + np.concatenate([zero, np.cumsum(h * vd[:-1] + h**2 / 2 * jerk, axis=0)])
    return varpi, vd, substep_sigma(varpi[:-1], vd[:-1], jerk, h)


def cv_substeps(varpi0, acc, h: float):
    """The CV SDE path over m sub-steps of piecewise-constant acceleration (d varpi = acc dt on each).

    Args: varpi0 (..., 6); acc (m, ..., 6) (for the SDE: a_j ~ N(0, Qc / h)); h: sub-step length, s.

    Returns:
        varpi (m + 1, ..., 6) at the knots and sigma (m, ..., 6) (`compose_poses`).
    """
    zero = np.zeros_like(acc[:1])
    varpi = varpi0 + np.concatenate([zero, np.cumsum(h * acc, axis=0)])
    return varpi, substep_sigma(varpi[:-1], acc, zero, h)


def compose_poses(T0, sigma) -> np.ndarray:
    """Poses at the knots, T_0 = T0 and T_{j+1} = exp(sigma_j^) T_j: T0 (..., 4, 4), sigma (m, ..., 6)
    -> (m + 1, ..., 4, 4)."""
    steps = se3.exp(sigma)
    out = np.empty((len(sigma) + 1,) + np.shape(T0))
    out[0] = T0
    for j in range(len(sigma)):
        out[j + 1] = steps[j] @ out[j]
    return out


def _check_state(T0, varpi0, vd0, P0):
    T0 = check_finite("T0", T0, (4, 4))
    if T0.shape != (4, 4):
        raise InputError(f"T0: expected shape (4, 4), got {T0.shape}")
    varpi0 = check_finite("varpi0", varpi0, (6,))
    vd0 = check_finite("vd0", vd0, (6,))
    for name, v in (("varpi0", varpi0), ("vd0", vd0)):
        if v.shape != (6,):
            raise InputError(f"{name}: expected shape (6,), got {v.shape}")
    P0 = check_finite("P0", P0, (18, 18))
    if P0.shape != (18, 18):
        raise InputError(f"P0: expected shape (18, 18), got {P0.shape}")
    if np.abs(P0 - P0.T).max() > 1e-12 * max(np.abs(P0).max(), 1e-300):
        raise InputError("P0: not symmetric")
    eig, vec = np.linalg.eigh(P0)
    if eig[0] < -1e-12 * max(eig[-1], 1e-300):
        raise InputError("P0: not positive semi-definite")
    return T0, varpi0, vd0, vec * np.sqrt(np.clip(eig, 0.0, None))


def _check_dt(dt) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise InputError(f"dt: expected a positive number of seconds, got {dt!r}") from None
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"dt: must be finite and > 0 seconds, got {dt!r}")
    return dt


def sample_prior(prior, T0, varpi0, vd0, P0, dt, n_samples: int, rng: np.random.Generator, substeps: int = 200):
    """Draw n_samples states at time dt from the CA SDE started at x0 (+) N(0, P0).

    Args:
        prior: a `ConstantAccelerationPrior` (only its `Qc` (6, 6) is used).
        T0: (4, 4) mean pose T_vehicle_world; varpi0, vd0: (6,) mean velocity and acceleration.
        P0: (18, 18) symmetric positive semi-definite covariance of gamma0 = [xi; eta; zeta].
        dt: horizon in seconds (> 0); n_samples: >= 1; rng: numpy Generator (from a SeedSequence).
        substeps: sub-steps of piecewise-constant jerk (>= 1).

    Returns:
        (T (n, 4, 4), varpi (n, 6), varpi_dot (n, 6)).

    Checked by: tests/sim/test_prior_sampling.py::test_monte_carlo_nees_within_chi2_bounds
    """
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng: expected a numpy.random.Generator (seeded from a SeedSequence)")
    if int(n_samples) != n_samples or n_samples < 1:
        raise InputError(f"n_samples: expected a positive integer, got {n_samples!r}")
    if int(substeps) != substeps or substeps < 1:
        raise InputError(f"substeps: expected a positive integer, got {substeps!r}")
    T0, varpi0, vd0, root = _check_state(T0, varpi0, vd0, P0)
    dt = _check_dt(dt)
    n, m = int(n_samples), int(substeps)
    h = dt / m
    Qc = np.asarray(prior.Qc, dtype=float)
    jerk_root = np.linalg.cholesky(Qc / h)

    g0 = rng.standard_normal((n, 18)) @ root.T
    T = se3.exp(g0[:, :6]) @ T0
    varpi = varpi0 + g0[:, 6:12]
    varpi_dot = vd0 + g0[:, 12:]
    for _ in range(m):
        jerk = rng.standard_normal((1, n, 6)) @ jerk_root.T
        v, vd, sigma = ca_substeps(varpi, varpi_dot, jerk, h)
        T = compose_poses(T, sigma)[1]
        varpi, varpi_dot = v[1], vd[1]
    return T, varpi, varpi_dot


def propagate_mean_cov(prior, T0, varpi0, vd0, P0, dt):
    """The prior's Gaussian at dt: mean f(x0) (eq. 31-34) and P = F P0 F^T + Q (eq. 37-38).

    Returns:
        ((T (4, 4), varpi (6,), varpi_dot (6,)), P (18, 18)).
    """
    T0, varpi0, vd0, _ = _check_state(T0, varpi0, vd0, P0)
    dt = _check_dt(dt)
    P0 = np.asarray(P0, dtype=float)
    mean = prior.predict(T0, varpi0, vd0, dt)
    F, Q = prior.transition_and_noise(varpi0, vd0, dt)
    P = F @ P0 @ F.T + Q
    return mean, 0.5 * (P + P.T)


def errors(samples, mean) -> np.ndarray:
    """x_i (-) x_mean (eq. 12) for every sample, (n, 18)."""
    T, varpi, varpi_dot = samples
    T_mean, varpi_mean, varpi_dot_mean = mean
    xi = se3.log(np.asarray(T) @ se3.inverse(np.asarray(T_mean)))
    return np.concatenate([xi, np.asarray(varpi) - varpi_mean, np.asarray(varpi_dot) - varpi_dot_mean], axis=-1)


def nees(samples, mean, P) -> np.ndarray:
    """Normalised estimation error squared e_i^T P^-1 e_i, e_i = x_i (-) x_mean, (n,)."""
    P = check_finite("P", P, (18, 18))
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise InputError("P: not positive definite") from None
    z = np.linalg.solve(L, errors(samples, mean).T)
    return np.sum(z * z, axis=0)


def nees_bounds(n_samples: int, dof: int = 18, level: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square bounds of the mean NEES of n_samples independent samples."""
    lo, hi = stats.chi2.ppf([(1 - level) / 2, (1 + level) / 2], dof * n_samples) / n_samples
    return float(lo), float(hi)


def covariance_test(samples, mean, P) -> tuple[float, int, float]:
    """Likelihood-ratio test of H0: the errors e_i ~ N(0, P) against an unrestricted covariance (mean known):
    `whitened_covariance_test` of z_i = L^-1 e_i (P = L L^T). Returns (stat, dof, p_value).

    Raises:
        InputError: fewer samples than `covariance_test_min_samples(18)` (62).
    """
    L = np.linalg.cholesky(np.asarray(P, dtype=float))
    return whitened_covariance_test(np.linalg.solve(L, errors(samples, mean).T).T)


LRT_MIN_RHO = 0.9  # the smallest Bartlett factor accepted: below it the corrected test rejects too often


def _bartlett_c(d: int) -> float:
    """c of Bartlett's factor rho = 1 - c / n for H0: Sigma = I with n degrees of freedom (Muirhead 8.4)."""
    return (2 * d * d + 3 * d - 1) / (6 * (d + 1))


def bartlett_factor(n: int, d: int) -> float:
    """rho = 1 - (2 d^2 + 3 d - 1) / (6 n (d + 1)): `whitened_covariance_test`'s statistic is rho times the
    plain likelihood-ratio statistic."""
    return 1 - _bartlett_c(d) / n


def covariance_test_min_samples(d: int) -> int:
    """The fewest samples of dimension d that `whitened_covariance_test` accepts: more than d (a non-singular
    sample covariance) and a Bartlett factor rho >= 0.9, where the corrected test holds its level (a rejection
    share within ~10 % of alpha = 1e-3 for d = 1..30 by Monte Carlo): 22 for d = 6, 42 for 12, 62 for 18."""
    return max(d + 1, math.ceil(_bartlett_c(d) / (1 - LRT_MIN_RHO) - 1e-9))


def whitened_covariance_test(z) -> tuple[float, int, float]:
    """Likelihood-ratio test of H0: z_i ~ N(0, I) (mean known) for whitened errors z (n, d) against an
    unrestricted covariance, with Bartlett's small-sample correction (Muirhead, Aspects of Multivariate
    Statistical Theory, Thm. 8.4.9, n degrees of freedom as the mean is known):

        S = mean(z z^T), stat = rho n (tr S - ln det S - d), rho = 1 - (2 d^2 + 3 d - 1) / (6 n (d + 1)),
        p = P(chi2_f > stat) + w2 [P(chi2_{f+4} > stat) - P(chi2_f > stat)], f = d (d + 1) / 2,
        w2 = d (2 d^4 + 6 d^3 + d^2 - 12 d - 13) / (288 (d + 1) (rho n)^2).

    The uncorrected statistic against chi2_f rejects a true H0 far too often at small n (d = 18: 98 % of the
    time at alpha = 1e-3 for n = 19, 4.8 % for n = 50); corrected it holds its level from
    `covariance_test_min_samples(d)` on. Returns (stat (corrected), dof f, p_value).

    Raises:
        InputError: z not (n, d) finite, or n below `covariance_test_min_samples(d)`.

    Checked by: tests/sim/test_review2_prior_lrt.py::test_covariance_test_holds_its_level_on_normal_data
    """
    z = np.asarray(z, dtype=float)
    if z.ndim != 2 or z.shape[1] < 1 or not np.all(np.isfinite(z)):
        raise InputError(f"covariance test: expected finite whitened errors (n, d), got shape {z.shape}")
    n, d = z.shape
    if n < covariance_test_min_samples(d):
        raise InputError(f"covariance test: {n} samples of dimension {d} are too few; it needs at least "
                         f"{covariance_test_min_samples(d)} ({_too_few_reason(d)})")
    S = z.T @ z / n
    rho = bartlett_factor(n, d)
    stat = float(rho * n * (np.trace(S) - np.linalg.slogdet(S)[1] - d))
    dof = d * (d + 1) // 2
    w2 = d * (2 * d**4 + 6 * d**3 + d * d - 12 * d - 13) / (288 * (d + 1) * (rho * n) ** 2)
    p0 = stats.chi2.sf(stat, dof)
    return stat, dof, float(np.clip(p0 + w2 * (stats.chi2.sf(stat, dof + 4) - p0), 0.0, 1.0))


def _too_few_reason(d: int) -> str:
    return (f"with fewer, the likelihood-ratio statistic of the {d} x {d} sample covariance is not chi-square "
            "even after Bartlett's small-sample correction, and the test rejects a correct covariance far more "
            f"often than its level{'; with n <= d the sample covariance is singular' if d > 1 else ''}")


def yaw_acceleration_case() -> dict:
    """The Fig. 1 set-up: driving forward at 10 m/s (nu = [-10, 0, 0]) with pure yaw acceleration to the
    left at 0.5 rad/s^2 (omega_dot = [0, 0, -0.5] in the paper's sign convention), horizon 1 s.

    Returns:
        dict with Qc (6, 6), T0 (4, 4), varpi0 (6,), vd0 (6,), P0 (18, 18), dt: the arguments of
        `sample_prior` / `propagate_mean_cov` (build the prior from Qc).
    """
    Qc = np.diag([0.5, 0.1, 0.05, 0.005, 0.005, 0.05])
    std0 = np.r_[0.05, 0.05, 0.02, 0.002, 0.002, 0.01,  # pose: m, rad
                 0.1, 0.05, 0.02, 0.005, 0.005, 0.02,  # velocity: m/s, rad/s
                 0.1, 0.05, 0.02, 0.005, 0.005, 0.05]  # acceleration: m/s^2, rad/s^2
    return dict(Qc=Qc, T0=np.eye(4), varpi0=np.array([-10.0, 0, 0, 0, 0, 0]),
                vd0=np.array([0.0, 0, 0, 0, 0, -0.5]), P0=np.diag(std0**2), dt=1.0)
