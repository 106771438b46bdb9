"""Learning the motion prior's power spectral density Qc from data (`rodo calibrate`, docs/calibration.md).

Q_k is linear in Qc (Q_k = int Phi L Qc L^T Phi^T), so with a diagonal Qc = diag(q),
Q_k(q) = sum_i q_i B_k^(i), B_k^(i) = Q_k(e_i e_i^T) (`noise_basis`). Given the second moments S_k of the
prior residuals e_k = x_k (-) f(x_{k-1}) (eq. 12, 31-34), `fit_qc` maximises

    L(q) = -1/2 sum_k [log det Q_k(q) + tr(Q_k(q)^-1 S_k) + d log 2 pi]

over q >= floor (L-BFGS-B on log q, analytic gradient). With ground truth S_k = e_k e_k^T and L is the
likelihood of the true trajectory under the prior (`fit_qc_to_truth`). Without it, `em_qc` alternates, as
Wong et al. (RA-L 2020) do, an E-step (S_k = E[w_k w_k^T | scans] from the estimator's per-scan posteriors, smoothed)
and this M-step: to the fixed point in the drive's linear-Gaussian stand-in between estimator runs
(`validation.em_surrogate`), until a run no longer moves it.

Checked by: tests/validation/test_calibrate.py, tests/validation/test_em_surrogate.py
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from rodo.estimator.config_rules import RULES
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.motion import MotionPrior, motion_prior
COMPONENTS = ("x", "y", "z", "roll", "pitch", "yaw")  # the diagonal of Qc: linear, then angular, body axes
DEFAULT_FLOOR = 1e-9  # lower bound of every q_i (a component the data never excites goes there)
QC_MIN, QC_MAX = RULES["noise.qc_ca"].lo, RULES["noise.qc_ca"].hi  # the config's bounds: the lowest floor, the fit's top


@dataclass(frozen=True)
class StateTrack:
    """States at times t: T_vehicle_world (N, 4, 4), varpi (N, 6), varpi_dot (N, 6) (zeros for CV), and
    optionally posterior covariances P (N, d, d) (left perturbation, [pose; velocity; acceleration]) and a mask
    `valid` (N - 1,) of the intervals to use (False: e.g. the estimator re-initialised at the later state)."""

    t: np.ndarray
    T_vehicle_world: np.ndarray
    varpi: np.ndarray
    varpi_dot: np.ndarray
    P: np.ndarray | None = None
    valid: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.t)
        if n < 2 or np.any(np.diff(self.t) <= 0):
            raise InputError(f"states: need >= 2 states at strictly increasing times, got {n}")
        for name, shape in (("T_vehicle_world", (n, 4, 4)), ("varpi", (n, 6)), ("varpi_dot", (n, 6))):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise InputError(f"states.{name}: expected finite shape {shape}, got {a.shape}")

    def intervals(self) -> np.ndarray:
        """Indices k of the used intervals (x_{k-1}, x_k), k >= 1."""
        k = np.arange(1, len(self.t))
        return k if self.valid is None else k[np.asarray(self.valid, dtype=bool)]


@dataclass
class QcFit:
    """A fitted diagonal Qc: q (6,), the log-likelihood L(q), the number of intervals, which components sit at
    the floor, and the optimiser's iterations."""

    qc: np.ndarray
    loglik: float
    intervals: int
    at_floor: list[bool] = field(default_factory=list)
    iterations: int = 0


def make_prior(kind: str, qc):
    """The array-level prior "ca" or "cv" with Qc = diag(qc) (`motion_prior(kind, qc).prior`)."""
    return motion_prior(kind, qc).prior


def _predict(motion: MotionPrior, track: StateTrack, k: np.ndarray):
    """(T_pred, varpi_pred, varpi_dot_pred, dt) of f(x_{k-1}) for the intervals k."""
    dt = np.diff(track.t)[k - 1]
    return (*motion.predict_batch(track.T_vehicle_world[k - 1], track.varpi[k - 1], track.varpi_dot[k - 1], dt),
            dt)


def prior_residuals(kind: str, track: StateTrack) -> np.ndarray:
    """e_k = x_k (-) f(x_{k-1}) = [ln(T_k T_pred^-1)^vee; varpi_k - varpi_pred; (vd_k - vd_pred)] for the
    track's intervals, (K, 12) for "cv", (K, 18) for "ca" (the priors' `residual`, batched).

    Checked by: tests/validation/test_calibrate.py::test_residuals_equal_the_priors_residual
    """
    k = track.intervals()
    motion = motion_prior(kind, np.ones(6))
    T_pred, w_pred, vd_pred, _ = _predict(motion, track, k)
    xi = se3.log(track.T_vehicle_world[k] @ se3.inverse(T_pred))
    return np.concatenate([xi, motion.tail(track.varpi[k], track.varpi_dot[k]) - motion.tail(w_pred, vd_pred)],
                          axis=-1)


def transitions_and_basis(kind: str, track: StateTrack, qc) -> tuple[np.ndarray, np.ndarray]:
    """F_k (K, d, d) at x_{k-1} and the noise basis B (K, 6, d, d), B[k, i] = Q_k(e_i e_i^T), so that
    Q_k(q) = sum_i q_i B[k, i] (Q_k is linear in Qc; each B from Q_k(e_i e_i^T + c I) - Q_k(c I), as the
    priors need a positive-definite Qc). `qc` only sets c (1e-3 of its smallest element, at most 1e-3)."""
    k = track.intervals()
    dt = np.diff(track.t)[k - 1]
    w, vd = track.varpi[k - 1], track.varpi_dot[k - 1]
    c = 1e-3 * min(1.0, float(np.min(qc)))  # small against the unit q_i: no digits lost to Q(c + e_i) - Q(c)

    def batch(q):
        return motion_prior(kind, q).transition_and_noise_batch(w, vd, dt)

    F, Q0 = batch(np.full(6, c))
    B = np.stack([batch(c + np.eye(6)[i])[1] - Q0 for i in range(6)], axis=1)
    return F, 0.5 * (B + np.swapaxes(B, -1, -2))


def process_noise(q, B) -> np.ndarray:
    """Q_k(q) = sum_i q_i B[k, i] (K, d, d), from the noise basis B (K, 6, d, d) of `transitions_and_basis`."""
    return np.einsum("i,kiab->kab", np.asarray(q, dtype=float), B)


def _whitened_terms(q, B, S):
    """Q^-1 (K, d, d) and the log-likelihood of S under Q(q) = sum q_i B_i (Jacobi-scaled Cholesky)."""
    Q = process_noise(q, B)
    D = 1.0 / np.sqrt(np.einsum("kaa->ka", Q))
    Qs = Q * D[:, :, None] * D[:, None, :]
    L = np.linalg.cholesky(Qs)
    Ls_inv = np.linalg.inv(L)
    Qs_inv = np.swapaxes(Ls_inv, -1, -2) @ Ls_inv
    Q_inv = Qs_inv * D[:, :, None] * D[:, None, :]
    logdet = 2 * np.log(np.einsum("kaa->ka", L)).sum() - 2 * np.log(D).sum()
    trace = np.einsum("kab,kba->", Q_inv, S)
    d = S.shape[-1]
    return Q_inv, -0.5 * (logdet + trace + S.shape[0] * d * np.log(2 * np.pi))


def expected_log_likelihood(q, B, S) -> tuple[float, np.ndarray]:
    """L(q) and dL/dq_i = 1/2 sum_k tr(B_ki (Q^-1 S Q^-1 - Q^-1)).

    Checked by: tests/validation/test_calibrate.py::test_likelihood_gradient_matches_finite_differences
    """
    Q_inv, value = _whitened_terms(np.asarray(q, dtype=float), B, S)
    M = Q_inv @ S @ Q_inv - Q_inv
    return float(value), 0.5 * np.einsum("kiab,kba->i", B, M)


def floors(floor) -> np.ndarray:
    """The six lower bounds of Qc's diagonal (COMPONENTS' order) from one number or six, each from QC_MIN to
    below QC_MAX."""
    lo = np.broadcast_to(np.asarray(floor, dtype=float), (6,)) if np.ndim(floor) == 0 else np.asarray(floor, float)
    if lo.shape != (6,) or not np.all((lo >= QC_MIN) & (lo < QC_MAX)):  # NaN fails too
        raise InputError(f"floor: one number or six ({','.join(COMPONENTS)}), each from {QC_MIN:g} to below "
                         f"{QC_MAX:g}, got {floor!r}")
    return lo.copy()


def fit_qc(B, S, floor=DEFAULT_FLOOR, qc0=None, fixed=None) -> QcFit:
    """Maximise L(q) (module docstring) over q_i >= floor_i, from qc0 (default: a moment estimate).

    Args:
        B: (K, 6, d, d) noise basis (`transitions_and_basis`); S: (K, d, d) second moments of the residuals.
        floor: one lower bound for every q_i, or six (`floors`).
        fixed: optional (6,) bool mask of components held at qc0 (which must then be given).

    Checked by: tests/validation/test_calibrate.py::test_ml_recovers_qc_of_ca_sde_trajectories
    """
    B, S = np.asarray(B, dtype=float), np.asarray(S, dtype=float)
    if B.ndim != 4 or B.shape[1] != 6 or S.shape != (B.shape[0], *B.shape[2:]) or B.shape[0] == 0:
        raise InputError(f"fit_qc: B (K, 6, d, d) and S (K, d, d) do not match: {B.shape}, {S.shape}")
    if qc0 is None:  # each q_i alone explaining the matching diagonal part of S
        diag_b = np.einsum("kiaa->ia", B)
        qc0 = np.einsum("kaa->a", S) @ diag_b.T / np.maximum((diag_b**2).sum(axis=1), 1e-300)
    floor = floors(floor)
    theta0 = np.log(np.maximum(np.asarray(qc0, dtype=float), floor))
    fixed = np.zeros(6, bool) if fixed is None else np.asarray(fixed, dtype=bool)
    bounds = [(t, t) if f else (np.log(lo), np.log(QC_MAX)) for t, f, lo in zip(theta0, fixed, floor)]
    scale = float(B.shape[0] * S.shape[-1])

    def objective(theta):
        value, grad = expected_log_likelihood(np.exp(theta), B, S)
        return -value / scale, -grad * np.exp(theta) / scale

    res = optimize.minimize(objective, theta0, jac=True, method="L-BFGS-B",
                            bounds=bounds, options=dict(maxiter=500, gtol=1e-10))
    qc = np.where(fixed, np.asarray(qc0, dtype=float), np.clip(np.exp(res.x), floor, QC_MAX))  # exp(log) rounds
    value, _ = expected_log_likelihood(qc, B, S)
    return QcFit(qc, value, int(B.shape[0]), [bool(x <= lo * 1.01 and not f) for x, f, lo in zip(qc, fixed, floor)],
                 int(res.nit))


def fit_qc_to_truth(kind: str, tracks, floor=DEFAULT_FLOOR) -> QcFit:
    """Maximum-likelihood diagonal Qc of the prior `kind` from true trajectories (one `StateTrack` or several:
    their intervals are pooled), S_k = e_k e_k^T, B_k linearised at the true states.

    Checked by: tests/validation/test_calibrate.py::test_ml_recovers_qc_of_ca_sde_trajectories,
    ::test_ml_recovers_qc_of_cv_sde_trajectories
    """
    tracks = [tracks] if isinstance(tracks, StateTrack) else list(tracks)
    if not tracks:
        raise InputError("fit_qc_to_truth: no trajectories")
    Bs, Ss = [], []
    for track in tracks:
        e = prior_residuals(kind, track)
        Bs.append(transitions_and_basis(kind, track, np.ones(6))[1])
        Ss.append(e[:, :, None] * e[:, None, :])
    return fit_qc(np.concatenate(Bs), np.concatenate(Ss), floor)


# ------------------------------------------------------------------------------------ EM without ground truth
@dataclass
class EmIteration:
    """One EM iteration: the Qc the estimator ran with (qc_in), the M-step's Qc (qc_out), the expected
    log-likelihood at qc_out, the largest relative change max_i |qc_out - qc_in| / qc_in, the Qc of the
    next run (qc_next: qc_out, or its Aitken extrapolation) and `remaining`, the largest relative distance from
    qc_out to EM's fixed point that the last two steps extrapolate to (`remaining_distance`)."""

    qc_in: np.ndarray
    qc_out: np.ndarray
    loglik: float
    change: float
    intervals: int
    qc_next: np.ndarray
    remaining: float = float("nan")
    steps: int = 0  # EM steps in the run's linear-Gaussian stand-in (`em_surrogate.surrogate_em`)


def remaining_distance(step: np.ndarray, previous: np.ndarray | None) -> float:
    """How far EM still has to go, relative, the largest over the components: a sequence converging
    geometrically with ratio r = step / previous (0 < r < 1) has |step| r / (1 - r) left (in log q); a step
    that grew (r >= 1) extrapolates to no fixed point (inf); one that turned back (r <= 0) has less than |step|
    left. The first step, with nothing to compare, counts as it is. EM's change per iteration is small where it
    converges slowly (the data say little), so the change alone stops it early: from 40 x the truth, 5 % a step
    was reached at 1.3 x (docs/calibration.md).

    Checked by: tests/validation/test_calibrate.py::test_remaining_distance_of_a_geometric_sequence
    """
    step = np.asarray(step, dtype=float)
    size = np.abs(step)
    if previous is None:
        return float(np.max(np.expm1(size)))
    previous = np.asarray(previous, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.abs(previous) > 1e-12, step / previous, 0.0)
    with np.errstate(divide="ignore"):
        tail = np.where(r >= 1.0, np.inf, np.where(r > 0.0, size * r / (1.0 - r), size))
    tail = np.where(size == 0.0, 0.0, tail)
    return float(np.max(np.expm1(tail)))


def aitken_step(step: np.ndarray, previous: np.ndarray | None, max_factor: float = 5.0) -> np.ndarray:
    """Accelerated EM step in log q, per component: an EM sequence converging geometrically with ratio
    r = step / previous (0 < r < 1) has its limit step / (1 - r) ahead (Aitken's delta-squared, as in
    McLachlan & Krishnan, "The EM Algorithm and Extensions", sec. 4.8); the factor is capped at max_factor
    (also for r >= 1) and only used when both steps point the same way. The fixed points are EM's.

    Checked by: tests/validation/test_calibrate.py::test_aitken_step_reaches_a_geometric_limit
    """
    if previous is None:
        return step
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.abs(previous) > 1e-12, step / previous, 0.0)
    factor = np.where(r > 0, 1.0 / np.maximum(1.0 - r, 1.0 / max_factor), 1.0)
    return step * factor


def em_qc(run, kind: str, qc0, iterations: int = 5, tolerance: float = 0.05, floor=DEFAULT_FLOOR,
          accelerate: bool = True, on_iteration=None, learn=None) -> list[EmIteration]:
    """EM without ground truth: `run(qc) -> StateTrack` (with P; or a list of them) is the estimator run with
    Qc = diag(qc); from its posteriors EM runs to its fixed point in the drive's linear-Gaussian stand-in
    (`em_surrogate.surrogate_em`: a smoother per step, the M-step `fit_qc`), and the estimator is run again at that
    Qc, until the Qc it returns is within `tolerance` (relative) of the fixed point the last two runs' steps
    extrapolate to (`remaining_distance`), or after `iterations` runs. With `accelerate` the next run uses the
    Aitken extrapolation of the runs' steps (`aitken_step`). Returns one EmIteration per run; the result is the
    last qc_out. `on_iteration(EmIteration)`, if given, is called after each. `learn`: optional (6,) bool mask of
    the components to learn; the others stay at qc0.

    Checked by: tests/validation/test_em_surrogate.py::test_em_recovers_qc_with_a_kalman_filter
    """
    from .em_surrogate import surrogate_em, surrogates

    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise InputError(f"iterations: must be an integer >= 1, got {iterations!r}")
    qc = np.asarray(qc0, dtype=float)
    if qc.shape != (6,) or not np.all(np.isfinite(qc)) or not np.all(qc > 0):
        raise InputError(f"qc0: must be 6 positive numbers, got {qc0!r}")
    if learn is not None and (np.shape(learn) != (6,) or not np.any(learn)):
        raise InputError(f"learn: expected 6 booleans, at least one true, got {learn!r}")
    floor = floors(floor)
    history, previous = [], None
    for _ in range(int(iterations)):
        tracks = run(qc)
        parts = [s for tr in ([tracks] if isinstance(tracks, StateTrack) else tracks)
                 for s in surrogates(kind, tr, qc)]
        fixed = np.zeros(6, bool) if learn is None else ~np.asarray(learn, dtype=bool)
        fit, steps = surrogate_em(parts, qc, floor, fixed=fixed)
        step = np.log(fit.qc) - np.log(qc)
        jump = aitken_step(step, previous) if accelerate else step
        qc_next = np.where(fixed, qc, np.clip(qc * np.exp(jump), floor, QC_MAX))  # a fixed one stays, floor or not
        change = float(np.max(np.abs(fit.qc - qc) / qc))
        remaining = remaining_distance(step, previous)
        history.append(EmIteration(qc, fit.qc, fit.loglik, change, fit.intervals, qc_next, remaining, steps))
        if on_iteration is not None:
            on_iteration(history[-1])
        if remaining < tolerance or np.any(fit.qc[~fixed] >= QC_MAX):  # converged, or a runaway: no fixed point
            break
        qc, previous = qc_next, step
    return history
